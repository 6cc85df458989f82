"""Phase functions, as Cycles' closure/volume_util.h: Henyey-Greenstein
(``volume_henyey_greenstein``) and, below, Rayleigh, Draine,
Fournier-Forand and Mie.

cos_theta is the cosine between the ray's direction of travel and the
scattered direction (g > 0 scatters forward).  |g| is clamped to 1 - 1e-3
as Cycles does, and |g| < 1e-3 is isotropic.
"""
import math

import numpy as np

from ..vec import frame, to_world

G_LIMIT = 1.0 - 1e-3
_ISOTROPIC = 1e-3


def clamp_g(g):
    return np.clip(np.asarray(g, np.float64), -G_LIMIT, G_LIMIT)


def hg_eval(cos_theta, g):
    """Phase function value (= its solid-angle pdf) per row."""
    g = clamp_g(g)
    g2 = g * g
    denom = np.maximum(1.0 + g2 - 2.0 * g * cos_theta, 1e-30)
    return (1.0 - g2) / (4.0 * np.pi * denom * np.sqrt(denom))


def hg_cos_theta(g, u):
    """Inverse CDF of cos_theta (Cycles' henyey_greenstein_sample)."""
    g = clamp_g(g)
    iso = np.abs(g) < _ISOTROPIC
    gs = np.where(iso, 0.5, g)
    k = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    cos = (1.0 + gs * gs - k * k) / (2.0 * gs)
    return np.clip(np.where(iso, 1.0 - 2.0 * u, cos), -1.0, 1.0)


def hg_sample(d, g, u1, u2):
    """Scattered unit directions about the travel directions d (N, 3) and
    their pdf (the phase function's value)."""
    cos = hg_cos_theta(g, u1)
    return direction_at(d, cos, u2), hg_eval(cos, g)


def direction_at(d, cos, u2):
    """Unit directions at angle acos(cos) to d, azimuth 2 pi u2 (Cycles'
    phase_sample_direction)."""
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    phi = 2.0 * np.pi * u2
    local = np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=1)
    s, t = frame(np.ascontiguousarray(d, np.float64))
    wi = to_world(local, s, t, d)
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    return wi


# ----------------------------------------------------------------------------
# The other phase functions of Blender 4.2+'s Volume Scatter (Cycles'
# closure/volume_util.h), and a mixture of two of them per medium (Mie is
# Henyey-Greenstein mixed with Draine).  Kinds:
HG, RAYLEIGH, DRAINE, FOURNIER_FORAND = 0, 1, 2, 3
PHASES = {"HENYEY_GREENSTEIN": HG, "RAYLEIGH": RAYLEIGH, "DRAINE": DRAINE, "FOURNIER_FORAND": FOURNIER_FORAND,
          "MIE": None}


def rayleigh_eval(cos):
    return (0.1875 / np.pi) * (1.0 + cos * cos)


def rayleigh_cos(u):
    a = 2.0 - 4.0 * u
    inv_u = -1.0 / np.cbrt(np.sqrt(1.0 + a * a) - a)
    return np.clip(1.0 / inv_u - inv_u, -1.0, 1.0)


def draine_eval(cos, g, alpha):
    """Draine's phase function (HG times (1 + alpha cos^2), normalized);
    |g| < 1e-3 with alpha > 0.999 is Rayleigh, |alpha| < 1e-3 is HG, as
    Cycles' phase_draine; |g| < 1e-3 otherwise is g = 0."""
    g = np.where(np.abs(g) < 1e-3, 0.0, np.clip(g, -G_LIMIT, G_LIMIT))
    g2 = g * g
    fac = np.maximum(1.0 + g2 - 2.0 * g * cos, 1e-30)
    out = (1.0 - g2) * (1.0 + alpha * cos * cos) / ((1.0 + alpha * (1.0 + 2.0 * g2) / 3.0) * 4.0 * np.pi * fac
                                                   * np.sqrt(fac))
    return np.where(np.abs(alpha) < 1e-3, hg_eval(cos, g), out)


