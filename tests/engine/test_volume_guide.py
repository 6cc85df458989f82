"""Volume scattering probability guiding of camera rays (Cycles 5.0's VSPG,
engine/integrator/volume_guide.py).

* The guided free flight with the default probability 1 - T(t_end) is the
  compiled flight's, and with any probabilities its scattering and passing
  weights keep their expectations (sigma_s integral_0^t_end T and T(t_end)).
* The guide's filter is Cycles' 11-tap Gaussian, its probability Cycles'
  formula.
* A spot in fog and a sun over a fog slab: guided and unguided renders
  agree block by block and over the whole image (one family), and over the
  slab, whose light comes mostly through the fog, guiding cuts the variance
  (ratio and standard error printed and asserted).
"""
import numpy as np
import pytest

from ember_stats import family_z, guided_pair_z as pair_z
from engine.integrator import volume_guide
from engine.media.flight import _homogeneous_flight
from engine.render import render
from analytic import ortho_camera
from engine.scene import (Camera, Instance, Lobe, Material, RenderSettings, Scene, SpotLight, SunLight, Volume,
                          World)
from engine.testscenes import box, look_at, quad

PASS = (Lobe("transparent", (1.0, 1.0, 1.0)),)


def flight_inputs(rng, n):
    sa = rng.uniform(0.0, 0.6, (n, 3))
    ss = rng.uniform(0.05, 1.5, (n, 3))
    em = np.zeros((n, 3))
    beta = rng.uniform(0.2, 1.0, (n, 3))
    t_end = rng.uniform(0.1, 4.0, n)
    return sa, ss, em, beta, t_end


def guided(sa, ss, em, beta, t_end, q, uc, ud):
    flight = _homogeneous_flight(sa, ss, em, np.zeros(len(sa)), beta, t_end, np.ones(len(sa), bool), uc, ud)
    volume_guide.guided_flight(flight, np.arange(len(sa)), q, ss, uc, ud)
    return flight


def test_default_probability_is_the_plain_free_flight():
    """q = 1 - T(t_end): the same scattering choices, distances and weights as the compiled flight."""
    rng = np.random.default_rng(5)
    n = 4000
    sa, ss, em, beta, t_end = flight_inputs(rng, n)
    uc, ud = rng.random(n), rng.random(n)
    plain = _homogeneous_flight(sa, ss, em, np.zeros(n), beta, t_end, np.ones(n, bool), uc, ud)
    q = 1.0 - np.exp(-(sa + ss) * t_end[:, None])
    got = guided(sa, ss, em, beta, t_end, q, uc, ud)
    # A choice may flip where u sits within rounding of 1 - T.
    same = got.scatter == plain.scatter
    assert same.mean() > 0.999
    np.testing.assert_allclose(got.t[same & got.scatter], plain.t[same & plain.scatter], rtol=1e-9)
    np.testing.assert_allclose(got.weight[same], plain.weight[same], rtol=1e-9)


@pytest.mark.parametrize("q_kind", ["low", "high", "mixed"])
def test_guided_weights_keep_their_expectations(q_kind):
    """Per channel, E[weight; scattered] = sigma_s (1 - T) / sigma_t and
    E[weight; passed] = T(t_end), whatever q (z-tests, power printed)."""
    rng = np.random.default_rng({"low": 1, "high": 2, "mixed": 3}[q_kind])
    n = 200_000
    row = flight_inputs(rng, 1)
    sa, ss, em, beta, t_end = (np.repeat(a, n, axis=0) for a in row)
    q = {"low": np.full((n, 3), 0.05), "high": np.full((n, 3), 0.97),
         "mixed": np.tile([0.2, 0.6, 1.0], (n, 1))}[q_kind]
    f = guided(sa, ss, em, beta, t_end, q, rng.random(n), rng.random(n))
    st = sa[0] + ss[0]
    want = {"scatter": ss[0] * (1.0 - np.exp(-st * t_end[0])) / st, "pass": np.exp(-st * t_end[0])}
    zc = family_z(__name__ + ".expectations." + q_kind, 6)
    for name, mask in (("scatter", f.scatter), ("pass", ~f.scatter)):
        x = np.where(mask[:, None], f.weight, 0.0)
        se = x.std(axis=0, ddof=1) / np.sqrt(n)
        z = (x.mean(axis=0) - want[name]) / se
        print(f"{q_kind} {name}: mean {x.mean(axis=0)} want {want[name]}, |z| {np.abs(z).max():.2f} "
              f"(limit {zc:.2f}), detects {(zc * se / want[name]).max():.2%}")
        assert np.abs(z).max() < zc


