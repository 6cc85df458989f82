"""Resampled light selection (light selection 'ris', engine/nee.py
``resample``, integrator stage ``resampled_light_sample``): M stratified
light-tree candidates per vertex, one kept by its unshadowed contribution
with the BSDF.

The choice itself is checked exactly (on a grid of uniform numbers: no
statistics), the render against the plain estimator, every light at every
vertex ('all', selection probability 1: nothing to get wrong), with MIS and
with light sampling alone, block by block and in the image mean (two
statistical families).
"""
import numpy as np

from engine import nee
from engine import scene as S


def test_resample_keeps_by_target_and_is_unbiased():
    """On an even grid of u, candidate k is kept for the share T_k / sum(T)
    of the grid, and the kept candidate's target times its factor averages
    to the candidates' mean target, sum(T) / M (the estimator's expectation
    given the candidates); rows of zero targets get factor 0."""
    rng = np.random.default_rng(3)
    m, rows, grid = 4, 6, 1 << 16
    targets = rng.random((m, rows)) * (rng.random((m, rows)) < 0.7)
    targets[:, 0] = 0.0                 # nothing brings light
    targets[:, 1] = [0.0, 0.0, 2.5, 0.0]   # one candidate only
    u = (np.arange(grid) + 0.5) / grid
    kept, factor = nee.resample(np.repeat(targets, grid, axis=1), np.tile(u, rows))
    kept, factor = kept.reshape(rows, grid), factor.reshape(rows, grid)
    assert np.all(factor[0] == 0.0)
    for r in range(1, rows):
        t = targets[:, r]
        share = np.bincount(kept[r], minlength=m) / grid
        np.testing.assert_allclose(share, t / t.sum(), atol=2.0 / grid)
        assert np.all(t[kept[r]] > 0)
        np.testing.assert_allclose((t[kept[r]] * factor[r]).mean(), t.sum() / m, rtol=1e-12)


def mixed_lights_scene(selection, strategy, seed, size=(48, 36), plates=True):
    """Veach's four glossy plates (plates=False: left out) and their four
    disk lights, a diffuse floor, and lights of every other kind: a delta
    point, a spot, a sun with a disk and an emissive quad, so candidates mix
    delta, infinite, area and mesh emitters."""
    from engine.testscenes import look_at, quad, veach_four
    scene = veach_four(size, power=20.0)
    scene.meshes.append(quad([[-6, -4, -0.6], [6, -4, -0.6], [6, 6, -0.6], [-6, 6, -0.6]]))
    scene.materials.append(S.Material("floor", (S.Lobe("diffuse", (0.6, 0.6, 0.6)),)))
    scene.instances.append(S.Instance(len(scene.meshes) - 1, materials=[len(scene.materials) - 1]))
    scene.meshes.append(quad([[-2.6, 1.8, 0.8], [-1.8, 1.8, 0.8], [-1.8, 1.8, 1.6], [-2.6, 1.8, 1.6]]))
    scene.materials.append(S.Material("glow", emission=(3.0, 2.0, 1.0)))
    scene.instances.append(S.Instance(len(scene.meshes) - 1, materials=[len(scene.materials) - 1]))
    scene.lights += [S.PointLight((2.5, -1.0, 2.0), (15.0, 12.0, 10.0), radius=0.0),
                     S.SpotLight((-1.0, -2.0, 3.0), (60.0, 60.0, 80.0), 0.05, direction=(0.3, 0.6, -1.0),
                                 spot_size=0.9),
                     S.SunLight((0.3, 0.4, -1.0), (0.4, 0.4, 0.35), 0.1)]
    if not plates:
        scene.instances = scene.instances[4:]
    scene.camera = S.Camera(look_at((0.0, -6.0, 1.6), (0, 0, 0.3), (0, 0, 1)), lens=40.0, resolution=size)
    return scene, S.RenderSettings(samples=512, samples_per_pass=256, max_bounces=2, seed=seed,
                                   light_selection=selection, strategy=strategy)


def test_resampled_render_agrees_with_all_lights():
    """'ris' against 'all', with MIS and with light sampling alone: Welch's
    z per 4x4-pixel block and the image mean.  With MIS, a BSDF ray that
    meets a light is weighed with min(1, M p_tree) as the light sample was;
    a mistake there (e.g. p_tree on one side) moves whole highlights.  Light
    sampling alone renders the scene without the plates: their sharpest
    highlights of the big lights are found by rare light samples only, a
    tail too heavy for the per-pixel variances to describe at this count."""
    from engine.render import render
    from ember_stats import block_means_var, detectable, family_level, family_z, z_scores, z_threshold
    strategies = ("mis", "light")
    blocks = 12 * 9 * 3
    limit = family_z(__name__ + ".blocks", blocks * len(strategies))
    level = family_level(__name__ + ".mean", len(strategies))
    z_mean = z_threshold(level)
    for k, strategy in enumerate(strategies):
        out = {sel: render(*mixed_lights_scene(sel, strategy, seed + 10 * k, plates=strategy == "mis"))
               for sel, seed in (("ris", 1), ("all", 2))}
        m = {}
        for sel, r in out.items():
            m[sel] = block_means_var(r.image[..., :3].astype(float), r.variance.astype(float), 4)
        z = z_scores(*m["ris"], *m["all"])
        (ma, va), (mb, vb) = m["ris"], m["all"]
        se = np.sqrt(va.sum() + vb.sum()) / ma.size
        zm = (ma.mean() - mb.mean()) / se
        print(f"\nris vs all ({strategy}): max block |z| {np.abs(z).max():.2f} (limit {limit:.2f}); image mean "
              f"{ma.mean():.5f} vs {mb.mean():.5f}, z {zm:.2f}; detects {detectable(se / mb.mean(), level):.2%} "
              f"of the mean; variance ris / all {out['ris'].variance.mean() / out['all'].variance.mean():.2f}")
        assert np.abs(z).max() < limit, strategy
        assert abs(zm) < z_mean, strategy
        assert detectable(se / mb.mean(), level) < 0.015
