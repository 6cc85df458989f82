"""Equiangular sampling of direct-light points in homogeneous media and its
MIS with distance sampling (engine/media/equiangular.py, the direct-light
points of engine/integrator/volume.py; Cycles' shade_volume.h).

The sampler's inverse CDF against its pdf in closed form, and a spot light
inside fog rendered with Volume > Sampling 'DISTANCE', 'EQUIANGULAR' and
'MULTIPLE_IMPORTANCE': the three agree block by block and over the whole
image (one statistical family), and equiangular / MIS have a lower variance
than distance sampling (the gain printed).
"""
import numpy as np
import pytest

from ember_stats import block_means_var, family_z, z_scores
from engine.media import equiangular
from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, SpotLight, Volume, World
from engine.testscenes import box, look_at, quad

PASS = (Lobe("transparent", (1.0, 1.0, 1.0)),)


@pytest.mark.parametrize("t_end", [0.7, 3.0, np.inf])
def test_equiangular_inverse_cdf_matches_its_pdf(t_end):
    """t(xi) from ``sample`` integrates ``pdf`` to xi (trapezoid on a fine
    grid), its pdf is the one ``pdf`` gives, and pdf integrates to 1."""
    rng = np.random.default_rng(5)
    n = 6
    o = rng.normal(size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    P = o + d * rng.uniform(-0.5, 2.0, n)[:, None] + rng.normal(scale=0.3, size=(n, 3))
    te = np.full(n, t_end)
    xi = np.linspace(0.05, 0.95, 7)
    for i in range(n):
        oo, dd, PP, tt = (np.repeat(a[i:i + 1], len(xi), axis=0) for a in (o, d, P, te))
        t, p = equiangular.sample(oo, dd, PP, np.zeros(len(xi)), tt, xi)
        assert (p > 0).all()
        np.testing.assert_allclose(p, equiangular.pdf(oo, dd, PP, np.zeros(len(xi)), tt, t), rtol=1e-12)
        top = t_end if np.isfinite(t_end) else 1e4
        grid = np.concatenate([np.linspace(0, min(top, 20.0), 200001), np.geomspace(20.0, 1e4, 20001)[1:]]) \
            if not np.isfinite(t_end) else np.linspace(0, top, 200001)
        g = len(grid)
        pg = equiangular.pdf(np.repeat(o[i:i + 1], g, 0), np.repeat(d[i:i + 1], g, 0),
                             np.repeat(P[i:i + 1], g, 0), np.zeros(g), np.full(g, t_end), grid)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (pg[1:] + pg[:-1]) * np.diff(grid))])
        np.testing.assert_allclose(np.interp(t, grid, cdf), xi, atol=2e-4)
        if np.isfinite(t_end):
            assert abs(cdf[-1] - 1.0) < 1e-6


def test_stack_method_combines_like_cycles():
    m = np.array([equiangular.DISTANCE, equiangular.EQUIANGULAR, equiangular.MIS])
    stacks = np.array([[0, -1], [1, -1], [2, -1], [0, 1], [1, 1], [-1, -1]])
    assert list(equiangular.stack_method(m, stacks)) == [equiangular.DISTANCE, equiangular.EQUIANGULAR,
                                                         equiangular.MIS, equiangular.MIS,
                                                         equiangular.EQUIANGULAR, equiangular.DISTANCE]


def spot_in_fog(sampling, size=(24, 18)):
    """A spot shining down through a fog box onto a grey floor, the camera
    outside the fog: the beam and its lit floor."""
    fog = Material("fog", PASS, volume=Volume(scattering=(0.5, 0.5, 0.5), absorption=(0.05, 0.08, 0.12),
                                              anisotropy=0.3, sampling=sampling))
    floor = Material("floor", (Lobe("diffuse", (0.6, 0.6, 0.6)),))
    spot = SpotLight((0.0, 0.0, 1.2), (60.0, 60.0, 60.0), radius=0.1, direction=(0.0, 0.0, -1.0),
                     spot_size=1.1, spot_blend=0.2)
    cam = Camera(look_at((0, -6, 0.3), (0, 0, 0.1)), lens=40, resolution=size)
    meshes = [box((3.0, 3.0, 3.0)), quad([[-1.4, -1.4, -1.2], [1.4, -1.4, -1.2], [1.4, 1.4, -1.2], [-1.4, 1.4, -1.2]])]
    instances = [Instance(0, materials=[0], name="fog box"), Instance(1, materials=[1], name="floor")]
    return Scene(meshes, instances, [fog, floor], [spot], World((0.0, 0.0, 0.0)), cam)


