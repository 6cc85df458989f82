"""The Principled Hair BSDF's Huang model (engine/lobes/hair_huang.py, the
``_huang_*`` helpers of engine/bsdf_loops.py, Cycles 5.0's
bsdf_principled_hair_huang.h).

Cycles' Huang sample and eval both report pdf 1: the pdf is an MIS stand-in,
not the density the sampler draws from (which has no closed form: it is
the composition of a sampled h, three sampled microfacet normals and a
Fresnel choice).  So there is no pdf to chi-square the sampler against;
what a sampler with its own weight must satisfy is E[weight 1{wi in cell}]
= integral over the cell of eval |cos|.  ``test_sampler_matches_eval_per_cell``
is that chi-square: per cell of an equal-area (wi.x, azimuth) grid the
sampler's weighted histogram against the Monte Carlo integral of eval,
(a - b)^2 / (var a + var b) summed over the cells.  Cycles' model does not
hold it (xfail-strict): its sampler and eval are different approximations
of the same lobes (R: the sampler draws h uniformly over the width, the
eval integrates over gamma, d gamma / dh = 1 / cos gamma; TRRT+: the
sampler's T R R A_res against the eval's geometric series).  Measured cell
chi2 at melanin 0.6: 123 / 64 (round), 101 / 64 (elliptical), 138 / 64
(roughness 0.6); the R lobe alone (absorption 50): 1966 / 64, its albedo
+1.6 % from the sampler.  Ember reproduces both halves as Cycles has them
(the parity test, tests/addon/test_hair_huang_parity.py, agrees with live
Cycles to 0.05 %), so the full model is held to its totals:
``test_sampler_albedo_matches_eval`` (z-test of the directional albedo two
ways; measured z 0.98, 2.08, -3.16 against a threshold of 4.6).  For
absorption-free hair Cycles' eval's TRRT+ (a geometric series at total
internal reflection, T_avg clamped to 1e-5) gives 1.65 where its sampler
gives 1.015 (measured; xfail-strict below).

Also: the sampler's white furnace (absorption 0: albedo 1 within the
model's 2 %), the ellipse's axis, and hostile parameters."""
import math

import numpy as np
import pytest

import ember_stats
from engine import bsdf, kernels
from engine import scene as S
from engine.lobes import hair, hair_huang

N = 200_000
SIGMA = tuple(float(x) for x in hair.sigma_from_melanin(0.6, 0.3, (1, 1, 1), 0.3))
CASES = [dict(aspect_ratio=1.0, absorption=SIGMA),
         dict(aspect_ratio=0.85, absorption=SIGMA, fibre_axis=(0.6, 0.8)),
         dict(aspect_ratio=1.0, absorption=SIGMA, roughness=0.6, hair_gains=(1.0, 0.5, 2.0))]
N_TESTS = len(CASES) + 1           # totals z-tests, the cell chi-square
LEVEL = ember_stats.family_level(__name__, N_TESTS)
Z_MAX = ember_stats.z_threshold(LEVEL)
WO = np.array([0.3, -0.4, math.sqrt(0.75)])
GRID = 8


@pytest.fixture(scope="module", autouse=True)
def compiled():
    """The compiled loops (the NumPy form runs the same helpers row by row in
    Python: tests/engine/test_bsdf_loops.py holds the two together)."""
    if not kernels.configure(True):
        pytest.skip("numba unavailable")
    assert kernels.wait(900)
    yield


def lobes_for(n, **kw):
    fields = dict(roughness=0.3, ior=1.55, offset=math.radians(2.0))
    fields.update(kw)
    lobe = S.Lobe('hair_huang', (1.0, 1.0, 1.0), **fields)
    return bsdf.MaterialTable([S.Material("huang", (lobe,))]).gather(np.zeros(n, np.int64))


def cells(wi):
    """Equal-area cells: wi.x (along the fibre) uniform, the azimuth about it uniform."""
    i = np.clip(((wi[:, 0] + 1.0) * 0.5 * GRID).astype(int), 0, GRID - 1)
    phi = np.arctan2(wi[:, 2], wi[:, 1])
    j = np.clip(((phi + np.pi) / (2 * np.pi) * GRID).astype(int), 0, GRID - 1)
    return i * GRID + j


def sampled_cells(lobes, rng, n):
    wo = np.tile(WO, (n, 1))
    wi, weight, pdf, delta = bsdf.sample(lobes, wo, rng.random(n), rng.random(n), rng.random(n))
    v = weight.mean(axis=1) * (~delta)
    c = cells(wi)
    mean = np.bincount(c, v, GRID * GRID) / n
    var = (np.bincount(c, v * v, GRID * GRID) / n - mean ** 2) / n
    return mean, var, v


def evaluated_cells(lobes, rng, n):
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    f, _ = bsdf.eval_pdf(lobes, np.tile(WO, (n, 1)), wi)
    g = f.mean(axis=1) * np.abs(wi[:, 2]) * 4.0 * np.pi
    c = cells(wi)
    mean = np.bincount(c, g, GRID * GRID) / n
    var = (np.bincount(c, g * g, GRID * GRID) / n - mean ** 2) / n
    return mean, var, g


