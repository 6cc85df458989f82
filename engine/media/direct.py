"""Direct-light points along a segment through homogeneous media
(engine/integrator/volume.py's equiangular / distance points, Cycles 5.0's
homogeneous direct scatter): per row, a distance in the lit part [t0, t1]
sampled equiangularly towards the light point P, or from the free flight's
channel mixture of exponentials truncated to [t0, t1]; and both pdfs of
the distance, for the power heuristic.  One compiled row loop
(``_points_rows``) with its NumPy reference form (``_points_numpy``).
"""
import numpy as np

from .. import kernels
from . import equiangular


def truncated_exponential(sigma, t0, t1, xi):
    """Distances in [t0, t1] of density sigma exp(-sigma (t - t0)),
    renormalized (uniform where sigma is 0)."""
    length = t1 - t0
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        mass = -np.expm1(-sigma * length)
        t = t0 - np.log1p(-xi * mass) / np.where(sigma > 0, sigma, 1.0)
        t = np.where(sigma > 0, t, t0 + xi * np.where(np.isfinite(length), length, 0.0))
    return np.clip(t, t0, t1)


def truncated_pdf(pc, sigma, t0, t1, t):
    """The channel mixture's pdf of ``truncated_exponential`` distances."""
    length = (t1 - t0)[:, None]
    x = (t - t0)[:, None]
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        mass = -np.expm1(-sigma * length)
        each = np.where(sigma > 0, sigma * np.exp(-sigma * x) / np.where(mass > 0, mass, 1.0),
                        np.where(np.isfinite(length), 1.0 / np.where(length > 0, length, 1.0), 0.0))
    out = (pc * np.where(np.isfinite(each), each, 0.0)).sum(axis=1)
    return np.where((t >= t0) & (t <= t1) & (t1 > t0), out, 0.0)


def sample_points(o, d, P, t0, t1, xi, uc, pc, st, equi, skip):
    """(t, equiangular pdf, distance pdf) per row: equiangular where
    ``equi``, else a truncated distance of channel c chosen by ``uc`` from
    ``pc``; rows ``skip`` (heterogeneous: sampled elsewhere) get t 0, p_e 0."""
    n = len(o)
    t, p_e, p_d = np.empty(n), np.empty(n), np.empty(n)
    f64 = np.float64
    _points_rows(*(np.ascontiguousarray(a, f64) for a in (o, d, P, t0, t1, xi, uc, pc, st)),
                 np.ascontiguousarray(equi, bool), np.ascontiguousarray(skip, bool), t, p_e, p_d)
    return t, p_e, p_d


def _points_numpy(o, d, P, t0, t1, xi, uc, pc, st, equi, skip, t, p_e, p_d):
    t[:], p_e[:] = 0.0, 0.0
    e = np.flatnonzero(equi & ~skip)
    t[e], p_e[e] = equiangular.sample(o[e], d[e], P[e], t0[e], t1[e], xi[e])
    k = np.flatnonzero(~equi & ~skip)
    if len(k):
        c = np.minimum((uc[k, None] >= np.cumsum(pc[k], axis=1)).sum(axis=1), 2)
        t[k] = truncated_exponential(st[k, c], t0[k], t1[k], xi[k])
        p_e[k] = equiangular.pdf(o[k], d[k], P[k], t0[k], t1[k], t[k])
    p_d[:] = truncated_pdf(pc, st, t0, t1, t)


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], "
                     "float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], boolean[::1], boolean[::1], "
                     "float64[::1], float64[::1], float64[::1])", _points_numpy)
