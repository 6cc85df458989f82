"""Anisotropic GGX reflection (Cycles' closure/bsdf_microfacet.h with
alpha_x != alpha_y): the Principled BSDF's Anisotropy.  alpha_x and alpha_y
come from the roughness and the lobe's ``anisotropy`` as Cycles' Principled
BSDF sets them: aspect = sqrt(1 - 0.9 anisotropy), alpha_x = alpha / aspect,
alpha_y = alpha aspect.  The tangent (alpha_x) is the shading frame's x axis.
The compiled form is the GLOSSY_ANISOTROPIC branch of engine/bsdf_loops.py."""
import numpy as np

from .. import microfacet as mf
from ..microfacet import ggx_sample_vndf
from .ggx import fresnel
from .registry import MIN_ALPHA, NONE, REFLECTION, LobeDef, register

GLOSSY_ANISOTROPIC = 8


def alphas(lobes, rows, k):
    """(alpha_x, alpha_y) of slot k, never below MIN_ALPHA."""
    alpha = lobes.alpha[rows, k]
    aspect = np.sqrt(1.0 - np.clip(lobes.anisotropy[rows, k], 0.0, 1.0) * 0.9)
    return np.maximum(alpha / aspect, MIN_ALPHA), np.maximum(alpha * aspect, MIN_ALPHA)


def smith_lambda(w, ax, ay):
    """Smith's Lambda of the anisotropic GGX (w.z > 0)."""
    t = (ax * ax * w[:, 0] * w[:, 0] + ay * ay * w[:, 1] * w[:, 1]) / (w[:, 2] * w[:, 2])
    return 0.5 * (np.sqrt(1.0 + t) - 1.0)


def ndf(h, ax, ay):
    """D(h) = 1 / (pi ax ay ((hx / ax)^2 + (hy / ay)^2 + hz^2)^2)."""
    x, y = h[:, 0] / ax, h[:, 1] / ay
    q = x * x + y * y + h[:, 2] * h[:, 2]
    return 1.0 / (np.pi * ax * ay * q * q)


def eval_f(lobes, rows, k, wo, wi):
    """f (without the weight) D G2 F / (4 cos_o cos_i) and the VNDF pdf
    D G1(wo) / (4 cos_o) (both directions above the surface)."""
    ax, ay = alphas(lobes, rows, k)
    h = wo + wi
    h /= mf.row_norm(h)[:, None]
    d = ndf(h, ax, ay)
    lo, li = smith_lambda(wo, ax, ay), smith_lambda(wi, ax, ay)
    spec = d / ((1.0 + lo + li) * 4.0 * wo[:, 2] * wi[:, 2])
    pdf = d / ((1.0 + lo) * 4.0 * wo[:, 2])
    return fresnel(lobes, rows, k, mf.row_dot(wo, h)) * spec[:, None], pdf


def eval_anisotropic(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_f(lobes, rows, k, wo, wi)
    return w * f, sel * pdf


def sample_anisotropic(lobes, rows, s):
    """Reflect wo about a visible normal (Heitz 2018, stretched by ax, ay);
    a reflection below the surface is absorbed, as for the isotropic lobe."""
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        ax, ay = alphas(lobes, r, k)
        h = ggx_sample_vndf(s.wo[r], ax, s.u1[r], s.u2[r], alpha_y=ay)
        s.wi[r] = mf.reflect(s.wo[r], h)
        s.kind[r[s.wi[r, 2] <= 0.0]] = NONE


register(LobeDef(GLOSSY_ANISOTROPIC, "glossy_anisotropic", "glossy", REFLECTION, sample_anisotropic,
                 eval_anisotropic, "upper", params=("roughness", "anisotropy", "fresnel", "ior", "f0", "edge_tint"),
                 doc="anisotropic GGX reflection: alpha_x = alpha / aspect, alpha_y = alpha aspect, "
                     "aspect = sqrt(1 - 0.9 anisotropy) (Cycles' Principled), tangent = the shading frame's x",
                 cases=[dict(color=(0.9, 0.8, 0.7), roughness=0.5, anisotropy=0.8),
                        dict(color=(1, 1, 1), roughness=0.3, anisotropy=0.5, fresnel="f82", f0=(0.9, 0.6, 0.3),
                             edge_tint=(0.9, 0.9, 0.5)),
                        dict(color=(1, 1, 1), roughness=0.4, anisotropy=1.0, fresnel="dielectric", ior=1.5)]))
