"""Flattening instances into one list of world-space triangles.

embreex has no instancing, so every instance's vertices are transformed into
world space; the triangles keep the mesh's vertex indices (offset per
instance), which Embree takes as they are.  Per-mesh conversions are done
once per mesh; each instance's rows are computed in its own slice of the
output, so temporaries stay the size of one instance.
"""
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import instance_columns, kernels
from .nodes import SceneShading
from .scene import DEFAULT_MATERIAL, Bump, NormalMap
from .vec import frame

# Ray visibility bits (Blender's Object > Visibility > Ray Visibility).
VIS_CAMERA, VIS_DIFFUSE, VIS_GLOSSY, VIS_TRANSMISSION, VIS_SHADOW = 1, 2, 4, 8, 16
VIS_ALL = 31
# Not an object visibility bit: set on paths.ray beside VIS_INDIRECT for rays a
# volume scattered (Cycles' PATH_RAY_VOLUME_SCATTER, the Light Path node's
# Is Volume Scatter Ray); visibility tests AND with VIS_ALL bits, so it changes none.
VIS_VOLUME = 32


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


def _slot_table(materials, n_materials):
    """Map material slot -> compiled material id; the last id is the default."""
    default = n_materials  # compiled table appends DEFAULT_MATERIAL
    ids = [m if 0 <= m < n_materials else default for m in materials]
    return np.array(ids + [default], dtype=np.int32)


def flatten(scene, with_instance=False, threads=0):
    """Build Triangles for every instance; degenerate triangles are dropped.
    with_instance: also record each triangle's instance index (passes);
    threads: at most this many for a big scene (0: every core)."""
    cols = instance_columns.columns(scene.instances)
    sizes = np.array([len(mesh.triangles) for mesh in scene.meshes] + [0], np.int64)
    placed = np.flatnonzero(sizes[cols.mesh] > 0)   # the instances with triangles, in order
    arrays = {int(k): _MeshArrays.of(scene.meshes[k]) for k in np.unique(cols.mesh[placed])}
    tris = _place(cols, placed, arrays, len(scene.materials), threads)
    counts = sizes[cols.mesh[placed]]
    owner = np.repeat(placed.astype(np.int64), counts)
    first_row = np.cumsum(counts) - counts
    local = np.arange(len(owner)) - np.repeat(first_row, counts)   # triangle index in its mesh
    if len(placed) and with_instance:
        tris.instance = _take_kept(owner.astype(np.int32), tris.kept)
    tris.shading = _scene_shading(scene, _take_kept(owner, tris.kept), _take_kept(local, tris.kept))
    if _needs_tangents(scene):
        _add_tangents(tris, scene, counts)
    return tris


@dataclass
class _MeshArrays:
    """A mesh's arrays as float64 / int64, converted once for all its instances."""
    positions: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray]
    uv: Optional[np.ndarray]
    slots: Optional[np.ndarray]

    @classmethod
    def of(cls, mesh):
        def optional(a, dtype):
            return None if a is None else np.asarray(a, dtype=dtype)
        return cls(np.asarray(mesh.positions, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64),
                   optional(mesh.normals, np.float64), optional(mesh.uvs, np.float64),
                   optional(mesh.material_slots, np.int64))

    @property
    def count(self):
        return len(self.triangles)


class _Out:
    """flatten's output arrays, rows in instance order."""

    def __init__(self, total, vertices, used):
        self.vertices = np.empty((vertices, 3))
        self.indices = np.empty((total, 3), np.int64)
        self.p0, self.e1, self.e2, self.ng = (np.empty((total, 3)) for _ in range(4))
        self.clen = np.empty(total)
        self.ns = np.empty((total, 3, 3)) if any(a.normals is not None for a in used) else None
        self.uv = np.zeros((total, 3, 2)) if any(a.uv is not None for a in used) else None
        self.material = np.empty(total, np.int32)
        self.smooth = np.empty(total, bool)
        self.visibility = np.empty(total, np.uint8)


# Rows computed at once: cache-sized temporaries for big meshes, few NumPy
# calls for many instances of small ones.
CHUNK_ROWS = 1 << 16


