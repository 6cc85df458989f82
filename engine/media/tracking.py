"""Null-scattering tracking through heterogeneous media (Cycles 5.0's
default volume integration: unbiased, against a majorant).

Along a ray in a stack holding a heterogeneous medium, tentative collisions
are a Poisson process of rate mu (the majorant: the homogeneous media's
largest extinction plus the Fields' grid majorants, piecewise constant
along the ray, stepped cell by cell).  At each collision the coefficients
are evaluated and, with sigma_n = mu - sigma_t per channel:

* ``flight`` (a path's free flight; spectral tracking, Kutz et al. 2017,
  with absorption kept as a weight): emission is collected as w x
  emission / mu; where the path may scatter, it scatters with probability
  P_s = mean|w sigma_s| / (mean|w sigma_s| + mean|w sigma_n|), its weight
  times sigma_s / (mu P_s), else it goes on with weight times
  sigma_n / (mu (1 - P_s)).  A path that may not scatter goes on with
  weight times sigma_n / mu (ratio tracking).
* ``ratio`` (shadow rays): weight times sigma_n / mu at each collision.
* ``delta`` (shadow rays, weighted delta tracking): survives with
  probability P = min(mean|sigma_n| / mu, 1), weight times
  sigma_n / (mu P); grey media under their majorant give 0 or 1.

Every estimator is unbiased for any positive majorant, also where
sigma_t > mu (a negative null weight).  Weights below RR_LEVEL are
Russian-rouletted; a ray still tracking after MAX_EVENTS collisions is
ended with weight 0 and counted (``Tracked.truncated``), so no density, however
large, can hang a render.
"""
from dataclasses import dataclass

import numpy as np

from .. import kernels

MAX_EVENTS = 512
# Tentative collisions drawn per row at once: shadow rays use them all;
# a free flight often stops at its first real collision.
BATCH = {"flight": 8, "ratio": 8, "delta": 8}
RR_LEVEL = 0.05


@dataclass
class Tracked:
    weight: np.ndarray     # (N, 3) the segment's throughput factor (pass or scatter)
    scatter: np.ndarray    # (N,) scattered inside the segment
    t: np.ndarray          # (N,) where (inf: not)
    emitted: np.ndarray    # (N, 3) emission collected, relative to the throughput at the start
    g: np.ndarray          # (N,) Henyey-Greenstein g at the scattering point
    light_w: np.ndarray    # (N, 3) weight on reaching x_light (0 if scattered or stopped first)
    truncated: int = 0


def track(table, stack, o, d, t_end, rng, mode="flight", beta=None, may_scatter=None, x_light=None,
          homogeneous=True):
    """Track rays o + t d, 0 <= t < t_end, through the media of ``stack``.
    ``homogeneous`` False: the stack's homogeneous media are left out (the
    caller takes their transmittance in closed form)."""
    n = len(o)
    w = np.ones((n, 3))
    out = Tracked(w, np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3)), np.zeros(n), np.zeros((n, 3)))
    if n == 0:
        return out
    beta = np.ones((n, 3)) if beta is None else np.ascontiguousarray(np.abs(beta), np.float64)
    may_scatter = np.zeros(n, bool) if may_scatter is None else np.ascontiguousarray(may_scatter, bool)
    x_light = np.full(n, np.inf) if x_light is None else np.ascontiguousarray(x_light, np.float64)
    t_end = np.ascontiguousarray(t_end, np.float64)
    hsa, hss, hem, hg = table.coefficients(stack)
    if not homogeneous:
        hsa, hss, hem = np.zeros_like(hsa), np.zeros_like(hss), np.zeros_like(hem)
    hst = hsa + hss
    hmu = hst.max(axis=1)
    hgw = hss.mean(axis=1) * hg
    t = np.zeros(n)
    eps = 1e-7 * (1.0 + np.abs(o).max(axis=1))
    live = np.flatnonzero(t_end > 0)
    events = np.zeros(n, np.int64)
    while len(live):
        tl, dl, st = t[live], d[live], stack[live]
        mu, dist = table.majorant(st, o[live] + dl * (tl + eps[live])[:, None], dl)
        mu = mu + hmu[live]
        step_end = np.minimum(tl + eps[live] + dist, t_end[live])
        # K tentative collisions per row at once (one shader evaluation for
        # all of them), resolved in order by one compiled pass.
        K = BATCH[mode]
        u = rng.random((len(live), K, 4))
        with np.errstate(divide="ignore"):
            dt = np.where(mu[:, None] > 0, -np.log1p(-u[..., 0]) / np.where(mu > 0, mu, 1.0)[:, None], np.inf)
        tk = tl[:, None] + np.cumsum(dt, axis=1)
        valid = tk < step_end[:, None]
        r, k = np.nonzero(valid)
        sa = np.zeros((len(live), K, 3))
        ss, em, gw = np.zeros_like(sa), np.zeros_like(sa), np.zeros((len(live), K))
        if len(r):
            p = o[live[r]] + d[live[r]] * tk[r, k, None]
            a, b, e, g = table.local(st[r], p, dl[r])
            sa[r, k], ss[r, k], em[r, k], gw[r, k] = a, b, e, g
        sa += hsa[live][:, None]
        ss += hss[live][:, None]
        em += hem[live][:, None]
        gw += hgw[live][:, None]
        done = np.zeros(len(live), bool)
        _resolve_rows(live, t, w, tk, valid, step_end, t_end, mu, sa, ss, em, gw, u, MODES[mode], beta,
                      may_scatter, x_light, out.light_w, out.emitted, out.scatter, out.t, out.g, done)
        events[live] += K
        live = live[~done & (events[live] < MAX_EVENTS)]
        live = live[t[live] < t_end[live]]
    left = np.flatnonzero((events >= MAX_EVENTS) & (t < t_end) & ~out.scatter & np.any(w != 0, axis=1))
    if len(left):
        out.truncated = len(left)
        w[left] = 0.0
        table.note_truncated(stack[left])
    return out


