"""Compiled kernels (numba) against the same functions run by NumPy.

engine/kernels.py runs one source two ways (and keeps NumPy reference forms
of its row loops); these tests require the two to agree within rounding
(tests/engine/rounding.py: the spread that last-bit differences in every
transcendental produce, element by element), kernel by kernel on random and
degenerate inputs (zeros, infinities, NaN, grazing angles), and as whole
fixed-seed renders by a z-test on their difference.
Under CI=true a missing numba fails instead of skipping.
"""
import os

import numpy as np
import pytest

from engine import kernels
from engine.bsdf import ggx_reflect
from engine.render import render
from engine import sampling
from engine.sampling import power_heuristic, spherical_rectangle_warp
from engine.scene import RenderSettings
from engine.testscenes import cornell_spheres
from rounding import assert_rounding_close, rounding_spread
import ember_stats


def require_numba():
    if kernels.AVAILABLE:
        return
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail("numba is required under CI=true: " + str(kernels.UNAVAILABLE))
    pytest.skip(str(kernels.UNAVAILABLE))


def compiled_ready():
    require_numba()
    kernels.configure(True)
    assert kernels.wait(600), kernels.UNAVAILABLE


@pytest.fixture
def jit():
    compiled_ready()
    yield
    kernels.configure(True)


class Reference(tuple):
    """The NumPy form's outputs, with how far rounding may move each element
    (tests/engine/rounding.py)."""
    spread = None


def _numpy_form(kernel, *args):
    kernels.configure(False)
    try:
        return kernel(*args)
    finally:
        kernels.configure(True)


def both_ways(kernel, *args):
    """The NumPy reference form's outputs (with their rounding spread) and
    the compiled form's, for the same arguments."""
    base, spread = rounding_spread(lambda *a: _numpy_form(kernel, *a), args)
    plain = Reference(base)
    plain.spread = spread
    kernels.configure(True)
    compiled = kernel(*args)
    return plain, tuple(compiled) if isinstance(compiled, tuple) else (compiled,)


def assert_agree(plain, compiled, what=""):
    """Within rounding, not bit for bit: numba calls libm while NumPy may
    run SIMD transcendentals (AVX-512), so the last bits differ by CPU.
    A render never mixes the two forms (engine/kernels.py: the choice is
    made once per render), so nothing needs them to round alike."""
    spread = getattr(plain, "spread", None) or [np.zeros(np.shape(a)) for a in plain]
    plain, compiled = tuple(plain), tuple(compiled)
    assert_rounding_close(plain, compiled, spread, what)


def mixed(rng, n, scale=1.0):
    """Random values with zeros, signed infinities, NaN and huge/tiny ones mixed in."""
    x = rng.normal(0.0, scale, n)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-300, -1e300, 1.0, -1.0])
    pick = rng.random(n) < 0.05
    x[pick] = rng.choice(special, pick.sum())
    return x


def test_power_heuristic_agrees(jit):
    rng = np.random.default_rng(1)
    a, b = np.abs(mixed(rng, 20000, 3.0)), np.abs(mixed(rng, 20000, 3.0))
    plain, compiled = both_ways(power_heuristic, a, b)
    assert_agree(plain, compiled)
    # Broadcast scalars as NumPy does.
    assert_agree(*both_ways(power_heuristic, a, 2.0))


def test_spherical_rectangle_warp_agrees(jit):
    rng = np.random.default_rng(2)
    n = 20000
    args = (mixed(rng, n), mixed(rng, n), np.abs(mixed(rng, n)), 0.5, np.abs(rng.normal(size=n)),
            rng.random(n), rng.random(n))
    assert_agree(*both_ways(spherical_rectangle_warp, *args))


def test_area_light_sample_agrees(jit):
    """The area light's fused sampling kernel, and the solid angle the MIS
    pdf of a light hit uses (the warp's, to the bit: both choose the same
    strategy for the same point)."""
    from engine.lights import _area_light_sample
    rng = np.random.default_rng(12)
    n = 20000
    p = [mixed(rng, n, 2.0) for _ in range(3)]
    c = [0.3, -0.2, 1.5]
    ex, ey = [1.0, 0.0, 0.0], [0.0, np.sqrt(0.5), np.sqrt(0.5)]
    n_light = [0.0, np.sqrt(0.5), -np.sqrt(0.5)]
    rect = (rng.random(n) < 0.8).astype(float)
    x, y = rng.random(n) - 0.5, rng.random(n) - 0.5
    args = (*p, *c, *ex, *ey, 0.7, np.abs(mixed(rng, n)), *n_light, 0.7, rect, x, y, rng.random(n),
            rng.random(n), 3e-4)
    plain, compiled = both_ways(_area_light_sample, *args)
    assert_agree(plain, compiled)
    solid_angle = both_ways(sampling.rectangle_solid_angle, *args[:14])
    assert_agree(*solid_angle)
    with np.errstate(all="ignore"):   # infinite points: NaN coordinates, as in the kernel
        xc, yc, z0, _, _, _ = sampling.rectangle_frame(*args[:12])
        z0 = np.where(z0 > 0, -z0, z0)
    warp = spherical_rectangle_warp(xc, yc, z0, *args[12:14], *args[-3:-1])
    assert_agree(solid_angle[0], warp[2:])


def test_area_light_rows_agree(jit):
    """The area lights' sampling loop (engine/lights/area.py _area_sample_rows):
    compiled against its NumPy form for rectangles (solid angle and area
    sampled), squares, disks, ellipses and a light of no area, one light per
    row, shading points behind, in and far from the lights' planes; and, on
    one rectangle, bit for bit the elementwise kernel it runs per row."""
    from engine.lights import AreaLights, _area_light_sample, _area_sample_rows
    from engine.lights.common import MIN_SPHERICAL
    from engine.scene import AreaLight

    def at(x, y, z, rx=0.0):
        m = np.eye(4)
        m[:3, 3] = x, y, z
        c, s = np.cos(rx), np.sin(rx)
        m[1:3, 1:3] = [[c, -s], [s, c]]
        return m
    lights = [AreaLight(at(0, 0, 2), (10.0, 10.0, 10.0), "RECTANGLE", 1.0, 0.6),
              AreaLight(at(1, 0, 1, 0.7), (5.0, 5.0, 5.0), "SQUARE", 0.01),
              AreaLight(at(0, 1, 1), (3.0, 3.0, 3.0), "DISK", 0.8),
              AreaLight(at(0, -1, 1, -0.4), (3.0, 2.0, 1.0), "ELLIPSE", 1.2, 0.5),
              AreaLight(at(2, 2, 2), (1.0, 1.0, 1.0), "RECTANGLE", 0.0, 1.0)]
    table = AreaLights(lights)
    rng = np.random.default_rng(33)
    n = 20000
    j = rng.integers(0, len(lights), n)
    p = rng.normal(size=(n, 3)) * 2.0
    p[:100] = table.c[0] + [0.1, 0.05, 0.0]              # in the rectangle's plane
    p[100:200] = table.c[1] + 30.0 * table.n[1]          # far from the tiny square
    j[:100], j[100:200] = 0, 1
    u = rng.random((n, 3))
    u1, u2 = u[:, 0], u[:, 1]                            # strided, as the sampler's columns
    u1[200:210] = u2[200:210] = 0.5                      # the disk's centre

    def run(j=j, p=p, u1=u1, u2=u2):
        m = len(j)
        outs = (np.empty((m, 3)), np.empty(m), np.empty(m))
        _area_sample_rows(j, p, u1, u2, table.c, table.ex, table.ey, table.n, table.len_u, table.len_v,
                          table.area, table.rect, table.ellipse, MIN_SPHERICAL, *outs)
        return outs
    plain, compiled = both_ways(run)
    assert_agree(plain, compiled)
    assert (plain[2][j == 4] == 0).all() and (plain[2][j == 2] > 0).any()
    one = j == 0
    rows = run(j[one].copy(), p[one].copy(), u1[one].copy(), u2[one].copy())
    c, ex, ey, nl = table.c[0], table.ex[0], table.ey[0], table.n[0]
    q = p[one]
    kernel = _area_light_sample(q[:, 0], q[:, 1], q[:, 2], *c, *ex, *ey, table.len_u[0], table.len_v[0], *nl,
                                table.area[0], 1.0, u1[one] - 0.5, u2[one] - 0.5, u1[one], u2[one], MIN_SPHERICAL)
    assert np.array_equal(rows[0], np.stack(kernel[:3], axis=1), equal_nan=True)
    assert np.array_equal(rows[1], kernel[3], equal_nan=True) and np.array_equal(rows[2], kernel[4], equal_nan=True)