def draine_cos(g, alpha, u):
    """Inverse CDF of Draine's cos theta: Cycles' phase_draine_sample_cos
    (after Jendersie and d'Eon's approximate Mie code) in float64; at g = 0
    the cubic (1 + alpha c^3 / 3 + c ...) solved by Cardano."""
    g = np.where(np.abs(g) < 1e-3, 0.0, np.clip(g, -G_LIMIT, G_LIMIT))
    alpha = np.asarray(alpha, np.float64) + 0.0 * g
    zero = g == 0.0
    gs = np.where(zero, 0.5, g)
    al = np.where(np.abs(alpha) < 1e-3, 1e-3, alpha)
    with np.errstate(all="ignore"):
        g2 = gs * gs
        g3, g4 = gs * g2, g2 * g2
        g6 = g2 * g4
        pgp1_2 = (1 + g2) ** 2
        T1a = al * (g4 - 1)
        T1a3 = T1a ** 3
        T2 = -1296 * (g2 - 1) * (al - al * g2) * T1a * (4 * g2 + al * pgp1_2)
        T9 = 2 + g2 + g3 * (1 + 2 * g2) * (2 * u - 1)
        T3 = 3 * g2 * (1 + gs * (2 * u - 1)) + al * T9
        T4a = 432 * T1a3 + T2 + 432 * (al * (1 - g2)) * T3 ** 2
        T10 = al * (2 * g4 - g2 - g6)
        T4b = 144 * T10
        T4 = T4a + np.sqrt(-4 * T4b ** 3 + T4a ** 2)
        inv_T4p3 = 1.0 / np.cbrt(T4)
        cbrt2 = 2.0 ** (1.0 / 3.0)
        T8 = 48 * cbrt2 * T10
        T6 = (2 * T1a + T8 * inv_T4p3 + 1 / (3 * cbrt2 * inv_T4p3)) / (al * (1 - g2))
        T5 = 6 * (1 + g2) + T6
        T7 = 6 * (1 + g2) - (8 * T3) / (al * (g2 - 1) * np.sqrt(T5)) - T6
        general = (1 + g2 - 0.25 * (np.sqrt(T7) - np.sqrt(T5)) ** 2) / (2 * gs)
        # g = 0: F(c) = (c + 1 + al (c^3 + 1) / 3) / (2 + 2 al / 3) = u.
        p = 3.0 / al
        q = 3.0 * (1.0 + al / 3.0 - u * (2.0 + 2.0 * al / 3.0)) / al
        disc = np.sqrt(q * q / 4.0 + p ** 3 / 27.0)
        flat = np.cbrt(-q / 2.0 + disc) + np.cbrt(-q / 2.0 - disc)
    out = np.where(zero, flat, general)
    out = np.where(np.abs(alpha) < 1e-3, hg_cos_theta(g, u), out)
    return np.clip(out, -1.0, 1.0)


def _ff_delta(n, s2):
    return 4.0 * s2 / (3.0 * (n - 1.0) ** 2)


def ff_coeffs(backscatter, ior):
    """(n, v, coefficient) of Fournier-Forand for a backscatter fraction B
    and a particle IOR (Cycles' phase_fournier_forand_coeffs)."""
    d90 = _ff_delta(ior, 0.5)
    d180 = _ff_delta(ior, 1.0)
    v = -np.log(2.0 * backscatter * (d90 - 1.0) + 1.0) / np.log(d90)
    return ior, v, (d180 ** -v - 1.0) / (d180 - 1.0)


def _ff_impl(cos, delta, pdv, v, s2, pf_coeff):
    md, mpdv = 1.0 - delta, 1.0 - pdv
    with np.errstate(all="ignore"):
        taylor = v * ((v - 1) - (v + 1) / s2) / (8 * np.pi) + v * (v + 1) * md * (
            2 * (v - 1) - (2 * v + 1) / s2) / (24 * np.pi)
        exact = (v * md - mpdv + (delta * mpdv - v * md) / s2) / (4 * np.pi * md * md * pdv)
    pf = np.where(np.abs(md) < 1e-3, taylor, exact)
    return pf + pf_coeff * (3.0 * cos * cos - 1.0)


def ff_eval(cos, n, v, c):
    pf_coeff = c / (16.0 * np.pi)
    s2 = np.maximum(0.5 * (1.0 - cos), 1e-30)
    delta = _ff_delta(n, s2)
    out = _ff_impl(cos, delta, delta ** v, v, s2, pf_coeff)
    return np.where(np.abs(cos) >= 1.0, 0.0, np.maximum(out, 0.0))


