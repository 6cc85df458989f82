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

The test: unit normals equal within NORMAL_TOL (grouped by NORMAL_CELL cells,
much coarser, so float noise rarely splits a plane's faces), plane offsets
within REL_TOL of the scene's size (sorted runs), and two faces of the two
objects overlapping in the plane by more than that tolerance (bounds, then
separating axes).  Faces facing opposite ways (a box's bottom on a floor)
count only when one object lets rays inside (a volume or a PASSABLE lobe):
a closed opaque box hides both from every ray.  Only instances whose bounds
meet are compared, and of a big mesh only the triangles near the others'
bounds.  Pure NumPy (cost: docs/real_scenes.md, coincident_faces).
"""
import numpy as np

from .instance_batch import InstanceBatch, field_of_each, meshes_of

REL_TOL = 1e-6
NORMAL_TOL = 1e-5
NORMAL_CELL = 1e-3
# World triangles checked at most (instances beyond are left out, named);
# and per batch of copies of one mesh.
BUDGET = 8_000_000
CHUNK = 1 << 17
# Meshes this big are filtered to the triangles near other instances first.
FILTER_MIN = 4096
QUANTA = int(round(1.0 / NORMAL_CELL)) + 1   # a quantized component lies in [-QUANTA, QUANTA]
# Lobes that let a ray inside an object (or through its face).
PASSABLE = ("glass", "refraction", "translucent", "transparent", "ray_portal")
# Sign reference for the normals: no common plane is perpendicular to it, so
# coplanar faces facing either way get the same canonical normal.
SIGN_REFERENCE = np.array([0.8017837, 0.5345225, 0.2672612]) + np.array([0.0, 1e-3, -2e-3])


def coincident_pairs(scene, budget=BUDGET):
    """([(name_a, name_b), ...] of instances with coincident faces, in
    order of first appearance; number of triangles left unchecked).  Faces
    facing opposite ways (a box's bottom on a floor) only count when one of
    the two objects lets rays inside (PASSABLE): closed opaque objects hide
    them from every ray."""
    instances = scene.instances
    if len(instances) < 2:
        return [], 0
    mesh_of, matrices = meshes_of(instances), _matrices(instances)
    boxes = _instance_bounds(scene, mesh_of, matrices)
    tol = REL_TOL * max(float((boxes[:, 1].max(axis=0) - boxes[:, 0].min(axis=0)).max()), 1e-30)
    rows, left_out = _plane_rows(scene, mesh_of, matrices, boxes, tol, budget)
    if rows is None:
        return [], left_out
    groups = _plane_groups(rows["normal"], rows["offset"], rows["owner"], tol)
    plane = _Plane(scene, rows, tol)
    names = field_of_each(instances, "name", "object")
    pairs = []
    for a, b in _overlapping_owners(groups, plane):
        pair = (names[a], names[b])
        if pair not in pairs:
            pairs.append(pair)
    return pairs, left_out


def _instance_bounds(scene, mesh_of, matrices):
    """(N, 2, 3) world bounds of each instance (its mesh's box transformed)."""
    local = np.zeros((len(scene.meshes) + 1, 8, 3))
    for m, mesh in enumerate(scene.meshes):
        p = np.asarray(mesh.positions, np.float64).reshape(-1, 3)
        if len(p):
            lo, hi = p.min(axis=0), p.max(axis=0)
            local[m] = [[(lo, hi)[k >> a & 1][a] for a in range(3)] for k in range(8)]
    corners = np.einsum("nij,ncj->nci", matrices[:, :3, :3], local[mesh_of]) + matrices[:, None, :3, 3]
    return np.stack([corners.min(axis=1), corners.max(axis=1)], axis=1)


def _partners(boxes, tol, most=4096):
    """Per instance, the instances whose bounds overlap its own (an array);
    None for every instance past ``most`` instances (all are checked)."""
    if len(boxes) > most:
        return None
    lo, hi = boxes[:, 0], boxes[:, 1]
    meet = ((lo[:, None] <= hi[None] + tol) & (lo[None] <= hi[:, None] + tol)).all(axis=2)
    np.fill_diagonal(meet, False)
    return [np.flatnonzero(row) for row in meet]


def _plane_rows(scene, mesh_of, matrices, boxes, tol, budget):
    """Per world triangle that may meet another instance's (near its
    partners' bounds): canonical unit normal, plane offset, 3D bounds
    (float32 but the offset, to keep 2 M triangles small), instance and
    triangle index, facing."""
    partners = _partners(boxes, tol)
    parts, used, left_out = [], 0, 0
    for m in np.unique(mesh_of):
        which = np.flatnonzero(mesh_of == m)
        if partners is not None:
            which = which[[len(partners[i]) > 0 for i in which]]
        mesh = scene.meshes[m]
        positions, triangles = np.asarray(mesh.positions, np.float64), np.asarray(mesh.triangles, np.int64)
        t = len(triangles)
        if t == 0 or len(which) == 0:
            continue
        room = max((budget - used) // t, 0)
        left_out += (len(which) - min(room, len(which))) * t
        which = which[:room]
        used += len(which) * t
        if partners is not None and t >= FILTER_MIN:
            parts += _near_rows(positions, triangles, matrices, which, [boxes[partners[i]] for i in which], tol)
            continue
        # Chunks of at most CHUNK triangles: small temporaries, reused (fresh
        # 100 MB arrays cost more in page faults than the arithmetic).
        step = max(CHUNK // t, 1)
        for start in range(0, len(which), step):
            copies = which[start:start + step]
            for first in range(0, t, CHUNK):
                index = np.arange(first, min(first + CHUNK, t))
                parts.append(_rows_of(positions[triangles[index]], matrices[copies], copies, index))
    if not parts:
        return None, left_out
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}, left_out


def _near_rows(positions, triangles, matrices, which, partner_boxes, tol):
    """Rows of a big mesh's copies ``which``: only the triangles whose
    bounds meet one of the copy's partners' bounds (tested in the mesh's own
    space, before any triangle is transformed), chunk by chunk."""
    out = []
    for first in range(0, len(triangles), CHUNK):
        index = np.arange(first, min(first + CHUNK, len(triangles)))
        corners = positions[triangles[index]]
        lo = np.minimum(np.minimum(corners[:, 0], corners[:, 1]), corners[:, 2])
        hi = np.maximum(np.maximum(corners[:, 0], corners[:, 1]), corners[:, 2])
        for i, world in zip(which, partner_boxes):
            near = _near(lo, hi, matrices[i], world, tol)
            if near.any():
                out.append(_rows_of(corners[near], matrices[i:i + 1], [i], index[near]))
    return out


def _near(lo, hi, matrix, world_boxes, tol, most=64):
    """(T,) whether local triangle bounds meet any of the world boxes (P, 2, 3)
    taken into the local space (their boxes there, widened by tol); past
    ``most`` boxes, their union."""
    try:
        inverse = np.linalg.inv(matrix)
    except np.linalg.LinAlgError:
        return np.ones(len(lo), bool)
    if len(world_boxes) > most:
        world_boxes = np.stack([world_boxes[:, 0].min(axis=0), world_boxes[:, 1].max(axis=0)])[None]
    k = np.arange(8)
    corners = np.stack([world_boxes[:, (k >> a) & 1, a] for a in range(3)], axis=2)   # (P, 8, 3)
    local = corners @ inverse[:3, :3].T + inverse[:3, 3]
    widen = tol * np.abs(inverse[:3, :3]).sum(axis=1).max()
    box_lo, box_hi = local.min(axis=1) - widen, local.max(axis=1) + widen
    near = np.zeros(len(lo), bool)
    for b_lo, b_hi in zip(box_lo, box_hi):
        meet = (lo[:, 0] <= b_hi[0]) & (b_lo[0] <= hi[:, 0])   # axis by axis: .all(axis=1) was slower
        for a in (1, 2):
            meet &= (lo[:, a] <= b_hi[a]) & (b_lo[a] <= hi[:, a])
        near |= meet
    return near


def _matrices(instances):
    if isinstance(instances, InstanceBatch):
        return instances.matrix
    return np.array([np.asarray(inst.matrix, np.float64) for inst in instances]).reshape(-1, 4, 4)


def _rows_of(local, matrices, owners, index):
    """_plane_rows' columns for the copies ``matrices`` (K, 4, 4) of one
    mesh's triangles ``index`` (``local``: their corners, object space)."""
    world = _corners(local, matrices)
    v0, v1, v2 = world[:, 0], world[:, 1], world[:, 2]
    n = _cross(v1 - v0, v2 - v0)
    length = np.sqrt(n[:, 0] ** 2 + n[:, 1] ** 2 + n[:, 2] ** 2)
    keep = length > 0
    n = n[keep] / length[keep, None]
    facing = np.where(n @ SIGN_REFERENCE < 0, -1, 1).astype(np.int8)
    n *= facing[:, None]
    v0, v1, v2 = v0[keep], v1[keep], v2[keep]
    tri = np.tile(np.asarray(index, np.int32), len(matrices))[keep]
    return dict(normal=n.astype(np.float32), offset=n[:, 0] * v0[:, 0] + n[:, 1] * v0[:, 1] + n[:, 2] * v0[:, 2],
                lo=np.minimum(np.minimum(v0, v1), v2).astype(np.float32),
                hi=np.maximum(np.maximum(v0, v1), v2).astype(np.float32),
                owner=np.repeat(np.asarray(owners, np.int32), len(local))[keep], tri=tri, facing=facing)


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
    q = np.round(normal / NORMAL_CELL).astype(np.int64) + QUANTA
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


class _Plane:
    """What the pair stage reads: the rows, each instance's mesh, matrix and
    whether rays get inside it, and the tolerance."""

    def __init__(self, scene, rows, tol):
        self.scene, self.rows, self.tol = scene, rows, tol
        self.mesh_of = meshes_of(scene.instances)
        self.matrices = _matrices(scene.instances)
        materials = field_of_each(scene.instances, "materials", ())
        passable = [_passable(scene, m) for m in range(len(scene.materials))]
        self.passable = np.array([any(passable[m] for m in mats if 0 <= m < len(passable)) for mats in materials])

    def corners_2d(self, rows, keep):
        """(R, 3, 2) world corners of rows, the plane's dominant axis dropped."""
        out = np.empty((len(rows), 3, 3))
        owner, tri = self.rows["owner"][rows], self.rows["tri"][rows]
        for o in np.unique(owner):
            at = owner == o
            mesh = self.scene.meshes[self.mesh_of[o]]
            local = np.asarray(mesh.positions, np.float64)[np.asarray(mesh.triangles, np.int64)[tri[at]]]
            out[at] = _corners(local, self.matrices[o:o + 1])
        return out[:, :, keep]


def _passable(scene, index):
    material = scene.materials[index]
    return getattr(material, "volume", None) is not None or any(
        lobe.kind in PASSABLE for lobe in getattr(material, "lobes", ()))


def _overlapping_owners(groups, plane):
    """(a, b) instance pairs, a < b, with faces of one plane group that
    overlap in the plane."""
    order, starts = groups
    if len(order) == 0:
        return []
    owner = plane.rows["owner"]
    owners = owner[order]
    shared = np.minimum.reduceat(owners, starts) != np.maximum.reduceat(owners, starts)
    ends = np.r_[starts[1:], len(order)]
    out = []
    for g0, g1 in zip(starts[shared], ends[shared]):
        rows = order[g0:g1]
        rows = rows[np.argsort(owner[rows], kind="stable")]
        keep = [a for a in range(3) if a != int(np.argmax(np.abs(plane.rows["normal"][rows[0]])))]
        cuts = np.flatnonzero(np.diff(owner[rows])) + 1
        spans = np.split(rows, cuts)
        for i, a in enumerate(spans):
            for b in spans[i + 1:]:
                if _faces_overlap(plane, a, b, keep):
                    out.append((int(owner[a[0]]), int(owner[b[0]])))
    return out


def _faces_overlap(plane, a, b, keep, limit=4_000_000):
    """Whether a face of rows a overlaps one of rows b: bounds first, then
    the triangles themselves (separating axes); opposite-facing pairs only
    when rays get inside one of the two objects.  Past 100 limit pairs, the
    two objects' bounds in the plane decide."""
    r = plane.rows
    if plane.passable[r["owner"][a[0]]] or plane.passable[r["owner"][b[0]]]:
        return _some_overlap(plane, a, b, keep, limit)
    up_a, up_b = r["facing"][a] == 1, r["facing"][b] == 1
    return (_some_overlap(plane, a[up_a], b[up_b], keep, limit)
            or _some_overlap(plane, a[~up_a], b[~up_b], keep, limit))


def _some_overlap(plane, a, b, keep, limit):
    if len(a) == 0 or len(b) == 0:
        return False
    lo, hi, tol = plane.rows["lo"][:, keep], plane.rows["hi"][:, keep], plane.tol
    if len(a) * len(b) > 100 * limit:
        return bool(((lo[a].min(axis=0) < hi[b].max(axis=0) - tol) & (lo[b].min(axis=0) < hi[a].max(axis=0) - tol)).all())
    small, large = (a, b) if len(a) <= len(b) else (b, a)
    step = max(limit // len(large), 1)
    for s in range(0, len(small), step):
        part = small[s:s + step]
        hit = ((lo[part, None] < hi[None, large] - tol) & (lo[None, large] < hi[part, None] - tol)).all(axis=2)
        i, j = np.nonzero(hit)
        i, j = _same_plane(plane, part[i], large[j], i, j)
        if len(i) and _triangles_overlap(plane.corners_2d(part[i], keep), plane.corners_2d(large[j], keep), tol).any():
            return True
    return False


def _same_plane(plane, rows_a, rows_b, i, j):
    """The candidate pairs whose two faces' normals agree within NORMAL_TOL
    and offsets within the tolerance (a group's cell is coarser)."""
    normal, offset = plane.rows["normal"], plane.rows["offset"]
    close = (np.abs(normal[rows_a] - normal[rows_b]).max(axis=1) <= NORMAL_TOL) & (
        np.abs(offset[rows_a] - offset[rows_b]) <= plane.tol)
    return i[close], j[close]


def _triangles_overlap(p, q, tol):
    """(R,) whether 2D triangles p[k] and q[k] (R, 3, 2) share more than a
    band tol wide: no edge normal of either separates them."""
    apart = np.zeros(len(p), bool)
    for tri in (p, q):
        for i in range(3):
            edge = tri[:, (i + 1) % 3] - tri[:, i]
            axis = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
            axis /= np.maximum(np.linalg.norm(axis, axis=1), 1e-300)[:, None]
            sp, sq = np.einsum("rcj,rj->rc", p, axis), np.einsum("rcj,rj->rc", q, axis)
            apart |= (sp.max(axis=1) <= sq.min(axis=1) + tol) | (sq.max(axis=1) <= sp.min(axis=1) + tol)
    return ~apart
