"""GGX microfacet terms, Fresnel models and Cycles' precomputed tables.

Everything here follows Cycles' kernel (closure/bsdf_microfacet.h,
bsdf_util.h, bsdf_sheen.h), on arrays.  Directions are in a local frame with
+Z the shading normal; ``wo`` is the direction towards the viewer.
``eta`` is the relative IOR (inside over outside, inverted when the ray
arrives from the inside), as Cycles' ``bsdf->ior``.

The tables (engine/data/tables.npz, built by ``python -m
engine.data.build_tables``) are indexed and interpolated as Cycles'
``lookup_table_read*``: a grid over [0, 1] per axis, clamped, linear.
"""
import os

import numpy as np

from .kernels import helper, kernel, where

COS_EPS = 1e-9
DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "tables.npz")


# ----------------------------------------------------------------------------
# GGX distribution, Smith masking (height-correlated), visible-normal sampling

@helper
def ggx_d(h_z, alpha):
    a2 = alpha * alpha
    t = h_z * h_z * (a2 - 1.0) + 1.0
    return a2 / (np.pi * t * t)


@helper
def ggx_lambda(w_z, alpha):
    z2 = np.maximum(w_z * w_z, COS_EPS)
    tan2 = np.maximum(1.0 - z2, 0.0) / z2
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


@helper
def ggx_reflect_terms(wox, woy, woz, wix, wiy, wiz, alpha):
    """Elementwise GGX reflection: D G2 / (4 cos_o cos_i), the VNDF pdf of
    wi and the unit half vector (x, y, z); 0 below either horizon."""
    hx = wox + wix
    hy = woy + wiy
    hz = woz + wiz
    hl = np.sqrt(hx * hx + hy * hy + hz * hz)
    inv = 1.0 / where(hl > 0, hl, 1.0)
    hx = hx * inv
    hy = hy * inv
    hz = hz * inv
    ok = (woz > COS_EPS) & (wiz > COS_EPS) & (hl > 0)
    lo = ggx_lambda(woz, alpha)
    li = ggx_lambda(wiz, alpha)
    d = ggx_d(hz, alpha)
    co = np.maximum(woz, COS_EPS)
    spec = d / (4.0 * co * np.maximum(wiz, COS_EPS) * (1.0 + lo + li))
    pdf = d / ((1.0 + lo) * 4.0 * co)
    return where(ok, spec, 0.0), where(ok, pdf, 0.0), hx, hy, hz


ggx_reflect = kernel(7, 5)(ggx_reflect_terms)


def ggx_sample_vndf(wo, alpha, u1, u2, alpha_y=None):
    """Visible microfacet normal for wo (wo.z > 0), Heitz 2018; anisotropic
    with roughness alpha along x and alpha_y along y when alpha_y is given."""
    ay = alpha if alpha_y is None else alpha_y
    vh = np.stack([alpha * wo[:, 0], ay * wo[:, 1], wo[:, 2]], axis=1)
    vh /= row_norm(vh)[:, None]
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = np.where(lensq > 0, 1.0 / np.sqrt(np.where(lensq > 0, lensq, 1.0)), 0.0)
    t1 = np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, np.zeros(len(vh))], axis=1)
    t1[lensq <= 0] = (1.0, 0.0, 0.0)
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    ne = np.stack([alpha * nh[:, 0], ay * nh[:, 1], np.maximum(nh[:, 2], 1e-12)], axis=1)
    return ne / row_norm(ne)[:, None]


# Dot products and norms written out term by term (not einsum, linalg.norm):
# engine/bsdf_loops.py computes them ray by ray in the same order.

def row_dot(a, b):
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def row_norm(a):
    return np.sqrt(row_dot(a, a))


def reflect(wo, h):
    return 2.0 * row_dot(wo, h)[:, None] * h - wo


def refract(wo, h, cos_t, eta):
    """Refracted direction through microfacet h; cos_t = |cos| of the
    transmitted angle (Cycles' refract_angle with its negative cos_t)."""
    inv = 1.0 / eta
    c = row_dot(wo, h)
    return (inv * c - cos_t)[:, None] * h - inv[:, None] * wo


def refraction_half(wo, wi, eta):
    """Half vector of a refraction wo -> wi (Walter 2007), turned towards +Z,
    and the length of the unnormalised -(eta wi + wo)."""
    h = -(eta[:, None] * wi + wo)
    length = row_norm(h)
    # Leaving a denser medium (eta < 1) the vector points down: flip it.
    h = h * (np.where(h[:, 2] < 0, -1.0, 1.0) / np.where(length > 0, length, 1.0))[:, None]
    return h, length


# ----------------------------------------------------------------------------
# Fresnel

def f0_from_ior(ior):
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_from_f0(f0):
    s = np.sqrt(np.clip(f0, 0.0, 0.99))
    return (1.0 + s) / (1.0 - s)


