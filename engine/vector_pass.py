"""The Vector pass: each first hit's screen-space motion (Cycles'
primitive_motion_vector).

Cycles writes it only when motion blur is off; the add-on then exports the
scene at frame - 1, frame and frame + 1 (``vector_motion`` of instances,
meshes and the camera: three steps, the middle one the frame rendered), and
the render stays still.  At a camera ray's first hit the point is carried to
the previous and next step (the same barycentrics on the moved triangle, the
instance's transform there) and projected by the camera at that step:
channels (pre - centre, centre - post) in raster pixels, y up (Cycles'
raster).  Rows that do not move, and the background, hold 0 where the
camera is still.
"""
from types import SimpleNamespace

import numpy as np

from .motion import MotionGeometry, _lerp_steps, transform_at
from .camera import border_window, view_plane

STEPS = (0.0, 0.5, 1.0)   # previous frame, the frame, next frame


def _finite(stack):
    return stack is not None and np.isfinite(np.asarray(stack, np.float64)).all()


def _as_motion(scene):
    """A stand-in of ``scene`` whose ``motion`` fields are its vector steps
    (non-finite steps are dropped: that object is taken as still)."""
    def swap(obj):
        steps = getattr(obj, "vector_motion", None)
        return SimpleNamespace(**{**vars(obj), "motion": steps if _finite(steps) else None,
                                  "motion_normals": None})
    return SimpleNamespace(instances=[swap(i) for i in scene.instances],
                           meshes=[swap(m) for m in scene.meshes])


class VectorMotion:
    """What the Vector pass needs: the moving triangles at the three steps
    and the camera there."""

    def __init__(self, scene, tris):
        proxy = _as_motion(scene)
        geometry = MotionGeometry(proxy, tris)
        self.geometry = geometry if geometry.moving else None
        cam = scene.camera
        steps = getattr(cam, "vector_motion", None)
        base = np.asarray(cam.matrix, np.float64)
        self.cameras = [np.asarray(s, np.float64) for s in steps] if _finite(steps) and len(steps) == 3 \
            else [base, base, base]
        self.x0, self.y0, _, _ = border_window(cam)
        self.xmin, self.ymin, self.pw, self.ph = view_plane(cam)
        self.ortho = cam.kind == "ORTHO"
        self.panoramic = cam.kind not in ("ORTHO", "PERSP")

    def _raster(self, p, step):
        """(N, 2) full-frame raster position (y up) of world points by the camera at ``step``."""
        m = self.cameras[step]
        rot = m[:3, :3] / np.maximum(np.linalg.norm(m[:3, :3], axis=0, keepdims=True), 1e-300)
        local = (p - m[:3, 3]) @ rot
        if self.ortho:
            sx, sy = local[:, 0], local[:, 1]
        else:
            z = np.where(np.abs(local[:, 2]) > 1e-12, -local[:, 2], 1e-12)
            sx, sy = local[:, 0] / z, local[:, 1] / z
        return np.stack([(sx - self.xmin) / self.pw, (sy - self.ymin) / self.ph], axis=1)

    def _corners(self, part, k, step):
        t = np.full(len(k), STEPS[step])
        L, T = transform_at(part.decomposition, t)
        c = _lerp_steps(part.corners, k, t)
        return np.einsum("nij,nkj->nki", L, c) + T[:, None, :]

    def positions(self, p, prim):
        """The hit points ``p`` on triangles ``prim`` at the previous and next steps."""
        pre, post = p.copy(), p.copy()
        g = self.geometry
        if g is None:
            return pre, post
        which = g.part[prim]
        for j in np.unique(which[which >= 0]):
            r = np.flatnonzero(which == j)
            part, k = g.parts[j], g.slot[prim[r]]
            w = self._corners(part, k, 1)
            b = _barycentric(p[r], w)
            pre[r] = np.einsum("nk,nki->ni", b, self._corners(part, k, 0))
            post[r] = np.einsum("nk,nki->ni", b, self._corners(part, k, 2))
        return pre, post

    def vectors(self, p, prim):
        """(N, 4) Cycles' Vector of first hits at ``p`` on triangles ``prim``."""
        if self.panoramic:
            return np.zeros((len(p), 4))
        pre, post = self.positions(p, prim)
        centre = self._raster(p, 1)
        out = np.concatenate([self._raster(pre, 0) - centre, centre - self._raster(post, 2)], axis=1)
        return np.where(np.isfinite(out), out, 0.0)


def _barycentric(p, w):
    """(N, 3) barycentric weights of points ``p`` on triangles ``w`` (N, 3, 3)."""
    e1, e2, d = w[:, 1] - w[:, 0], w[:, 2] - w[:, 0], p - w[:, 0]
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d20, d21 = (d * e1).sum(1), (d * e2).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-300, den, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    u = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - u, v, u], axis=1)


def wanted(scene, passes):
    """Whether a render needs VectorMotion: the Vector pass on and the scene
    still (motion blur on: Cycles writes no Vector)."""
    from .motion import has_motion
    return "Vector" in (passes or ()) and not has_motion(scene)