def _place(cols, placed, arrays, n_mat, threads=0):
    """Triangles of the instances ``placed`` (indices into the
    InstanceColumns ``cols``), with ``arrays`` their meshes' _MeshArrays by
    mesh index.  Per instance only what differs between instances is
    computed (vertices, normals, materials), for the instances of one mesh
    at once; edges, face normals and unit shading normals then row by row."""
    if not len(placed):
        empty3 = np.zeros((0, 3))
        return Triangles(empty3, empty3, empty3, empty3, None, np.zeros(0, bool), None,
                         np.zeros(0, np.int32), np.zeros(0))
    meshes = cols.mesh[placed]
    table = max(arrays) + 1
    tri_count, vertex_count = np.zeros(table, np.int64), np.zeros(table, np.int64)
    for k, a in arrays.items():
        tri_count[k], vertex_count[k] = a.count, len(a.positions)
    rows, verts = tri_count[meshes], vertex_count[meshes]
    out = _Out(int(rows.sum()), int(verts.sum()), arrays.values())
    first_row, first_vertex = np.cumsum(rows) - rows, np.cumsum(verts) - verts
    order = np.argsort(meshes, kind="stable")   # the placed instances of each mesh, in order
    bounds = np.flatnonzero(np.diff(meshes[order])) + 1
    jobs = []
    for numbers in np.split(order, bounds):
        mesh_arrays = arrays[int(meshes[numbers[0]])]
        step = max(1, CHUNK_ROWS // mesh_arrays.count)
        for lo in range(0, len(numbers), step):
            some = numbers[lo:lo + step]
            jobs.append((mesh_arrays, placed[some], first_row[some], first_vertex[some]))
    keep = np.empty(len(out.p0), bool)
    ns = out.ns if out.ns is not None else np.empty((0, 3, 3))

    def place_rows(lo, hi):
        _place_rows(out.vertices, out.indices[lo:hi], out.smooth[lo:hi], out.ns is not None, out.p0[lo:hi],
                    out.e1[lo:hi], out.e2[lo:hi], out.ng[lo:hi], out.clen[lo:hi],
                    ns[lo:hi] if out.ns is not None else ns, keep[lo:hi])
    with _Workers(len(keep), threads) as run:
        # Jobs write disjoint rows; NumPy and the compiled loop release the GIL.
        run(lambda job: _place_instances(out, cols, *job, n_mat), jobs)
        run(lambda bounds: place_rows(*bounds), _ranges(len(keep), run.threads))
    dropped = int(len(keep) - np.count_nonzero(keep))
    keep = None if dropped == 0 else keep

    def kept(a):
        return None if a is None else _take_kept(a, keep)
    visibility = None if np.all(out.visibility == VIS_ALL) else kept(out.visibility)
    tris = Triangles(kept(out.p0), kept(out.e1), kept(out.e2), kept(out.ng), kept(out.ns), kept(out.smooth),
                     kept(out.uv), kept(out.material), 0.5 * kept(out.clen), dropped, visibility=visibility)
    tris.vertices = out.vertices
    # Half the memory; Embree takes 32-bit indices.
    tris.indices = kept(out.indices.astype(np.int32) if len(out.vertices) < 2 ** 31 else out.indices)
    tris.kept = keep
    return tris


# Triangles from which flatten runs on every core (a big scene's preparation
# is otherwise one core's work before the render starts).
PARALLEL_ROWS = 1 << 18


class _Workers:
    """``run(fn, items)``: fn over items on every core for big scenes, in
    this thread for small ones (a pool costs more than it saves there)."""

    def __init__(self, rows, threads=0):
        cores = min(threads or os.cpu_count() or 1, 8)
        self.threads = cores if rows >= PARALLEL_ROWS else 1
        self.pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def __enter__(self):
        return self

    def __call__(self, fn, items):
        if self.pool is None:
            for item in items:
                fn(item)
        else:
            list(self.pool.map(fn, items))   # list(): raises a job's exception here

    def __exit__(self, *exc):
        if self.pool is not None:
            self.pool.shutdown()


def _ranges(n, parts):
    """``parts`` (lo, hi) row ranges covering 0..n."""
    cut = np.linspace(0, n, parts + 1).astype(np.int64)
    return list(zip(cut[:-1], cut[1:]))


def _rows_of(first, count):
    """Row numbers of blocks of ``count`` rows starting at each of ``first``."""
    return (first[:, None] + np.arange(count)).reshape(-1)


def _place_instances(out, cols, arrays, insts, first_row, first_vertex, n_mat):
    """Instances ``insts`` (indices into ``cols``) of one mesh: world-space
    vertices, vertex indices, materials, flags, UVs and (not yet unit)
    shading normals."""
    k, n = len(insts), arrays.count
    m = cols.matrix[insts]
    lin, off = m[:, :3, :3], m[:, :3, 3]
    rows = _rows_of(first_row, n)
    # Vertices, not corners: a third of the work, and each instance's
    # (V, 3) @ (3, 3) is one BLAS call.  The values of positions @ lin.T + off.
    world = np.matmul(arrays.positions, lin.transpose(0, 2, 1)) + off[:, None, :]
    out.vertices[_rows_of(first_vertex, len(arrays.positions))] = world.reshape(-1, 3)
    out.indices[rows] = (arrays.triangles + first_vertex[:, None, None]).reshape(-1, 3)
    out.material[rows] = _materials(arrays.slots, n, cols.slot_set[insts], cols.slot_sets, n_mat).reshape(-1)
    out.smooth[rows] = arrays.normals is not None
    out.visibility[rows] = np.repeat(cols.visibility[insts], n)
    if arrays.uv is not None:
        out.uv[rows] = np.broadcast_to(arrays.uv, (k,) + arrays.uv.shape).reshape(-1, 3, 2)
    if out.ns is not None and arrays.normals is None:
        out.ns[rows] = 0.0   # flat: _place_rows puts the face normal
    elif arrays.normals is not None:
        # Normals transform with the inverse transpose; a mirroring matrix
        # flips the winding, which the cross product in _place_rows sees too.
        nmat_t = lin.transpose(0, 2, 1).copy()   # nmat.T where lin is singular
        invertible = np.abs(np.linalg.det(lin)) > 0
        if invertible.any():
            nmat_t[invertible] = np.linalg.inv(lin[invertible])
        ns = np.matmul(arrays.normals.reshape(-1, 3), nmat_t)
        out.ns[rows] = ns.reshape(-1, 3, 3)


def _materials(slots, n, set_of_instance, slot_sets, n_mat):
    """(K, n) compiled material ids of K instances' triangles, from each
    instance's material-slot set (an index into ``slot_sets``)."""
    distinct, which = np.unique(set_of_instance, return_inverse=True)
    tables = [_slot_table(slot_sets[k], n_mat) for k in distinct]
    if slots is None:
        return np.repeat(np.array([t[0] for t in tables], np.int32)[which][:, None], n, axis=1)
    width = max(len(t) for t in tables)
    padded = np.full((len(tables), width), n_mat, np.int32)
    for row, table in zip(padded, tables):
        row[:len(table)] = table
    last = np.array([len(t) - 1 for t in tables])
    return padded[np.arange(len(tables))[:, None], np.minimum(slots[None, :], last[:, None])][which]


def _place_rows_numpy(vertices, indices, smooth, has_ns, p0, e1, e2, ng, clen, ns, keep):
    """Edges, face normals and their lengths, unit shading normals (in place,
    when ``has_ns``) and which triangles to keep (finite, not degenerate)."""
    with np.errstate(all="ignore"):   # degenerate and non-finite rows are dropped
        for lo in range(0, len(indices), CHUNK_ROWS):
            rows = slice(lo, lo + CHUNK_ROWS)
            tri = indices[rows]
            a = p0[rows] = vertices[tri[:, 0]]
            b = e1[rows] = vertices[tri[:, 1]] - a
            c = e2[rows] = vertices[tri[:, 2]] - a
            cross = np.cross(b, c)
            length = clen[rows] = _row_norm(cross)
            face = ng[rows] = cross / length[:, None]
            if has_ns:
                ns[rows] = _unit_normals(ns[rows], face, smooth[rows])
        keep[:] = np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)


