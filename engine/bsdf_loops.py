"""The layered BSDF's per-ray loops, compiled by numba (engine/kernels.py).

engine/bsdf.py weighs, selects and evaluates lobes on whole batches with
NumPy: a loop over the K lobe slots, each a few masked gathers over all
rows.  Here the same maths runs ray by ray in one pass over the K slots,
without temporaries; bsdf.py wraps each loop in a ``LoopKernel`` whose NumPy
twin is its batch code, and tests/engine/test_bsdf_loops.py checks that both
agree to float64 rounding on random lobes.  Each lobe kind is one branch of
the eval, sample (and, for layers, weights) loops, the compiled form of its
registry entry's kernels (engine/lobes/).

``lobes`` is the tuple ``LOBE_FIELDS`` of per-ray arrays (derived from the
registry's parameters) and ``tables`` the tuple ``TABLES`` of Cycles' albedo
tables (engine/microfacet.py).  Two plain row loops close the file: the end
of ``sample`` (weights from eval_pdf) and ``MaterialTable.gather``'s copy of
the lobe parameters.
"""
import numpy as np

from .kernels import clip
from .lobes import EXTRA_PARAMS, FILM_CUTOFF, PARAMS
from .lobe_ids import (DIFFUSE, F_CONDUCTOR, F_DIELECTRIC, F_F82, F_NONE, F_SCHLICK, GLASS, GLOSSY, GLOSSY_ANISOTROPIC, MIN_ALPHA,
                       MIRROR, NONE, OREN_NAYAR, REFRACTION, SHEEN, SUBSURFACE_BURLEY, SUBSURFACE_RANDOM_WALK,
                       SUBSURFACE_SKIN, TRANSLUCENT, TRANSPARENT, RAY_PORTAL, HAIR_CHIANG, HAIR_REFLECTION, HAIR_TRANSMISSION,
                       HAIR_HUANG)
from .microfacet import COS_EPS, F82_F5, F82_SCALE, ggx_d, ggx_lambda, ggx_reflect_terms, pow5

_NUMBA_TYPES = {np.dtype(np.int8): "int8", np.dtype(np.float64): "float64", np.dtype(np.bool_): "boolean"}


def array_type(dtype, ndim):
    """numba's name for a C-contiguous array type."""
    return _NUMBA_TYPES[np.dtype(dtype)] + "[" + ":, " * (ndim - 1) + "::1]"


# The per-ray lobe arrays the loops read (bsdf.Lobes without the legacy
# schlick flag), in the registry's parameter order, then back.  The loops
# unpack the first twelve by position and back as the last: a parameter
# appended to the registry needs no edit here.
LOBE_FIELDS = ((("kind", array_type(np.int8, 2), np.int8),)
               + tuple((p.field, array_type(p.dtype, 2 + len(p.tail)), p.dtype) for p in PARAMS)
               + (("back", array_type(np.bool_, 1), np.bool_),))
ANISOTROPY = [name for name, _, _ in LOBE_FIELDS].index("anisotropy")   # the glossy_anisotropic lobe's arrays
ROTATION = [name for name, _, _ in LOBE_FIELDS].index("rotation")
DIFFUSE_ROUGHNESS = [name for name, _, _ in LOBE_FIELDS].index("diffuse_roughness")   # oren_nayar's
ABSORPTION = [name for name, _, _ in LOBE_FIELDS].index("absorption")   # hair_chiang's
RADIAL_ROUGHNESS = [name for name, _, _ in LOBE_FIELDS].index("radial_roughness")
COAT = [name for name, _, _ in LOBE_FIELDS].index("coat")
OFFSET = [name for name, _, _ in LOBE_FIELDS].index("offset")
ASPECT_RATIO = [name for name, _, _ in LOBE_FIELDS].index("aspect_ratio")   # hair_huang's
HAIR_GAINS = [name for name, _, _ in LOBE_FIELDS].index("hair_gains")
FIBRE_AXIS = [name for name, _, _ in LOBE_FIELDS].index("fibre_axis")
PIXEL_COVERAGE = [name for name, _, _ in LOBE_FIELDS].index("pixel_coverage")
FILM_THICKNESS = [name for name, _, _ in LOBE_FIELDS].index("thin_film_thickness")   # thin films
FILM_IOR = [name for name, _, _ in LOBE_FIELDS].index("thin_film_ior")
# MaterialTable's arrays gathered per ray (bsdf.Lobes' fields up to back).
GATHER_FIELDS = (("kind", np.int8, ()), ("color", np.float64, (3,)), ("alpha", np.float64, ()),
                 ("schlick", np.bool_, ())) + tuple((p.field, p.dtype, p.tail) for p in EXTRA_PARAMS)
GATHER_DTYPES = (np.dtype(np.float64), np.dtype(np.int8), np.dtype(np.bool_))


def _gather_group(dtype):
    count = sum(np.dtype(d) == dtype for _, d, _ in GATHER_FIELDS)
    return f"UniTuple({array_type(dtype, 2)}, {count})"


GATHER_SIGNATURE = "void(int64[::1], " + ", ".join(
    f"{_gather_group(d)}, {_gather_group(d)}" for d in GATHER_DTYPES) + ")"
TABLES = (("ggx_E", "float64[:, ::1]"), ("ggx_Eavg", "float64[::1]"), ("ggx_glass_E", "float64[:, :, ::1]"),
          ("ggx_glass_inv_E", "float64[:, :, ::1]"), ("ggx_glass_Eavg", "float64[:, ::1]"),
          ("ggx_glass_inv_Eavg", "float64[:, ::1]"), ("ggx_gen_schlick_ior_s", "float64[:, :, ::1]"),
          ("sheen_ltc", "float64[:, :, ::1]"), ("thin_film_cmf", "float64[:, ::1]"))
LOBES_SIGNATURE = "Tuple((" + ", ".join(t for _, t, _ in LOBE_FIELDS) + "))"
TABLES_SIGNATURE = "Tuple((" + ", ".join(t for _, t in TABLES) + "))"

_HELPERS = []


def helper(fn):
    """A function the loops call, compiled as a function of its own (not
    inlined as kernels.helper: the loops call the larger ones from several
    places, and numba's inlining made them compile for minutes)."""
    _HELPERS.append(fn)
    return fn


def register(numba):
    """Make the helpers callable from compiled code (once, before the loops compile)."""
    from numba.extending import register_jitable
    while _HELPERS:
        register_jitable(_HELPERS.pop(0))


INV_PI = 1.0 / np.pi
TWO_PI = 2.0 * np.pi
FLT_MIN = 1.1754943508222875e-38
# engine/lobes/anisotropic's clamps: anisotropy up to 1/0.9 (the Glossy
# BSDF's range), the aspect's square at least MIN_ASPECT_SQ.
MAX_ANISOTROPY = 1.0 / 0.9
MIN_ASPECT_SQ = 1e-8

# ----------------------------------------------------------------------------
# Cycles' lookup_table_read_{1,2,3}D for one point (mf.lookup, same order)

@helper
def _axis(c, size):
    x = clip(c, 0.0, 1.0) * (size - 1)
    i = min(np.int64(x), size - 1)
    return i, min(i + 1, size - 1), x - i


@helper
def _lookup1(t, x):
    i0, i1, wx = _axis(x, t.shape[0])
    return 0.0 + (1.0 - wx) * t[i0] + wx * t[i1]


@helper
def _lookup2(t, x, y):
    i0, i1, wx = _axis(x, t.shape[1])
    j0, j1, wy = _axis(y, t.shape[0])
    out = 0.0 + (1.0 - wx) * (1.0 - wy) * t[j0, i0]
    out = out + wx * (1.0 - wy) * t[j0, i1]
    out = out + (1.0 - wx) * wy * t[j1, i0]
    return out + wx * wy * t[j1, i1]


@helper
def _lookup3(t, x, y, z):
    i0, i1, wx = _axis(x, t.shape[2])
    j0, j1, wy = _axis(y, t.shape[1])
    k0, k1, wz = _axis(z, t.shape[0])
    out = 0.0 + (1.0 - wx) * (1.0 - wy) * (1.0 - wz) * t[k0, j0, i0]
    out = out + wx * (1.0 - wy) * (1.0 - wz) * t[k0, j0, i1]
    out = out + (1.0 - wx) * wy * (1.0 - wz) * t[k0, j1, i0]
    out = out + wx * wy * (1.0 - wz) * t[k0, j1, i1]
    out = out + (1.0 - wx) * (1.0 - wy) * wz * t[k1, j0, i0]
    out = out + wx * (1.0 - wy) * wz * t[k1, j0, i1]
    out = out + (1.0 - wx) * wy * wz * t[k1, j1, i0]
    return out + wx * wy * wz * t[k1, j1, i1]


@helper
def _sheen_ltc(t, which, rough, mu):
    return _lookup2(t[which], mu, clip(rough, 1e-3, 1.0))


# ----------------------------------------------------------------------------
# Fresnel (engine/microfacet.py, one value)

@helper
def _fresnel_dielectric(cos_i, eta):
    c = np.abs(cos_i)
    t2 = eta * eta - (1.0 - c * c)
    if t2 <= 0:
        return 1.0, 0.0
    cos_t = np.sqrt(max(t2, 0.0)) / eta
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    f = 0.5 * (rs * rs + rp * rp)
    if not np.isfinite(f):
        f = 1.0
    return f, cos_t


@helper
def _f0_from_ior(ior):
    r = (ior - 1.0) / (ior + 1.0)
    return r * r


@helper
def _schlick_s(cos, ior):
    f, cos_t = _fresnel_dielectric(cos, ior)
    f0 = _f0_from_ior(ior)
    return clip((f - f0) / max(1.0 - f0, 1e-12), 0.0, 1.0), cos_t


@helper
def _ior_z(eta):
    return np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))


@helper
def _eta(ior, kind, back):
    """bsdf._eta: the IOR, inverted on back faces for refracting lobes."""
    ior = max(ior, 1e-5)
    if back and (kind == GLASS or kind == REFRACTION):
        return 1.0 / ior
    return ior


@helper
def _f82_b(f0, tint):
    schlick = f0 + (1.0 - f0) * F82_F5
    return schlick * F82_SCALE * (1.0 - tint)


@helper
def _fresnel_s(code, ior, cos):
    """The angular term of bsdf._fresnel shared by the channels: (1 - cos)^5
    (clamped) for Schlick and F82, the remapped real Fresnel for dielectric."""
    if code == F_DIELECTRIC:
        return _schlick_s(cos, max(ior, 1e-5))[0]
    return clip(1.0 - cos, 0.0, 1.0)


@helper
def _add_specular(f_0, f_1, f_2, w, code, ior, color, f0, tint, cos, spec):
    """f plus one Fresnel-weighted specular lobe (w, color, f0, tint: the
    lobe's RGB rows)."""
    s = _fresnel_s(code, ior, cos)
    return (f_0 + w[0] * (_fresnel(code, color[0], f0[0], tint[0], s, cos) * spec),
            f_1 + w[1] * (_fresnel(code, color[1], f0[1], tint[1], s, cos) * spec),
            f_2 + w[2] * (_fresnel(code, color[2], f0[2], tint[2], s, cos) * spec))


@helper
def _add_specular_film(f_0, f_1, f_2, w, code, ior, color, f0, tint, thickness, film_ior, cmf, cos, spec):
    """_add_specular, with the lobe's thin film where it has one."""
    if not _has_film(code, thickness):
        return _add_specular(f_0, f_1, f_2, w, code, ior, color, f0, tint, cos, spec)
    r0, r1, r2 = _film_rgb(cmf, code, cos, max(ior, 1e-5), f0, tint, thickness, film_ior)
    return f_0 + w[0] * (r0 * spec), f_1 + w[1] * (r1 * spec), f_2 + w[2] * (r2 * spec)


