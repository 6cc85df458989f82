"""Light bounds (pbrt-v4 LightBounds): what the light tree knows of an
emitter or a node of emitters.  Plain data with its union: each light type
(engine/lights/) computes its own bounds, the tree (engine/lighttree.py)
reads them, and neither imports the other."""
import math

import numpy as np


class Bounds:
    """Light bounds of one emitter or node: a box, the power phi, an
    orientation cone (axis w, cos theta_o of the normals' spread, cos
    theta_e of the emission about a normal) and whether both sides emit.
    ``rect``: an area light's (centre, full edge u, full edge v), which the
    tree tests as Cycles does at points without transmission (None: none)."""

    def __init__(self, lo, hi, phi, w, cos_o, cos_e, two_sided, rect=None):
        self.rect = rect
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.phi = float(phi)
        self.w = np.asarray(w, float)
        self.cos_o, self.cos_e, self.two_sided = float(cos_o), float(cos_e), bool(two_sided)
        self.center = 0.5 * (self.lo + self.hi)

    def centroid(self):
        return self.center


def union(a, b):
    if a.phi <= 0:
        return b
    if b.phi <= 0:
        return a
    w, cos_o = _cone_union(a.w, a.cos_o, b.w, b.cos_o)
    return Bounds(np.minimum(a.lo, b.lo), np.maximum(a.hi, b.hi), a.phi + b.phi, w, cos_o,
                  min(a.cos_e, b.cos_e), a.two_sided or b.two_sided)


def _cone_union(wa, cos_a, wb, cos_b):
    """Smallest cone holding two direction cones (pbrt-v4 DirectionCone Union).
    Scalar maths: called once per tree node, where NumPy's per-call cost
    on 3-vectors would dominate building trees over many triangles."""
    ax, ay, az = float(wa[0]), float(wa[1]), float(wa[2])
    bx, by, bz = float(wb[0]), float(wb[1]), float(wb[2])
    theta_a, theta_b = math.acos(min(max(cos_a, -1.0), 1.0)), math.acos(min(max(cos_b, -1.0), 1.0))
    theta_d = math.acos(min(max(ax * bx + ay * by + az * bz, -1.0), 1.0))
    if min(theta_d + theta_b, math.pi) <= theta_a:
        return wa, cos_a
    if min(theta_d + theta_a, math.pi) <= theta_b:
        return wb, cos_b
    theta_o = 0.5 * (theta_a + theta_d + theta_b)
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    length = math.sqrt(cx * cx + cy * cy + cz * cz)
    if theta_o >= math.pi or length == 0:
        return wa, -1.0
    cx, cy, cz = cx / length, cy / length, cz / length
    theta_r = theta_o - theta_a
    # Rodrigues: rotate wa by theta_r about the axis (perpendicular to wa).
    c, sn = math.cos(theta_r), math.sin(theta_r)
    w = np.array([ax * c + (cy * az - cz * ay) * sn, ay * c + (cz * ax - cx * az) * sn,
                  az * c + (cx * ay - cy * ax) * sn])
    return w / math.sqrt(w @ w), math.cos(theta_o)


def triangle_bounds(tris, members):
    """Bounds of each emissive triangle of ``members`` (for a tree over one
    mesh group's triangles): power by area (a group shares its emission),
    two-sided Lambertian emission about each normal."""
    p0 = tris.p0[members]
    p1, p2 = p0 + tris.e1[members], p0 + tris.e2[members]
    lo = np.minimum(np.minimum(p0, p1), p2)
    hi = np.maximum(np.maximum(p0, p1), p2)
    area, ng = tris.area[members], tris.ng[members]
    return [Bounds(lo[k], hi[k], area[k], ng[k], 1.0, 0.0, True) for k in range(len(members))]
