"""Thin films in the lobes (engine/lobes/ggx.py, glass.py, bsdf.py): the
lobes' Fresnel under a film is engine/thinfilm.py's (tested there against
Cycles' transcription), the no-film limits are the plain Fresnel, back
faces of glass read the film IOR divided by the glass IOR, the layer and
closure albedos and the lobe choice read the film at the view angle as
Cycles, smooth filmed glass chooses reflection with its probability and
keeps the energy, and hostile film inputs stay finite.  The registry cases
(chi-square, energy) and the compiled loops' agreement are in
test_lobe_registry.py and test_bsdf_loops.py."""
import math

import numpy as np
import pytest

import ember_stats
from engine import bsdf, thinfilm
from engine import microfacet as mf
from engine import scene as S
from engine.lobes import ggx, glass

COS = np.linspace(0.05, 1.0, 20)


def lobes_of(n=len(COS), back=False, **lobe):
    kind = lobe.pop("kind", "glossy")
    table = bsdf.MaterialTable([S.Material("m", (S.Lobe(kind, **lobe),))])
    lob = table.gather(np.zeros(n, np.int64))
    lob.back = np.full(n, back)
    return lob


METAL = dict(color=(1, 1, 1), roughness=0.3, fresnel="f82", f0=(0.9, 0.6, 0.3), edge_tint=(0.9, 0.9, 0.5),
             thin_film_thickness=420.0, thin_film_ior=1.5)
SPECULAR = dict(color=(1, 1, 1), roughness=0.3, fresnel="dielectric", ior=1.5, f0=(0.06, 0.04, 0.03),
                thin_film_thickness=600.0, thin_film_ior=1.4)


def test_glossy_fresnel_is_the_films():
    rows = np.arange(len(COS))
    lob = lobes_of(**METAL)
    f0 = np.array(METAL["f0"])
    b = mf.f82_b(f0, np.array(METAL["edge_tint"]))
    want = thinfilm.f82_conductor(COS, np.tile(f0, (len(COS), 1)), np.tile(b, (len(COS), 1)), 420.0, 1.5,
                                  dtype=np.float64)
    np.testing.assert_allclose(ggx.fresnel(lob, rows, 0, COS), want, rtol=0, atol=1e-12)
    lob = lobes_of(**SPECULAR)
    want = thinfilm.principled_dielectric(COS, 1.5, np.tile(SPECULAR["f0"], (len(COS), 1)), 600.0, 1.4,
                                          dtype=np.float64)
    np.testing.assert_allclose(ggx.fresnel(lob, rows, 0, COS), want, rtol=0, atol=1e-12)
    # the film colours the reflection: channels differ by more than the plain Fresnel's f0 tint
    assert np.ptp(want, axis=1).max() > 0.05


@pytest.mark.parametrize("thickness,film_ior", [(0.05, 1.5), (300.0, 1.0)])
def test_no_film_limits_are_the_plain_fresnel(thickness, film_ior):
    """At most 0.1 nm, or a film of the ambient IOR: the plain Fresnel."""
    rows = np.arange(len(COS))
    plain = ggx.fresnel(lobes_of(**dict(SPECULAR, thin_film_thickness=0.0, f0=None)), rows, 0, COS)
    filmed = ggx.fresnel(lobes_of(**dict(SPECULAR, thin_film_thickness=thickness, thin_film_ior=film_ior,
                                         f0=None)), rows, 0, COS)
    np.testing.assert_allclose(filmed, plain, rtol=0, atol=1e-6 if thickness > 1 else 1e-15)


