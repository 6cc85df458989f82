"""Motion blur: geometry at each ray's time (Cycles' object, deformation and
camera motion).

A scene with motion (``Instance.motion``: object-to-world at the shutter's
steps; ``Mesh.motion``: vertex positions there; ``Camera.motion``) gives
every camera sample a time in [0, 1] over the shutter (the sampler's
``TIME`` set, stratified per pixel like the other sets); the path keeps it
for all its rays.  Time 0.5 is the shutter's centre, where the add-on
exports the scene itself (Cycles' rule for every shutter position), so a
ray without a time sees the triangles of ``geometry.Triangles``.

Rays are traced by Embree's own motion blur through its C API
(``engine.embree_c``): still triangles sit in one world-space geometry;
each moving instance is an Embree instance of a scene of its object-space
triangles (time steps for deformation) placed by a quaternion decomposition
per step (translation and the upper-triangular scale / skew linear, the
rotation by slerp), as Cycles places its moving objects.  Between steps
everything is interpolated at the ray's exact time: no slices, no bias.

``MotionGeometry.at`` rebuilds the hit triangle at the ray's time in float64
with the same interpolation (the hit point is re-intersected with that
triangle's plane, as for still hits); shading normals interpolate between
the steps and turn with the object.
"""
import threading
import time as _time

import numpy as np

from . import embree_c, instance_columns
from .accel import Accel, OFFSET_SCALE

CENTRE = 0.5   # the shutter time the scene's own arrays (Triangles) are at


def has_motion(scene):
    """Whether anything in the scene moves during the shutter."""
    cam = scene.camera
    return (getattr(cam, "motion", None) is not None
            or getattr(cam, "lens_motion", None) is not None
            or bool(instance_columns.columns(scene.instances).moving.any())
            or any(getattr(mesh, "motion", None) is not None for mesh in scene.meshes)
            or any(getattr(item, "motion", None) is not None or getattr(item, "motion_positions", None) is not None
                   for item in list(getattr(scene, "points", ()) or ()) + list(getattr(scene, "curves", ()) or ())))


# ----------------------------------------------------------------------------
# transforms: decomposition and interpolation

def _quaternion(r):
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    m = r
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = np.sqrt(trace + 1.0) * 2.0
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q / np.linalg.norm(q)


def decompose(matrices):
    """(S, 16) rows of Embree's RTCQuaternionDecomposition (scale xyz, skew
    xy xz yz, shift xyz, quaternion r i j k, translation xyz) of (S, 4, 4)
    matrices: M = R U with R a rotation and U upper triangular (QR, so
    Embree represents it exactly), quaternions sign-matched from step to
    step so slerp takes the short way (as Cycles' transform_motion_decompose)."""
    matrices = np.asarray(matrices, np.float64).reshape(-1, 4, 4)
    rows = np.zeros((len(matrices), 16))
    previous = None
    for k, m in enumerate(matrices):
        q_mat, u = np.linalg.qr(m[:3, :3])
        signs = np.where(np.diag(u) < 0, -1.0, 1.0)
        q_mat, u = q_mat * signs[None, :], u * signs[:, None]
        if np.linalg.det(q_mat) < 0:     # a mirror: the rotation takes -1, the scale its sign
            q_mat, u = -q_mat, -u
        q = _quaternion(q_mat)
        if previous is not None and np.dot(previous, q) < 0:
            q = -q
        previous = q
        rows[k, 0:3] = np.diag(u)
        rows[k, 3:6] = u[0, 1], u[0, 2], u[1, 2]
        rows[k, 9:13] = q
        rows[k, 13:16] = m[:3, 3]
    return rows


def _step_weights(steps, time):
    """(k, a): each time between step k and k + 1 at fraction a (Embree's
    and Cycles' rule: f = time (S - 1), k = min(floor f, S - 2))."""
    time = np.clip(np.asarray(time, np.float64), 0.0, 1.0)
    if steps == 1:
        return np.zeros(len(time), np.int64), np.zeros(len(time))
    f = time * (steps - 1)
    k = np.minimum(np.floor(f).astype(np.int64), steps - 2)
    return k, f - k


