"""RenderEngine.bake for Ember (bpy.ops.object.bake): reads the texels
Blender prepared (BakePrimitive), computes the baked values with
engine/bake.py and writes them into the bake result's Combined pass.
Blender applies the margin, the normal space and swizzle, cage and
selected-to-active itself.  Bad input ends in a clear report, never a crash."""
import numpy as np

import bpy

from . import backend
from .export import material as material_export
from .export import mesh as mesh_export


# Bake types of the whole exported scene besides the light bakes.
SCENE_WIDE = ('SHADOW', 'ENVIRONMENT')


class BakeError(Exception):
    """A bake Ember cannot do; the message is meant for the user."""


def bake(engine, depsgraph, obj, pass_type, pass_filter, width, height):
    try:
        _bake(engine, depsgraph, obj, pass_type, pass_filter, width, height)
    except BakeError as err:
        engine.report({'ERROR'}, f"Ember: {err}")
    except Exception as err:  # noqa: BLE001 - every failure must reach the user
        import traceback
        traceback.print_exc()
        engine.report({'ERROR'}, f"Ember: bake failed: {type(err).__name__}: {err}")


def _bake(engine, depsgraph, obj, pass_type, pass_filter, width, height):
    renderer = backend.engine()
    name = getattr(obj, 'name', '?')
    if width <= 0 or height <= 0:
        raise BakeError(f"object '{name}': the bake image has no pixels ({width} x {height})")
    if obj is None or obj.type not in mesh_export.MESHABLE_TYPES:
        raise BakeError(f"object '{name}' is not a mesh: only meshes can be baked")
    if pass_type not in renderer.bake.SUPPORTED:
        raise BakeError(f"bake type {pass_type} is not supported yet (Ember bakes "
                        f"{', '.join(renderer.bake.SUPPORTED)})")
    evaluated = obj.evaluated_get(depsgraph) if hasattr(obj, 'evaluated_get') else obj
    mesh = mesh_export.mesh_from_object(evaluated, name, depsgraph=depsgraph)
    if mesh is None:
        raise BakeError(f"object '{name}' has no triangles to bake")
    if pass_type in renderer.bake.LIGHT + SCENE_WIDE and mesh.uvs is None:
        raise BakeError(f"object '{name}' has no UV map: a {pass_type} bake needs one to place its texels")
    matrix = np.array(evaluated.matrix_world, np.float64)
    result = engine.begin_result(0, 0, width, height, layer=depsgraph.view_layer.name, view="")
    try:
        layer = result.layers[0]
        primitive_pass = layer.passes.get("BakePrimitive") if hasattr(layer.passes, 'get') else None
        if primitive_pass is None:
            primitive_pass = next((p for p in layer.passes if p.name == "BakePrimitive"), None)
        if primitive_pass is None:
            raise BakeError("Blender gave no BakePrimitive pass")
        channels = primitive_pass.channels
        flat = np.empty(width * height * channels, np.float32)
        try:
            primitive_pass.rect.foreach_get(flat)
        except (RuntimeError, TypeError, ValueError) as err:   # a result of another size than asked
            raise BakeError(f"object '{name}': Blender's bake result does not hold {width} x {height} "
                            f"texels ({err})") from None
        prim, u, v = renderer.bake.unpack_primitives(flat.reshape(-1, channels))
        if pass_type in renderer.bake.LIGHT + SCENE_WIDE:
            rgba = _bake_light(engine, renderer, depsgraph, evaluated, pass_type, pass_filter, prim, u, v,
                               _differentials(layer, width * height))
            if rgba is None:
                return   # cancelled: Blender keeps the image as it was
        elif pass_type == 'AO':
            scene, index = _exported_scene(engine, depsgraph, evaluated)
            world = depsgraph.scene.world
            distance = world.light_settings.distance if world is not None else 10.0
            rgba = renderer.bake.bake_ao(scene, index, prim, u, v, depsgraph.scene.ember.samples, distance,
                                         seed=getattr(depsgraph.scene.ember, 'seed', 0))
        elif pass_type in renderer.bake.SHADED:
            rgba = renderer.bake.bake_shaded(_object_scene(renderer, depsgraph, evaluated, mesh, matrix, engine),
                                             pass_type, prim, u, v)
        else:
            rgba = renderer.bake.bake_geometric(mesh, matrix, pass_type, prim, u, v)
        combined = next(p for p in layer.passes if p.name == "Combined")
        out = np.zeros((width * height, combined.channels), np.float32)
        k = min(4, combined.channels)
        out[:, :k] = rgba[:, :k]
        combined.rect.foreach_set(np.ascontiguousarray(out).ravel())
    finally:
        engine.end_result(result)