def fresnel_dielectric(cos_i, eta):
    """Unpolarised dielectric reflectance and |cos| of the transmitted angle
    (0 under total internal reflection, where F = 1)."""
    c = np.abs(cos_i)
    t2 = eta * eta - (1.0 - c * c)
    tir = t2 <= 0
    cos_t = np.sqrt(np.maximum(t2, 0.0)) / eta
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = (c - eta * cos_t) / (c + eta * cos_t)
        rp = (eta * c - cos_t) / (eta * c + cos_t)
        f = 0.5 * (rs * rs + rp * rp)
    f = np.where(tir | ~np.isfinite(f), 1.0, f)
    return f, np.where(tir, 0.0, cos_t)


def dielectric_fss(eta):
    """Average single-scattering dielectric Fresnel (Kulla-Conty fit)."""
    return np.where(eta < 1.0, 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607)),
                    (eta - 1.0) / (4.08567 + 1.00071 * eta))


def schlick_s(cos, ior):
    """Principled BSDF's generalised Schlick weight: the real Fresnel curve
    remapped from [F0(ior), 1] to [0, 1] (F = mix(f0, 1, s)); also cos_t."""
    f, cos_t = fresnel_dielectric(cos, ior)
    f0 = f0_from_ior(ior)
    s = np.clip((f - f0) / np.maximum(1.0 - f0, 1e-12), 0.0, 1.0)
    return s, cos_t


# The F82 model's constants: Schlick's weight at cos 1/7 (82 degrees) and the B term's scale.
F82_F5 = (6.0 / 7.0) ** 5
F82_SCALE = 7.0 / (F82_F5 * (6.0 / 7.0))


def f82_b(f0, tint):
    """B term of Cycles' F82-tint metal Fresnel (Kutz et al.)."""
    schlick = f0 + (1.0 - f0) * F82_F5
    return schlick * F82_SCALE * (1.0 - tint)


@helper
def pow5(x):
    """x^5 by multiplication (several times cheaper than pow; the compiled
    loops of engine/bsdf_loops.py multiply in the same order)."""
    x2 = x * x
    return x2 * x2 * x


def f82(cos, f0, b):
    s = np.clip(1.0 - cos, 0.0, 1.0)[..., None]
    s5 = pow5(s)
    return np.clip(f0 + (1.0 - f0) * s5 - b * cos[..., None] * s5 * s, 0.0, 1.0)


def f82_fss(f0, b):
    return f0 + (1.0 - f0) / 21.0 - b / 126.0


def conductor(cos, n, k):
    """(..., 3) unpolarized Fresnel reflectance of a conductor n + i k (each
    (..., 3)) at cos (...,) from a medium of IOR 1: Cycles' fresnel_conductor."""
    c = np.clip(np.asarray(cos, np.float64), 0.0, 1.0)[..., None]
    c2 = c * c
    s2 = 1.0 - c2
    n2, k2 = n * n, k * k
    t0 = n2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * n2 * k2)
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.where(t1 + t2 > 0, (t1 - t2) / (t1 + t2), 1.0)
        t3 = c2 * a2b2 + s2 * s2
        t4 = t2 * s2
        rp = np.where(t3 + t4 > 0, rs * (t3 - t4) / (t3 + t4), 1.0)
    return np.clip(0.5 * (rp + rs), 0.0, 1.0)


def conductor_fss(n, k):
    """Cycles' fresnel_conductor_Fss: the F82 model fitted at cos 1 and 1/7,
    its closed-form average, saturated."""
    f0 = conductor(np.ones(np.shape(n)[:-1]), n, k)
    f82 = conductor(np.full(np.shape(n)[:-1], 1.0 / 7.0), n, k)
    b = F82_SCALE * ((f0 + (1.0 - f0) * F82_F5) - f82)
    return np.clip(f82_fss(f0, b), 0.0, 1.0)


# ----------------------------------------------------------------------------
# Tables

_tables = None


def tables():
    global _tables
    if _tables is None:
        with np.load(DATA) as data:
            _tables = {name: data[name].astype(np.float64) for name in data.files}
    return _tables


def lookup(table, *coords):
    """Cycles' lookup_table_read_{1,2,3}D: ``table`` has shape (..., nz, ny, nx)
    and coords are (x, y, z) in [0, 1] (clamped), linearly interpolated."""
    idx = []
    weights = []
    for axis, c in enumerate(coords):
        size = table.shape[table.ndim - 1 - axis]
        x = np.clip(c, 0.0, 1.0) * (size - 1)
        i = np.minimum(x.astype(np.int64), size - 1)
        idx.append((i, np.minimum(i + 1, size - 1)))
        weights.append(x - i)
    out = 0.0
    for corner in range(1 << len(coords)):
        w = 1.0
        index = []
        for axis in range(len(coords)):
            bit = (corner >> axis) & 1
            w = w * (weights[axis] if bit else 1.0 - weights[axis])
            index.append(idx[axis][bit])
        out = out + w * table[tuple(reversed(index))]
    return out


def ior_z(eta):
    """Table coordinate of an IOR (Cycles: sqrt(|eta - 1| / (eta + 1)))."""
    return np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))
