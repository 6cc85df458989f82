"""Warps from uniform random numbers to directions and points, with their pdfs.

All functions take arrays of uniforms in [0, 1) and work on whole batches.
Directions are in a local frame whose +Z is the pole (normal, cone axis).
"""
import numpy as np

TWO_PI = 2.0 * np.pi
INV_PI = 1.0 / np.pi


def concentric_disk(u1, u2):
    """Uniform point on the unit disk, Shirley-Chiu concentric map (x, y)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    first = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(first, a, b)
        phi = np.where(first, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +Z (Malley's method with the polar disk
    map: cheaper than the concentric map, and our samples are not stratified
    anyway); returns (dirs (N,3), pdf)."""
    r = np.sqrt(u1)
    phi = TWO_PI * u2
    d = np.empty((len(r), 3))
    d[:, 0] = r * np.cos(phi)
    d[:, 1] = r * np.sin(phi)
    d[:, 2] = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return d, d[:, 2] * INV_PI


def cosine_hemisphere_pdf(cos_theta):
    return np.maximum(cos_theta, 0.0) * INV_PI


def uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return d, np.full(len(z), 1.0 / (4 * np.pi))


def uniform_cone(u1, u2, one_minus_cos_max):
    """Uniform direction in the cone cos(theta) >= 1 - one_minus_cos_max about +Z.

    Takes and works with 1 - cos so that tiny cones (a sun of half a degree, a
    far sphere light) keep their precision: callers compute it without
    cancellation (``sin_sq_to_one_minus_cos``, 2 sin^2(theta / 2))."""
    one_minus_cos = u1 * one_minus_cos_max
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = TWO_PI * u2
    d = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
    return d, uniform_cone_pdf(one_minus_cos_max)


def uniform_cone_pdf(one_minus_cos_max):
    return 1.0 / (TWO_PI * one_minus_cos_max)


def sin_sq_to_one_minus_cos(sin_sq):
    """1 - sqrt(1 - x) without cancellation for small x (Cycles' helper)."""
    return np.where(sin_sq < 0.0004, 0.5 * sin_sq + 0.125 * sin_sq * sin_sq,
                    1.0 - np.sqrt(np.maximum(0.0, 1.0 - sin_sq)))


def uniform_triangle(u1, u2):
    """Barycentrics (b1, b2) of a uniform point on a triangle (sqrt warp)."""
    su = np.sqrt(u1)
    return 1.0 - su, u2 * su


def power_heuristic(a, b):
    """w = a^2 / (a^2 + b^2), defined as 0 where that is not finite."""
    a2 = a * a
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        w = a2 / (a2 + b * b)
    return np.where(np.isfinite(w), w, np.where(np.isinf(a) & np.isfinite(b), 1.0, 0.0))


class Distribution1D:
    """Piecewise-constant discrete distribution sampled by inverse CDF."""

    def __init__(self, weights):
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 1 or len(w) == 0:
            raise ValueError("Distribution1D needs a non-empty 1D weight array")
        w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        total = w.sum()
        if total <= 0:
            w = np.ones_like(w)
            total = w.sum()
        self.pmf = w / total
        self.cdf = np.cumsum(self.pmf)
        # The CDF is exactly 1 from the last non-zero entry on: a rounded sum
        # just below 1 would let u in [sum, 1) pick a trailing zero entry.
        self.cdf[np.nonzero(self.pmf)[0][-1]:] = 1.0
        self.total = total

    def __len__(self):
        return len(self.pmf)

    def sample(self, u):
        """Index for each uniform u, and its probability."""
        idx = np.searchsorted(self.cdf, u, side="right")
        idx = np.minimum(idx, len(self.pmf) - 1)
        # Zero-probability entries have an empty CDF interval: searchsorted
        # never lands on them, except through the clamp above.
        return idx, self.pmf[idx]

    def sample_continuous(self, u):
        """Index, its probability and u remapped to [0, 1) inside that bin."""
        idx, p = self.sample(u)
        lo = np.where(idx > 0, self.cdf[np.maximum(idx - 1, 0)], 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            du = np.where(p > 0, (u - lo) / p, 0.0)
        return idx, p, np.clip(du, 0.0, np.nextafter(1.0, 0.0))
