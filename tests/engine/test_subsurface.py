"""Subsurface scattering (engine/integrator/subsurface.py, Cycles' random walk).

* The walk against a closed form: a semi-infinite, index-matched,
  isotropically scattering half-space lit at normal incidence reflects
  R(a) = 1 - H(1; a) sqrt(1 - a) (Chandrasekhar, Radiative Transfer 1950,
  section 49; H his H-function of the single-scattering albedo a, from its
  integral form), for several albedos.
* Cycles' coefficient maps (bssrdf.h, subsurface_random_walk.h) at known points.
* Renders: a white-furnace sphere of albedo 1 stays 1; hostile radius,
  scale and open meshes give finite pixels and a warning naming the material.
"""
import math

import numpy as np
import pytest

from ember_stats import detectable, family_level, z_threshold
from engine.integrator import subsurface as ss
ss_mod = ss
from engine.render import prepare, render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
from engine.testscenes import box, look_at, quad, uv_sphere

ALBEDOS = (0.3, 0.6, 0.9)
WALKS = 20_000


def h_function(mu, a, nodes=400):
    """Chandrasekhar's H(mu) for isotropic scattering of albedo a:
    exp(-(mu / pi) int_0^{pi/2} ln(1 - a theta cot theta) / (cos^2 + mu^2 sin^2) dtheta)
    by Gauss-Legendre quadrature (the integrand is smooth)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    theta = 0.25 * math.pi * (x + 1.0)
    integrand = np.log(1.0 - a * theta / np.tan(theta)) / (np.cos(theta) ** 2 + mu * mu * np.sin(theta) ** 2)
    return math.exp(-(mu / math.pi) * 0.25 * math.pi * float(np.sum(w * integrand)))


def slab_albedo(a):
    """Diffuse reflectance of the half-space at normal incidence."""
    return 1.0 - h_function(1.0, a) * math.sqrt(1.0 - a)


def test_h_function_known_values():
    """H(1) of a conservative medium is 2.9078 (Chandrasekhar's table);
    the reflectance is 1 there and 0 without scattering."""
    assert h_function(1.0, 1.0) == pytest.approx(2.9078, abs=2e-4)
    assert slab_albedo(1e-12) == pytest.approx(0.0, abs=1e-9)


def _half_space():
    """A box 2000 mean free paths wide and deep whose top face is z = 0."""
    mesh = box((2000.0, 2000.0, 2000.0))
    mesh.positions = np.asarray(mesh.positions, np.float64) - np.array([0.0, 0.0, 1000.0])
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0)), resolution=(4, 4))
    mat = Material("slab", (Lobe("subsurface", (0.5, 0.5, 0.5)),))
    return Scene([mesh], [Instance(0, materials=[0], name="slab")], [mat], [], World((0, 0, 0)), cam)


@pytest.mark.parametrize("a", ALBEDOS)
def test_walk_reflects_the_half_space_albedo(a):
    """Walks from just under the surface straight down, sigma_t = 1,
    isotropic: the mean exit throughput is R(a), within its standard error."""
    ctx = prepare(_half_space(), RenderSettings(samples=1, seed=11, sampling_pattern="random"))
    n = WALKS
    o = np.tile([0.0, 0.0, -1e-4], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    ones = np.ones((n, 3))
    pseed = ctx.sampler.pixel_seeds(np.arange(n))
    beta, _, _, prim, _ = ss.random_walk(ctx, o, d, ones, ones, ones * a, np.zeros(n),
                                         np.zeros(n, np.int64), pseed, np.zeros(n, np.uint32), 0)
    value = np.where(prim >= 0, beta[:, 0], 0.0)
    mean, se = value.mean(), value.std(ddof=1) / math.sqrt(n)
    expected = slab_albedo(a)
    level = family_level(f"{__name__}.half_space", len(ALBEDOS))
    print(f"albedo {a}: walk {mean:.4f} +- {se:.4f}, closed form {expected:.4f}; "
          f"detects {detectable(se, level):.4f} ({detectable(se, level) / expected:.1%})")
    assert abs(mean - expected) < z_threshold(level) * se
    assert np.all(beta[:, 0] == beta[:, 1]) and np.all(beta[:, 0] == beta[:, 2])   # grey: channels agree


SLAB_CASES = (0.0, 0.6)


def _slab(thickness):
    """A box 2000 wide, ``thickness`` deep, its top face z = 0."""
    mesh = box((2000.0, 2000.0, thickness))
    mesh.positions = np.asarray(mesh.positions, np.float64) - np.array([0.0, 0.0, 0.5 * thickness])
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0)), resolution=(4, 4))
    mat = Material("slab", (Lobe("subsurface", (0.5, 0.5, 0.5)),))
    return Scene([mesh], [Instance(0, materials=[0], name="slab")], [mat], [], World((0, 0, 0)), cam)


@pytest.mark.parametrize("g", SLAB_CASES)
def test_guided_walk_matches_the_classic_walk(g):
    """Through a slab 2 mean free paths thick (its far side within the
    first step's look-ahead: Cycles' backward guiding is on) the guided
    walk reflects and transmits what the classic walk does: a two-sample
    test per side on independent walks (other seeds); the guided walk's
    variance printed against the classic one's."""
    ctx = prepare(_slab(2.0), RenderSettings(samples=1, seed=5, sampling_pattern="random"))
    n = WALKS
    o = np.tile([0.0, 0.0, -1e-4], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    ones = np.ones((n, 3))
    alpha = ones * np.array([0.95, 0.8, 0.6])
    sides = {}
    for guided, first in ((True, 0), (False, n)):
        pseed = ctx.sampler.pixel_seeds(np.arange(first, first + n))
        beta, out_o, _, prim, _ = ss.random_walk(ctx, o, d, ones, ones, alpha, np.full(n, g), np.zeros(n, np.int64),
                                                 pseed, np.zeros(n, np.uint32), 0, guided=guided)
        value = np.where(prim >= 0, beta[:, 0], 0.0)
        top = out_o[:, 2] > -1.0
        sides[guided] = [(x.mean(), x.std(ddof=1) / math.sqrt(n)) for x in (value * top, value * ~top)]
    level = family_level(f"{__name__}.guided_slab", 2 * len(SLAB_CASES))
    for k, side in enumerate(("reflected", "transmitted")):
        (mg, sg), (mc, sc) = sides[True][k], sides[False][k]
        se = math.hypot(sg, sc)
        print(f"g {g} {side}: guided {mg:.4f} +- {sg:.4f}, classic {mc:.4f} +- {sc:.4f} "
              f"(variance ratio {(sg / sc) ** 2:.2f}); detects {detectable(se, level):.4f}")
        assert abs(mg - mc) < z_threshold(level) * se


def test_hostile_walk_coefficients_stay_finite():
    """Extreme walks (albedo at Cycles' clamps, g near +-1, extinctions of
    1e-12 and 1e12, a normal along the ray): finite throughputs, no NaN."""
    ctx = prepare(_slab(2.0), RenderSettings(samples=1, seed=2, sampling_pattern="random"))
    n = 600
    rng = np.random.default_rng(8)
    o = np.tile([0.0, 0.0, -1e-4], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    sigma_t = rng.choice([1e-12, 1e-3, 1.0, 1e12], (n, 3))
    alpha = rng.choice([0.2, 0.5, 0.999999], (n, 3))
    g = rng.choice([-0.999, -0.5, 0.0, 0.9, 0.999], n)
    beta, out_o, out_d, prim, _ = ss.random_walk(ctx, o, d, np.ones((n, 3)), sigma_t, alpha, g, np.zeros(n, np.int64),
                                                 ctx.sampler.pixel_seeds(np.arange(n)), np.zeros(n, np.uint32), 0,
                                                 normal=-d)
    assert np.isfinite(beta).all() and np.isfinite(out_o).all() and np.isfinite(out_d).all()
    assert (prim >= 0).any()


def test_cycles_coefficients():
    """Cycles' maps at known points: the single-scattering albedo fit is
    0 at 0 and close to 1 at 1; the Skin radius remap is sqrt(3 (1 - a'))
    with a' the dipole albedo giving the colour back."""
    alpha = ss.single_scatter_albedo(np.array([[0.0, 0.5, 1.0]]), np.array([0.0]))
    assert alpha[0, 0] == 0.0 and 0.8 < alpha[0, 1] < 0.99 and alpha[0, 2] > 0.999
    ior = 1.4
    inv = 1.0 / ior
    f_dr = inv * (-1.440 * inv + 0.710) + 0.668 + 0.0636 * ior
    a4 = (4.0 / 3.0) * (1.0 + f_dr) / (1.0 - f_dr)
    ap = ss.dipole_alpha_prime(np.array([0.1, 0.5, 0.8]), a4)
    lo, hi = np.zeros(3), np.ones(3)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        low = ss.dipole_rd(mid, a4) < [0.1, 0.5, 0.8]
        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
    assert np.all(np.abs(ap - lo) <= 2.0 ** -12)   # Cycles' 12 bisection steps
    r = ss.remapped_radius(np.ones((1, 3)), np.array([[0.1, 0.5, 0.8]]), np.array([ior]), np.array([True]))
    np.testing.assert_allclose(r[0], np.sqrt(3.0 * (1.0 - ap)))
    r = ss.remapped_radius(np.ones((1, 3)), np.array([[0.1, 0.5, 0.8]]), np.array([ior]), np.array([False]))
    np.testing.assert_allclose(r[0], 0.25 / math.pi)


def _ball(lobe, mesh=None, world=(1.0, 1.0, 1.0), size=(10, 10)):
    mesh = uv_sphere(1.0, 32, 16) if mesh is None else mesh
    cam = Camera(look_at((0, -4, 0), (0, 0, 0)), kind="ORTHO", ortho_scale=2.4, resolution=size,
                 clip_start=0.01, clip_end=100.0)
    return Scene([mesh], [Instance(0, materials=[0], name="ball")], [Material("wax", (lobe,))], [],
                 World(world), cam)


# Skin scales the radius of albedo 1 by sqrt(3 (1 - 0.999999)) = 0.0017.
@pytest.mark.parametrize("kind,radius", [("subsurface", 20.0), ("subsurface_skin", 1e4)])
def test_white_furnace_sphere(kind, radius):
    """Albedo 1 in a white world: walks lose nothing but the paths past
    256 scatterings (a radius of several sphere sizes keeps those rare), so
    pixels are 1.  Flat shading: with a smooth normal some entry directions
    leave above the triangle, and Cycles drops those (so does Ember)."""
    r = render(_ball(Lobe(kind, (1.0, 1.0, 1.0), 0.5, ior=1.4, radius=(radius,) * 3), uv_sphere(1.0, 32, 16, False)),
               RenderSettings(samples=8, samples_per_pass=8, max_bounces=64, rr_depth=1000, seed=3))
    img = r.image[..., :3]
    print(kind, img.mean(), img.min())
    assert np.all(np.abs(img - 1.0) < 2e-3)


@pytest.mark.parametrize("kind", ["subsurface", "subsurface_burley"])
@pytest.mark.parametrize("radius", [(0.0, 0.0, 0.0), (1e30, 1e30, 1e30), (float("nan"), 1.0, 1.0),
                                    (float("inf"), 1e-12, 0.5)])
def test_hostile_radius_renders_finite(radius, kind):
    r = render(_ball(Lobe(kind, (0.8, 0.5, 0.3), 0.5, radius=radius), size=(6, 6)),
               RenderSettings(samples=2, samples_per_pass=2, max_bounces=8))
    assert np.isfinite(r.image).all()


@pytest.mark.parametrize("mesh", ["quad", "triangle"])
def test_open_mesh_is_named(mesh):
    """Subsurface on an open mesh: walks may never come out (as in Cycles);
    finite pixels and a warning naming the object and the material."""
    if mesh == "quad":
        m = quad([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]])
    else:
        m = quad([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]])
        m.triangles = np.asarray(m.triangles)[:1]
    r = render(_ball(Lobe("subsurface", (0.8, 0.8, 0.8), radius=(0.5, 0.5, 0.5)), mesh=m, size=(6, 6)),
               RenderSettings(samples=2, samples_per_pass=2, max_bounces=4))
    assert np.isfinite(r.image).all()
    assert any("'wax'" in w and "'ball'" in w and "not closed" in w for w in r.warnings), r.warnings


def test_walk_kernels_agree():
    """The walk's two row loops, compiled, against their NumPy forms (to
    rounding: numba calls libm, NumPy its own transcendentals), on the
    first step (look-ahead, opposite side) and later ones (classic,
    guided forward and backward)."""
    from engine import kernels
    rng = np.random.default_rng(4)
    n = 5000
    u, u2 = rng.random((n, 4)), rng.random((n, 4))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    d[:5] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, -1, 0], [0.6, 0, -0.8]]
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    g = rng.uniform(-1.0, 1.0, n)
    g[:50] = 0.0
    b = rng.random((n, 3))
    b[:20] = 0.0
    a = rng.uniform(0.2, 0.999999, (n, 3))
    st = rng.uniform(0.1, 10.0, (n, 3))
    o, p0 = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    hit = rng.random(n) < 0.3
    t_hit = rng.random(n)
    state = ss_mod._walk_state(o, d, b, st, a, g, nrm, p0, True)
    for scatter, similar in ((False, False), (True, False), (True, True)):
        state[:, ss_mod.HAVE] = rng.random(n) < 0.5
        state[:, ss_mod.OPP] = rng.uniform(-0.5, 3.0, n)
        results = []
        for jit in (False, True):
            kernels.configure(jit)
            st8, t, tmax, terms = state.copy(), np.empty(n), np.empty(n), np.empty((n, 6))
            ss_mod._direction_rows(u, u2, st8, scatter, similar, 0.75, t, tmax, terms)
            hv, t2, done = hit.copy(), t.copy(), np.empty(n, bool)
            ss_mod._advance_rows(hv, t_hit, t2, st8, terms, scatter, similar, done)
            results.append((t, tmax, terms, st8, t2, hv, done))
        for x, y in zip(results[0][:5], results[1][:5]):
            np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-12)
        for x, y in zip(results[0][5:], results[1][5:]):
            assert np.array_equal(x, y)


