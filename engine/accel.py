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
import time

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


class Accel:
    def __init__(self, triangles):
        self.triangles = triangles
        self.empty = len(triangles) == 0
        self._lock = threading.Lock()
        self._totals = {"seconds": 0.0, "rays": 0}
        self.upload = None
        if not self.empty:
            self.scene = self._build(triangles)
            # The first run() commits the BVH; do it now, single-threaded.
            self.scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))

    def _build(self, triangles):
        """An EmbreeScene holding the triangles (primID = their index).
        Shared vertices when the triangles have them (fewer to copy), copied
        at memory speed when engine.embree_upload can, else through
        embreex's per-element loop.  ``self.upload`` says which."""
        mc, rs = _import_embreex()
        from embreex import rtcore  # loaded with rtcore_scene (its EmbreeDevice type)
        device = rtcore.EmbreeDevice()
        scene = rs.EmbreeScene(device)
        indexed = getattr(triangles, "indexed_float32", lambda: None)()
        if indexed is None:   # a corner soup: corner k of triangle t is vertex 3 t + k
            corners = triangles.corners_float32()
            vertices = corners.reshape(-1, 3)
            indices = np.arange(len(vertices), dtype=np.int32).reshape(-1, 3)
        else:
            vertices, indices = indexed
        if embree_upload.upload(scene, device, vertices, indices):
            self.upload = "direct"
        else:
            mc.TriangleMesh(scene, *((corners,) if indexed is None else indexed))
            self.upload = "embreex"
        return scene

    # -- timing ---------------------------------------------------------------
    def _account(self, seconds, rays):
        with self._lock:
            self._totals["seconds"] += seconds
            self._totals["rays"] += rays

    def totals(self):
        with self._lock:
            return dict(self._totals)

    # -- queries --------------------------------------------------------------
    def intersect(self, origins, directions, tmax):
        """Closest hits.  Returns (t, prim, u, v); prim = -1 and t = inf on miss."""
        n = len(origins)
        if self.empty or n == 0:
            return (np.full(n, np.inf), np.full(n, -1, np.int64),
                    np.zeros(n), np.zeros(n))
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.minimum(tmax, 1e37).astype(np.float32)
        t0 = time.perf_counter()
        res = self.scene.run(o, d, dists=tfar, query="INTERSECT", output=1)
        self._account(time.perf_counter() - t0, n)
        prim = res["primID"].astype(np.int64)
        hit = prim >= 0
        t = np.where(hit, res["tfar"].astype(np.float64), np.inf)
        return t, prim, res["u"].astype(np.float64), res["v"].astype(np.float64)

    def occluded(self, origins, directions, tmax):
        """True where something lies between the origin and tmax."""
        n = len(origins)
        if self.empty or n == 0:
            return np.zeros(n, dtype=bool)
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.ascontiguousarray(np.maximum(tmax, 0.0), dtype=np.float32)
        t0 = time.perf_counter()
        res = self.scene.run(o, d, dists=tfar, query="OCCLUDED")
        self._account(time.perf_counter() - t0, n)
        return res == 0

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


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:], float64[:, ::1])",
                     _offset_numpy)
def _offset_rows(p, ng, direction, eps, out):
    for i in range(len(p)):
        # einsum's order: x0 + x2, then x1 (engine/vec.py)
        d = (ng[i, 0] * direction[i, 0] + ng[i, 2] * direction[i, 2]) + ng[i, 1] * direction[i, 1]
        side = -eps[i] if d < 0 else eps[i]
        for k in range(3):
            out[i, k] = p[i, k] + ng[i, k] * side
