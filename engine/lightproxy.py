"""Broad phase for BSDF rays meeting analytic lights (point, spot, area).

``LightSet.intersect`` tests every ray against every light, exactly, in
float64: one light at a time over all rays, so its cost grows with rays x
lights (64 small lights: 40 % of a frame).  Most rays pass far from every
light.  Here each light gets a closed box around it (a parallelepiped of 12
triangles) in a small Embree scene of its own; one occlusion query per ray
tells which rays can meet a light at all, and only those go through the
exact tests.  The boxes are enlarged a little (relative 1e-3, plus an
absolute margin for float32), so no ray that meets a light is dropped: the
proxies only choose which rays are tested, never the answer.
"""
import numpy as np

from .accel import _import_embreex

# With fewer lights the exact tests on every ray cost about what one
# Embree query does.
MIN_LIGHTS = 3
GROW = 1e-3
# The 12 triangles of a box from its corners numbered by bits (x, y, z).
_FACES = np.array([
    (0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5),   # two per face: the faces where one bit is fixed
    (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
    (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)])


def _box_corners(centre, axes):
    """(8, 3) corners centre +- a0 +- a1 +- a2 (axes: (3, 3) half-edge rows)."""
    signs = np.array([[(k >> 2) & 1, (k >> 1) & 1, k & 1] for k in range(8)], float) * 2.0 - 1.0
    return centre + signs @ axes


def _margin(centre, size):
    return GROW * size + 1e-5 * (1.0 + np.abs(centre).max())


def point_light_boxes(points):
    """Boxes around sphere and disk lights (a disk faces the shading point,
    so it lies in the sphere of its radius too); lights of radius 0 cannot
    be hit and get none."""
    boxes = []
    for j in range(points.count):
        r = points.radius[j]
        if r > 0:
            half = r + _margin(points.pos[j], r)
            boxes.append(_box_corners(points.pos[j], np.eye(3) * half))
    return boxes


def area_light_boxes(areas):
    """Thin boxes around rectangles, squares, disks and ellipses.  The exact
    test (lights._AreaLights.intersect) meets the plane through c normal to
    the light's n, and accepts a point q when its projections on the unit
    axes of u and v stay within half their lengths: the parallelogram
    +-a e1 +-b e2 of that plane, with (e1, e2) dual to those axes (u x v
    itself unless the light's matrix is sheared).  Ellipses lie inside it."""
    boxes = []
    for j in range(areas.count):
        u, v, c, n = areas.u[j], areas.v[j], areas.c[j], areas.n[j]
        lu, lv = np.linalg.norm(u), np.linalg.norm(v)
        frame = np.array([u / max(lu, 1e-300), v / max(lv, 1e-300), n])
        if lu <= 0 or lv <= 0 or abs(np.linalg.det(frame)) < 1e-9:
            continue   # degenerate: the exact test finds no hit either
        dual = np.linalg.inv(frame)   # columns e1, e2 (in the plane) and n'
        corners = np.array([s * 0.5 * lu * dual[:, 0] + t * 0.5 * lv * dual[:, 1]
                            for s in (-1, 1) for t in (-1, 1)])
        ax = dual[:, 0] / np.linalg.norm(dual[:, 0])
        ay = np.cross(n, ax)
        half_x, half_y = np.abs(corners @ ax).max(), np.abs(corners @ ay).max()
        pad = _margin(c, max(half_x, half_y))
        boxes.append(_box_corners(c, np.array([ax * (half_x + pad), ay * (half_y + pad), n * pad])))
    return boxes


class LightProxies:
    """An Embree scene of boxes around the lights; ``candidates`` says which
    rays may meet one before tmax."""

    def __init__(self, boxes):
        corners = np.concatenate([box[_FACES] for box in boxes]).astype(np.float32)
        # Longer than any box's diagonal: a ray that starts inside a box is
        # traced from this far behind its origin, so it enters the box.
        self.reach = 1.01 * max(np.linalg.norm(box[7] - box[0]) for box in boxes)
        mc, rs = _import_embreex()
        self.scene = rs.EmbreeScene()
        mc.TriangleMesh(self.scene, corners)
        self.scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # build now

    @classmethod
    def for_lights(cls, points, areas):
        """Proxies when there are enough lights to pay for them, else None."""
        boxes = point_light_boxes(points) + area_light_boxes(areas)
        return cls(boxes) if len(boxes) >= MIN_LIGHTS else None

    def candidates(self, o, d, tmax):
        """True where the segment from o to o + tmax d meets a box (with
        margin).  The segment is extended back by ``reach``, so one that
        starts inside a box counts (it may meet the light before leaving
        the box); boxes just behind the origin are false alarms, harmless."""
        n = len(o)
        if n == 0:
            return np.zeros(0, bool)
        tmax = np.broadcast_to(np.minimum(tmax, 1e37), (n,))
        tfar = np.minimum((tmax + self.reach) * (1.0 + 1e-5) + 1e-5, 1e37)
        start = o - d * self.reach
        res = self.scene.run(np.ascontiguousarray(start, dtype=np.float32),
                             np.ascontiguousarray(d, dtype=np.float32),
                             dists=np.ascontiguousarray(tfar, dtype=np.float32), query="OCCLUDED")
        return res == 0
