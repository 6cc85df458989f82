"""The Vector pass: each first hit's screen-space motion (Cycles'
primitive_motion_vector).

Cycles writes it only when motion blur is off; the add-on then exports the
scene at frame - 1, frame and frame + 1 (``vector_motion`` of instances,
meshes and the camera: three steps, the middle one the frame rendered), and
the render stays still.  At a camera ray's first hit the point is carried to
the previous and next step (the same barycentrics on the moved triangle, the
instance's transform there) and projected by the camera at that step:
channels (pre - centre, centre - post) in raster pixels, y up (Cycles'
raster; a panoramic camera's (u, v) of the direction to the point times
the frame's size).  Rows that do not move, and the background, hold 0 where the
camera is still.

Points and curves follow the same rule with Cycles' centre for them: a
point's hit is carried as the point's centre (``point_motion_center_location``)
and a curve's as the point of its segment's two keys mixed linearly by
Embree's u (``curve_motion_center_location``), at the frame and at the
steps (``vector_motion`` of a cloud or curve set: object-to-world at the
three steps; ``vector_positions``: its points or keys there, deformation).
The vector of a strand is thus the same across its width, as Cycles'.
Steps that are not finite as float32 (what Blender can hold) are dropped:
that item is taken as still and named in ``warnings``.
"""
from types import SimpleNamespace

import numpy as np

from .motion import MotionGeometry, _lerp_steps, transform_at
from .camera import border_window, view_plane
from .panorama import Panorama
from .points import padded_index

STEPS = (0.0, 0.5, 1.0)   # previous frame, the frame, next frame
# Vectors beyond this many pixels (only hostile steps give them) are written
# as 0: the film sums float32, where they would overflow to infinity.
LIMIT = 1e30


def _finite(stack):
    """Whether steps are given and finite in float32 (1e300 is not)."""
    if stack is None:
        return False
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(np.asarray(stack, np.float64).astype(np.float32)).all())


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
    """What the Vector pass needs: the moving triangles at the three steps,
    the points' centres and the curves' keys there, and the camera there.
    ``primitives``: (spheres, point owners, clouds, strands, curve owners)
    as engine/render.py prepares them, or None."""

    def __init__(self, scene, tris, primitives=None):
        self.warnings = []
        self.spheres = self.strands = None
        if primitives is not None:
            self._primitives(tris, *primitives)
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
        # Panoramic cameras: Cycles projects by direction_to_panorama (u, v)
        # times the frame's size, with no shift (primitive_motion_vector).
        self.pano = Panorama(cam) if cam.kind == "PANO" else None
        self.size = float(cam.resolution[0]), float(cam.resolution[1])

    def _primitives(self, tris, spheres, point_owners, clouds, strands, curve_owners):
        """World (pre, post) of each sphere's centre and each strand key."""
        if spheres is not None:
            pre, post = spheres.centres.copy(), spheres.centres.copy()
            owner, local = tris.shading.instance, tris.shading.local
            for inst_index, cloud in zip(point_owners, clouds):
                steps = self._world_steps(cloud, "point cloud", cloud.positions)
                if steps is not None:
                    mine = np.flatnonzero(owner == inst_index)
                    pre[spheres.slot[mine]], post[spheres.slot[mine]] = steps[0][local[mine]], steps[2][local[mine]]
            self.spheres = (spheres, pre, post)
        if strands is not None:
            pre, post = strands.cvs[:, :3].copy(), strands.cvs[:, :3].copy()
            base = 0
            for _, curves in curve_owners:
                index = padded_index(np.asarray(curves.offsets, np.int64))   # the keys as strands_of lays them out
                steps = self._world_steps(curves, "curves", curves.points)
                if steps is not None:
                    pre[base:base + len(index)], post[base:base + len(index)] = steps[0][index], steps[2][index]
                base += len(index)
            self.strands = (strands, pre, post)

    def _world_steps(self, item, kind, points):
        """(3, N, 3) world positions of an item's points at the three steps,
        or None when it does not move (or its steps are dropped)."""
        matrices = getattr(item, "vector_motion", None)
        positions = getattr(item, "vector_positions", None)
        if matrices is None and positions is None:
            return None
        if (matrices is not None and not _finite(matrices)) or (positions is not None and not _finite(positions)):
            self.warnings.append(f"{kind} {item.name!r}: its Vector steps are NaN or infinite, "
                                 "its Vector pass is the camera's motion alone")
            return None
        points = np.asarray(points, np.float64)
        matrices = (np.repeat(np.asarray(item.matrix, np.float64)[None], 3, axis=0) if matrices is None
                    else np.asarray(matrices, np.float64))
        positions = np.repeat(points[None], 3, axis=0) if positions is None else np.asarray(positions, np.float64)
        return np.einsum("sij,snj->sni", matrices[:, :3, :3], positions) + matrices[:, None, :3, 3]

    def _raster(self, p, step):
        """(N, 2) full-frame raster position (y up) of world points by the camera at ``step``."""
        m = self.cameras[step]
        rot = m[:3, :3] / np.maximum(np.linalg.norm(m[:3, :3], axis=0, keepdims=True), 1e-300)
        local = (p - m[:3, 3]) @ rot
        if self.pano is not None:
            u, v = self.pano.from_direction(self.pano.from_local(local))
            return np.stack([u * self.size[0], v * self.size[1]], axis=1)
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

    def centres(self, p, prim, u=None):
        """(centre, pre, post) world points of first hits at ``p`` on rows
        ``prim`` (triangles, points or curve segments at Embree's ``u``)."""
        centre = np.array(p, np.float64, copy=True)
        pre, post = self.positions(p, prim)
        if self.spheres is not None:
            spheres, pre_c, post_c = self.spheres
            on = np.flatnonzero(spheres.is_point[prim])
            k = spheres.slot[prim[on]]
            centre[on], pre[on], post[on] = spheres.centres[k], pre_c[k], post_c[k]
        if self.strands is not None:
            strands, pre_k, post_k = self.strands
            on = np.flatnonzero(strands.is_curve[prim])
            k0 = strands.start[strands.slot[prim[on]]] + 1          # the segment's first key
            a = np.clip(np.zeros(len(on)) if u is None else np.asarray(u, np.float64)[on], 0.0, 1.0)[:, None]
            for out, keys in ((centre, strands.cvs[:, :3]), (pre, pre_k), (post, post_k)):
                out[on] = (1.0 - a) * keys[k0] + a * keys[k0 + 1]
        return centre, pre, post

    def vectors(self, p, prim, u=None):
        """(N, 4) Cycles' Vector of first hits at ``p`` on rows ``prim``
        (``u``: Embree's curve parameter of curve hits)."""
        centre, pre, post = self.centres(p, np.asarray(prim, np.int64), u)
        with np.errstate(over="ignore", invalid="ignore"):
            at = self._raster(centre, 1)
            out = np.concatenate([self._raster(pre, 0) - at, at - self._raster(post, 2)], axis=1)
        return np.where(np.isfinite(out) & (np.abs(out) <= LIMIT), out, 0.0)


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
