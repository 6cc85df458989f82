"""Transparent surfaces as Cycles treats them (issue 4): shadow rays cross
Transparent BSDFs and Principled Alpha < 1, attenuated by their
transparency; BSDF-sampled paths through the same surfaces carry the same
weight (strategies agree); transparent passes count towards
transparent_max_bounces, not max_bounces; a transparent film shows through.

Analytic values: a diffuse floor of albedo rho under a light of irradiance E
reflects rho E / pi, times the transparency T of every plate between them.
"""
import numpy as np
import pytest

from engine.render import render
from engine.scene import (AreaLight, Camera, Instance, Lobe, Material, PointLight, RenderSettings,
                          Scene, World)
from engine.testscenes import look_at, quad

from ember_stats import block_means_var, family_z, median_block_detects, z_scores
from analytic import check_against, disk_irradiance, pixel_centres

RHO = 0.5
SIZE, SCALE = 40, 5.0      # ortho camera: 40 x 40 pixels over 5 x 5 m of floor
FLOOR = Material("floor", (Lobe("diffuse", (RHO, RHO, RHO)),))
# 50 % transparent: a Mix(Transparent, Diffuse) as the exporter writes it.
HALF = Material("half", (Lobe("transparent", (1.0, 1.0, 1.0), weight=0.5),
                         Lobe("diffuse", (0.8, 0.6, 0.4), weight=0.5)))


def settings(**kw):
    base = dict(samples=64, samples_per_pass=64, seed=3, max_bounces=0, filter_type="BOX",
                filter_width=1e-3)
    base.update(kw)
    return RenderSettings(**base)


def plate_scene(light, plates, material, visible_camera=False, floor=FLOOR):
    """A floor at z = 0 and square plates (height, half size) above it; the
    camera looks straight down and, by default, does not see the plates."""
    meshes = [quad([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])]
    instances = [Instance(0, materials=[0], name="floor")]
    for k, (h, a) in enumerate(plates):
        meshes.append(quad([[-a, -a, h], [a, -a, h], [a, a, h], [-a, a, h]]))
        instances.append(Instance(k + 1, materials=[1], name=f"plate{k}", visible_camera=visible_camera))
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=SCALE,
                 resolution=(SIZE, SIZE), clip_start=0.01, clip_end=100.0)
    lights = [] if light is None else [light]
    return Scene(meshes, instances, [floor, material], lights, World((0.0, 0.0, 0.0)), cam)


def point_light_floor(h, P):
    """rho E / pi on the floor under a point light of power P at height h."""
    x, y = pixel_centres(SIZE, SCALE)
    return x, y, RHO / np.pi * P / (4 * np.pi) * h / (x * x + y * y + h * h) ** 1.5


@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
@pytest.mark.parametrize("material,T", [(HALF, 0.5),
                                        (Material("alpha 0.4", (Lobe("transparent", (1, 1, 1), weight=0.6),
                                                                Lobe("diffuse", (0.8, 0.8, 0.8), weight=0.4))),
                                         0.6)])
def test_point_light_through_plate_is_transparency_times_unshadowed(strategy, material, T):
    """A point light 2 m above a plate at 1 m: the floor under the plate gets
    exactly T x the unshadowed irradiance (shadow rays cross it), the rest 1x."""
    h, P = 2.0, 30.0
    scene = plate_scene(PointLight((0, 0, h), (P, P, P), radius=0.0), [(1.0, 0.6)], material)
    r = render(scene, settings(strategy=strategy, samples=4, samples_per_pass=4))
    x, y, free = point_light_floor(h, P)
    edge = np.maximum(np.abs(x), np.abs(y))   # the plate's shadow ends at 1.2
    expected = np.where(edge < 1.2, T, 1.0) * free
    keep = np.abs(edge - 1.2) > 0.1
    np.testing.assert_allclose(r.image[..., 0][keep], expected[keep], rtol=2e-3)


def disk_scene(plate_material=HALF):
    R, h, P = 0.3, 2.0, 40.0
    m = np.eye(4)
    m[:3, 3] = (0, 0, h)
    light = AreaLight(m, (P, P, P), "DISK", 2 * R)
    return plate_scene(light, [(1.0, 0.6)], plate_material), R, h, P / (np.pi * np.pi * R * R)


