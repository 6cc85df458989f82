"""Flattening instances into one world-space triangle soup.

embreex has no instancing, so every instance's triangles are transformed into
world space.  Per-mesh work (corner gathering, slot lookup, validity) is done
once per mesh; per instance only the matrix multiply remains.
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .scene import DEFAULT_MATERIAL, Bump, NormalMap
from .vec import frame

# Ray visibility bits (Blender's Object > Visibility > Ray Visibility).
VIS_CAMERA, VIS_DIFFUSE, VIS_GLOSSY, VIS_TRANSMISSION, VIS_SHADOW = 1, 2, 4, 8, 16
VIS_ALL = 31


def visibility_bits(item):
    """The VIS_* bits of an Instance or a light (missing fields: visible)."""
    bits = 0
    for bit, name in ((VIS_CAMERA, "visible_camera"), (VIS_DIFFUSE, "visible_diffuse"),
                      (VIS_GLOSSY, "visible_glossy"), (VIS_TRANSMISSION, "visible_transmission"),
                      (VIS_SHADOW, "visible_shadow")):
        if getattr(item, name, True):
            bits |= bit
    return bits


@dataclass
class Triangles:
    """World-space triangles; index = Embree primID.

    p0, e1, e2: (T, 3) float64 vertex 0 and the two edges (p1 - p0, p2 - p0)
    ng: (T, 3) unit geometric normals (right-handed winding)
    ns: (T, 3, 3) per-corner unit shading normals, or None (all flat)
    smooth: (T,) bool, whether ns is meaningful for this triangle
    uv: (T, 3, 2) or None
    material: (T,) int32 index into the compiled material table
    area: (T,)
    visibility: (T,) uint8 VIS_* bits of the triangle's instance, or None
        when every triangle is visible to every ray (the common case)
    """
    p0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    ng: np.ndarray
    ns: Optional[np.ndarray]
    smooth: np.ndarray
    uv: Optional[np.ndarray]
    material: np.ndarray
    area: np.ndarray
    dropped: int = 0
    visibility: Optional[np.ndarray] = None
    # World-space per-corner tangents (T, 3, 3) and bitangent signs (T, 3)
    # for normal maps, or None when no material has one.
    tangent: Optional[np.ndarray] = None
    tangent_sign: Optional[np.ndarray] = None
    # Shader-node data (engine.nodes.SceneShading): each triangle's instance
    # and its index in its mesh, object matrices and info, corner attributes.
    shading: object = None
    # (T,) int32 index of the triangle's scene instance (for passes).
    instance: Optional[np.ndarray] = None

    def __len__(self):
        return len(self.p0)

    def corners_float32(self):
        """(T, 3, 3) float32 vertex positions for Embree."""
        v = np.empty((len(self.p0), 3, 3), dtype=np.float32)
        v[:, 0] = self.p0
        v[:, 1] = self.p0 + self.e1
        v[:, 2] = self.p0 + self.e2
        return v


def _mesh_corners(mesh):
    pos = np.asarray(mesh.positions, dtype=np.float64)
    tris = np.asarray(mesh.triangles, dtype=np.int64)
    return pos[tris]  # (T, 3, 3)


def _slot_table(inst, n_materials):
    """Map material slot -> compiled material id; the last id is the default."""
    default = n_materials  # compiled table appends DEFAULT_MATERIAL
    ids = [m if 0 <= m < n_materials else default for m in inst.materials]
    return np.array(ids + [default], dtype=np.int32)


def flatten(scene, with_instance=False):
    """Build Triangles for every instance; degenerate triangles are dropped.
    with_instance: also record each triangle's instance index (passes)."""
    n_mat = len(scene.materials)
    mesh_cache = {}
    parts = []
    owners = []   # per part: its instance index for each triangle
    for index, inst in enumerate(scene.instances):
        mesh = scene.meshes[inst.mesh]
        if len(mesh.triangles) == 0:
            continue
        if inst.mesh not in mesh_cache:
            mesh_cache[inst.mesh] = _mesh_corners(mesh)
        corners = mesh_cache[inst.mesh]
        parts.append(_instance_part(mesh, corners, inst, n_mat))
        owners.append(np.full(len(corners), index, np.int32))
    tris = _concat(parts)
    if owners and with_instance:
        tris.instance = np.concatenate(owners)[tris.kept]
    tris.shading = _scene_shading(scene, owners, tris)
    if _needs_tangents(scene):
        _add_tangents(tris, scene, parts)
    return tris