def _rotation(q):
    """(N, 3, 3) rotation matrices of (N, 4) unit quaternions (w, x, y, z)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)], axis=1)


def _slerp(q0, q1, a):
    """Embree's quaternion slerp (normalized lerp where cos > 0.9995)."""
    cos = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where((cos < 0)[:, None], -q1, q1)
    cos = np.abs(cos)
    phi = a * np.arccos(np.clip(cos, -1.0, 1.0))
    perp = q1 - q0 * cos[:, None]
    perp /= np.maximum(np.linalg.norm(perp, axis=1), 1e-300)[:, None]
    slerp = q0 * np.cos(phi)[:, None] + perp * np.sin(phi)[:, None]
    lerp = q0 + (q1 - q0) * a[:, None]
    lerp /= np.linalg.norm(lerp, axis=1)[:, None]
    return np.where((cos > 0.9995)[:, None], lerp, slerp)


def transform_at(rows, time):
    """(L (N, 3, 3), T (N, 3)): the transform of decomposition ``rows``
    (S, 16) at each time, world = L p + T."""
    rows = np.asarray(rows, np.float64)
    k, a = _step_weights(len(rows), time)
    r0 = rows[k]
    r1 = rows[np.minimum(k + 1, len(rows) - 1)]
    lin = r0 + (r1 - r0) * a[:, None]
    q = _slerp(r0[:, 9:13], r1[:, 9:13], a)
    n = len(a)
    u = np.zeros((n, 3, 3))
    u[:, 0, 0], u[:, 1, 1], u[:, 2, 2] = lin[:, 0], lin[:, 1], lin[:, 2]
    u[:, 0, 1], u[:, 0, 2], u[:, 1, 2] = lin[:, 3], lin[:, 4], lin[:, 5]
    shift = lin[:, 6:9]
    L = np.einsum("nij,njk->nik", _rotation(q), u)
    return L, np.einsum("nij,nj->ni", _rotation(q), shift) + lin[:, 13:16]


def matrix_at(rows, time):
    """(4, 4) transform of decomposition ``rows`` at one time."""
    L, T = transform_at(rows, np.array([float(time)]))
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = L[0], T[0]
    return m


def _lerp_steps(steps, index, time):
    """(N, ...) float64 rows ``index`` (N,) or (N, W) of per-step arrays
    (S, M, ...) at each of the N times."""
    k, a = _step_weights(len(steps), time)
    if len(steps) == 1:
        return np.asarray(steps[0][index], np.float64)
    k = k.reshape((-1,) + (1,) * (np.ndim(index) - 1))    # each row's step, for every column of index
    lo = np.asarray(steps[k, index], np.float64)
    hi = np.asarray(steps[k + 1, index], np.float64)
    a = a.reshape((-1,) + (1,) * (lo.ndim - 1))
    return lo + (hi - lo) * a


# ----------------------------------------------------------------------------
# geometry

class _Part:
    """One moving instance's triangles: object-space corners per step
    (S, M, 3, 3) float32 (as Embree holds them), per-corner normals per
    step or None, its placement's decomposition rows (S', 16) and the
    global rows of its triangles."""

    def __init__(self, rows, corners, normals, decomposition, smooth):
        self.rows, self.corners, self.normals = rows, corners, normals
        self.decomposition, self.smooth = decomposition, smooth