def test_spot_in_fog_sampling_methods_agree():
    """Distance, equiangular and MIS direct-light points give the same
    image (blocks and whole-image means, single scattering as Cycles'
    default volume_bounces 0), and equiangular sampling (alone or by MIS)
    cuts the variance of a spot's beam against distance sampling (each
    segment's own point, truncated to the spot's cone, as Cycles 5.0)."""
    results = {}
    for seed, sampling in enumerate(("DISTANCE", "EQUIANGULAR", "MULTIPLE_IMPORTANCE"), start=41):
        spp = 1024
        # Guiding off: the camera rays' scatter / transmit choice (volume_guide.py,
        # one pass here: q = mix(1 - T, 1/2)) would add its own noise to the
        # direct-light points' variance compared below.
        results[sampling] = render(spot_in_fog(sampling), RenderSettings(samples=spp, samples_per_pass=spp,
                                                                         seed=seed, max_bounces=4,
                                                                         volume_guiding=False))
        assert np.isfinite(results[sampling].image).all()
    blocks = {k: block_means_var(r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), 3)
              for k, r in results.items()}
    ref = blocks["MULTIPLE_IMPORTANCE"][0]
    keep = ref > 0.02 * ref.max()
    names = list(results)
    pairs = [(names[i], names[j]) for i in range(3) for j in range(i + 1, 3)]
    zc = family_z(__name__ + ".methods", (int(keep.sum()) + 3) * len(pairs))
    worst = worst_pair_z(results, blocks, pairs, keep, zc)
    # The variance gain over the lit pixels: in total, and the median of
    # the per-pixel ratios (distance sampling's variance is mostly in a few
    # pixels, from points next to the light).
    lit = results["MULTIPLE_IMPORTANCE"].image[..., :3].mean(axis=2)
    lit = lit > 0.05 * lit.max()
    var = {k: r.variance[..., :3].astype(np.float64).sum(axis=2)[lit] for k, r in results.items()}
    gain = {k: float(np.median(var["DISTANCE"] / np.maximum(v, 1e-30))) for k, v in var.items()}
    total = {k: float(v.sum()) for k, v in var.items()}
    print(f"{lit.sum()} lit pixels; median variance gain over distance sampling:",
          {k: f"{g:.2f}x" for k, g in gain.items()}, "; total variance", total)
    assert keep.sum() >= 20
    assert worst < zc
    assert total["EQUIANGULAR"] < total["DISTANCE"] and total["MULTIPLE_IMPORTANCE"] < total["DISTANCE"], total


