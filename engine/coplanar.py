"""Coincident faces: triangles of different objects lying in one plane and
overlapping (a box's bottom resting exactly on a floor).

A ray meets both at the same distance; which one counts is decided by float
rounding and BVH order, in Cycles as in Ember (a transparent cube on an
emissive floor: Cycles finds the floor under a 12 m floor and not under a
2 m one, Ember by object order; tilted, each engine per pixel), and the one
missed is skipped by the ray that goes on (Cycles starts it exactly on the
plane, where the other face's distance is 0 and rejected; Ember lifts its
origin off the plane).  The renderers cannot agree there, so the exporter
names such pairs (``coincident_pairs``).

The test: unit normals equal within NORMAL_TOL (quantized), plane offsets
within REL_TOL of the scene's size (sorted runs), and the two objects'
triangles' bounds overlapping in the plane by more than that tolerance.
Pure NumPy, about one sort of the scene's triangles (docs/benchmarks.md).
"""
import numpy as np

from .instance_batch import InstanceBatch, field_of_each, meshes_of

REL_TOL = 1e-6
NORMAL_TOL = 1e-5
# World triangles checked at most (instances beyond are left out, named);
# and per batch of copies of one mesh.
BUDGET = 8_000_000
CHUNK = 1 << 17
# Sign reference for the normals: no common plane is perpendicular to it, so
# coplanar faces facing either way get the same canonical normal.
QUANTA = int(round(1.0 / NORMAL_TOL)) + 1   # a quantized component lies in [-QUANTA, QUANTA]
SIGN_REFERENCE = np.array([0.8017837, 0.5345225, 0.2672612]) + np.array([0.0, 1e-3, -2e-3])


def coincident_pairs(scene, budget=BUDGET):
    """([(name_a, name_b), ...] of instances with coincident faces, in
    order of first appearance; number of triangles left unchecked)."""
    rows, left_out = _plane_rows(scene, budget)
    if rows is None:
        return [], left_out
    normal, offset, lo, hi, owner = rows
    tol = REL_TOL * max(float((hi.max(axis=0) - lo.min(axis=0)).max()), 1e-30)
    groups = _plane_groups(normal, offset, owner, tol)
    names = field_of_each(scene.instances, "name", "object")
    pairs = []
    for a, b in _overlapping_owners(groups, normal, lo, hi, owner, tol):
        pair = (names[a], names[b])
        if pair not in pairs:
            pairs.append(pair)
    return pairs, left_out


