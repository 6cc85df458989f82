"""Cycles' energy-preserving Oren-Nayar diffuse (closure/bsdf_oren_nayar.h,
Blender 4.3+): Fujii's improved Oren-Nayar single scattering plus the
OpenPBR multiple-scattering term, so a white surface keeps (nearly) all
its energy at any roughness.  The Diffuse BSDF's Roughness and the
Principled BSDF's Diffuse Roughness (sigma, clamped to [0, 1]); sampled as
Lambert (cosine hemisphere), as Cycles.  The compiled form is the
OREN_NAYAR branch of engine/bsdf_loops.py (``oren_nayar_f``)."""
import numpy as np

from ..sampling import INV_PI, cosine_hemisphere
from .registry import REFLECTION, LobeDef, register

OREN_NAYAR = 9
HALF_PI = 0.5 * np.pi
FLT_MIN = 1.1754943508222875e-38


def coefficients(sigma):
    """Cycles' a and b of bsdf_oren_nayar_setup (sigma saturated)."""
    sigma = np.clip(sigma, 0.0, 1.0)
    a = 1.0 / (np.pi + sigma * (HALF_PI - 2.0 / 3.0))
    return a, sigma * a


def g_term(cos):
    """bsdf_oren_nayar_G: the directional albedo's angular part."""
    c = np.asarray(cos, dtype=np.float64)
    safe = np.maximum(c, 1e-6)
    s = np.sqrt(np.maximum(1.0 - safe * safe, 0.0))
    theta = np.arccos(np.clip(safe, -1.0, 1.0))
    full = s * (theta - 2.0 / 3.0 - s * safe) + 2.0 / 3.0 * (s / safe) * (1.0 - s * s * s)
    return np.where(c < 1e-6, (HALF_PI - 2.0 / 3.0) - c, full)


def multiscatter(albedo, a, b, cos_o):
    """Ems (1 - E(wo)) per channel: the view-dependent factor of Cycles'
    multiscatter_term (albedo saturated)."""
    rho = np.clip(albedo, 0.0, 1.0)
    # b = 0 (sigma 0) is Lambert, whose E_avg is 1: no multiple scattering.
    e_avg = np.where(b > 0.0, a * np.pi + ((2.0 * np.pi - 5.6) / 3.0) * b, 0.5)
    ems = INV_PI * rho * rho * (e_avg / (1.0 - e_avg))[:, None] / (1.0 - rho * (1.0 - e_avg)[:, None])
    e_o = a * np.pi + b * g_term(np.maximum(cos_o, 0.0))
    return np.where((b > 0.0)[:, None], ems * (1.0 - e_o)[:, None], 0.0)


def eval_f(lobes, rows, k, wo, wi):
    """f per channel (without the weight; the colour enters the
    multiple-scattering term) and the cosine pdf."""
    a, b = coefficients(lobes.diffuse_roughness[rows, k])
    nl = np.maximum(wi[:, 2], 0.0)
    nv = np.maximum(wo[:, 2], 0.0)
    t = np.einsum("ij,ij->i", wi, wo) - nl * nv
    t = np.where(t > 0.0, t / (np.maximum(nl, nv) + FLT_MIN), t)
    single = a + b * t
    e_l = a * np.pi + b * g_term(nl)
    f = single[:, None] + multiscatter(lobes.color[rows, k], a, b, nv) * (1.0 - e_l)[:, None]
    f = np.where((b > 0.0)[:, None], f, INV_PI)
    return f, nl * INV_PI


def eval_oren_nayar(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_f(lobes, rows, k, wo, wi)
    if term is not None:
        f = f * term[:, None]
    return w * f, sel * pdf


def sample_oren_nayar(lobes, rows, s):
    s.wi[rows] = cosine_hemisphere(s.u1[rows], s.u2[rows])[0]


register(LobeDef(OREN_NAYAR, "oren_nayar", "diffuse", REFLECTION, sample_oren_nayar, eval_oren_nayar, "upper",
                 params=("diffuse_roughness",),
                 doc="energy-preserving Oren-Nayar (Fujii + OpenPBR multiple scattering, Cycles 4.3+)",
                 cases=[dict(color=(0.8, 0.6, 0.4), diffuse_roughness=1.0),
                        dict(color=(1.0, 1.0, 1.0), diffuse_roughness=0.5)]))
