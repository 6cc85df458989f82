"""Ray casting through Intel Embree (embreex).

One EmbreeScene holds every world-space triangle (primID = index into
``geometry.Triangles``).  embreex fixes tnear at 0, so callers offset ray
origins with ``offset_origin``; shadow rays get a shortened tfar.

``run()`` releases the GIL for the whole batch, so queries from several
threads run in parallel; this module records the wall time spent inside
embreex per thread so the benchmark can report Embree's share.
"""
import os
import sys
import threading
from time import perf_counter

import numpy as np

from . import embree_upload, kernels
from .vec import column, row_max, rows3


def _import_embreex():
    # Blender 3.4 links its own libembree3 globally; without DEEPBIND the
    # embreex extension binds to it and crashes building a scene.
    old = sys.getdlopenflags()
    try:
        sys.setdlopenflags(os.RTLD_NOW | os.RTLD_DEEPBIND)
        from embreex import mesh_construction, rtcore_scene
    finally:
        sys.setdlopenflags(old)
    return mesh_construction, rtcore_scene


OFFSET_SCALE = 1e-5


class BuiltScenes:
    """The last BVH built, kept for Blender's Persistent Data: the next
    render that traces the same triangles (same float32 vertices and
    indices, compared by a hash of their bytes) reuses it instead of
    building again.  One entry: an animation's frames follow each other."""

    def __init__(self):
        self._lock = threading.Lock()
        self.key = self.entry = None
        self.hits = self.builds = 0

    def get(self, vertices, indices, build):
        key = _geometry_hash(vertices, indices)
        with self._lock:
            if self.key == key:
                self.hits += 1
                return self.entry
        entry = build()
        with self._lock:
            self.key, self.entry = key, entry
            self.builds += 1
        return entry

    def clear(self):
        with self._lock:
            self.key = self.entry = None


def _geometry_hash(vertices, indices):
    import hashlib
    h = hashlib.blake2b(digest_size=16)
    for a in (vertices, indices):
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(memoryview(a).cast("B"))
    return h.digest()


def _geometry_arrays(triangles):
    """(float32 vertices, int32 indices, the corner soup or None): shared
    vertices when the triangles have them (fewer to copy), else a corner
    soup, corner k of triangle t being vertex 3 t + k."""
    indexed = getattr(triangles, "indexed_float32", lambda: None)()
    if indexed is not None:
        return indexed[0], indexed[1], None
    corners = triangles.corners_float32()
    vertices = corners.reshape(-1, 3)
    return vertices, np.arange(len(vertices), dtype=np.int32).reshape(-1, 3), corners


# The process's persistent BVH (engine.render.prepare passes it when
# RenderSettings.persistent is on, and clears it when a render is not).
PERSISTENT = BuiltScenes()


