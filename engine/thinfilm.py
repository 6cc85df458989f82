"""Thin-film iridescence: the Airy / Belcour-Barla Fresnel of a dielectric
film on a dielectric substrate, as Cycles computes it (closure/bsdf_util.h,
``fresnel_iridescence``, Blender 4.2's form with the Gaussian fit of the
CIE XYZ sensitivities; Belcour and Barla, "A Practical Extension to
Microfacet Theory for the Modeling of Varying Iridescence", SIGGRAPH 2017).

Elementwise on arrays, in float32 as Cycles (``dtype``: float64 for a
reference).  Thickness is in nanometres; ``eta1`` is the ambient IOR, ``eta2``
the film's and ``eta3`` the substrate's.  Films under 30 nm blend their IOR
towards the ambient one (thickness 0: the plain Fresnel of eta3 / eta1).

Not yet here (see docs/design.md, "Thin film"): Cycles 5.0 replaced the
Gaussian fit by a lookup table of the working space's RGB sensitivities
and added conductor substrates (F82 / complex IOR); the lobes do not call
this yet.
"""
import numpy as np

# Rec.709 / sRGB primaries, D65 (Blender's default scene-linear space):
# Cycles' xyz_to_rgb and film.white_xyz (the XYZ of RGB white).
XYZ_TO_RGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                       [-0.9692660, 1.8760108, 0.0415560],
                       [0.0556434, -0.2040259, 1.0572252]])
RGB_TO_XYZ = np.linalg.inv(XYZ_TO_RGB)
WHITE_XYZ = RGB_TO_XYZ @ np.ones(3)

_VAL = (5.4856e-13, 4.4201e-13, 5.2481e-13)
_POS = (1.6810e+06, 1.7953e+06, 2.2084e+06)
_VAR = (4.3278e+09, 9.3046e+09, 6.6121e+09)


def fresnel_dielectric_polarized(cos_i, eta, dtype=np.float32):
    """(R_s, R_p), cos of the transmitted angle (negative, relative to the
    normal) and the phase shifts on reflection (0 or pi); TIR: R = 1."""
    cos_i = np.asarray(cos_i, dtype)
    eta = np.asarray(eta, dtype)
    t2 = eta * eta - (dtype(1.0) - cos_i * cos_i)
    tir = t2 <= 0
    c = np.abs(cos_i)
    cos_t = -np.sqrt(np.maximum(t2, dtype(0.0))) / eta
    with np.errstate(divide="ignore", invalid="ignore"):
        r_s = (c + eta * cos_t) / (c - eta * cos_t)
        r_p = (cos_t + eta * c) / (eta * c - cos_t)
    pi = dtype(np.pi)
    phi_s = np.where(tir, dtype(0.0), np.where(r_s < 0, pi, dtype(0.0)))
    phi_p = np.where(tir, dtype(0.0), np.where(r_p < 0, pi, dtype(0.0)))
    one = dtype(1.0)
    return (np.where(tir, one, r_s * r_s), np.where(tir, one, r_p * r_p),
            np.where(tir, dtype(0.0), cos_t), phi_s, phi_p)


def sensitivity(opd, shift, dtype=np.float32):
    """(..., 3) XYZ sensitivity of an optical path difference (nm) and phase
    shift: Cycles' iridescence_lookup_sensitivity."""
    phase = (dtype(2.0 * np.pi) * np.asarray(opd, dtype) * dtype(1e-9))[..., None]
    shift = np.asarray(shift, dtype)[..., None]
    val, pos, var = (np.array(v, dtype) for v in (_VAL, _POS, _VAR))
    xyz = val * np.sqrt(dtype(2.0 * np.pi) * var) * np.cos(pos * phase + shift) * np.exp(-(phase * phase) * var)
    p = phase[..., 0]
    extra = dtype(1.64408e-8) * np.cos(dtype(2.2399e+06) * p + shift[..., 0]) * np.exp(dtype(-4.5282e+09) * (p * p))
    xyz = np.concatenate([(xyz[..., 0] + extra)[..., None], xyz[..., 1:]], axis=-1)
    return xyz / dtype(1.0685e-7)


def airy_summation(t121, r12, r23, opd, phi, dtype=np.float32):
    """(..., 3) XYZ reflectance of one polarisation, orders m <= 3."""
    r123 = r12 * r23
    sq = np.sqrt(r123)
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = t121 * t121 * r23 / (dtype(1.0) - r123)
    out = np.repeat((r12 + rs)[..., None], 3, axis=-1)
    cm = rs - t121
    for m in range(1, 4):
        cm = cm * sq
        out = out + (cm * dtype(2.0))[..., None] * sensitivity(dtype(m) * opd, dtype(m) * phi, dtype)
    return np.where((r23 == 1.0)[..., None], dtype(1.0), out)


def smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fresnel_iridescence(eta1, eta2, eta3, cos1, thickness, dtype=np.float32):
    """(..., 3) RGB reflectance of a thin film (Cycles' fresnel_iridescence)
    and the cos of the angle transmitted into the substrate (0 under TIR)."""
    eta1, eta2, eta3, cos1, thickness = np.broadcast_arrays(*(np.asarray(a, dtype)
                                                              for a in (eta1, eta2, eta3, cos1, thickness)))
    thin = thickness < 30.0
    s = smoothstep(dtype(0.0), dtype(30.0), thickness).astype(dtype)
    eta2 = np.where(thin, eta1 + (eta2 - eta1) * s, eta2).astype(dtype)
    r12s, r12p, cos2, phi12s, phi12p = fresnel_dielectric_polarized(cos1, eta2 / eta1, dtype)
    opd = dtype(-2.0) * eta2 * thickness * cos2
    r23s, r23p, cos3, phi23s, phi23p = fresnel_dielectric_polarized(-cos2, eta3 / eta2, dtype)
    pi = dtype(np.pi)
    rs = airy_summation(dtype(1.0) - r12s, r12s, r23s, opd, pi - phi12s + phi23s, dtype)
    rp = airy_summation(dtype(1.0) - r12p, r12p, r23p, opd, pi - phi12p + phi23p, dtype)
    xyz = (rs + (rp - rs) * dtype(0.5)) * WHITE_XYZ.astype(dtype)
    rgb = np.clip(xyz @ XYZ_TO_RGB.T.astype(dtype), 0.0, 1.0).astype(dtype)
    tir = ((r12s == 1.0) & (r12p == 1.0)) | ((r23s == 1.0) & (r23p == 1.0))
    rgb = np.where(tir[..., None], dtype(1.0), rgb)
    return rgb, np.where(tir, dtype(0.0), cos3)
