"""A ray segment through homogeneous media (Cycles' homogeneous volume
integration with distance sampling).

Along a segment of length t_end in a medium of extinction sigma_t =
sigma_a + sigma_s, the radiance reaching the ray's start is

    integral_0^t_end T(s) (emission + sigma_s L_in(s)) ds + T(t_end) L_end,

with T(s) = exp(-sigma_t s) per channel.  The emission term is integrated in
closed form (Cycles' volume_emission_integrate).  The rest is estimated by
one distance: a colour channel c is chosen with probability proportional to
|throughput x albedo| (Cycles' volume_sample_channel_pdf), a distance from
sigma_t[c] exp(-sigma_t[c] s); the estimate divides by the pdf summed over
the channels (one-sample MIS over the three strategies), so a grey medium
is exact and a coloured one never divides by a channel's tiny pdf.
A segment that may not scatter (absorption only, or past the volume
bounces) is attenuated by T(t_end).
"""
from dataclasses import dataclass

import numpy as np

from .. import kernels
from .tracking import track, transmittance


@dataclass
class FreeFlight:
    """One free flight per row of ``rows`` (the paths in a medium): the
    segment's end, whether a scattering happened before it and where
    (t; inf where not), the factor on the throughput, the emission integral
    (times the throughput at the segment's start), the phase function's g,
    and, for lights met on the way, the channel pdfs."""
    rows: np.ndarray
    t_end: np.ndarray
    scatter: np.ndarray
    t: np.ndarray
    weight: np.ndarray
    emitted: np.ndarray
    g: np.ndarray
    sigma_t: np.ndarray
    channel_pdf: np.ndarray   # (n, 3); 0 rows where the segment may not scatter
    samples: np.ndarray       # which rows sampled a distance
    # Rows in a heterogeneous medium, tracked (tracking.py), and their
    # throughput factor on reaching the light met on the way.
    tracked: np.ndarray = None
    light_w: np.ndarray = None
    truncated: int = 0
    # (n,) the medium whose phase function a scattering follows (-1:
    # Henyey-Greenstein of g), MediumTable.phase_medium.
    phase_medium: np.ndarray = None
    # Set by the integrator (engine/integrator/volume.py): the factor on the
    # light sampled at the scattering point, and the equiangular direct-light
    # points (rows, t, throughput factor, emitter, its selection
    # probability, g at the point) or None.
    nee_scale: np.ndarray = None
    direct: tuple = None


def _exp_neg(sigma, t):
    """exp(-sigma t), 1 where sigma is 0 (also for t = inf)."""
    with np.errstate(invalid="ignore", over="ignore"):
        return np.where(sigma > 0, np.exp(-sigma * np.where(sigma > 0, t, 0.0)), 1.0)


def emission_integral(emission, sigma_t, t):
    """integral_0^t exp(-sigma_t s) ds x emission, per channel; 0 where it
    would be infinite (an emitting, non-extinguishing medium without end)."""
    t = np.asarray(t, np.float64)[:, None] if np.ndim(t) == 1 else t
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        out = np.where(sigma_t > 0, (1.0 - _exp_neg(sigma_t, t)) / np.where(sigma_t > 0, sigma_t, 1.0),
                       np.where(np.isfinite(t), t, 0.0))
    return emission * out


def channel_pdf(beta, sigma_s, sigma_t):
    """Cycles' volume_sample_channel_pdf: |beta x albedo| normalized, else uniform."""
    with np.errstate(invalid="ignore", divide="ignore"):
        albedo = np.where(sigma_t > 0, sigma_s / np.where(sigma_t > 0, sigma_t, 1.0), 0.0)
    w = np.abs(beta * albedo)
    total = w.sum(axis=1)
    return np.where(total[:, None] > 0, w / np.where(total > 0, total, 1.0)[:, None], 1.0 / 3.0)