def test_area_light_hits_agree(jit):
    """Rays meeting an area light (engine/lights/area.py _area_hit_rows): the
    compiled loop against its NumPy form for a rectangle (solid-angle and
    area pdfs), a tiny square, a disk and an ellipse, with rays
    from behind, grazing, parallel to the plane and through the edges."""
    from engine.lights import AreaLights, _area_hit_rows
    from engine.lights.common import MIN_SPHERICAL
    from engine.scene import AreaLight
    m = np.eye(4)
    m[:3, 3] = 0.2, -0.1, 2.0
    lights = [AreaLight(m, (10.0, 10.0, 10.0), shape, sx, sy)
              for shape, sx, sy in (("RECTANGLE", 1.0, 0.6), ("SQUARE", 0.01, 0.01), ("DISK", 0.8, 0.8),
                                    ("ELLIPSE", 1.2, 0.5))]
    table = AreaLights(lights)
    rng = np.random.default_rng(34)
    n = 20000
    o = rng.normal(size=(n, 3))
    o[:200, 2] = 40.0                                    # far: the area pdf on the rectangle
    target = table.c[0] + rng.uniform(-0.7, 0.7, (n, 3)) * [1.0, 1.0, 0.0]
    d = target - o
    d[200:300, 2] = 0.0                                  # parallel to the plane
    d /= np.linalg.norm(d, axis=1)[:, None]
    d[300:400] *= -1.0                                   # away from the light
    for j in range(len(lights)):
        def run():
            outs = (np.empty(n), np.empty(n), np.empty(n, bool))
            _area_hit_rows(o, d, j, table.c, table.n, table.du, table.dv, table.ex, table.ey, table.len_u,
                           table.len_v, table.area, table.rect, table.ellipse, MIN_SPHERICAL, *outs)
            return outs
        plain, compiled = both_ways(run)
        assert_agree(plain, compiled, f"light {j}")
        assert plain[2].any() and not plain[2][200:400].any()
        assert np.array_equal(plain[2], np.isfinite(plain[0]))


def test_light_tree_importance_agrees(jit):
    from engine.lighttree import _importance
    rng = np.random.default_rng(6)
    n = 20000
    args = [mixed(rng, n, 2.0) for _ in range(6)]                 # p, n
    args += [(rng.random(n) < 0.5).astype(float)]                  # one-sided (no transmission)
    args += [mixed(rng, n, 2.0) for _ in range(3)]                 # centre
    args += [np.abs(mixed(rng, n))] + [mixed(rng, n) for _ in range(3)]   # radius, axis
    args += [(rng.random(n) < 0.5).astype(float)]                  # two-sided
    cos_o, cos_e = np.cos(rng.random(n) * np.pi), np.cos(rng.random(n) * np.pi / 2)
    args += [np.sqrt(1.0 - cos_o ** 2), cos_o, cos_e, np.abs(mixed(rng, n))]
    args[3][:100] = args[4][:100] = args[5][:100] = 0.0           # no normal
    assert_agree(*both_ways(_importance, *args))


def test_light_tree_segment_importance_agrees(jit):
    """A node's importance along a ray segment (lighttree._segment_importance),
    compiled and NumPy: random segments, some of no end, some through the
    node's centre, some of length 0."""
    from engine.lighttree import _segment_importance
    rng = np.random.default_rng(16)
    n = 20000
    o = [mixed(rng, n, 2.0) for _ in range(3)]
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    t = rng.random(n) * 6.0
    t[:500], t[500:600] = np.inf, 0.0
    c = [mixed(rng, n, 2.0) for _ in range(3)]
    for k in range(3):
        c[k][600:700] = o[k][600:700] + d[k][600:700] * 0.5 * t[600:700]   # the centre on the segment
    w = rng.normal(size=(3, n))
    w /= np.linalg.norm(w, axis=0)
    cos_o, cos_e = np.cos(rng.random(n) * np.pi), np.cos(rng.random(n) * np.pi / 2)
    args = [*o, *d, t, *c, np.abs(mixed(rng, n)), *w, (rng.random(n) < 0.5).astype(float),
            np.sqrt(1.0 - cos_o ** 2), cos_o, cos_e, np.abs(mixed(rng, n))]
    assert_agree(*both_ways(_segment_importance, *args))


def test_area_light_visibility_agrees(jit):
    """Cycles' area-light test at vertices without transmission
    (lighttree._rect_visible), compiled and NumPy, over random lights
    about p, some behind it, some edge-on, some at p itself."""
    from engine.lighttree import _rect_visible
    rng = np.random.default_rng(9)
    n = 20000
    args = [mixed(rng, n, 2.0) for _ in range(18)]
    args[6][:50] = args[0][:50]
    args[7][:50] = args[1][:50]
    args[8][:50] = args[2][:50]                                    # the centre at p
    plain, compiled = both_ways(_rect_visible, *args)
    assert_agree(plain, compiled)
    assert 0.2 < np.mean(plain[0]) < 0.8, np.mean(plain[0])