@helper
def _conductor(cos, n, k):
    """One channel of microfacet.conductor: the unpolarized Fresnel of a
    conductor n + i k at cos (n, k below 0 read as 0)."""
    c = clip(cos, 0.0, 1.0)
    n, k = max(n, 0.0), max(k, 0.0)
    c2 = c * c
    s2 = 1.0 - c2
    n2, k2 = n * n, k * k
    t0 = n2 - k2 - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * n2 * k2)
    a = np.sqrt(max(0.5 * (a2b2 + t0), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * a * c
    rs = (t1 - t2) / (t1 + t2) if t1 + t2 > 0 else 1.0
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4) if t3 + t4 > 0 else 1.0
    return clip(0.5 * (rp + rs), 0.0, 1.0)


@helper
def _conductor_fss(n, k):
    """One channel of microfacet.conductor_fss (Cycles' fresnel_conductor_Fss)."""
    f0 = _conductor(1.0, n, k)
    f82 = _conductor(1.0 / 7.0, n, k)
    b = F82_SCALE * ((f0 + (1.0 - f0) * F82_F5) - f82)
    return clip(f0 + (1.0 - f0) / 21.0 - b / 126.0, 0.0, 1.0)


@helper
def _fresnel(code, color, f0, tint, s, cos):
    """One channel of bsdf._fresnel given _fresnel_s's s (a conductor's n
    in f0, its k in tint)."""
    if code == F_CONDUCTOR:
        return _conductor(cos, f0, tint)
    if code == F_SCHLICK:
        return color + (1.0 - color) * pow5(s)
    if code == F_F82:
        b = _f82_b(f0, tint)
        s5 = pow5(s)
        return clip(f0 + (1.0 - f0) * s5 - b * cos * s5 * s, 0.0, 1.0)
    if code == F_DIELECTRIC:
        return f0 + (1.0 - f0) * s
    return 1.0


@helper
def _dielectric_refl(refraction, f0, s):
    return 0.0 if refraction else f0 + (1.0 - f0) * s


@helper
def _glass_refl(cmf, refraction, f0, s, cos, eta, ior, back, thickness, film_ior):
    """glass.dielectric's reflectance (RGB) given the remapped Fresnel s: a
    glass lobe's thin film over eta where it has one, its film IOR divided by
    the glass IOR on back faces (glass.film_ior_of)."""
    if refraction:
        return 0.0, 0.0, 0.0
    if thickness > FILM_CUTOFF:
        film = film_ior / max(ior, 1e-5) if back else film_ior
        return _film_rgb(cmf, F_DIELECTRIC, cos, eta, f0, f0, thickness, film)
    return f0[0] + (1.0 - f0[0]) * s, f0[1] + (1.0 - f0[1]) * s, f0[2] + (1.0 - f0[2]) * s


@helper
def _dielectric_trans(refraction, refl, tint, cos_t):
    return (1.0 if refraction else 1.0 - refl) * tint if cos_t > 0 else 0.0


# ----------------------------------------------------------------------------
# Thin-film iridescence (engine/thinfilm.py for one ray, in float64; the
# table is thinfilm.sensitivity_table: real R G B, imaginary R G B)

FILM_TABLE = 512
FILM_SCALE = 2.0 * np.pi


@helper
def _film_lookup(cmf, row, x):
    x = clip(x, 0.0, 1.0) * (FILM_TABLE - 1)
    i = min(np.int64(x), FILM_TABLE - 1)
    j = min(i + 1, FILM_TABLE - 1)
    t = x - i
    return (1.0 - t) * cmf[row, i] + t * cmf[row, j]


@helper
def _film_dielectric(cos_i, eta):
    """thinfilm.fresnel_dielectric_polarized: R_s, R_p, cos_t (negative),
    the phase signs of s and p."""
    t2 = eta * eta - (1.0 - cos_i * cos_i)
    if t2 <= 0:
        return 1.0, 1.0, 0.0, 1.0, 1.0
    c = np.abs(cos_i)
    cos_t = -np.sqrt(t2) / eta
    r_s = (c + eta * cos_t) / (c - eta * cos_t)
    r_p = (cos_t + eta * c) / (eta * c - cos_t)
    return r_s * r_s, r_p * r_p, cos_t, (1.0 if r_s >= 0 else -1.0), (1.0 if r_p >= 0 else -1.0)


@helper
def _film_f82(cos, f0, b):
    s = clip(1.0 - cos, 0.0, 1.0)
    s5 = (s * s) * (s * s) * s
    return clip(f0 + (1.0 - f0) * s5 - b * cos * s5 * s, 0.0, 1.0)


@helper
def _film_conductor(cosi, eta1, eta2, k2, f82):
    """thinfilm.fresnel_conductor_polarized: R_s, R_p (the F82 model's for
    both with f82 >= 0, the exact ones with f82 < 0) and the phasors of s
    and p (re, im)."""
    eta1_sq, eta2_sq, k2_sq = eta1 * eta1, eta2 * eta2, k2 * k2
    two_eta2_k2 = 2.0 * eta2 * k2
    t1 = eta2_sq - k2_sq - eta1_sq * (1.0 - cosi * cosi)
    t2 = np.sqrt(t1 * t1 + two_eta2_k2 * two_eta2_k2)
    u_sq = max(0.5 * (t2 + t1), 0.0)
    v_sq = max(0.5 * (t2 - t1), 0.0)
    u, v = np.sqrt(u_sq), np.sqrt(v_sq)
    if f82 >= 0.0:
        n = eta2 / eta1
        k_sq = (k2 / eta1) ** 2
        f0 = ((n - 1.0) ** 2 + k_sq) / ((n + 1.0) ** 2 + k_sq)
        b = F82_SCALE * ((f0 + (1.0 - f0) * F82_F5) - f82)
        r_s = r_p = _film_f82(cosi, f0, b)
    else:
        r_s = _ratio((eta1 * cosi - u) ** 2 + v_sq, (eta1 * cosi + u) ** 2 + v_sq)
        t3 = (eta2_sq - k2_sq) * cosi
        t4 = two_eta2_k2 * cosi
        r_p = _ratio((t3 - eta1 * u) ** 2 + (t4 - eta1 * v) ** 2, (t3 + eta1 * u) ** 2 + (t4 + eta1 * v) ** 2)
    re_s = -u_sq - v_sq + (eta1 * cosi) ** 2
    im_s = -2.0 * eta1 * cosi * v
    mag_s = np.sqrt(re_s * re_s + im_s * im_s)
    re_p = ((eta2_sq + k2_sq) * cosi) ** 2 - eta1_sq * (u_sq + v_sq)
    im_p = 2.0 * eta1 * cosi * (two_eta2_k2 * u - (eta2_sq - k2_sq) * v)
    mag_p = np.sqrt(re_p * re_p + im_p * im_p)
    if mag_s == 0:
        re_s, im_s = 1.0, 0.0
    else:
        re_s, im_s = re_s / mag_s, im_s / mag_s
    if mag_p == 0:
        re_p, im_p = 1.0, 0.0
    else:
        re_p, im_p = re_p / mag_p, im_p / mag_p
    return r_s, r_p, re_s, im_s, re_p, im_p


@helper
def _ratio(a, b):
    """thinfilm._safe_divide for one value."""
    return a / b if b != 0.0 else 0.0


@helper
def _film_airy(cmf, channel, r12, r23, opd, ph_re, ph_im):
    """thinfilm.airy_summation for one polarisation and channel."""
    t121 = 1.0 - r12
    r123 = r12 * r23
    sq = np.sqrt(r123)
    rs = t121 * t121 * r23 / (1.0 - r123)
    acc_re, acc_im = ph_re, ph_im
    out = rs + r12
    cm = rs - t121
    for m in range(1, 4):
        cm = cm * sq
        x = FILM_SCALE * (m * opd) / 60000.0
        s_re = _film_lookup(cmf, channel, x)
        s_im = _film_lookup(cmf, channel + 3, x)
        out = out + cm * 2.0 * (acc_re * s_re + acc_im * s_im)
        acc_re, acc_im = acc_re * ph_re - acc_im * ph_im, acc_re * ph_im + acc_im * ph_re
    return out


@helper
def _film_channel(cmf, channel, thickness, film_ior, sub_n, sub_k, cos1, conductive, f82):
    """thinfilm.fresnel_iridescence's reflectance (ambient IOR 1)."""
    if thickness < 1.0:
        t = clip(thickness, 0.0, 1.0)
        film_ior = 1.0 + (film_ior - 1.0) * (t * t * (3.0 - 2.0 * t))
    r12s, r12p, cos2, ph12s, ph12p = _film_dielectric(cos1, film_ior)
    if r12s == 1.0 and r12p == 1.0:
        return 1.0
    if conductive:
        r23s, r23p, re_s, im_s, re_p, im_p = _film_conductor(-cos2, film_ior, sub_n, sub_k, f82)
    else:
        r23s, r23p, _, c23s, c23p = _film_dielectric(-cos2, sub_n / film_ior)
        if r23s == 1.0 and r23p == 1.0:
            return 1.0
        re_s, im_s, re_p, im_p = c23s, 0.0, c23p, 0.0
    opd = -2.0 * film_ior * thickness * cos2
    r_s = _film_airy(cmf, channel, r12s, r23s, opd, re_s * -ph12s, im_s * -ph12s)
    r_p = _film_airy(cmf, channel, r12p, r23p, opd, re_p * -ph12p, im_p * -ph12p)
    r = 0.5 * (r_s + r_p)
    if not r == r:
        return 0.0
    return clip(r, 0.0, 1.0)


@helper
def _film_metal(cmf, c, cos, f0, tint, thickness, film_ior):
    """One channel of thinfilm.f82_conductor (F0, edge tint of the F82 lobe)."""
    f0 = clip(f0, 0.0, 1.0)
    b = _f82_b(f0, tint)
    r = min(f0, 0.999)
    g = _film_f82(1.0 / 7.0, f0, b)
    sr = np.sqrt(r)
    n = (1.0 + sr) / (1.0 - sr)
    n = n + ((1.0 - r) / (1.0 + r) - n) * g
    k = np.sqrt(max((r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (1.0 - r), 0.0))
    return _film_channel(cmf, c, thickness, film_ior, n, k, cos, True, g)


@helper
def _film_rgb(cmf, code, cos, ior, f0, tint, thickness, film_ior):
    """ggx.film_fresnel for one ray: the RGB reflectance of the film over
    an F82 metal or over a dielectric of IOR ``ior`` scaled towards f0 /
    F0(ior) (f0, tint: the lobe's RGB rows)."""
    cos = clip(cos, -1.0, 1.0)
    if code == F_CONDUCTOR:   # its own n (f0), k (tint): exact Fresnel under the film
        return (_film_channel(cmf, 0, thickness, film_ior, max(f0[0], 0.0), max(tint[0], 0.0), cos, True, -1.0),
                _film_channel(cmf, 1, thickness, film_ior, max(f0[1], 0.0), max(tint[1], 0.0), cos, True, -1.0),
                _film_channel(cmf, 2, thickness, film_ior, max(f0[2], 0.0), max(tint[2], 0.0), cos, True, -1.0))
    if code == F_F82:
        return (_film_metal(cmf, 0, cos, f0[0], tint[0], thickness, film_ior),
                _film_metal(cmf, 1, cos, f0[1], tint[1], thickness, film_ior),
                _film_metal(cmf, 2, cos, f0[2], tint[2], thickness, film_ior))
    r0 = _film_channel(cmf, 0, thickness, film_ior, ior, 0.0, cos, False, 0.0)
    r1 = _film_channel(cmf, 1, thickness, film_ior, ior, 0.0, cos, False, 0.0)
    r2 = _film_channel(cmf, 2, thickness, film_ior, ior, 0.0, cos, False, 0.0)
    f0_real = _f0_from_ior(ior)
    if f0_real > 1e-5 and not (r0 == 1.0 and r1 == 1.0 and r2 == 1.0):
        r0 = _film_scale(r0, f0[0], f0_real)
        r1 = _film_scale(r1, f0[1], f0_real)
        r2 = _film_scale(r2, f0[2], f0_real)
    return r0, r1, r2


@helper
def _film_scale(f, f0, f0_real):
    """thinfilm.principled_dielectric's F0 scaling of one channel."""
    s = clip((f - 1.0) / (f0_real - 1.0), 0.0, 1.0)
    factor = clip(f0, 0.0, 1.0) / f0_real
    return clip(f * (1.0 + (factor - 1.0) * s), 0.0, 1.0)


@helper
def _has_film(code, thickness):
    """The F82, conductor and dielectric Fresnel modes take a film thicker than the cutoff."""
    return thickness > FILM_CUTOFF and (code == F_F82 or code == F_DIELECTRIC or code == F_CONDUCTOR)


@helper
def _fresnel_rgb(cmf, code, ior, color, f0, tint, thickness, film_ior, cos):
    """bsdf._fresnel for one ray, every channel (a thin film where it has one)."""
    if _has_film(code, thickness):
        return _film_rgb(cmf, code, cos, max(ior, 1e-5), f0, tint, thickness, film_ior)
    s = _fresnel_s(code, ior, cos)
    return (_fresnel(code, color[0], f0[0], tint[0], s, cos), _fresnel(code, color[1], f0[1], tint[1], s, cos),
            _fresnel(code, color[2], f0[2], tint[2], s, cos))


# ----------------------------------------------------------------------------
# weights (bsdf.weights)

@helper
def _glossy_fss(code, color, f0, tint, ior):
    """One channel of bsdf._glossy_fss."""
    if code == F_SCHLICK:
        return f0 + (1.0 - f0) / 21.0
    if code == F_F82:
        return f0 + (1.0 - f0) / 21.0 - _f82_b(f0, tint) / 126.0
    if code == F_CONDUCTOR:
        return _conductor_fss(f0, tint)
    if code == F_DIELECTRIC:
        ior = max(ior, 1e-5)
        f0_real = _f0_from_ior(ior)
        if ior < 1.0:
            fss = 0.997118 + ior * (0.1014 - ior * (0.965241 + ior * 0.130607))
        else:
            fss = (ior - 1.0) / (4.08567 + 1.00071 * ior)
        s = clip((fss - f0_real) / max(1.0 - f0_real, 1e-12), 0.0, 1.0)
        return f0 + (1.0 - f0) * s
    return color


@helper
def _energy_tables(glass, eta, rough, mu, t_e, t_eavg, t_ge, t_gie, t_geavg, t_gieavg):
    """E(mu) and E_avg of bsdf._energy (clamped E)."""
    if glass:
        if eta < 1.0:
            z = _ior_z(1.0 / eta)
            e = _lookup3(t_gie, rough, mu, z)
            e_avg = _lookup2(t_gieavg, rough, z)
        else:
            z = _ior_z(eta)
            e = _lookup3(t_ge, rough, mu, z)
            e_avg = _lookup2(t_geavg, rough, z)
    else:
        e = _lookup2(t_e, rough, mu)
        e_avg = _lookup1(t_eavg, rough)
    return max(e, 1e-4), e_avg


@helper
def _energy(fss, e, e_avg):
    """One channel of bsdf._energy: the multiscatter factor and the darkening alone."""
    missing = (1.0 - e) / e
    fms = fss * e_avg / max(1.0 - fss * (1.0 - e_avg), 1e-12)
    factor = 1.0 + fms * missing
    return factor, factor / (1.0 + missing)


def weights_loop(lobes, tables, wo, out):
    """bsdf.weights into out (N, K, 3)."""
    kind, color, alpha, fresnel, ior, f0, edge, trans_tint, multiscatter, covers, absorb, weight = lobes[:12]
    back = lobes[-1]
    t_e, t_eavg, t_ge, t_gie, t_geavg, t_gieavg, t_s, t_sheen, cmf = tables
    n, kk = kind.shape
    energy = np.empty((2, 3))   # the multiscatter factor and darkening of one lobe, per channel
    for i in range(n):
        mu = clip(wo[i, 2], 0.0, 1.0)
        for k in range(kk):
            for c in range(3):
                out[i, k, c] = weight[i, k] if fresnel[i, k] == F_SCHLICK else color[i, k, c] * weight[i, k]
        for k in range(kk):
            kd = kind[i, k]
            rough = np.sqrt(alpha[i, k])
            if kd == SHEEN:
                albedo = _sheen_ltc(t_sheen, 2, rough, mu)
                for c in range(3):
                    out[i, k, c] *= albedo
            # Multiscatter GGX (bsdf._energy): scales the lobe, darkens a layer's albedo.
            ms = multiscatter[i, k] and kd != SHEEN and (kd == GLOSSY or kd == GLOSSY_ANISOTROPIC or kd == GLASS
                                                         or covers[i, k] > 0)
            if ms:
                glass = kd == GLASS
                e, e_avg = _energy_tables(glass, _eta(ior[i, k], kd, back[i]), rough, mu,
                                          t_e, t_eavg, t_ge, t_gie, t_geavg, t_gieavg)
                for c in range(3):
                    if glass:
                        fss = color[i, k, c] * trans_tint[i, k, c]
                    else:
                        fss = _glossy_fss(fresnel[i, k], color[i, k, c], f0[i, k, c], edge[i, k, c], ior[i, k])
                    energy[0, c], energy[1, c] = _energy(fss, e, e_avg)
                if kd == GLOSSY or kd == GLOSSY_ANISOTROPIC or glass:
                    for c in range(3):
                        out[i, k, c] *= energy[0, c]
            if covers[i, k] <= 0:
                continue
            # The layer's albedo (bsdf._layer_albedo), its largest channel.
            film = kd != SHEEN and fresnel[i, k] == F_DIELECTRIC and lobes[FILM_THICKNESS][i, k] > FILM_CUTOFF
            e0 = e1 = e2 = 0.0
            if kd == SHEEN:
                albedo = _sheen_ltc(t_sheen, 2, rough, mu)
            elif film:
                # No table under a thin film: its reflectance at the view angle (Cycles).
                e0, e1, e2 = _film_rgb(cmf, F_DIELECTRIC, mu, max(ior[i, k], 1e-5), f0[i, k], edge[i, k],
                                       lobes[FILM_THICKNESS][i, k], lobes[FILM_IOR][i, k])
            else:
                s = _lookup3(t_s, rough, mu, _ior_z(max(ior[i, k], 1e-5)))
            a = 0.0
            for c in range(3):
                if kd == SHEEN:
                    layer = color[i, k, c] * albedo
                else:
                    if film:
                        est = e0 if c == 0 else (e1 if c == 1 else e2)
                    else:
                        est = f0[i, k, c] + (1.0 - f0[i, k, c]) * s
                    if ms:
                        est = est * energy[1, c]
                    layer = color[i, k, c] * est
                a = layer if c == 0 else max(a, layer)
            below = 1.0 - clip(a, 0.0, 1.0)
            # The coat's tint along the refracted view ray (bsdf._coat_absorption).
            eta = max(ior[i, k], 1.0)
            cos_t = np.sqrt(max(1.0 - (1.0 - mu * mu) / (eta * eta), 1e-12))
            mean = (color[i, k, 0] + color[i, k, 1] + color[i, k, 2]) / 3.0
            for c in range(3):
                tint = max(absorb[i, k, c], 0.0)
                if tint != 1.0:   # pow(1, y) = 1: an untinted coat skips the pow
                    tint = tint ** (1.0 / cos_t)
                tint = 1.0 + mean * (tint - 1.0)
                for j in range(k + 1, min(kk, k + 1 + covers[i, k])):
                    out[i, j, c] = out[i, j, c] * below * tint
        for k in range(kk):
            for c in range(3):
                out[i, k, c] = max(out[i, k, c], 0.0)


# ----------------------------------------------------------------------------
# selection (bsdf.selection)

@helper
def _luminance(r, g, b):
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def selection_loop(lobes, tables, wo, w, out):
    """bsdf.selection into out (N, K)."""
    kind, color, fresnel, ior, f0, edge = lobes[0], lobes[1], lobes[3], lobes[4], lobes[5], lobes[6]
    thickness, film_ior = lobes[FILM_THICKNESS], lobes[FILM_IOR]
    cmf = tables[8]
    n, kk = kind.shape
    for i in range(n):
        cos_o = clip(wo[i, 2], 0.0, 1.0)
        total = 0.0
        for k in range(kk):
            code = fresnel[i, k]
            if code == F_SCHLICK:
                s5 = pow5(clip(1.0 - cos_o, 0.0, 1.0))
                r = (color[i, k, 0] + (1.0 - color[i, k, 0]) * s5) * w[i, k, 0]
                g = (color[i, k, 1] + (1.0 - color[i, k, 1]) * s5) * w[i, k, 1]
                b = (color[i, k, 2] + (1.0 - color[i, k, 2]) * s5) * w[i, k, 2]
                lum = (r + g + b) / 3.0   # Cycles' sample weight: average(weight) (bsdf._selection_numpy)
            else:
                lum = (w[i, k, 0] + w[i, k, 1] + w[i, k, 2]) / 3.0
            guess = 1.0
            if kind[i, k] == NONE:
                guess = 0.0
            elif kind[i, k] == GLOSSY and _has_film(code, thickness[i, k]):
                r0, r1, r2 = _film_rgb(cmf, code, cos_o, max(ior[i, k], 1e-5), f0[i, k], edge[i, k],
                                       thickness[i, k], film_ior[i, k])
                guess = _luminance(r0, r1, r2)
            elif kind[i, k] == GLOSSY and code == F_CONDUCTOR:   # exact Fresnel at the view angle
                guess = _luminance(_conductor(cos_o, f0[i, k, 0], edge[i, k, 0]),
                                   _conductor(cos_o, f0[i, k, 1], edge[i, k, 1]),
                                   _conductor(cos_o, f0[i, k, 2], edge[i, k, 2]))
            elif kind[i, k] == GLOSSY and code != F_SCHLICK and code != F_NONE:
                f0l = _luminance(f0[i, k, 0], f0[i, k, 1], f0[i, k, 2])
                guess = f0l + (1.0 - f0l) * pow5(1.0 - cos_o)
            s = max(lum * guess, 0.0)
            out[i, k] = s
            total = s if k == 0 else total + s
        for k in range(kk):
            out[i, k] = out[i, k] / total if total > 0 else 0.0


# ----------------------------------------------------------------------------
# eval_pdf (bsdf.eval_pdf)

@helper
def _eval_sheen(t_sheen, rough, wox, woy, woz, wix, wiy, wiz):
    """bsdf._eval_sheen: f (one value for all channels) and pdf."""
    mu = clip(woz, 0.0, 1.0)
    a = _sheen_ltc(t_sheen, 0, rough, mu)
    b = _sheen_ltc(t_sheen, 1, rough, mu)
    length = np.sqrt(wox * wox + woy * woy + 0.0 * 0.0)
    if length < 1e-7:
        tx, ty = 1.0, 0.0
    else:
        tx, ty = wox / length, woy / length
    x = wix * tx + wiy * ty + wiz * 0.0
    y = wix * -ty + wiy * tx + wiz * 0.0
    z = wiz
    p = a * x + b * z
    q = a * y
    len_sq = p * p + q * q + z * z
    r = a / len_sq
    val = INV_PI * (r * r)
    if not ((z > COS_EPS) and (woz > COS_EPS) and (np.abs(a) >= 1e-5) and np.isfinite(val)):
        val = 0.0
    return val, val * max(z, 0.0)


@helper
def _refraction(alpha, eta, wox, woy, woz, wix, wiy, wiz):
    """The refraction half of bsdf._eval_glass: D G / ... (what multiplies
    the transmittance in f), the pdf's common factor and |cos(wo, h)|.
    Pairs no microfacet refracts between are scored too, as Cycles'
    bsdf_microfacet_eval (engine/lobes/glass.py: unjoined)."""
    hx = -(eta * wix + wox)
    hy = -(eta * wiy + woy)
    hz = -(eta * wiz + woz)
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    scale = (-1.0 if hz < 0 else 1.0) / (length if length > 0 else 1.0)
    hx, hy, hz = hx * scale, hy * scale, hz * scale
    c_o = wox * hx + woy * hy + woz * hz
    c_i = wix * hx + wiy * hy + wiz * hz
    if not length > 0:
        return 0.0, 0.0, c_o, 0.0
    lo = ggx_lambda(woz, alpha)
    li = ggx_lambda(wiz, alpha)
    q = eta / length
    common = ggx_d(hz, alpha) / max(woz, COS_EPS) * (q * q) * np.abs(c_o * c_i)
    return common / ((1.0 + lo + li) * -wiz), common, np.abs(c_o), 1.0 + lo


@helper
def _aniso_alphas(alpha, anisotropy):
    """engine/lobes/anisotropic.alphas for one lobe."""
    aspect = np.sqrt(max(1.0 - clip(anisotropy, 0.0, MAX_ANISOTROPY) * 0.9, MIN_ASPECT_SQ))
    return max(alpha / aspect, MIN_ALPHA), max(alpha * aspect, MIN_ALPHA)


@helper
def _turn(rotation):
    """cos and sin of the tangent's rotation (engine/lobes/anisotropic.turn)."""
    angle = TWO_PI * (rotation - np.floor(rotation))
    return np.cos(angle), np.sin(angle)


@helper
def _g_oren_nayar(c):
    """engine/lobes/oren_nayar.g_term for one cosine."""
    if c < 1e-6:
        return (0.5 * np.pi - 2.0 / 3.0) - c
    s = np.sqrt(max(1.0 - c * c, 0.0))
    theta = np.arccos(min(c, 1.0))
    return s * (theta - 2.0 / 3.0 - s * c) + 2.0 / 3.0 * (s / c) * (1.0 - s * s * s)


@helper
def _oren_nayar_ms(rho, e_avg, factor):
    """One channel of oren_nayar.multiscatter times (1 - E(wi)): Ems x factor."""
    rho = clip(rho, 0.0, 1.0)
    return INV_PI * rho * rho * (e_avg / (1.0 - e_avg)) / (1.0 - rho * (1.0 - e_avg)) * factor


@helper
def _oren_nayar(sigma, wox, woy, woz, wix, wiy, wiz):
    """engine/lobes/oren_nayar.eval_f's shared part: the single-scattering
    value, E_avg and (1 - E(wo)) (1 - E(wi)); b = 0 is Lambert."""
    sigma = clip(sigma, 0.0, 1.0)
    a = 1.0 / (np.pi + sigma * (0.5 * np.pi - 2.0 / 3.0))
    b = sigma * a
    if not b > 0.0:
        return INV_PI, 0.5, 0.0
    nl = max(wiz, 0.0)
    nv = max(woz, 0.0)
    t = (wix * wox + wiy * woy + wiz * woz) - nl * nv
    if t > 0.0:
        t = t / (max(nl, nv) + FLT_MIN)
    e_avg = a * np.pi + ((2.0 * np.pi - 5.6) / 3.0) * b
    e_o = a * np.pi + b * _g_oren_nayar(nv)
    e_l = a * np.pi + b * _g_oren_nayar(nl)
    return a + b * t, e_avg, (1.0 - e_o) * (1.0 - e_l)


@helper
def _ggx_aniso(ax, ay, wox, woy, woz, wix, wiy, wiz):
    """engine/lobes/anisotropic.eval_f without the Fresnel: D G2 / (4 cos_o
    cos_i), the VNDF pdf and cos(wo, h)."""
    hx, hy, hz = wox + wix, woy + wiy, woz + wiz
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / length, hy / length, hz / length
    x, y = hx / ax, hy / ay
    q = x * x + y * y + hz * hz
    d = 1.0 / (np.pi * ax * ay * q * q)
    lo = 0.5 * (np.sqrt(1.0 + (ax * ax * wox * wox + ay * ay * woy * woy) / (woz * woz)) - 1.0)
    li = 0.5 * (np.sqrt(1.0 + (ax * ax * wix * wix + ay * ay * wiy * wiy) / (wiz * wiz)) - 1.0)
    spec = d / ((1.0 + lo + li) * 4.0 * woz * wiz)
    return spec, d / ((1.0 + lo) * 4.0 * woz), wox * hx + woy * hy + woz * hz


# ----------------------------------------------------------------------------
# hair_chiang (engine/lobes/hair.py for one ray)

SQRT_PI_8 = np.sqrt(np.pi / 8.0)
I0_TERMS = 24   # as engine/lobes/hair.py
LN_2PI = np.log(2.0 * np.pi)


@helper
def _cos_from_sin(s):
    return np.sqrt(max(1.0 - s * s, 0.0))


@helper
def _hair_variance(r):
    r = clip(r, 0.001, 1.0)
    a = 0.726 * r + 0.812 * r * r + 3.7 * r ** 20
    return a * a


@helper
def _bessel_i0(x):
    x = x * x
    val = 1.0 + 0.25 * x
    pw = x * x
    fac = 1.0
    p4 = 16.0
    for i in range(2, I0_TERMS):
        fac *= i * i
        val = val + pw / (p4 * fac)
        pw = pw * x
        p4 *= 4.0
    return val


@helper
def _hair_mp(sin_i, cos_i, sin_o, cos_o, v):
    inv_v = 1.0 / v
    cos_arg = cos_i * cos_o * inv_v
    sin_arg = sin_i * sin_o * inv_v
    if v <= 0.1:
        if cos_arg > 12.0:   # hair.log_bessel_i0's asymptotic form
            inv = 1.0 / cos_arg
            i0 = (cos_arg - 0.5 * (LN_2PI + np.log(cos_arg))
                  + np.log1p(inv * (0.125 + inv * (9.0 / 128.0 + inv * (225.0 / 3072.0)))))
        else:
            i0 = np.log(_bessel_i0(cos_arg))
        return np.exp(i0 - sin_arg - inv_v + 0.6931 + np.log(0.5 * inv_v))
    return np.exp(-sin_arg) * _bessel_i0(cos_arg) / (np.sinh(inv_v) * 2.0 * v)


@helper
def _logistic_cdf(x, s):
    arg = -x / s
    if arg > 88.0:
        return 0.0
    return 1.0 / (1.0 + np.exp(arg))


@helper
def _hair_np(phi, p, s, gamma_o, gamma_t):
    a = phi - (2.0 * p * gamma_t - 2.0 * gamma_o + p * np.pi)
    a = (a + np.pi) - 2.0 * np.pi * np.floor((a + np.pi) / (2.0 * np.pi)) - np.pi
    e = np.exp(-np.abs(a) / s)
    scale = 1.0 - 2.0 * _logistic_cdf(-np.pi, s)
    return e / (s * (1.0 + e) * (1.0 + e)) / scale if scale > 0 else 0.0


@helper
def _fresnel_dielectric_cos(cos, eta):
    c = np.abs(cos)
    g = eta * eta - 1.0 + c * c
    if g <= 0:
        return 1.0
    g = np.sqrt(g)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


@helper
def _hair_fibre(lobes, i, k, wox, woy, woz, ap, energy, tilt):
    """hair.Fibre for one ray: fills ap (4, 3), energy (4,), tilt (3, 2);
    returns (v, s, m0, sin_o, cos_o, phi_o, gamma_o, gamma_t)."""
    alpha = lobes[2]
    ior = lobes[4]
    r = np.sqrt(alpha[i, k])
    radial = lobes[RADIAL_ROUGHNESS][i, k]
    v = _hair_variance(r)
    sr = clip(radial, 0.001, 1.0)
    s = (0.265 * sr + 1.194 * sr * sr + 5.372 * sr ** 22) * SQRT_PI_8
    m0 = _hair_variance(clip((1.0 - clip(lobes[COAT][i, k], 0.0, 1.0)) * clip(r, 0.001, 1.0), 0.001, 1.0))
    tilt_angle = -lobes[OFFSET][i, k]
    eta = max(ior[i, k], 1e-5)
    sin_o = clip(wox, -1.0, 1.0)
    cos_o = _cos_from_sin(sin_o)
    phi_o = np.arctan2(woz, woy)
    yz = np.sqrt(woy * woy + woz * woz)
    h = clip(-woy / yz, -1.0, 1.0) if yz > 0 else 0.0
    gamma_o = np.arcsin(h)
    cos_gamma_o = _cos_from_sin(h)
    cos_t = _cos_from_sin(sin_o / eta)
    sin_gt = h * cos_o / np.sqrt(max(eta * eta - sin_o * sin_o, 1e-30))
    gamma_t = np.arcsin(clip(sin_gt, -1.0, 1.0))
    cos_gt = _cos_from_sin(sin_gt)
    f = _fresnel_dielectric_cos(cos_o * cos_gamma_o, eta)
    total = 0.0
    for c in range(3):
        t = np.exp(-max(lobes[ABSORPTION][i, k, c], 0.0) * (2.0 * cos_gt / max(cos_t, 1e-30)))
        ap[0, c] = f
        col = (1.0 - f) * (1.0 - f) * t
        ap[1, c] = col
        col = col * t * f
        ap[2, c] = col
        tf = t * f
        ap[3, c] = col * (tf / (1.0 - tf) if tf < 1.0 else 0.0)
    for p in range(4):
        energy[p] = _luminance(ap[p, 0], ap[p, 1], ap[p, 2])
        total += energy[p]
    for p in range(4):
        energy[p] = energy[p] / total if total > 0 else 0.0
    s1 = np.sin(tilt_angle)
    c1 = _cos_from_sin(s1)
    s2 = 2.0 * s1 * c1
    c2 = c1 * c1 - s1 * s1
    s4 = 2.0 * s2 * c2
    c4 = c2 * c2 - s2 * s2
    tilt[0, 0], tilt[0, 1] = sin_o * c2 - cos_o * s2, np.abs(cos_o * c2 + sin_o * s2)
    tilt[1, 0], tilt[1, 1] = sin_o * c1 + cos_o * s1, np.abs(cos_o * c1 - sin_o * s1)
    tilt[2, 0], tilt[2, 1] = sin_o * c4 + cos_o * s4, np.abs(cos_o * c4 - sin_o * s4)
    return v, s, m0, sin_o, cos_o, phi_o, gamma_o, gamma_t


@helper
def _hair_eval(lobes, i, k, wox, woy, woz, wix, wiy, wiz, ap, energy, tilt):
    """hair.eval_hair_f for one ray: (f_0, f_1, f_2, pdf), f without the weight."""
    v, s, m0, sin_o, cos_o, phi_o, gamma_o, gamma_t = _hair_fibre(lobes, i, k, wox, woy, woz, ap, energy, tilt)
    sin_i = clip(wix, -1.0, 1.0)
    cos_i = _cos_from_sin(sin_i)
    phi = np.arctan2(wiz, wiy) - phi_o
    f_0 = f_1 = f_2 = e = 0.0
    for p in range(3):
        vp = m0 if p == 0 else (0.25 * v if p == 1 else 4.0 * v)
        mn = _hair_mp(sin_i, cos_i, tilt[p, 0], tilt[p, 1], vp) * _hair_np(phi, p, s, gamma_o, gamma_t)
        f_0 += ap[p, 0] * mn
        f_1 += ap[p, 1] * mn
        f_2 += ap[p, 2] * mn
        e += energy[p] * mn
    m = _hair_mp(sin_i, cos_i, sin_o, cos_o, 4.0 * v) / (2.0 * np.pi)
    f_0 += ap[3, 0] * m
    f_1 += ap[3, 1] * m
    f_2 += ap[3, 2] * m
    e += energy[3] * m
    cos = np.abs(wiz)
    if not cos > 1e-12 or not (np.isfinite(f_0) and np.isfinite(f_1) and np.isfinite(f_2) and np.isfinite(e)):
        return 0.0, 0.0, 0.0, 0.0
    return f_0 / cos, f_1 / cos, f_2 / cos, e


@helper
def _hair_sample(lobes, i, k, wox, woy, woz, u_lobe, u1, u2, ap, energy, tilt):
    """hair.sample_hair_dir for one ray."""
    v, s, m0, sin_o, cos_o, phi_o, gamma_o, gamma_t = _hair_fibre(lobes, i, k, wox, woy, woz, ap, energy, tilt)
    z = u_lobe
    p = 0
    while p < 3:
        if z < energy[p]:
            break
        z -= energy[p]
        p += 1
    if energy[p] > 0:
        z = z / energy[p]
    if p == 1:
        v = v * 0.25
    elif p >= 2:
        v = v * 4.0
    so, co = sin_o, cos_o
    if p < 3:
        so, co = tilt[p, 0], tilt[p, 1]
    z = max(z, 1e-5)
    fac = 1.0 + v * np.log(z + (1.0 - z) * np.exp(-2.0 / v))
    sin_i = -fac * so + _cos_from_sin(fac) * np.cos(TWO_PI * u2) * co
    cos_i = _cos_from_sin(sin_i)
    if p < 3:
        c = _logistic_cdf(-np.pi, s)
        d = u1 * (1.0 - 2.0 * c) + c
        x = -s * np.log(1.0 / d - 1.0) if d > 0 else -np.pi
        phi = 2.0 * p * gamma_t - 2.0 * gamma_o + p * np.pi + clip(x, -np.pi, np.pi)
    else:
        phi = TWO_PI * u1
    phi_i = phi_o + phi
    return sin_i, cos_i * np.cos(phi_i), cos_i * np.sin(phi_i)


# ----------------------------------------------------------------------------
# hair_reflection / hair_transmission (engine/lobes/hair_bsdf.py for one ray)

HALF_PI = 0.5 * np.pi
HAIR_POLE = 1e-3   # as hair_bsdf.POLE


@helper
def _hair_bsdf_view(alpha, radial, offset, wox, woy, woz):
    """hair_bsdf.View: (r1, r2, offset, theta_r, ly, lz, a, b, ok)."""
    r1 = clip(np.sqrt(alpha) if alpha > 0 else 0.0, 0.001, 1.0)
    r2 = clip(radial if radial > 0 else 0.0, 0.001, 1.0)
    off = -offset if np.isfinite(offset) else 0.0
    theta_r = np.arcsin(clip(wox, -1.0, 1.0))
    yz = np.hypot(woy, woz)
    ok = yz > 1e-12
    ly, lz = (woy / yz, woz / yz) if ok else (woy, woz)
    b = np.arctan(((-HALF_PI + theta_r) * 0.5 - off) / r1)
    a = np.arctan(((HALF_PI + theta_r) * 0.5 - off) / r1)
    return r1, r2, off, theta_r, ly, lz, a, b, ok


@helper
def _hair_theta_pdf(r1, off, theta_r, a, b, theta_i):
    t = (theta_i + theta_r) * 0.5 - off
    d = 2.0 * (t * t + r1 * r1) * (a - b) * np.cos(theta_i)
    return r1 / d if d != 0.0 else np.inf


@helper
def _hair_phi_pdf(transmission, r2, phi):
    """Cycles' reported azimuthal pdf: phi the reflection's scaled azimuth,
    or the transmission's p = azimuth - pi."""
    if transmission:
        c = 2.0 * np.arctan(HALF_PI / r2)
        return r2 / (c * (phi * phi + r2 * r2))
    return np.cos(phi * 0.5) * 0.25 / r2


@helper
def _hair_bsdf_result(pdf, wiz, ok):
    """(f, pdf): f = pdf / |cos|, both 0 where rejected or not finite."""
    cos = np.abs(wiz)
    if not (ok and cos > 1e-12 and np.isfinite(pdf) and pdf > 0):
        return 0.0, 0.0
    f = pdf / cos
    if not np.isfinite(f):
        return 0.0, 0.0
    return f, pdf


@helper
def _hair_bsdf_eval(transmission, alpha, radial, offset, wox, woy, woz, wix, wiy, wiz):
    """hair_bsdf.eval_hair_bsdf_f for one ray."""
    r1, r2, off, theta_r, ly, lz, a, b, ok = _hair_bsdf_view(alpha, radial, offset, wox, woy, woz)
    theta_i = np.arcsin(clip(wix, -1.0, 1.0))
    yz = np.hypot(wiy, wiz)
    cos_phi = clip((wiy * ly + wiz * lz) / yz, -1.0, 1.0) if yz > 0 else 1.0
    ok = ok and yz > 0 and HALF_PI - np.abs(theta_i) >= HAIR_POLE
    if transmission:
        ok = ok and wiz < 0.0
        phi = np.pi - np.arccos(cos_phi)
    else:
        ok = ok and wiz >= 0.0 and cos_phi >= 0.0
        phi = min(np.arccos(cos_phi) / r2, np.pi)
    if not ok:
        return 0.0, 0.0
    pdf = _hair_phi_pdf(transmission, r2, phi) * _hair_theta_pdf(r1, off, theta_r, a, b, theta_i)
    return _hair_bsdf_result(pdf, wiz, ok)


@helper
def _hair_bsdf_sample(transmission, alpha, radial, offset, wox, woy, woz, u1, u2):
    """hair_bsdf.sample_hair_bsdf_dir for one ray: (x, y, z, f, pdf)."""
    r1, r2, off, theta_r, ly, lz, a, b, ok = _hair_bsdf_view(alpha, radial, offset, wox, woy, woz)
    t = r1 * np.tan(u1 * (a - b) + b)
    theta_i = 2.0 * (t + off) - theta_r
    if transmission:
        p = r2 * np.tan(2.0 * np.arctan(HALF_PI / r2) * (u2 - 0.5))
        phi = p + np.pi
        phi_pdf = _hair_phi_pdf(True, r2, p)
    else:
        phi = 2.0 * np.arcsin(1.0 - 2.0 * u2) * r2
        phi_pdf = _hair_phi_pdf(False, r2, phi)
    c = np.cos(theta_i)
    cp, sp = np.cos(phi) * c, np.sin(phi) * c
    x, y, z = np.sin(theta_i), cp * ly - sp * lz, cp * lz + sp * ly
    ok = ok and HALF_PI - np.abs(theta_i) >= HAIR_POLE and np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
    f, pdf = _hair_bsdf_result(np.abs(phi_pdf * _hair_theta_pdf(r1, off, theta_r, a, b, theta_i)), z, ok)
    if pdf == 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    return x, y, z, f, pdf


# ----------------------------------------------------------------------------
# hair_huang (engine/lobes/hair_huang.py): Cycles' bsdf_principled_hair_huang.h
# for one ray, in Cycles' local frame (X the major axis or the normal to the
# view, Y the fibre's tangent, Z = X x Y); "wi" is the view and "wo" the light
# as Cycles names them.  These are the only source: the registry's NumPy
# kernels call them row by row.

LCG_MASK = 0xFFFFFFFF


@helper
def _lcg(state):
    """Cycles' lcg_step_float: (next state, float in [0, 1])."""
    state = (1103515245 * state + 12345) & LCG_MASK
    return state, state * (1.0 / 4294967295.0)


@helper
def _lcg_seed(a, b, c):
    """A state from three floats (directions or random numbers): Ember's
    stand-in for Cycles' per-shading-point lcg_state."""
    a = a if np.isfinite(a) else 0.0
    b = b if np.isfinite(b) else 0.0
    c = c if np.isfinite(c) else 0.0
    s = (np.int64(a * 2147483647.0) * 73856093) ^ (np.int64(b * 2147483647.0) * 19349663)
    s = (s ^ (np.int64(c * 2147483647.0) * 83492791)) & LCG_MASK
    for _ in range(3):
        s = (1103515245 * s + 12345) & LCG_MASK
    return s


@helper
def _huang_lambda(alpha2, cos_n):
    c2 = cos_n * cos_n
    if c2 <= 0.0:
        return np.inf
    return 0.5 * (np.sqrt(1.0 + alpha2 * max(1.0 / c2 - 1.0, 0.0)) - 1.0)


@helper
def _huang_g(alpha2, cos_i, cos_o):
    """bsdf_G<GGX>."""
    return 1.0 / (1.0 + _huang_lambda(alpha2, cos_i) + _huang_lambda(alpha2, cos_o))


@helper
def _huang_go(alpha2, cos_i, cos_o):
    """bsdf_Go: the shadowing-masking over the masking from wi."""
    li = _huang_lambda(alpha2, cos_i)
    lo = _huang_lambda(alpha2, cos_o)
    if not np.isfinite(li + lo):
        return 0.0
    return (1.0 + li) / (1.0 + li + lo)


@helper
def _huang_d(alpha2, cos_h):
    c2 = cos_h * cos_h
    t = (1.0 - c2) + alpha2 * c2
    return alpha2 / (np.pi * t * t)


@helper
def _huang_scale(t_ge, t_gie, mu, rough, eta):
    """bsdf_hair_huang_energy_scale: 1 / the glass albedo table (rough = sqrt(roughness))."""
    z = np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))
    e = _lookup3(t_gie, rough, mu, z) if eta < 1.0 else _lookup3(t_ge, rough, mu, z)
    return 1.0 / e if e > 0 else 0.0


