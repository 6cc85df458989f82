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
    # The same triangles as shared vertices for Embree: (V, 3) world-space
    # vertices and (T, 3) indices into them (p0 = vertices[indices[:, 0]]),
    # or None (then Embree gets the corners).
    vertices: Optional[np.ndarray] = None
    indices: Optional[np.ndarray] = None
    # Which of flatten's triangles were kept (bool mask), None when all were.
    kept: Optional[np.ndarray] = None

    def __len__(self):
        return len(self.p0)

    def indexed_float32(self):
        """(V, 3) float32 vertices and (T, 3) int32 indices for Embree, or
        None when the triangles carry no shared vertices."""
        if self.vertices is None or self.indices is None:
            return None
        return (np.ascontiguousarray(self.vertices, dtype=np.float32),
                np.ascontiguousarray(self.indices, dtype=np.int32))

    def corners_float32(self):
        """(T, 3, 3) float32 vertex positions for Embree."""
        v = np.empty((len(self.p0), 3, 3), dtype=np.float32)
        v[:, 0] = self.p0
        v[:, 1] = self.p0 + self.e1
        v[:, 2] = self.p0 + self.e2
        return v


def _mesh_arrays(mesh):
    """Per-mesh arrays every instance of it shares, converted once."""
    slots = (None if mesh.material_slots is None
             else np.asarray(mesh.material_slots, dtype=np.int64))
    normals = None if mesh.normals is None else np.asarray(mesh.normals, dtype=np.float64)
    uv = None if mesh.uvs is None else np.asarray(mesh.uvs, dtype=np.float64)
    return (np.asarray(mesh.positions, dtype=np.float64),
            np.asarray(mesh.triangles, dtype=np.int64), normals, uv, slots)


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
            mesh_cache[inst.mesh] = _mesh_arrays(mesh)
        part = _instance_part(mesh_cache[inst.mesh], inst, n_mat)
        parts.append(part)
        owners.append(np.full(part.count, index, np.int32))
    tris = _concat(parts)
    if owners and with_instance:
        tris.instance = _take_kept(np.concatenate(owners), tris.kept)
    tris.shading = _scene_shading(scene, owners, tris)
    if _needs_tangents(scene):
        _add_tangents(tris, scene, parts)
    return tris


@dataclass
class _Part:
    """One instance's triangles: its world-space vertices and the mesh's
    vertex indices (shared by every instance of the mesh)."""
    vertices: np.ndarray       # (V, 3) float64, world space
    triangles: np.ndarray      # (T, 3) int64 into vertices
    ns: Optional[np.ndarray]   # (T, 3, 3) world-space corner normals
    uv: Optional[np.ndarray]
    material: np.ndarray
    visibility: int

    @property
    def count(self):
        return len(self.triangles)


def _instance_part(arrays, inst, n_mat):
    positions, triangles, normals, uv, slots = arrays
    m = np.asarray(inst.matrix, dtype=np.float64)
    lin, off = m[:3, :3], m[:3, 3]
    # Vertices, not corners: a third of the work, and (V, 3) @ (3, 3) is one
    # BLAS call where a (T, 3, 3) stack is one per triangle.  Same values.
    world = positions @ lin.T + off
    table = _slot_table(inst, n_mat)
    if slots is None:
        material = np.full(len(triangles), table[0], np.int32)
    else:
        material = table[np.minimum(slots, len(table) - 1)]
    ns = None
    if normals is not None:
        # Normals transform with the inverse transpose; a mirroring matrix
        # flips the winding, which the cross product in _concat sees too.
        nmat = np.linalg.inv(lin).T if abs(np.linalg.det(lin)) > 0 else lin
        ns = (normals.reshape(-1, 3) @ nmat.T).reshape(normals.shape)
    return _Part(world, triangles, ns, uv, material, visibility_bits(inst))


