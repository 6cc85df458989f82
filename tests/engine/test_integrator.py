"""End-to-end estimator tests: furnace, analytic irradiance, strategy agreement,
and robustness (no NaN/Inf ever reaches the film).

Every tolerance comes from the standard error the film measures (per-sample
second moments), with a Sidak correction over the pixels or blocks tested.
"""
import numpy as np
import pytest

from engine import bsdf
from engine.render import render
from engine.scene import (AreaLight, Camera, Instance, Lobe, Material, Mesh, PointLight,
                          RenderSettings, Scene, SceneError, SpotLight, SunLight, World)
from engine.testscenes import box, look_at, quad, uv_sphere, veach_plates

from analytic import (analytic_scene, big_plane, check_against, directional_albedo, disk_irradiance,  # noqa: F401
                      furnace_plane, ortho_camera, pixel_centres)
from ember_stats import (block_means_var, detectable, family_level, family_z, median_block_detects, z_scores,
                         z_threshold)



# ----------------------------------------------------------------------------
# White furnace

def test_diffuse_furnace_is_exact():
    """Albedo-1 Lambertian objects under a unit world reflect exactly 1."""
    white = Material("white", (Lobe("diffuse", (1.0, 1.0, 1.0)),))
    for mu in (0.15, 0.6, 1.0):
        r = furnace_plane(white, mu, spp=16)
        np.testing.assert_allclose(r.image[..., :3], 1.0, rtol=1e-6)
    sphere = uv_sphere(1.0, 64, 32, smooth=False)
    cam = ortho_camera((0, -5, 0), (0, 0, 0), (32, 32), 2.6, up=(0, 0, 1))
    scene = Scene([sphere], [Instance(0, materials=[0])], [white], [], World((1.0, 1.0, 1.0)), cam)
    r = render(scene, RenderSettings(samples=16, samples_per_pass=16, transparent=True))
    assert r.image[..., 3].max() == 1.0 and r.image[..., 3].min() == 0.0  # sphere and background seen
    r = render(scene, RenderSettings(samples=16, samples_per_pass=16))
    np.testing.assert_allclose(r.image[..., :3], 1.0, rtol=1e-6)


LAMBERT_COLOUR = (0.2, 0.55, 0.9)


@pytest.mark.parametrize("mu", [0.2, 0.7, 1.0])
def test_lambert_albedo_is_its_colour(mu):
    """Truth: Lambert's law, f = rho / pi, has the directional albedo rho at
    every view angle (int rho / pi cos d omega = rho), so a coloured diffuse
    plane under a unit world renders its colour in each channel; the same
    closed form holds for the quadrature of eval().  Cosine-weighted sampling
    gives every path the weight rho exactly: the render is exact."""
    mat = Material("coloured", (Lobe("diffuse", LAMBERT_COLOUR),))
    np.testing.assert_allclose(directional_albedo(mat, mu), LAMBERT_COLOUR, rtol=1e-6)
    r = furnace_plane(mat, mu, spp=8)
    np.testing.assert_allclose(r.image[..., :3], np.broadcast_to(LAMBERT_COLOUR, r.image[..., :3].shape),
                               rtol=1e-6)


# Cycles' own directional albedo of single-scatter GGX with Fresnel 1:
# table_ggx_E in intern/cycles/scene/shader.tables (blender/blender, commit
# 09cf4924), computed by intern/cycles/app/cycles_precompute.cpp with Cycles'
# bsdf_microfacet_ggx_sample, 2^23 Sobol samples per entry (Monte Carlo error
# below 1e-5) and printed to 6 decimals.  The table is 32 x 32, row mu =
# y / 31 (clamped to 1e-4), column roughness = x / 31 (alpha = roughness^2).
# Entries at grid nodes, so no interpolation enters: {(y, x): E}.
CYCLES_GGX_E = {(8, 10): 0.920251, (8, 19): 0.801368, (8, 31): 0.591195,
                (22, 10): 0.980174, (22, 19): 0.782625, (22, 31): 0.376017,
                (31, 10): 0.987261, (31, 19): 0.809871, (31, 31): 0.306853}
