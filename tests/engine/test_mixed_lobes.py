"""A reflecting lobe mixed with a transmitting one (issue 8, the Mix Shader
of Translucent and Glossy that rendered brighter than Cycles).

``bsdf.sample`` picks one lobe and returns f / pdf summed over all lobes,
so the pdf must be the density the sampler really has.  GGX reflection
sampled through a visible microfacet can point below the surface; Cycles
absorbs such a sample (bsdf_microfacet_sample).  Ember handed it to the
translucent (or glass) lobe, whose pdf leaves out the glossy sampler's
density there: light through the surface came out 3.7 % too bright.

Checked here per hemisphere: the mean sample weight (what a path carries)
against an independent estimate of the integral of f |cos| (cosine-weighted
directions evaluated by ``eval_pdf``), and against the exact
transmission of a translucent lobe (its weight x colour).  One family of the
suite budget (ember_stats.family_level), seeds fixed.
"""
import math

import numpy as np
import pytest

import ember_stats
from engine import bsdf
from engine import scene as S
from engine.sampling import cosine_hemisphere
from engine.scene import Material

N = 200_000
LEAF = (S.Lobe("translucent", (0.3, 0.8, 0.2), weight=0.7),       # Mix Shader, Fac 0.3, as exported
        S.Lobe("glossy", (0.9, 0.9, 0.9), 0.5, weight=0.3))
MATERIALS = {
    "leaf": LEAF,
    "glossy_glass": (S.Lobe("glossy", (0.8, 0.8, 0.8), 0.6, weight=0.5),
                     S.Lobe("glass", (0.9, 0.95, 1.0), 0.35, ior=1.45, weight=0.5)),
    "glossy_refraction": (S.Lobe("glossy", (0.7, 0.7, 0.7), 0.5, weight=0.4),
                          S.Lobe("refraction", (1.0, 0.9, 0.8), 0.3, ior=1.3, weight=0.6)),
}
CASES = [("leaf", 0.9), ("leaf", 0.3), ("glossy_glass", 0.5), ("glossy_refraction", 0.5)]
# Per case: 2 hemispheres x 3 channels against the independent estimate, and
# for the leaf 3 channels against the exact transmission.
N_TESTS = len(CASES) * 6 + 3 * sum(name == "leaf" for name, _ in CASES)
LEVEL = ember_stats.family_level(__name__, N_TESTS)
Z_MAX = ember_stats.z_threshold(LEVEL)


def _lobes(name, n):
    return bsdf.MaterialTable([Material(name, MATERIALS[name])]).gather(np.zeros(n, int))


def _wo(cos_o, n):
    s = math.sqrt(1.0 - cos_o * cos_o)
    return np.tile([s * math.cos(0.4), s * math.sin(0.4), cos_o], (n, 1))


def _sampled(name, cos_o, seed):
    """Per-sample weights, split by the hemisphere of wi: (upper, lower)."""
    wo = _wo(cos_o, N)
    wi, weight, _, _ = bsdf.sample(_lobes(name, N), wo, *np.random.default_rng(seed).random((3, N)))
    assert np.all(np.isfinite(weight)) and np.all(weight >= 0)
    return weight * (wi[:, 2:] > 0), weight * (wi[:, 2:] < 0)


def _integrated(name, cos_o, seed):
    """pi f(wi) per cosine-weighted wi of each hemisphere: its mean is the
    integral of f |cos| over that hemisphere, without the sampling code."""
    wo = _wo(cos_o, N)
    d, _ = cosine_hemisphere(*np.random.default_rng(seed).random((2, N)))
    out = []
    for flip in (1.0, -1.0):
        f, _ = bsdf.eval_pdf(_lobes(name, N), wo, d * np.array([1.0, 1.0, flip]))
        out.append(math.pi * f)
    return out


def _z(a, b):
    """Per channel z of mean(a) - mean(b) (b an array or exact)."""
    var = a.var(axis=0, ddof=1) / len(a)
    if isinstance(b, np.ndarray) and b.ndim == 2:
        var = var + b.var(axis=0, ddof=1) / len(b)
        b = b.mean(axis=0)
    return (a.mean(axis=0) - b) / np.sqrt(var)


def _detects(a, b):
    """Per channel: the relative difference the |z| < Z_MAX test detects
    with probability 1/2 (as text)."""
    var = a.var(axis=0, ddof=1) / len(a)
    if isinstance(b, np.ndarray) and b.ndim == 2:
        var = var + b.var(axis=0, ddof=1) / len(b)
        b = b.mean(axis=0)
    rel = Z_MAX * np.sqrt(var) / np.maximum(np.abs(b), 1e-300)
    return "(" + ", ".join(f"{r:.2%}" for r in rel) + ")"


@pytest.mark.parametrize("name,cos_o", CASES)
def test_sample_weights_integrate_f_cos_per_hemisphere(name, cos_o):
    seed = 40 + CASES.index((name, cos_o))
    sampled = _sampled(name, cos_o, seed)
    integrated = _integrated(name, cos_o, seed + 100)
    for side, s, q in zip(("upper", "lower"), sampled, integrated):
        z = _z(s, q)
        print(f"{name} cos_o {cos_o} {side}: sampled {s.mean(axis=0).round(4)}, "
              f"integrated {q.mean(axis=0).round(4)}, z {z.round(2)}; detects {_detects(s, q)} with probability 1/2")
        assert np.all(np.abs(z) < Z_MAX), f"{name} cos_o {cos_o} {side}: z {z} (|z| < {Z_MAX:.2f})"


@pytest.mark.parametrize("cos_o", [c for name, c in CASES if name == "leaf"])
def test_leaf_transmits_its_translucent_weight(cos_o):
    """Below the surface only the translucent lobe scatters: its albedo
    there is exactly weight x colour (0.7 x (0.3, 0.8, 0.2))."""
    _, lower = _sampled("leaf", cos_o, 60 + int(cos_o * 10))
    exact = 0.7 * np.array([0.3, 0.8, 0.2])
    z = _z(lower, exact)
    print(f"leaf cos_o {cos_o}: transmitted {lower.mean(axis=0).round(4)}, exact {exact}, z {z.round(2)}; "
          f"detects {_detects(lower, exact)} with probability 1/2")
    assert np.all(np.abs(z) < Z_MAX), f"cos_o {cos_o}: z {z} (|z| < {Z_MAX:.2f})"