@pytest.mark.parametrize("cos_half", [0.95, 0.6, 0.0])
def test_cone_segment_is_where_the_ray_is_inside_the_cone(cos_half):
    """The spot's lit interval of random rays against points tested one by
    one along them (grid spacing 1e-3: endpoints agree within 2 steps)."""
    rng = np.random.default_rng(8)
    n = 200
    o = rng.uniform(-2, 2, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    apex = np.zeros((n, 3))
    axis = np.tile([0.0, 0.0, -1.0], (n, 1))
    t_end = np.where(np.arange(n) % 3 == 0, np.inf, rng.uniform(0.5, 5.0, n))
    t0, t1 = equiangular.cone_segment(o, d, apex, axis, np.full(n, cos_half), t_end)
    grid = np.arange(0, 8.0, 1e-3)
    for i in range(n):
        top = min(t_end[i], 8.0)
        ts = grid[grid <= top]
        x = o[i] + d[i] * ts[:, None]
        inside = x @ axis[i] >= cos_half * np.linalg.norm(x, axis=1)
        if not inside.any():
            assert t1[i] <= t0[i] + 2e-3 or t0[i] >= top - 2e-3, (i, t0[i], t1[i])
            continue
        assert abs(t0[i] - ts[inside][0]) < 2e-3, (i, t0[i], ts[inside][0])
        if ts[inside][-1] < top - 2e-3:
            assert abs(min(t1[i], 8.0) - ts[inside][-1]) < 2e-3, (i, t1[i], ts[inside][-1])
        else:
            assert t1[i] >= top - 2e-3


def test_three_lights_in_fog_agree_with_light_sampling_at_scattering_points():
    """A spot, a point light and a sun in fog: each segment's direct-light
    point (restricted to the cone of the spot when the spot was picked; a
    truncated distance for the sun) against
    light sampling at the free flights' scattering points (strategy
    'light', which has no direct-light points), blocks and image means."""
    from engine.scene import PointLight, SunLight
    results = {}
    for seed, strategy in ((61, "mis"), (62, "light")):
        scene = spot_in_fog("MULTIPLE_IMPORTANCE")
        scene.lights.append(PointLight((-1.0, 0.5, 0.2), (8.0, 4.0, 2.0), radius=0.1))
        scene.lights.append(SunLight((0.5, 0.3, -0.8), (0.3, 0.4, 0.6), angle=0.05))
        results[strategy] = render(scene, RenderSettings(samples=1024, samples_per_pass=1024, seed=seed,
                                                         strategy=strategy, max_bounces=4))
        assert np.isfinite(results[strategy].image).all()
    blocks = {k: block_means_var(r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), 3)
              for k, r in results.items()}
    ref = blocks["mis"][0]
    keep = ref > 0.02 * ref.max()
    zc = family_z(__name__ + ".three_lights", int(keep.sum()) + 3)
    z = z_scores(*blocks["mis"], *blocks["light"])[keep]
    rel_se = np.sqrt(blocks["mis"][1][keep] + blocks["light"][1][keep]) / blocks["light"][0][keep]
    ma, mb = (results[k].image[..., :3].astype(np.float64).sum(axis=(0, 1)) for k in ("mis", "light"))
    se = np.sqrt(sum(results[k].variance[..., :3].astype(np.float64).sum(axis=(0, 1)) for k in results))
    zm = (ma - mb) / se
    print(f"direct-light points vs light sampling at scattering points: {keep.sum()} block-channels, max |z| "
          f"{np.abs(z).max():.2f} (limit {zc:.2f}), median block detects {zc * np.median(rel_se):.1%}; image "
          f"|z| {np.abs(zm).max():.2f}, detects {(zc * se / mb).max():.2%}")
    assert keep.sum() >= 20
    assert max(np.abs(z).max(), np.abs(zm).max()) < zc


def worst_pair_z(results, blocks, pairs, keep, zc):
    """The largest |z| over the kept block-channels and the whole-image
    means of each pair of renders (their power printed against ``zc``)."""
    worst = 0.0
    for a, b in pairs:
        z = z_scores(*blocks[a], *blocks[b])[keep]
        rel_se = np.sqrt(blocks[a][1][keep] + blocks[b][1][keep]) / blocks[b][0][keep]
        ma, mb = (results[k].image[..., :3].astype(np.float64).sum(axis=(0, 1)) for k in (a, b))
        se = np.sqrt(sum(results[k].variance[..., :3].astype(np.float64).sum(axis=(0, 1)) for k in (a, b)))
        zm = (ma - mb) / se
        worst = max(worst, np.abs(z).max(), np.abs(zm).max())
        print(f"{a} vs {b}: {keep.sum()} block-channels, max |z| {np.abs(z).max():.2f} (limit {zc:.2f}), "
              f"median block detects {zc * np.median(rel_se):.1%}; image |z| {np.abs(zm).max():.2f}, "
              f"detects {(zc * se / mb).max():.2%}")
    return worst
