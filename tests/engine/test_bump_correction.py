"""Cycles' Bump Map Correction (engine/bump_correction.py): the glossy
normal against a line-by-line transcription of Cycles 5.0's
ensure_valid_specular_reflection (closure/bsdf_util.h), and a normal map
bent away from the view rendered analytically: the diffuse lobe keeps the
bent normal, lit as Cycles lights it (no warning any more)."""
import math

import numpy as np
import pytest

from engine import bump_correction
from engine.render import render
from engine.scene import (Camera, Instance, Lobe, Material, Mesh, NormalMap, RenderSettings, Scene, SunLight,
                          World)
from engine.testscenes import look_at
from tests.engine.test_bump_shadowing import conty_estevez


def cycles_ensure_valid(ng, i, n):
    """closure/bsdf_util.h, one row, float64."""
    r = 2.0 * np.dot(n, i) * n - i
    iz = float(np.dot(i, ng))
    threshold = min(0.9 * iz, 0.01)
    if np.dot(ng, r) >= threshold:
        return n
    x = n - np.dot(n, ng) * ng
    length = np.linalg.norm(x)
    x = x / length if length > 0 else n
    ix = float(np.dot(i, x))
    a = ix * ix + iz * iz
    b = 2.0 * (a + iz * threshold)
    c = (threshold + iz) ** 2
    root = math.sqrt(max(b * b - 4.0 * a * c, 0.0))
    nz2 = 0.25 * (b + root) / a if ix < 0 else 0.25 * (b - root) / a
    return math.sqrt(max(1.0 - nz2, 0.0)) * x + math.sqrt(max(nz2, 0.0)) * ng


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_glossy_normal_matches_cycles_and_lifts_the_reflection_just_above_the_surface():
    rng = np.random.default_rng(11)
    m = 3000
    ng = unit(rng.normal(size=(m, 3)))
    wi = unit(rng.normal(size=(m, 3)))
    wi = np.where((np.einsum("ij,ij->i", wi, ng) < 0)[:, None], -wi, wi)   # the view above Ng (Cycles asserts it)
    n = unit(ng + 1.5 * rng.normal(size=(m, 3)))
    n = np.where((np.einsum("ij,ij->i", n, ng) < 0)[:, None], -n, n)
    out = bump_correction.ensure_valid_specular_reflection(ng, wi, n)
    moved = 0
    for k in range(m):
        want = cycles_ensure_valid(ng[k], wi[k], n[k])
        np.testing.assert_allclose(out[k], want, atol=1e-9)
        if not np.array_equal(want, n[k]):
            moved += 1
            r = 2.0 * np.dot(out[k], wi[k]) * out[k] - wi[k]
            threshold = min(0.9 * np.dot(wi[k], ng[k]), 0.01)
            assert np.dot(r, ng[k]) == pytest.approx(threshold, abs=1e-7)
            assert np.dot(out[k], wi[k]) > 0   # the view lies above the corrected normal
    assert 0.2 * m < moved < 0.9 * m
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-12)


def test_normal_map_bent_away_from_the_view_lights_the_diffuse_lobe_with_the_bent_normal():
    """A plane whose normal map leans 88 degrees towards +y, seen from -y
    (every bent normal faces away from the view), under a sun from +y:
    Cycles' diffuse closure keeps the bent normal, f = c / pi cos(bent, L)
    times its bump shadowing term (Blender 4.5+); the unbent normal Ember
    used before gives 0.8 E c / pi instead (14% above)."""
    p = 5.0 * np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    mesh = Mesh(p, tris, uvs=(p[tris][..., :2] + 5) / 10, name="plane")
    color = (0.5, 1.0, 0.51)
    albedo = 0.7
    mat = Material("steep map", (Lobe("diffuse", (albedo,) * 3),), normal=NormalMap(color, 1.0))
    light = unit(np.array([0.0, 0.6, 0.8]))
    cam = Camera(look_at((0, -3, 3), (0, 0, 0)), lens=50.0, resolution=(8, 8))
    scene = Scene([mesh], [Instance(0, materials=[0])], [mat], [SunLight(tuple(-light), (2.0, 2.0, 2.0))],
                  World((0.0, 0.0, 0.0)), cam)
    result = render(scene, RenderSettings(samples=1, samples_per_pass=1, max_bounces=0))
    assert not any("away from the view" in w for w in result.warnings), result.warnings
    bent = unit(2.0 * (np.array(color) - 0.5))
    view = unit(np.array([0, -3, 3]))
    assert np.dot(bent, view) < 0
    term = conty_estevez(np.array([0.0, 0.0, 1.0]), bent, light, True, True)
    want = albedo / np.pi * 2.0 * np.dot(bent, light) * term
    on = np.ones(result.image.shape[:2], bool)   # the plane fills the view
    assert on.mean() > 0.3
    np.testing.assert_allclose(result.image[on][:, :3], want, rtol=1e-5)