class MotionGeometry:
    """The scene's triangles over the shutter: which rows move (``part``,
    -1 for still ones), their steps, and their shape at any time."""

    def __init__(self, scene, tris):
        shading = tris.shading
        owner, local = shading.instance, shading.local
        self.part = np.full(len(tris), -1, np.int32)
        self.slot = np.zeros(len(tris), np.int64)
        self.parts = []
        for index, inst in enumerate(scene.instances):
            mesh = scene.meshes[inst.mesh]
            if getattr(inst, "motion", None) is None and getattr(mesh, "motion", None) is None:
                continue
            rows = np.flatnonzero(owner == index)
            if len(rows) == 0:
                continue
            loc = local[rows]
            corner_ids = np.asarray(mesh.triangles, np.int64)[loc]
            steps = (np.asarray(mesh.motion, np.float64) if mesh.motion is not None
                     else np.asarray(mesh.positions, np.float64)[None])
            corners = steps[:, corner_ids].astype(np.float32)            # (S, M, 3, 3)
            normals = None
            if tris.ns is not None and mesh.normals is not None:
                if getattr(mesh, "motion_normals", None) is not None:
                    normals = np.asarray(mesh.motion_normals, np.float64)[:, loc]
                else:
                    normals = np.asarray(mesh.normals, np.float64)[loc][None]
            matrices = inst.motion if inst.motion is not None else np.asarray(inst.matrix)[None]
            self.part[rows] = len(self.parts)
            self.slot[rows] = np.arange(len(rows))
            self.parts.append(_Part(rows, corners, normals, decompose(matrices), tris.smooth[rows]))
        self.still = np.flatnonzero(self.part < 0)

    @property
    def moving(self):
        return len(self.parts) > 0

    def embree_instances(self):
        """The moving instances for embree_c.TriangleScene."""
        instances = []
        for part in self.parts:
            s, m = part.corners.shape[:2]
            instances.append((part.corners.reshape(s, -1, 3), np.arange(3 * m).reshape(-1, 3), part.rows,
                              part.decomposition.astype(np.float32)))
        return instances

    def corners_at(self, tris, prim, time):
        """(p0, e1, e2) float64 of triangles ``prim`` at each ray's time
        (still rows as Triangles holds them)."""
        p0, e1, e2 = tris.p0[prim].copy(), tris.e1[prim].copy(), tris.e2[prim].copy()
        which = self.part[prim]
        for j in np.unique(which[which >= 0]):
            r = np.flatnonzero(which == j)
            w, _ = self._world(j, prim[r], time[r])
            p0[r], e1[r], e2[r] = w[:, 0], w[:, 1] - w[:, 0], w[:, 2] - w[:, 0]
        return p0, e1, e2

    def _world(self, j, prim, time):
        """World corners (n, 3, 3) of part j's rows ``prim`` at ``time``,
        and the placement's linear part L (n, 3, 3)."""
        part = self.parts[j]
        L, T = transform_at(part.decomposition, time)
        c = _lerp_steps(part.corners, self.slot[prim], time)          # (n, 3, 3) object space
        return np.einsum("nij,nkj->nki", L, c) + T[:, None, :], L

    def at(self, tris, prim, time):
        """(p0, ng, ns) of triangles ``prim`` at each ray's time: float64
        rows as Triangles holds them (ns None when the scene is all flat)."""
        p0, ng = tris.p0[prim], tris.ng[prim]
        ns = tris.ns[prim] if tris.ns is not None else None
        which = self.part[prim]
        for j in np.unique(which[which >= 0]):
            r = np.flatnonzero(which == j)
            part, k, t = self.parts[j], self.slot[prim[r]], time[r]
            w, L = self._world(j, prim[r], t)
            n = np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
            p0[r], ng[r] = w[:, 0], n
            if ns is not None:
                flat = np.repeat(n[:, None, :], 3, axis=1)
                if part.normals is not None:
                    # normals turn with the inverse transpose: its direction is the
                    # cofactor matrix's times the determinant's sign (no inverse of a
                    # singular step, a scale of 0, is taken)
                    a, b, c3 = L[:, :, 0], L[:, :, 1], L[:, :, 2]
                    cof = np.stack([np.cross(b, c3), np.cross(c3, a), np.cross(a, b)], axis=2)
                    cof *= np.where(np.einsum("ni,ni->n", a, np.cross(b, c3)) < 0, -1.0, 1.0)[:, None, None]
                    nn = np.einsum("nij,nkj->nki", cof, _lerp_steps(part.normals, k, t))
                    nn /= np.maximum(np.linalg.norm(nn, axis=2), 1e-300)[..., None]
                    ns[r] = np.where(part.smooth[k][:, None, None], nn, flat)
                else:
                    ns[r] = flat
        return p0, ng, ns


class _AtTime:
    """What engine.hits.hit_geometry reads of Triangles (ng, p0, ns), one row per hit."""

    def __init__(self, p0, ng, ns):
        self.p0, self.ng, self.ns = p0, ng, ns


def triangles_at(motion, tris, prim, time):
    """A stand-in for ``tris`` whose row i is triangle prim[i] at time[i]."""
    return _AtTime(*motion.at(tris, prim, time))