@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
def test_disk_light_through_plate_matches_analytic(strategy):
    """Disk light (radius 0.3 at 2 m) over the 50 % plate (half size 0.6 at
    1 m): where the whole disk is seen through the plate (|x|, |y| < 0.9)
    the floor gets 0.5 E, where none of it is (beyond 1.5) E; NEE, BSDF
    sampling (BSDF rays cross the plate) and MIS all agree with that."""
    scene, R, h, L = disk_scene()
    spp = 512 if strategy == "bsdf" else 64
    r = render(scene, settings(strategy=strategy, samples=spp, samples_per_pass=spp, seed=11))
    x, y = pixel_centres(SIZE, SCALE)
    edge = np.maximum(np.abs(x), np.abs(y))
    E = RHO / np.pi * disk_irradiance(L, R, h, np.hypot(x, y))
    check_against(r, 0.5 * E, edge < 0.9, f"through the plate ({strategy})")
    check_against(r, E, edge > 1.5, f"beside the plate ({strategy})")


@pytest.mark.parametrize("bounces", [0, 2])
def test_strategies_agree_through_transparent_plate(bounces):
    """NEE-only, BSDF-only and MIS agree block by block, with indirect light
    off the plate's diffuse half too (max_bounces 2)."""
    scene, _, _, _ = disk_scene()
    blocks = {}
    for seed, strategy in enumerate(("light", "bsdf", "mis"), start=5):   # independent seeds
        spp = 512 if strategy == "bsdf" else 128
        r = render(scene, settings(strategy=strategy, samples=spp, samples_per_pass=spp, seed=seed,
                                   max_bounces=bounces))
        assert np.isfinite(r.image).all()
        blocks[strategy] = block_means_var(r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), 4)
    pairs = (("light", "bsdf"), ("light", "mis"), ("bsdf", "mis"))
    ref = blocks["mis"][0]
    keep = ref > 0.01 * ref.max()
    zc = family_z(__name__, keep.sum() * len(pairs))
    for a, b in pairs:
        z = np.abs(z_scores(*blocks[a], *blocks[b])[keep])
        rel = blocks[a][0][keep].mean() / blocks[b][0][keep].mean() - 1.0
        print(f"bounces {bounces}, {a} vs {b}: max |z| {z.max():.2f} (limit {zc:.2f}), "
              f"relative mean difference {rel:+.4f}; the median block detects "
              f"{median_block_detects(zc, blocks[b][0][keep], blocks[a][1][keep], blocks[b][1][keep]):.1%}")
        assert z.max() < zc


GREY = Material("grey transparent", (Lobe("transparent", (0.5, 0.5, 0.5)),))
THREE = [(0.6, 3.0), (0.9, 3.0), (1.2, 3.0)]   # each plate covers the whole view


@pytest.mark.parametrize("limit,factor", [(8, 0.125), (3, 0.125), (2, 0.0)])
def test_shadow_rays_cross_up_to_transparent_max_bounces(limit, factor):
    """Three Transparent BSDF plates of colour 0.5 between a point light and
    the floor: 0.5^3 of the light with 3 or more transparent bounces; with
    fewer, shadow rays are blocked (Cycles' max transparent hits)."""
    h, P = 2.0, 30.0
    scene = plate_scene(PointLight((0, 0, h), (P, P, P), radius=0.0), THREE, GREY)
    r = render(scene, settings(samples=4, samples_per_pass=4, transparent_max_bounces=limit))
    _, _, free = point_light_floor(h, P)
    np.testing.assert_allclose(r.image[..., 0], factor * free, rtol=2e-3, atol=1e-9)


@pytest.mark.parametrize("limit,max_bounces,seen", [(8, 0, 0.125), (3, 0, 0.125), (2, 4, 0.0),
                                                    (3, 4, 0.125)])
def test_camera_rays_count_transparent_bounces_apart(limit, max_bounces, seen):
    """The camera looks through three 0.5 plates at a floor emitting 1: it
    sees 0.125 whenever transparent_max_bounces >= 3, even with max_bounces
    0 (transparent passes are no bounces); with 2 the third plate ends the
    path (Cycles: terminate on the next surface) and the floor is unseen."""
    lamp = Material("lamp", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=(1.0, 1.0, 1.0))
    scene = plate_scene(None, THREE, GREY, visible_camera=True, floor=lamp)
    r = render(scene, settings(samples=4, samples_per_pass=4, max_bounces=max_bounces,
                               transparent_max_bounces=limit))
    np.testing.assert_allclose(r.image[..., :3], seen, rtol=1e-6, atol=1e-9)