CYCLES_TABLE_ERROR = 1e-5 + 5e-7      # its Monte Carlo error and its rounding, as a bound


def glossy_furnace(roughness, mu, spp=128):
    """A white GGX plane under a unit world: rendered mean and its standard
    error."""
    mat = Material("glossy", (Lobe("glossy", (1.0, 1.0, 1.0), roughness),))
    r = furnace_plane(mat, mu, spp=spp)
    img = r.image[..., 0].astype(np.float64)
    var = r.variance[..., 0].astype(np.float64)
    return img.mean(), np.sqrt(var.sum()) / img.size


def furnace_z(mean, se, expected):
    """z of a furnace mean against a Cycles table value (its error bound
    added in quadrature, as if it were one standard error)."""
    return (mean - expected) / np.hypot(se, CYCLES_TABLE_ERROR)


@pytest.mark.parametrize("rough_x", [10, 19, 31])
@pytest.mark.parametrize("mu_y", [8, 22, 31])
def test_glossy_furnace_matches_cycles_albedo(rough_x, mu_y):
    """Truth from outside Ember: a white GGX plane under a unit world renders
    Cycles' directional albedo E(mu, roughness) (CYCLES_GGX_E, Cycles' own
    precomputed table at a grid node): 1 minus the energy single-scatter GGX
    loses."""
    roughness, mu = rough_x / 31, mu_y / 31
    expected = CYCLES_GGX_E[(mu_y, rough_x)]
    mean, se = glossy_furnace(roughness, mu)
    z = furnace_z(mean, se, expected)
    level = family_level(__name__)
    print(f"roughness {roughness:.4f} mu {mu:.4f}: rendered {mean:.5f} +- {se:.5f}, Cycles' E {expected:.6f}, "
          f"energy lost {1 - expected:.4f}, z {z:+.2f}; detects a relative bias of "
          f"{detectable(np.hypot(se, CYCLES_TABLE_ERROR), level) / expected:.3%} with probability 1/2")
    assert abs(z) < z_threshold(level)


def test_mutation_bsdf_pdf_101_is_caught(monkeypatch):
    """Mutation check: GGX sampling that claims a pdf 1.01 times too high
    (so each sample's weight f cos / pdf is 1 % low) must fail the furnace.
    The mutation wraps the public ``engine.bsdf.sample`` the integrator calls."""
    real = bsdf.sample

    def pdf_too_high(*args, **kwargs):
        wi, weight, pdf, delta = real(*args, **kwargs)
        return wi, weight / 1.01, pdf * 1.01, delta
    monkeypatch.setattr(bsdf, "sample", pdf_too_high)
    mean, se = glossy_furnace(10 / 31, 22 / 31)
    z = furnace_z(mean, se, CYCLES_GGX_E[(22, 10)])
    zc = family_z(__name__, 1)
    print(f"pdf x 1.01: rendered {mean:.5f} +- {se:.5f}, Cycles' E {CYCLES_GGX_E[(22, 10)]}, z {z:+.2f} "
          f"(limit {zc:.2f}; detects {zc * se / CYCLES_GGX_E[(22, 10)]:.2%} with probability 1/2)")
    assert z < -zc, "a 1 % error in the BSDF pdf went unnoticed"


def test_mixed_lobes_furnace():
    """Diffuse 0.5 + glossy 0.5 (no Fresnel): the albedo is the sum of the
    lobes' closed or outside truths, 0.5 (Lambert) + 0.5 E (Cycles' table at
    the node mu = 8/31, roughness 19/31)."""
    mat = Material("mix", (Lobe("diffuse", (0.5, 0.5, 0.5)),
                           Lobe("glossy", (0.5, 0.5, 0.5), 19 / 31, "none")))
    expected = 0.5 + 0.5 * CYCLES_GGX_E[(8, 19)]
    r = furnace_plane(mat, 8 / 31, spp=128)
    img = r.image[..., 0].astype(np.float64)
    se = np.sqrt(r.variance[..., 0].astype(np.float64).sum()) / img.size
    z = furnace_z(img.mean(), se, expected)
    level = family_level(__name__)
    print(f"diffuse + glossy: rendered {img.mean():.5f} +- {se:.5f}, expected {expected:.6f}, z {z:+.2f}; "
          f"detects {detectable(np.hypot(se, CYCLES_TABLE_ERROR), level) / expected:.3%} with probability 1/2")
    assert abs(z) < z_threshold(level)