class MotionAccel(Accel):
    """engine.accel.Accel's queries through Embree's C API (engine.embree_c)
    for what embreex cannot trace: moving triangles (``motion``, a
    MotionGeometry: queries take a time per ray, None = the shutter's
    centre) and spheres (``spheres``, engine.points.Spheres rows)."""

    OFFSET = 4 * OFFSET_SCALE   # Embree's float32 interpolation against ours in float64


    def __init__(self, triangles, motion=None, spheres=None, strands=None):
        self.triangles = triangles
        self.motion = motion
        self.empty = len(triangles) == 0
        self._lock = threading.Lock()
        self._totals = {"seconds": 0.0, "rays": 0}
        self.upload = "embree C API"
        if not self.empty:
            special = np.zeros(len(triangles), bool)
            if motion is not None:
                special |= motion.part >= 0
            if spheres is not None:
                special[spheres.rows] = True
            if strands is not None:
                special[strands.rows] = True
            still = np.flatnonzero(~special)
            parts = []
            if len(still):
                corners = triangles.corners_float32()[still]
                parts.append((corners.reshape(1, -1, 3), np.arange(3 * len(corners)).reshape(-1, 3), still))
            points = None
            if spheres is not None and len(spheres):
                k = _still_slots(spheres)
                if len(k):
                    points = (np.concatenate([spheres.centres[k], spheres.radii[k, None]], axis=1), spheres.rows[k])
            instances = motion.embree_instances() if motion is not None else []
            curves = None
            curve_type, shift, rate = _curve_geometry(strands)
            if strands is not None and len(strands):
                k = _still_slots(strands)
                if len(k):
                    curves = (strands.cvs, strands.start[k] + shift, strands.rows[k], rate, curve_type)
                self.self_key = strands.curve   # rays leaving a strand pass all of it
            moving = ([(embree_c.RTC_GEOMETRY_TYPE_SPHERE_POINT, m.steps, None, m.rows, None,
                        m.decomposition.astype(np.float32)) for m in _moving_sets(spheres)]
                      + [(curve_type, m.steps, m.index + shift, m.rows,
                          rate, m.decomposition.astype(np.float32)) for m in _moving_sets(strands)])
            self.scene = embree_c.TriangleScene(parts, instances, points, curves, moving)

    def intersect(self, origins, directions, tmax, time=None):
        n = len(origins)
        if self.empty or n == 0:
            return (np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n), np.zeros(n))
        t0 = _time.perf_counter()
        res = self.scene.intersect(origins, directions, tmax, CENTRE if time is None else time)
        self._account(_time.perf_counter() - t0, n)
        return res

    def occluded(self, origins, directions, tmax, time=None):
        n = len(origins)
        if self.empty or n == 0:
            return np.zeros(n, dtype=bool)
        t0 = _time.perf_counter()
        res = self.scene.occluded(origins, directions, tmax, CENTRE if time is None else time)
        self._account(_time.perf_counter() - t0, n)
        return res

    @classmethod
    def offset_scale(cls, p):
        return cls.OFFSET * (1.0 + np.max(np.abs(p), axis=1))


def _curve_geometry(strands):
    """(Embree curve type, shift of each segment's start, tessellation rate)
    of a points.Strands: round Catmull-Rom curves (Cycles' 3D curves), flat
    ones (its ribbons), or round linear ones (its linear 3D curves) over the
    same padded control points, each segment from its first key (start + 1;
    the padding keeps consecutive segments of one curve consecutive, so
    Embree joins them and caps only the curve's ends); no rate there."""
    if strands is not None and strands.ribbon:
        return embree_c.RTC_GEOMETRY_TYPE_FLAT_CATMULL_ROM_CURVE, 0, strands.rate
    if strands is not None and strands.linear:
        return embree_c.RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE, 1, None
    return embree_c.RTC_GEOMETRY_TYPE_ROUND_CATMULL_ROM_CURVE, 0, getattr(strands, "rate", None)


def _moving_sets(holder):
    """The moving point clouds or curve sets of a points.Spheres / Strands
    (engine.primitive_motion.MovingSet), none when it is None or still."""
    moving = getattr(holder, "moving", None) if holder is not None else None
    return moving.sets if moving else []


def _still_slots(holder):
    """The slots of a Spheres / Strands that do not move."""
    moving = getattr(holder, "moving", None)
    return np.arange(len(holder)) if not moving else np.flatnonzero(moving.part < 0)


def path_time(paths):
    """The paths' times (N,), or None in a still scene (Paths.time is (N, 0))."""
    time = getattr(paths, "time", None)
    if time is None or time.shape[1] == 0:
        return None
    return time[:, 0]