def test_burley_root_inverts_its_cdf():
    """bssrdf_burley_root_find: the scaled radius whose CDF
    1 - e^-r / 4 - 3 e^(-r/3) / 4 is xi."""
    xi = np.linspace(0.0, 0.99, 100)
    r = ss.burley_root(xi)
    np.testing.assert_allclose(1.0 - 0.25 * np.exp(-r) - 0.75 * np.exp(-r / 3.0), xi, atol=2e-6)


def test_burley_on_a_plane_is_its_albedo():
    """Christensen-Burley on a flat surface in a white world: the profile
    integrates to 1 over the plane (every probe along the normal finds the
    point; those along the tangents find none), so the surface reflects
    its colour; within the render's standard error."""
    mesh = box((20.0, 20.0, 20.0))
    mesh.positions = np.asarray(mesh.positions, np.float64) - np.array([0.0, 0.0, 10.0])
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0)), kind="ORTHO", ortho_scale=2.0, resolution=(12, 12),
                 clip_start=0.01, clip_end=100.0)
    colour = (0.8, 0.5, 0.2)
    scene = Scene([mesh], [Instance(0, materials=[0], name="slab")],
                  [Material("marble", (Lobe("subsurface_burley", colour, radius=(0.05, 0.1, 0.2)),))], [],
                  World((1, 1, 1)), cam)
    r = render(scene, RenderSettings(samples=32, samples_per_pass=32, max_bounces=8, seed=2, sampling_pattern="random"))
    mean = r.image[..., :3].mean(axis=(0, 1))
    se = np.sqrt(r.variance[..., :3].sum(axis=(0, 1))) / 144
    level = family_level(f"{__name__}.burley_plane", 3)
    print(f"Burley plane: {mean} +- {se} against {colour}; detects {detectable(se.max(), level):.4f}")
    assert np.all(np.abs(mean - colour) < z_threshold(level) * np.maximum(se, 1e-9))


