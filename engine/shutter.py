"""The shutter: a camera sample's time from its random number (Cycles'
camera_sample motion-blur block, scene/camera.cpp shutter_table).

Time runs over [0, 1] of the shutter.  Cycles maps the sample's number by
the inverse CDF of the shutter curve (Render > Motion Blur > Shutter Curve,
256 values of the curve over the shutter), tabulated at 256 points and read
with linear interpolation; even the flat default curve maps [0, 1] onto
[0.002, 0.994] (its table is 255/256 of the range), so the table is ported
as Cycles builds it, quirks included.  The rolling shutter (Top-Bottom)
then mixes in a time set by the pixel's row: top row 0, bottom row 1.
"""
import numpy as np

TABLE_SIZE = 256      # Cycles' SHUTTER_TABLE_SIZE and RAMP_TABLE_SIZE


def curve_value(curve, x):
    """Cycles' shutter_curve_eval: the curve's samples read at x (note its
    ``saturate(x) * size - 1``, which reads slightly off the sample grid)."""
    curve = np.asarray(curve, np.float64)
    size = len(curve)
    if size == 0:
        return np.ones_like(x)
    x = np.clip(x, 0.0, 1.0) * size - 1.0
    index = np.trunc(x).astype(np.int64)     # C's (int): toward zero
    frac = x - index
    below = index < size - 1
    nxt = np.minimum(index + 1, size - 1)
    return np.where(below, curve[index] + (curve[nxt] - curve[index]) * frac, curve[-1])


def shutter_table(curve):
    """Cycles' util_cdf_inverted(256, 0, 1, curve, symmetric off): the time
    of numbers (i + 0.5) / 256.  A curve that is zero (or not finite)
    everywhere gives Cycles' table of that case (every time near the end)."""
    curve = np.asarray(curve, np.float64)
    curve = np.where(np.isfinite(curve), curve, 0.0)    # (hostile curves: as zero there)
    values = np.abs(curve_value(curve, np.arange(TABLE_SIZE - 1) / (TABLE_SIZE - 2)))
    cdf = np.concatenate([[0.0], np.cumsum(values)])
    total = cdf[-1]
    cdf = cdf * (0.0 if total == 0.0 else 1.0 / total)
    cdf[-1] = 1.0
    x = (np.arange(TABLE_SIZE) + 0.5) / TABLE_SIZE
    index = np.searchsorted(cdf, x, side='right') - 1
    inside = index < len(cdf) - 1
    lo = cdf[np.minimum(index, len(cdf) - 1)]
    hi = cdf[np.minimum(index + 1, len(cdf) - 1)]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = np.where(inside, (x - lo) / (hi - lo), 0.0)
    index = np.where(inside, index, TABLE_SIZE)
    return (index + t) / TABLE_SIZE


def table_read(table, u):
    """Cycles' lookup_table_read: the table linearly interpolated at u in [0, 1]."""
    x = np.clip(u, 0.0, 1.0) * (len(table) - 1)
    index = np.minimum(x.astype(np.int64), len(table) - 1)
    t = x - index
    return table[index] * (1.0 - t) + table[np.minimum(index + 1, len(table) - 1)] * t


def table_cdf(table, t):
    """P(time <= t) of the times ``table_read`` gives uniform numbers (the
    piecewise-linear map inverted): the exact law a chi-square test holds
    the sampler to."""
    knots = np.linspace(0.0, 1.0, len(table))
    return np.interp(t, table, knots, left=0.0, right=1.0)


class Shutter:
    """Times of camera samples for a camera (engine.scene.Camera)."""

    def __init__(self, cam):
        curve = getattr(cam, "shutter_curve", None)
        self.table = shutter_table(np.ones(TABLE_SIZE) if curve is None else curve)
        self.rolling = getattr(cam, "rolling_shutter", "NONE") == "TOP"
        duration = float(getattr(cam, "rolling_duration", 0.1))
        self.duration = min(max(duration, 0.0), 1.0) if np.isfinite(duration) else 0.0
        self.full_height = max(int(cam.resolution[1]), 1)

    def times(self, u, row):
        """Shutter times of numbers ``u`` for samples in full-frame pixel
        rows ``row`` (counted from the bottom, as Cycles' raster y)."""
        time = table_read(self.table, np.asarray(u, np.float64))
        if not self.rolling:
            return time
        rolled = 1.0 - np.asarray(row, np.float64) / self.full_height
        if self.duration == 0.0:
            return rolled
        # Cycles' mix of the two: blur over ``duration``, the rest rolling
        return (time - 0.5) * self.duration + (rolled - 0.5) * (1.0 - self.duration) + 0.5
