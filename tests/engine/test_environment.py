"""HDRI worlds: Cycles' equirectangular convention, the environment sampler
against its own pdf, and renders lit by an environment that must come out
right whatever the strategy (furnace, analytic irradiance, agreement).

Statistical tests form one family (ember_stats.family_level, Sidak over N_TESTS);
deterministic checks use rounding tolerances.
"""
import importlib
import math
import os
import sys

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
for _path in (ROOT, HERE):
    if _path not in sys.path:
        sys.path.insert(0, _path)

import chi2 as C  # noqa: E402
import ember_stats
from engine import lights as lights_module  # noqa: E402
render_module = importlib.import_module("engine.render")  # the module: engine.render is the function
from engine.environment import (EnvironmentMap, direction_to_equirect,  # noqa: E402
                                direction_to_mirrorball, equirect_to_direction, lookup)
from engine.render import render  # noqa: E402
from engine.sampling import Distribution2D  # noqa: E402
from engine.scene import (Camera, EnvironmentTexture, Instance, Lobe, Material,  # noqa: E402
                          RenderSettings, Scene, SceneError, World)
from engine.vec import luminance  # noqa: E402
from engine.testscenes import look_at, quad, uv_sphere  # noqa: E402
from ember_stats import block_means_var, median_block_detects, z_scores  # noqa: E402


N = 1_000_000
MATRICES = ("identity", "rotation", "skewed")
SAMPLER_CASES = [(m, interp, comp) for m in MATRICES for interp in ("Linear", "Closest")
                 for comp in (False, True)]
PLANE_CASES = [(s, c) for s in ("mis", "light", "bsdf") for c in (False, True) if s == "mis" or not c]
N_TESTS = (1                              # Distribution2D chi2
           + 2 * len(SAMPLER_CASES)       # chi2 + mean(1/pdf)
           + 2 * 2                        # the same for mirror balls
           + 2                            # furnace (mis, light)
           + len(PLANE_CASES)             # analytic irradiance
           + 3)                           # strategy agreement (light, mis, mis + compensation vs bsdf)
LEVEL = ember_stats.family_level(__name__, N_TESTS)   # the suite budget, Sidak over N_TESTS
Z_MAX = C.z_threshold(LEVEL)
XYZ = (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))


def rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def matrix_for(name):
    if name == "identity":
        return np.eye(3)
    r = rotation((0.3, -0.5, 0.8), 1.1)
    if name == "rotation":
        return r
    return r @ np.diag([1.0, 2.0, 0.5]) @ rotation((1, 0, 0), 0.4)  # a Mapping with scale