def test_zero_transparent_bounces_still_cross_one_surface():
    """Cycles' quirk (its FIXME in path_state_next): with 0 transparent
    bounces a camera ray crosses one transparent surface and then ends at
    the next, collecting its emission; shadow rays cross none."""
    lamp = Material("lamp", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=(1.0, 1.0, 1.0))
    scene = plate_scene(None, THREE[:1], GREY, visible_camera=True, floor=lamp)
    r = render(scene, settings(samples=4, samples_per_pass=4, transparent_max_bounces=0))
    np.testing.assert_allclose(r.image[..., :3], 0.5, rtol=1e-6)
    h, P = 2.0, 30.0
    scene = plate_scene(PointLight((0, 0, h), (P, P, P), radius=0.0), THREE[:1], GREY)
    r = render(scene, settings(samples=4, samples_per_pass=4, transparent_max_bounces=0))
    assert r.image[..., :3].max() == 0.0


def test_transparent_film_alpha_through_plate():
    """With a transparent film, a camera ray leaving through a transparent
    surface uncovers the film by its throughput (Cycles: alpha = 1 - the
    mean throughput of such rays): a Transparent 0.5 plate gives alpha 0.5
    exactly; the 50 % Mix plate 0.5 on average."""
    scene = plate_scene(None, [(1.0, 3.0)], GREY, visible_camera=True)
    scene.instances = scene.instances[1:]           # no floor: the world behind
    r = render(scene, settings(samples=4, samples_per_pass=4, transparent=True))
    np.testing.assert_allclose(r.image[..., 3], 0.5, rtol=1e-6)
    scene.materials = [FLOOR, HALF]
    r = render(scene, settings(samples=256, samples_per_pass=256, transparent=True))
    alpha = r.image[..., 3].astype(np.float64)
    # Per sample alpha is 1 (diffuse chosen) or 1 - 0.5 / p (transparent
    # chosen); the pixels are independent means of 256 samples each, so
    # their scatter measures the standard error of the image mean.
    se = alpha.std(ddof=1) / np.sqrt(alpha.size)
    limit = family_z(__name__, 1)
    print(f"film alpha through the 50 % plate: {alpha.mean():.4f} +- {se:.4f} (expected 0.5); "
          f"detects {limit * se:.4f} with probability 1/2")
    if se == 0:
        # The transparent lobe's share is 0.5 / (0.5 + mean(0.4, 0.3, 0.2)) =
        # 5/8 (Cycles' average-weight choice) and 256 Sobol samples split
        # 5/8 exactly in every pixel: each pixel is then the exact value.
        np.testing.assert_allclose(alpha, 0.5, atol=1e-6)
    else:
        assert abs(alpha.mean() - 0.5) < limit * se


def test_opaque_scenes_keep_plain_shadow_rays(monkeypatch):
    """Scenes without a transparent lobe never trace transparent shadows."""
    from engine.integrator import transparency
    calls = []
    monkeypatch.setattr(transparency, "transmittance", lambda *a: calls.append(a))
    h, P = 2.0, 30.0
    scene = plate_scene(PointLight((0, 0, h), (P, P, P), radius=0.0), [(1.0, 0.6)], FLOOR)
    render(scene, settings(samples=2, samples_per_pass=2))
    assert calls == []


def test_camera_invisible_plate_still_blocks_bsdf_rays():
    """An object hidden from the camera only (no other visibility flag in
    the scene) is still there for indirect rays: BSDF sampling alone finds
    the disk light blocked under an opaque plate, as Cycles."""
    scene, _, _, _ = disk_scene(plate_material=FLOOR)
    r = render(scene, settings(strategy="bsdf", samples=64, samples_per_pass=64))
    x, y = pixel_centres(SIZE, SCALE)
    under = np.maximum(np.abs(x), np.abs(y)) < 0.9
    assert r.image[..., 0][under].max() == 0.0
    assert r.image[..., 0][~under].mean() > 0.0


@pytest.mark.parametrize("soft", [False, True])
def test_light_passed_before_a_transparent_plate_is_met_once(soft):
    """BSDF rays from the floor that pass a point light (sphere, or soft
    falloff's disk) and then a fully transparent plate above it: the second
    segment starts past the light, so it must not meet the light again
    (Cycles' ray tmin).  Same seed with and without the plate: the light is
    reached on the first segment either way, so the images agree to
    rounding; counting it again doubled what the rays through the plate
    collected (the fog bench's worst fireflies, 2026-12-06)."""
    clear = Material("clear", (Lobe("transparent", (1.0, 1.0, 1.0)),))
    light = PointLight((0, 0, 1.0), (50.0, 50.0, 50.0), radius=0.3, soft_falloff=soft)
    cfg = settings(strategy="bsdf", samples=16, samples_per_pass=16, seed=5)
    without = render(plate_scene(light, [], clear), cfg).image
    with_plate = render(plate_scene(light, [(1.5, 3.0)], clear), cfg).image
    assert without[..., 0].mean() > 0.01   # the floor sees the light
    np.testing.assert_allclose(with_plate, without, rtol=1e-9, atol=1e-12)