@kernels.loop_kernel("void(float64[:, ::1], int64[:, ::1], boolean[::1], boolean, float64[:, ::1], "
                     "float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[:, :, ::1], "
                     "boolean[::1])", _place_rows_numpy)
def _place_rows(vertices, indices, smooth, has_ns, p0, e1, e2, ng, clen, ns, keep):
    for i in range(len(indices)):
        a, b, c = indices[i, 0], indices[i, 1], indices[i, 2]
        for k in range(3):
            p0[i, k] = vertices[a, k]
            e1[i, k] = vertices[b, k] - vertices[a, k]
            e2[i, k] = vertices[c, k] - vertices[a, k]
        cx = e1[i, 1] * e2[i, 2] - e1[i, 2] * e2[i, 1]
        cy = e1[i, 2] * e2[i, 0] - e1[i, 0] * e2[i, 2]
        cz = e1[i, 0] * e2[i, 1] - e1[i, 1] * e2[i, 0]
        length = np.sqrt((cx * cx + cy * cy) + cz * cz)
        clen[i] = length
        ng[i, 0], ng[i, 1], ng[i, 2] = cx / length, cy / length, cz / length
        if has_ns:
            for j in range(3):
                nx, ny, nz = ns[i, j, 0], ns[i, j, 1], ns[i, j, 2]
                ln = np.sqrt((nx * nx + ny * ny) + nz * nz)
                if not np.isfinite(ln) or ln < 1e-12 or not smooth[i]:
                    ns[i, j, 0], ns[i, j, 1], ns[i, j, 2] = ng[i, 0], ng[i, 1], ng[i, 2]
                else:
                    ns[i, j, 0], ns[i, j, 1], ns[i, j, 2] = nx / ln, ny / ln, nz / ln
        m = max(abs(p0[i, 0]), abs(p0[i, 1]), abs(p0[i, 2]))
        q = 1.0 + m
        keep[i] = np.isfinite(length) and length > 1e-12 * (q * q)