def hdri(width=24, height=12, sun=2000.0, seed=5, black=True):
    """A test sky (row 0 = top): brighter above the horizon, a black patch
    (optional), texture noise and a 2x2-texel sun."""
    rng = np.random.default_rng(seed)
    rows = np.linspace(1.0, 0.1, height)[:, None, None]
    px = rows * np.array([0.6, 0.8, 1.0]) * (0.5 + rng.random((height, width, 1)))
    px = np.broadcast_to(px, (height, width, 3)).copy()
    if black:
        px[height // 2 + 1:, : width // 4] = 0.0      # zero pdf there (but at its rim if bilinear)
    px[2:4, width // 3: width // 3 + 2] = sun * np.array([1.0, 0.9, 0.7])
    return px.astype(np.float32)


def assert_z(mean, target, se, what):
    z = (mean - target) / se if se > 0 else (0.0 if mean == target else math.inf)
    print(f"{what}: {mean:.6g} vs {target:.6g} (se {se:.3g}, z {z:+.2f}, |z| < {Z_MAX:.2f}); detects "
          f"{Z_MAX * se / abs(target):.2%} with probability 1/2")
    assert abs(z) < Z_MAX, f"{what}: {mean} vs {target}, z = {z:.2f}"


# ----------------------------------------------------------------------------
# Conventions (deterministic)

def test_equirect_convention_is_cycles():
    """Cycles: u = (atan2(y, x) - pi) / -2pi, v = (acos(z) - pi) / -pi."""
    d = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    u, v = direction_to_equirect(d)
    np.testing.assert_allclose(u[:3], [0.5, 0.25, 0.75], atol=1e-15)
    np.testing.assert_allclose(v, [0.5, 0.5, 0.5, 1.0, 0.0], atol=1e-15)
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(1000, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    u, v = direction_to_equirect(dirs * 3.0)  # length does not matter
    np.testing.assert_allclose(equirect_to_direction(u, v), dirs, atol=1e-12)


def texel_direction(row, col, width, height):
    """Direction of the centre of texel (row from the top, col)."""
    return equirect_to_direction(np.array([(col + 0.5) / width]), np.array([1.0 - (row + 0.5) / height]))


@pytest.mark.parametrize("interp", ["Linear", "Closest"])
def test_lookup_orientation_and_texel_centres(interp):
    """Row 0 of the pixels is the top (+Z); texel centres return the texel
    exactly; +X looks at the middle column, +Y a quarter from the left."""
    w, h = 16, 8
    px = np.arange(w * h * 3, dtype=np.float32).reshape(h, w, 3)
    env = EnvironmentMap(EnvironmentTexture(px, 2.0, interpolation=interp))
    for row, col in [(0, 0), (0, 5), (3, 8), (7, 15), (4, 12)]:
        np.testing.assert_allclose(env.eval(texel_direction(row, col, w, h))[0], 2.0 * px[row, col],
                                   rtol=1e-6, atol=1e-9)
    # Closest: near +Z (towards +X: u = 0.5) the top row, middle column; on
    # the horizon (v = 0.5 exactly: the upper row) at +Y, column w/4 or the
    # one before, depending on the side.
    closest = EnvironmentMap(EnvironmentTexture(px, 1.0, interpolation="Closest"))
    up = np.array([[1e-3, 0.0, 1.0]])
    assert closest.eval(up / np.linalg.norm(up))[0, 0] == px[0, w // 2, 0]
    assert closest.eval(np.array([[0.0, 0.0, -1.0]]))[0, 0] == px[h - 1, w // 2, 0]
    y = closest.eval(np.array([[1e-9, 1.0, 0.0], [-1e-9, 1.0, 0.0]]))
    assert y[0, 0] == px[h // 2 - 1, w // 4, 0] and y[1, 0] == px[h // 2 - 1, w // 4 - 1, 0]
    if interp == "Linear":
        # Halfway between two texel centres: their mean; across u = 0: wraps.
        mid = equirect_to_direction(np.array([2.0 / w, 0.0]), np.array([1 - 2.5 / h, 1 - 2.5 / h]))
        got = env.eval(mid)
        np.testing.assert_allclose(got[0], (px[2, 1] + px[2, 2]), rtol=1e-6)   # 2 * mean
        np.testing.assert_allclose(got[1], (px[2, 0] + px[2, w - 1]), rtol=1e-6)


def test_rotation_moves_the_map():
    """With matrix M the world direction d looks up M d."""
    px = hdri()
    m = matrix_for("rotation")
    plain = EnvironmentMap(EnvironmentTexture(px))
    rotated = EnvironmentMap(EnvironmentTexture(px, matrix=m))
    d = np.random.default_rng(2).normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    np.testing.assert_allclose(rotated.eval(d), plain.eval(d @ m.T), rtol=1e-12)
    np.testing.assert_allclose(rotated.pdf(d), plain.pdf(d @ m.T), rtol=1e-9)


# ----------------------------------------------------------------------------
# Samplers against their own pdf

def test_distribution2d_chi2():
    rng = np.random.default_rng(11)
    w = rng.random((7, 9)) ** 3
    w[2] = 0.0          # an empty row
    w[:, 4] = 0.0       # an empty column
    dist = Distribution2D(w)
    u = np.random.default_rng(12).random((2, N))
    x, y, pdf = dist.sample(u[0], u[1])
    assert np.all((x >= 0) & (x < 1) & (y >= 0) & (y < 1))
    np.testing.assert_allclose(pdf, dist.pdf(x, y), rtol=1e-12)
    counts, outside = C.histogram2d(x, y, np.linspace(0, 1, 10), np.linspace(0, 1, 8))
    assert outside == 0
    expected = N * (w / w.sum()).T
    res = C.chi2_test(counts, expected)
    print("chi2 Distribution2D:", res.power_line(LEVEL))
    assert res.p > LEVEL
    # Points inside a cell follow its uniform density: check the fractional part.
    fx = (x * 9) % 1.0
    assert abs(fx.mean() - 0.5) < Z_MAX * math.sqrt(1 / 12 / N)


def env_for(matrix, interp, comp):
    # Bilinear lookups, uncompensated, sample every direction: no black patch.
    black = interp == "Closest" or comp
    return EnvironmentMap(EnvironmentTexture(hdri(black=black), 1.0, matrix_for(matrix), interp),
                          compensate=comp)


@pytest.mark.parametrize("matrix,interp,comp", SAMPLER_CASES)
def test_environment_sampler(matrix, interp, comp):
    env = env_for(matrix, interp, comp)
    seed = 100 + SAMPLER_CASES.index((matrix, interp, comp))
    check_sampler(env, seed, f"{matrix} {interp} compensate={comp}", interp == "Linear" and not comp)


def check_sampler(env, seed, what, full_support):
    """sample() against pdf(): chi-square in texture space and mean(1/pdf)
    against the solid angle of the support."""
    u = np.random.default_rng(seed).random((2, N))
    d, pdf = env.sample(u[0], u[1])
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    ok = pdf > 0
    assert ok.mean() > 1 - 1e-5, "samples without pdf"
    d, pdf = d[ok], pdf[ok]
    # sample() and pdf() agree (but on cell edges, where truncation may pick
    # the neighbour after rounding).
    again = env.pdf(d)
    m = env.matrix
    uu, vv = direction_to_equirect(d @ m.T)
    inside = (np.abs(((uu * env.dist.cols) + 0.5) % 1 - 0.5) > 1e-7) & \
             (np.abs(((vv * env.dist.rows) + 0.5) % 1 - 0.5) > 1e-7)
    np.testing.assert_allclose(again[inside], pdf[inside], rtol=1e-9)

    # chi-square in texture space (e = M d / |M d|), on a grid aligned with
    # the texels so that the texel-wise constant pdf integrates exactly.
    e = d @ m.T
    e /= np.linalg.norm(e, axis=1)[:, None]
    a = np.linalg.inv(m)
    det_a = abs(np.linalg.det(a))

    def pdf_e(v):
        ae = v @ a.T
        length = np.linalg.norm(ae, axis=1)
        return env.pdf(ae / length[:, None]) * det_a / length ** 3   # d omega_d / d omega_e
    w, h = env.dist.cols, env.dist.rows
    phi_edges = np.linspace(0.0, 2 * np.pi, 2 * w + 1)
    theta_edges = np.linspace(0.0, np.pi, 2 * h + 1)
    phi, theta = C.to_phi_theta(e, XYZ)
    counts, outside = C.histogram2d(phi, theta, phi_edges, theta_edges)
    mass = C.integrate_cells(lambda ph, th: pdf_e(C.from_phi_theta(ph, th, XYZ)) * np.sin(th),
                             phi_edges, theta_edges, periodic_x=True)
    obs = np.append(counts.ravel(), outside + (~ok).sum())
    exp = np.append(N * mass.ravel(), max(N - N * mass.sum(), 0.0))
    res = C.chi2_test(obs, exp)
    print(f"chi2 environment {what}: {res.power_line(LEVEL)}")
    assert res.p > LEVEL

    # mean(1/pdf) = the world solid angle of the support: 4 pi, but for the
    # black patch ('Closest' reads it exactly) and what compensation drops.
    support = C.integrate_cells(
        lambda ph, th: (pdf_e(C.from_phi_theta(ph, th, XYZ)) > 0) * np.sin(th)
        * _jacobian(a, C.from_phi_theta(ph, th, XYZ)), phi_edges, theta_edges, periodic_x=True).sum()
    if full_support:
        assert support == pytest.approx(4 * np.pi, rel=1e-9)
    inv = 1.0 / pdf
    assert_z(inv.mean(), support, inv.std(ddof=1) / math.sqrt(len(inv)), f"mean(1/pdf) {what}")


# ----------------------------------------------------------------------------
# Mirror-ball projection (Cycles' direction_to_mirrorball)

def cycles_mirrorball_to_direction(u, v):
    """Cycles' mirrorball_to_direction (kernel/camera/projection.h)."""
    x, z = 2.0 * u - 1.0, 2.0 * v - 1.0
    y = -np.sqrt(np.maximum(1.0 - x * x - z * z, 0.0))
    dot = -y                                   # dot(dir, I) with I = (0, -1, 0)
    return np.stack([2 * dot * x, 2 * dot * y + 1.0, 2 * dot * z], axis=1)


def test_mirror_ball_convention_is_cycles():
    """The centre reflects -Y; +X and +Z lie 1/sqrt(2) of the radius out;
    +Y and the zero vector read the centre (Cycles' division guard); the
    mapping inverts Cycles' mirrorball_to_direction; length does not matter."""
    d = np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0], [0, 0, 0]])
    u, v = direction_to_mirrorball(d)
    r = 0.5 * (1 + 1 / math.sqrt(2))
    np.testing.assert_allclose(u, [0.5, r, 0.5, 0.5, 0.5], atol=1e-15)
    np.testing.assert_allclose(v, [0.5, 0.5, r, 0.5, 0.5], atol=1e-15)
    rng = np.random.default_rng(2)
    uv = rng.random((4000, 2))
    uv = uv[np.hypot(uv[:, 0] - 0.5, uv[:, 1] - 0.5) < 0.49]
    e = cycles_mirrorball_to_direction(uv[:, 0], uv[:, 1])
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), 1.0, atol=1e-12)
    u, v = direction_to_mirrorball(e * 2.5)
    np.testing.assert_allclose(np.stack([u, v], axis=1), uv, atol=1e-9)


def mirror_ball(size=16, seed=7):
    """A square mirror-ball image (row 0 = top): noise, a 2x2 bright spot."""
    rng = np.random.default_rng(seed)
    px = (0.2 + rng.random((size, size, 3))).astype(np.float32)
    px[4:6, 9:11] = np.array([800.0, 700.0, 500.0], np.float32)
    return px


@pytest.mark.parametrize("interp", ["Linear", "Closest"])
def test_mirror_ball_eval_is_the_lookup(interp):
    """Radiance along d is the image read at direction_to_mirrorball(M d)."""
    px = mirror_ball()
    m = matrix_for("rotation")
    env = EnvironmentMap(EnvironmentTexture(px, 2.0, m, interp, projection="MIRROR_BALL"))
    d = np.random.default_rng(3).normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    u, v = direction_to_mirrorball(d @ m.T)
    want = lookup(np.ascontiguousarray(px[::-1]) * np.float32(2.0), u, v, interp == "Closest")
    np.testing.assert_allclose(env.eval(d), want, rtol=1e-12)
    # not the equirect reading of the same pixels
    assert not np.allclose(EnvironmentMap(EnvironmentTexture(px, 2.0, m, interp)).eval(d), want)


@pytest.mark.parametrize("interp", ["Linear", "Closest"])
def test_mirror_ball_sampler(interp):
    """The sampling table of a mirror ball (resampled onto equirect (u, v))
    matches its pdf, and finds the bright spot: most samples land where the
    radiance is."""
    env = EnvironmentMap(EnvironmentTexture(mirror_ball(), 1.0, matrix_for("rotation"), interp,
                                            projection="MIRROR_BALL"))
    check_sampler(env, 300 + (interp == "Closest"), f"mirror ball {interp}", True)
    d, pdf = env.sample(*np.random.default_rng(9).random((2, 20000)))
    bright = luminance(env.eval(d)) > 100
    assert bright.mean() > 0.5, f"only {bright.mean():.1%} of the samples see the bright spot"


def _jacobian(a, e):
    """d omega_d / d omega_e for d = A e / |A e|."""
    ae = e @ a.T
    return abs(np.linalg.det(a)) / np.linalg.norm(ae, axis=1) ** 3


def test_light_set_registers_the_environment():
    """An HDRI world is one NEE emitter whose samples match what escaping rays see."""
    tex = EnvironmentTexture(hdri(), 1.5, matrix_for("rotation"))
    scene = Scene(world=World((0, 0, 0), tex))
    from engine import bsdf, geometry
    ls = lights_module.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
    assert ls.count == 1 and ls.kind[0] == lights_module.ENV
    u = np.random.default_rng(3).random((3, 1000))
    s = ls.sample(np.zeros(1000, np.int64), np.zeros((1000, 3)), u[0], u[1], u[2])
    emitter, Le, pdf = ls.environment_hits(s.wi)
    assert emitter == 0 and not s.delta.any() and np.all(np.isinf(s.dist))
    np.testing.assert_allclose(Le, s.Le, rtol=1e-12)
    np.testing.assert_allclose(pdf, s.pdf, rtol=1e-6)
    constant = Scene(world=World((1, 1, 1)))
    assert lights_module.LightSet(constant, geometry.flatten(constant),
                                  bsdf.MaterialTable(geometry.material_table(constant))).count == 0


# ----------------------------------------------------------------------------
# Renders

def with_compensation(monkeypatch, on):
    """Build LightSets with MIS compensation on or off (what
    RenderSettings.mis_compensation selects once render.prepare passes it)."""
    original = lights_module.LightSet
    monkeypatch.setattr(render_module, "LightSet",
                        lambda *a, **k: original(*a, **{**k, "env_compensation": on}))


def ortho_down(size=(16, 16), scale=2.0):
    return Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=scale,
                  resolution=size, clip_start=0.01, clip_end=100.0)