def free_flight(table, stack, beta, t_end, may_scatter, u_channel, u_distance, o=None, d=None, rng=None,
                x_light=None, media=None):
    """The FreeFlight of segments of length t_end (inf: no end) in the
    media of ``stack`` (rows of the paths in a medium); ``may_scatter``:
    the path has scattering events left.  Rows whose stack holds a
    heterogeneous medium are tracked along o + t d (tracking.py, random
    numbers from ``rng``; ``x_light``: where a light on the ray is).
    ``media``: table.stack_media(stack) when the caller has it."""
    sa, ss, em, g, phase_medium = table.stack_media(stack) if media is None else media
    flight = _homogeneous_flight(sa, ss, em, g, beta, t_end, may_scatter, u_channel, u_distance)
    flight.phase_medium = phase_medium
    het = table.heterogeneous(stack)
    flight.tracked = het
    if het.any():
        h = np.flatnonzero(het)
        xl = None if x_light is None else x_light[h]
        tr = track(table, stack[h], o[h], d[h], t_end[h], rng, "flight", beta[h], may_scatter[h], xl)
        flight.scatter[h], flight.t[h], flight.weight[h] = tr.scatter, tr.t, tr.weight
        flight.emitted[h], flight.g[h] = tr.emitted, tr.g
        flight.samples[h] = False
        flight.channel_pdf[h] = 0.0
        flight.light_w = np.zeros((len(stack), 3))
        flight.light_w[h] = tr.light_w
        flight.truncated = tr.truncated
    return flight


def _homogeneous_flight(sa, ss, em, g, beta, t_end, may_scatter, u_channel, u_distance):
    n = len(sa)
    scatter, samples = np.empty(n, bool), np.empty(n, bool)
    t = np.empty(n)
    weight, emitted, st, pc = (np.empty((n, 3)) for _ in range(4))
    f64 = np.float64
    _flight_rows(np.ascontiguousarray(sa, f64), np.ascontiguousarray(ss, f64), np.ascontiguousarray(em, f64),
                 np.ascontiguousarray(beta, f64), np.ascontiguousarray(t_end, f64),
                 np.ascontiguousarray(may_scatter, bool), np.ascontiguousarray(u_channel, f64),
                 np.ascontiguousarray(u_distance, f64), scatter, t, weight, emitted, st, pc, samples)
    return FreeFlight(None, t_end, scatter, t, weight, emitted, g, st, pc, samples)


def _flight_numpy(sa, ss, em, beta, t_end, may_scatter, u_channel, u_distance,
                  scatter, t, weight, emitted, st, pc, samples):
    """The reference form of ``_flight_rows`` (the module's docstring)."""
    n = len(sa)
    st[:] = sa + ss
    emitted[:] = emission_integral(em, st, t_end)
    samples[:] = may_scatter & np.any(ss > 0, axis=1)
    pc[:] = np.where(samples[:, None], channel_pdf(beta, ss, st), 0.0)
    c = np.minimum((u_channel[:, None] >= np.cumsum(pc, axis=1)).sum(axis=1), 2)
    sig_c = st[np.arange(n), c]
    with np.errstate(divide="ignore"):
        t[:] = np.where(samples & (sig_c > 0), -np.log1p(-np.minimum(u_distance, 1.0 - 2 ** -53))
                        / np.where(sig_c > 0, sig_c, 1.0), np.inf)
    scatter[:] = t < t_end
    T_end = _exp_neg(st, t_end[:, None])
    weight[:] = T_end
    s = np.flatnonzero(scatter)
    if len(s):
        T_t = _exp_neg(st[s], t[s, None])
        pdf = (pc[s] * st[s] * T_t).sum(axis=1)
        weight[s] = ss[s] * T_t / np.maximum(pdf, 1e-300)[:, None]
    p = np.flatnonzero(samples & ~scatter)
    if len(p):
        P = (pc[p] * T_end[p]).sum(axis=1)
        weight[p] = np.where(P[:, None] > 0, T_end[p] / np.where(P > 0, P, 1.0)[:, None], 0.0)


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], "
                     "boolean[::1], float64[::1], float64[::1], boolean[::1], float64[::1], float64[:, ::1], "
                     "float64[:, ::1], float64[:, ::1], float64[:, ::1], boolean[::1])", _flight_numpy)
