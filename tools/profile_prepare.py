"""Where a bench-cycles scene's preparation goes, stage by stage, through
the add-on's export (bpy module):

    .venv/bin/python -P tools/profile_prepare.py --scene instanced --repeat 3
    .venv/bin/python -P tools/profile_prepare.py --scene instanced --profile
    .venv/bin/python -P tools/profile_prepare.py --instances 1000000   # fuzz_scenes' many_instances

Stages: export (depsgraph -> engine Scene), flatten (instances -> world-space
Triangles), accel (Embree upload and BVH commit), prepare (all of
engine.render.prepare: the two before plus lights, camera, materials).
Each shows wall seconds and process CPU seconds (all threads: Embree's
commit runs on TBB's).  On a shared machine compare CPU seconds, and run
the versions to compare alternately.  ``--profile`` prints cProfile's
top functions of one prepare instead.  The compiled kernels are ready
first, as in any render after Blender's first (``--no-jit``: NumPy forms).
"""
import argparse
import cProfile
import os
import pstats
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def setup(name, instances=0):
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-prepare-'))
    for path in (ROOT, os.path.join(ROOT, 'tools'), os.path.join(ROOT, 'tests', 'addon')):
        if path not in sys.path:
            sys.path.insert(0, path)
    import addon
    import bench_scenes
    addon.register()
    if instances:
        import numpy as np
        import fuzz_scenes
        scene = fuzz_scenes.reset_scene()
        fuzz_scenes.many_instances(scene, np.random.default_rng(0), tempfile.mkdtemp(), count=instances)
        return scene
    return bench_scenes.SCENES[name][1]()


def timed(function, *args):
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def stages(depsgraph, settings):
    from addon.export import scene as scene_export
    from engine import accel, geometry, prepare
    from engine.blas import single_threaded_blas
    out = {}
    with single_threaded_blas():   # as engine.render.render runs prepare
        exported, *out['export'] = timed(scene_export.export_scene, depsgraph)
        tris, *out['flatten'] = timed(geometry.flatten, exported.scene)
        _, *out['accel'] = timed(accel.Accel, tris)
        del tris
        _, *out['prepare'] = timed(prepare, exported.scene, settings)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scene', default='instanced')
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--instances', type=int, default=0, help="fuzz_scenes.many_instances of this many copies")
    parser.add_argument('--profile', action='store_true', help="cProfile one prepare instead")
    parser.add_argument('--no-jit', action='store_true', help="NumPy forms of the kernels (as EMBER_JIT=0)")
    args = parser.parse_args(argv)
    scene = setup(args.scene, args.instances)
    from engine import kernels, render  # noqa: F401 - every kernel defined before compiling
    # As a render after the first: the compiled kernels ready (flatten has one).
    print(f"compiled kernels: {kernels.configure(not args.no_jit) and kernels.wait(900)}")
    import bpy
    from addon.export import scene as scene_export
    depsgraph = bpy.context.evaluated_depsgraph_get()
    settings = scene_export.render_settings(scene)
    settings.use_jit = not args.no_jit   # prepare configures the kernels from the settings
    if args.profile:
        from engine import prepare
        from engine.blas import single_threaded_blas
        exported = scene_export.export_scene(depsgraph)
        profile = cProfile.Profile()
        with single_threaded_blas():
            profile.runcall(prepare, exported.scene, settings)
        pstats.Stats(profile).sort_stats('tottime').print_stats(25)
        return
    for _ in range(args.repeat):
        out = stages(depsgraph, settings)
        print('  '.join(f"{name} {wall:.2f} s / {cpu:.2f} s CPU" for name, (wall, cpu) in out.items())
              + f"  (load {os.getloadavg()[0]:.1f})", flush=True)


if __name__ == '__main__':
    main()
