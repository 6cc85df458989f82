"""Zeltner et al. 2022 LTC sheen, as Cycles' bsdf_sheen.h (Sheen BSDF,
the Principled sheen layer)."""
import numpy as np

from .. import microfacet as mf
from ..microfacet import COS_EPS
from ..sampling import INV_PI, TWO_PI
from .registry import REFLECTION, LobeDef, register

SHEEN = 7


def sheen_ltc(rough, mu):
    """Cycles' sheen LTC coefficients a, b and albedo for (roughness, cos)."""
    t = mf.tables()["sheen_ltc"]
    r = np.clip(rough, 1e-3, 1.0)
    return tuple(mf.lookup(t[i], mu, r) for i in range(3))


def sheen_frame(wo):
    """Tangent towards wo (Cycles' make_orthonormals_safe_tangent)."""
    t = np.stack([wo[:, 0], wo[:, 1], np.zeros(len(wo))], axis=1)
    length = np.sqrt(mf.row_dot(t, t))
    flat = length < 1e-7
    t = np.where(flat[:, None], np.array([1.0, 0.0, 0.0]), t / np.where(flat, 1.0, length)[:, None])
    b = np.stack([-t[:, 1], t[:, 0], np.zeros(len(wo))], axis=1)   # z x t
    return t, b


def ltc(lobes, rows, k, wo):
    a, b, _ = sheen_ltc(np.sqrt(lobes.alpha[rows, k]), np.clip(wo[:, 2], 0.0, 1.0))
    return a, b


def eval_sheen_f(lobes, rows, k, wo, wi):
    """f (without the weight) and pdf; f * cos = pdf (the albedo sits in the
    weight), so f = pdf / cos."""
    a, b = ltc(lobes, rows, k, wo)
    t, bt = sheen_frame(wo)
    x, y, z = mf.row_dot(wi, t), mf.row_dot(wi, bt), wi[:, 2]
    len_sq = (a * x + b * z) ** 2 + (a * y) ** 2 + z * z
    ok = (z > COS_EPS) & (wo[:, 2] > COS_EPS) & (np.abs(a) >= 1e-5)
    with np.errstate(divide="ignore", invalid="ignore"):
        val = INV_PI * (a / len_sq) ** 2
    val = np.where(ok & np.isfinite(val), val, 0.0)
    return np.repeat(val[:, None], 3, axis=1), val * np.maximum(z, 0.0)


def eval_sheen(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_sheen_f(lobes, rows, k, wo, wi)
    return w * f, sel * pdf


def sample_sheen_dir(lobes, rows, k, wo, u1, u2):
    a, b = ltc(lobes, rows, k, wo)
    r = np.sqrt(u1)
    phi = TWO_PI * u2
    dx, dy = r * np.cos(phi), r * np.sin(phi)
    dz = np.sqrt(np.maximum(0.0, 1.0 - u1))
    local = np.stack([dx - dz * b, dy, dz * a], axis=1)
    local /= np.maximum(mf.row_norm(local), 1e-30)[:, None]
    t, bt = sheen_frame(wo)
    return local[:, :1] * t + local[:, 1:2] * bt + local[:, 2:3] * np.array([0.0, 0.0, 1.0])


def sample_sheen(lobes, rows, s):
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        s.wi[r] = sample_sheen_dir(lobes, r, k, s.wo[r], s.u1[r], s.u2[r])


register(LobeDef(SHEEN, "sheen", "diffuse", REFLECTION, sample_sheen, eval_sheen, "upper",
                 params=("roughness",), reciprocal=False,
                 doc="LTC sheen; its directional albedo is folded into its weight (bsdf.weights)",
                 cases=[dict(color=(0.6, 0.6, 0.9), roughness=0.3), dict(color=(1, 1, 1), roughness=0.8)]))
