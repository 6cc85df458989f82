"""Thin-film iridescence: the Airy / Belcour-Barla Fresnel of a dielectric
film over a dielectric or conductor substrate, as Cycles computes it
(closure/bsdf_util.h ``fresnel_iridescence_channel`` and its helpers,
closure/bsdf_microfacet.h for how the Principled specular layer and the
F82 / physical conductors call it; Belcour and Barla, "A Practical Extension
to Microfacet Theory for the Modeling of Varying Iridescence", 2017).

The spectral integral is a lookup in the Fourier transform of the CIE 1931
colour matching functions (engine/data/thin_film_cmf.npz, Cycles'
table_thin_film_cmf, built by engine/data/build_thin_film.py), turned into
Rec.709 RGB and normalised to a DC term of 1 as Cycles'
``ShaderManager::compute_thin_film_table`` does for Blender's default
scene-linear space.

Elementwise on arrays, in float32 as Cycles (``dtype=np.float64`` gives a
reference).  Thickness is in nanometres.  A film at most
THICKNESS_CUTOFF thick is no film; under 1 nm its IOR blends towards the
ambient one (thickness 0: the plain Fresnel of the substrate).
"""
import os

import numpy as np

THICKNESS_CUTOFF = 0.1          # Cycles' THINFILM_THICKNESS_CUTOFF (svm/types.h)
TABLE_SIZE = 512                # THIN_FILM_TABLE_SIZE
DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "thin_film_cmf.npz")
# Cycles' XYZ (D65) to Rec.709 (ShaderManager::init_xyz_transforms' default).
XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                          [-0.9692660, 1.8760108, 0.0415560],
                          [0.0556434, -0.2040259, 1.0572252]])

_tables = {}


def sensitivity_table(dtype=np.float32):
    """(6, 512): real R G B then imaginary R G B of the RGB sensitivities,
    each channel divided by its DC term (compute_thin_film_table)."""
    key = np.dtype(dtype).name
    if key not in _tables:
        with np.load(DATA) as data:
            cmf = data["cmf"].astype(dtype)
        m = XYZ_TO_REC709.astype(dtype)
        re = cmf[:, :3] @ m.T
        im = cmf[:, 3:] @ m.T
        norm = dtype(1.0) / re[0]
        _tables[key] = np.concatenate([(re * norm).T, (im * norm).T]).astype(dtype)
    return _tables[key]


def lookup(row, x, dtype=np.float32):
    """Cycles' lookup_table_read: x in [0, 1] clamped, linear."""
    x = np.clip(x, 0.0, 1.0).astype(dtype) * dtype(TABLE_SIZE - 1)
    i = np.minimum(x.astype(np.int64), TABLE_SIZE - 1)
    j = np.minimum(i + 1, TABLE_SIZE - 1)
    t = x - i
    return (dtype(1.0) - t) * row[i] + t * row[j]


def fresnel_dielectric_polarized(cos_i, eta, dtype=np.float32):
    """R_s, R_p, cos of the transmitted angle (negative: relative to the
    normal) and cos of the phase shift on reflection for s and p (+-1);
    total internal reflection: R = 1, cos phi = 1."""
    cos_i = np.asarray(cos_i, dtype)
    eta = np.asarray(eta, dtype)
    one = dtype(1.0)
    t2 = eta * eta - (one - cos_i * cos_i)
    tir = t2 <= 0
    c = np.abs(cos_i)
    cos_t = -np.sqrt(np.maximum(t2, dtype(0.0))) / eta
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (c + eta * cos_t) / (c - eta * cos_t)
        r_p = (cos_t + eta * c) / (eta * c - cos_t)
    phase_s = np.where(tir | (r_s >= 0), one, -one).astype(dtype)
    phase_p = np.where(tir | (r_p >= 0), one, -one).astype(dtype)
    return (np.where(tir, one, r_s * r_s), np.where(tir, one, r_p * r_p), np.where(tir, dtype(0.0), cos_t),
            phase_s, phase_p)