# ----------------------------------------------------------------------------
# Analytic irradiance

@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
def test_disk_light_irradiance(strategy):
    R, h, P = 0.5, 1.0, 20.0
    m = np.eye(4)
    m[:3, 3] = (0, 0, h)
    scene, rho = analytic_scene(AreaLight(m, (P, P, P), "DISK", 2 * R))
    L = P / (np.pi * np.pi * R * R)
    spp = 256 if strategy == "bsdf" else 64
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, seed=11, strategy=strategy,
                                     filter_type="BOX", filter_width=1e-3))
    x, y = pixel_centres(40, 4.0)
    expected = rho / np.pi * disk_irradiance(L, R, h, np.hypot(x, y))
    check_against(r, expected, np.ones_like(expected, bool), f"disk light ({strategy})")


def test_mutation_dropped_cosine_is_caught(monkeypatch):
    """Mutation check: light sampling without the receiver's cosine (f
    divided by |cos theta_i| before the integrator multiplies it back) must
    fail the analytic disk-light check.  Wraps the public
    ``engine.bsdf.eval_pdf``."""
    real = bsdf.eval_pdf

    def no_cosine(lobes, wo, wi, *args, **kwargs):
        f, pdf = real(lobes, wo, wi, *args, **kwargs)
        return f / np.maximum(np.abs(wi[:, 2:3]), 1e-6), pdf
    monkeypatch.setattr(bsdf, "eval_pdf", no_cosine)
    with pytest.raises(AssertionError, match="image mean is off"):
        test_disk_light_irradiance("light")


@pytest.mark.parametrize("selection", ["power", "uniform", "all", "auto"])
def test_sphere_light_irradiance(selection):
    r_light, d, P = 0.25, 1.0, 30.0
    light = PointLight((0, 0, d), (P, P, P), radius=r_light, soft_falloff=False)
    scene, rho = analytic_scene(light)
    # A second, far-away dim light makes the selection strategies differ.
    scene.lights = [light, PointLight((30, 0, 30), (0.0, 0.0, 0.0), radius=0.1)]
    r = render(scene, RenderSettings(samples=64, samples_per_pass=64, seed=5, light_selection=selection,
                                     filter_type="BOX", filter_width=1e-3))
    x, y = pixel_centres(40, 4.0)
    D2 = x * x + y * y + d * d
    expected = rho / np.pi * P / (4 * np.pi) * d / D2 ** 1.5
    # Pixels that see the sphere itself are not the plane.
    mask = np.hypot(x, y) > r_light + 0.15
    check_against(r, expected, mask, f"sphere light ({selection})")


@pytest.mark.parametrize("d", [0.3, 2.0])
def test_soft_falloff_point_light_is_cycles_disk(d):
    """Blender 4+'s soft falloff: a disk of radius r facing the shading point.
    On-axis irradiance P / (4 pi (d^2 + r^2)): 0.59x the sphere's at d 0.3, r 0.25.
    Estimated straight from the light sampler (the camera would see the disk)."""
    from engine.geometry import flatten, material_table
    from engine.lights import LightSet

    r_light, P, n = 0.25, 10.0, 400_000
    scene, _ = analytic_scene(PointLight((0, 0, d), (P, P, P), radius=r_light, soft_falloff=True))
    lights = LightSet(scene, flatten(scene), bsdf.MaterialTable(material_table(scene)))
    rng = np.random.default_rng(4)
    u = rng.random((n, 3))
    ls = lights.sample(np.zeros(n, int), np.zeros((n, 3)), u[:, 0], u[:, 1], u[:, 2])
    est = ls.Le[:, 0] * np.maximum(ls.wi[:, 2], 0) / ls.pdf
    expected = P / (4 * np.pi * (d * d + r_light * r_light))
    se = est.std() / np.sqrt(n)
    zc = family_z(__name__, 2)
    print(f"soft falloff d={d}: E {est.mean():.5f} +- {se:.5f}, expected {expected:.5f}, "
          f"ratio to sphere {est.mean() / (P / (4 * np.pi * d * d)):.4f}; detects {zc * se / expected:.2%}")
    assert abs(est.mean() - expected) < zc * se