def _flight_rows(sa, ss, em, beta, t_end, may_scatter, u_channel, u_distance,
                 scatter, t, weight, emitted, st, pc, samples):
    for i in range(sa.shape[0]):
        te = t_end[i]
        any_s = False
        total = 0.0
        for c in range(3):
            s = sa[i, c] + ss[i, c]
            st[i, c] = s
            if s > 0:
                e = (1.0 - np.exp(-s * te)) / s
            else:
                e = te if np.isfinite(te) else 0.0
            emitted[i, c] = em[i, c] * e
            any_s = any_s or ss[i, c] > 0
            pc[i, c] = abs(beta[i, c] * (ss[i, c] / s if s > 0 else 0.0))
            total += pc[i, c]
        smp = may_scatter[i] and any_s
        samples[i] = smp
        for c in range(3):
            pc[i, c] = (pc[i, c] / total if total > 0 else 1.0 / 3.0) if smp else 0.0
        # The channel: the first whose cumulative pdf passes u (Cycles' volume_sample_channel).
        ch, cum = 0, pc[i, 0]
        while ch < 2 and u_channel[i] >= cum:
            ch += 1
            cum += pc[i, ch]
        sig = st[i, ch]
        ti = np.inf
        if smp and sig > 0:
            ti = -np.log1p(-min(u_distance[i], 1.0 - 2.0 ** -53)) / sig
        t[i] = ti
        sc = ti < te
        scatter[i] = sc
        pdf, P = 0.0, 0.0
        for c in range(3):
            s = st[i, c]
            T = np.exp(-s * te) if s > 0 else 1.0
            weight[i, c] = T
            P += pc[i, c] * T
            if sc:
                T_t = np.exp(-s * ti) if s > 0 else 1.0
                weight[i, c] = ss[i, c] * T_t
                pdf += pc[i, c] * s * T_t
        if sc:
            for c in range(3):
                weight[i, c] /= max(pdf, 1e-300)
        elif smp:
            for c in range(3):
                weight[i, c] = weight[i, c] / P if P > 0 else 0.0


def light_factor(flight, k, x):
    """Throughput factor at distance x (< the segment's end) of rows k of a
    flight, for a light met there: T(x) / P(no scattering before x), 0
    where the path scattered before x; T(x) where the segment samples no
    distance."""
    T = _exp_neg(flight.sigma_t[k], x[:, None])
    out = T.copy()
    smp = flight.samples[k]
    if smp.any():
        P = (flight.channel_pdf[k] * T).sum(axis=1)
        ok = smp & (flight.t[k] > x) & (P > 0)
        out[smp] = np.where(ok[smp, None], T[smp] / np.where(P[smp] > 0, P[smp], 1.0)[:, None], 0.0)
    if flight.tracked is not None and flight.tracked[k].any():
        tk = flight.tracked[k]
        out[tk] = flight.light_w[k[tk]]
    return out


def transmittance_factor(table, stack, length, o=None, d=None, rng=None):
    """(N, 3) transmittance of segments of ``length`` through the media of
    ``stack``: exp(-sigma_t length) in homogeneous media, a ratio-tracking
    estimate along o + t d where a heterogeneous medium is in the stack."""
    length = np.asarray(length, np.float64)
    out = _exp_neg(table.extinction(stack), length[:, None])
    het = table.heterogeneous(stack)
    if het.any():
        h = np.flatnonzero(het)
        out[h] = transmittance(table, stack[h], o[h], d[h], length[h], rng)
    return out
