"""True displacement (Cycles' "Displacement Only" and "Displacement and
Bump" material methods, without adaptive subdivision), applied to the
meshes before the triangles are flattened and the BVH is built.

As Cycles' scene/mesh_displace.cpp: the displacement is evaluated once per
vertex, at the corner of the first triangle (in triangle order) that uses
the vertex and whose material displaces, with that triangle's corner
attributes (UV, Generated, the corner's normal: the smooth normal, or the
face normal on a flat face) and the first object that uses the mesh (Cycles
calls the choice arbitrary).  The vertex moves by the displacement vector
in object space; non-finite offsets move nothing (Cycles' ensure_finite).
With "Displacement Only" the vertex normals of the displaced triangles are
recomputed: each the normalized sum of the unit face normals around it
(flat faces keep their face normal); with "Both" the normals stay the
undisplaced ones and the material's bump (the same height) bends them.

A displaced mesh is shared by every instance of the same mesh whose slots
name the same displacing materials.
"""
import dataclasses

import numpy as np

from . import instance_columns
from .geometry import flatten
from .nodes.context import ShadingContext, texture_space, _is_position_texspace
from .scene import SceneError
from .textures import Compiler

# Past this an object-space coordinate loses every bit of a float32 BVH's
# precision; a displacement moving a vertex there is named, not rendered.
LIMIT = 1e15   # well inside validate.MAX_MAGNITUDE
# Barycentrics (u, v) of a triangle's corners 0, 1, 2 (p0 + u e1 + v e2).
CORNER_BARY = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


def displaced_scene(scene):
    """The scene with its displacing meshes displaced (the scene itself when
    no material displaces).  Instances of one mesh with one material set
    share its displaced copy; where instances give a mesh different sets,
    each displacing set gets its own copy."""
    mats = scene.materials
    if not any(getattr(m, "displacement", None) is not None for m in mats):
        return scene
    cols = instance_columns.columns(scene.instances)
    n_mesh = len(scene.meshes)
    mesh = np.asarray(cols.mesh, np.int64)
    pairs, first, which = np.unique(np.stack([mesh, np.asarray(cols.slot_set, np.int64)], axis=1), axis=0,
                                    return_index=True, return_inverse=True)
    which = np.asarray(which).reshape(-1)
    meshes, remap = list(scene.meshes), {}
    for g, ((m, _), i) in enumerate(zip(pairs, first)):
        if not 0 <= m < n_mesh:
            continue
        inst = scene.instances[int(i)]
        slots = _slot_materials(scene.meshes[m], inst, mats)
        if slots is None:
            continue
        shared = (pairs[:, 0] == m).sum() == 1 or not isinstance(scene.instances, (list, tuple))
        if shared:
            meshes[m] = displace_mesh(scene, int(m), inst, slots)
        else:
            remap[g] = len(meshes)
            meshes.append(displace_mesh(scene, int(m), inst, slots))
    instances = scene.instances
    if remap:
        instances = [dataclasses.replace(inst, mesh=remap[int(g)]) if int(g) in remap else inst
                     for inst, g in zip(scene.instances, which)]
    return dataclasses.replace(scene, meshes=meshes, instances=instances)


def _slot_materials(mesh, inst, mats):
    """The scene material index of each slot the mesh's triangles use (-1:
    the default material), or None when none of them displaces."""
    used = (np.unique(np.asarray(mesh.material_slots)) if mesh.material_slots is not None
            else np.zeros(1, np.int64))
    if not len(mesh.triangles):
        return None
    top = int(used.max()) + 1
    table = [int(inst.materials[s]) if s < len(inst.materials) else -1 for s in range(top)]
    if any(0 <= t < len(mats) and getattr(mats[t], "displacement", None) is not None for t in table):
        return table
    return None


