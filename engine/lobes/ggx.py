"""GGX reflection (Glossy BSDF, Principled metal / specular / coat) and the
perfect mirror a glossy lobe becomes below MIN_ALPHA; their Fresnel modes,
with Cycles' thin-film iridescence over the 'dielectric' and 'f82' ones
(microfacet_fresnel's GENERALIZED_SCHLICK and F82_TINT film branches)."""
import numpy as np

from .. import microfacet as mf
from .. import thinfilm
from ..microfacet import ggx_reflect, ggx_sample_vndf
from .registry import (DELTA, F_CONDUCTOR, F_DIELECTRIC, F_F82, F_NONE, F_SCHLICK, FILM_CUTOFF, NONE, REFLECTION, LobeDef,
                       register)

MIRROR = 1
GLOSSY = 2


def luminance(rgb):
    """Rec.709 luminance, Blender's default scene-linear space."""
    return 0.2126 * rgb[:, 0] + 0.7152 * rgb[:, 1] + 0.0722 * rgb[:, 2]


def schlick(f0, cos):
    c = np.clip(1.0 - cos, 0.0, 1.0)
    return f0 + (1.0 - f0) * mf.pow5(c)[:, None]


def fresnel(lobes, rows, k, cos):
    """(n, 3) reflectance of a glossy or mirror lobe at cos(wo, h)."""
    code = lobes.fresnel[rows, k]
    if len(code) and code.min() == code.max():
        return fresnel_of(int(code[0]), lobes, rows, k, cos)   # one kind: no masked copies
    rows = np.arange(len(lobes))[rows]
    out = np.ones((len(code), 3))
    for kind in (F_SCHLICK, F_F82, F_DIELECTRIC, F_CONDUCTOR):
        m = np.flatnonzero(code == kind)
        if len(m):
            out[m] = fresnel_of(kind, lobes, rows[m], k, cos[m])
    return out


def fresnel_of(code, lobes, rows, k, cos):
    """``fresnel`` for lobes that all have Fresnel mode ``code``."""
    if code == F_SCHLICK:
        return schlick(lobes.color[rows, k], cos)
    if code == F_F82:
        f0 = lobes.f0[rows, k]
        out = mf.f82(cos, f0, mf.f82_b(f0, lobes.edge_tint[rows, k]))
    elif code == F_DIELECTRIC:
        f0 = lobes.f0[rows, k]
        s, _ = mf.schlick_s(cos, np.maximum(lobes.ior[rows, k], 1e-5))
        out = f0 + (1.0 - f0) * s[:, None]
    elif code == F_CONDUCTOR:   # n in f0, k in edge_tint
        out = mf.conductor(cos, lobes.f0[rows, k], lobes.edge_tint[rows, k])
    else:
        return np.ones((len(cos), 3))
    rows = np.arange(len(lobes))[rows]
    m = np.flatnonzero(has_film(lobes, rows, k))
    if len(m):
        out[m] = film_fresnel(code, lobes, rows[m], k, np.asarray(cos)[m])
    return out


def has_film(lobes, rows, k):
    """Which of ``rows`` have a thin film on slot k (Cycles: thickness > 0.1 nm)."""
    return lobes.thin_film_thickness[rows, k] > FILM_CUTOFF


def film_fresnel(code, lobes, rows, k, cos, eta=None, film_ior=None):
    """(n, 3) reflectance of a thin film over the lobe's Fresnel at cos
    (F82: the film over Gulbrandsen's n, k of F0 and the value at 82
    degrees; conductor: the film over its own n, k, exact Fresnel; dielectric: the film over the IOR ``eta`` (default the lobe's),
    each channel scaled towards f0 / F0(eta)), in float64."""
    thickness = lobes.thin_film_thickness[rows, k]
    if film_ior is None:
        film_ior = lobes.thin_film_ior[rows, k]
    f0 = np.clip(lobes.f0[rows, k], 0.0, 1.0)
    cos = np.clip(cos, -1.0, 1.0)
    with np.errstate(all="ignore"):
        if code == F_CONDUCTOR:
            out = thinfilm.conductor(cos, lobes.f0[rows, k], lobes.edge_tint[rows, k], thickness, film_ior,
                                     dtype=np.float64)
        elif code == F_F82:
            b = mf.f82_b(f0, lobes.edge_tint[rows, k])
            out = thinfilm.f82_conductor(cos, f0, b, thickness, film_ior, dtype=np.float64)
        else:
            ior = np.maximum(lobes.ior[rows, k], 1e-5) if eta is None else eta
            out = thinfilm.principled_dielectric(cos, ior, f0, thickness, film_ior, dtype=np.float64)
    return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)


def ggx_reflect_rows(wo, wi, alpha):
    """D G2 / (4 cos_o cos_i), the VNDF pdf of wi, and the half vector."""
    spec, pdf, hx, hy, hz = ggx_reflect(wo[:, 0], wo[:, 1], wo[:, 2], wi[:, 0], wi[:, 1], wi[:, 2], alpha)
    return spec, pdf, np.stack([hx, hy, hz], axis=1)


def ggx_pdf(wo, wi, alpha):
    """Solid-angle pdf of wi under VNDF sampling of the reflection."""
    _, pdf, h = ggx_reflect_rows(wo, wi, alpha)
    return pdf, h


def eval_glossy_f(lobes, rows, k, wo, wi):
    """f (without the weight) and pdf of GGX reflection."""
    spec, pdf, h = ggx_reflect_rows(wo, wi, lobes.alpha[rows, k])
    f = fresnel(lobes, rows, k, mf.row_dot(wo, h)) * spec[:, None]
    return f, pdf