# ----------------------------------------------------------------------------
# sampling a split row: the mean sample weight against an independent
# estimate of the integral of f |cos| over the sphere (one family)

import ember_stats  # noqa: E402
from engine import bsdf  # noqa: E402
from engine import scene as S  # noqa: E402

N = 400_000
SPLIT_CASES = [(0.8, -0.3), (0.4, 0.2)]   # (cos of wo to the shading normal, of wo to the bent normal)
LEVEL = ember_stats.family_level(__name__, 3 * len(SPLIT_CASES))
Z_MAX = ember_stats.z_threshold(LEVEL)


def _split_lobes(n, cos_o, cos_bent):
    lobes = bsdf.MaterialTable([Material("m", (S.Lobe("diffuse", (0.8, 0.5, 0.3), weight=0.6),
                                               S.Lobe("glossy", (0.9, 0.9, 0.9), 0.5, weight=0.4)))]
                               ).gather(np.zeros(n, int))
    s = math.sqrt(1.0 - cos_o * cos_o)
    wo = np.tile([s, 0.0, cos_o], (n, 1))
    # The bent normal in the plane of wo and z, at cos_bent to wo.
    tilt = math.acos(cos_o) - math.acos(cos_bent)   # from z towards wo (negative: away from it)
    bent = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    assert np.dot(bent, wo[0]) == pytest.approx(cos_bent, abs=1e-12)
    z = np.tile([0.0, 0.0, 1.0], (n, 1))
    rot, split = bump_correction.rotations(np.tile([1.0, 0, 0], (n, 1)), np.tile([0, 1.0, 0], (n, 1)), z,
                                           np.tile(bent, (n, 1)))
    lobes.diffuse_rot, lobes.diffuse_split = rot, split
    return lobes, wo, bent


@pytest.mark.parametrize("cos_o,cos_bent", SPLIT_CASES)
def test_split_rows_sample_what_they_evaluate(cos_o, cos_bent):
    """A diffuse lobe on its bent normal (facing away from the view in the
    first case) beside a glossy one on the shading normal: the mean of
    bsdf.sample's weights is the integral of eval_pdf's f |wi.z| over the
    sphere (uniform directions); power asserted (2%)."""
    seed = 70 + SPLIT_CASES.index((cos_o, cos_bent))
    lobes, wo, bent = _split_lobes(N, cos_o, cos_bent)
    rng = np.random.default_rng(seed)
    wi, weight, pdf, _ = bsdf.sample(lobes, wo, *rng.random((3, N)))
    assert np.all(np.isfinite(weight)) and np.all(weight >= 0) and np.all(pdf >= 0)
    d = unit(rng.normal(size=(N, 3)))
    f, _ = bsdf.eval_pdf(lobes, wo, d)
    quad = 4.0 * np.pi * f * np.abs(d[:, 2:])
    var = weight.var(axis=0, ddof=1) / N + quad.var(axis=0, ddof=1) / N
    z = (weight.mean(axis=0) - quad.mean(axis=0)) / np.sqrt(var)
    detects = Z_MAX * np.sqrt(var) / quad.mean(axis=0)
    print(f"split row cos_o {cos_o} cos_bent {cos_bent}: sampled {weight.mean(axis=0).round(4)}, integrated "
          f"{quad.mean(axis=0).round(4)}, z {z.round(2)}; detects {np.round(detects * 100, 2)}% with probability 1/2")
    assert np.all(np.abs(z) < Z_MAX), z
    assert np.all(detects < 0.02)