def _scene_shading(scene, owners, tris):
    """SceneShading (shader-node data) for the triangles _concat kept."""
    from .nodes import SceneShading
    if not owners:
        return SceneShading(scene, np.zeros(0, np.int64), np.zeros(0, np.int64))
    instance = np.concatenate(owners).astype(np.int64)
    local = np.concatenate([np.arange(len(o)) for o in owners])
    return SceneShading(scene, _take_kept(instance, tris.kept), _take_kept(local, tris.kept))


def _take_kept(array, keep):
    """array[keep], without the copy when every triangle was kept."""
    return array if keep is None else array[keep]


def _row_norm(v):
    """Euclidean length over the last axis; the same sums, in the same order,
    as np.linalg.norm, without its temporaries."""
    s = v * v
    return np.sqrt(s[..., 0] + s[..., 1] + s[..., 2])


def _stack_vertices(parts):
    """All instances' vertices in one (V, 3) array and every triangle's
    indices into it, (T, 3) int64."""
    vertices = np.concatenate([p.vertices for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    indices = np.concatenate([p.triangles + o for p, o in zip(parts, offsets)])
    return vertices, indices


def _concat(parts):
    if not parts:
        empty3 = np.zeros((0, 3))
        tris = Triangles(empty3, empty3, empty3, empty3, None, np.zeros(0, bool), None,
                         np.zeros(0, np.int32), np.zeros(0))
        return tris
    vertices, indices = _stack_vertices(parts)
    any_ns = any(p.ns is not None for p in parts)
    any_uv = any(p.uv is not None for p in parts)
    n_each = [p.count for p in parts]
    smooth = np.concatenate([np.full(p.count, p.ns is not None) for p in parts])
    ns = _stack_optional([p.ns for p in parts], n_each, (3, 3)) if any_ns else None
    uv = _stack_optional([p.uv for p in parts], n_each, (3, 2)) if any_uv else None
    material = np.concatenate([p.material for p in parts]).astype(np.int32)
    visibility = None
    if any(p.visibility != VIS_ALL for p in parts):
        visibility = np.concatenate([np.full(p.count, p.visibility, np.uint8) for p in parts])

    p0 = vertices[indices[:, 0]]
    e1 = vertices[indices[:, 1]] - p0
    e2 = vertices[indices[:, 2]] - p0
    c = np.cross(e1, e2)
    clen = _row_norm(c)
    keep = np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)
    dropped = int(len(keep) - np.count_nonzero(keep))
    keep = None if dropped == 0 else keep
    clen, c = _take_kept(clen, keep), _take_kept(c, keep)
    ng = c / clen[:, None]
    smooth = _take_kept(smooth, keep)
    if ns is not None:
        ns = _fix_normals(_take_kept(ns, keep), ng, smooth)
    tris = Triangles(_take_kept(p0, keep), _take_kept(e1, keep), _take_kept(e2, keep), ng, ns, smooth,
                     None if uv is None else _take_kept(uv, keep), _take_kept(material, keep),
                     0.5 * clen, dropped,
                     visibility=None if visibility is None else _take_kept(visibility, keep))
    tris.vertices, tris.indices, tris.kept = vertices, _take_kept(indices, keep), keep
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
    length = _row_norm(ns)
    bad = ~np.isfinite(length) | (length < 1e-12)
    if bad.any():
        ns = np.where(bad[..., None], ng[:, None, :], ns / np.where(bad, 1.0, length)[..., None])
    else:
        ns = ns / length[..., None]
    # Flat triangles in a partly smooth scene carry the face normal.
    if not smooth.all():
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
    n_each = [p.count for p in parts]
    t = _stack_optional(tangent, n_each, (3, 3))
    s = _stack_optional(sign, n_each, (3,))
    have = np.concatenate([np.full(n, x is not None) for n, x in zip(n_each, tangent)])
    t, s, have = _take_kept(t, tris.kept), _take_kept(s, tris.kept), _take_kept(have, tris.kept)
    ut, us = uv_tangents(tris)
    t[~have] = ut[~have, None, :]
    s[~have] = us[~have, None]
    tris.tangent, tris.tangent_sign = t, np.where(s < 0, -1.0, 1.0)


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