def eval_glossy(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_glossy_f(lobes, rows, k, wo, wi)
    return w * f, sel * pdf


def sample_glossy(lobes, rows, s):
    h = ggx_sample_vndf(s.wo[rows], lobes.alpha[rows, s.chosen[rows]], s.u1[rows], s.u2[rows])
    s.wi[rows] = mf.reflect(s.wo[rows], h)
    # A reflection below the surface is absorbed, as in Cycles
    # (bsdf_microfacet_sample): eval_pdf would hand it to a transmitting
    # lobe whose pdf leaves out this sampler's density there (biased).
    s.kind[rows[s.wi[rows, 2] <= 0.0]] = NONE


def sample_mirror(lobes, rows, s):
    s.wi[rows] = s.wo[rows] * np.array([-1.0, -1.0, 1.0])
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        s.weight[r] = s.w[r, k] * fresnel(lobes, r, k, s.wo[r, 2]) / s.p_lobe[r, None]
    s.delta[rows] = True
    s.pdf[rows] = s.p_lobe[rows]


def albedo_guess_glossy(lobes, k, mu):
    """The Fresnel at the view angle for F82 and dielectric lobes (their
    colour does not hold it; under a thin film its reflectance there, as
    Cycles' sample weight); 1 for the others."""
    f0 = luminance(lobes.f0[:, k])
    est = f0 + (1.0 - f0) * mf.pow5(1.0 - mu)
    code = lobes.fresnel[:, k]
    est = np.where((code != F_NONE) & (code != F_SCHLICK), est, 1.0)
    m = np.flatnonzero(code == F_CONDUCTOR)   # its exact Fresnel at the view angle (f0 holds n)
    if len(m):
        est[m] = luminance(mf.conductor(mu[m], lobes.f0[m, k], lobes.edge_tint[m, k]))
    for c in (F_F82, F_DIELECTRIC, F_CONDUCTOR):
        m = np.flatnonzero((code == c) & has_film(lobes, slice(None), k))
        if len(m):
            est[m] = luminance(film_fresnel(c, lobes, m, k, mu[m]))
    return est


_FRESNEL = ("fresnel", "ior", "f0", "edge_tint", "thin_film_thickness", "thin_film_ior")
register(LobeDef(MIRROR, "mirror", "glossy", REFLECTION | DELTA, sample_mirror, params=_FRESNEL,
                 doc="perfect specular reflection (a glossy lobe below MIN_ALPHA becomes one)",
                 cases=[dict(color=(0.9, 0.8, 0.7)), dict(color=(1, 1, 1), fresnel="f82", f0=(0.9, 0.6, 0.3),
                                                           edge_tint=(0.9, 0.9, 0.5)),
                        dict(color=(1, 1, 1), fresnel="f82", f0=(0.9, 0.6, 0.3), edge_tint=(0.9, 0.9, 0.5),
                             thin_film_thickness=350.0, thin_film_ior=1.5),
                        # a physical conductor (gold's n, k), bare and under a film
                        dict(color=(1, 1, 1), fresnel="conductor", f0=(0.18, 0.42, 1.37), edge_tint=(3.42, 2.35, 1.77)),
                        dict(color=(1, 1, 1), fresnel="conductor", f0=(0.18, 0.42, 1.37), edge_tint=(3.42, 2.35, 1.77),
                             thin_film_thickness=300.0, thin_film_ior=1.4)]))
register(LobeDef(GLOSSY, "glossy", "glossy", REFLECTION, sample_glossy, eval_glossy, "upper",
                 albedo_guess=albedo_guess_glossy, params=("roughness", "multiscatter") + _FRESNEL,
                 doc="GGX microfacet reflection, alpha = roughness^2 (Walter et al. 2007, VNDF sampling)",
                 cases=[dict(color=(0.8, 0.7, 0.6), roughness=0.5),
                        dict(color=(0.9, 0.9, 0.9), roughness=0.15),
                        dict(color=(0.04, 0.04, 0.04), roughness=0.4, fresnel="schlick"),
                        dict(color=(1, 1, 1), roughness=0.3, fresnel="f82", f0=(0.9, 0.6, 0.3),
                             edge_tint=(0.9, 0.9, 0.5)),
                        dict(color=(1, 1, 1), roughness=0.6, fresnel="dielectric", ior=1.45),
                        dict(color=(0.8, 0.8, 0.8), roughness=0.4, multiscatter=True),
                        # thin films: oil on a metal, a soap film on the Principled specular layer
                        dict(color=(1, 1, 1), roughness=0.25, fresnel="f82", f0=(0.9, 0.6, 0.3),
                             edge_tint=(0.9, 0.9, 0.5), thin_film_thickness=450.0, thin_film_ior=1.5),
                        dict(color=(1, 1, 1), roughness=0.3, fresnel="dielectric", ior=1.5,
                             thin_film_thickness=500.0, thin_film_ior=1.33, multiscatter=True),
                        # physical conductors: a dielectric-like n (k 0, where the F82 fit is worst) and
                        # copper's n, k under a film, with multiscatter (Fss from the fit, as Cycles)
                        dict(color=(1, 1, 1), roughness=0.35, fresnel="conductor", f0=(1.5, 1.5, 1.5),
                             edge_tint=(0.0, 0.0, 0.0)),
                        dict(color=(1, 1, 1), roughness=0.3, fresnel="conductor", f0=(0.27, 0.68, 1.32),
                             edge_tint=(3.61, 2.62, 2.29), thin_film_thickness=420.0, thin_film_ior=1.5,
                             multiscatter=True)]))