# ----------------------------------------------------------------------------
# Strategy agreement (Veach's plates)

def test_strategies_agree_and_mis_has_lowest_variance():
    """Light-only, BSDF-only and MIS agree block by block; MIS has the lowest
    variance.  Blocks holding under 1% of the brightest block's radiance are
    left out: there the weak strategy's only contributions are rare events
    (e.g. BSDF samples of a near-mirror's GGX tail hitting the small light), so
    its sample variance is no estimate of its error (it is often 0)."""
    scene = veach_plates()
    results = {}
    # Independent seeds: the z-tests below assume independent estimates.
    for seed, strategy in enumerate(("light", "bsdf", "mis"), start=7):
        r = render(scene, RenderSettings(samples=256, samples_per_pass=256, seed=seed, strategy=strategy,
                                         max_bounces=0))
        assert np.isfinite(r.image).all()
        results[strategy] = r
    variances = {k: float(r.variance[..., :3].astype(np.float64).sum()) for k, r in results.items()}
    print("summed pixel variance:", {k: f"{v:.4g}" for k, v in variances.items()})
    blocks = {k: block_means_var(r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), 4)
              for k, r in results.items()}
    ref = blocks["mis"][0]
    keep = ref > 0.01 * ref.max()
    pairs = (("light", "bsdf"), ("light", "mis"), ("bsdf", "mis"))
    zc = family_z(__name__, keep.sum() * len(pairs))
    worst = {}
    for a, b in pairs:
        z = z_scores(*blocks[a], *blocks[b])[keep]
        worst[(a, b)] = np.abs(z).max()
        print(f"{a} vs {b}: {keep.sum()} block-channels, max |z| {worst[(a, b)]:.2f} (limit {zc:.2f}), "
              f"means {blocks[a][0][keep].mean():.4f} / {blocks[b][0][keep].mean():.4f}; the median block "
              f"detects {median_block_detects(zc, blocks[b][0][keep], blocks[a][1][keep], blocks[b][1][keep]):.1%}")
    assert keep.sum() >= 30  # the plates and lights, not the black background
    assert max(worst.values()) < zc
    assert variances["mis"] < variances["light"]
    assert variances["mis"] < variances["bsdf"]


# ----------------------------------------------------------------------------
# Robustness: nothing non-finite reaches the film; bad input is a clear error

def hostile_scene():
    degenerate = Mesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 0.0]]),
                      np.array([[0, 1, 2], [0, 0, 3], [1, 1, 1]]), name="degenerate")
    inside_out = box((3, 3, 3))
    inside_out = Mesh(inside_out.positions, inside_out.triangles[:, ::-1].copy(), name="inside out")
    sphere = uv_sphere(0.5, 16, 8, smooth=True)
    bad_normals = sphere.normals.copy()
    bad_normals[::3] *= -1.0          # normals against the winding
    bad_normals[1::7] = 0.0           # zero-length normals
    sphere.normals = bad_normals
    meshes = [degenerate, inside_out, sphere]
    mats = [Material("mirror", (Lobe("mirror", (1, 1, 1)),)),
            Material("glossy", (Lobe("glossy", (1, 1, 1), 0.0),
                                Lobe("diffuse", (0.5, 0.5, 0.5)))),
            Material("lamp", (Lobe("diffuse", (0.5, 0.5, 0.5)),), emission=(5.0, 5.0, 5.0))]
    instances = [Instance(0, materials=[2]), Instance(1, materials=[0]), Instance(2, materials=[1]),
                 Instance(2, np.diag([1.0, 1.0, -1.0, 1.0]) @ np.eye(4), [2], "mirrored")]
    spot = SpotLight((0, 0, 1.2), (50, 50, 50), radius=0.0, direction=(0, 0, -1), spot_blend=0.0)
    lights = [PointLight((0.3, 0.2, 0.4), (20, 20, 20), radius=0.2),   # intersects the sphere
              spot, SunLight((0, 0, -1), (2, 2, 2), 0.0),
              AreaLight(np.eye(4), (5, 5, 5), "RECTANGLE", 0.0, 0.0),   # zero area
              PointLight((0, 0, 0), (5, 5, 5), radius=0.0, soft_falloff=True)]
    cam = Camera(look_at((1.4, -1.4, 1.4), (0, 0, 0)), lens=12.0, resolution=(32, 24))
    return Scene(meshes, instances, mats, lights, World((0.2, 0.2, 0.2)), cam)