def _plane_rows(scene, budget):
    """Per world triangle: canonical unit normal, plane offset, 3D bounds
    (float32 but the offset, to keep 2 M triangles small) and instance index."""
    instances = scene.instances
    if len(instances) == 0:
        return None, 0
    mesh_of = meshes_of(instances)
    matrices = _matrices(instances)
    parts, used, left_out = [], 0, 0
    for m in np.unique(mesh_of):
        which = np.flatnonzero(mesh_of == m)
        mesh = scene.meshes[m]
        positions, triangles = np.asarray(mesh.positions, np.float64), np.asarray(mesh.triangles, np.int64)
        t = len(triangles)
        if t == 0:
            continue
        room = max((budget - used) // t, 0)
        left_out += (len(which) - min(room, len(which))) * t
        which = which[:room]
        # Chunks of at most CHUNK triangles: small temporaries, reused (fresh
        # 100 MB arrays cost more in page faults than the arithmetic).
        step = max(CHUNK // t, 1)
        for start in range(0, len(which), step):
            copies = which[start:start + step]
            for first in range(0, t, CHUNK):
                local = positions[triangles[first:first + CHUNK]]
                parts.append(_rows_of(local, matrices[copies], copies))
        used += len(which) * t
    if not parts:
        return None, left_out
    return tuple(np.concatenate(column) for column in zip(*parts)), left_out


def _matrices(instances):
    if isinstance(instances, InstanceBatch):
        return instances.matrix
    return np.array([np.asarray(inst.matrix, np.float64) for inst in instances]).reshape(-1, 4, 4)


def _rows_of(local, matrices, owners):
    """_plane_rows' columns for the copies ``matrices`` (K, 4, 4) of one mesh."""
    world = _corners(local, matrices)
    v0, v1, v2 = world[:, 0], world[:, 1], world[:, 2]
    n = _cross(v1 - v0, v2 - v0)
    length = np.sqrt(n[:, 0] ** 2 + n[:, 1] ** 2 + n[:, 2] ** 2)
    keep = length > 0
    n = n[keep] / length[keep, None]
    n *= np.where(n @ SIGN_REFERENCE < 0, -1.0, 1.0)[:, None]
    v0, v1, v2 = v0[keep], v1[keep], v2[keep]
    offset = n[:, 0] * v0[:, 0] + n[:, 1] * v0[:, 1] + n[:, 2] * v0[:, 2]
    lo = np.minimum(np.minimum(v0, v1), v2).astype(np.float32)
    hi = np.maximum(np.maximum(v0, v1), v2).astype(np.float32)
    owner = np.repeat(np.asarray(owners, np.int32), len(local))[keep]
    return n.astype(np.float32), offset, lo, hi, owner


def _corners(local, matrices):
    """(K T, 3, 3) world corners: big meshes copy by copy (three scaled
    columns: a (3 T, 3) x (3, 3) matmul was slower), many copies of a small
    one in one einsum."""
    if len(local) < 64:
        world = np.einsum("kij,tcj->ktci", matrices[:, :3, :3], local) + matrices[:, None, None, :3, 3]
        return world.reshape(-1, 3, 3)
    flat = local.reshape(-1, 3)
    out = []
    for m in matrices:
        world = flat[:, :1] * m[:3, 0] + m[:3, 3]
        world += flat[:, 1:2] * m[:3, 1]
        world += flat[:, 2:] * m[:3, 2]
        out.append(world.reshape(-1, 3, 3))
    return out[0] if len(out) == 1 else np.concatenate(out)


def _cross(a, b):
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _plane_groups(normal, offset, owner, tol):
    """(row order, start of each group in it) over the rows whose quantized
    normal some other object's face shares (the rest cannot be coincident
    with anything: one cheap sort of a packed key leaves them out), sorted
    by normal then offset; a group is a run of one normal whose offsets step
    by at most tol."""
    q = np.round(normal / NORMAL_TOL).astype(np.int64) + QUANTA
    packed = (q[:, 0] * (2 * QUANTA + 1) + q[:, 1]) * (2 * QUANTA + 1) + q[:, 2]
    by_normal = np.argsort(packed)
    keys = packed[by_normal]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    owners = owner[by_normal]
    shared = np.minimum.reduceat(owners, starts) != np.maximum.reduceat(owners, starts)
    run = np.repeat(shared, np.diff(np.r_[starts, len(keys)]))
    rows = by_normal[run]
    order = rows[np.lexsort((offset[rows], packed[rows]))]
    ks, ds = packed[order], offset[order]
    new = np.ones(len(order), bool)
    new[1:] = (ks[1:] != ks[:-1]) | (ds[1:] - ds[:-1] > tol)
    return order, np.flatnonzero(new)


def _overlapping_owners(groups, normal, lo, hi, owner, tol):
    """(a, b) instance pairs, a < b, whose faces of one plane group overlap
    in the plane (bounds, less the group's dominant normal axis)."""
    order, starts = groups
    if len(order) == 0:
        return []
    owners = owner[order]
    shared = np.minimum.reduceat(owners, starts) != np.maximum.reduceat(owners, starts)
    ends = np.r_[starts[1:], len(order)]
    out = []
    for g0, g1 in zip(starts[shared], ends[shared]):
        rows = order[g0:g1]
        rows = rows[np.argsort(owner[rows], kind="stable")]
        keep = [a for a in range(3) if a != int(np.argmax(np.abs(normal[rows[0]])))]
        out += _pairs_in_plane(lo[rows][:, keep], hi[rows][:, keep], owner[rows], tol)
    return out


def _pairs_in_plane(lo, hi, owner, tol):
    """Owner pairs with some two faces' 2D bounds overlapping by > tol."""
    cuts = np.flatnonzero(np.diff(owner)) + 1
    spans = list(zip(np.r_[0, cuts], np.r_[cuts, len(owner)]))
    out = []
    for i, (a0, a1) in enumerate(spans):
        for b0, b1 in spans[i + 1:]:
            if _boxes_overlap(lo[a0:a1], hi[a0:a1], lo[b0:b1], hi[b0:b1], tol):
                out.append((int(owner[a0]), int(owner[b0])))
    return out


def _boxes_overlap(lo_a, hi_a, lo_b, hi_b, tol, limit=4_000_000):
    """Whether a face of A and a face of B overlap (bounds): every pair when
    there are few, else the two objects' whole bounds in the plane."""
    if len(lo_a) * len(lo_b) > limit:
        lo_a, hi_a = lo_a.min(axis=0, keepdims=True), hi_a.max(axis=0, keepdims=True)
        lo_b, hi_b = lo_b.min(axis=0, keepdims=True), hi_b.max(axis=0, keepdims=True)
    small, large = ((lo_a, hi_a), (lo_b, hi_b)) if len(lo_a) <= len(lo_b) else ((lo_b, hi_b), (lo_a, hi_a))
    step = max(limit // max(len(large[0]), 1), 1)
    for s in range(0, len(small[0]), step):
        lo_s, hi_s = small[0][s:s + step, None], small[1][s:s + step, None]
        hit = ((lo_s < large[1][None] - tol) & (large[0][None] < hi_s - tol)).all(axis=2)
        if hit.any():
            return True
    return False