def test_glass_back_face_divides_the_film_ior():
    """Cycles' adjust_thin_film_ior_at_backface: from inside, the film over
    eta = 1 / ior with the film IOR / ior; the front face keeps both."""
    rows = np.arange(len(COS))
    lob = lobes_of(back=True, kind="glass", color=(1, 1, 1), roughness=0.2, ior=1.33,
                   thin_film_thickness=500.0, thin_film_ior=1.45)
    eta = glass.eta_of(lob, 0)
    np.testing.assert_allclose(eta, 1.0 / 1.33)
    refl, trans, p_refl, cos_t = glass.dielectric(lob, rows, 0, COS, eta)
    f0 = np.tile(lob.f0[0, 0], (len(COS), 1))
    want = thinfilm.principled_dielectric(COS, 1.0 / 1.33, f0, 500.0, 1.45 / 1.33, dtype=np.float64)
    np.testing.assert_allclose(refl, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(trans, np.where((cos_t > 0)[:, None], 1.0 - want, 0.0), rtol=0, atol=1e-12)
    assert np.all(refl[cos_t <= 0] == 1.0)           # total internal reflection stays total
    front = lobes_of(kind="glass", color=(1, 1, 1), roughness=0.2, ior=1.33, thin_film_thickness=500.0,
                     thin_film_ior=1.45)
    refl_f = glass.dielectric(front, rows, 0, COS, glass.eta_of(front, 0))[0]
    np.testing.assert_allclose(refl_f, thinfilm.principled_dielectric(COS, 1.33, f0, 500.0, 1.45,
                                                                      dtype=np.float64), atol=1e-12)


def test_layer_closure_albedo_and_choice_read_the_film_at_the_view_angle():
    """The specular layer dims the diffuse base by 1 - max(F_film(mu)) (no
    table under a film, Cycles' bsdf_albedo), its Glossy Color is F_film(mu),
    its selection guess the film's luminance."""
    mu = np.array([0.9, 0.5, 0.2])
    wo = np.stack([np.sqrt(1 - mu * mu), np.zeros(3), mu], axis=1)
    table = bsdf.MaterialTable([S.Material("m", (S.Lobe("glossy", **dict(SPECULAR, covers=1)),
                                                 S.Lobe("diffuse", (0.5, 0.5, 0.5))))])
    lob = table.gather(np.zeros(3, np.int64))
    film = thinfilm.principled_dielectric(mu, 1.5, np.tile(SPECULAR["f0"], (3, 1)), 600.0, 1.4, dtype=np.float64)
    w = bsdf.weights(lob, wo)
    np.testing.assert_allclose(w[:, 1], 0.5 * (1.0 - film.max(axis=1))[:, None] * np.ones(3), rtol=1e-9)
    refl, _ = bsdf.closure_albedos(lob, wo)
    np.testing.assert_allclose(refl[:, 0], film, rtol=1e-9)
    guess = ggx.albedo_guess_glossy(lob, 0, mu)
    np.testing.assert_allclose(guess, ggx.luminance(film), rtol=1e-12)


def test_smooth_filmed_glass_keeps_energy():
    """A smooth glass sphere's film: each branch's weight is exact (F /
    P(reflect), (1 - F) / P(refract)), reflection is chosen with its
    probability (a binomial z-test, power printed), so the mean weight is
    F + (1 - F) = 1 in every channel."""
    n = 200_000
    cos = 0.6
    wo = np.tile([math.sqrt(1 - cos * cos), 0.0, cos], (n, 1))
    lob = lobes_of(n, kind="glass", color=(1, 1, 1), roughness=0.0, ior=1.33, thin_film_thickness=500.0,
                   thin_film_ior=1.45)
    rng = np.random.default_rng(11)
    wi, weight, pdf, delta = bsdf.sample(lob, wo, rng.random(n), rng.random(n), rng.random(n))
    assert delta.all() and np.isfinite(weight).all()
    refl, trans, p_refl, _ = glass.dielectric(lob, np.arange(1), 0, np.array([cos]), glass.eta_of(lob, 0)[:1])
    p = float(p_refl[0])
    up = wi[:, 2] > 0
    np.testing.assert_allclose(weight[up], np.tile(refl[0] / p, (up.sum(), 1)), rtol=1e-9)
    np.testing.assert_allclose(weight[~up], np.tile(trans[0] / (1 - p), ((~up).sum(), 1)), rtol=1e-9)
    assert np.ptp(refl[0]) > 0.01                      # the film colours the branches
    level = ember_stats.family_level(__name__)
    z_max = ember_stats.z_threshold(level)
    se = math.sqrt(p * (1 - p) / n)
    z = (up.mean() - p) / se
    print(f"P(reflect) {up.mean():.5f} vs {p:.5f}: z = {z:.2f} (|z| < {z_max:.2f}); detects a difference of "
          f"{ember_stats.detectable(se, level):.5f}")
    assert abs(z) < z_max
    np.testing.assert_allclose(refl[0] + trans[0], 1.0, rtol=1e-12)


@pytest.mark.parametrize("thickness,film_ior", [(float("nan"), 1.5), (-300.0, 1.5), (1e30, 0.0), (400.0, float("nan")),
                                                (1e300, 1e300), (400.0, 0.0)])
@pytest.mark.parametrize("kind", ["glossy-f82", "glossy-dielectric", "glass", "mirror"])
def test_hostile_films_are_finite(kind, thickness, film_ior):
    name, _, code = kind.partition("-")
    lobe = dict(color=(1, 1, 1), roughness=0.0 if name == "mirror" else 0.3, thin_film_thickness=thickness,
                thin_film_ior=film_ior, ior=1.5)
    if name != "glass":
        lobe["fresnel"] = code or "f82"
    n = 2000
    rng = np.random.default_rng(5)
    lob = lobes_of(n, back=False, kind=name, **lobe)
    lob.back = rng.random(n) < 0.5
    assert np.isfinite(lob.thin_film_thickness).all() and np.isfinite(lob.thin_film_ior).all()
    assert lob.thin_film_ior.min() >= 1e-5 and lob.thin_film_thickness.min() >= 0.0
    wo = rng.normal(size=(n, 3))
    wo[:, 2] = np.abs(wo[:, 2])
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    f, pdf = bsdf.eval_pdf(lob, wo, wi)
    out = bsdf.sample(lob, wo, rng.random(n), rng.random(n), rng.random(n))
    albedos = bsdf.closure_albedos(lob, wo)
    for a in (f, pdf, *out, *albedos):
        assert np.isfinite(a).all()
    assert (out[1] >= 0).all() and (albedos[0] >= 0).all()


def test_textured_film_equals_constant_film():
    """A thickness and film IOR given as texture expressions (a linked
    socket) gather per ray to the constants' values, and render the same
    Fresnel."""
    n = len(COS)
    textured = bsdf.MaterialTable([S.Material("t", (S.Lobe("glossy", **dict(
        SPECULAR, thin_film_thickness=S.Math("ADD", 250.0, 350.0),
        thin_film_ior=S.Math("MULTIPLY", 0.7, 2.0))),))]).gather(np.zeros(n, np.int64), np.zeros((n, 2)))
    constant = lobes_of(**SPECULAR)
    np.testing.assert_allclose(textured.thin_film_thickness, 600.0)
    np.testing.assert_allclose(textured.thin_film_ior, 1.4)
    rows = np.arange(n)
    np.testing.assert_allclose(ggx.fresnel(textured, rows, 0, COS), ggx.fresnel(constant, rows, 0, COS), atol=1e-12)
