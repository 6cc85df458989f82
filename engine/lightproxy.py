"""Broad phase for BSDF rays meeting analytic lights (point, spot, area:
each light type's ``proxy_boxes`` says where its lights are).

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


def box_corners(centre, axes):
    """(8, 3) corners centre +- a0 +- a1 +- a2 (axes: (3, 3) half-edge rows)."""
    signs = np.array([[(k >> 2) & 1, (k >> 1) & 1, k & 1] for k in range(8)], float) * 2.0 - 1.0
    return centre + signs @ axes


def proxy_margin(centre, size):
    """How much a box around a light of this size at centre grows."""
    return GROW * size + 1e-5 * (1.0 + np.abs(centre).max())


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
    def for_lights(cls, tables):
        """Proxies around every light of the light tables (each type's
        ``proxy_boxes``) when there are enough to pay for them, else None."""
        boxes = [box for table in tables for box in table.proxy_boxes()]
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
