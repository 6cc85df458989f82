"""Benchmarks of the Blender side of Ember (bpy module):

    .venv/bin/python -P tools/bench_export.py [--json FILE]

1. export: a scene of more than a million triangles made mostly by instancing
   (geometry-node copies of a dense sphere, collection instances of a
   subdivided monkey) plus one large unique grid; prints the export time, the
   instanced triangles per second (what the renderer will trace) and the unique
   triangles per second (what was actually copied out of Blender);
2. first pass: the time from the start of render() to the first displayed pass
   for blend_scenes/cornell.blend at its own resolution.
"""
import argparse
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def setup():
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-bench-'))
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    import addon
    addon.register()


def build_heavy_scene():
    import bpy
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    bpy.data.objects.remove(bpy.data.objects['Cube'])
    # A dense sphere copied onto a 10x10 grid by geometry nodes.
    bpy.ops.mesh.primitive_uv_sphere_add(segments=128, ring_count=64, location=(0, 0, -100))
    sphere = bpy.context.object
    sys.path.insert(0, os.path.join(ROOT, 'blend_scenes'))
    import build_scenes
    grid = build_scenes._geometry_nodes_instancer(scene, sphere)
    grid.data.clear_geometry()
    grid.data.from_pydata([(x * 2.5, y * 2.5, 0.0) for x in range(10) for y in range(10)], [], [])
    # A subdivided monkey in a collection instanced 20 times.
    bpy.ops.mesh.primitive_monkey_add()
    monkey = bpy.context.object
    monkey.modifiers.new("Subsurf", 'SUBSURF').levels = 2
    source = bpy.data.collections.new("MonkeySource")
    for owner in list(monkey.users_collection):
        owner.objects.unlink(monkey)
    source.objects.link(monkey)
    for i in range(20):
        empty = bpy.data.objects.new(f"Monkey{i}", None)
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = source
        empty.location = (i * 2.5, -5.0, 0.0)
        scene.collection.objects.link(empty)
    # One large unique mesh.
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=400, y_subdivisions=400, size=30, location=(0, 0, -2))
    bpy.ops.object.shade_smooth()
    bpy.context.view_layer.update()
    return scene


def bench_export(repeats=3):
    import bpy
    from addon.export import scene as scene_export
    build_heavy_scene()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        exported = scene_export.export_scene(depsgraph)
        runs.append(time.perf_counter() - start)
    unique = sum(len(mesh.triangles) for mesh in exported.scene.meshes)
    best = min(runs)
    return {
        'instances': len(exported.scene.instances),
        'meshes': len(exported.scene.meshes),
        'instanced_triangles': exported.triangles,
        'unique_triangles': unique,
        'export_seconds_first': runs[0],
        'export_seconds_best': best,
        'instanced_triangles_per_second': exported.triangles / best,
        'unique_triangles_per_second': unique / best,
    }


def bench_first_pass(samples=16):
    import bpy
    from addon import backend
    from addon import engine as ember_engine
    try:
        backend.require_ray_tracer()
    except ImportError as err:
        return {'first_pass_error': f"engine.render unavailable: {err}"}
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, 'blend_scenes', 'cornell.blend'))
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    scene.ember.samples = samples
    del ember_engine.RENDER_LOG[:]
    try:
        bpy.ops.render.render()
    except RuntimeError as err:
        return {'first_pass_error': str(err).strip()}
    entry = ember_engine.RENDER_LOG[-1]
    return {
        'cornell_resolution': (scene.render.resolution_x, scene.render.resolution_y),
        'cornell_export_seconds': entry.get('export_seconds'),
        'cornell_first_pass_seconds': entry.get('first_pass_seconds'),
        'cornell_total_seconds': entry.get('seconds'),
        'cornell_samples': entry.get('samples'),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', help="also write the numbers to this file")
    args = parser.parse_args(argv)
    setup()
    results = bench_export()
    print(f"export: {results['instanced_triangles']:,} instanced triangles "
          f"({results['instances']} instances of {results['meshes']} meshes, "
          f"{results['unique_triangles']:,} unique) in {results['export_seconds_best']:.3f} s "
          f"(first run {results['export_seconds_first']:.3f} s)")
    print(f"export: {results['instanced_triangles_per_second'] / 1e6:.1f} M instanced triangles/s, "
          f"{results['unique_triangles_per_second'] / 1e6:.2f} M unique triangles/s")
    results.update(bench_first_pass())
    if 'first_pass_error' in results:
        print("first pass: not measured:", results['first_pass_error'])
    else:
        print(f"first pass: {results['cornell_first_pass_seconds']:.3f} s after render start "
              f"(Cornell box {results['cornell_resolution'][0]}x{results['cornell_resolution'][1]}, "
              f"export {results['cornell_export_seconds']:.3f} s)")
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as handle:
            json.dump(results, handle, indent=2)
    return results


if __name__ == '__main__':
    main()
