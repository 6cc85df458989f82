"""Evaluated Blender geometry -> engine.scene.Mesh.

Everything is read with ``foreach_get`` into preallocated NumPy arrays: a
Python loop over vertices would cost seconds on a million triangles.
"""
import numpy as np

# Object types whose evaluated geometry ``to_mesh`` can triangulate.
MESHABLE_TYPES = {'MESH', 'CURVE', 'SURFACE', 'FONT', 'META'}


def _get(collection, attribute, count, width, dtype):
    """``collection.foreach_get`` into a new (count, width) array."""
    flat = np.empty(count * width, dtype=dtype)
    if count:
        collection.foreach_get(attribute, flat)
    return flat.reshape(count, width) if width > 1 else flat


def _has_smooth_faces(mesh):
    """True if any face is shaded smooth (then per-corner normals matter)."""
    count = len(mesh.polygons)
    if count == 0:
        return False
    smooth = np.empty(count, dtype=bool)
    mesh.polygons.foreach_get('use_smooth', smooth)
    return bool(smooth.any())


def _has_custom_normals(mesh):
    return bool(getattr(mesh, 'has_custom_normals', False))


def _corner_normals(mesh, tri_count):
    """Per-corner shading normals, (T, 3, 3), or None when every face is flat.

    Split normals cover flat, smooth, auto-smooth and custom normals at once.
    Before 4.1 they must be computed explicitly; 4.1 computes them on demand.
    """
    if not (_has_smooth_faces(mesh) or _has_custom_normals(mesh)):
        return None
    if hasattr(mesh, 'calc_normals_split'):
        mesh.calc_normals_split()
    normals = _get(mesh.loop_triangles, 'split_normals', tri_count, 9, np.float32)
    return normals.reshape(tri_count, 3, 3)


def _corner_uvs(mesh, loops):
    """Per-corner UVs of the active UV map, (T, 3, 2), or None."""
    layer = mesh.uv_layers.active
    if layer is None:
        return None
    uv = _get(layer.data, 'uv', len(mesh.loops), 2, np.float32)
    return uv[loops]


def mesh_from_blender(mesh, name):
    """Copy a triangulated Blender mesh into an engine Mesh.

    Returns None for geometry without triangles (empty meshes, edges, points),
    which the renderer cannot hit anyway.
    """
    mesh.calc_loop_triangles()
    tri_count = len(mesh.loop_triangles)
    if tri_count == 0:
        return None
    scene = _scene_module()
    positions = _get(mesh.vertices, 'co', len(mesh.vertices), 3, np.float32)
    triangles = _get(mesh.loop_triangles, 'vertices', tri_count, 3, np.int32)
    loops = _get(mesh.loop_triangles, 'loops', tri_count, 3, np.int32)
    slots = _get(mesh.loop_triangles, 'material_index', tri_count, 1, np.int32)
    return scene.Mesh(
        positions=positions,
        triangles=triangles,
        normals=_corner_normals(mesh, tri_count),
        uvs=_corner_uvs(mesh, loops),
        material_slots=slots if slots.any() else None,
        name=name,
    )


def mesh_from_object(obj, name):
    """Export an evaluated object's geometry (modifiers applied).

    ``to_mesh`` on an evaluated object returns the final geometry for meshes,
    curves, text and metaballs; the temporary mesh is freed right after copy.
    """
    if obj.type == 'MESH':
        # The evaluated mesh already has the modifiers applied: no copy needed.
        return mesh_from_blender(obj.data, name)
    mesh = obj.to_mesh()
    try:
        if mesh is None:
            return None
        return mesh_from_blender(mesh, name)
    finally:
        obj.to_mesh_clear()


def _scene_module():
    from .. import backend
    return backend.scene_module()