def fresnel_conductor_polarized(cosi, eta1, eta2, k2, f82=None, dtype=np.float32):
    """R_s, R_p and the phasors exp(i phi) (re, im) of s and p at a
    dielectric (IOR eta1) to conductor (eta2 + i k2) interface; with ``f82``
    (>= 0) the reflectances are the F82 model's of the relative n, k."""
    cosi, eta1, eta2, k2 = (np.asarray(a, dtype) for a in (cosi, eta1, eta2, k2))
    one = dtype(1.0)
    eta1_sq, eta2_sq, k2_sq = eta1 * eta1, eta2 * eta2, k2 * k2
    two_eta2_k2 = dtype(2.0) * eta2 * k2
    t1 = eta2_sq - k2_sq - eta1_sq * (one - cosi * cosi)
    t2 = np.sqrt(t1 * t1 + two_eta2_k2 * two_eta2_k2)
    u_sq = np.maximum(dtype(0.5) * (t2 + t1), dtype(0.0))
    v_sq = np.maximum(dtype(0.5) * (t2 - t1), dtype(0.0))
    u, v = np.sqrt(u_sq), np.sqrt(v_sq)
    with np.errstate(divide="ignore", invalid="ignore"):
        if f82 is not None:
            n = eta2 / eta1
            k_sq = (k2 / eta1) ** 2
            f0 = ((n - one) ** 2 + k_sq) / ((n + one) ** 2 + k_sq)
            r_s = f82_fresnel(cosi, f0, f82_b(f0, np.asarray(f82, dtype), dtype), dtype)
            r_p = r_s
        else:
            r_s = _safe_divide((eta1 * cosi - u) ** 2 + v_sq, (eta1 * cosi + u) ** 2 + v_sq)
            t3 = (eta2_sq - k2_sq) * cosi
            t4 = two_eta2_k2 * cosi
            r_p = _safe_divide((t3 - eta1 * u) ** 2 + (t4 - eta1 * v) ** 2, (t3 + eta1 * u) ** 2 + (t4 + eta1 * v) ** 2)
        re_s = -u_sq - v_sq + (eta1 * cosi) ** 2
        im_s = dtype(-2.0) * eta1 * cosi * v
        mag_s = np.sqrt(re_s * re_s + im_s * im_s)
        re_p = ((eta2_sq + k2_sq) * cosi) ** 2 - eta1_sq * (u_sq + v_sq)
        im_p = dtype(2.0) * eta1 * cosi * (two_eta2_k2 * u - (eta2_sq - k2_sq) * v)
        mag_p = np.sqrt(re_p * re_p + im_p * im_p)
        ph_s = (np.where(mag_s == 0, one, re_s / mag_s), np.where(mag_s == 0, dtype(0.0), im_s / mag_s))
        ph_p = (np.where(mag_p == 0, one, re_p / mag_p), np.where(mag_p == 0, dtype(0.0), im_p / mag_p))
    return r_s.astype(dtype), r_p.astype(dtype), ph_s, ph_p


def _safe_divide(a, b):
    return np.where(b != 0, a / np.where(b != 0, b, 1.0), 0.0)


def f82_b(f0, f82, dtype=np.float32):
    """Cycles' fresnel_f82_B (the B term given the value at 82 degrees)."""
    f = dtype(6.0 / 7.0)
    f5 = (f * f) * (f * f) * f
    schlick = f0 + (dtype(1.0) - f0) * f5
    return (dtype(7.0) / (f5 * f)) * (schlick - f82)


def f82_fresnel(cosi, f0, b, dtype=np.float32):
    s = np.clip(dtype(1.0) - cosi, 0.0, 1.0).astype(dtype)
    s5 = (s * s) * (s * s) * s
    return np.clip(f0 + (dtype(1.0) - f0) * s5 - b * cosi * s5 * s, 0.0, 1.0).astype(dtype)


def airy_summation(channel, r12, r23, opd, phasor, dtype=np.float32):
    """One polarisation's reflectance in one channel: the Airy series over
    path order differences m <= 3 (equation 10)."""
    table = sensitivity_table(dtype)
    t121 = dtype(1.0) - r12
    r123 = r12 * r23
    sq = np.sqrt(r123)
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = t121 * t121 * r23 / (dtype(1.0) - r123)
    acc_re, acc_im = phasor
    out = rs + r12
    cm = rs - t121
    for m in range(1, 4):
        cm = cm * sq
        x = dtype(2.0 * np.pi) * (dtype(m) * opd) / dtype(60000.0)
        s_re = lookup(table[channel], x, dtype)
        s_im = lookup(table[channel + 3], x, dtype)
        out = out + cm * dtype(2.0) * (acc_re * s_re + acc_im * s_im)
        acc_re, acc_im = acc_re * phasor[0] - acc_im * phasor[1], acc_re * phasor[1] + acc_im * phasor[0]
    return out


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fresnel_iridescence(channel, ambient_ior, thickness, film_ior, substrate_n, substrate_k, cos1,
                        conductive=False, f82=None, dtype=np.float32):
    """Reflectance of channel ``channel`` (0 R, 1 G, 2 B) of a film over a
    dielectric (``substrate_n``) or conductor (n + i k) substrate, and the cos
    of the angle transmitted into a dielectric substrate (Cycles'
    fresnel_iridescence_channel)."""
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype) for a in
                                   (ambient_ior, thickness, film_ior, substrate_n, substrate_k, cos1)))
    ambient_ior, thickness, film_ior, substrate_n, substrate_k, cos1 = arrays
    film_ior = np.where(thickness < 1.0, ambient_ior + (film_ior - ambient_ior) * smoothstep(
        dtype(0.0), dtype(1.0), thickness), film_ior).astype(dtype)
    r12s, r12p, cos2, ph12s, ph12p = fresnel_dielectric_polarized(cos1, film_ior / ambient_ior, dtype)
    top_tir = (r12s == 1.0) & (r12p == 1.0)
    cos3 = np.zeros_like(cos1)
    if conductive:
        r23s, r23p, ph23s, ph23p = fresnel_conductor_polarized(-cos2, film_ior, substrate_n, substrate_k, f82, dtype)
        bottom_tir = np.zeros(cos1.shape, bool)
    else:
        r23s, r23p, cos3, c23s, c23p = fresnel_dielectric_polarized(-cos2, substrate_n / film_ior, dtype)
        bottom_tir = (r23s == 1.0) & (r23p == 1.0)
        zero = np.zeros_like(cos1)
        ph23s, ph23p = (c23s, zero), (c23p, zero)
    opd = dtype(-2.0) * film_ior * thickness * cos2
    phs = (ph23s[0] * -ph12s, ph23s[1] * -ph12s)
    php = (ph23p[0] * -ph12p, ph23p[1] * -ph12p)
    r_s = airy_summation(channel, r12s, r23s, opd, phs, dtype)
    r_p = airy_summation(channel, r12p, r23p, opd, php, dtype)
    r = np.clip(dtype(0.5) * (r_s + r_p), 0.0, 1.0).astype(dtype)
    r = np.where(top_tir | bottom_tir, dtype(1.0), r)
    return r, np.where(top_tir, dtype(0.0), cos3)