def test_sobol_sampler_agrees(jit):
    """The compiled Sobol loop (uint32 maths in uint64) and the table-driven
    NumPy form give the same numbers, for every dimension set kind and
    sample indices over the whole uint32 range."""
    from engine import sampler
    rng = np.random.default_rng(5)
    n = 50000
    pseed = rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32)
    sample = np.concatenate([np.arange(n // 2), rng.integers(0, 2 ** 32, n - n // 2, dtype=np.uint64)])
    sample = sample.astype(np.uint32)
    for dim_set in (sampler.CAMERA, sampler.vertex_set(3, sampler.BSDF), sampler.emitter_set(7, 12345)):
        plain, compiled = both_ways(sampler.sobol4, pseed, sample, dim_set)
        assert_agree(plain, compiled)
        assert np.all((plain[0] >= 0) & (plain[0] < 1))


def test_ggx_reflect_agrees(jit):
    rng = np.random.default_rng(3)
    n = 20000
    wo = rng.normal(size=(n, 3))
    wi = rng.normal(size=(n, 3))
    wi[:50] = -wo[:50]          # h = 0
    wo[50:100, 2] = 1e-12       # grazing
    for v in (wo, wi):
        v /= np.linalg.norm(v, axis=1, keepdims=True)
    alpha = np.clip(rng.random(n), 1e-4, 1.0)
    args = (*wo.T, *wi.T, alpha)
    assert_agree(*both_ways(ggx_reflect, *args))


def test_disabled_by_setting(jit):
    assert kernels.configure(False) is False
    assert not kernels.enabled()
    assert kernels.configure(True) is True


def test_disabled_by_environment():
    """EMBER_JIT=0: nothing is compiled, the NumPy forms run."""
    import subprocess
    import sys
    code = ("from engine import kernels, sampling; import numpy as np; "
            "assert not kernels.AVAILABLE and kernels.UNAVAILABLE == 'EMBER_JIT=0'; "
            "assert kernels.configure(True) is False and not kernels.wait(1); "
            "assert float(sampling.power_heuristic(np.ones(1), np.ones(1))[0]) == 0.5; "
            "assert all(k.compiled is None for k in kernels.KERNELS); print('ok')")
    env = dict(os.environ, EMBER_JIT="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr


@pytest.fixture(scope="module")
def renders():
    """A glossy Cornell scene (rectangle light: spherical-rectangle warp;
    GGX spheres) at a fixed seed, with compiled kernels and without."""
    if not kernels.AVAILABLE:
        return None
    compiled_ready()
    scene = cornell_spheres(40, 40, grid=3, segments=16, rings=8)
    out = {}
    for jit in (False, True):
        settings = RenderSettings(samples=8, seed=11, max_bounces=4, use_jit=jit, threads=2)
        out[jit] = render(scene, settings).image
        # Every other kind of light the loops handle: a sun with a disc, a
        # sphere light, an HDRI seen through the open front; Gaussian filter.
        settings = RenderSettings(samples=4, seed=12, max_bounces=3, use_jit=jit, threads=2,
                                  filter_type="GAUSSIAN", filter_width=2.0)
        out[jit, "lights"] = render(_open_scene_with_every_light(scene), settings).image
    kernels.configure(True)
    return out


def _open_scene_with_every_light(scene):
    import dataclasses
    from engine.scene import EnvironmentTexture, PointLight, SunLight, World
    rng = np.random.default_rng(28)
    lights = list(scene.lights) + [SunLight((0.3, 0.4, -0.87), (2.0, 1.8, 1.5), angle=0.2),
                                   PointLight((0.2, 0.3, 0.5), (5.0, 5.0, 5.0), radius=0.1)]
    world = World(texture=EnvironmentTexture(rng.random((16, 32, 3)).astype(np.float32)))
    return dataclasses.replace(scene, lights=lights, world=world)


@pytest.mark.parametrize("which", [None, "lights"])
def test_fixed_seed_render_agrees_with_and_without_jit(renders, which):
    """The same random numbers through the same maths on two code paths:
    where rounding flips a decision (a light, a lobe, roulette) a path goes
    elsewhere, and the pixel's two estimates differ by a zero-mean error.
    So most pixels agree to float32 rounding, and the mean difference over
    the image is zero within its standard error (z-test, the suite's
    budget)."""
    require_numba()
    key = (lambda jit: jit) if which is None else (lambda jit: (jit, which))
    plain, compiled = renders[key(False)], renders[key(True)]
    assert np.isfinite(compiled).all() and compiled.max() > 0
    rgb_p, rgb_c = plain[..., :3].astype(np.float64), compiled[..., :3].astype(np.float64)
    rounding = 4 * np.spacing(np.maximum(np.abs(rgb_p), np.abs(rgb_c)).astype(np.float32))
    close = np.abs(rgb_c - rgb_p) <= rounding
    assert close.mean() > 0.5, f"only {close.mean():.1%} of pixel values agree to float32 rounding"
    d = (rgb_c - rgb_p).ravel()
    level = ember_stats.family_level(f"jit render difference {which}")
    if np.all(d == 0):
        print(f"jit/no-jit {which}: identical images")
        return
    se = d.std(ddof=1) / np.sqrt(d.size)
    z = d.mean() / se
    print(ember_stats.power_line(f"jit/no-jit {which}", se / max(rgb_p.mean(), 1e-12), level))
    assert abs(z) < ember_stats.z_threshold(level), f"mean difference {d.mean():.3g} is {z:.1f} standard errors"


def test_light_tree_descent_agrees(jit):
    """The compiled descent and path pmf give the NumPy forms' picks and
    probabilities (within rounding), points with and without normals, on a tree
    with an infinite emitter (a sun) next to hundreds of bounded ones."""
    from engine.lighttree import Bounds, LightTree
    rng = np.random.default_rng(8)
    bounds = [None]
    for k in range(300):
        c = rng.normal(size=3) * 3.0
        r = rng.random() * 0.3
        w = rng.normal(size=3)
        cos_o = np.cos(rng.random() * np.pi)
        rect = (c, rng.normal(size=3) * r, rng.normal(size=3) * r) if k % 3 == 0 else None   # an area light's
        bounds.append(Bounds(c - r, c + r, rng.random() * 10.0 * (k % 7 != 0), w / np.linalg.norm(w),
                             cos_o, np.cos(rng.random() * np.pi / 2), k % 2 == 0, rect=rect))
    tree = LightTree(bounds)
    n = 20000
    p = rng.normal(size=(n, 3)) * 4.0
    nn = rng.normal(size=(n, 3))
    nn /= np.linalg.norm(nn, axis=1)[:, None]
    nn[:500] = 0.0
    u = rng.random(n)
    u[:20] = 0.0
    plain, compiled = both_ways(tree.select, u, p, nn)
    assert_agree(plain, compiled)
    emitter = rng.integers(0, len(bounds), n)
    assert_agree(*both_ways(tree.pmf, emitter, p, nn))
    assert_agree(*both_ways(tree.pmf, plain[0], p, nn))
    # Two compiled paths to one product of per-level probabilities (at most
    # about 20 levels of a few roundings each).
    np.testing.assert_allclose(tree.pmf(plain[0], p, nn), plain[1], rtol=64 * np.finfo(float).eps, atol=0)
    # Several ascending numbers per point (resampled selection's strata):
    # the compiled descent reuses the levels a row's descents share.
    strata = np.minimum((u[:, None] + np.arange(4)) / 4, np.nextafter(1.0, 0.0))
    many = both_ways(tree.select_many, strata, p, nn)
    assert_agree(*many)
    for k in range(4):
        assert_agree(tuple(a[:, k] for a in many[0]), tree.select(strata[:, k], p, nn))
    # With glossy-lobe terms (light selection 'tree_bsdf'): the same agreements.
    lobe = np.empty((n, 5))
    r = rng.normal(size=(n, 3))
    lobe[:, :3] = r / np.linalg.norm(r, axis=1)[:, None]
    lobe[:, 3], lobe[:, 4] = rng.uniform(0.02, 1.0, n), rng.uniform(0.0, 0.9, n)
    plain, compiled = both_ways(tree.select, u, p, nn, lobe)
    assert_agree(plain, compiled)
    assert_agree(*both_ways(tree.pmf, plain[0], p, nn, lobe))
    # Points without transmission (a fourth column 1 on half the rows): the
    # signed incidence and the leaf test, in both forms.
    sided = np.concatenate([nn, (rng.random((n, 1)) < 0.5).astype(float)], axis=1)
    one_plain, one_compiled = both_ways(tree.select, u, p, sided)
    assert_agree(one_plain, one_compiled)
    assert (one_plain[1] == 0).mean() > 0.05
    assert_agree(*both_ways(tree.pmf, emitter, p, sided))
    assert_agree(*both_ways(tree.select_many, strata, p, sided))
    np.testing.assert_allclose(tree.pmf(plain[0], p, nn, lobe), plain[1], rtol=64 * np.finfo(float).eps, atol=0)
    # Ray segments in volumes (select_segment): the same agreements.
    t = rng.random(n) * 8.0
    t[:1000] = np.inf
    dd = nn.copy()
    dd[:500] = 1.0 / np.sqrt(3.0)   # the rows without a normal: any unit direction
    seg_plain, seg_compiled = both_ways(tree.select_segment, u, p, dd, t)
    assert_agree(seg_plain, seg_compiled)
    assert_agree(*both_ways(tree.pmf_segment, emitter, p, dd, t))
    # The compiled descent's probability is the compiled path pmf of its pick.
    np.testing.assert_allclose(tree.pmf_segment(seg_compiled[0], p, dd, t), seg_compiled[1],
                               rtol=64 * np.finfo(float).eps, atol=0)


def test_hit_geometry_agrees(jit):
    """Hit points and normals from the compiled loop and the NumPy form, bit
    for bit: rays parallel to their triangle (Embree's t kept), shading
    normals facing away from the viewer or zero, back faces, flat meshes."""
    from engine import hits
    rng = np.random.default_rng(14)
    tris, n = 50, 20000
    ng = rng.normal(size=(tris, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    p0 = rng.normal(size=(tris, 3))
    ns = rng.normal(size=(tris, 3, 3))
    ns[:3] = 0.0
    o, d = rng.normal(size=(n, 3)) * 3.0, rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    prim = rng.integers(0, tris, n)
    d[:200] -= ng[prim[:200]] * np.einsum("ij,ij->i", d[:200], ng[prim[:200]])[:, None]   # parallel
    t, bu = rng.random(n) * 5.0, rng.random(n)
    bv = rng.random(n) * (1.0 - bu)

    def run(smooth):
        outs = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, bool))
        hits._hit_geometry(o, d, t, prim, bu, bv, ng, p0, ns, smooth, *outs)
        return outs
    for smooth in (True, False):
        plain, compiled = both_ways(run, smooth)
        assert_agree(plain, compiled)


def test_nearest_point_light_agrees(jit):
    """The compiled nearest-light loop over spheres and soft-falloff disks,
    against the NumPy loop over lights, bit for bit: visibility bits, lights
    of radius 0, rays starting inside a sphere, a closer tmax, a tmin past
    some hits (those rays meet the next light or none)."""
    from engine.lights import _nearest_point
    rng = np.random.default_rng(16)
    n, lights = 20000, 24
    pos = rng.normal(size=(lights, 3)) * 2.0
    radius = np.abs(rng.normal(size=lights)) * 0.5
    radius[:2] = 0.0
    sphere = rng.random(lights) < 0.5
    sphere[5:7] = True
    light_bits = rng.integers(0, 16, lights).astype(np.uint8)
    light_bits[5:7] = 15
    radius[5:7] = 0.8
    o = rng.normal(size=(n, 3)) * 3.0
    o[:100] = pos[5]                                   # inside a light
    o[100:200] = pos[6] + 0.3 * radius[6]
    target = pos[rng.integers(0, lights, n)] + rng.normal(size=(n, 3)) * 0.3
    d = target - o
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-30)[:, None]
    ray_bits = rng.integers(0, 16, n).astype(np.uint8)
    tmax = np.where(rng.random(n) < 0.2, rng.random(n) * 3.0, np.inf)
    tmin = np.where(rng.random(n) < 0.3, rng.random(n) * 4.0, 0.0)

    def run(tmin):
        outs = (tmax.copy(), np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n))
        _nearest_point(o, d, outs[0], tmin, ray_bits, pos, radius, sphere, light_bits, *outs[1:])
        return outs
    plain, compiled = both_ways(run, np.zeros(n))
    assert_agree(plain, compiled)
    assert (plain[2] >= 0).sum() > n // 4
    # From inside: the far side at pdf 1 / (4 pi) (Cycles 5.0's uniform sphere).
    inner = np.flatnonzero((plain[2][:200] == np.repeat([5, 6], 100)) & np.isinf(tmax[:200]))
    assert len(inner) > 50
    far = o[inner] + d[inner] * plain[1][inner, None] - pos[plain[2][inner]]
    assert np.allclose(np.linalg.norm(far, axis=1), radius[plain[2][inner]])
    assert np.allclose(plain[3][inner], 1.0 / (4.0 * np.pi))
    away = np.einsum("ij,ij->i", d[100:200], o[100:200] - pos[6]) >= 0   # leaving the centre: hit too
    assert (plain[2][100:200][away] == 6).any() and (plain[2][100:200][~away] == 6).any()
    past, compiled = both_ways(run, tmin)
    assert_agree(past, compiled)
    hit = past[2] >= 0
    assert (past[1][hit] > tmin[hit]).all()
    # Rays whose first hit lies before tmin lose it: some meet no light then, some a farther one.
    lost = (plain[2] >= 0) & (plain[1] <= tmin)
    assert lost.sum() > 500 and (past[2][lost] < 0).any() and (past[2][lost] >= 0).any()


def _double_plus_one(x):
    return 2.0 * x + 1.0


def test_kernels_defined_after_a_compile_are_compiled_too(jit):
    """A kernel defined after the background compile ran (a module imported
    later, as the add-on imports the renderer after an early configure) is
    compiled at the next ``configure``, not left on its NumPy form."""
    late = kernels.Kernel(_double_plus_one, 1, 1)
    try:
        assert late.compiled is None
        assert kernels.configure(True)
        assert kernels.wait(600) and late.compiled is not None
        x = np.linspace(-3.0, 3.0, 101)
        assert_agree(*both_ways(late, x))
    finally:
        kernels.KERNELS.remove(late)


def test_place_rows_agrees(jit):
    """Edges, face normals, unit shading normals and the kept triangles of
    flatten's compiled row loop against its NumPy form, bit for bit:
    degenerate and non-finite triangles, zero and NaN shading normals, flat
    rows in a smooth mesh, meshes without normals."""
    from engine.geometry import _place_rows
    rng = np.random.default_rng(21)
    verts, tris = 3000, 70000   # more than one NumPy chunk
    vertices = rng.normal(size=(verts, 3)) * 10.0
    vertices[:3] = vertices[3]            # a degenerate triangle below
    vertices[4] = np.nan
    vertices[5] = np.inf
    indices = rng.integers(8, verts, (tris, 3))
    indices[0] = (0, 1, 2)
    indices[1, 0], indices[2, 1] = 4, 5
    indices[3] = (6, 7, 7)
    smooth = rng.random(tris) < 0.8
    ns0 = rng.normal(size=(tris, 3, 3))
    ns0[10:20] = 0.0
    ns0[20:30, 1] = np.nan
    indices[100:110, 2] = indices[100:110, 0]   # degenerate

    def run(has_ns):
        outs = [np.empty((tris, 3)) for _ in range(4)] + [np.empty(tris)]
        ns = ns0.copy() if has_ns else np.empty((0, 3, 3))
        keep = np.empty(tris, bool)
        _place_rows(vertices, indices, smooth, has_ns, *outs, ns, keep)
        return (*outs, ns, keep)
    for has_ns in (True, False):
        plain, compiled = both_ways(run, has_ns)
        assert_agree(plain, compiled)
        a, b, c = indices.T
        dropped = (a == b) | (b == c) | (a == c)        # rows 3, 100-109 and chance repeats
        dropped[:3] = True                              # same points, NaN, inf
        np.testing.assert_array_equal(plain[-1], ~dropped)


def test_frame_and_rotations_agree(jit):
    """Shading frames, to_local / to_world and offset_origin: the compiled
    row loops against their NumPy forms, bit for bit, on unit and odd
    normals (poles, -0.0, NaN, zero), strided views and scalar eps."""
    from engine import vec
    from engine.accel import Accel
    rng = np.random.default_rng(22)
    n = 5000
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    normals[:4] = ((0, 0, 1), (0, 0, -1), (0.0, 0.0, -0.0), (0, 0, 0))
    normals[4] = np.nan
    wide = rng.normal(size=(n, 6))
    v = wide[:, ::2]                                       # a strided view
    assert not v.flags.c_contiguous
    s, t = vec.frame(normals)
    eps = rng.random(n) * 1e-4
    assert_agree(*both_ways(vec.frame, normals))
    assert_agree(*both_ways(vec.to_local, v, s, t, normals))
    assert_agree(*both_ways(vec.to_world, v, s, t, normals))
    for e in (eps, 1e-5):
        assert_agree(*both_ways(Accel.offset_origin, None, wide[:, 1::2], normals, v, e))


def test_bump_terms_agree(jit):
    """Bump Map Correction's compiled loops (engine/bump_correction.py:
    ``corrected``, the glossy lobes' lifted normal; ``rotations``, the
    bent-normal frames) and bsdf.bump_shadowing (both of Cycles' terms)
    against their NumPy forms, on random normals, unmoved rows (bent equal
    to smooth), views below the bent normal, grazing and zero cosines, NaN."""
    from engine import bsdf, bump_correction, vec
    rng = np.random.default_rng(41)
    n = 6000

    def unit(m):
        v = rng.normal(size=(m, 3))
        return v / np.linalg.norm(v, axis=1)[:, None]
    ng, wo, bent = unit(n), unit(n), unit(n)
    wo = np.where((vec.dot(wo, ng) < 0)[:, None], -wo, wo)       # the view above Ng, as the integrator's
    smooth = np.array(bent)
    smooth[: n // 2] = vec.normalize(ng[: n // 2] + 0.3 * unit(n // 2))   # half the rows moved
    bent[10:20] = -wo[10:20]                                      # bent normal facing away from the view
    bent[20] = np.nan
    assert_agree(*both_ways(bump_correction.corrected, ng, wo, bent, smooth), "corrected")
    tt, bb = vec.frame(smooth)
    plain, compiled = both_ways(bump_correction.rotations, tt, bb, smooth, bent)
    np.testing.assert_array_equal(plain[1], compiled[1])
    assert_agree(plain[:1], compiled[:1], "rotations")
    wi = unit(n)
    wi[:50, 2] = 0.0                                              # light in the shading plane
    wi[50:60] = smooth[50:60]                                     # along the smooth normal
    local_smooth = unit(n)
    local_smooth[:, 2] = np.abs(local_smooth[:, 2])
    local_smooth[60:70] = (0.0, 0.0, 1.0)                         # an unmoved normal: cos_sn = 1
    local_smooth[70] = np.nan
    for model in (bsdf.BUMP_CHIANG, bsdf.BUMP_GGX):
        plain, compiled = both_ways(bsdf.bump_shadowing, local_smooth, np.full(n, model, np.int8), wi)
        np.testing.assert_array_equal(plain[1], compiled[1])
        assert_agree(plain[:1], compiled[:1], f"bump_shadowing model {model}")


def test_one_process_at_a_time_fills_the_cache(tmp_path):
    """Two processes compiling into one numba cache crashed the second (a
    segfault loading a gufunc the first was writing): ``cache_lock`` lets
    one in at a time; a waiter that is told to stop gives up at once.  No
    clock: the holder writes a marker file as the last thing it does while
    it holds the lock, so whoever gets the lock after it must find the
    marker (a lock that let the waiter in early would not).  The holder is
    told to finish from inside the waiter's wait (its give_up callback), so
    the waiter provably waited."""
    import subprocess
    import sys
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    marker = tmp_path / "released"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; sys.path.insert(0, sys.argv[1]); from engine import kernels\n"
         "with kernels.cache_lock(sys.argv[2]):\n    print('held', flush=True); sys.stdin.readline()\n"
         "    open(sys.argv[3], 'w').close()",
         root, str(tmp_path), str(marker)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with kernels.cache_lock(str(tmp_path), give_up=lambda: True) as locked:
            assert not locked
        assert not marker.exists()
        told = []

        def release_holder():             # called only while we wait for the lock
            if not told:
                holder.stdin.write("go\n")
                holder.stdin.flush()
                told.append(True)
            return False
        with kernels.cache_lock(str(tmp_path), give_up=release_holder) as locked:
            assert locked and told, "the lock was granted without waiting for the holder"
            assert marker.exists(), "the lock was granted while the holder still had it"
    finally:
        holder.stdin.close()
        holder.wait(30)


def test_light_sample_contribution_agrees(jit):
    """NEE's MIS weight, contribution and live rows (engine/nee.py): the
    compiled row loop against the NumPy form, bit for bit, with delta
    lights, zero, infinite and NaN pdfs, directions below either surface
    and strided rows; with MIS and without."""
    from engine import nee
    rng = np.random.default_rng(23)
    n = 20000
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    ng = rng.normal(size=(n, 6))[:, ::2]
    wi_l = rng.normal(size=(n, 3))
    wi_l[:50, 2] = 0.0
    light_pdf = np.abs(rng.normal(size=n))
    light_pdf[50:100] = 0.0
    light_pdf[100:110] = np.inf
    pdf_b = np.abs(rng.normal(size=n))
    pdf_b[110:120] = np.nan
    pdf_b[120:130] = np.inf
    delta = rng.random(n) < 0.2
    beta, f, le = (np.abs(rng.normal(size=(n, 3))) for _ in range(3))
    f[130:140] = 0.0
    for mis in (True, False):
        for p_sel in (rng.random(n), np.ones(n)):
            args = (wi_l, wi, ng, light_pdf, p_sel, pdf_b, delta, mis, beta, f, le)
            plain, compiled = both_ways(nee.contribution, *args)
            assert_agree(plain, compiled)
            assert plain[2].any() and not plain[2].all()


def test_throughput_update_agrees(jit):
    """The BSDF sample's throughput update with Russian roulette
    (engine/throughput.py): compiled row loop against NumPy form, bit for
    bit, with leaking directions, NaN / infinite / zero weights, paths
    before and after the roulette depth, and none past it."""
    from engine import throughput
    rng = np.random.default_rng(24)
    n = 20000
    wi = rng.normal(size=(n, 3))
    ng = rng.normal(size=(n, 6))[:, ::2]
    wi_l = rng.normal(size=(n, 3))
    weight = np.abs(rng.normal(size=(n, 3)))
    weight[:20] = np.nan
    weight[20:40, 1] = np.inf
    weight[40:60] = 0.0
    beta = np.abs(rng.normal(size=(n, 3)))
    beta[60:70, 0] = np.nan
    bounce = rng.integers(0, 8, n).astype(np.int32)
    u = rng.random(n)
    for depth in (3, 100):
        plain, compiled = both_ways(throughput.update, wi, ng, wi_l, weight, beta, bounce, depth, u)
        assert_agree(plain, compiled)
        assert plain[0].any() and not plain[0].all()


def test_environment_lookup_agrees(jit):
    """The environment map's bilinear lookup: compiled loop against the
    NumPy form, bit for bit, across the wrap in both axes and outside
    [0, 1], for RGB and RGBA float32 images."""
    from engine.environment import lookup
    rng = np.random.default_rng(25)
    n = 20000
    u = rng.random(n) * 3.0 - 1.0
    v = rng.random(n) * 3.0 - 1.0
    u[:4] = (0.0, 1.0, 0.5 / 64, 1.0 - 1e-17)
    for channels in (3, 4):
        image = rng.random((32, 64, channels)).astype(np.float32) * 100.0
        assert_agree(*both_ways(lookup, image, u, v))


def test_pixel_filter_sample_agrees(jit):
    """The pixel filter's inverse CDF by guide table: compiled loop against
    the NumPy form, bit for bit, for each filter (the Gaussian's tails put
    many bins in one guide cell: the binary-search branch), at u = 0, 0.5
    and just below 1."""
    from engine.camera import PixelFilter
    rng = np.random.default_rng(26)
    u = rng.random(50000)
    u[:3] = (0.0, 0.5, np.nextafter(1.0, 0.0))
    for kind, width in (("BLACKMAN_HARRIS", 1.5), ("GAUSSIAN", 1.5), ("GAUSSIAN", 10.0), ("BOX", 1.0)):
        pixel_filter = PixelFilter(kind, width)
        assert_agree(*both_ways(pixel_filter.sample, u))


def test_sun_sample_agrees(jit):
    """Sun directions in their cones (engine/lights.py): the compiled loop
    against the NumPy form, bit for bit, for a half-degree and a wide sun,
    a delta sun and axes at the poles."""
    from engine.lights import _sun_sample
    rng = np.random.default_rng(27)
    n = 20000
    axes = np.array([(0.3, -0.5, -0.81), (0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.6, 0.0, 0.8)])
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    one_minus_cos = np.array([2.0 * np.sin(np.radians(0.25)) ** 2, 0.3, 0.01, 1.0])
    delta = np.array([False, False, False, True])
    j = rng.integers(0, 4, n)
    u1, u2 = rng.random(n), rng.random(n)

    def run():
        wi, pdf = np.empty((n, 3)), np.empty(n)
        _sun_sample(j, u1, u2, axes, one_minus_cos, delta, wi, pdf)
        return wi, pdf
    assert_agree(*both_ways(run))


def test_distribution2d_row_search_agrees(jit):
    """The column search of Distribution2D within the sampled row: the
    compiled loop against np.searchsorted over the whole flat CDF, bit for
    bit, with empty rows and columns, keys at row boundaries, NaN and keys
    outside their row."""
    from engine.sampling import Distribution2D, _search_rows
    rng = np.random.default_rng(29)
    w = rng.random((40, 70)) ** 4
    w[5] = 0.0
    w[:, 10:20] = 0.0
    dist = Distribution2D(w)
    n = 30000
    row = rng.integers(0, 40, n)
    key = row + np.minimum(rng.random(n), np.nextafter(1.0, 0.0))
    key[:5] = row[:5]
    key[5] = np.nan
    key[6:10] = row[6:10] + 2.5                        # not in its row: the whole-CDF fallback

    def run():
        out = np.empty(n, np.int64)
        _search_rows(dist.flat_cdf, row, key, dist.cols, out)
        return out
    plain, compiled = both_ways(run)
    assert_agree(plain, compiled)
    assert_agree(*both_ways(dist.sample, rng.random(n), rng.random(n)))


def test_point_light_sample_agrees(jit):
    """Points on sphere, soft-falloff disk, spot and radius-0 lights
    (engine/lights.py _point_sample): the compiled loop against the NumPy
    form, bit for bit, with shading points inside a sphere, far from tiny
    lights (the small-angle branch of 1 - cos) and strided inputs."""
    from engine.lights import _PointLights
    from engine.scene import PointLight, SpotLight
    rng = np.random.default_rng(30)
    lights = [PointLight((0.0, 0.0, 2.0), (10.0, 8.0, 6.0), radius=0.5),
              PointLight((1.0, 0.0, 1.0), (5.0, 5.0, 5.0), radius=0.001),
              PointLight((0.0, 1.0, 1.0), (3.0, 3.0, 3.0), radius=0.2, soft_falloff=True),
              PointLight((0.0, -1.0, 1.0), (3.0, 2.0, 1.0), radius=0.0),
              SpotLight((0.5, 0.5, 3.0), (20.0, 20.0, 20.0), radius=0.1, direction=(0.0, 0.0, -1.0),
                        spot_size=0.8, spot_blend=0.3),
              SpotLight((-0.5, 0.5, 3.0), (20.0, 20.0, 20.0), radius=0.0, direction=(0.2, 0.0, -1.0),
                        spot_size=1.0, spot_blend=0.0)]
    group = _PointLights(lights)
    n = 20000
    j = rng.integers(0, len(lights), n)
    p = rng.normal(size=(n, 6))[:, ::2] * 2.0
    p[:100] = group.pos[0] + 0.1                         # inside the first sphere
    p[100:200] = group.pos[1] + 5.0                      # far from the tiny one
    j[:100], j[100:200] = 0, 1
    u1, u2 = rng.random(n), rng.random(n)
    u1[200:210] = u2[200:210] = 0.5                      # the disk's centre
    p[210:260] = group.pos[4] + (0.0, 0.0, 0.05)         # inside the spot's sphere, above its cone
    j[210:260] = 4

    def run():
        from engine.lights import _point_sample
        outs = (np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n, bool))
        _point_sample(j, np.ascontiguousarray(p), u1, u2, group.pos, group.radius, group.sphere, group.L,
                      group.spot, group.dir, group.cos_half, group.smooth, *outs)
        return outs
    plain, compiled = both_ways(run)
    assert_agree(plain, compiled)
    # Inside: the uniform sphere, a point on the sphere's far side, no spot attenuation.
    assert np.allclose(plain[3][:100], 1.0 / (4.0 * np.pi)) and (plain[3][200:] > 0).any()
    far = p[:100] + plain[0][:100] * plain[1][:100, None] - group.pos[0]
    assert np.allclose(np.linalg.norm(far, axis=1), 0.5)
    assert np.allclose(plain[2][210:260], group.L[4]) and np.allclose(plain[3][210:260], 1.0 / (4.0 * np.pi))


def test_single_lobe_sample_agrees(jit):
    """One-lobe materials' closed-form sample (bsdf._sample_single): the
    compiled loop against the NumPy form, bit for bit, for diffuse, GGX and
    mirror lobes in every Fresnel mode, empty slots and wo below the
    horizon."""
    from engine import bsdf
    rng = np.random.default_rng(31)
    n = 20000
    kind = rng.choice(np.array([bsdf.NONE, bsdf.DIFFUSE, bsdf.GLOSSY, bsdf.MIRROR], np.int8), n)[:, None]
    fresnel = rng.integers(0, 4, (n, 1)).astype(np.int8)
    lobes = bsdf.Lobes(kind, rng.random((n, 1, 3)), rng.random((n, 1)) * 0.9 + 0.001, fresnel == bsdf.F_SCHLICK,
                       fresnel=fresnel, ior=rng.random((n, 1)) + 1.05, f0=rng.random((n, 1, 3)),
                       edge_tint=rng.random((n, 1, 3)))
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    u1, u2 = rng.random(n), rng.random(n)
    plain, compiled = both_ways(bsdf._sample_single, lobes, wo, u1, u2)
    assert_agree(plain, compiled)
    assert plain[3].any() and (plain[2] > 0).mean() > 0.3


def test_shadow_rays_agree(jit):
    """Shadow rays for NEE (engine/accel.py): the compiled gather of origin,
    direction and tfar in float32 against the NumPy form, bit for bit, with
    suns (infinite distance), points on triangles (re-aimed and shortened),
    a zero distance and strided inputs; and the float64 form it casts."""
    from engine.accel import shadow_rays, shadow_rays_f32
    rng = np.random.default_rng(29)
    n = 20000
    p = rng.normal(size=(n, 6))[:, ::2] * 10.0
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    dist = np.abs(rng.normal(size=n)) * 5.0
    dist[:100] = np.inf
    dist[100:110] = 0.0
    on = rng.random(n) < 0.3
    on[:100] = False
    eps = 1e-5 * (1.0 + np.abs(p).max(axis=1))
    rows = np.sort(rng.choice(n, n // 2, replace=False))
    plain, compiled = both_ways(shadow_rays_f32, p, ng, wi, dist, on, eps, rows)
    assert_agree(plain, compiled)
    assert all(a.dtype == np.float32 for a in compiled)
    origin, w, tmax = shadow_rays(p, ng, wi, dist, on, eps, rows)
    assert_agree(compiled, (origin.astype(np.float32), w.astype(np.float32),
                            np.maximum(tmax, 0.0).astype(np.float32)))
    # Re-aimed rays end 10 eps short of the sampled point; suns go on.
    aimed = np.flatnonzero(on[rows] & (dist[rows] > 0.01))
    end = origin[aimed] + w[aimed] * tmax[aimed, None]
    target = p[rows][aimed] + wi[rows][aimed] * dist[rows][aimed, None]
    reach = np.linalg.norm(target - origin[aimed], axis=1)
    assert np.allclose(np.linalg.norm(target - end, axis=1), 10.0 * eps[rows][aimed] + 1e-6 * reach,
                       rtol=1e-6, atol=1e-12)
    assert (tmax[dist[rows] == np.inf] == 1e37).all()


def test_add_rows_agrees(jit):
    """NEE's radiance added to the rows whose shadow ray is free: compiled
    loop against both NumPy forms (few rows: gather; most: masked add)."""
    from engine.integrator import _add_rows
    rng = np.random.default_rng(31)
    n = 5000
    for share in (0.1, 0.9):
        rows = np.sort(rng.choice(n, int(n * share), replace=False))
        values = rng.random((n, 3))
        out = []
        for on in (False, True):
            kernels.configure(on)
            L = rng.random((n, 3)) if not out else out[0][0].copy()
            start = L.copy()
            _add_rows(L, rows, values)
            out.append((start, L))
        assert_agree((out[0][1],), (out[1][1],))
        changed = np.flatnonzero((out[0][1] != out[0][0]).any(axis=1))
        assert set(changed) <= set(rows) and len(changed) > 0.9 * len(rows)


def test_tree_normals_agree(jit):
    """The light tree's normals (engine/nee.py tree_normals): the shading
    normal and the no-transmission flag, compiled loop against the NumPy
    form, with lobe kinds NONE (-1) and transmitting or not, weights with
    zeros, negatives and NaN; the flag is set exactly where expected."""
    from engine import nee
    rng = np.random.default_rng(37)
    n, k = 4000, 3
    transmitting = (2, 5)
    ns = rng.normal(size=(n, 3))
    kind = rng.integers(-1, 7, size=(n, k)).astype(np.int8)
    weights = rng.normal(size=(n, k, 3))
    weights[rng.random((n, k)) < 0.3] = 0.0
    weights[rng.random((n, k, 3)) < 0.02] = np.nan
    out = []
    for on in (False, True):
        kernels.configure(on)
        out.append(nee.tree_normals(ns, kind, weights, transmitting))
    np.testing.assert_array_equal(out[0], out[1])   # copies and a flag: no rounding
    with np.errstate(invalid="ignore"):
        through = np.isin(kind, transmitting) & (weights.max(axis=2) > 0)
    np.testing.assert_array_equal(out[1][:, 3], ~through.any(axis=1))
    assert 0.2 < out[1][:, 3].mean() < 0.8
    np.testing.assert_array_equal(out[1][:, :3], ns)


def test_a_kernel_called_before_it_compiled_waits_for_the_compile(jit):
    """With the JIT on, a kernel not compiled yet (a module imported late)
    compiles when first called: a render never mixes the two forms."""
    late = kernels.Kernel(_double_plus_one, 1, 1)
    try:
        assert kernels.enabled() and late.compiled is None
        np.testing.assert_array_equal(late(np.array([1.0, 2.0])), [3.0, 5.0])
        assert late.compiled is not None     # it ran compiled (the NumPy form compiles nothing)
    finally:
        kernels.KERNELS.remove(late)


class _Watcher:
    def __init__(self, stop):
        self.stop, self.status = stop, []

    def on_status(self, text, fraction):
        self.status.append((text, fraction))

    def should_stop(self):
        return self.stop


def test_for_render_shows_the_compile_and_can_be_cancelled(jit):
    late = kernels.Kernel(_double_plus_one, 1, 1)
    try:
        # Holding the cache's lock keeps the compile waiting, so the stop
        # request meets it still running.
        with kernels.cache_lock(kernels.cache_dir()), pytest.raises(kernels.CompileCancelled):
            kernels.for_render(True, _Watcher(stop=True), poll=0.001)
        watcher = _Watcher(stop=False)
        assert kernels.for_render(True, watcher, poll=0.001) == "compiled"
        assert late.compiled is not None
        assert all(text.startswith("Compiling kernels") and 0 <= f <= 1 for text, f in watcher.status)
    finally:
        kernels.KERNELS.remove(late)
    assert kernels.for_render(False) == "numpy" and not kernels.enabled()
    kernels.configure(True)


@pytest.mark.parametrize("use_jit", [True, False])
def test_a_render_records_its_kernels(jit, use_jit):
    result = render(cornell_spheres(8, 8, grid=1), RenderSettings(samples=1, use_jit=use_jit, threads=1))
    assert result.stats["kernels"] == ("compiled" if use_jit else "numpy")
    assert result.stats["compile_wait_seconds"] >= 0
    kernels.configure(True)


def test_perlin_noise_agrees(jit):
    """Cycles' signed Perlin noise (engine/nodes/noise.py): the compiled row
    loop against the NumPy form in 1-4 dimensions, on points spanning cell
    corners, negative cells, the 1e5 wrap and non-finite coordinates."""
    from engine.nodes.noise import snoise
    rng = np.random.default_rng(31)
    for d in (1, 2, 3, 4):
        p = (rng.normal(0.0, 20.0, (6000, d))).astype(np.float32)
        p[:500] = np.round(p[:500])                  # on the lattice: grad . 0
        p[500:600] *= np.float32(1e4)                # past the 1e5 wrap
        p[600:610, 0] = (np.nan, np.inf, -np.inf, 1e30, -1e30, 0.0, -0.0, 0.5, -0.5, 99999.5)
        assert_agree(*both_ways(snoise, p), f"snoise {d}D")


def test_voronoi_octave_agrees(jit):
    """One Voronoi octave (engine/nodes/voronoi_loop.py): the compiled loop
    against the NumPy form for F1, F2 and Smooth F1 under the compiled metrics in
    2D-4D (Blender 5's integer cell hashes), on points spanning negative
    cells, cell borders, zero randomness and huge or non-finite coordinates."""
    from engine.nodes.texture_nodes import _octave
    rng = np.random.default_rng(32)
    n = 800   # the NumPy form of Smooth F1 in 4D visits 625 cells, nine times for the rounding spread
    for dim in (2, 3, 4):
        q = rng.normal(0.0, 6.0, (n, dim)).astype(np.float32)
        q[:200] = np.round(q[:200])                       # on cell borders
        q[200:210, 0] = (np.nan, np.inf, -np.inf, 3e9, -3e9, 1e20, 0.0, -0.0, 0.5, -0.5)
        rand = rng.uniform(0.0, 1.0, n).astype(np.float32)
        rand[:100] = 0.0
        expo = rng.uniform(0.3, 4.0, n).astype(np.float32)
        smooth = rng.uniform(0.0, 0.5, n).astype(np.float32)
        for feature in ("F1", "F2", "SMOOTH_F1"):
            for metric in ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV"):
                def octave(q, rand, expo, smooth):
                    return _octave(q, feature, metric, expo, rand, smooth, True, True)
                assert_agree(*both_ways(octave, q, rand, expo, smooth), f"voronoi {dim}D {feature} {metric}")


def test_voronoi_f1_skipping_cells_agrees(jit):
    """The compiled F1 skips neighbour cells whose box lies beyond the own
    cell's feature point: points a hair from cell faces, edges and corners,
    randomness 0, tiny and 1, every compiled metric, agree with the NumPy
    form that measures every cell (a bound off by more than rounding would
    pick a farther point somewhere here)."""
    from engine.nodes.texture_nodes import _octave
    rng = np.random.default_rng(33)
    near = np.array([0.0, 1e-7, 1e-5, 2e-5, 0.5, 1.0 - 2e-5, 1.0 - 1e-5, 1.0 - 1e-7], np.float32)
    for dim in (2, 3, 4):
        n = 3000
        cell = rng.integers(-50, 50, (n, dim)).astype(np.float32)
        local = np.where(rng.random((n, dim)) < 0.7, rng.choice(near, (n, dim)), rng.random((n, dim)))
        q = (cell + local.astype(np.float32)).astype(np.float32)
        rand = rng.choice(np.array([0.0, 1e-6, 0.3, 1.0], np.float32), n)
        ones = np.ones(n, np.float32)
        for metric in ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV"):
            def octave(q, rand):
                return _octave(q, "F1", metric, ones, rand, ones, True, True)
            assert_agree(*both_ways(octave, q, rand), f"voronoi F1 {dim}D {metric}")


def test_fbm_3d_agrees(jit):
    """3D fBm noise (engine/nodes/noise.py): the fused loop of all octaves
    against the NumPy form, integer and fractional detail, normalized or
    not, on points spanning cell corners, the 1e5 wrap and large scales."""
    from engine.nodes.noise import fbm
    rng = np.random.default_rng(33)
    n = 4000
    p = rng.normal(0.0, 8.0, (n, 3)).astype(np.float32)
    p[:300] = np.round(p[:300])
    p[300:400] *= np.float32(2e4)
    detail = rng.choice([0.0, 1.0, 2.0, 2.5, 3.7, 15.0], n).astype(np.float32)
    rough = rng.uniform(0.0, 1.0, n).astype(np.float32)
    lac = rng.uniform(1.0, 3.0, n).astype(np.float32)
    for normalize in (True, False):
        assert_agree(*both_ways(lambda *a: fbm(*a, normalize), p, detail, rough, lac), f"fbm normalize={normalize}")


def test_fbm_3d_cell_memo_agrees(jit):
    """The fused fBm keeps each octave's last lattice cell and its corner
    hashes (the bump's four copies of a point are consecutive rows): runs
    of nearby points, some straddling a cell face at one octave or another,
    with details that change along the run (a memo row shared by octaves
    of different runs), agree with the NumPy form, which hashes every
    point."""
    from engine.nodes.noise import fbm
    rng = np.random.default_rng(34)
    base = rng.normal(0.0, 5.0, (1500, 3))
    base[:300] = np.round(base[:300])                    # on cell corners: copies straddle them
    p = np.repeat(base, 4, axis=0) + rng.normal(0.0, 1e-4, (6000, 3))
    p[::7] = -p[::7]
    p = p.astype(np.float32)
    detail = np.repeat(rng.choice([0.0, 1.0, 2.0, 2.5, 15.0], 1500), 4).astype(np.float32)
    detail[::5] = 3.7
    rough, lac = np.full(6000, 0.5, np.float32), np.full(6000, 2.0, np.float32)
    for normalize in (True, False):
        assert_agree(*both_ways(lambda *a: fbm(*a, normalize), p, detail, rough, lac), f"fbm memo normalize={normalize}")


def test_cache_lock_is_per_engine_copy(tmp_path, monkeypatch):
    """Another copy of the engine (the add-on vendored into a Blender) does
    not wait for this copy's compile: numba files their kernels apart."""
    with kernels.cache_lock(str(tmp_path)) as held:
        assert held
        with kernels.cache_lock(str(tmp_path), give_up=lambda: True) as same_copy:
            assert not same_copy          # flock: a second open of the same lock file waits
        monkeypatch.setattr(kernels, "_ENGINE_DIR", "/elsewhere/ember/engine")
        with kernels.cache_lock(str(tmp_path), give_up=lambda: True) as other_copy:
            assert other_copy


def test_bump_kernels_agree(jit):
    """The footprint bump's steps and svm_node_set_bump (engine/textures.py
    bump_steps, set_bump_rows): compiled against NumPy on random and odd
    rows (the diagonal normal, degenerate triangles, zero, infinite and NaN
    footprints and heights)."""
    from engine.textures import bump_steps, set_bump_rows
    rng = np.random.default_rng(31)
    n = 4000
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    normal[:3] = ((1, 1, 1), (0, 0, 1), (0, 0, 0))
    normal[0] /= np.sqrt(3.0)
    edges = rng.normal(size=(n, 6))
    edges[3, 3:] = edges[3, :3]                                  # a degenerate triangle
    dp, w = np.abs(mixed(rng, n, 1e-3)), np.abs(mixed(rng, n, 0.1))
    assert_agree(*both_ways(bump_steps, *normal.T, dp, w, *edges.T), "bump_steps")
    dx, dy = rng.normal(size=(n, 3)) * 1e-3, rng.normal(size=(n, 3)) * 1e-3
    heights = np.column_stack([mixed(rng, n), mixed(rng, n), mixed(rng, n)])
    strength, distance = rng.random(n) * 1.5 - 0.25, mixed(rng, n, 0.1)
    assert_agree(*both_ways(set_bump_rows, *normal.T, *dx.T, *dy.T, *heights.T, strength, distance, w),
                 "set_bump_rows")


def test_color_ramp_loop_agrees(jit):
    """The Color Ramp's compiled lookup (converter_nodes._ramp_loop) against
    ramp_lookup, its NumPy reference, on factors inside, outside and at the
    ends of [0, 1], NaN and infinities, interpolated and constant."""
    from engine.nodes.converter_nodes import RAMP_SIZE, ramp_lookup, ramp_rows
    rng = np.random.default_rng(12)
    table = rng.random((RAMP_SIZE, 4))
    f = np.concatenate([rng.random(3000) * 1.4 - 0.2, [0.0, 1.0, -0.0, 0.5, np.nan, np.inf, -np.inf, 1e300]])
    f[:200] = np.arange(200) / 256.0           # exactly on table entries: t = 0
    for interpolate in (True, False):
        want = ramp_lookup(table, f, interpolate)
        np.testing.assert_allclose(ramp_rows(table, f, interpolate), want, rtol=1e-15, atol=0)
        np.testing.assert_allclose(ramp_rows(table, f[::2], interpolate), want[::2], rtol=1e-15, atol=0)