def _scene_shading(scene, instance, local):
    """SceneShading (shader-node data) of the kept triangles: each one's
    instance and index in its mesh."""
    return SceneShading(scene, instance, local)


def _take_kept(array, keep):
    """array[keep], without the copy when every triangle was kept."""
    return array if keep is None else array[keep]


def _row_norm(v):
    """Euclidean length over the last axis; the same sums, in the same order,
    as np.linalg.norm, without its temporaries."""
    s = v * v
    return np.sqrt(s[..., 0] + s[..., 1] + s[..., 2])


def _unit_normals(ns, ng, smooth):
    """Unit shading normals; zero or NaN ones fall back to the face normal,
    and so do flat triangles (in a partly smooth scene)."""
    length = _row_norm(ns)
    bad = ~np.isfinite(length) | (length < 1e-12)
    bad[~smooth] = True
    if bad.any():
        return np.where(bad[..., None], ng[:, None, :], ns / np.where(bad, 1.0, length)[..., None])
    return ns / length[..., None]


def material_table(scene):
    """The scene's materials plus the default material at the end."""
    return list(scene.materials) + [DEFAULT_MATERIAL]


# ----------------------------------------------------------------------------
# Tangents for normal maps

def _needs_tangents(scene):
    def has_map(normal):
        return isinstance(normal, NormalMap) or (isinstance(normal, Bump) and has_map(normal.normal))
    return any(has_map(getattr(m, "normal", None)) for m in scene.materials)


def _add_tangents(tris, scene, n_each):
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
    t = _stack_optional(tangent, n_each, (3, 3))
    s = _stack_optional(sign, n_each, (3,))
    have = np.concatenate([np.full(n, x is not None) for n, x in zip(n_each, tangent)])
    t, s, have = _take_kept(t, tris.kept), _take_kept(s, tris.kept), _take_kept(have, tris.kept)
    ut, us = uv_tangents(tris)
    t[~have] = ut[~have, None, :]
    s[~have] = us[~have, None]
    tris.tangent, tris.tangent_sign = t, np.where(s < 0, -1.0, 1.0)


def _stack_optional(arrays, counts, tail):
    out = np.zeros((sum(counts),) + tail)
    start = 0
    for a, n in zip(arrays, counts):
        if a is not None:
            out[start:start + n] = a
        start += n
    return out


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


def corner_bounds(tris):
    """(lo, hi) of the finite corners of triangles (p0, e1, e2 arrays), or
    None when there are none (min / max per corner: no (3T, 3) copy)."""
    los, his = [], []
    for corner in (tris.p0, tris.p0 + tris.e1, tris.p0 + tris.e2):
        corner = corner[np.isfinite(corner).all(axis=1)]
        if len(corner):
            los.append(corner.min(axis=0))
            his.append(corner.max(axis=0))
    return (np.min(los, axis=0), np.max(his, axis=0)) if los else None
