"""Subsurface scattering lobes (Cycles' BSSRDF closures, kernel/closure/bssrdf.h).

A BSSRDF has no BSDF value: light enters at one point and leaves at
another, found by the integrator's subsurface stage
(engine/integrator/subsurface.py, Cycles' random walk).  The lobes here
declare the closure (its parameters: colour = the surface albedo, radius,
phase_g, ior, roughness for the refractive entry) and the entry bounce
(Cycles' ``subsurface_entry_bounce``): the direction into the surface, in
the shading frame.  ``eval`` is zero everywhere, so light sampling sees the
BSDF lobes only (as Cycles, whose BSSRDF closures are not evaluated there);
the stage chooses a subsurface lobe by its selection probability and
hands the rest of the selection to the BSDF lobes.

``subsurface`` is Cycles' Random Walk, ``subsurface_skin`` its Random Walk
(Skin): a fixed entry roughness of 1 with half the entries diffuse, and a
radius remapped by the albedo and IOR (``bssrdf_setup_radius``).
"""
import numpy as np

from ..microfacet import ggx_sample_vndf
from ..sampling import cosine_hemisphere
from .registry import DELTA, SUBSURFACE, TRANSMISSION, LobeDef, register

SUBSURFACE_RANDOM_WALK = 20
SUBSURFACE_SKIN = 21
IDS = (SUBSURFACE_RANDOM_WALK, SUBSURFACE_SKIN)
# Cycles' bssrdf_setup clamps.
IOR_RANGE = (1.01, 3.8)
G_RANGE = (0.0, 0.9)


def entry_direction(skin, wo, alpha, ior, u1, u2):
    """Cycles' subsurface_entry_bounce in the shading frame (wo.z > 0):
    the refracted direction through a GGX microfacet of roughness alpha
    (1 for skin) with relative IOR ior, or for skin half of the time a
    cosine direction into the surface.  Returns (wi (N, 3), ok (N,))."""
    n = len(wo)
    skin = np.broadcast_to(np.asarray(skin, bool), (n,))
    u1 = np.array(u1, np.float64)
    diffuse = skin & (u1 < 0.5)
    u1 = np.where(skin, np.where(diffuse, 2.0 * u1, 2.0 * (u1 - 0.5)), u1)
    u1 = np.minimum(u1, 1.0 - 1e-12)
    a = np.where(skin, 1.0, alpha)
    neta = 1.0 / np.clip(ior, *IOR_RANGE)
    ok = wo[:, 2] > 0.0
    wo_up = np.where(ok[:, None], wo, np.array([0.0, 0.0, 1.0]))
    h = ggx_sample_vndf(wo_up, a, u1, u2)
    cos_hi = np.einsum("ij,ij->i", h, wo_up)
    arg = 1.0 - neta * neta * (1.0 - cos_hi * cos_hi)
    dnp = np.maximum(np.sqrt(np.maximum(arg, 0.0)), 1e-7)
    nk = neta * cos_hi - dnp
    wi = -neta[:, None] * wo_up + nk[:, None] * h
    cos = cosine_hemisphere(u1, u2)[0] * np.array([1.0, 1.0, -1.0])
    wi = np.where(diffuse[:, None], cos, wi)
    wi /= np.maximum(np.linalg.norm(wi, axis=1), 1e-30)[:, None]
    return wi, (ok | diffuse) & (wi[:, 2] < 0.0)


def _eval(lobes, rows, k, wo, wi, w, sel, term, sampled):
    """No BSDF value (the walk carries the light)."""
    n = len(wo)
    return np.zeros((n, 3)), np.zeros(n)


def _sample(skin):
    def sample(lobes, rows, s):
        """The entry direction, with the closure's weight over its
        selection probability (Cycles' subsurface_bounce throughput)."""
        k = s.chosen[rows]
        wi, ok = entry_direction(skin, s.wo[rows], lobes.alpha[rows, k], lobes.ior[rows, k],
                                 s.u1[rows], s.u2[rows])
        s.wi[rows] = wi
        s.weight[rows] = np.where(ok[:, None], s.w[rows, k] / s.p_lobe[rows, None], 0.0)
        s.delta[rows] = True
        s.pdf[rows] = s.p_lobe[rows]
    return sample


_PARAMS = ("roughness", "ior", "radius", "phase_g")
_CASES = [dict(color=(0.8, 0.5, 0.3), radius=(1.0, 0.2, 0.1), roughness=0.5, ior=1.4)]
register(LobeDef(SUBSURFACE_RANDOM_WALK, "subsurface", "diffuse", DELTA | TRANSMISSION | SUBSURFACE, _sample(False),
                 _eval, "lower", params=_PARAMS,
                 doc="Cycles' Random Walk BSSRDF (Principled Subsurface, Subsurface Scattering node)",
                 cases=_CASES))
register(LobeDef(SUBSURFACE_SKIN, "subsurface_skin", "diffuse", DELTA | TRANSMISSION | SUBSURFACE, _sample(True),
                 _eval, "lower", params=_PARAMS,
                 doc="Cycles' Random Walk (Skin) BSSRDF: fixed entry roughness, albedo-remapped radius",
                 cases=_CASES))
