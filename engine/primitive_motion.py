"""Motion blur of points and curves (Cycles' object motion and motion
positions attribute of point clouds and hair).

A moving point cloud or curve set (``PointCloud.motion`` /
``HairCurves.motion``: object-to-world at the shutter's steps;
``motion_positions`` (and a cloud's ``motion_radii``): its points at the
steps) is traced as Cycles' Embree setup does (bvh/embree.cpp): one
geometry of object-space control points (x, y, z, radius) with a vertex
buffer per deformation step, in a scene of its own that an Embree instance
places by the quaternion decomposition of each transform step (the moving
triangles' rule, engine/motion.py).  Embree interpolates both at each ray's
exact time; ``world_rows`` rebuilds the control points a hit ray saw, in
float64 with the same interpolation, so the hit point, normal and tangent
are those of the strand or sphere at the ray's time.  Curves keep their
radii over the shutter (Cycles' ``pack_motion_verts`` reads the centre's),
points take theirs at each step (the motion attribute's w).
"""
import numpy as np

from .motion import _lerp_steps, decompose, transform_at


class MovingSet:
    """One moving cloud or curve set: ``steps`` (S, K, 4) float32
    object-space control rows (x, y, z, radius) per deformation step,
    ``decomposition`` (S', 16) its placement's steps, ``rows`` the
    Triangles rows of its primitives in the order Embree numbers them,
    ``index`` (P,) each primitive's first control row (curves) or None
    (points: primitive k is row k)."""

    def __init__(self, steps, decomposition, rows, index=None):
        self.steps, self.decomposition, self.rows, self.index = steps, decomposition, rows, index


class MovingRows:
    """Which slots of a Spheres / Strands move: ``part`` (n_slots,) the
    MovingSet of each (-1: still), ``first`` its first control row there."""

    def __init__(self, n_slots):
        self.part = np.full(n_slots, -1, np.int64)
        self.first = np.zeros(n_slots, np.int64)
        self.sets = []

    def add(self, slots, first, moving_set):
        self.part[slots] = len(self.sets)
        self.first[slots] = first
        self.sets.append(moving_set)

    def __bool__(self):
        return bool(self.sets)


def _steps_of(item, positions, radii, motion_radii=None):
    """(S, N, 4) object-space (x, y, z, r) of an item's points per step."""
    steps = getattr(item, "motion_positions", None)
    steps = np.asarray(positions, np.float64)[None] if steps is None else np.asarray(steps, np.float64)
    r = np.broadcast_to(np.asarray(radii, np.float64), steps.shape[:2]) if motion_radii is None \
        else np.asarray(motion_radii, np.float64)
    return np.concatenate([steps, r[..., None]], axis=2)


def _placement(item):
    matrices = getattr(item, "motion", None)
    return decompose(np.asarray(item.matrix, np.float64)[None] if matrices is None else matrices)


def moves(item):
    return getattr(item, "motion", None) is not None or getattr(item, "motion_positions", None) is not None


def attach_points(spheres, tris, owners, clouds):
    """Mark the spheres of moving clouds (``owners[i]`` the stand-in
    instance of ``clouds[i]``): ``spheres.moving``."""
    if spheres is None:
        return
    moving = MovingRows(len(spheres))
    owner, local = tris.shading.instance, tris.shading.local
    for inst_index, cloud in zip(owners, clouds):
        if not moves(cloud):
            continue
        mine = np.flatnonzero(owner == inst_index)
        mine = mine[np.argsort(local[mine], kind="stable")]   # Embree's primitive k: the k-th point
        steps = _steps_of(cloud, cloud.positions, cloud.radii, getattr(cloud, "motion_radii", None))
        moving.add(spheres.slot[mine], np.arange(len(mine)),
                   MovingSet(steps[:, local[mine]].astype(np.float32), _placement(cloud), mine))
    spheres.moving = moving if moving else None


def attach_curves(strands, tris, owners, padded_index, segment_start):
    """Mark the segments of moving curve sets (``owners``: (stand-in
    instance, HairCurves) pairs; ``padded_index(offsets)`` Embree's control
    point order; ``segment_start(offsets)`` each segment's first one):
    ``strands.moving``."""
    if strands is None:
        return
    moving = MovingRows(len(strands))
    owner, local = tris.shading.instance, tris.shading.local
    for inst_index, curves in owners:
        if not moves(curves):
            continue
        mine = np.flatnonzero(owner == inst_index)
        offsets = np.asarray(curves.offsets, np.int64)
        steps = _steps_of(curves, curves.points, curves.radii)[:, padded_index(offsets)]
        start = segment_start(offsets)[local[mine]]
        moving.add(strands.slot[mine], start, MovingSet(steps.astype(np.float32), _placement(curves), mine, start))
    strands.moving = moving if moving else None


def world_rows(holder, slots, time, width, still):
    """(n, width, 4) world (x, y, z, r) control rows of primitives
    ``slots`` at each ray's time: ``still(slots)`` gives them for slots that
    do not move (or with no time); moving ones are interpolated and placed
    as Embree does (the radius scaled by cbrt|det| of the placement)."""
    out = still(slots)
    moving = getattr(holder, "moving", None)
    if not moving or time is None:
        return out
    part = moving.part[slots]
    for j in np.unique(part[part >= 0]):
        r = np.flatnonzero(part == j)
        moving_set = moving.sets[j]
        index = moving.first[slots[r]][:, None] + np.arange(width)[None, :]
        c = _lerp_steps(moving_set.steps, index, time[r])
        L, T = transform_at(moving_set.decomposition, time[r])
        scale = np.abs(np.linalg.det(L)) ** (1.0 / 3.0)
        out[r, :, :3] = np.einsum("nij,nkj->nki", L, c[..., :3]) + T[:, None, :]
        out[r, :, 3] = c[..., 3] * scale[:, None]
    return out
