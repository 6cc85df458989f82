"""Cycles' per-kind bounce limits (Light Paths > Max Bounces: Diffuse,
Glossy, Transmission; engine/integrator/stages.py count_kind,
transparency.last_vertices): after more than that many bounces of a kind, the
next vertex only adds its emission, as after max_bounces.

The truth for diffuse bounces is a closed form: inside a closed enclosure
whose walls all emit Le and reflect diffusely with albedo rho, every wall
point sees walls in every direction, so the k-th bounce adds Le rho^k
exactly, and a path allowed K bounces sees Le (1 - rho^(K+2)) / (1 - rho)
(vertices 0..K sample the walls' emission, vertex K + 1 collects it).  For
glossy and transmission bounces, a scene of only that kind must render the
same with the kind's limit k as with max_bounces k (the kinds are Cycles'
closure labels: engine/integrator/visibility.ray_kind)."""
import numpy as np
import pytest

from ember_stats import family_z
from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
from engine.testscenes import box, look_at

LE, RHO = 1.0, 0.6
# (max_bounces, diffuse_bounces)
CASES = [(6, 0), (6, 1), (6, 3), (2, 1024)]


def enclosure(material):
    cam = Camera(look_at((0, 0, 0), (0, 1, 0.2)), lens=20.0, resolution=(24, 24), clip_start=0.01)
    return Scene([box((2.0, 2.0, 2.0))], [Instance(0, materials=[0])], [material], [], World((0, 0, 0)), cam)


def settings(samples=64, **kw):
    return RenderSettings(samples=samples, samples_per_pass=samples, seed=3, filter_type="BOX",
                          filter_width=1.0, **kw)


def test_diffuse_limit_against_the_closed_form():
    scene = enclosure(Material("wall", (Lobe("diffuse", (RHO, RHO, RHO)),), emission=(LE, LE, LE)))
    zc = family_z(__name__ + " enclosure", len(CASES))
    for max_bounces, diffuse in CASES:
        r = render(scene, settings(max_bounces=max_bounces, diffuse_bounces=diffuse))
        k = min(max_bounces, diffuse)
        expected = LE * (1 - RHO ** (k + 2)) / (1 - RHO)
        n = r.image[..., 0].size
        mean = float(r.image[..., 0].mean())
        se = float(np.sqrt(r.variance[..., 0].sum()) / n)
        z = (mean - expected) / se
        print(f"max {max_bounces}, diffuse {diffuse}: {mean:.5f} against {expected:.5f} (closed form), "
              f"z {z:+.2f} (limit {zc:.2f}); detects {zc * se / expected:.3%} with probability 1/2; "
              f"one bounce more or less is {RHO ** (k + 1) / expected:.1%}")
        assert abs(z) < zc, f"max {max_bounces}, diffuse {diffuse}: {mean} against {expected}"


@pytest.mark.parametrize("lobe, limit", [(Lobe("glossy", (0.7, 0.7, 0.7), roughness=0.3), "glossy_bounces"),
                                         (Lobe("glossy", (0.7, 0.7, 0.7), roughness=0.0), "glossy_bounces")])
def test_a_kind_limit_acts_as_max_bounces_in_a_scene_of_that_kind(lobe, limit):
    scene = enclosure(Material("wall", (lobe,), emission=(LE, LE, LE)))
    by_kind = render(scene, settings(16, max_bounces=8, **{limit: 2})).image
    by_total = render(scene, settings(16, max_bounces=2)).image
    more = render(scene, settings(16, max_bounces=3)).image
    np.testing.assert_allclose(by_kind, by_total, rtol=1e-9, atol=1e-12)
    assert more.mean() > by_total.mean() * 1.02   # the scene does show a third bounce


def test_transmission_bounces_end_paths_inside_glass():
    """A glass pane between the camera and an emitter: 0 transmission
    bounces stop the paths at the pane's first refraction (only reflections
    go on), so the emitter is not seen through it; 2 let it through."""
    from engine.testscenes import quad
    pane = box((4.0, 4.0, 0.1))
    lamp = quad([[-3, -3, -1], [3, -3, -1], [3, 3, -1], [-3, 3, -1]])
    cam = Camera(look_at((0, 0, 3), (0, 0, 0), up=(0, 1, 0)), lens=50.0, resolution=(8, 8))
    glass = Material("glass", (Lobe("glass", (1, 1, 1), ior=1.5, roughness=0.0),))
    lamp_mat = Material("lamp", (Lobe("diffuse", (0, 0, 0)),), emission=(1, 1, 1))
    scene = Scene([pane, lamp], [Instance(0, materials=[0]), Instance(1, materials=[1])], [glass, lamp_mat],
                  [], World((0, 0, 0)), cam)
    seen = render(scene, settings(8, max_bounces=8, transmission_bounces=2)).image[..., 0].mean()
    blocked = render(scene, settings(8, max_bounces=8, transmission_bounces=0)).image[..., 0].mean()
    # Through a pane: (1 - F)^2 = 0.92 at normal incidence; none at all with 0.
    assert 0.85 < seen < 0.97, seen
    assert blocked < 0.01, blocked


def test_filter_glossy_blurs_microfacet_lobes_only():
    """Cycles' bsdf_blur (Filter Glossy): microfacet alphas raised to the
    blur roughness, a mirror made a glossy lobe that rough, other lobes
    and rows untouched."""
    from engine import bsdf
    from engine.lobe_ids import DIFFUSE, GLASS, GLOSSY, MIRROR, NONE
    mats = bsdf.MaterialTable([Material("m", (Lobe("diffuse"), Lobe("glossy", roughness=0.0),
                                              Lobe("glossy", roughness=0.8), Lobe("glass", roughness=0.0)))])
    lobes = mats.gather(np.zeros(3, np.int64))
    assert list(lobes.kind[0]) == [DIFFUSE, MIRROR, GLOSSY, GLASS]
    before = lobes.alpha.copy()
    bsdf.blur(lobes, np.array([0, 2]), np.array([0.3, 0.1]))
    assert list(lobes.kind[0]) == [DIFFUSE, GLOSSY, GLOSSY, GLASS] and lobes.kind[1, 1] == MIRROR
    np.testing.assert_allclose(lobes.alpha[0], [before[0, 0], 0.3, 0.64, 0.3])
    np.testing.assert_allclose(lobes.alpha[2], [before[2, 0], 0.1, 0.64, 0.1])
    np.testing.assert_array_equal(lobes.alpha[1], before[1])
    assert NONE not in lobes.kind[0]