@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
def test_no_nan_in_hostile_scene(strategy):
    r = render(hostile_scene(), RenderSettings(samples=16, samples_per_pass=8, strategy=strategy,
                                               light_selection="all" if strategy == "bsdf" else "power"))
    for arr in (r.image, r.depth, r.normal, r.albedo, r.variance):
        assert np.isfinite(arr).all()
    assert r.image[..., :3].max() > 0
    assert any("degenerate" in w for w in r.warnings)


def test_grazing_camera_is_finite():
    mesh, inst = big_plane()
    cam = Camera(look_at((0, -10, 1e-4), (0, 10, 1e-4)), lens=20.0, resolution=(16, 16))
    scene = Scene([mesh], [inst], [Material("g", (Lobe("glossy", (1, 1, 1), 0.2),))],
                  [SunLight((0.0, 1.0, -1e-3), (3, 3, 3), 0.01)], World((0.5, 0.5, 0.5)), cam)
    r = render(scene, RenderSettings(samples=8, samples_per_pass=8))
    assert np.isfinite(r.image).all()


@pytest.mark.parametrize("mutate, message", [
    (lambda s: setattr(s.meshes[0], "positions", np.array([[np.nan, 0, 0]] * 4)), "NaN"),
    (lambda s: setattr(s.meshes[0], "triangles", np.array([[0, 1, 9]])), "out of range"),
    (lambda s: setattr(s.meshes[0], "triangles", np.array([0, 1, 2])), "shape"),
    (lambda s: setattr(s.meshes[0], "positions", np.array([["a", "b", "c"]] * 4)), "dtype"),
    (lambda s: setattr(s.instances[0], "mesh", 3), "mesh index"),
    (lambda s: setattr(s.instances[0], "materials", [5]), "material"),
    (lambda s: setattr(s.camera, "resolution", (0, 10)), "resolution"),
    (lambda s: setattr(s.lights[0], "radius", -1.0), "radius"),
    (lambda s: setattr(s.materials[0], "lobes", (Lobe("glossy_anisotropic", (1, 1, 1), 0.3, anisotropy=np.nan),)),
     "anisotropy"),
    (lambda s: setattr(s.materials[0], "lobes", (Lobe("glossy_anisotropic", (1, 1, 1), 0.3, anisotropy=3.0),)),
     "anisotropy"),
])
def test_bad_input_is_a_clear_error(mutate, message):
    mesh, inst = big_plane()
    scene = Scene([mesh], [inst], [Material()], [PointLight((0, 0, 1), (1, 1, 1))], World(),
                  Camera(resolution=(8, 8)))
    mutate(scene)
    with pytest.raises(SceneError, match=message):
        render(scene, RenderSettings(samples=1))


