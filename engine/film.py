"""Per-pixel accumulation of samples: radiance (with second moments for
variance estimates), alpha, and first-hit depth, normal and albedo."""
import threading

import numpy as np

from . import passes as extra_passes


class Tile:
    """Sums for a contiguous range of pixels [lo, hi), filled by one batch."""

    def __init__(self, lo, hi, passes=()):
        self.lo, self.hi = lo, hi
        self.extra = extra_passes.Sums(passes, lo, hi) if passes else None
        n = hi - lo
        self.rgb = np.zeros((n, 3))
        self.rgb2 = np.zeros((n, 3))
        self.alpha = np.zeros(n)
        self.count = np.zeros(n)
        self.depth = np.zeros(n)
        self.normal = np.zeros((n, 3))
        self.albedo = np.zeros((n, 3))
        self._pending = []

    def _bin(self, pix, w):
        return np.bincount(pix - self.lo, weights=w, minlength=self.hi - self.lo)

    def add_radiance(self, pix, L):
        """Queue finished paths; ``flush`` bins them all at once."""
        self._pending.append((pix, L))

    def flush(self):
        if not self._pending:
            return
        pix = np.concatenate([p for p, _ in self._pending]) - self.lo
        L = np.concatenate([l for _, l in self._pending])
        self._pending = []
        # One bincount per moment over (pixel, channel) pairs.
        idx = (pix[:, None] * 3 + np.arange(3)).ravel()
        n = 3 * (self.hi - self.lo)
        self.rgb += np.bincount(idx, weights=L.ravel(), minlength=n).reshape(-1, 3)
        self.rgb2 += np.bincount(idx, weights=(L * L).ravel(), minlength=n).reshape(-1, 3)

    def add_camera(self, pix, alpha, depth, normal, albedo):
        self.count += np.bincount(pix - self.lo, minlength=self.hi - self.lo)
        self.alpha += self._bin(pix, alpha)
        self.depth += self._bin(pix, depth)
        for c in range(3):
            self.normal[:, c] += self._bin(pix, normal[:, c])
            self.albedo[:, c] += self._bin(pix, albedo[:, c])


class Film:
    """Per-pixel sums.  Radiance and its second moment stay float64 (they sum
    thousands of samples of any magnitude); coverage, counts and the first-hit
    AOVs are float32, which halves their memory on large frames."""

    def __init__(self, width, height, passes=()):
        self.width, self.height = width, height
        self.passes = tuple(passes)
        self.extra = extra_passes.Sums(self.passes, 0, width * height) if self.passes else None
        n = width * height
        self.rgb = np.zeros((n, 3))
        self.rgb2 = np.zeros((n, 3))
        self.alpha = np.zeros(n, np.float32)
        self.count = np.zeros(n, np.float32)
        self.depth = np.zeros(n, np.float32)
        self.normal = np.zeros((n, 3), np.float32)
        self.albedo = np.zeros((n, 3), np.float32)
        self._lock = threading.Lock()

    def merge(self, tile):
        tile.flush()
        s = slice(tile.lo, tile.hi)
        with self._lock:
            for name in ("rgb", "rgb2", "alpha", "count", "depth", "normal", "albedo"):
                getattr(self, name)[s] += getattr(tile, name)
            if self.extra is not None and tile.extra is not None:
                self.extra.merge(tile.extra, tile.lo)

    def _mean(self, arr):
        c = np.maximum(self.count, 1.0)
        return arr / (c if arr.ndim == 1 else c[:, None])

    def image(self, transparent=True):
        """(H, W, 4) float32 RGBA, row 0 at the top.  Alpha is the coverage
        with a transparent film, else 1 (as Cycles)."""
        out = np.empty((self.height * self.width, 4), np.float32)
        out[:, :3] = self._mean(self.rgb)
        out[:, 3] = self._mean(self.alpha) if transparent else 1.0
        return out.reshape(self.height, self.width, 4)

    def variance(self):
        """(H, W, 3) float32 variance of the pixel mean, from the per-sample moments."""
        c = np.maximum(self.count.astype(np.float64), 2.0)[:, None]
        mean = self.rgb / c
        var = self.rgb2 / c
        var -= mean * mean
        np.maximum(var, 0.0, out=var)
        var /= c - 1.0  # unbiased sample variance / c = variance of the mean
        return var.astype(np.float32).reshape(self.height, self.width, 3)

    def aov(self, name):
        arr = self._mean(getattr(self, name))
        shape = (self.height, self.width) + arr.shape[1:]
        return arr.reshape(shape).astype(np.float32)


# ----------------------------------------------------------------------------
# Named extra passes (engine/passes.py): Tile.add_pass collects, Film.pass_images
# hands out the pictures.

def _tile_add_pass(self, name, pix, values, rank=None):
    """Add per-sample values of the named pass (ignored when not requested)."""
    if self.extra is not None:
        self.extra.add(name, pix, values, rank)


def _tile_wants(self, name):
    return self.extra is not None and self.extra.wants(name)


def _film_pass_images(self, config=None):
    """{name: (H, W, C) float32} for every requested pass."""
    if not self.passes:
        return {}
    return extra_passes.images(self.extra, self.count, self.width, self.height, self.passes,
                               film=self, config=config)


Tile.add_pass = _tile_add_pass
Tile.wants = _tile_wants
Film.pass_images = _film_pass_images