class Accel:
    def __init__(self, triangles, reuse=None):
        """``reuse``: a BuiltScenes whose BVH serves if it holds the same
        triangles (``self.reused`` says whether it did)."""
        self.triangles = triangles
        self.empty = len(triangles) == 0
        self._lock = threading.Lock()
        self._totals = {"seconds": 0.0, "rays": 0}
        self.upload = None
        self.reused = False
        if not self.empty:
            vertices, indices, corners = _geometry_arrays(triangles)
            if reuse is None:
                self.scene, self.upload = self._build(vertices, indices, corners)
            else:
                built = []
                self.scene, self.upload = reuse.get(vertices, indices, lambda: built.append(1) or
                                                    self._build(vertices, indices, corners))
                self.reused = not built

    @staticmethod
    def _build(vertices, indices, corners):
        """An EmbreeScene holding the triangles (primID = their index), and
        how it was filled: copied at memory speed when engine.embree_upload
        can ("direct"), else through embreex's per-element loop."""
        mc, rs = _import_embreex()
        from embreex import rtcore  # loaded with rtcore_scene (its EmbreeDevice type)
        device = rtcore.EmbreeDevice()
        scene = rs.EmbreeScene(device)
        if embree_upload.upload(scene, device, vertices, indices):
            upload = "direct"
        else:
            mc.TriangleMesh(scene, *((corners,) if corners is not None else (vertices, indices)))
            upload = "embreex"
        # The first run() commits the BVH; do it now, single-threaded.
        scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))
        return scene, upload

    # -- timing ---------------------------------------------------------------
    def _account(self, seconds, rays):
        with self._lock:
            self._totals["seconds"] += seconds
            self._totals["rays"] += rays

    def totals(self):
        with self._lock:
            return dict(self._totals)

    # -- queries --------------------------------------------------------------
    def intersect(self, origins, directions, tmax, time=None):
        """Closest hits.  Returns (t, prim, u, v); prim = -1 and t = inf on miss.
        ``time``: the rays' shutter times, which a still scene ignores
        (engine.motion.MotionAccel reads them)."""
        n = len(origins)
        if self.empty or n == 0:
            return (np.full(n, np.inf), np.full(n, -1, np.int64),
                    np.zeros(n), np.zeros(n))
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.minimum(tmax, 1e37).astype(np.float32)
        t0 = perf_counter()
        res = self.scene.run(o, d, dists=tfar, query="INTERSECT", output=1)
        self._account(perf_counter() - t0, n)
        prim = res["primID"].astype(np.int64)
        hit = prim >= 0
        t = np.where(hit, res["tfar"].astype(np.float64), np.inf)
        return t, prim, res["u"].astype(np.float64), res["v"].astype(np.float64)

    def occluded(self, origins, directions, tmax, time=None):
        """True where something lies between the origin and tmax (``time``: as intersect)."""
        n = len(origins)
        if self.empty or n == 0:
            return np.zeros(n, dtype=bool)
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.ascontiguousarray(np.maximum(tmax, 0.0), dtype=np.float32)
        t0 = perf_counter()
        res = self.scene.run(o, d, dists=tfar, query="OCCLUDED")
        self._account(perf_counter() - t0, n)
        return res == 0

    # -- Cycles' self-intersection rule for curves ------------------------------
    # A ray leaving a strand passes every hit on that strand (Cycles'
    # intersection_skip_self: ray->self.prim is the curve, every segment of it
    # maps to it, kernel/device/cpu/bvh.h): a transmitted or light-sampled ray
    # goes through the strand it starts on, a reflected one never meets it
    # again, whatever its shape.  ``skip`` (N,): the key each ray leaves (-1:
    # none); a hit's key is ``self_key[prim]`` (MotionAccel: the curve of a
    # segment row, -1 elsewhere), or the row itself without one.  A ray may
    # meet its own strand several times (a curl): up to SELF_SKIPS, past
    # them the hit counts.
    SELF_SKIPS = 8
    self_key = None

    def _own(self, prim, skip):
        key = prim if self.self_key is None else self.self_key[np.maximum(prim, 0)]
        return (prim >= 0) & (skip >= 0) & (key == skip)

    def intersect_skipping(self, origins, directions, tmax, skip, time=None):
        """``intersect`` passing each ray's own row ``skip``; t is measured
        from the original origins."""
        t, prim, u, v = self.intersect(origins, directions, tmax, time=time)
        again = np.flatnonzero(self._own(prim, skip))
        if len(again) == 0:
            return t, prim, u, v
        t, prim, u, v = t.copy(), prim.copy(), u.copy(), v.copy()
        o = np.asarray(origins, np.float64)
        d = np.asarray(directions, np.float64)
        for _ in range(self.SELF_SKIPS):
            # go on from just past the self hit (its row is passed again anyway)
            p = o[again] + d[again] * t[again, None]
            step = t[again] + self.offset_scale(p)
            tn, pn, un, vn = self.intersect(o[again] + d[again] * step[:, None], d[again],
                                            np.maximum(tmax[again] - step, 0.0),
                                            time=None if time is None else time[again])
            t[again] = np.where(pn >= 0, tn + step, np.inf)
            prim[again], u[again], v[again] = pn, un, vn
            again = again[self._own(pn, skip[again])]
            if len(again) == 0:
                break
        return t, prim, u, v

    def occluded_skipping(self, origins, directions, tmax, skip, time=None):
        """``occluded`` passing each ray's own row ``skip``: blocked rays
        leaving a row are traced again to see what blocks them."""
        blocked = self.occluded(origins, directions, tmax, time=time)
        rows = np.flatnonzero(blocked & (skip >= 0))
        if len(rows):
            _, prim, _, _ = self.intersect_skipping(origins[rows], directions[rows], tmax[rows], skip[rows],
                                                    time=None if time is None else time[rows])
            blocked[rows] = prim >= 0
        return blocked

    @staticmethod
    def offset_scale(p):
        """How far to move a point off its surface.  Embree sees float32
        vertices: the surface it hits can sit a few ulps of the coordinate
        magnitude away from our float64 point."""
        return OFFSET_SCALE * (1.0 + row_max(np.abs(p)))

    def offset_origin(self, p, ng, direction, eps=None):
        """Move p off its surface to the side ``direction`` leaves through."""
        if eps is None:
            eps = self.offset_scale(p)
        rows = rows3(p, ng, direction)
        if rows is None:
            side = np.where(np.einsum("ij,ij->i", ng, direction) < 0, -eps, eps)
            return p + ng * side[:, None]
        out = np.empty(rows[0].shape)
        _offset_rows(*rows, column(eps, len(out), np.float64), out)
        return out