def test_deterministic_for_a_seed():
    scene = veach_plates((16, 12))
    a = render(scene, RenderSettings(samples=4, samples_per_pass=2, seed=9)).image
    b = render(scene, RenderSettings(samples=4, samples_per_pass=2, seed=9)).image
    c = render(scene, RenderSettings(samples=4, samples_per_pass=2, seed=10)).image
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("transparent_max_bounces", [8, 1])
def test_paths_go_on_past_lights_as_in_cycles(transparent_max_bounces):
    """Cycles (integrator_shade_light) adds a light's emission and continues
    the ray past it, counting a transparent bounce, and ends the path when
    that count reaches transparent_max_bounces.  A camera sees a camera-
    visible square light in front of an emissive floor: light plus floor,
    or the light alone when one transparent bounce is the limit.  (Paths
    ending at lights made the Cornell box 0.9 % darker than Cycles:
    tests/addon/test_cycles_references.py.)"""
    floor = quad([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]])
    glow = Material("glow", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=(0.5, 0.25, 0.125))
    up = np.diag([1.0, -1.0, -1.0, 1.0])       # emits along -Z of its matrix: here +z, at the camera
    up[:3, 3] = (0.0, 0.0, 1.0)
    P = 10.0
    light = AreaLight(up, (P, P, P), "SQUARE", 2.0, visible_camera=True)
    cam = ortho_camera((0, 0, 5), (0, 0, 0), (8, 8), 1.0)
    scene = Scene([floor], [Instance(0, materials=[0])], [glow], [light], World((0.0, 0.0, 0.0)), cam)
    r = render(scene, RenderSettings(samples=4, samples_per_pass=4, max_bounces=0, filter_type="BOX",
                                     filter_width=1e-3, transparent_max_bounces=transparent_max_bounces))
    L = P / (np.pi * 4.0)
    expected = L + (np.array([0.5, 0.25, 0.125]) if transparent_max_bounces > 1 else 0.0)
    np.testing.assert_allclose(r.image[..., :3], np.broadcast_to(expected, (8, 8, 3)), rtol=1e-6)


# ----------------------------------------------------------------------------
# Russian roulette

def closed_sphere(rr_depth, seed, spp=16):
    """Inside a closed diffuse sphere (albedo 0.8, normals inwards by the
    winding Ember sees from inside) lit by a point light near its centre:
    most light arrives after many bounces, so roulette (from ``rr_depth``)
    weighs nearly every path's tail."""
    sphere = uv_sphere(1.0, 48, 24, smooth=False)
    grey = Material("grey", (Lobe("diffuse", (0.8, 0.8, 0.8)),))
    cam = Camera(look_at((0.0, 0.0, -0.2), (1.0, 0.0, -0.2), (0.0, 0.0, 1.0)), resolution=(24, 16),
                 clip_start=0.01, clip_end=10.0)
    light = PointLight((0.0, 0.0, 0.1), (10.0, 10.0, 10.0), radius=0.0)
    scene = Scene([sphere], [Instance(0, materials=[0])], [grey], [light], World((0.0, 0.0, 0.0)), cam)
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, max_bounces=24, rr_depth=rr_depth,
                                     seed=seed))
    img = r.image[..., 0].astype(np.float64)
    return img.mean(), np.sqrt(r.variance[..., 0].astype(np.float64).sum()) / img.size


def test_russian_roulette_is_unbiased():
    """Truth: the same estimator without roulette (rr_depth beyond the bounce
    limit: every path traced to 24 bounces with its full weight), which no
    roulette code touches.  With roulette from bounce 1 the image mean must
    agree (independent seeds, z-test); a survival weight off by 2 % moves it
    by about 1 % here (0.8^k of the light comes after k >= 1 bounces)."""
    with_rr, se_rr = closed_sphere(1, seed=5, spp=256)
    without, se = closed_sphere(1000, seed=6, spp=8)
    se_diff = np.hypot(se_rr, se)
    z = (with_rr - without) / se_diff
    limit = family_z(__name__ + " roulette", 1)
    print(f"roulette from bounce 1: {with_rr:.5f} +- {se_rr:.5f}, without: {without:.5f} +- {se:.5f}, z {z:+.2f}; "
          f"detects a relative bias of {limit * se_diff / without:.2%} with probability 1/2")
    assert abs(z) < limit