@helper
def _huang_fresnel(cos_i, eta):
    """Cycles' fresnel_dielectric with its (negative) cos_theta_t (0 under total reflection)."""
    f, cos_t = _fresnel_dielectric(cos_i, eta)
    return f, -cos_t


@helper
def _dot3(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@helper
def _cos_theta(x, z):
    return np.sqrt(x * x + z * z)


@helper
def _dir_phi(x, z):
    return np.arctan2(x, z)


@helper
def _to_phi(gamma, b):
    if b == 1.0:
        return gamma
    return np.arctan2(b * np.sin(gamma), np.cos(gamma))


@helper
def _to_gamma(phi, b):
    if b == 1.0:
        return phi
    return np.arctan2(np.sin(phi), b * np.cos(phi))


@helper
def _sincos_phi(x, y, z):
    c = _cos_theta(x, z)
    if c <= 0.0:
        return 0.0, 1.0
    return x / c, z / c


@helper
def _phi_to_h(phi, b, ix, iy, iz):
    if b == 1.0:
        return -np.sin(phi)
    g = _to_gamma(phi, b)
    sp, cp = _sincos_phi(ix, iy, iz)
    return -cp * np.sin(g) + b * sp * np.cos(g)


@helper
def _h_to_gamma(h, b, ix, iz):
    if b == 1.0:
        return -np.arcsin(clip(h, -1.0, 1.0))
    return np.arctan2(iz, -b * ix) - np.arccos(clip(-h, -1.0, 1.0))


@helper
def _d_gamma_d_h(sp, cp, gamma, b):
    if b == 1.0:
        d = np.cos(gamma)
    else:
        d = cp * np.cos(gamma) + b * sp * np.sin(gamma)
    return 1.0 / d if d != 0.0 else 0.0


@helper
def _sphg_dir(theta, gamma, b):
    st, ct = np.sin(theta), np.cos(theta)
    sg, cg = np.sin(gamma), np.cos(gamma)
    if b == 1.0 or np.abs(cg) < 1e-6:
        sp, cp = sg, cg
    else:
        tan_phi = b * sg / cg
        cp = (1.0 if cg > 0 else (-1.0 if cg < 0 else 0.0)) / np.sqrt(tan_phi * tan_phi + 1.0)
        sp = cp * tan_phi
    return sp * ct, st, cp * ct


@helper
def _arc_length(e2, gamma):
    if e2 == 0.0:
        return 1.0
    s = np.sin(gamma)
    return np.sqrt(max(1.0 - e2 * s * s, 0.0))


@helper
def _point_distance(g1, g2, b):
    """len(to_point(g1, b) - to_point(g2, b))."""
    dx = np.sin(g1) - np.sin(g2)
    dy = b * (np.cos(g1) - np.cos(g2))
    return np.sqrt(dx * dx + dy * dy)


@helper
def _visible(vx, vy, vz, mx, my, mz, hx, hy, hz):
    """microfacet_visible(v, m, h)."""
    return _dot3(vx, vy, vz, hx, hy, hz) > 0.0 and _dot3(vx, vy, vz, mx, my, mz) > 0.0


@helper
def _sample_wh(rough, ix, iy, iz, mx, my, mz, u1, u2):
    """sample_wh: a GGX visible normal about the mesonormal m."""
    # make_orthonormals(m): any frame (the VNDF is isotropic about m)
    if np.abs(mx) > 0.5:
        sx, sy, sz = -my, mx, 0.0
    else:
        sx, sy, sz = 0.0, -mz, my
    ls = np.sqrt(sx * sx + sy * sy + sz * sz)
    sx, sy, sz = sx / ls, sy / ls, sz / ls
    tx, ty, tz = my * sz - mz * sy, mz * sx - mx * sz, mx * sy - my * sx
    lx, ly, lz = _dot3(ix, iy, iz, sx, sy, sz), _dot3(ix, iy, iz, tx, ty, tz), _dot3(ix, iy, iz, mx, my, mz)
    hx, hy, hz = _vndf(lx, ly, lz, rough, u1, u2)
    return hx * sx + hy * tx + hz * mx, hx * sy + hy * ty + hz * my, hx * sz + hy * tz + hz * mz


@helper
def _refract_angle(ix, iy, iz, nx, ny, nz, cos_t, inv_eta):
    c = inv_eta * _dot3(nx, ny, nz, ix, iy, iz) + cos_t
    return c * nx - inv_eta * ix, c * ny - inv_eta * iy, c * nz - inv_eta * iz


@helper
def _normalized(x, y, z):
    length = np.sqrt(x * x + y * y + z * z)
    if length <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    return x / length, y / length, z / length, 1.0 / length


@helper
def _huang_axes(b, axis_y, axis_z, woy, woz):
    """Cycles' X (bsdf->N) in the shading frame's (y, z): perpendicular to
    the view on round fibres, the ellipse's major axis (per ray) otherwise."""
    if b == 1.0:
        ay, az = -woz, woy
    else:
        ay, az = axis_y, axis_z
    length = np.sqrt(ay * ay + az * az)
    if length > 0.0:
        return ay / length, az / length
    return 0.0, 1.0


@helper
def _huang_setup(aspect, axis_y, axis_z, wox, woy, woz):
    """bsdf_hair_huang_setup: (b, Xy, Xz, local view (x, y, z), h, radius, e2)."""
    b = aspect if np.isfinite(aspect) else 1.0
    b = max(b, 1e-3)
    if b > 1.0:
        b = 1.0 / b
    xy, xz = _huang_axes(b, axis_y, axis_z, woy, woz)
    ix, iy, iz = woy * xy + woz * xz, wox, woy * xz - woz * xy
    yz = np.sqrt(woy * woy + woz * woz)
    h = clip(-woy / yz, -1.0, 1.0) if yz > 0 else 0.0
    e2 = 1.0 - b * b
    radius = 1.0
    if e2 != 0.0:
        d = ix * ix + iz * iz
        radius = np.sqrt(max(1.0 - e2 * ix * ix / d, 0.0)) if d > 0 else 1.0
    return b, xy, xz, ix, iy, iz, h, radius, e2


@helper
def _huang_transparent(aspect, axis_y, axis_z, wox, woy, woz):
    """A hit outside the ellipse's projected width: Cycles makes the closure transparent."""
    b, xy, xz, ix, iy, iz, h, radius, e2 = _huang_setup(aspect, axis_y, axis_z, wox, woy, woz)
    return np.abs(h) >= radius


@helper
def _huang_eval_r(t_ge, t_gie, gain, rough, tilt, eta, b, e2, h_lo, h_hi, ix, iy, iz, ox, oy, oz):
    if gain <= 0.0:
        return 0.0
    hx, hy, hz, _ = _normalized(ix + ox, iy + oy, iz + oz)
    r2 = rough * rough
    sp, cp = _sincos_phi(ix, iy, iz)
    res = rough * 0.7
    h_range = h_hi - h_lo
    intervals = 2 * np.int64(np.ceil(h_range / res * 0.5))
    res = h_range / intervals
    integral = 0.0
    for i in range(intervals + 1):
        h = h_lo + i * res
        gm = _h_to_gamma(h, b, ix, iz)
        mx, my, mz = _sphg_dir(tilt, gm, b)
        if (_visible(ix, iy, iz, mx, 0.0, mz, hx, hy, hz) and _visible(ox, oy, oz, mx, 0.0, mz, hx, hy, hz)):
            weight = (0.5 if i == 0 or i == intervals else (i % 2 + 1)) * _d_gamma_d_h(sp, cp, gm, b)
            cos_mi = _dot3(mx, my, mz, ix, iy, iz)
            g = _huang_g(r2, cos_mi, _dot3(mx, my, mz, ox, oy, oz))
            integral += (weight * _huang_d(r2, _dot3(mx, my, mz, hx, hy, hz)) * g * _arc_length(e2, gm)
                         * _huang_scale(t_ge, t_gie, cos_mi, np.sqrt(rough), eta))
    integral *= 2.0 / 3.0 * res
    f = _fresnel_dielectric_cos(_dot3(ix, iy, iz, hx, hy, hz), eta)
    return gain * 0.25 * f * integral


@helper
def _huang_trrt(t, r, a):
    """bsdf_hair_huang_eval_trrt for one channel."""
    t_avg = max(1.0 - r, 1e-5)
    return t * r * r * t_avg * a * a * a / (1.0 - a * (1.0 - t_avg))


@helper
def _huang_eval_residual(t_ge, t_gie, tt_gain, trt_gain, sigma, rough, tilt, eta, b, e2, h_lo, h_hi,
                         ix, iy, iz, ox, oy, oz, state, out):
    """bsdf_hair_huang_eval_residual into out (3,): TT and TRT by Monte
    Carlo-Simpson quadrature (the LCG from state), TRRT+ by Chiang's M."""
    out[0] = out[1] = out[2] = 0.0
    if tt_gain <= 0.0 and trt_gain <= 0.0:
        return
    inv_eta = 1.0 / eta
    r2 = rough * rough
    sqrt_r = np.sqrt(rough)
    sp, cp = _sincos_phi(ix, iy, iz)
    res = rough * 0.8
    h_range = h_hi - h_lo
    intervals = 2 * np.int64(np.ceil(h_range / res * 0.5))
    res = h_range / intervals
    s_tt0 = s_tt1 = s_tt2 = s_trt0 = s_trt1 = s_trt2 = s_r0 = s_r1 = s_r2 = 0.0
    for i in range(intervals + 1):
        h = h_lo + i * res
        gmi = _h_to_gamma(h, b, ix, iz)
        mix_, miy, miz = _sphg_dir(tilt, gmi, b)
        nix, niy, niz = _sphg_dir(0.0, gmi, b)
        state, u1 = _lcg(state)
        state, u2 = _lcg(state)
        h1x, h1y, h1z = _sample_wh(rough, ix, iy, iz, mix_, miy, miz, u1, u2)
        cos_hi1 = _dot3(ix, iy, iz, h1x, h1y, h1z)
        if not cos_hi1 > 0.0:
            continue
        cos_mi1 = _dot3(ix, iy, iz, mix_, miy, miz)
        f1, cos_t1 = _huang_fresnel(cos_hi1, eta)
        t1 = 1.0 - f1
        scale1 = _huang_scale(t_ge, t_gie, cos_mi1, sqrt_r, eta)
        wtx, wty, wtz = _refract_angle(ix, iy, iz, h1x, h1y, h1z, cos_t1, inv_eta)
        phi_t = _dir_phi(wtx, wtz)
        gmt = 2.0 * _to_phi(phi_t, b) - gmi
        mtx, mty, mtz = _sphg_dir(-tilt, gmt, b)
        ntx, nty, ntz = _sphg_dir(0.0, gmt, b)
        cos_mo1 = -_dot3(wtx, wty, wtz, mix_, miy, miz)
        cos_mi2 = -_dot3(wtx, wty, wtz, mtx, mty, mtz)
        g1o = _huang_go(r2, cos_mi1, cos_mo1)
        if not (_visible(ix, iy, iz, mix_, miy, miz, h1x, h1y, h1z)
                and _visible(-wtx, -wty, -wtz, mix_, miy, miz, h1x, h1y, h1z)
                and _visible(ix, iy, iz, nix, niy, niz, h1x, h1y, h1z)
                and _visible(-wtx, -wty, -wtz, nix, niy, niz, h1x, h1y, h1z)):
            continue
        weight = (0.5 if i == 0 or i == intervals else (i % 2 + 1)) * _d_gamma_d_h(sp, cp, gmi, b)
        ct = _cos_theta(wtx, wtz)
        if b == 1.0:
            path = 2.0 * np.cos(gmi - phi_t)
        else:
            path = -_point_distance(gmi, gmt + np.pi, b)
        a0 = np.exp(sigma[0] / ct * path)
        a1 = np.exp(sigma[1] / ct * path)
        a2 = np.exp(sigma[2] / ct * path)
        scale2 = _huang_scale(t_ge, t_gie, cos_mi2, sqrt_r, inv_eta)
        if tt_gain > 0.0 and _dot3(ox, oy, oz, wtx, wty, wtz) >= inv_eta - 1e-5:
            hx, hy, hz, rcp = _normalized(-wtx + inv_eta * ox, -wty + inv_eta * oy, -wtz + inv_eta * oz)
            cos_mh2 = _dot3(mtx, mty, mtz, hx, hy, hz)
            if cos_mh2 >= 0.0:
                cos_hi2 = -_dot3(wtx, wty, wtz, hx, hy, hz)
                cos_ho2 = -_dot3(ox, oy, oz, hx, hy, hz)
                cos_mo2 = -_dot3(ox, oy, oz, mtx, mty, mtz)
                t2 = (1.0 - _fresnel_dielectric_cos(cos_hi2, inv_eta)) * scale2
                common = (weight * t1 * scale1 * t2 * _huang_d(r2, cos_mh2) * g1o * _huang_g(r2, cos_mi2, cos_mo2)
                          / cos_mo1 * cos_mi1 * cos_hi2 * cos_ho2 * rcp * rcp)
                arc = tt_gain * _arc_length(e2, gmt)
                if np.isfinite(common * a0) and np.isfinite(common * a1) and np.isfinite(common * a2):
                    s_tt0 += arc * common * a0
                    s_tt1 += arc * common * a1
                    s_tt2 += arc * common * a2
        if trt_gain > 0.0:
            state, u1 = _lcg(state)
            state, u2 = _lcg(state)
            h2x, h2y, h2z = _sample_wh(rough, -wtx, -wty, -wtz, mtx, mty, mtz, u1, u2)
            cos_hi2 = -_dot3(wtx, wty, wtz, h2x, h2y, h2z)
            if not cos_hi2 > 0.0:
                continue
            r2f = _fresnel_dielectric_cos(cos_hi2, inv_eta)
            trx, try_, trz = _reflect(wtx, wty, wtz, h2x, h2y, h2z)   # -reflect(wt, wh2)
            if -_dot3(trx, try_, trz, ox, oy, oz) < inv_eta - 1e-5:   # total internal reflection
                s_r0 += weight * _huang_trrt(t1, r2f, a0)
                s_r1 += weight * _huang_trrt(t1, r2f, a1)
                s_r2 += weight * _huang_trrt(t1, r2f, a2)
                continue
            if not (_visible(-wtx, -wty, -wtz, mtx, mty, mtz, h2x, h2y, h2z)
                    and _visible(-trx, -try_, -trz, mtx, mty, mtz, h2x, h2y, h2z)
                    and _visible(-wtx, -wty, -wtz, ntx, nty, ntz, h2x, h2y, h2z)
                    and _visible(-trx, -try_, -trz, ntx, nty, ntz, h2x, h2y, h2z)):
                continue
            phi_tr = _dir_phi(trx, trz)
            gmtr = gmi - 2.0 * (_to_phi(phi_t, b) - _to_phi(phi_tr, b)) + np.pi
            mrx, mry, mrz = _sphg_dir(-tilt, gmtr, b)
            nrx, nry, nrz = _sphg_dir(0.0, gmtr, b)
            hx, hy, hz, rcp = _normalized(trx + inv_eta * ox, try_ + inv_eta * oy, trz + inv_eta * oz)
            cos_mh3 = _dot3(mrx, mry, mrz, hx, hy, hz)
            if (cos_mh3 < 0.0 or not (_visible(trx, try_, trz, mrx, mry, mrz, hx, hy, hz)
                                      and _visible(-ox, -oy, -oz, mrx, mry, mrz, hx, hy, hz)
                                      and _visible(trx, try_, trz, nrx, nry, nrz, hx, hy, hz)
                                      and _visible(-ox, -oy, -oz, nrx, nry, nrz, hx, hy, hz))):
                s_r0 += weight * _huang_trrt(t1, r2f, a0)
                s_r1 += weight * _huang_trrt(t1, r2f, a1)
                s_r2 += weight * _huang_trrt(t1, r2f, a2)
                continue
            cos_hi3 = _dot3(hx, hy, hz, trx, try_, trz)
            cos_ho3 = -_dot3(hx, hy, hz, ox, oy, oz)
            cos_mi3 = _dot3(mrx, mry, mrz, trx, try_, trz)
            t3 = (1.0 - _fresnel_dielectric_cos(cos_hi3, inv_eta)) * _huang_scale(t_ge, t_gie, cos_mi3, sqrt_r,
                                                                                  inv_eta)
            ctr = _cos_theta(trx, trz)
            if b == 1.0:
                path2 = -2.0 * np.abs(np.cos(phi_tr - gmt))
            else:
                path2 = -_point_distance(gmtr, gmt, b)
            cos_mo2 = -_dot3(mtx, mty, mtz, trx, try_, trz)
            common = (weight * t1 * scale1 * r2f * scale2 * t3 * _huang_d(r2, cos_mh3) * g1o
                      * _huang_go(r2, cos_mi2, cos_mo2) * _huang_g(r2, cos_mi3, -_dot3(mrx, mry, mrz, ox, oy, oz))
                      / (cos_mo1 * cos_mo2) * cos_mi1 * cos_mi2 * cos_hi3 * cos_ho3 * rcp * rcp)
            arc = trt_gain * _arc_length(e2, gmtr)
            v0 = common * a0 * np.exp(sigma[0] / ctr * path2)
            v1 = common * a1 * np.exp(sigma[1] / ctr * path2)
            v2 = common * a2 * np.exp(sigma[2] / ctr * path2)
            if np.isfinite(v0) and np.isfinite(v1) and np.isfinite(v2):
                s_trt0 += arc * v0
                s_trt1 += arc * v1
                s_trt2 += arc * v2
            s_r0 += weight * _huang_trrt(t1, r2f, a0)
            s_r1 += weight * _huang_trrt(t1, r2f, a1)
            s_r2 += weight * _huang_trrt(t1, r2f, a2)
    m = _hair_mp(iy, _cos_theta(ix, iz), oy, _cos_theta(ox, oz), 4.0 * rough)
    trrt = m / (2.0 * np.pi) * (2.0 / np.pi)
    c = 2.0 / 3.0 * res
    ie2 = inv_eta * inv_eta
    out[0] = ((s_tt0 + s_trt0) * ie2 + s_r0 * trrt) * c
    out[1] = ((s_tt1 + s_trt1) * ie2 + s_r1 * trrt) * c
    out[2] = ((s_tt2 + s_trt2) * ie2 + s_r2 * trrt) * c


@helper
def _huang_params(alpha, ior, offset):
    """(roughness, tilt, eta) as bsdf_hair_huang_setup (Offset negated;
    NaN roughness 0.001, NaN or non-positive IOR 1.55)."""
    rough = clip(np.sqrt(alpha) if alpha > 0 else 0.0, 0.001, 1.0)
    tilt = -offset if np.isfinite(offset) else 0.0
    eta = ior if (np.isfinite(ior) and ior > 0.0) else 1.55
    return rough, tilt, eta


@helper
def _huang_eval(t_ge, t_gie, alpha, ior, sigma, offset, aspect, axis, gains, coverage,
                wox, woy, woz, wix, wiy, wiz, out):
    """bsdf_hair_huang_eval: f (its value over the shading frame's |wi.z|)
    into out (3,); returns the pdf Cycles reports (1; 0 where the closure
    is transparent, outside the ellipse's projected width)."""
    out[0] = out[1] = out[2] = 0.0
    b, xy, xz, ix, iy, iz, h, radius, e2 = _huang_setup(aspect, axis[0], axis[1], wox, woy, woz)
    if not np.abs(h) < radius:
        return 0.0
    rough, tilt, eta = _huang_params(alpha, ior, offset)
    ox, oy, oz = wiy * xy + wiz * xz, wix, wiy * xz - wiz * xy
    tan_tilt = np.tan(tilt)
    co, ci = _cos_theta(ox, oz), _cos_theta(ix, iz)
    if ci <= 0.0 or np.abs(wiz) < 1e-12:
        return 1.0
    if co > 0.0 and tan_tilt * (oy / co) < -1.0:   # dot(wo, wmo) < 0 everywhere
        return 1.0
    arg = max(-tan_tilt * (iy / ci), 0.0)
    if arg > 1.0:   # dot(wi, wmi) < 0 everywhere
        return 1.0
    half_span = np.arccos(arg)
    phi_i = 0.0 if b == 1.0 else _dir_phi(ix, iz)
    h_lo = _phi_to_h(phi_i + half_span, b, ix, iy, iz)
    h_hi = _phi_to_h(phi_i - half_span, b, ix, iy, iz)
    dh = 2.0
    if radius > coverage:   # near field: the part of the width this pixel sees
        n_lo, n_hi = max(-radius, h - coverage), min(radius, h + coverage)
        dh = (n_hi - n_lo) / radius
        h_lo, h_hi = max(h_lo, n_lo), min(h_hi, n_hi)
    h_lo, h_hi = max(h_lo / radius, -0.999), min(h_hi / radius, 0.999)
    if not h_lo < h_hi:
        return 1.0
    fr = _huang_eval_r(t_ge, t_gie, gains[0], rough, tilt, eta, b, e2, h_lo, h_hi, ix, iy, iz, ox, oy, oz)
    state = _lcg_seed(wix - 0.5 * wox, wiy + 0.25 * woy, wiz - 0.125 * woz)
    _huang_eval_residual(t_ge, t_gie, gains[1], gains[2], sigma, rough, tilt, eta, b, e2, h_lo, h_hi,
                         ix, iy, iz, ox, oy, oz, state, out)
    scale = 1.0 / (ci * dh * np.abs(wiz))
    for c in range(3):
        v = (out[c] + fr) * scale
        out[c] = v if np.isfinite(v) else 0.0
    return 1.0


@helper
def _huang_sample(t_ge, t_gie, alpha, ior, sigma, offset, aspect, axis, gains, coverage,
                  wox, woy, woz, u_lobe, u1, u2, out):
    """bsdf_hair_huang_sample: (x, y, z, ok) in the shading frame and its
    eval (f |cos|, the weight at pdf 1) into out (3,); rand = (u_lobe, u1,
    u2), the rest from an LCG seeded by them."""
    out[0] = out[1] = out[2] = 0.0
    b, xy, xz, ix, iy, iz, h, radius, e2 = _huang_setup(aspect, axis[0], axis[1], wox, woy, woz)
    rough, tilt, eta = _huang_params(alpha, ior, offset)
    state = _lcg_seed(u_lobe, u1, u2)
    state, h1y = _lcg(state)
    state, h2x_ = _lcg(state)
    state, h2y_ = _lcg(state)
    state, h3x_ = _lcg(state)
    state, h3y_ = _lcg(state)
    # The far field samples h (the hit's own h may be numerically poor).
    h_div_r = h / radius if radius > coverage else u1 * 2.0 - 1.0
    gmi = _h_to_gamma(h_div_r, b, ix, iz)
    nix, niy, niz = _sphg_dir(0.0, gmi, b)
    st, ct = np.sin(tilt), np.cos(tilt)
    mix_, miy, miz = nix * ct, st, niz * ct
    cos_mi1 = _dot3(mix_, miy, miz, ix, iy, iz)
    if cos_mi1 < 0.0 or _dot3(nix, niy, niz, ix, iy, iz) < 0.0:
        return 0.0, 0.0, 1.0, False
    r2 = rough * rough
    sqrt_r = np.sqrt(rough)
    h1x, h1y, h1z = _sample_wh(rough, ix, iy, iz, mix_, miy, miz, u2, h1y)
    wrx, wry, wrz = _reflect(ix, iy, iz, h1x, h1y, h1z)
    if not _visible(ix, iy, iz, nix, niy, niz, h1x, h1y, h1z):
        return 0.0, 0.0, 1.0, False
    f1, cos_t1 = _huang_fresnel(_dot3(ix, iy, iz, h1x, h1y, h1z), eta)
    scale1 = _huang_scale(t_ge, t_gie, cos_mi1, sqrt_r, eta)
    r_val = 0.0
    if _visible(wrx, wry, wrz, nix, niy, niz, h1x, h1y, h1z):
        r_val = gains[0] * f1 * scale1 * _huang_go(r2, cos_mi1, _dot3(mix_, miy, miz, wrx, wry, wrz))
    inv_eta = 1.0 / eta
    wtx, wty, wtz = _refract_angle(ix, iy, iz, h1x, h1y, h1z, cos_t1, inv_eta)
    phi_t = _dir_phi(wtx, wtz)
    gmt = 2.0 * _to_phi(phi_t, b) - gmi
    mtx, mty, mtz = _sphg_dir(-tilt, gmt, b)
    ntx, nty, ntz = _sphg_dir(0.0, gmt, b)
    h2x, h2y, h2z = _sample_wh(rough, -wtx, -wty, -wtz, mtx, mty, mtz, h2x_, h2y_)
    trx, try_, trz = _reflect(wtx, wty, wtz, h2x, h2y, h2z)
    tt0 = tt1 = tt2 = trt0 = trt1 = trt2 = rr0 = rr1 = rr2 = 0.0
    ttx = tty = ttz = rtx = rty = rtz = qx = qy = qz = 0.0
    cos_mi2 = -_dot3(wtx, wty, wtz, mtx, mty, mtz)
    if (cos_mi2 > 0.0 and _visible(-wtx, -wty, -wtz, nix, niy, niz, h1x, h1y, h1z)
            and _visible(-wtx, -wty, -wtz, ntx, nty, ntz, h2x, h2y, h2z)):
        if b == 1.0:
            path = 2.0 * np.cos(phi_t - gmi)
        else:
            path = -_point_distance(gmi, gmt + np.pi, b)
        ct_t = _cos_theta(wtx, wtz)
        a0 = np.exp(sigma[0] / ct_t * path)
        a1 = np.exp(sigma[1] / ct_t * path)
        a2 = np.exp(sigma[2] / ct_t * path)
        f2, cos_t2 = _huang_fresnel(-_dot3(wtx, wty, wtz, h2x, h2y, h2z), inv_eta)
        t1 = (1.0 - f1) * scale1 * _huang_go(r2, cos_mi1, -_dot3(mix_, miy, miz, wtx, wty, wtz))
        t2 = 1.0 - f2
        scale2 = _huang_scale(t_ge, t_gie, cos_mi2, sqrt_r, inv_eta)
        ttx, tty, ttz = _refract_angle(-wtx, -wty, -wtz, h2x, h2y, h2z, cos_t2, eta)
        if (-_dot3(mtx, mty, mtz, ttx, tty, ttz) > 0.0 and t2 > 0.0
                and _visible(-ttx, -tty, -ttz, ntx, nty, ntz, h2x, h2y, h2z)):
            g = gains[1] * t1 * t2 * scale2 * _huang_go(r2, cos_mi2, -_dot3(mtx, mty, mtz, ttx, tty, ttz))
            tt0, tt1, tt2 = g * a0, g * a1, g * a2
        phi_tr = _dir_phi(trx, trz)
        gmtr = gmi - 2.0 * (_to_phi(phi_t, b) - _to_phi(phi_tr, b)) + np.pi
        mrx, mry, mrz = _sphg_dir(-tilt, gmtr, b)
        h3x, h3y, h3z = _sample_wh(rough, trx, try_, trz, mrx, mry, mrz, h3x_, h3y_)
        f3, cos_t3 = _huang_fresnel(_dot3(trx, try_, trz, h3x, h3y, h3z), inv_eta)
        rtx, rty, rtz = _refract_angle(trx, try_, trz, h3x, h3y, h3z, cos_t3, eta)
        cos_mi3 = _dot3(mrx, mry, mrz, trx, try_, trz)
        if cos_mi3 > 0.0:
            if b == 1.0:
                path2 = -2.0 * np.abs(np.cos(phi_tr - gmt))
            else:
                path2 = -_point_distance(gmt, gmtr, b)
            ct_r = _cos_theta(trx, trz)
            b0 = np.exp(sigma[0] / ct_r * path2)
            b1 = np.exp(sigma[1] / ct_r * path2)
            b2 = np.exp(sigma[2] / ct_r * path2)
            tr = (t1 * f2 * scale2 * _huang_scale(t_ge, t_gie, cos_mi3, sqrt_r, inv_eta)
                  * _huang_go(r2, cos_mi2, -_dot3(mtx, mty, mtz, trx, try_, trz)))
            t3 = 1.0 - f3
            if (t3 > 0.0 and _visible(trx, try_, trz, mrx, 0.0, mrz, h3x, h3y, h3z)
                    and _visible(-rtx, -rty, -rtz, mrx, 0.0, mrz, h3x, h3y, h3z)):
                g = gains[2] * tr * t3 * _huang_go(r2, cos_mi3, -_dot3(mrx, mry, mrz, rtx, rty, rtz))
                trt0, trt1, trt2 = g * a0 * b0, g * a1 * b1, g * a2 * b2
            # TRRT+: Chiang's longitudinal lobe, a uniform azimuth
            state, rt = _lcg(state)
            rt = max(rt, 1e-5)
            fac = 1.0 + 4.0 * rough * np.log(rt + (1.0 - rt) * np.exp(-0.5 / rough))
            state, uc = _lcg(state)
            sin_o = -fac * iy + _cos_from_sin(fac) * np.cos(2.0 * np.pi * uc) * _cos_theta(ix, iz)
            cos_o = _cos_from_sin(sin_o)
            state, up = _lcg(state)
            qx, qy, qz = np.sin(2.0 * np.pi * up) * cos_o, sin_o, np.cos(2.0 * np.pi * up) * cos_o
            t_avg = max(0.5 * (t2 + t3), 1e-5)
            sx, sy, sz = _reflect(trx, try_, trz, h3x, h3y, h3z)
            g = tr * f3 * _huang_go(r2, cos_mi3, _dot3(mrx, mry, mrz, sx, sy, sz))
            avg = np.sqrt(a0 * b0)
            rr0 = g * a0 * b0 * avg * t_avg / (1.0 - avg * (1.0 - t_avg))
            avg = np.sqrt(a1 * b1)
            rr1 = g * a1 * b1 * avg * t_avg / (1.0 - avg * (1.0 - t_avg))
            avg = np.sqrt(a2 * b2)
            rr2 = g * a2 * b2 * avg * t_avg / (1.0 - avg * (1.0 - t_avg))
    tt = (tt0 + tt1 + tt2) / 3.0
    trt = (trt0 + trt1 + trt2) / 3.0
    trrt = (rr0 + rr1 + rr2) / 3.0
    total = r_val + tt + trt + trrt
    if not (total > 0.0 and np.isfinite(total)):
        return 0.0, 0.0, 1.0, False
    pick = u_lobe * total
    if pick < r_val:
        lx, ly, lz = wrx, wry, wrz
        out[0] = out[1] = out[2] = total
    elif pick < r_val + tt:
        lx, ly, lz = ttx, tty, ttz
        out[0], out[1], out[2] = tt0 / tt * total, tt1 / tt * total, tt2 / tt * total
    elif pick < r_val + tt + trt:
        lx, ly, lz = rtx, rty, rtz
        out[0], out[1], out[2] = trt0 / trt * total, trt1 / trt * total, trt2 / trt * total
    else:
        lx, ly, lz = qx, qy, qz
        out[0], out[1], out[2] = rr0 / trrt * total, rr1 / trrt * total, rr2 / trrt * total
    x, y, z = ly, lx * xy + lz * xz, lx * xz - lz * xy
    ok = np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
    for c in range(3):
        if not np.isfinite(out[c]):
            ok = False
    return x, y, z, ok


def eval_pdf_loop(lobes, tables, wo, wi, sel, w, diffuse_term, keep, sampled, f, pdf):
    """bsdf.eval_pdf into f (N, 3) and pdf (N,); diffuse_term and keep
    are bsdf.bump_shadowing's arrays, or empty without a moved normal."""
    kind, color, alpha, fresnel, ior, f0, edge, trans_tint, multiscatter, covers, absorb, weight = lobes[:12]
    back = lobes[-1]
    t_sheen, cmf = tables[7], tables[8]
    thickness, film_ior = lobes[FILM_THICKNESS], lobes[FILM_IOR]
    bump = len(diffuse_term) > 0
    ap, energy, tilt = np.empty((4, 3)), np.empty(4), np.empty((3, 2))
    hb = np.empty(3)
    for i in range(len(wo)):
        wox, woy, woz, wix, wiy, wiz = wo[i, 0], wo[i, 1], wo[i, 2], wi[i, 0], wi[i, 1], wi[i, 2]
        f_0 = f_1 = f_2 = p = 0.0
        upper = woz > COS_EPS and wiz > COS_EPS
        lower = woz > COS_EPS and wiz < -COS_EPS
        for k in range(kind.shape[1]):
            kd = kind[i, k]
            if (kd == DIFFUSE and upper) or (kd == TRANSLUCENT and lower):
                if bump and (kd == DIFFUSE or not sampled):
                    s = INV_PI * diffuse_term[i]
                else:
                    s = INV_PI
                f_0 += w[i, k, 0] * s
                f_1 += w[i, k, 1] * s
                f_2 += w[i, k, 2] * s
                p += sel[i, k] * np.abs(wiz) * INV_PI
            elif kd == HAIR_CHIANG and woz > COS_EPS:
                h0, h1, h2, pk = _hair_eval(lobes, i, k, wox, woy, woz, wix, wiy, wiz, ap, energy, tilt)
                f_0 += w[i, k, 0] * h0
                f_1 += w[i, k, 1] * h1
                f_2 += w[i, k, 2] * h2
                p += sel[i, k] * pk
            elif kd == HAIR_HUANG and woz > COS_EPS:
                pk = _huang_eval(tables[2], tables[3], alpha[i, k], ior[i, k], lobes[ABSORPTION][i, k],
                                 lobes[OFFSET][i, k], lobes[ASPECT_RATIO][i, k], lobes[FIBRE_AXIS][i, k],
                                 lobes[HAIR_GAINS][i, k], lobes[PIXEL_COVERAGE][i, k],
                                 wox, woy, woz, wix, wiy, wiz, hb)
                f_0 += w[i, k, 0] * hb[0]
                f_1 += w[i, k, 1] * hb[1]
                f_2 += w[i, k, 2] * hb[2]
                p += sel[i, k] * pk
            elif (kd == HAIR_REFLECTION and upper) or (kd == HAIR_TRANSMISSION and lower):
                h, pk = _hair_bsdf_eval(kd == HAIR_TRANSMISSION, alpha[i, k], lobes[RADIAL_ROUGHNESS][i, k],
                                        lobes[OFFSET][i, k], wox, woy, woz, wix, wiy, wiz)
                f_0 += w[i, k, 0] * h
                f_1 += w[i, k, 1] * h
                f_2 += w[i, k, 2] * h
                p += sel[i, k] * pk
            elif kd == OREN_NAYAR and upper:
                single, e_avg, ms = _oren_nayar(lobes[DIFFUSE_ROUGHNESS][i, k], wox, woy, woz, wix, wiy, wiz)
                s = diffuse_term[i] if bump else 1.0
                f_0 += w[i, k, 0] * ((single + _oren_nayar_ms(color[i, k, 0], e_avg, ms)) * s)
                f_1 += w[i, k, 1] * ((single + _oren_nayar_ms(color[i, k, 1], e_avg, ms)) * s)
                f_2 += w[i, k, 2] * ((single + _oren_nayar_ms(color[i, k, 2], e_avg, ms)) * s)
                p += sel[i, k] * (max(wiz, 0.0) * INV_PI)
            elif kd == SHEEN and upper:
                v, pk = _eval_sheen(t_sheen, np.sqrt(alpha[i, k]), wox, woy, woz, wix, wiy, wiz)
                f_0 += w[i, k, 0] * v
                f_1 += w[i, k, 1] * v
                f_2 += w[i, k, 2] * v
                p += sel[i, k] * pk
            elif kd == GLOSSY_ANISOTROPIC and upper:
                ax, ay = _aniso_alphas(alpha[i, k], lobes[ANISOTROPY][i, k])
                rc, rs = _turn(lobes[ROTATION][i, k])
                spec, pk, cos = _ggx_aniso(ax, ay, rc * wox + rs * woy, rc * woy - rs * wox, woz,
                                           rc * wix + rs * wiy, rc * wiy - rs * wix, wiz)
                f_0, f_1, f_2 = _add_specular_film(f_0, f_1, f_2, w[i, k], fresnel[i, k], ior[i, k], color[i, k],
                                                   f0[i, k], edge[i, k], thickness[i, k], film_ior[i, k], cmf,
                                                   cos, spec)
                p += sel[i, k] * pk
            elif (kd == GLOSSY and upper) or ((kd == GLASS or kd == REFRACTION) and alpha[i, k] > MIN_ALPHA
                                               and (upper or lower)):
                # GGX reflection (glossy, glass above), refraction (glass below).
                common = 0.0
                if upper:
                    spec, pk, hx, hy, hz = ggx_reflect_terms(wox, woy, woz, wix, wiy, wiz, alpha[i, k])
                    cos = wox * hx + woy * hy + woz * hz
                else:
                    spec, common, cos, pk = _refraction(alpha[i, k], _eta(ior[i, k], kd, back[i]),
                                                        wox, woy, woz, wix, wiy, wiz)
                if kd == GLOSSY:
                    f_0, f_1, f_2 = _add_specular_film(f_0, f_1, f_2, w[i, k], fresnel[i, k], ior[i, k],
                                                       color[i, k], f0[i, k], edge[i, k], thickness[i, k],
                                                       film_ior[i, k], cmf, cos, spec)
                    p += sel[i, k] * pk
                    continue
                # bsdf._eval_glass: the dielectric Fresnel splits reflection and refraction.
                refraction = kd == REFRACTION
                eta = _eta(ior[i, k], kd, back[i])
                s, cos_t = _schlick_s(cos, eta)
                r0, r1, r2 = _glass_refl(cmf, refraction, f0[i, k], s, cos, eta, ior[i, k], back[i],
                                         thickness[i, k], film_ior[i, k])
                t0 = _dielectric_trans(refraction, r0, trans_tint[i, k, 0], cos_t)
                t1 = _dielectric_trans(refraction, r1, trans_tint[i, k, 1], cos_t)
                t2 = _dielectric_trans(refraction, r2, trans_tint[i, k, 2], cos_t)
                r = (r0 + r1 + r2) / 3.0
                t = (t0 + t1 + t2) / 3.0
                p_refl = r / (r + t) if r + t > 0 else 1.0
                if upper:
                    f_0 += w[i, k, 0] * (r0 * spec)
                    f_1 += w[i, k, 1] * (r1 * spec)
                    f_2 += w[i, k, 2] * (r2 * spec)
                    p += sel[i, k] * (pk * p_refl)
                else:
                    f_0 += w[i, k, 0] * (t0 * spec)
                    f_1 += w[i, k, 1] * (t1 * spec)
                    f_2 += w[i, k, 2] * (t2 * spec)
                    p += sel[i, k] * (common * (1.0 - p_refl) / pk if pk > 0 else 0.0)
        if bump and not sampled and not keep[i]:
            f_0 = f_1 = f_2 = p = 0.0
        f[i, 0], f[i, 1], f[i, 2], pdf[i] = f_0, f_1, f_2, p


# ----------------------------------------------------------------------------
# sample (bsdf.sample: the choice of lobe and its direction)

@helper
def _vndf(wox, woy, woz, alpha, u1, u2):
    """microfacet.ggx_sample_vndf for one ray."""
    return _vndf_aniso(wox, woy, woz, alpha, alpha, u1, u2)


@helper
def _vndf_aniso(wox, woy, woz, ax, ay, u1, u2):
    """microfacet.ggx_sample_vndf for one ray, roughness ax along x, ay along y."""
    vx, vy, vz = ax * wox, ay * woy, woz
    length = np.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / length, vy / length, vz / length
    lensq = vx * vx + vy * vy
    if lensq > 0:
        inv = 1.0 / np.sqrt(lensq)
        t1x, t1y, t1z = -vy * inv, vx * inv, 0.0
    else:
        t1x, t1y, t1z = 1.0, 0.0, 0.0
    t2x = vy * t1z - vz * t1y
    t2y = vz * t1x - vx * t1z
    t2z = vx * t1y - vy * t1x
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * np.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    nx = p1 * t1x + p2 * t2x + p3 * vx
    ny = p1 * t1y + p2 * t2y + p3 * vy
    nz = p1 * t1z + p2 * t2z + p3 * vz
    ex, ey, ez = ax * nx, ay * ny, max(nz, 1e-12)
    length = np.sqrt(ex * ex + ey * ey + ez * ez)
    return ex / length, ey / length, ez / length


@helper
def _reflect(wox, woy, woz, hx, hy, hz):
    c = 2.0 * (wox * hx + woy * hy + woz * hz)
    return c * hx - wox, c * hy - woy, c * hz - woz


@helper
def _sample_sheen(t_sheen, rough, wox, woy, woz, u1, u2):
    """bsdf._sample_sheen for one ray."""
    mu = clip(woz, 0.0, 1.0)
    a = _sheen_ltc(t_sheen, 0, rough, mu)
    b = _sheen_ltc(t_sheen, 1, rough, mu)
    r = np.sqrt(u1)
    phi = TWO_PI * u2
    dx, dy = r * np.cos(phi), r * np.sin(phi)
    dz = np.sqrt(max(0.0, 1.0 - u1))
    lx, ly, lz = dx - dz * b, dy, dz * a
    length = max(np.sqrt(lx * lx + ly * ly + lz * lz), 1e-30)
    lx, ly, lz = lx / length, ly / length, lz / length
    length = np.sqrt(wox * wox + woy * woy + 0.0 * 0.0)
    if length < 1e-7:
        tx, ty = 1.0, 0.0
    else:
        tx, ty = wox / length, woy / length
    return (lx * tx + ly * -ty + lz * 0.0, lx * ty + ly * tx + lz * 0.0,
            lx * 0.0 + ly * 0.0 + lz * 1.0)


@helper
def _subsurface_entry(skin, wox, woy, woz, alpha, ior, u1, u2):
    """lobes/subsurface.entry_direction for one ray: (x, y, z, ok)."""
    diffuse = skin and u1 < 0.5
    if skin:
        u1 = 2.0 * u1 if diffuse else 2.0 * (u1 - 0.5)
        alpha = 1.0
    u1 = min(u1, 1.0 - 1e-12)
    if diffuse:
        r = np.sqrt(u1)
        phi = TWO_PI * u2
        return r * np.cos(phi), r * np.sin(phi), -np.sqrt(max(0.0, 1.0 - u1)), True
    if woz <= 0.0:
        return 0.0, 0.0, 1.0, False
    neta = 1.0 / clip(ior, 1.01, 3.8)
    hx, hy, hz = _vndf(wox, woy, woz, alpha, u1, u2)
    cos_hi = hx * wox + hy * woy + hz * woz
    arg = 1.0 - neta * neta * (1.0 - cos_hi * cos_hi)
    nk = neta * cos_hi - max(np.sqrt(max(arg, 0.0)), 1e-7)
    x, y, z = -neta * wox + nk * hx, -neta * woy + nk * hy, -neta * woz + nk * hz
    length = max(np.sqrt(x * x + y * y + z * z), 1e-30)
    return x / length, y / length, z / length, z < 0.0


def sample_loop(lobes, tables, wo, u_lobe, u1, u2, sel, w, wi, weight, pdf, delta, smooth):
    """bsdf._sample_numpy into wi, weight, pdf, delta, smooth."""
    kind, color, alpha, fresnel, ior, f0, edge, trans_tint, multiscatter, covers, absorb, lobe_weight = lobes[:12]
    back = lobes[-1]
    t_sheen, cmf = tables[7], tables[8]
    thickness, film_ior = lobes[FILM_THICKNESS], lobes[FILM_IOR]
    kk = kind.shape[1]
    ap, energy, tilt = np.empty((4, 3)), np.empty(4), np.empty((3, 2))
    hb = np.empty(3)
    for i in range(len(wo)):
        wox, woy, woz = wo[i, 0], wo[i, 1], wo[i, 2]
        # The lobe: u_lobe against the running sum of the selection
        # probabilities, never past the last lobe that has one.
        cdf = 0.0
        count = 0
        last = kk - 1
        for k in range(kk - 1, -1, -1):
            if sel[i, k] > 0:
                last = k
                break
        lo = 0.0
        for k in range(kk):
            cdf = sel[i, k] if k == 0 else cdf + sel[i, k]
            if u_lobe[i] >= cdf:
                count += 1
        k = min(count, last)
        total = cdf
        cdf = 0.0
        for j in range(k + 1):
            cdf = sel[i, j] if j == 0 else cdf + sel[i, j]
        kd = kind[i, k] if total > 0 else NONE
        p_lobe = sel[i, k]
        lo = cdf - p_lobe
        u_sub = clip((u_lobe[i] - lo) / (p_lobe if p_lobe > 0 else 1.0), 0.0, 1.0 - 1e-12)
        x, y, z = 0.0, 0.0, 1.0
        r0 = r1 = r2 = p = 0.0
        is_delta = False
        if kd == DIFFUSE or kd == TRANSLUCENT or kd == OREN_NAYAR:
            r = np.sqrt(u1[i])
            phi = TWO_PI * u2[i]
            x, y, z = r * np.cos(phi), r * np.sin(phi), np.sqrt(max(0.0, 1.0 - u1[i]))
            if kd == TRANSLUCENT:
                z = z * -1.0
        elif kd == GLOSSY:
            hx, hy, hz = _vndf(wox, woy, woz, alpha[i, k], u1[i], u2[i])
            x, y, z = _reflect(wox, woy, woz, hx, hy, hz)
            if z <= 0.0:   # a reflection below the surface is absorbed (as Cycles)
                kd = NONE
        elif kd == GLOSSY_ANISOTROPIC:
            ax, ay = _aniso_alphas(alpha[i, k], lobes[ANISOTROPY][i, k])
            rc, rs = _turn(lobes[ROTATION][i, k])
            # In the rotated tangent's frame, then back.
            lx, ly = rc * wox + rs * woy, rc * woy - rs * wox
            hx, hy, hz = _vndf_aniso(lx, ly, woz, ax, ay, u1[i], u2[i])
            x, y, z = _reflect(lx, ly, woz, hx, hy, hz)
            x, y = rc * x - rs * y, rs * x + rc * y
            if z <= 0.0:
                kd = NONE
        elif kd == HAIR_CHIANG:
            x, y, z = _hair_sample(lobes, i, k, wox, woy, woz, u_sub, u1[i], u2[i], ap, energy, tilt)
        elif kd == HAIR_HUANG:
            # OWN_WEIGHT (Cycles' pdf 1); outside the ellipse's projected width a transparent pass.
            if _huang_transparent(lobes[ASPECT_RATIO][i, k], lobes[FIBRE_AXIS][i, k, 0], lobes[FIBRE_AXIS][i, k, 1],
                                  wox, woy, woz):
                x, y, z = -wox, -woy, -woz
                r0, r1, r2 = w[i, k, 0] / p_lobe, w[i, k, 1] / p_lobe, w[i, k, 2] / p_lobe
                is_delta = True
                p = p_lobe
            else:
                x, y, z, ok = _huang_sample(tables[2], tables[3], alpha[i, k], ior[i, k], lobes[ABSORPTION][i, k],
                                            lobes[OFFSET][i, k], lobes[ASPECT_RATIO][i, k], lobes[FIBRE_AXIS][i, k],
                                            lobes[HAIR_GAINS][i, k], lobes[PIXEL_COVERAGE][i, k],
                                            wox, woy, woz, u_sub, u1[i], u2[i], hb)
                cos = np.abs(z)
                if ok and cos > 1e-12:
                    r0, r1, r2 = w[i, k, 0] * hb[0] / cos, w[i, k, 1] * hb[1] / cos, w[i, k, 2] * hb[2] / cos
                    p = p_lobe
                else:
                    x, y, z = 0.0, 0.0, 1.0
                    kd = NONE
        elif kd == HAIR_REFLECTION or kd == HAIR_TRANSMISSION:
            # OWN_WEIGHT: its f (weighted) and pdf, which bsdf.sample adds to the others' eval.
            x, y, z, h, pk = _hair_bsdf_sample(kd == HAIR_TRANSMISSION, alpha[i, k], lobes[RADIAL_ROUGHNESS][i, k],
                                               lobes[OFFSET][i, k], wox, woy, woz, u1[i], u2[i])
            r0, r1, r2 = w[i, k, 0] * h, w[i, k, 1] * h, w[i, k, 2] * h
            p = p_lobe * pk
            if pk == 0.0:
                kd = NONE
        elif kd == SHEEN:
            x, y, z = _sample_sheen(t_sheen, np.sqrt(alpha[i, k]), wox, woy, woz, u1[i], u2[i])
        elif kd == MIRROR:
            x, y, z = wox * -1.0, woy * -1.0, woz * 1.0
            a0, a1, a2 = _fresnel_rgb(cmf, fresnel[i, k], ior[i, k], color[i, k], f0[i, k], edge[i, k],
                                      thickness[i, k], film_ior[i, k], woz)
            r0, r1, r2 = w[i, k, 0] * a0 / p_lobe, w[i, k, 1] * a1 / p_lobe, w[i, k, 2] * a2 / p_lobe
            is_delta = True
            p = p_lobe
        elif kd == TRANSPARENT or kd == RAY_PORTAL:   # the portal moves the ray after (integrator/portal.py)
            x, y, z = -wox, -woy, -woz
            r0, r1, r2 = w[i, k, 0] / p_lobe, w[i, k, 1] / p_lobe, w[i, k, 2] / p_lobe
            is_delta = True
            p = p_lobe
        elif kd == SUBSURFACE_RANDOM_WALK or kd == SUBSURFACE_SKIN or kd == SUBSURFACE_BURLEY:
            # lobes/subsurface.entry (the integrator's subsurface stage draws it itself).
            if kd == SUBSURFACE_BURLEY:
                x, y, z, ok = 0.0, 0.0, -1.0, woz > 0.0
            else:
                x, y, z, ok = _subsurface_entry(kd == SUBSURFACE_SKIN, wox, woy, woz, alpha[i, k], ior[i, k],
                                                u1[i], u2[i])
            if ok:
                r0, r1, r2 = w[i, k, 0] / p_lobe, w[i, k, 1] / p_lobe, w[i, k, 2] / p_lobe
            is_delta = True
            p = p_lobe
        elif kd == GLASS or kd == REFRACTION:
            # bsdf._sample_glass: reflect or refract through a visible
            # microfacet (the normal itself when singular).
            eta = _eta(ior[i, k], kd, back[i])
            singular = alpha[i, k] <= MIN_ALPHA
            if singular:
                hx, hy, hz = 0.0, 0.0, 1.0
            else:
                hx, hy, hz = _vndf(wox, woy, woz, alpha[i, k], u1[i], u2[i])
            cos = wox * hx + woy * hy + woz * hz
            refraction = kd == REFRACTION
            p_refl, cos_t = _glass_choice(cmf, refraction, f0[i, k], trans_tint[i, k], cos, eta, ior[i, k], back[i],
                                          thickness[i, k], film_ior[i, k])
            refract = u_sub >= p_refl
            if refract:
                inv = 1.0 / eta
                c = inv * cos - cos_t
                x, y, z = c * hx - inv * wox, c * hy - inv * woy, c * hz - inv * woz
            else:
                x, y, z = _reflect(wox, woy, woz, hx, hy, hz)
            # A refraction that ends above the surface (or a reflection
            # below) is absorbed, as Cycles does.
            if refract != (z < 0):
                kd = NONE
            if singular:
                s, cos_t = _schlick_s(woz, eta)
                a0, a1, a2 = _glass_refl(cmf, refraction, f0[i, k], s, woz, eta, ior[i, k], back[i],
                                         thickness[i, k], film_ior[i, k])
                if refract:
                    a0 = _dielectric_trans(refraction, a0, trans_tint[i, k, 0], cos_t)
                    a1 = _dielectric_trans(refraction, a1, trans_tint[i, k, 1], cos_t)
                    a2 = _dielectric_trans(refraction, a2, trans_tint[i, k, 2], cos_t)
                    pk = 1.0 - p_refl
                else:
                    pk = p_refl
                d = max(pk * p_lobe, 1e-300)
                r0, r1, r2 = w[i, k, 0] * a0 / d, w[i, k, 1] * a1 / d, w[i, k, 2] * a2 / d
                is_delta = True
                p = pk * p_lobe
        wi[i, 0], wi[i, 1], wi[i, 2] = x, y, z
        weight[i, 0], weight[i, 1], weight[i, 2] = r0, r1, r2
        pdf[i] = p
        delta[i] = is_delta
        smooth[i] = not is_delta and kd != NONE


@helper
def _glass_choice(cmf, refraction, f0, tint, cos, eta, ior, back, thickness, film_ior):
    """The probability of reflecting and |cos| of the refracted angle (bsdf._dielectric)."""
    s, cos_t = _schlick_s(cos, eta)
    r0, r1, r2 = _glass_refl(cmf, refraction, f0, s, cos, eta, ior, back, thickness, film_ior)
    t0 = _dielectric_trans(refraction, r0, tint[0], cos_t)
    t1 = _dielectric_trans(refraction, r1, tint[1], cos_t)
    t2 = _dielectric_trans(refraction, r2, tint[2], cos_t)
    r = (r0 + r1 + r2) / 3.0
    t = (t0 + t1 + t2) / 3.0
    return (r / (r + t) if r + t > 0 else 1.0), cos_t


def single_sample_loop(lobes, wo, u1, u2, wi, weight, pdf, delta):
    """bsdf._sample_single (one diffuse, glossy or mirror lobe, no moved
    normal) into wi, weight, pdf, delta: the weight in closed form."""
    kind, color, alpha, fresnel, ior, f0, edge = lobes[0], lobes[1], lobes[2], lobes[3], lobes[4], lobes[5], lobes[6]
    for i in range(len(wo)):
        wox, woy, woz = wo[i, 0], wo[i, 1], wo[i, 2]
        kd = kind[i, 0]
        up = woz > COS_EPS
        wx, wy, wz = 0.0, 0.0, 1.0
        w0, w1, w2 = 0.0, 0.0, 0.0
        p = 0.0
        if up and kd == DIFFUSE:
            r = np.sqrt(u1[i])
            phi = TWO_PI * u2[i]
            wx, wy, wz = r * np.cos(phi), r * np.sin(phi), np.sqrt(max(0.0, 1.0 - u1[i]))
            p = wz * INV_PI
            if p > 0:
                w0, w1, w2 = color[i, 0, 0], color[i, 0, 1], color[i, 0, 2]
        elif up and kd == GLOSSY:
            a = alpha[i, 0]
            hx, hy, hz = _vndf(wox, woy, woz, a, u1[i], u2[i])
            cos_oh = (wox * hx + woz * hz) + woy * hy        # einsum's order
            wx, wy, wz = 2.0 * cos_oh * hx - wox, 2.0 * cos_oh * hy - woy, 2.0 * cos_oh * hz - woz
            ok = wz > COS_EPS
            lam_o = ggx_lambda(woz, a)
            g1 = 1.0 / (1.0 + lam_o)
            g2 = 1.0 / (1.0 + lam_o + ggx_lambda(wz, a))
            p = ggx_d(hz, a) * g1 / (4.0 * woz) if ok else 0.0
            ratio = g2 / g1 if ok else 0.0
            w0, w1, w2 = _single_fresnel(i, fresnel, color, f0, edge, ior, cos_oh, ratio)
        elif up and kd == MIRROR:
            wx, wy, wz = wox * -1.0, woy * -1.0, woz * 1.0
            w0, w1, w2 = _single_fresnel(i, fresnel, color, f0, edge, ior, woz, 1.0)
            p = 1.0
        wi[i, 0], wi[i, 1], wi[i, 2] = wx, wy, wz
        weight[i, 0], weight[i, 1], weight[i, 2] = w0, w1, w2
        pdf[i] = p
        delta[i] = up and kd == MIRROR


@helper
def _single_fresnel(i, fresnel, color, f0, edge, ior, cos, ratio):
    """col F(cos) ratio per channel, col = 1 for the legacy Schlick mode
    (its colour is F0), as bsdf._sample_single."""
    code = fresnel[i, 0]
    s = _fresnel_s(code, ior[i, 0], cos)
    out0 = _fresnel(code, color[i, 0, 0], f0[i, 0, 0], edge[i, 0, 0], s, cos)
    out1 = _fresnel(code, color[i, 0, 1], f0[i, 0, 1], edge[i, 0, 1], s, cos)
    out2 = _fresnel(code, color[i, 0, 2], f0[i, 0, 2], edge[i, 0, 2], s, cos)
    if code == F_SCHLICK:
        return 1.0 * out0 * ratio, 1.0 * out1 * ratio, 1.0 * out2 * ratio
    return color[i, 0, 0] * out0 * ratio, color[i, 0, 1] * out1 * ratio, color[i, 0, 2] * out2 * ratio


def finish_sample_loop(wo, wi, smooth, fs, ps, weight, pdf):
    """bsdf._finish_numpy: smooth samples' weight and pdf from eval_pdf's f, pdf."""
    for i in range(len(wo)):
        if smooth[i]:
            p = ps[i]
            if p > 0:
                scale = np.abs(wi[i, 2]) / p
                weight[i, 0], weight[i, 1], weight[i, 2] = fs[i, 0] * scale, fs[i, 1] * scale, fs[i, 2] * scale
            else:
                weight[i, 0] = weight[i, 1] = weight[i, 2] = 0.0
            pdf[i] = p
        if not wo[i, 2] > COS_EPS:
            weight[i, 0] = weight[i, 1] = weight[i, 2] = 0.0


# ----------------------------------------------------------------------------
# MaterialTable.gather: every lobe field of each ray's material in one pass

def gather_loop(mat, floats, float_out, ints, int_out, flags, flag_out):
    """out[i] = table[mat[i]] for bsdf.Lobes' fields (GATHER_FIELDS), as
    np.take does field by field: the tables and outputs come as 2D views
    (RGB fields flattened to K * 3 columns), grouped by dtype so that each
    group is a tuple of one array type."""
    for j in range(len(floats)):
        _take_rows(mat, floats[j], float_out[j])
    for j in range(len(ints)):
        _take_rows(mat, ints[j], int_out[j])
    for j in range(len(flags)):
        _take_rows(mat, flags[j], flag_out[j])


@helper
def _take_rows(mat, table, out):
    width = table.shape[1]
    if width == 0:
        return
    for i in range(len(mat)):
        m = mat[i]
        for c in range(width):
            out[i, c] = table[m, c]