MODES = {"flight": 0, "ratio": 1, "delta": 2}
_MODE_NAMES = ("flight", "ratio", "delta")


def _resolve_numpy(live, t, w, tk, valid, step_end, t_end, mu, sa, ss, em, gw, u, mode, beta, may_scatter,
                   x_light, light_w, emitted, scatter, t_out, g, done):
    """The reference form of ``_resolve_rows``: one batch of K tentative
    collisions of the rows ``live``, resolved in order (sets ``done``)."""
    out = Tracked(w, scatter, t_out, emitted, g, light_w)
    name = _MODE_NAMES[mode]
    K = tk.shape[1]
    going = np.ones(len(live), bool)     # still collides in this batch
    for j in range(K):
        c = np.flatnonzero(going & valid[:, j])
        out_of = np.flatnonzero(going & ~valid[:, j])
        if len(out_of):   # past the cell (or the segment's end) before collision j
            rows = live[out_of]
            _light(light_w, w, x_light, rows, t[rows], step_end[out_of])
            t[rows] = step_end[out_of]
            done[out_of] = step_end[out_of] >= t_end[rows]
            going[out_of] = False
        if len(c) == 0:
            continue
        rows = live[c]
        tn = tk[c, j]
        _light(light_w, w, x_light, rows, t[rows], tn)
        t[rows] = tn
        stop = _collide(out, w, rows, tn, mu[c], sa[c, j], ss[c, j], em[c, j], gw[c, j], u[c, j], name,
                        beta, may_scatter)
        done[c] |= stop
        going[c] &= ~stop


@kernels.loop_kernel("void(int64[::1], float64[::1], float64[:, ::1], float64[:, ::1], boolean[:, ::1], "
                     "float64[::1], float64[::1], float64[::1], float64[:, :, ::1], float64[:, :, ::1], "
                     "float64[:, :, ::1], float64[:, ::1], float64[:, :, ::1], int64, float64[:, ::1], "
                     "boolean[::1], float64[::1], float64[:, ::1], float64[:, ::1], boolean[::1], float64[::1], "
                     "float64[::1], boolean[::1])", _resolve_numpy)