def _differentials(layer, count):
    """(N, 4) BakeDifferential (du/dx, du/dy, dv/dx, dv/dy), or None."""
    diff = next((p for p in layer.passes if p.name == "BakeDifferential"), None)
    if diff is None or diff.channels != 4:
        return None
    flat = np.empty(count * 4, np.float32)
    diff.rect.foreach_get(flat)
    return flat.reshape(-1, 4)


def filter_names(pass_filter):
    """Blender's pass filter (an int of BakeSettings.pass_filter bits, or a
    set of its names) as a set of names."""
    if isinstance(pass_filter, (set, frozenset, list, tuple)):
        return {str(n) for n in pass_filter}
    items = bpy.types.BakeSettings.bl_rna.properties['pass_filter'].enum_items
    return {item.identifier for item in items if item.value and int(pass_filter) & item.value}


class _BakeProgress:
    """Progress and cancel of a light bake, as a render's: Blender's
    progress bar and status line, Esc (test_break) between batches."""

    def __init__(self, engine, samples):
        self.engine, self.samples = engine, max(int(samples), 1)
        self.cancelled = False

    def on_pass(self, image, samples_done, stats):
        self.engine.update_progress(min(samples_done / self.samples, 1.0))
        self.engine.update_stats("", f"Ember: baking, sample {samples_done} / {self.samples}")

    def should_stop(self):
        from . import output
        if output.break_requested(self.engine):
            self.cancelled = True
        return self.cancelled


def _bake_light(engine, renderer, depsgraph, obj, pass_type, pass_filter, prim, u, v, diff):
    """A DIFFUSE / GLOSSY / TRANSMISSION / COMBINED / SHADOW bake: the
    whole scene (every object casts, reflects and emits light), traced by
    the render integrator from the object's texels with Render > Samples
    (ENVIRONMENT: the world only); None when the user cancelled."""
    from .export import scene as scene_export
    backend.require_ray_tracer()
    scene, index = _exported_scene(engine, depsgraph, obj)
    settings = scene_export.render_settings(depsgraph.scene)
    progress = _BakeProgress(engine, settings.samples)
    try:
        if pass_type == 'SHADOW':
            baked = renderer.bake.bake_shadow(scene, index, prim, u, v, settings, diff=diff, progress=progress)
        elif pass_type == 'ENVIRONMENT':
            baked = renderer.bake.bake_background(scene, index, prim, u, v, settings, diff=diff)
        else:
            baked = renderer.bake.bake_light(scene, index, prim, u, v, pass_type, filter_names(pass_filter),
                                             settings, diff=diff, progress=progress)
    except renderer.Cancelled:
        return None
    for warning in getattr(baked.result, 'warnings', None) or ():
        engine.report({'WARNING'}, f"Ember: {warning}")
    return None if progress.cancelled else baked.rgba


def _object_scene(renderer, depsgraph, obj, mesh, matrix, engine):
    """A one-instance engine Scene of the baked object with its materials
    compiled by the exporter (the render's node evaluation); their
    translation warnings reach the user."""
    override = getattr(depsgraph.view_layer, 'material_override', None)
    materials = material_export.MaterialTable(override)
    instance = renderer.Instance(mesh=0, matrix=matrix, materials=materials.slots(obj), name=obj.name)
    for warning in materials.warnings:
        engine.report({'WARNING'}, f"Ember: {warning}")
    return renderer.Scene(meshes=[mesh], instances=[instance], materials=materials.materials,
                          cycles_version=tuple(bpy.app.version))


def _exported_scene(engine, depsgraph, obj):
    """The whole scene as the render exports it (meshes, point clouds,
    curves, lights, world: what casts, occludes and emits) and the index of
    the baked object's instance; the export's warnings reach the user."""
    from .export import scene as scene_export
    exported = scene_export.export_scene(depsgraph, require_camera=False)
    for warning in exported.warnings:
        engine.report({'WARNING'}, f"Ember: {warning}")
    scene = exported.scene
    index = next((i for i, inst in enumerate(scene.instances) if inst.name == obj.name), None)
    if index is None:
        raise BakeError(f"object '{obj.name}' is not rendered in this view layer: nothing to bake")
    return scene, index
