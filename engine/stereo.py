"""Spherical stereo (Cycles 5.0's spherical_stereo_transform, camera.h):
each camera ray of one eye starts half the interocular distance to the side
of the camera's centre, the side taken per ray from its own direction (so a
360-degree panorama is stereo in every direction), and turns to meet the
centre's ray at the convergence distance.  Towards the poles the offset
fades out (pole merge), so the eyes' images meet there.

Cycles applies it in the panorama's camera space (z up) for panoramic
cameras and in world space (world z up) for perspective ones; the caller
passes rays in the right space.  Blender's stereo without the Spherical
Stereo option (off-axis, toe-in, parallel) needs nothing here: the add-on
renders each eye from Blender's camera matrix and shift for that view.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Stereo:
    """One eye: ``offset`` the signed half interocular distance (left < 0,
    Cycles' interocular_offset), ``convergence`` the distance at which the
    eyes' rays meet (inf: parallel), ``pole_merge`` the altitudes (radians,
    from, to) over which the offset fades to 0 ((0, 0): none)."""
    offset: float = 0.0
    convergence: float = np.inf
    pole_merge: tuple = (0.0, 0.0)


def transform(stereo, o, d):
    """Rays (o, d) of the eye, from the centre's rays (o, unit d, (N, 3))."""
    d = np.asarray(d, np.float64)
    offset = np.full(len(d), float(stereo.offset))
    lo, hi = stereo.pole_merge
    if hi > 0.0:
        altitude = np.abs(np.arcsin(np.clip(d[:, 2], -1.0, 1.0)))
        fade = np.cos(np.clip((altitude - lo) / max(hi - lo, 1e-30), 0.0, 1.0) * (0.5 * np.pi))
        offset = np.where(altitude > hi, 0.0, np.where(altitude > lo, offset * fade, offset))
    # side = normalize(cross(d, up)), up = (0, 0, 1): (d.y, -d.x, 0).
    side = np.stack([d[:, 1], -d[:, 0], np.zeros(len(d))], axis=1)
    length = np.linalg.norm(side, axis=1, keepdims=True)
    # Straight up or down the side is undefined: Cycles' normalize gives 0 there.
    side = np.where(length > 0, side / np.where(length > 0, length, 1.0), 0.0)
    shift = side * offset[:, None]
    o = o + shift
    if np.isfinite(stereo.convergence):
        d = stereo.convergence * d - shift
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return o, d