@pytest.mark.parametrize("pattern", ["random", "sobol"])
def test_whole_walk_agrees_with_the_wavefront(pattern):
    """The compiled walk (each walk start to exit in one loop, rtcIntersect1
    in the object's own Embree scene, the sampler's numbers per walk) and
    its NumPy form (the wavefront through Embree packets) against the
    NumPy wavefront through the object's Accel (embreex) and the sampler:
    the same numbers drive all three, so walk by walk the exits agree to
    rounding (a ray grazing an edge may meet the other triangle: a few in
    10^4 may differ), and the mean exit throughput by a paired z-test."""
    from engine import kernels
    ctx = prepare(_slab(2.0), RenderSettings(samples=1, seed=7, sampling_pattern=pattern))
    n = 4000
    o = np.tile([0.0, 0.0, -1e-4], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    ones = np.ones((n, 3))
    alpha = ones * np.array([0.95, 0.8, 0.6])
    g = np.where(np.arange(n) % 2 == 0, 0.0, 0.6)
    pseed = ctx.sampler.pixel_seeds(np.arange(n))
    sample = np.arange(n, dtype=np.uint32) % 7

    def walk(jit, whole):
        kernels.configure(jit)
        return ss.random_walk(ctx, o, d, ones, ones, alpha, g, np.zeros(n, np.int64), pseed, sample, 1, whole=whole)
    try:
        ref = walk(False, False)
        forms = {"compiled": walk(True, True), "numpy": walk(False, True)}
    finally:
        kernels.configure(True)
    level = family_level(f"{__name__}.whole_walk", 4)
    for name, got in forms.items():
        same = (got[3] == ref[3]) & np.all(np.isclose(got[0], ref[0], rtol=1e-6, atol=1e-12), axis=1) \
            & np.all(np.isclose(got[1], ref[1], rtol=1e-6, atol=1e-9), axis=1)
        diff = np.where(got[3] >= 0, got[0][:, 0], 0.0) - np.where(ref[3] >= 0, ref[0][:, 0], 0.0)
        se = max(diff.std(ddof=1) / math.sqrt(n), 1e-12)
        mean = max(abs(ref[0][:, 0][ref[3] >= 0]).mean(), 1e-12)
        print(f"{pattern} {name}: {same.mean():.5f} of walks agree; mean difference {diff.mean():.2e} +- {se:.1e}"
              f" (detects a relative mean exit-throughput difference of {detectable(se, level) / mean:.1e})")
        assert same.mean() > 0.998
        assert abs(diff.mean()) < z_threshold(level) * se or abs(diff.mean()) < 1e-9
