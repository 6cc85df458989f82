"""Shading data of hair curves: what the Curves Info node, the Attribute,
Color Attribute and UV Map nodes read on a strand (Cycles' blender/curves.cpp
export_hair_curves / sync_particle_hair and kernel/geom/curve.h).

A curve set is traced as stand-in rows, one per segment (engine.points); a
segment's corners here are (its first key, its second key, its first key
again), so the shading context's barycentric interpolation (1 - u - v) c0 +
u c1 + v c2 is Cycles' linear mix of the two keys by the curve parameter u
(curve_attribute for ATTR_ELEMENT_CURVE_KEY) whatever v is.  Per-curve values
(ATTR_ELEMENT_CURVE) are constant along the strand.

The corners are made on first use (``LazyCorners``): 100k strands of 8
segments cost 19 MB per float attribute, paid only by scenes whose
materials read it.
"""
from collections.abc import Mapping

import numpy as np

from .nodes.context import (CURVE_INTERCEPT, CURVE_LENGTH, CURVE_RANDOM, CURVE_THICKNESS, IS_RIBBON, IS_STRAND,
                            POSITION_TEXSPACE)
from .nodes.hashing import hash_uint, to_float


class LazyCorners(Mapping):
    """{name: (S, 3, C) corners}, each computed by its maker when first read."""

    def __init__(self, makers):
        self._makers, self._made = dict(makers), {}

    def __getitem__(self, name):
        if name not in self._made:
            self._made[name] = self._makers[name]()
        return self._made[name]

    def __iter__(self):
        return iter(self._makers)

    def __len__(self):
        return len(self._makers)


def _columns(values, n):
    """(n, C) float64 of an attribute's values ((n,) reads as one column)."""
    a = np.asarray(values, np.float64)
    return a.reshape(n, -1)


class SegmentCorners:
    """Corner data of one curve set's segments (the stand-in rows, in
    engine.points.segment_starts order)."""

    def __init__(self, strands):
        self.offsets = np.asarray(strands.offsets, np.int64)
        first, last = self.offsets[:-1], self.offsets[1:]
        self.count = np.maximum(last - first - 1, 0)     # segments per curve
        self.curve = np.repeat(np.arange(len(first)), self.count)
        self.key = first[self.curve] + np.arange(self.count.sum()) - np.repeat(np.cumsum(self.count) - self.count,
                                                                                self.count)

    def of_points(self, values):
        """(S, 3, C) of per-key values (N, C): the segment's two keys."""
        v = _columns(values, self.offsets[-1])
        return np.stack([v[self.key], v[self.key + 1], v[self.key]], axis=1)

    def of_curves(self, values):
        """(S, 3, C) of per-curve values (C_curves, C), the same at every corner."""
        v = _columns(values, len(self.offsets) - 1)[self.curve]
        return np.repeat(v[:, None, :], 3, axis=1)


def intercepts_and_lengths(points, offsets):
    """(per key: arc length from the root over the curve's length, 0 where
    that is 0; per curve: its length), along the control polygon in object
    space, as Cycles' export (not along the spline)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    offsets = np.asarray(offsets, np.int64)
    step = np.zeros(len(p))
    if len(p) > 1:
        step[1:] = np.linalg.norm(p[1:] - p[:-1], axis=1)
    step[offsets[:-1][offsets[:-1] < len(p)]] = 0.0     # no step into a curve's first key
    run = np.cumsum(step)
    base = np.repeat(run[offsets[:-1]] if len(p) else np.zeros(0), np.diff(offsets))
    along = run - base
    length = along[offsets[1:] - 1] if len(p) else np.zeros(0)
    per_key = np.repeat(length, np.diff(offsets))
    with np.errstate(invalid="ignore", divide="ignore"):
        intercept = np.where(per_key > 0, along / np.where(per_key > 0, per_key, 1.0), 0.0)
    return intercept, length


def curve_randoms(n_curves, first_curve=0):
    """Cycles' ATTR_STD_CURVE_RANDOM: hash_uint2_to_float(curve index, 0),
    the index counted over the curves of one Cycles Hair (all particle
    systems of an emitter)."""
    index = np.arange(n_curves, dtype=np.int64) + int(first_curve)
    return to_float(hash_uint(index, np.zeros_like(index))).astype(np.float64)


def world_scale(matrix):
    """The radius scale of a transform, cbrt|det| (Cycles' Hair::apply_transform)."""
    m = np.asarray(matrix, np.float64)
    return abs(np.linalg.det(m[:3, :3])) ** (1.0 / 3.0)


def corner_attributes(strands, ribbons=False):
    """The stand-in mesh's attributes of a curve set: the user's point and
    curve attributes by name, and the Curves Info node's reserved ones
    (``ribbons``: the set is traced as ribbons, IS_RIBBON)."""
    seg = SegmentCorners(strands)
    n_curves = len(seg.offsets) - 1
    # (intercept, length) computed once for both makers that need them
    shape = {}

    def shape_data():
        if not shape:
            shape["value"] = intercepts_and_lengths(strands.points, strands.offsets)
        return shape["value"]

    makers = {
        IS_STRAND: lambda: np.ones((len(seg.key), 3, 1)),
        IS_RIBBON: lambda: np.full((len(seg.key), 3, 1), 1.0 if ribbons else 0.0),
        CURVE_INTERCEPT: lambda: seg.of_points(shape_data()[0]),
        CURVE_LENGTH: lambda: seg.of_curves(shape_data()[1]),
        CURVE_RANDOM: lambda: seg.of_curves(curve_randoms(n_curves, getattr(strands, "first_curve", 0))),
        CURVE_THICKNESS: lambda: seg.of_points(2.0 * np.asarray(strands.radii, np.float64)
                                               * world_scale(strands.matrix)),
    }
    for name, values in (getattr(strands, "point_attributes", None) or {}).items():
        makers[name] = (lambda v=values: seg.of_points(v))
    for name, values in (getattr(strands, "curve_attributes", None) or {}).items():
        makers.setdefault(name, lambda v=values: seg.of_curves(v))
    return LazyCorners(makers)


def uv_maps(strands):
    """(active UV corners or None, {name: corners}) of a curve set's 2-column
    attributes: what the UV Map node and image textures read on strands
    (Cycles: a Curves object's first float2 curve attribute is its UV map;
    particle hair carries the emitter's UV maps per strand)."""
    seg = SegmentCorners(strands)
    maps = {}
    for domain, corners in (("point_attributes", seg.of_points), ("curve_attributes", seg.of_curves)):
        for name, values in (getattr(strands, domain, None) or {}).items():
            a = np.asarray(values)
            if a.ndim == 2 and a.shape[1] == 2 and name not in maps:
                maps[name] = corners(a)
    active = getattr(strands, "uv", None)
    return maps.get(active), maps


def generated(strands):
    """(texspace, orco) of a curve set's stand-in mesh for Generated
    coordinates: with the emitter's texture space (particle hair) each
    strand's root mapped through it (Cycles' sync_particle_hair: constant
    per strand); without one, the object-space position (Cycles' fallback:
    Curves objects carry no generated attribute)."""
    space = getattr(strands, "texspace", None)
    if space is None:
        return POSITION_TEXSPACE, None
    seg = SegmentCorners(strands)
    roots = np.asarray(strands.points, np.float64).reshape(-1, 3)[seg.offsets[:-1]]
    return space, seg.of_curves(roots)
