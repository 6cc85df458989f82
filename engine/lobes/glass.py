"""GGX dielectrics (Walter et al. 2007, as Cycles): the Glass BSDF and the
Principled transmission (reflection and refraction), the Refraction BSDF
(refraction only); smooth ones (alpha <= MIN_ALPHA) are delta lobes."""
import numpy as np

from .. import microfacet as mf
from ..microfacet import COS_EPS, ggx_d, ggx_lambda, ggx_sample_vndf
from .ggx import film_fresnel, ggx_reflect_rows, has_film
from .registry import (DELTA_WHEN_SMOOTH, F_DIELECTRIC, MIN_ALPHA, NONE, REFLECTION, TRANSMISSION, LobeDef, register)

GLASS = 3
REFRACTION = 4


def mean3(x):
    return (x[:, 0] + x[:, 1] + x[:, 2]) / 3.0


def eta_of(lobes, k):
    """Relative IOR seen from the side of wo: Cycles inverts it on back faces
    for the lobes that refract (a coat or specular layer keeps its IOR)."""
    ior = np.maximum(lobes.ior[:, k], 1e-5)
    refracts = (lobes.kind[:, k] == GLASS) | (lobes.kind[:, k] == REFRACTION)
    return np.where(lobes.back & refracts, 1.0 / ior, ior)


def film_ior_of(lobes, rows, k):
    """The film IOR a glass lobe's film is evaluated with: on back faces
    divided by the glass IOR (Cycles' adjust_thin_film_ior_at_backface: the
    stack glass | film | air read from outside as air | film / ior | 1 / ior)."""
    ior = np.maximum(lobes.ior[rows, k], 1e-5)
    film = lobes.thin_film_ior[rows, k]
    return np.where(lobes.back[rows], film / ior, film)


def dielectric(lobes, rows, k, cos, eta):
    """Glass: reflectance (n, 3), transmittance (n, 3), probability of
    reflecting, |cos| of the refracted angle (0 under total internal
    reflection).  Principled/Glass BSDF: F = mix(f0, 1, s) with s the real
    Fresnel remapped (under a thin film, the film's reflectance scaled by
    f0 / F0(eta) per channel); Refraction BSDF: no reflection, T = 1 unless
    TIR.  ``eta`` is per row of ``rows``."""
    s, cos_t = mf.schlick_s(cos, eta)
    f0 = lobes.f0[rows, k]
    refl = f0 + (1.0 - f0) * s[:, None]
    rows = np.arange(len(lobes))[rows]
    film = np.flatnonzero(has_film(lobes, rows, k) & (lobes.kind[rows, k] == GLASS))
    if len(film):
        # Under a film that reflects all (its own total reflection) the
        # transmittance 1 - F is 0 whatever cos_t says, as in Cycles.
        refl[film] = film_fresnel(F_DIELECTRIC, lobes, rows[film], k, cos[film], eta[film],
                                  film_ior_of(lobes, rows[film], k))
    refraction = lobes.kind[rows, k] == REFRACTION
    refl = np.where(refraction[:, None], 0.0, refl)
    trans = np.where(refraction[:, None], 1.0, 1.0 - refl) * lobes.transmission_tint[rows, k]
    trans = np.where((cos_t > 0)[:, None], trans, 0.0)
    r, t = mean3(refl), mean3(trans)
    p_refl = np.where(r + t > 0, r / np.where(r + t > 0, r + t, 1.0), 1.0)
    return refl, trans, p_refl, cos_t


def eval_glass_f(lobes, rows, k, wo, wi):
    """Rough dielectric: f (without the weight) and pdf, reflection above,
    refraction below the surface; pdf includes the reflect/refract choice."""
    alpha = lobes.alpha[rows, k]
    eta = eta_of(lobes, k)[rows]
    n = len(alpha)
    f = np.zeros((n, 3))
    pdf = np.zeros(n)
    up = wi[:, 2] > COS_EPS
    down = wi[:, 2] < -COS_EPS
    co = np.maximum(wo[:, 2], COS_EPS)
    ok_o = wo[:, 2] > COS_EPS
    rows = np.arange(len(lobes))[rows]
    if up.any():
        r = np.nonzero(up & ok_o)[0]
        spec, p, h = ggx_reflect_rows(wo[r], wi[r], alpha[r])
        refl, _, p_refl, _ = dielectric(lobes, rows[r], k, mf.row_dot(wo[r], h), eta[r])
        f[r] = refl * spec[:, None]
        pdf[r] = p * p_refl
    if down.any():
        t = np.nonzero(down & ok_o)[0]
        h, length = mf.refraction_half(wo[t], wi[t], eta[t])
        # Every pair is scored, also those no microfacet refracts between
        # (unjoined below): Cycles' bsdf_microfacet_eval does ("TODO: check
        # if the refraction configuration is valid"), so its light sampling
        # brings light from outside the refraction cone; its Fresnel reads |cos|.
        c_o = np.abs(mf.row_dot(wo[t], h))
        c_i = mf.row_dot(wi[t], h)
        valid = length > 0
        _, trans, p_refl, _ = dielectric(lobes, rows[t], k, c_o, eta[t])
        a = alpha[t]
        lo, li = ggx_lambda(wo[t, 2], a), ggx_lambda(wi[t, 2], a)
        common = (ggx_d(h[:, 2], a) / co[t] * (eta[t] / np.where(length > 0, length, 1.0)) ** 2
                  * np.abs(c_o * c_i))
        f[t] = np.where(valid[:, None], trans * (common / ((1.0 + lo + li) * -wi[t, 2]))[:, None], 0.0)
        pdf[t] = np.where(valid, common * (1.0 - p_refl) / (1.0 + lo), 0.0)
    return f, pdf