@pytest.mark.parametrize("strategy", ["mis", "light"])
def test_white_furnace_under_constant_hdri(strategy):
    """An albedo-1 diffuse sphere under a constant "HDRI" (light sampled,
    unlike a constant world) renders 1."""
    tex = EnvironmentTexture(np.ones((8, 16, 3), np.float32), 1.0, matrix_for("rotation"))
    white = Material("white", (Lobe("diffuse", (1.0, 1.0, 1.0)),))
    cam = Camera(look_at((0, -5, 0), (0, 0, 0), (0, 0, 1)), kind="ORTHO", ortho_scale=2.6,
                 resolution=(24, 24), clip_start=0.01, clip_end=100.0)
    scene = Scene([uv_sphere(1.0, 48, 24)], [Instance(0, materials=[0])], [white], [],
                  World((0, 0, 0), tex), cam)
    r = render(scene, RenderSettings(samples=32, samples_per_pass=32, max_bounces=8, strategy=strategy,
                                     seed=4, sum_variance=True))
    img = r.image[..., :3].astype(np.float64)
    var = r.variance.astype(np.float64)
    assert np.isfinite(img).all()
    # The mean over channels: the variance of R + G + B (equal channels here: 9x var(R), not 3x).
    assert_z(img.mean(), 1.0, math.sqrt(r.sum_variance.astype(np.float64).sum()) / img.size, f"furnace {strategy}")
    # Blocks of 4 x 4 pixels (512 samples): near-normal means.
    a, va = block_means_var(img, var, 4)
    z = np.abs(a - 1.0) / np.sqrt(np.maximum(va, 1e-30))
    z = np.where(np.abs(a - 1.0) < 1e-9, 0.0, z)
    limit = C.z_threshold(C.sidak(LEVEL, z.size))
    print(f"furnace {strategy}: max block |z| {z.max():.2f} (limit {limit:.2f}); the median block detects "
          f"{median_block_detects(limit, a, va):.2%} with probability 1/2")
    assert z.max() < limit


