"""Where one batch of a yardstick scene spends its CPU, without Blender in the loop.

    .venv/bin/python -P tools/profile_scene.py principled            (thread CPU per 64k paths)
    .venv/bin/python -P tools/profile_scene.py principled --profile  (cProfile, top functions)

The scene is built and exported once through the add-on (tools/bench_scenes.py,
bpy) and cached as a pickle in build/scene_pickles/; later runs load it with
the engine alone.  Each timing traces the same 65,536 camera paths (pixels 0..
65535, one sample) on one thread with the compiled kernels ready: alternate two
checkouts in one run to compare versions (timings vary 10-20 % between runs).
"""
import argparse
import cProfile
import os
import pickle
import pstats
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CACHE = os.path.join(ROOT, 'build', 'scene_pickles')
PATHS = 1 << 16


def export(name, path):
    """Build the scene in a bpy subprocess and pickle (Scene, RenderSettings)."""
    code = f"""
import sys, pickle
sys.path[:0] = [{ROOT!r}, {os.path.join(ROOT, 'tools')!r}, {os.path.join(ROOT, 'tests')!r},
                {os.path.join(ROOT, 'tests', 'addon')!r}]
import bpy, addon
addon.register()
import bench_scenes
from addon.export import scene as export
from ember_testlib import setup_ember
scene = bench_scenes.SCENES[{name!r}][1]()
scene.render.resolution_x = scene.render.resolution_y = 256
scene.render.resolution_percentage = 100
setup_ember(scene, 8, 1, 8)
scene.ember.use_adaptive_sampling = False
exported = export.export_scene(bpy.context.evaluated_depsgraph_get())
with open({path!r}, 'wb') as handle:
    pickle.dump((exported.scene, export.render_settings(scene)), handle)
"""
    subprocess.run([sys.executable, '-P', '-c', code], check=True)


def load(name):
    os.makedirs(CACHE, exist_ok=True)
    path = os.path.join(CACHE, name + '.pkl')
    if not os.path.isfile(path):
        export(name, path)
    with open(path, 'rb') as handle:
        return pickle.load(handle)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('scene', help="a tools/bench_scenes.py name (cornell, veach_mis, principled, ...)")
    parser.add_argument('--profile', action='store_true', help="cProfile one batch instead of timing three")
    parser.add_argument('--top', type=int, default=30)
    parser.add_argument('--sort', default='tottime')
    args = parser.parse_args(argv)
    sys.path.insert(0, ROOT)
    from engine import kernels
    from engine.blas import single_threaded_blas
    from engine.film import Film
    from engine.integrator import trace_batch
    from engine.render import prepare
    scene, settings = load(args.scene)
    ctx = prepare(scene, settings)
    print(f"compiled kernels: {kernels.configure(True) and kernels.wait(900)}")
    film = Film(ctx.camera.width, ctx.camera.height, settings.aovs)
    pixels = np.arange(PATHS) % (ctx.camera.width * ctx.camera.height)

    def batch(sample):
        trace_batch(ctx, pixels, np.full(PATHS, sample, np.uint32), film.new_tile(0, int(pixels.max()) + 1))
    with single_threaded_blas():
        batch(0)   # warm caches
        if args.profile:
            profiler = cProfile.Profile()
            profiler.enable()
            batch(1)
            profiler.disable()
            pstats.Stats(profiler).sort_stats(args.sort).print_stats(args.top)
            return
        for sample in (1, 2, 3):
            t0 = time.thread_time()
            batch(sample)
            print(f"{args.scene}: {time.thread_time() - t0:.3f} CPU-s per {PATHS} paths (sample {sample})")


if __name__ == '__main__':
    main()