def unjoined(lobes, k, wo, wi):
    """(N,) bool: refraction pairs wo -> wi no microfacet refracts between
    (pbrt's check: h faces both, wo above and wi below it).  eval scores
    them as Cycles does, the sampler never draws them: the registry tests
    leave them out of the sampler's density and the albedo."""
    eta = eta_of(lobes, k)
    h, length = mf.refraction_half(wo, wi, eta)
    joined = (h[:, 2] > 0) & (mf.row_dot(wo, h) > 0) & (mf.row_dot(wi, h) < 0) & (length > 0)
    return (wi[:, 2] < 0) & rough(lobes, k) & ~joined


def eval_glass(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_glass_f(lobes, rows, k, wo, wi)
    return w * f, sel * pdf


def rough(lobes, k):
    """Rows whose slot k is a rough dielectric (the smooth ones are delta)."""
    return lobes.alpha[:, k] > MIN_ALPHA


def sample_glass_dir(lobes, rows, k, wo, u_choice, u1, u2, singular):
    """Reflect or refract through a visible microfacet (the normal itself
    when singular); returns wi, whether it refracted, and p_refl."""
    alpha = lobes.alpha[rows, k]
    eta = eta_of(lobes, k)[rows]
    h = np.zeros((len(rows), 3))
    h[:, 2] = 1.0
    is_rough = ~singular
    if is_rough.any():
        h[is_rough] = ggx_sample_vndf(wo[is_rough], alpha[is_rough], u1[is_rough], u2[is_rough])
    cos = mf.row_dot(wo, h)
    _, _, p_refl, cos_t = dielectric(lobes, rows, k, cos, eta)
    refract = u_choice >= p_refl
    wi = mf.reflect(wo, h)
    if refract.any():
        wi[refract] = mf.refract(wo[refract], h[refract], cos_t[refract], eta[refract])
    return wi, refract, p_refl


def sample_glass(lobes, rows, s):
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        singular = lobes.alpha[r, k] <= MIN_ALPHA
        s.wi[r], refract, p_refl = sample_glass_dir(lobes, r, k, s.wo[r], s.u_sub[r], s.u1[r], s.u2[r], singular)
        # A refraction that ends above the surface (or a reflection below)
        # is absorbed, as Cycles does: eval would read it as the other branch.
        s.kind[r[refract != (s.wi[r, 2] < 0)]] = NONE
        d = r[singular]
        if len(d):
            refl, trans, _, _ = dielectric(lobes, d, k, s.wo[d, 2], eta_of(lobes, k)[d])
            rs = refract[singular]
            p = np.where(rs, 1.0 - p_refl[singular], p_refl[singular])
            col = np.where(rs[:, None], trans, refl)
            s.weight[d] = s.w[d, k] * col / np.maximum(p * s.p_lobe[d], 1e-300)[:, None]
            s.delta[d] = True
            s.pdf[d] = p * s.p_lobe[d]


_PARAMS = ("roughness", "ior", "f0", "transmission_tint", "multiscatter", "thin_film_thickness", "thin_film_ior")
register(LobeDef(GLASS, "glass", "glossy", REFLECTION | TRANSMISSION | DELTA_WHEN_SMOOTH, sample_glass,
                 eval_glass, "both", evaluates=rough, params=_PARAMS, reciprocal=False, unjoined=unjoined,
                 has_transmission=True,
                 doc="GGX dielectric: reflection and refraction (Glass BSDF, Principled transmission); its "
                     "refraction is told by direction in the passes",
                 cases=[dict(color=(1, 1, 1), roughness=0.4, ior=1.5),
                        dict(color=(1, 1, 1), roughness=0.2, ior=1.33, transmission_tint=(0.9, 1.0, 0.8)),
                        dict(color=(1, 1, 1), roughness=0.3, ior=1.5, multiscatter=True),
                        dict(color=(1, 1, 1), roughness=0.0, ior=1.5),
                        # a soap bubble's film over water (smooth: tests/engine/test_thinfilm_lobes.py,
                        # its sample weights vary by channel, so its albedo is 1 only in the mean)
                        dict(color=(1, 1, 1), roughness=0.2, ior=1.33, thin_film_thickness=500.0,
                             thin_film_ior=1.4)]))
register(LobeDef(REFRACTION, "refraction", "transmission", TRANSMISSION | DELTA_WHEN_SMOOTH, sample_glass,
                 eval_glass, "both", evaluates=rough, params=_PARAMS, reciprocal=False, unjoined=unjoined,
                 has_transmission=True,
                 doc="Refraction BSDF: GGX refraction only",
                 cases=[dict(color=(0.9, 0.9, 1.0), roughness=0.3, ior=1.4),
                        dict(color=(1, 1, 1), roughness=0.0, ior=1.4)]))
