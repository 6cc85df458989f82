"""Peak memory of Ember renders through the add-on (bpy module), and where it goes.

Each measurement runs in a fresh process (peak RSS = the kernel's VmHWM, which
a fork would inherit otherwise):

    python -P tools/bench_memory.py                      # 3840x2160 and 7680x4320, 1 sample
    python -P tools/bench_memory.py --sizes 1920x1080 --samples 4
    python -P tools/bench_memory.py --animation 100      # RSS after every frame of a 100-frame render
    python -P tools/bench_memory.py --image 8192         # an 8k x 8k texture: copies of its pixels

The breakdown: ``baseline`` is the process before rendering (Python, bpy,
the scene); ``numpy peak`` is the largest total of NumPy/Python allocations
during the render (tracemalloc, which NumPy reports to); of it, ``film`` is
the engine's accumulation buffers and ``paths`` the path state of the
batches in flight (``max_paths``); ``outside numpy`` is the rest of the peak:
Blender's render result buffers (its Combined pass and the copies Blender
makes to display and save it), Embree's BVH and allocator slack.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MIB = 1024 * 1024

CHILD = r'''
import importlib, json, os, sys, time, tracemalloc
sys.path.insert(0, ROOT)
os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp())
import bpy, numpy as np
import addon
addon.register()
from addon import backend, engine as ember_engine

def status(field):
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith(field + ':'):
                return int(line.split()[1]) * 1024
    return 0

scene = bpy.context.scene
scene.render.engine = 'EMBER'
scene.render.resolution_x, scene.render.resolution_y = WIDTH, HEIGHT
scene.render.resolution_percentage = 100
scene.ember.samples = SAMPLES
scene.ember.threads = 2
if IMAGE:
    import zlib, struct
    path = os.path.join(tempfile.mkdtemp(), 'big.exr')
    img = bpy.data.images.new('Big', IMAGE, IMAGE, float_buffer=True)
    img.pixels.foreach_set(np.random.default_rng(0).random(IMAGE * IMAGE * 4, dtype=np.float32))
    img.filepath_raw = path
    img.file_format = 'OPEN_EXR'
    img.save()
    bpy.data.images.remove(img)
    mat = bpy.data.materials.new('Tex')
    mat.use_nodes = True
    node = mat.node_tree.nodes.new('ShaderNodeTexImage')
    node.image = bpy.data.images.load(path)
    bsdf = mat.node_tree.nodes['Principled BSDF']
    mat.node_tree.links.new(node.outputs['Color'], bsdf.inputs['Base Color'])
    cube = scene.objects['Cube']
    cube.data.materials.append(mat)
    node.image.buffers_free()  # Blender loaded nothing yet: only Ember's copy counts

film_bytes = []
render_module = importlib.import_module(backend.engine().__name__ + '.render')  # the module
RealFilm = render_module.Film
class MeasuredFilm(RealFilm):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        film_bytes.append(sum(v.nbytes for v in vars(self).values() if isinstance(v, np.ndarray)))
render_module.Film = MeasuredFilm

rss = []
def after_frame(*_):
    rss.append(status('VmRSS'))
bpy.app.handlers.render_post.append(after_frame)

if FRAMES > 1:
    # Growth per frame, not the compiler's: with a cold kernel cache (a new
    # Ember version) the kernels would compile during the first frames.
    backend.engine().configure_kernels(True)
    backend.engine().wait_for_kernels(900)
baseline = status('VmRSS')
tracemalloc.start()
if FRAMES > 1:
    scene.frame_start, scene.frame_end = 1, FRAMES
    scene.render.filepath = os.path.join(tempfile.mkdtemp(), 'frame_####')
    scene.render.image_settings.file_format = 'PNG'
    cube = scene.objects['Cube']
    cube.rotation_mode = 'XYZ'
    cube.keyframe_insert('rotation_euler', frame=1)
    cube.rotation_euler = (0, 0, 3.14)
    cube.keyframe_insert('rotation_euler', frame=FRAMES)
    bpy.ops.render.render(animation=True)
else:
    bpy.ops.render.render()
_, numpy_peak = tracemalloc.get_traced_memory()
tracemalloc.stop()
log = ember_engine.RENDER_LOG[-1]
print("MEMORY " + json.dumps({
    'width': WIDTH, 'height': HEIGHT, 'samples': SAMPLES, 'error': log['error'],
    'baseline': baseline, 'peak': status('VmHWM'), 'numpy_peak': numpy_peak,
    'film': film_bytes[-1] if film_bytes else 0, 'max_paths': MAX_PATHS,
    'rss_after_frames': rss, 'image': IMAGE}))
'''


def measure(width, height, samples=1, frames=1, image=0):
    from addon.export.scene import MAX_PATHS
    code = CHILD
    for name, value in (('ROOT', repr(ROOT)), ('WIDTH', width), ('HEIGHT', height), ('SAMPLES', samples),
                        ('FRAMES', frames), ('IMAGE', image), ('MAX_PATHS', MAX_PATHS)):
        code = code.replace(name, str(value))
    code = 'import tempfile\n' + code
    env = dict(os.environ, PYTHONPATH=ROOT)
    proc = subprocess.run([sys.executable, '-P', '-c', code], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=3600)
    lines = [line for line in proc.stdout.splitlines() if line.startswith('MEMORY ')]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"measurement failed ({proc.returncode}): {(proc.stdout + proc.stderr)[-3000:]}")
    return json.loads(lines[-1][len('MEMORY '):])


def describe(m):
    peak, base, numpy_peak, film = m['peak'], m['baseline'], m['numpy_peak'], m['film']
    return (f"{m['width']}x{m['height']} {m['samples']} spp: peak RSS {peak / MIB:.0f} MiB "
            f"= baseline {base / MIB:.0f} + render {(peak - base) / MIB:.0f} MiB; numpy peak "
            f"{numpy_peak / MIB:.0f} MiB (film {film / MIB:.0f} MiB, {m['width'] * m['height'] / 1e6:.1f} Mpx x "
            f"{film / max(m['width'] * m['height'], 1):.0f} B), outside numpy "
            f"{(peak - base - numpy_peak) / MIB:.0f} MiB (Blender result buffers, BVH)")


def animation_growth(m, skip=5):
    """RSS growth from frame `skip` to the last frame, in MiB."""
    rss = m['rss_after_frames']
    return (rss[-1] - rss[min(skip, len(rss) - 1)]) / MIB if rss else 0.0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sizes', nargs='*', default=['3840x2160', '7680x4320'])
    parser.add_argument('--samples', type=int, default=1)
    parser.add_argument('--animation', type=int, default=0, help="frames of a 64x64 animation")
    parser.add_argument('--image', type=int, default=0, help="side of a square float texture to add")
    parser.add_argument('--json', help="write the measurements here")
    args = parser.parse_args(argv)
    sys.path.insert(0, ROOT)
    results = []
    for size in args.sizes:
        width, height = (int(v) for v in size.split('x'))
        m = measure(width, height, args.samples, image=args.image)
        results.append(m)
        print(describe(m), flush=True)
    if args.animation:
        m = measure(64, 64, 1, frames=args.animation)
        results.append(m)
        rss = [v / MIB for v in m['rss_after_frames']]
        print(f"{args.animation}-frame animation: RSS after frame 1 {rss[0]:.0f} MiB, frame 5 {rss[4]:.0f} MiB, "
              f"last {rss[-1]:.0f} MiB; growth after frame 5: {animation_growth(m):+.1f} MiB")
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
