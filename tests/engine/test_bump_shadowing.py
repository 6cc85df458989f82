"""Cycles' bump shadowing terms (kernel/closure/bsdf.h), transcribed one
direction at a time from each version's source, against the vectorized
engine/bsdf.bump_shadowing; and the term's effect on a rendered plane whose
normal map tilts every shading normal."""
import math

import numpy as np
import pytest

from engine import bsdf


def chiang(ng, n, i):
    """Blender 3.4-4.4, with Ng := the smooth normal sd->N."""
    cos_ni = float(np.dot(n, i))
    if cos_ni < 0.0:
        ng = -ng
    den = cos_ni * float(np.dot(ng, n))
    g = float(np.dot(ng, i)) / den if den != 0.0 else 0.0
    if g >= 1.0:
        return 1.0
    if g < 0.0:
        return 0.0
    return -g * g * g + g * g + g


def conty_estevez(ns, n, i, is_eval, is_diffuse):
    """Blender 4.5+: (factor, rejected)."""
    cos_si, cos_sn, cos_ni = float(np.dot(ns, i)), float(np.dot(ns, n)), float(np.dot(n, i))
    if cos_si * cos_sn * cos_ni < 0.0 and (is_eval or is_diffuse):
        return 0.0
    if not is_diffuse:
        return 1.0
    ci, cd = abs(cos_si), abs(cos_sn)
    if cd >= 1.0 or ci >= 1.0:
        return 1.0
    if ci < 1e-6:
        return 0.0
    alpha2 = min(max(0.125 * (1.0 / cd ** 2 - 1.0), 0.0), 1.0)
    lam = 0.5 * (math.sqrt(1.0 + alpha2 * max(1.0 / ci ** 2 - 1.0, 0.0)) - 1.0)
    return 1.0 / (1.0 + lam)


def unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("model", [bsdf.BUMP_CHIANG, bsdf.BUMP_GGX])
def test_terms_match_cycles_source(model):
    rng = np.random.default_rng(3)
    n = 4000
    smooth = unit(rng.normal(size=(n, 3)) * [0.6, 0.6, 1.0] + [0, 0, 1.2])   # shading frame: N = z
    smooth[:50] = [0.0, 0.0, 1.0]   # normals the map left alone
    wi = unit(rng.normal(size=(n, 3)))
    diffuse, keep = bsdf.bump_shadowing(smooth, np.full(n, model, np.int8), wi)
    z = np.array([0.0, 0.0, 1.0])
    for k in range(n):
        if model == bsdf.BUMP_CHIANG:
            assert diffuse[k] == pytest.approx(chiang(smooth[k], z, wi[k]), abs=1e-12)
            assert keep[k]
        else:
            assert diffuse[k] == pytest.approx(conty_estevez(smooth[k], z, wi[k], True, True), abs=1e-12)
            assert keep[k] == (conty_estevez(smooth[k], z, wi[k], True, False) != 0.0)
    # The test covers all branches: softened, full and zero values.
    assert np.any(diffuse == 0) and np.any(diffuse == 1) and np.any((diffuse > 0) & (diffuse < 1))


def test_unmoved_normal_changes_nothing():
    wi = unit(np.random.default_rng(4).normal(size=(500, 3)))
    smooth = np.tile([0.0, 0.0, 1.0], (500, 1))
    for model in (bsdf.BUMP_CHIANG, bsdf.BUMP_GGX):
        diffuse, keep = bsdf.bump_shadowing(smooth, np.full(500, model, np.int8), wi)
        assert np.all(diffuse[wi[:, 2] != 0] == 1.0) and np.all(keep)


def test_version_picks_the_term():
    assert bsdf.bump_model((3, 4, 1)) == bsdf.bump_model((4, 4, 0)) == bsdf.BUMP_CHIANG
    assert bsdf.bump_model((4, 5, 0)) == bsdf.bump_model((5, 0, 1)) == bsdf.BUMP_GGX