def _points_rows(o, d, P, t0, t1, xi, uc, pc, st, equi, skip, t, p_e, p_d):
    for i in range(o.shape[0]):
        a0, b0 = t0[i], t1[i]
        # The light point's frame on the ray (equiangular._frame, _angles).
        q0, q1, q2 = P[i, 0] - o[i, 0], P[i, 1] - o[i, 1], P[i, 2] - o[i, 2]
        delta = q0 * d[i, 0] + q1 * d[i, 1] + q2 * d[i, 2]
        r0, r1, r2 = q0 - d[i, 0] * delta, q1 - d[i, 1] * delta, q2 - d[i, 2] * delta
        D = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        lo = np.arctan2(a0 - delta, D)
        hi = np.arctan2(b0 - delta, D) if np.isfinite(b0) else 0.5 * np.pi
        span = hi - lo
        frame_ok = D > 1e-12 and span > 1e-9 and np.isfinite(delta) and b0 > a0
        ti, pe = 0.0, 0.0
        if skip[i]:
            pass
        elif equi[i]:
            if frame_ok:
                tt = D * np.tan(xi[i] * hi + (1.0 - xi[i]) * lo)
                x = min(max(delta + tt, a0), b0)
                pdf = D / (span * (D * D + tt * tt))
                if np.isfinite(x) and pdf > 0 and np.isfinite(pdf):
                    ti, pe = x, pdf
        else:
            ch, cum = 0, pc[i, 0]
            while ch < 2 and uc[i] >= cum:
                ch += 1
                cum += pc[i, ch]
            sigma, length = st[i, ch], b0 - a0
            if sigma > 0:
                x = a0 - np.log1p(-xi[i] * -np.expm1(-sigma * length)) / sigma
            else:
                x = a0 + xi[i] * (length if np.isfinite(length) else 0.0)
            ti = min(max(x, a0), b0)
            if frame_ok and ti >= a0 and ti <= b0:
                tt = ti - delta
                pdf = D / (span * (D * D + tt * tt))
                pe = pdf if np.isfinite(pdf) else 0.0
        t[i], p_e[i] = ti, pe
        # The channel mixture's truncated pdf (truncated_pdf).
        length, x = b0 - a0, ti - a0
        out = 0.0
        for c in range(3):
            sigma = st[i, c]
            if sigma > 0:
                mass = -np.expm1(-sigma * length)
                each = sigma * np.exp(-sigma * x) / (mass if mass > 0 else 1.0)
            else:
                each = (1.0 / (length if length > 0 else 1.0)) if np.isfinite(length) else 0.0
            out += pc[i, c] * (each if np.isfinite(each) else 0.0)
        p_d[i] = out if ti >= a0 and ti <= b0 and b0 > a0 else 0.0


def point_weights(t, p_e, p_d, equi, mis, t0, t1, st, ss):
    """(good, factor) of sampled direct-light points: good where the point's
    pdf p (p_e where ``equi``, else p_d) is positive, t finite and the lit
    part not empty; factor (N, 3) = ss exp(-st t) w / p, w = 2 x the power
    heuristic of p against the other pdf under MIS (Cycles'
    volume_direct_scatter_mis), else 1; 0 where not good."""
    n = len(t)
    good, factor = np.empty(n, bool), np.empty((n, 3))
    f64 = np.float64
    _weights_rows(*(np.ascontiguousarray(a, f64) for a in (t, p_e, p_d)), np.ascontiguousarray(equi, bool),
                  np.ascontiguousarray(mis, bool), *(np.ascontiguousarray(a, f64) for a in (t0, t1, st, ss)),
                  good, factor)
    return good, factor


def _weights_numpy(t, p_e, p_d, equi, mis, t0, t1, st, ss, good, factor):
    p = np.where(equi, p_e, p_d)
    q = np.where(equi, p_d, p_e)
    good[:] = (p > 0) & np.isfinite(t) & (t1 > t0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        a2 = p * p
        h = a2 / (a2 + q * q)
        h = np.where(np.isfinite(h), h, np.where(np.isinf(p) & np.isfinite(q), 1.0, 0.0))   # sampling.power_heuristic
        w = np.where(mis, 2.0 * h, 1.0)
        f = ss * np.exp(-st * t[:, None]) * (w / np.where(good, p, 1.0))[:, None]
    factor[:] = np.where(good[:, None], f, 0.0)


@kernels.loop_kernel("void(float64[::1], float64[::1], float64[::1], boolean[::1], boolean[::1], float64[::1], "
                     "float64[::1], float64[:, ::1], float64[:, ::1], boolean[::1], float64[:, ::1])", _weights_numpy)
def _weights_rows(t, p_e, p_d, equi, mis, t0, t1, st, ss, good, factor):
    for i in range(t.shape[0]):
        p, q = (p_e[i], p_d[i]) if equi[i] else (p_d[i], p_e[i])
        ok = p > 0 and np.isfinite(t[i]) and t1[i] > t0[i]
        good[i] = ok
        if not ok:
            factor[i, 0], factor[i, 1], factor[i, 2] = 0.0, 0.0, 0.0
            continue
        w = 1.0
        if mis[i]:
            a2 = p * p
            h = a2 / (a2 + q * q)
            if not np.isfinite(h):
                h = 1.0 if np.isinf(p) and np.isfinite(q) else 0.0
            w = 2.0 * h
        s = w / p
        for c in range(3):
            factor[i, c] = ss[i, c] * np.exp(-st[i, c] * t[i]) * s