def plane_irradiance(px, strength=1.0):
    """Irradiance on an upward plane from a 'Closest' map (H even): each
    texel row spans theta in [pi r / H, pi (r + 1) / H]."""
    h, w = px.shape[:2]
    rows = np.arange(h // 2)
    s0, s1 = np.sin(np.pi * rows / h), np.sin(np.pi * (rows + 1) / h)
    weight = 0.5 * (s1 ** 2 - s0 ** 2) * (2 * np.pi / w)   # integral of cos sin dtheta dphi
    return strength * (px[: h // 2].astype(np.float64) * weight[:, None, None]).sum(axis=(0, 1))


@pytest.mark.parametrize("strategy,comp", PLANE_CASES)
def test_plane_under_hdri_matches_analytic_irradiance(strategy, comp, monkeypatch):
    """A diffuse plane facing up reflects rho E / pi, E integrated texel by
    texel: NEE, BSDF sampling, MIS and MIS compensation are all unbiased."""
    with_compensation(monkeypatch, comp)
    px = hdri(32, 16, sun=500.0)
    tex = EnvironmentTexture(px, 0.7, rotation((0, 0, 1), 0.9), "Closest")
    rho = 0.8
    mesh = quad([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
    scene = Scene([mesh], [Instance(0, materials=[0])], [Material("grey", (Lobe("diffuse", (rho,) * 3),))],
                  [], World((0, 0, 0), tex), ortho_down())
    spp = 64 if strategy != "bsdf" else 256
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, max_bounces=0,
                                     strategy=strategy, seed=7))
    expected = rho * plane_irradiance(px, 0.7) / np.pi
    img = r.image[..., :3].astype(np.float64)
    var = r.variance.astype(np.float64)
    # One test on the luminance of the whole image (channels are correlated).
    lum_w = np.array([0.2126, 0.7152, 0.0722])
    print(f"{strategy} compensate={comp}: mean pixel variance {var.mean():.4g}")
    assert_z((img @ lum_w).mean(), expected @ lum_w, math.sqrt((var @ lum_w ** 2).sum()) / (img.size / 3),
             f"plane irradiance {strategy} compensate={comp}")


def spheres_scene(tex, size=(32, 24)):
    plane = quad([[-6, -6, 0], [6, -6, 0], [6, 6, 0], [-6, 6, 0]])
    sphere = uv_sphere(1.0, 32, 16, smooth=True)
    left, right = np.eye(4), np.eye(4)
    left[:3, 3], right[:3, 3] = (-1.1, 0, 1), (1.1, 0, 1)
    mats = [Material("diffuse", (Lobe("diffuse", (0.8, 0.7, 0.6)),)),
            Material("glossy", (Lobe("glossy", (0.9, 0.9, 0.9), 0.35),))]
    cam = Camera(look_at((0, -7, 3.5), (0, 0, 0.8), (0, 0, 1)), resolution=size, lens=40)
    return Scene([plane, sphere], [Instance(0, materials=[0]), Instance(1, left, [0]), Instance(1, right, [1])],
                 mats, [], World((0, 0, 0), tex), cam)


def test_strategies_agree_under_hdri(monkeypatch):
    """MIS and MIS with compensation agree with BSDF sampling block by block,
    with far less variance.  (NEE alone is checked on the plane above: on a
    glossy sphere its estimates are too heavy-tailed for a z-test at a
    test's sample count; so are BSDF-only ones under a brighter sun.)"""
    tex = EnvironmentTexture(hdri(64, 32, sun=50.0), 1.0, matrix_for("rotation"))
    scene = spheres_scene(tex)
    out = {}
    for seed, (name, strategy, comp, spp) in enumerate((("bsdf", "bsdf", False, 512), ("mis", "mis", False, 64),
                                                        ("mis+comp", "mis", True, 64)), start=9):
        with_compensation(monkeypatch, comp)   # independent seeds: compared by z-tests below
        r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, max_bounces=2,
                                         strategy=strategy, seed=seed))
        assert np.isfinite(r.image).all()
        out[name] = (r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), spp)
    per_sample = {k: (v * spp).mean() for k, (_, v, spp) in out.items()}
    for name, ref_name in (("mis", "bsdf"), ("mis+comp", "bsdf"), ("mis+comp", "mis")):
        img, var, _ = out[name]
        ref, ref_var, _ = out[ref_name]
        a, va = block_means_var(img, var, 4)
        b, vb = block_means_var(ref, ref_var, 4)
        z = z_scores(a, va, b, vb)
        limit = C.z_threshold(C.sidak(LEVEL, z.size))
        print(f"{name} vs {ref_name}: mean {img.mean():.4f} vs {ref.mean():.4f}, relative "
              f"{img.mean() / ref.mean() - 1:+.4f}; per-sample variance {per_sample[name]:.4g} vs "
              f"{per_sample[ref_name]:.4g}; max |z| {np.abs(z).max():.2f} (limit {limit:.2f}); the median block "
              f"detects {median_block_detects(limit, b, va, vb):.1%} with probability 1/2")
        assert np.abs(z).max() < limit, f"{name} disagrees with {ref_name}"
    assert per_sample["mis"] < 0.5 * per_sample["bsdf"]
    assert per_sample["mis+comp"] < per_sample["mis"]