def _instance_part(mesh, corners, inst, n_mat):
    m = np.asarray(inst.matrix, dtype=np.float64)
    lin, off = m[:3, :3], m[:3, 3]
    world = corners @ lin.T + off
    slots = (np.zeros(len(corners), np.int64) if mesh.material_slots is None
             else np.asarray(mesh.material_slots, dtype=np.int64))
    table = _slot_table(inst, n_mat)
    material = table[np.minimum(slots, len(table) - 1)]
    ns = None
    if mesh.normals is not None:
        # Normals transform with the inverse transpose; a mirroring matrix
        # flips the winding, which the cross product in _concat sees too.
        nmat = np.linalg.inv(lin).T if abs(np.linalg.det(lin)) > 0 else lin
        ns = np.asarray(mesh.normals, dtype=np.float64) @ nmat.T
    uv = None if mesh.uvs is None else np.asarray(mesh.uvs, dtype=np.float64)
    return world, ns, uv, material, visibility_bits(inst)


def _scene_shading(scene, owners, tris):
    """SceneShading (shader-node data) for the triangles _concat kept."""
    from .nodes import SceneShading
    if not owners:
        return SceneShading(scene, np.zeros(0, np.int64), np.zeros(0, np.int64))
    instance = np.concatenate(owners).astype(np.int64)
    local = np.concatenate([np.arange(len(o)) for o in owners])
    return SceneShading(scene, instance[tris.kept], local[tris.kept])


def _concat(parts):
    if not parts:
        empty3 = np.zeros((0, 3))
        return Triangles(empty3, empty3, empty3, empty3, None, np.zeros(0, bool), None,
                         np.zeros(0, np.int32), np.zeros(0))
    world = np.concatenate([p[0] for p in parts])
    any_ns = any(p[1] is not None for p in parts)
    any_uv = any(p[2] is not None for p in parts)
    n_each = [len(p[0]) for p in parts]
    smooth = np.concatenate([np.full(n, p[1] is not None) for n, p in zip(n_each, parts)])
    ns = _stack_optional([p[1] for p in parts], n_each, (3, 3)) if any_ns else None
    uv = _stack_optional([p[2] for p in parts], n_each, (3, 2)) if any_uv else None
    material = np.concatenate([p[3] for p in parts]).astype(np.int32)
    visibility = None
    if any(p[4] != VIS_ALL for p in parts):
        visibility = np.concatenate([np.full(n, p[4], np.uint8) for n, p in zip(n_each, parts)])

    p0 = world[:, 0]
    e1 = world[:, 1] - p0
    e2 = world[:, 2] - p0
    c = np.cross(e1, e2)
    clen = np.linalg.norm(c, axis=1)
    keep = np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)
    dropped = int(len(keep) - keep.sum())
    ng = c[keep] / clen[keep, None]
    if ns is not None:
        ns = _fix_normals(ns[keep], ng, smooth[keep])
    tris = Triangles(p0[keep], e1[keep], e2[keep], ng, ns, smooth[keep],
                     None if uv is None else uv[keep], material[keep],
                     0.5 * clen[keep], dropped,
                     visibility=None if visibility is None else visibility[keep])
    tris.kept = keep
    return tris


def _stack_optional(arrays, counts, tail):
    out = np.zeros((sum(counts),) + tail)
    start = 0
    for a, n in zip(arrays, counts):
        if a is not None:
            out[start:start + n] = a
        start += n
    return out


