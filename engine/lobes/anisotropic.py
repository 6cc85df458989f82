"""Anisotropic GGX reflection (Cycles' closure/bsdf_microfacet.h with
alpha_x != alpha_y): the Principled and Metallic BSDFs' Anisotropy and the
Glossy BSDF's.  alpha_x and alpha_y come from the roughness and the lobe's
``anisotropy`` as Cycles' Principled BSDF sets them: aspect = sqrt(1 - 0.9
anisotropy), alpha_x = alpha / aspect, alpha_y = alpha aspect (the Glossy
BSDF's mapping is expressed in it by the exporter: anisotropy up to 1/0.9,
a quarter turn where its long axis is the bitangent).  The tangent is the
shading frame's x axis (the material's tangent, Cycles' radial default,
engine/integrator/stages.shade), turned about the normal by ``rotation``
turns as Cycles' rotate_around_axis.  Multiscatter GGX compensates it with
the isotropic tables at alpha = sqrt(alpha_x alpha_y), as Cycles.  The
compiled form is the GLOSSY_ANISOTROPIC branch of engine/bsdf_loops.py."""
import numpy as np

from .. import microfacet as mf
from ..microfacet import ggx_sample_vndf
from .ggx import fresnel
from .registry import MIN_ALPHA, NONE, REFLECTION, LobeDef, register

GLOSSY_ANISOTROPIC = 8
MAX_ANISOTROPY = 1.0 / 0.9     # aspect 0: the Glossy BSDF's Anisotropy +-1
MIN_ASPECT_SQ = 1e-8           # the aspect's square at least this (alpha ratio 1e8)


def alphas(lobes, rows, k):
    """(alpha_x, alpha_y) of slot k, never below MIN_ALPHA."""
    alpha = lobes.alpha[rows, k]
    aspect = np.sqrt(np.maximum(1.0 - np.clip(lobes.anisotropy[rows, k], 0.0, MAX_ANISOTROPY) * 0.9, MIN_ASPECT_SQ))
    return np.maximum(alpha / aspect, MIN_ALPHA), np.maximum(alpha * aspect, MIN_ALPHA)


def turn(rotation):
    """cos and sin of a tangent rotated by ``rotation`` turns (its fraction)."""
    angle = 2.0 * np.pi * (rotation - np.floor(rotation))
    return np.cos(angle), np.sin(angle)


def to_tangent(w, c, s):
    """Directions in the frame whose x axis is the tangent turned by
    (cos, sin) about z: x' = c x + s y, y' = c y - s x."""
    return np.stack([c * w[:, 0] + s * w[:, 1], c * w[:, 1] - s * w[:, 0], w[:, 2]], axis=1)


def from_tangent(w, c, s):
    return np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], axis=1)


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
    c, s = turn(lobes.rotation[rows, k])
    wo, wi = to_tangent(wo, c, s), to_tangent(wi, c, s)
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
        c, sn = turn(lobes.rotation[r, k])
        wo = to_tangent(s.wo[r], c, sn)
        h = ggx_sample_vndf(wo, ax, s.u1[r], s.u2[r], alpha_y=ay)
        s.wi[r] = from_tangent(mf.reflect(wo, h), c, sn)
        s.kind[r[s.wi[r, 2] <= 0.0]] = NONE


register(LobeDef(GLOSSY_ANISOTROPIC, "glossy_anisotropic", "glossy", REFLECTION, sample_anisotropic,
                 eval_anisotropic, "upper", params=("roughness", "anisotropy", "rotation", "multiscatter", "fresnel", "ior", "f0",
                                                    "edge_tint"),
                 doc="anisotropic GGX reflection: alpha_x = alpha / aspect, alpha_y = alpha aspect, "
                     "aspect = sqrt(1 - 0.9 anisotropy) (Cycles' Principled), tangent = the shading frame's x",
                 cases=[dict(color=(0.9, 0.8, 0.7), roughness=0.5, anisotropy=0.8),
                        dict(color=(1, 1, 1), roughness=0.3, anisotropy=0.5, fresnel="f82", f0=(0.9, 0.6, 0.3),
                             edge_tint=(0.9, 0.9, 0.5)),
                        dict(color=(1, 1, 1), roughness=0.4, anisotropy=1.0, fresnel="dielectric", ior=1.5),
                        dict(color=(0.9, 0.9, 0.9), roughness=0.35, anisotropy=1.05, rotation=0.15),
                        dict(color=(0.8, 0.8, 0.8), roughness=0.5, anisotropy=0.6, rotation=0.4,
                             multiscatter=True),
                        dict(color=(1, 1, 1), roughness=0.3, anisotropy=0.7, fresnel="conductor",
                             f0=(0.18, 0.42, 1.37), edge_tint=(3.42, 2.35, 1.77), multiscatter=True)]))