def displace_mesh(scene, m, inst, slots):
    """A copy of mesh m displaced by the materials ``slots`` (scene index per
    slot) give it, evaluated with instance ``inst``."""
    mesh = scene.meshes[m]
    mats = scene.materials
    tri = np.asarray(mesh.triangles, np.int64)
    slot = (np.asarray(mesh.material_slots, np.int64) if mesh.material_slots is not None
            else np.zeros(len(tri), np.int64))
    mat_of_tri = np.asarray(slots, np.int64)[np.minimum(slot, len(slots) - 1)]
    disp = [getattr(mats[k], "displacement", None) if 0 <= k < len(mats) else None for k in range(len(mats))]
    displacing = np.array([d is not None for d in disp] + [False])[mat_of_tri]   # -1 reads the False
    pos = np.asarray(mesh.positions, np.float64)
    offsets = _vertex_offsets(scene, mesh, inst, tri, mat_of_tri, displacing, disp)
    moved = pos + offsets
    if not np.isfinite(moved).all() or np.abs(moved).max(initial=0.0) > LIMIT:
        names = sorted({mats[k].name for k in np.unique(mat_of_tri[displacing])})
        raise SceneError(f"mesh {mesh.name!r}: the displacement of material {', '.join(map(repr, names))} "
                         f"moves vertices beyond {LIMIT:g} (object space); lower its scale")
    true_disp = np.array([d is not None and d.method == "DISPLACEMENT" for d in disp] + [False])[mat_of_tri]
    out = dataclasses.replace(mesh, positions=moved.astype(np.asarray(mesh.positions).dtype, copy=False),
                              **_kept_generated(mesh, pos, tri))
    both = np.array([d is not None and d.method == "BOTH" for d in disp] + [False])[mat_of_tri]
    if both.any():
        out.undisplaced = pos     # the bump of "Both" differentiates on the undisplaced surface
    if mesh.normals is not None and true_disp.any():
        out.normals = _recomputed_normals(mesh.normals, moved, tri, true_disp, _smooth(mesh))
    if mesh.motion is not None:
        out.motion = np.asarray(mesh.motion) + offsets
        if mesh.motion_normals is not None and true_disp.any():
            out.motion_normals = np.stack([_recomputed_normals(n, p, tri, true_disp, _smooth(mesh))
                                           for n, p in zip(mesh.motion_normals, out.motion)])
    if getattr(mesh, "vector_motion", None) is not None:
        out.vector_motion = np.asarray(mesh.vector_motion) + offsets
    return out


def _kept_generated(mesh, pos, tri):
    """Generated coordinates stay the undisplaced ones (Blender's orco and
    automatic texture space are of the mesh before displacement)."""
    if _is_position_texspace(mesh):
        return {}
    changes = {}
    if mesh.orco is None:
        changes["orco"] = pos[tri]
    if mesh.texspace is None:
        loc, factor = texture_space(mesh)
        size = np.where(factor != 0.0, 0.5 / np.where(factor != 0.0, factor, 1.0), 0.0)
        changes["texspace"] = (tuple(loc), tuple(size))
    return changes