def _resolve_rows(live, t, w, tk, valid, step_end, t_end, mu, sa, ss, em, gw, u, mode, beta, may_scatter,
                  x_light, light_w, emitted, scatter, t_out, g, done):
    K = tk.shape[1]
    wr = np.empty(3)
    sn = np.empty(3)
    for i in range(live.shape[0]):
        r = live[i]
        for j in range(K):
            t1 = step_end[i] if not valid[i, j] else tk[i, j]
            if t[r] < x_light[r] and x_light[r] <= t1:   # the light on the ray is passed: the weight there
                for c in range(3):
                    light_w[r, c] = w[r, c]
            t[r] = t1
            if not valid[i, j]:   # past the cell (or the segment's end) before collision j
                done[i] = t1 >= t_end[r]
                break
            m = mu[i]
            any_s = False
            a, b, mean_ss, mean_sn = 0.0, 0.0, 0.0, 0.0
            for c in range(3):
                wr[c] = w[r, c]
                sn[c] = m - sa[i, j, c] - ss[i, j, c]
                any_s = any_s or ss[i, j, c] > 0
                a += abs(beta[r, c] * wr[c] * ss[i, j, c]) / 3.0
                b += abs(beta[r, c] * wr[c] * sn[c]) / 3.0
                mean_ss += ss[i, j, c] / 3.0
                mean_sn += abs(sn[c]) / 3.0
            stop = False
            if mode == 0:
                for c in range(3):
                    emitted[r, c] += wr[c] * em[i, j, c] / m
                ps = a / (a + b) if (may_scatter[r] and any_s and a + b > 0) else 0.0
                sc = u[i, j, 1] < ps
                ps_c = ps if sc else 1.0 - ps
                for c in range(3):
                    wr[c] = (ss[i, j, c] if sc else sn[c]) * wr[c] / (m * (ps_c if ps_c > 0 else 1.0))
                if sc:
                    scatter[r] = True
                    t_out[r] = t1
                    g[r] = gw[i, j] / mean_ss if mean_ss > 0 else 0.0
                    stop = True
            elif mode == 1:
                for c in range(3):
                    wr[c] = wr[c] * sn[c] / m
            else:
                P = min(mean_sn / m, 1.0)
                survive = u[i, j, 1] < P
                for c in range(3):
                    wr[c] = wr[c] * sn[c] / (m * (P if P > 0 else 1.0)) if survive else 0.0
                stop = not survive
            # Russian roulette on small weights (not on a scattering's).
            level = max(abs(wr[0]), max(abs(wr[1]), abs(wr[2])))
            if not stop and level < RR_LEVEL:
                if u[i, j, 2] * RR_LEVEL < level:
                    for c in range(3):
                        wr[c] = wr[c] * (RR_LEVEL / (level if level > 0 else 1.0))
                else:
                    for c in range(3):
                        wr[c] = 0.0
                    stop = True
            for c in range(3):
                w[r, c] = wr[c]
            if stop:
                done[i] = True
                break


def _light(into, w, x, rows, t0, t1):
    """Rows passing x on their ray between t0 and t1: their weight there."""
    seen = (t0 < x[rows]) & (x[rows] <= t1)
    into[rows[seen]] = w[rows[seen]]


def _collide(out, w, rows, tn, mu, sa, ss, em, gw, u, mode, beta, may_scatter):
    """One tentative collision of each of ``rows``; returns which stop."""
    m = mu[:, None]
    sn = m - sa - ss
    wr = w[rows]
    stop = np.zeros(len(rows), bool)
    if mode == "flight":
        out.emitted[rows] += wr * em / m
        can = may_scatter[rows] & np.any(ss > 0, axis=1)
        a = np.abs(beta[rows] * wr * ss).mean(axis=1)
        b = np.abs(beta[rows] * wr * sn).mean(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            ps = np.where(can & (a + b > 0), a / np.where(a + b > 0, a + b, 1.0), 0.0)
        sc = u[:, 1] < ps
        ps_c = np.where(sc, ps, 1.0 - ps)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            wr = np.where(sc[:, None], ss, sn) * wr / (m * np.where(ps_c > 0, ps_c, 1.0))
        s = rows[sc]
        out.scatter[s] = True
        out.t[s] = tn[sc]
        mean_ss = ss[sc].mean(axis=1)
        out.g[s] = np.where(mean_ss > 0, gw[sc] / np.where(mean_ss > 0, mean_ss, 1.0), 0.0)
        stop |= sc
    elif mode == "ratio":
        wr = wr * sn / m
    else:   # delta tracking
        P = np.minimum(np.abs(sn).mean(axis=1) / mu, 1.0)
        survive = u[:, 1] < P
        wr = np.where(survive[:, None], wr * sn / (m * np.where(P > 0, P, 1.0)[:, None]), 0.0)
        stop |= ~survive
    # Russian roulette on small weights (not on a scattering's).
    level = np.abs(wr).max(axis=1)
    low = ~stop & (level < RR_LEVEL)
    keep = u[:, 2] * RR_LEVEL < level
    wr = np.where((low & keep)[:, None], wr * (RR_LEVEL / np.where(level > 0, level, 1.0))[:, None],
                  np.where(low[:, None], 0.0, wr))
    stop |= low & ~keep
    w[rows] = wr
    return stop


def transmittance(table, stack, o, d, length, rng, estimator="ratio"):
    """(N, 3) transmittance estimates of segments through the media of stack."""
    return track(table, stack, o, d, np.asarray(length, np.float64), rng, mode=estimator).weight


def field_transmittance(table, stack, o, d, length, rng):
    """(N, 3) transmittance of segments through the media of ``stack``:
    the homogeneous media's exp(-sigma_t length) in closed form times a
    ratio-tracking estimate of the textured ones' alone (no collisions,
    hence no noise, from the homogeneous part)."""
    length = np.asarray(length, np.float64)
    closed = np.exp(-table.extinction(stack) * length[:, None])
    return closed * track(table, stack, o, d, length, rng, mode="ratio", homogeneous=False).weight