def ff_cos(u, n, v, c):
    """Cycles' phase_fournier_forand_newton: Newton on the CDF, 20 steps."""
    pf_coeff = c / (16.0 * np.pi)
    cos = np.full(np.shape(u), 0.64278760968)
    done = np.zeros(np.shape(u), bool)
    for _ in range(20):
        s2 = np.maximum(0.5 * (1.0 - cos), 1e-30)
        delta = _ff_delta(n, s2)
        cdf = _ff_theta_cdf(cos, n, v, c, 1e-30)
        pf = _ff_impl(cos, delta, delta ** v, v, s2, pf_coeff)
        with np.errstate(all="ignore"):
            new = cos + (cdf - u) / (2.0 * np.pi * pf)
        new = np.where(new >= 1.0, np.maximum(0.5 * (cos + 1.0), 0.99), new)
        new = np.where(np.isfinite(new), new, cos)
        stop = (np.abs(cos - new) < 1e-6) | (new == 1.0)
        cos = np.where(done, cos, new)
        done |= stop
        if done.all():
            break
    # Where Newton stalls (a forward peak within 1e-6 of cos = 1, e.g. a
    # negative v), bisection on log(1 - cos) finishes the inversion exactly
    # (Cycles keeps the stalled value, a sample its pdf does not describe).
    bad = np.flatnonzero(np.abs(_ff_theta_cdf(cos, n, v, c) - u) > 1e-7)
    if len(bad):
        lo, hi = np.full(len(bad), np.log(2.3e-16)), np.full(len(bad), np.log(2.0))   # log(1 - cos) < 0
        ub = np.asarray(u)[bad]
        nb, vb, cb = (np.broadcast_to(x, np.shape(u))[bad] for x in (n, v, c))
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            below = _ff_theta_cdf(1.0 - np.exp(mid), nb, vb, cb) < ub
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        cos = np.array(cos)
        cos[bad] = 1.0 - np.exp(0.5 * (lo + hi))
    return np.clip(cos, -1.0, 1.0)


def _ff_theta_cdf(cos, n, v, c, floor=1e-300):
    """P(angle < theta) of Fournier-Forand at cos theta (the paper's CDF)."""
    s2 = np.maximum(0.5 * (1.0 - cos), floor)
    delta = _ff_delta(n, s2)
    pdv = delta ** v
    md, mpdv = 1.0 - delta, 1.0 - pdv
    with np.errstate(all="ignore"):
        cdf = np.where(np.abs(md) < 1e-3, 1 + v * (1 - s2) * (1 - 0.5 * (v + 1) * md),
                       (1 - pdv * delta - mpdv * s2) / (md * pdv))
    return cdf + c / 8.0 * cos * (1 - cos * cos)


def mie_params(d):
    """(g_HG, g_D, alpha, w) of the Mie approximation for water droplets of
    diameter d micrometres: HG(g_HG) x (1 - w) + Draine(g_D, alpha) x w
    (Cycles' phase_mie_fitted_parameters, Jendersie and d'Eon 2023)."""
    d = max(float(d), 0.0)
    if d <= 0.1:
        return 13.8 * d * d, 1.1456 * d * math.sin(9.29044 * d), 250.0, 0.252977 - 312.983 * d ** 4.3
    if d < 1.5:
        ld = math.log(d)
        a = (ld - 0.238604) * (ld + 1.00667)
        b = 0.507522 - 0.15677 * ld
        c = 1.19692 * math.cos(a / b) + 1.37932 * ld + 0.0625835
        return (0.862 - 0.143 * ld * ld, 0.379685 * math.cos(c) + 0.344213, 250.0,
                0.146209 * math.cos(3.38707 * ld + 2.11193) + 0.316072 + 0.0778917 * ld)
    if d < 5.0:
        ld = math.log(d)
        temp = math.cos(5.68947 * (math.log(ld) - 0.0292149))
        return (0.0604931 * math.log(ld) + 0.940256, 0.500411 - 0.081287 / (-2.0 * ld + math.tan(ld) + 1.27551),
                7.30354 * ld + 6.31675, 0.026914 * (ld - temp) + 0.3764)
    return (math.exp(-0.0990567 / (d - 1.67154)), math.exp(-2.20679 / (d + 3.91029) - 0.428934),
            math.exp(3.62489 - 8.29288 / (d + 5.52825)), math.exp(-0.599085 / (d - 0.641583) - 0.665888))