def test_filter_and_probability_are_cycles():
    """Cycles' gaussian_params, edges left out unrenormalized; q as
    volume_scatter_probability_homogeneous (1/2 where nothing is known)."""
    np.testing.assert_allclose(volume_guide.WEIGHTS[:6], [0.0012273699895602, 0.0084674212370284,
                                                          0.0379843612914121, 0.1108921888487800,
                                                          0.2108379677336155, 0.2611813817992076], rtol=1e-12)
    assert volume_guide.WEIGHTS.sum() == pytest.approx(1.0, abs=1e-9)
    one = np.zeros((11, 11, 3))
    one[5, 0] = 1.0
    out = volume_guide.blur(one)
    assert out[5, 0, 0] == pytest.approx(volume_guide.WEIGHTS[5] ** 2)
    assert out[..., 0].sum() == pytest.approx(volume_guide.WEIGHTS[5:].sum(), rel=1e-12)
    att = np.array([[0.4, 0.4, 0.0], [0.4, 0.4, 0.4]])
    q = volume_guide.scatter_probability(att, np.array([[0.0] * 3, [1.0] * 3]), np.array([[0.0] * 3, [3.0] * 3]),
                                         np.array([np.inf, -np.log(0.2)]))
    np.testing.assert_allclose(q[0], 0.25 * att[0] + 0.75 * np.array([0.5, 0.5, 0.0]))
    np.testing.assert_allclose(q[1], 0.25 * 0.4 + 0.75 * min(0.25 * 0.4 / 0.8, 1.0))


def spot_in_fog(size=(20, 15)):
    """A spot shining down through a fog box onto a grey floor, the camera
    outside the fog (tests/engine/test_media_equiangular.py's scene)."""
    fog = Material("fog", PASS, volume=Volume(scattering=(0.5, 0.5, 0.5), absorption=(0.05, 0.08, 0.12),
                                              anisotropy=0.3))
    floor = Material("floor", (Lobe("diffuse", (0.6, 0.6, 0.6)),))
    spot = SpotLight((0.0, 0.0, 1.2), (60.0, 60.0, 60.0), radius=0.1, direction=(0.0, 0.0, -1.0),
                     spot_size=1.1, spot_blend=0.2)
    cam = Camera(look_at((0, -6, 0.3), (0, 0, 0.1)), lens=40, resolution=size)
    meshes = [box((3.0, 3.0, 3.0)), quad([[-1.4, -1.4, -1.2], [1.4, -1.4, -1.2], [1.4, 1.4, -1.2], [-1.4, 1.4, -1.2]])]
    instances = [Instance(0, materials=[0], name="fog box"), Instance(1, materials=[1], name="floor")]
    return Scene(meshes, instances, [fog, floor], [spot], World((0.0, 0.0, 0.0)), cam)


def jackknife_ratio(a, b, groups):
    """sum(a) / sum(b) and its jackknife standard error over ``groups``
    (pixel blocks as independent units)."""
    ids = np.unique(groups)
    sa = np.array([a[groups == g].sum() for g in ids])
    sb = np.array([b[groups == g].sum() for g in ids])
    ratio = sa.sum() / sb.sum()
    loo = (sa.sum() - sa) / (sb.sum() - sb)
    k = len(ids)
    return ratio, float(np.sqrt((k - 1) / k * ((loo - loo.mean()) ** 2).sum()))


