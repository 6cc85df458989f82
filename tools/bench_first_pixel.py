"""Time to Ember's first image of the Cornell box (blend_scenes/cornell.blend
at 256x256) through the add-on, as a user meets it:

    .venv/bin/python -P tools/bench_first_pixel.py [--size 256]

1. cold: a new process whose numba cache is empty, as right after an
   install (the render waits for the kernels to compile, showing
   "Compiling kernels", then runs compiled);
2. warm: a new process with that cache filled (a user's second session);
3. again: a second F12 in the warm process.

"First image" is the time from the start of ``RenderEngine.render`` (export
included) to the first pass written to Blender's render result; "render" is
the whole F12 less the wait for the compile.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r'''
import json, os, sys, time
sys.path.insert(0, {root!r})
os.environ.setdefault('BLENDER_USER_RESOURCES', {resources!r})
import bpy, addon
addon.register()
from addon import engine as ember_engine
bpy.ops.wm.open_mainfile(filepath=os.path.join({root!r}, 'blend_scenes', 'cornell.blend'))
scene = bpy.context.scene
scene.render.engine = 'EMBER'
scene.render.resolution_x = scene.render.resolution_y = {size}
scene.render.resolution_percentage = 100
scene.ember.samples = 16
out = []
for _ in range(2):
    bpy.ops.render.render()
    log = ember_engine.RENDER_LOG[-1]
    stats = log.get('stats') or dict()
    out.append(dict(first=log.get('first_pass_seconds'), export=log.get('export_seconds'), total=log.get('seconds'),
                    wait=stats.get('compile_wait_seconds', 0.0), kernels=stats.get('kernels')))
print('RESULT ' + json.dumps(out))
'''


def run(size, cache, resources):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=ROOT)
    code = CHILD.format(root=ROOT, size=size, resources=resources)
    done = subprocess.run([sys.executable, '-P', '-c', code], env=env, capture_output=True, text=True,
                          timeout=900)
    for line in done.stdout.splitlines():
        if line.startswith('RESULT '):
            return json.loads(line[7:])
    raise SystemExit(f"child failed:\n{done.stdout[-2000:]}\n{done.stderr[-4000:]}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--size', type=int, default=256)
    args = parser.parse_args(argv)
    print(f"Cornell box {args.size}x{args.size}, load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory(prefix='ember-numba-') as cache, \
            tempfile.TemporaryDirectory(prefix='ember-resources-') as resources:
        cold = run(args.size, cache, resources)
        warm = run(args.size, cache, resources)
    rows = [("cold cache, new process", cold[0]), ("warm cache, new process", warm[0]),
            ("warm, second F12", warm[1])]
    for label, r in rows:
        print(f"  {label:26s} first image {r['first']:.2f} s (export {r['export']:.2f} s), "
              f"16 spp done {r['total']:.2f} s, of it {r['wait']:.2f} s compiling; "
              f"render {r['total'] - r['wait']:.2f} s on {r['kernels']} kernels")
    ratio = (cold[0]['total'] - cold[0]['wait']) / (warm[1]['total'] - warm[1]['wait'])
    print(f"  first F12 after install / second F12, compile wait left out: {ratio:.2f}x")


if __name__ == '__main__':
    main()