def mixture_of(volume):
    """A medium's phase function as (k1, a1, b1, k2, a2, b2, w): lobe 1
    (kind, parameters) weighted 1 - w, lobe 2 weighted w."""
    phase = getattr(volume, "phase", "HENYEY_GREENSTEIN")
    g = getattr(volume, "anisotropy", 0.0)
    # A textured g (Henyey-Greenstein only) is the field's, per point: the
    # medium's mixture is then plain HG, which takes each scattering's g.
    g = float(g) if isinstance(g, (int, float, np.floating, np.integer)) else 0.0
    if phase == "RAYLEIGH":
        return (RAYLEIGH, 0.0, 0.0, RAYLEIGH, 0.0, 0.0, 0.0)
    if phase == "DRAINE":
        return (DRAINE, g, float(volume.alpha), DRAINE, g, float(volume.alpha), 0.0)
    if phase == "FOURNIER_FORAND":
        return (FOURNIER_FORAND, float(volume.backscatter), float(volume.ior), FOURNIER_FORAND,
                float(volume.backscatter), float(volume.ior), 0.0)
    if phase == "MIE":
        g_hg, g_d, alpha, w = mie_params(volume.diameter)
        return (HG, g_hg, 0.0, DRAINE, g_d, alpha, min(max(w, 0.0), 1.0))
    return (HG, g, 0.0, HG, g, 0.0, 0.0)


def _lobe_eval(kind, a, b, cos):
    out = np.zeros(len(cos))
    for k, fn in ((HG, lambda c, a, b: hg_eval(c, a)), (RAYLEIGH, lambda c, a, b: rayleigh_eval(c)),
                  (DRAINE, draine_eval), (FOURNIER_FORAND, _ff_eval_ab)):
        m = kind == k
        if m.any():
            out[m] = fn(cos[m], a[m], b[m])
    return out


def _ff_eval_ab(cos, backscatter, ior):
    n, v, c = ff_coeffs(backscatter, ior)
    return ff_eval(cos, n, v, c)


def _lobe_cos(kind, a, b, u):
    out = np.zeros(len(u))
    for k in (HG, RAYLEIGH, DRAINE, FOURNIER_FORAND):
        m = kind == k
        if not m.any():
            continue
        if k == HG:
            out[m] = hg_cos_theta(a[m], u[m])
        elif k == RAYLEIGH:
            out[m] = rayleigh_cos(u[m])
        elif k == DRAINE:
            out[m] = draine_cos(a[m], b[m], u[m])
        else:
            n, v, c = ff_coeffs(a[m], b[m])
            out[m] = ff_cos(u[m], n, v, c)
    return out


def phase_eval(cos, mix):
    """Phase function value (= pdf) of mixtures ``mix`` (7 arrays (N,))."""
    k1, a1, b1, k2, a2, b2, w = mix
    f = _lobe_eval(k1, a1, b1, cos)
    two = w > 0
    if two.any():
        f[two] = (1.0 - w[two]) * f[two] + w[two] * _lobe_eval(k2[two], a2[two], b2[two], cos[two])
    return f


def phase_sample(d, mix, u1, u2):
    """Scattered directions about travel directions d and their pdf: a lobe
    chosen by the mixture weight (u1 reused), then its cos theta."""
    k1, a1, b1, k2, a2, b2, w = mix
    second = u1 < w
    u = np.where(second, u1 / np.where(w > 0, w, 1.0), (u1 - w) / np.where(w < 1, 1.0 - w, 1.0))
    u = np.clip(u, 0.0, 1.0 - 1e-12)
    kind = np.where(second, k2, k1)
    cos = _lobe_cos(kind, np.where(second, a2, a1), np.where(second, b2, b1), u)
    return direction_at(d, cos, u2), phase_eval(cos, mix)