def sun_slab(size=(16, 16)):
    """An orthographic camera looking down through an absorbing, thinly
    scattering slab at a white floor, a sun above: most of the light comes
    through the fog (the guide's L_t is 7x its L_s)."""
    fog = Material("fog", PASS, volume=Volume(scattering=(0.3, 0.3, 0.3), absorption=(0.9, 1.0, 1.1)))
    floor = Material("floor", (Lobe("diffuse", (0.8, 0.8, 0.8)),))
    sun = SunLight((0.3, 0.2, -1.0), (3.0, 3.0, 3.0))
    meshes = [box((3.0, 3.0, 0.6)), quad([[-5, -5, -1], [5, -5, -1], [5, 5, -1], [-5, 5, -1]])]
    instances = [Instance(0, np.eye(4), [0], "slab"), Instance(1, np.eye(4), [1], "floor")]
    return Scene(meshes, instances, [fog, floor], [sun], World((0.0, 0.0, 0.0)), ortho_camera((0, 0, 3), (0, 0, 0),
                                                                                                size, 1.0))


def guided_pair(scene, seed, **settings):
    """{guided: render} of a scene, 16 samples a pass (the guide is rebuilt between passes)."""
    out = {}
    for guide in (False, True):
        out[guide] = render(scene, RenderSettings(samples_per_pass=16, seed=seed + guide, volume_guiding=guide,
                                                  **settings))
        assert np.isfinite(out[guide].image).all()
    assert out[True].film.guide is not None and out[False].film.guide is None
    return out


@pytest.fixture(scope="module")
def slab():
    return guided_pair(sun_slab(), 71, samples=256, max_bounces=2)


def test_guided_and_unguided_agree(slab):
    """Camera rays guided by the passes before give the unguided image,
    block by block and over the whole image (one family): the spot in fog
    (equiangular and distance direct-light points, the spot's cone, a
    coloured extinction: per-channel q) and the sun over a slab."""
    spot = guided_pair(spot_in_fog(), 61, samples=256, max_bounces=4)
    tests = {name: pair_z(r, 3 if name == "spot" else 2) for name, r in (("spot", spot), ("slab", slab))}
    zc = family_z(__name__ + ".agree", sum(len(t[0]) + 3 for t in tests.values()))
    for name, (z, zm, block_rel, image_rel) in tests.items():
        print(f"{name}: guided vs unguided, {len(z)} block-channels, max |z| {z.max():.2f} (limit {zc:.2f}), "
              f"median block detects {zc * block_rel:.1%}; image |z| {zm.max():.2f}, detects {zc * image_rel:.2%}")
        assert len(z) >= 20
        assert z.max() < zc and zm.max() < zc


def test_guiding_cuts_the_variance(slab):
    """Over the slab, where 7/8 of the light comes through the fog, the
    guide lowers the camera rays' scattering probability: the total
    variance falls to 0.293 +- 0.001 of the unguided (jackknife over 4x4
    pixel blocks; measured 2026-12-07), i.e. 2x fewer samples for the
    same noise after the time the guided paths' floor bounces add."""
    g = slab[True].film.guide
    assert g.transmit.sum() > 5.0 * g.scatter.sum() > 0
    h, w = slab[True].image.shape[:2]
    groups = (np.arange(h)[:, None] // 4 * 100 + np.arange(w)[None, :] // 4).ravel()
    var = {k: r.variance[..., :3].astype(np.float64).sum(axis=2).ravel() for k, r in slab.items()}
    ratio, ratio_se = jackknife_ratio(var[True], var[False], groups)
    print(f"variance guided / unguided {ratio:.3f} +- {ratio_se:.4f}")
    assert ratio + 4.0 * ratio_se < 0.45, (ratio, ratio_se)
