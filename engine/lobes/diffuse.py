"""Lambert diffuse and translucent lobes (Cycles' bsdf_diffuse.h)."""
import numpy as np

from ..sampling import INV_PI, cosine_hemisphere
from .registry import REFLECTION, TRANSMISSION, LobeDef, register

DIFFUSE = 0
TRANSLUCENT = 5


def _eval(w, sel, wi, term):
    """Lambert: f = colour / pi (times Cycles' bump softening), pdf = |cos| / pi."""
    f = w * INV_PI if term is None else w * (INV_PI * term)[:, None]
    return f, sel * np.abs(wi[:, 2]) * INV_PI


def eval_diffuse(lobes, rows, k, wo, wi, w, sel, term, sampled):
    return _eval(w, sel, wi, term)


def eval_translucent(lobes, rows, k, wo, wi, w, sel, term, sampled):
    """Cycles softens a sampled translucent direction's bump shadowing not."""
    return _eval(w, sel, wi, None if sampled else term)


def _sample(rows, s, flip):
    s.wi[rows] = cosine_hemisphere(s.u1[rows], s.u2[rows])[0] * np.array([1.0, 1.0, flip])


def sample_diffuse(lobes, rows, s):
    _sample(rows, s, 1.0)


def sample_translucent(lobes, rows, s):
    _sample(rows, s, -1.0)


register(LobeDef(DIFFUSE, "diffuse", "diffuse", REFLECTION, sample_diffuse, eval_diffuse, "upper",
                 doc="Lambert (Diffuse BSDF, the Principled base)",
                 cases=[dict(color=(0.8, 0.6, 0.4))]))
register(LobeDef(TRANSLUCENT, "translucent", "diffuse", TRANSMISSION, sample_translucent, eval_translucent,
                 "lower", doc="Lambert on the other side (Translucent BSDF)", has_transmission=True,
                 cases=[dict(color=(0.5, 0.8, 0.5))]))