def _first_corners(tri, displacing):
    """(vertex, triangle, corner) of each displaced vertex's first corner in
    triangle order among the displacing triangles."""
    rows = np.flatnonzero(displacing)
    flat = tri[rows].reshape(-1)
    verts, first = np.unique(flat, return_index=True)
    return verts, rows[first // 3], first % 3


def _vertex_offsets(scene, mesh, inst, tri, mat_of_tri, displacing, disp):
    """(V, 3) object-space offset of every vertex (0 where nothing displaces)."""
    offsets = np.zeros((len(mesh.positions), 3))
    if not displacing.any():
        return offsets
    verts, t, corner = _first_corners(tri, displacing)
    tris = _single_instance_triangles(scene, mesh, inst)
    keep = np.ones(len(tri), bool) if tris.kept is None else np.asarray(tris.kept, bool)
    row_of = np.cumsum(keep) - 1          # row of each kept local triangle
    kept = keep[t]
    verts, t, corner = verts[kept], t[kept], corner[kept]   # a degenerate triangle has no corner to shade
    normals = _corner_normals(mesh, tri, t, corner)
    matrix = np.asarray(inst.matrix, np.float64)
    compiler = Compiler()
    for k in np.unique(mat_of_tri[t]):
        d = disp[k]
        rows = np.flatnonzero(mat_of_tri[t] == k)
        bary = CORNER_BARY[corner[rows]]
        ctx = ShadingContext.at(tris, row_of[t[rows]], bary[:, 0], bary[:, 1])
        height = np.asarray(compiler.compile(d.height)[0](ctx), np.float64).reshape(-1)
        offsets[verts[rows]] = _offset(height, normals[rows], d.space, matrix)
    bad = ~np.isfinite(offsets)
    offsets[bad] = 0.0     # Cycles' ensure_finite: a NaN or infinite component moves nothing
    return offsets


def _single_instance_triangles(scene, mesh, inst):
    """The mesh's triangles placed by ``inst`` alone (kept: local triangles
    that are not degenerate), with the shading data nodes read."""
    one = dataclasses.replace(scene, meshes=[mesh], instances=[dataclasses.replace(inst, mesh=0)])
    with instance_columns.prepared():
        tris = flatten(one, threads=1)
    return tris


def _corner_normals(mesh, tri, t, corner):
    """Unit object-space normals at the corners: the mesh's corner normal
    (the face normal on flat faces), or the face normal without any."""
    pos = np.asarray(mesh.positions, np.float64)
    p = pos[tri[t]]
    face = _unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), np.array([1.0, 0.0, 0.0]))
    if mesh.normals is None:
        return face
    n = np.asarray(mesh.normals, np.float64)[t, corner]
    return _unit(n, face)


def _offset(height, normal, space, matrix):
    """Object-space offset of a Displacement node: height along the unit
    object-space normal (Object space), or along the world normal brought
    back to object space (World space: Cycles moves in world space and
    transforms the offset back with the object's inverse)."""
    if space == "OBJECT":
        return height[:, None] * normal
    m = matrix[:3, :3]
    try:
        inv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        return np.zeros_like(normal)
    world = _unit(normal @ inv, normal)   # inverse transpose: n_world = M^-T n
    return (height[:, None] * world) @ inv.T


def _smooth(mesh):
    """(T,) whether each triangle is shaded smooth (the exporter's
    ``Mesh.smooth``; without it every face with corner normals is)."""
    smooth = getattr(mesh, "smooth", None)
    return np.ones(len(mesh.triangles), bool) if smooth is None else np.asarray(smooth, bool)


def _recomputed_normals(normals, pos, tri, true_disp, smooth):
    """Corner normals with the smooth corners of "Displacement Only"
    triangles replaced by the displaced mesh's vertex normals (the
    normalized sum of the unit face normals of those triangles around each
    vertex, as Cycles); flat triangles get their new face normal."""
    dtype = np.asarray(normals).dtype
    normals = np.array(normals, dtype=np.float64)
    p = pos[tri]
    face = _unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), np.array([1.0, 0.0, 0.0]))
    rows = np.flatnonzero(true_disp)
    vn = np.zeros((len(pos), 3))
    for j in range(3):
        np.add.at(vn, tri[rows, j], face[rows])
    vn = _unit(vn, np.array([0.0, 0.0, 1.0]))
    new = vn[tri[rows]]
    flat = ~smooth[rows]
    new[flat] = face[rows][flat][:, None, :]
    normals[rows] = new
    return normals.astype(dtype, copy=False)


def _unit(v, fallback):
    with np.errstate(all="ignore"):
        length = np.linalg.norm(v, axis=-1, keepdims=True)
        out = v / length
    good = np.isfinite(out).all(axis=-1, keepdims=True) & (length > 0)
    return np.where(good, out, fallback)