def _compare(case, seed):
    rng = np.random.default_rng(seed)
    lobes = lobes_for(N, **case)
    a, va, v = sampled_cells(lobes, rng, N)
    b, vb, g = evaluated_cells(lobes, rng, N)
    keep = (va + vb) > 0
    stat = float(np.sum((a - b)[keep] ** 2 / (va + vb)[keep]))
    dof = int(keep.sum())
    p = ember_stats.chi2_sf(stat, dof)
    se = math.sqrt(v.var() / N + g.var() / N)
    z = (v.mean() - g.mean()) / se
    print(f"huang {case}: sampler albedo {v.mean():.4f}, eval {g.mean():.4f} +- {se:.4f} (z {z:.2f}); cells "
          f"chi2 {stat:.1f} / {dof}, p {p:.3g}; " + ember_stats.power_line("albedo", se / g.mean(), LEVEL))
    return p, z


@pytest.mark.parametrize("case", range(len(CASES)))
def test_sampler_albedo_matches_eval(case):
    p, z = _compare(CASES[case], 10 + case)
    assert abs(z) < Z_MAX, z


@pytest.mark.xfail(strict=True, reason="Cycles' Huang sampler and eval are different approximations (the R "
                   "lobe alone: cells chi2 1966 / 64), reproduced as Cycles has them")
def test_sampler_matches_eval_per_cell():
    p, z = _compare(dict(aspect_ratio=1.0, absorption=(50.0, 50.0, 50.0)), 20)
    assert p > LEVEL, p


@pytest.mark.xfail(strict=True, reason="Cycles' own model: with no absorption its eval's TRRT+ (T_avg clamped "
                   "at 1e-5 under internal total reflection) integrates to 1.65, its sampler to 1.015")
def test_white_hair_eval_matches_sampler():
    p, z = _compare(dict(aspect_ratio=1.0, absorption=(0.0, 0.0, 0.0)), 3)
    assert abs(z) < Z_MAX, z


@pytest.mark.parametrize("aspect", [1.0, 0.85])
def test_white_furnace_of_the_sampler(aspect):
    """Absorption 0, every gain 1: the sampler's mean weight (its albedo)
    over random views is 1 within the model's approximations (measured
    1.015 at roughness 0.3; the bound is not statistical)."""
    rng = np.random.default_rng(5)
    n = 40_000
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    lobes = lobes_for(n, aspect_ratio=aspect, absorption=(0.0, 0.0, 0.0), fibre_axis=(0.0, 1.0))
    wi, weight, pdf, delta = bsdf.sample(lobes, wo, rng.random(n), rng.random(n), rng.random(n))
    albedo = weight.mean()
    print(f"huang white furnace (aspect {aspect}): sampler albedo {albedo:.4f}")
    assert 0.97 < albedo < 1.05, albedo


def test_ellipse_axes_are_cycles():
    """Cycles' make_orthonormals where a curve has no normal, else the normal
    made perpendicular to the tangent, in the shading frame's (y, z)."""
    t = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]) / np.array([[1.0], [math.sqrt(3.0)]])
    a, b = hair_huang.make_orthonormals(t)
    assert np.allclose(np.einsum("ij,ij->i", a, t), 0) and np.allclose(np.linalg.norm(b, axis=1), 1)
    assert np.allclose(a[0], np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0))   # (N.z - N.y, N.x - N.z, N.y - N.x)
    tangent = np.array([[1.0, 0.0, 0.0]])
    axes = hair_huang.ellipse_axes(tangent, np.array([[0.3, 0.0, 2.0]]), np.array([[1.0, 0, 0]]),
                                   np.array([[0, 1.0, 0]]), np.array([[0, 0, 1.0]]))
    assert np.allclose(axes, [[0.0, 1.0]])
    axes = hair_huang.ellipse_axes(tangent, np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]),
                                   np.array([[0, 0, 1.0]]))
    assert np.allclose(np.hypot(*axes[0]), 1.0)


def test_near_field_is_far_field_at_full_coverage():
    """pixel_coverage 1 (or more) is the far field; a narrow pixel integrates
    a part of the width (a different, finite value)."""
    rng = np.random.default_rng(7)
    n = 2000
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    wo = np.tile(WO, (n, 1))
    far, _ = bsdf.eval_pdf(lobes_for(n, absorption=SIGMA), wo, wi)
    near, _ = bsdf.eval_pdf(lobes_for(n, absorption=SIGMA, pixel_coverage=0.2), wo, wi)
    same, _ = bsdf.eval_pdf(lobes_for(n, absorption=SIGMA, pixel_coverage=1.0), wo, wi)
    assert np.array_equal(far, same)
    assert np.isfinite(near).all() and not np.allclose(near, far)


@pytest.mark.parametrize("fields", [dict(aspect_ratio=0.0), dict(aspect_ratio=float('nan')),
                                    dict(aspect_ratio=1e9), dict(hair_gains=(-1.0, float('nan'), -3.0)),
                                    dict(roughness=float('nan')), dict(roughness=0.0), dict(ior=float('nan')),
                                    dict(offset=1e6), dict(fibre_axis=(float('nan'), 0.0)),
                                    dict(pixel_coverage=float('nan')), dict(pixel_coverage=0.0),
                                    dict(absorption=(1e30, float('inf'), 0.0))])
def test_hostile_parameters_stay_finite(fields):
    rng = np.random.default_rng(9)
    n = 500
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2])
    wo[0] = (1.0, 0.0, 0.0)       # along the fibre
    wo[1] = (0.0, 1.0, 1e-9)      # grazing the edge
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    lobes = lobes_for(n, **{"absorption": SIGMA, **fields})
    wi, weight, pdf, delta = bsdf.sample(lobes, wo, rng.random(n), rng.random(n), rng.random(n))
    f, p = bsdf.eval_pdf(lobes, wo, wi)
    for a in (wi, weight, pdf, f, p):
        assert np.isfinite(a).all()
    assert (weight >= 0).all() and (f >= 0).all()