def principled_dielectric(cos, ior, f0, thickness, film_ior, dtype=np.float32):
    """(n, 3) reflectance of the Principled specular layer with a thin film
    (generalized_schlick_fresnel's thin-film branch): the film over the
    dielectric, each channel scaled towards f0 / F0(ior) (Specular IOR Level
    and tint) the closer it is to F0(ior)."""
    cos, ior, thickness, film_ior = (np.asarray(a, dtype) for a in (cos, ior, thickness, film_ior))
    f = np.stack([fresnel_iridescence(c, 1.0, thickness, film_ior, ior, 0.0, cos, dtype=dtype)[0]
                  for c in range(3)], axis=-1)
    f0_real = ((ior - dtype(1.0)) / (ior + dtype(1.0))) ** 2
    scale = (f0_real > 1e-5) & ~np.all(f == 1.0, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip((f - 1.0) / (f0_real[..., None] - 1.0), 0.0, 1.0)
        factor = np.asarray(f0, dtype) / f0_real[..., None]
    scaled = f * (dtype(1.0) + (factor - dtype(1.0)) * s)
    return np.where(scale[..., None], scaled, f).astype(dtype)


def conductor(cos, n, k, thickness, film_ior, dtype=np.float32):
    """(n, 3) reflectance of a physical conductor n + i k (each (n, 3))
    under a film: the conductor Airy sum with its exact polarized Fresnel
    (microfacet_fresnel's CONDUCTOR branch, F82 nullptr)."""
    cos, thickness, film_ior = (np.asarray(a, dtype) for a in (cos, thickness, film_ior))
    n, k = np.maximum(np.asarray(n, dtype), 0.0), np.maximum(np.asarray(k, dtype), 0.0)
    return np.stack([fresnel_iridescence(c, 1.0, thickness, film_ior, n[..., c], k[..., c], cos, conductive=True,
                                         dtype=dtype)[0] for c in range(3)], axis=-1)


def f82_conductor(cos, f0, b, thickness, film_ior, dtype=np.float32):
    """(n, 3) reflectance of an F82-tint metal under a film: n and k from F0
    and the value at 82 degrees (Gulbrandsen), then the conductor Airy sum
    with F82 reflectances (microfacet_fresnel's F82_TINT branch)."""
    cos, thickness, film_ior = (np.asarray(a, dtype) for a in (cos, thickness, film_ior))
    f0 = np.asarray(f0, dtype)
    b = np.asarray(b, dtype)
    out = []
    for c in range(3):
        f0c, bc = f0[..., c], b[..., c]
        r = np.minimum(f0c, dtype(0.999))
        g = f82_fresnel(dtype(1.0 / 7.0), f0c, bc, dtype)
        sr = np.sqrt(r)
        n = (dtype(1.0) + sr) / (dtype(1.0) - sr)
        n = n + ((dtype(1.0) - r) / (dtype(1.0) + r) - n) * g
        k = np.sqrt(np.maximum((r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (dtype(1.0) - r), 0.0)).astype(dtype)
        out.append(fresnel_iridescence(c, 1.0, thickness, film_ior, n, k, cos, conductive=True, f82=g,
                                       dtype=dtype)[0])
    return np.stack(out, axis=-1)