def _fix_normals(ns, ng, smooth):
    """Unit shading normals; zero or NaN ones fall back to the face normal."""
    length = np.linalg.norm(ns, axis=2)
    bad = ~np.isfinite(length) | (length < 1e-12)
    ns = np.where(bad[..., None], ng[:, None, :], ns / np.where(bad, 1.0, length)[..., None])
    # Flat triangles in a partly smooth scene carry the face normal.
    ns[~smooth] = ng[~smooth, None, :]
    return ns


def material_table(scene):
    """The scene's materials plus the default material at the end."""
    return list(scene.materials) + [DEFAULT_MATERIAL]


# ----------------------------------------------------------------------------
# Tangents for normal maps

def _needs_tangents(scene):
    def has_map(normal):
        return isinstance(normal, NormalMap) or (isinstance(normal, Bump) and has_map(normal.normal))
    return any(has_map(getattr(m, "normal", None)) for m in scene.materials)


def _add_tangents(tris, scene, parts):
    """World-space corner tangents: the mesh's own (MikkTSpace from Blender)
    where it has them, else each triangle's UV tangent dP/du.  Kept
    triangles only, in Triangles order."""
    if tris.uv is None or len(tris) == 0:
        return
    tangent, sign = [], []
    for inst in scene.instances:
        mesh = scene.meshes[inst.mesh]
        if len(mesh.triangles) == 0:
            continue
        lin = np.asarray(inst.matrix, dtype=np.float64)[:3, :3]
        if mesh.tangents is not None and mesh.tangent_signs is not None:
            # A mirroring matrix flips the bitangent relative to n x t.
            flip = -1.0 if np.linalg.det(lin) < 0 else 1.0
            tangent.append(np.asarray(mesh.tangents, dtype=np.float64) @ lin.T)
            sign.append(np.asarray(mesh.tangent_signs, dtype=np.float64) * flip)
        else:
            tangent.append(None)
            sign.append(None)
    n_each = [len(p[0]) for p in parts]
    t = _stack_optional(tangent, n_each, (3, 3))
    s = _stack_optional(sign, n_each, (3,))
    have = np.concatenate([np.full(n, x is not None) for n, x in zip(n_each, tangent)])
    keep = _kept(parts)
    t, s, have = t[keep], s[keep], have[keep]
    ut, us = uv_tangents(tris)
    t[~have] = ut[~have, None, :]
    s[~have] = us[~have, None]
    tris.tangent, tris.tangent_sign = t, np.where(s < 0, -1.0, 1.0)


def _kept(parts):
    """The triangles _concat kept (it drops degenerate ones)."""
    world = np.concatenate([p[0] for p in parts])
    p0 = world[:, 0]
    c = np.cross(world[:, 1] - p0, world[:, 2] - p0)
    clen = np.linalg.norm(c, axis=1)
    return np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)


def uv_tangents(tris):
    """Per-triangle unit dP/du (world space) and the sign that makes
    sign * cross(ng, tangent) point along dP/dv; a frame tangent where the
    UVs are degenerate."""
    c = tris.uv
    d1, d2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (tris.e1 * d2[:, 1:2] - tris.e2 * d1[:, 1:2]) * inv
    dpdv = (tris.e2 * d1[:, 0:1] - tris.e1 * d2[:, 0:1]) * inv
    dpdu -= np.einsum("ij,ij->i", dpdu, tris.ng)[:, None] * tris.ng
    length = np.linalg.norm(dpdu, axis=1)
    ok &= np.isfinite(length) & (length > 1e-20)
    fallback = frame(tris.ng)[0]
    t = np.where(ok[:, None], dpdu / np.where(ok, length, 1.0)[:, None], fallback)
    sign = np.where(np.einsum("ij,ij->i", np.cross(tris.ng, t), dpdv) < 0, -1.0, 1.0)
    return t, sign