def test_transparent_film_hides_the_hdri_but_keeps_its_light():
    tex = EnvironmentTexture(hdri(), 1.0)
    scene = spheres_scene(tex, size=(16, 12))
    r = render(scene, RenderSettings(samples=4, samples_per_pass=4, max_bounces=1, transparent=True))
    sky = r.image[0, :, :]          # the top row sees the sky only
    assert np.all(sky == 0.0)
    assert r.image[-1, :, :3].mean() > 0.01 and np.all(r.image[-1, :, 3] == 1.0)


# ----------------------------------------------------------------------------
# Bad input

@pytest.mark.parametrize("change,message", [
    (dict(pixels=np.ones((4, 8), np.float32)), "shape"),
    (dict(pixels=np.ones((4, 8, 3), np.int32)), "float"),
    (dict(pixels=np.full((4, 8, 3), np.nan, np.float32)), "NaN"),
    (dict(matrix=np.diag([1.0, 0.0, 1.0])), "singular"),
    (dict(matrix=np.eye(4)), "3x3"),
    (dict(interpolation="Cubic"), "interpolation"),
    (dict(projection="CUBE"), "projection"),
    (dict(strength=float("inf")), "strength"),
])
def test_bad_environment_is_a_scene_error(change, message):
    args = dict(pixels=np.ones((4, 8, 3), np.float32), name="sky.exr")
    args.update(change)
    scene = Scene(world=World((0, 0, 0), EnvironmentTexture(**args)))
    with pytest.raises(SceneError, match=message) as err:
        render(scene, RenderSettings(samples=1))
    assert "sky.exr" in str(err.value)