def _offset_numpy(p, ng, direction, eps, out):
    side = np.where(np.einsum("ij,ij->i", ng, direction) < 0, -eps, eps)
    out[:] = p + ng * side[:, None]


@kernels.helper
def _lifted(p, ng, direction, r, eps):
    """Row r of ``_offset_numpy``'s result in compiled loops: x, y, z."""
    # einsum's order: x0 + x2, then x1 (engine/vec.py)
    d = (ng[r, 0] * direction[r, 0] + ng[r, 2] * direction[r, 2]) + ng[r, 1] * direction[r, 1]
    side = -eps if d < 0 else eps
    return p[r, 0] + ng[r, 0] * side, p[r, 1] + ng[r, 1] * side, p[r, 2] + ng[r, 2] * side


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:], float64[:, ::1])",
                     _offset_numpy)
def _offset_rows(p, ng, direction, eps, out):
    for i in range(len(p)):
        out[i, 0], out[i, 1], out[i, 2] = _lifted(p, ng, direction, i, eps[i])


# -- shadow rays ---------------------------------------------------------------
# A light sample's shadow ray, for the rows of a batch that need one: the
# origin lifted off the surface, the direction (re-aimed at the sampled point
# itself for points on triangles) and how far it may go.  One loop gathers
# the rows and writes the float32 arrays Embree reads, instead of a dozen
# (N, 3) gathers, copies and casts.

def shadow_rays(p, ng, wi, dist, on, eps, rows):
    """float64 (origin, direction, tmax) of the shadow rays from p[rows]
    towards lights sampled in directions wi at distances dist (inf: a sun);
    ``on``: the sampled point lies on a triangle, which would block its own
    ray, so the ray stops 10 eps short of it; eps: each row's origin offset."""
    e = eps[rows]
    pr, wr = p[rows], wi[rows]
    origin = np.empty(pr.shape)
    _offset_numpy(pr, ng[rows], wr, e, origin)
    d, w, onr = dist[rows], wr, on[rows]
    if onr.any():
        # Aim from the offset origin at the sampled point itself: parallel to
        # wi, a ray raised by eps meets a grazing emitter's plane eps / sin
        # before the point, past any shortening, and is blocked by it.
        v = (pr[onr] + w[onr] * d[onr, None]) - origin[onr]
        d, w = d.copy(), w.copy()
        d[onr] = np.linalg.norm(v, axis=1)
        w[onr] = v / np.maximum(d[onr], 1e-30)[:, None]
    shorten = np.where(onr, 10.0 * e, 0.0)
    tmax = np.where(np.isfinite(d), d * (1.0 - 1e-6) - shorten, 1e37)
    return origin, w, tmax


def _shadow_rays_numpy(p, ng, wi, dist, on, eps, rows, o, d, tfar):
    origin, w, tmax = shadow_rays(p, ng, wi, dist, on, eps, rows)
    o[:], d[:], tfar[:] = origin, w, np.maximum(tmax, 0.0)


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], boolean[::1], "
                     "float64[::1], int64[::1], float32[:, ::1], float32[:, ::1], float32[::1])",
                     _shadow_rays_numpy)
def _shadow_rays_loop(p, ng, wi, dist, on, eps, rows, o, d, tfar):
    for i in range(len(rows)):
        r = rows[i]
        e = eps[r]
        ox, oy, oz = _lifted(p, ng, wi, r, e)
        t = dist[r]
        wx, wy, wz = wi[r, 0], wi[r, 1], wi[r, 2]
        shorten = 0.0
        if on[r]:
            vx = (p[r, 0] + wx * t) - ox
            vy = (p[r, 1] + wy * t) - oy
            vz = (p[r, 2] + wz * t) - oz
            t = np.sqrt((vx * vx + vy * vy) + vz * vz)   # np.linalg.norm's order
            inv = max(t, 1e-30)
            wx, wy, wz = vx / inv, vy / inv, vz / inv
            shorten = 10.0 * e
        tmax = t * (1.0 - 1e-6) - shorten if np.isfinite(t) else 1e37
        if tmax < 0.0:
            tmax = 0.0
        o[i, 0], o[i, 1], o[i, 2] = ox, oy, oz
        d[i, 0], d[i, 1], d[i, 2] = wx, wy, wz
        tfar[i] = tmax


def shadow_rays_f32(p, ng, wi, dist, on, eps, rows):
    """``shadow_rays`` as the float32 (origin, direction, tfar >= 0) that
    Embree reads, in one compiled loop."""
    n = len(rows)
    o, d, tfar = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32), np.empty(n, np.float32)
    _shadow_rays_loop(*rows3(p, ng, wi), column(dist, len(p), np.float64), np.ascontiguousarray(on, bool),
                      column(eps, len(p), np.float64), np.ascontiguousarray(rows, np.int64), o, d, tfar)
    return o, d, tfar
