"""What the light types share: the NEE sample record, selection power,
input checks, the Light Falloff node's factor and small helpers."""
from dataclasses import dataclass

import numpy as np

from ..scene import FALLOFFS, SceneError

# Solid-angle sampling of rectangles and triangles is used between these
# solid angles (sr); outside, area sampling (pbrt-v4's Triangle thresholds:
# below, the two pdfs are the same up to rounding; near 2 pi, the spherical
# triangle warp degenerates).  Triangles also only from points near their
# plane (mesh.MeshLights._spherical, Cycles' rule).
MIN_SPHERICAL = 3e-4
MAX_SPHERICAL = 6.22
# The largest radiance or power Ember renders (validate.py checks every
# colour against it; float32 films hold it).
MAX_MAGNITUDE = 1e30


@dataclass
class LightSample:
    wi: np.ndarray        # (N, 3) unit direction towards the light
    dist: np.ndarray      # (N,) distance to the sampled point (inf for suns)
    Le: np.ndarray        # (N, 3) radiance (or intensity/d^2 for delta lights)
    pdf: np.ndarray       # (N,) solid-angle pdf, 0 = no sample
    delta: np.ndarray     # (N,) bool
    on_surface: np.ndarray  # (N,) bool: the point lies on a triangle (shorten the shadow ray)
    # What a Light Path node in an emission reads of the sampling path:
    # (depth (N,), PATH_COLUMNS (N, 7)) or None (see LightSet.sample).
    path: object = None
    # The sampling paths' shutter times (N,), None in a still scene: moving
    # emissive triangles are sampled where they are then.
    time: object = None


def selection_power(rgb):
    """The scalar power that light selection (power and tree) weighs an
    emitter by: the mean of its RGB power, as Cycles' light tree
    (``average(strength)``).  Not luminance: the image's error is measured
    per channel, and luminance, dominated by green, gives red and blue
    lights too few samples (Veach's MIS scene: 0.17 instead of about 0.25
    for its red light, 1.5x the variance in that light's highlights)."""
    return np.abs(np.asarray(rgb, float).mean(axis=-1))


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class Falloff:
    """Cycles' Light Falloff node between a light's Emission Strength and
    the light (svm_node_light_falloff, with ray_length the distance t from
    the shading point to the point on the light): radiance times t^power
    (Quadratic 0, Linear 1, Constant 2), times t^2 / (smooth + t^2) where
    smooth > 0.  The same factor scales NEE samples and the lights BSDF rays
    hit, so MIS stays unbiased."""

    def __init__(self, lights):
        self.power = np.array([FALLOFFS.index(l.falloff) for l in lights], float)
        self.smooth = np.array([l.falloff_smooth for l in lights], float)

    @classmethod
    def of(cls, lights):
        """The table's falloff, or None when every light is plain quadratic."""
        if any(l.falloff != "QUADRATIC" or l.falloff_smooth > 0 for l in lights):
            return cls(lights)
        return None

    def factor(self, j, t):
        """Per row: the factor of light j at distance t."""
        k, smooth = self.power[j], self.smooth[j]
        t2 = t * t
        with np.errstate(invalid="ignore", divide="ignore"):
            soft = np.where(smooth > 0, t2 / (smooth + t2), 1.0)
        return np.where(k == 0, 1.0, np.where(k == 1, t, t2)) * np.where(np.isfinite(soft), soft, 1.0)


def check_falloff(light, what):
    if light.falloff not in FALLOFFS:
        raise SceneError(f"{what}: unknown falloff {light.falloff!r} (one of {', '.join(FALLOFFS)})")
    if not (np.isfinite(light.falloff_smooth) and light.falloff_smooth >= 0):
        raise SceneError(f"{what}: falloff smooth must be finite and >= 0, got {light.falloff_smooth}")


def check_rgb(value, what, nonnegative=False):
    """value as a finite float (3,) array, or SceneError."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{what}: expected 3 numbers, got {value!r}") from None
    if arr.shape != (3,):
        raise SceneError(f"{what}: expected 3 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SceneError(f"{what}: contains NaN or infinity")
    if np.abs(arr).max() > MAX_MAGNITUDE * (1 + 1e-6):   # 1e30 as float32 passes
        raise SceneError(f"{what}: {np.abs(arr).max():.3g} is beyond the largest value Ember "
                         f"can render ({MAX_MAGNITUDE:g})")
    if nonnegative and np.any(arr < 0):
        raise SceneError(f"{what}: must not be negative, got {tuple(arr)}")
    return arr


def check_direction(value, what):
    d = check_rgb(value, what)
    if np.linalg.norm(d) == 0:
        raise SceneError(f"{what} is zero")
    return d


def check_size(value, what, low=0.0, high=np.inf):
    """A finite number in [low, high], or SceneError."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SceneError(f"{what}: expected a number, got {value!r}") from None
    if not (np.isfinite(x) and low <= x <= high):
        bound = f">= {low:g}" if high == np.inf else f"in [{low:g}, {high:g}]"
        raise SceneError(f"{what} must be a finite number {bound}, got {value}")
    return x


def uniform_index(j):
    """j itself, or its single value when every ray picked the same light, so
    per-light parameters broadcast instead of being gathered per ray."""
    if len(j) and j[0] == j[-1] and (j == j[0]).all():
        return int(j[0])
    return j


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def normals(n, count):
    """The normals n, or zero rows (no normal) where there are none."""
    return np.zeros((count, 3)) if n is None else n
