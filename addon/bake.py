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


class BakeError(Exception):
    """A bake Ember cannot do; the message is meant for the user."""


def bake(engine, depsgraph, obj, pass_type, pass_filter, width, height):
    try:
        _bake(engine, depsgraph, obj, pass_type, width, height)
    except BakeError as err:
        engine.report({'ERROR'}, f"Ember: {err}")
    except Exception as err:  # noqa: BLE001 - every failure must reach the user
        import traceback
        traceback.print_exc()
        engine.report({'ERROR'}, f"Ember: bake failed: {type(err).__name__}: {err}")


def _bake(engine, depsgraph, obj, pass_type, width, height):
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
    mesh = mesh_export.mesh_from_object(evaluated, name)
    if mesh is None:
        raise BakeError(f"object '{name}' has no triangles to bake")
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
        primitive_pass.rect.foreach_get(flat)
        prim, u, v = renderer.bake.unpack_primitives(flat.reshape(-1, channels))
        if pass_type == 'AO':
            scene, index = _whole_scene(renderer, depsgraph, evaluated, engine)
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


def _whole_scene(renderer, depsgraph, obj, engine):
    """Every mesh instance of the depsgraph as an engine Scene (the
    occluders of an AO bake) and the index of the baked object's instance."""
    from .export import instances as instance_export
    override = getattr(depsgraph.view_layer, 'material_override', None)
    materials = material_export.MaterialTable(override)
    meshes, instances, warnings = instance_export.collect_instances(depsgraph, materials.slots)
    index = next((i for i, inst in enumerate(instances) if inst.name == obj.name), None)
    if index is None:
        raise BakeError(f"object '{obj.name}' is not rendered in this view layer: nothing to bake")
    for warning in materials.warnings + warnings:
        engine.report({'WARNING'}, f"Ember: {warning}")
    return renderer.Scene(meshes=meshes, instances=instances, materials=materials.materials,
                          cycles_version=tuple(bpy.app.version)), index
