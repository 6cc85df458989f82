"""The Henyey-Greenstein phase function, as Cycles' ``volume_henyey_greenstein``.

cos_theta is the cosine between the ray's direction of travel and the
scattered direction (g > 0 scatters forward).  |g| is clamped to 1 - 1e-3
as Cycles does, and |g| < 1e-3 is isotropic.
"""
import numpy as np

from ..vec import frame, to_world

G_LIMIT = 1.0 - 1e-3
_ISOTROPIC = 1e-3


def clamp_g(g):
    return np.clip(np.asarray(g, np.float64), -G_LIMIT, G_LIMIT)


def hg_eval(cos_theta, g):
    """Phase function value (= its solid-angle pdf) per row."""
    g = clamp_g(g)
    g2 = g * g
    denom = np.maximum(1.0 + g2 - 2.0 * g * cos_theta, 1e-30)
    return (1.0 - g2) / (4.0 * np.pi * denom * np.sqrt(denom))


def hg_cos_theta(g, u):
    """Inverse CDF of cos_theta (Cycles' henyey_greenstein_sample)."""
    g = clamp_g(g)
    iso = np.abs(g) < _ISOTROPIC
    gs = np.where(iso, 0.5, g)
    k = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    cos = (1.0 + gs * gs - k * k) / (2.0 * gs)
    return np.clip(np.where(iso, 1.0 - 2.0 * u, cos), -1.0, 1.0)


def hg_sample(d, g, u1, u2):
    """Scattered unit directions about the travel directions d (N, 3) and
    their pdf (the phase function's value)."""
    cos = hg_cos_theta(g, u1)
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=1)
    s, t = frame(np.ascontiguousarray(d, np.float64))
    wi = to_world(local, s, t, d)
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    return wi, hg_eval(cos, g)
