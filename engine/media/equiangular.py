"""Equiangular sampling of a scattering distance towards a light point
(Kulla and Fajardo 2012, as Cycles' volume_equiangular_sample /
volume_equiangular_pdf), and the choice of how a segment samples the point
its direct light is estimated at (Cycles' volume_stack_sample_method).

Along o + t d, 0 <= t < t_end, with the light point P at distance D from
the ray's line and delta = (P - o) . d, t = delta + D tan(theta) with theta
uniform between atan2(-delta, D) and atan2(t_end - delta, D): the pdf is
D / ((theta_b - theta_a) (D^2 + (t - delta)^2)), which cancels the 1/r^2 of
a light near the ray.
"""
import numpy as np

from .. import kernels

DISTANCE, EQUIANGULAR, MIS = 0, 1, 2
METHODS = {"DISTANCE": DISTANCE, "EQUIANGULAR": EQUIANGULAR, "MULTIPLE_IMPORTANCE": MIS}


def _frame(o, d, P):
    delta = np.einsum("ij,ij->i", P - o, d)
    D = np.linalg.norm(P - o - d * delta[:, None], axis=1)
    return delta, D


def _angles(delta, D, t0, t1):
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.arctan2(t0 - delta, D)
        b = np.where(np.isfinite(t1), np.arctan2(np.where(np.isfinite(t1), t1, 0.0) - delta, D), 0.5 * np.pi)
    return a, b


def sample(o, d, P, t0, t1, xi):
    """(t, pdf) per row, t in [t0, t1]; pdf 0 where the light point is on
    the ray's line or the interval is empty (no equiangular sample: the
    caller samples a distance instead)."""
    delta, D = _frame(o, d, P)
    a, b = _angles(delta, D, t0, t1)
    span = b - a
    ok = (D > 1e-12) & (span > 1e-9) & np.isfinite(delta) & (t1 > t0)
    with np.errstate(invalid="ignore", over="ignore"):
        tt = D * np.tan(xi * b + (1.0 - xi) * a)
        t = np.clip(delta + tt, t0, t1)
        pdf = D / (np.where(ok, span, 1.0) * (D * D + tt * tt))
    ok &= np.isfinite(t) & (pdf > 0) & np.isfinite(pdf)
    return np.where(ok, t, 0.0), np.where(ok, pdf, 0.0)


def pdf(o, d, P, t0, t1, t):
    """The equiangular pdf of distance t (0 where ``sample`` gives none)."""
    delta, D = _frame(o, d, P)
    a, b = _angles(delta, D, t0, t1)
    span = b - a
    ok = (D > 1e-12) & (span > 1e-9) & np.isfinite(delta) & (t >= t0) & (t <= t1) & (t1 > t0)
    with np.errstate(invalid="ignore", over="ignore"):
        tt = t - delta
        out = D / (np.where(ok, span, 1.0) * (D * D + tt * tt))
    return np.where(ok & np.isfinite(out), out, 0.0)


def cone_segment(o, d, apex, axis, cos_half, t_end):
    """(t0, t1): the part of o + t d, 0 <= t <= t_end, inside the cone of
    half-angle acos(cos_half) <= 90 degrees around ``axis`` from ``apex``
    (a spot light's lit region, Cycles' spot_light_valid_ray_segment); an
    empty interval has t1 <= t0.  A convex cone meets a line in one
    interval: the roots of the cone's quadratic split the ray, and the
    pieces whose middles are inside make it."""
    rows = np.arange(len(o))
    return lit_segments(o, d, rows, rows, np.ones(len(o), bool), apex, axis, cos_half, t_end)


def _cone_segment_numpy(o, d, apex, axis, cos_half, t_end, t0, t1):
    """The arithmetic of ``_cone_row`` over arrays (the reference form of
    ``_lit_rows``' cones)."""
    v = o - apex
    da, va = np.einsum("ij,ij->i", d, axis), np.einsum("ij,ij->i", v, axis)
    dv, vv = np.einsum("ij,ij->i", d, v), np.einsum("ij,ij->i", v, v)
    c2 = cos_half * cos_half
    A, B, C = da * da - c2, 2.0 * (da * va - c2 * dv), va * va - c2 * vv
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = B * B - 4.0 * A * C
        sq = np.sqrt(np.maximum(disc, 0.0))
        lin = np.abs(A) < 1e-12
        r1 = np.where(lin, np.where(B != 0, -C / np.where(B != 0, B, 1.0), np.nan), (-B - sq) / (2.0 * np.where(lin, 1.0, A)))
        r2 = np.where(lin, np.nan, (-B + sq) / (2.0 * np.where(lin, 1.0, A)))
    real = disc >= -1e-9 * (B * B + np.abs(4.0 * A * C))   # a tangent ray's double root, within rounding
    r1, r2 = np.where(real, r1, np.nan), np.where(real, r2, np.nan)
    end = np.where(np.isfinite(t_end), t_end, np.inf)
    cuts = np.stack([np.zeros_like(end), np.clip(np.nan_to_num(r1, nan=0.0), 0.0, end),
                     np.clip(np.nan_to_num(r2, nan=0.0), 0.0, end), end], axis=1)
    cuts = np.sort(cuts, axis=1)
    lo, hi = np.full(len(o), np.inf), np.full(len(o), -np.inf)
    for k in range(3):
        a, b = cuts[:, k], cuts[:, k + 1]
        mid = np.where(np.isfinite(b), 0.5 * (a + b), a + 1.0 + np.abs(a))
        x = v + d * mid[:, None]
        inside = (np.einsum("ij,ij->i", x, axis) >= cos_half * np.linalg.norm(x, axis=1)) & (b > a)
        lo = np.where(inside, np.minimum(lo, a), lo)
        hi = np.where(inside, np.maximum(hi, b), hi)
    empty = ~(hi > lo)
    t0[:], t1[:] = np.where(empty, 0.0, lo), np.where(empty, 0.0, hi)



@kernels.helper
def _cone_row(o0, o1, o2, d0, d1, d2, x0, x1, x2, a0, a1, a2, cos_half, t_end):
    """(t0, t1) of one ray (o, d) up to t_end in the cone of apex x, axis a:
    ``_cone_segment_numpy``'s arithmetic for one row."""
    big = 1.7976931348623157e308   # np.finfo(np.float64).max
    v0, v1, v2 = o0 - x0, o1 - x1, o2 - x2
    da = d0 * a0 + d1 * a1 + d2 * a2
    va = v0 * a0 + v1 * a1 + v2 * a2
    dv = d0 * v0 + d1 * v1 + d2 * v2
    vv = v0 * v0 + v1 * v1 + v2 * v2
    c2 = cos_half * cos_half
    A, B, C = da * da - c2, 2.0 * (da * va - c2 * dv), va * va - c2 * vv
    disc = B * B - 4.0 * A * C
    sq = np.sqrt(max(disc, 0.0))
    if abs(A) < 1e-12:
        r1 = -C / B if B != 0 else np.nan
        r2 = np.nan
    else:
        r1, r2 = (-B - sq) / (2.0 * A), (-B + sq) / (2.0 * A)
    if not disc >= -1e-9 * (B * B + abs(4.0 * A * C)):   # a tangent ray's double root, within rounding
        r1, r2 = np.nan, np.nan
    end = t_end if np.isfinite(t_end) else np.inf
    # np.nan_to_num, then clipped to [0, end]: both cuts lie between 0 and end.
    c1 = min(max(0.0 if np.isnan(r1) else min(max(r1, -big), big), 0.0), end)
    c2 = min(max(0.0 if np.isnan(r2) else min(max(r2, -big), big), 0.0), end)
    lo, hi = np.inf, -np.inf
    for k in range(3):   # the pieces (0, c), (c, c'), (c', end), c <= c'
        a = 0.0 if k == 0 else (min(c1, c2) if k == 1 else max(c1, c2))
        b = min(c1, c2) if k == 0 else (max(c1, c2) if k == 1 else end)
        mid = 0.5 * (a + b) if np.isfinite(b) else a + 1.0 + abs(a)
        y0, y1, y2 = v0 + d0 * mid, v1 + d1 * mid, v2 + d2 * mid
        ya = y0 * a0 + y1 * a1 + y2 * a2
        if b > a and ya >= cos_half * np.sqrt(y0 * y0 + y1 * y1 + y2 * y2):
            lo, hi = min(lo, a), max(hi, b)
    if hi > lo:
        return lo, hi
    return 0.0, 0.0


def lit_segments(o, d, rows, e, lit, apex, axis, cos_half, t_end):
    """(t0, t1) per row i of the rays o[rows[i]], d[rows[i]] up to t_end[i]:
    the cone (apex, axis, cos_half)[e[i]] where lit[e[i]], else (0, t_end)
    (what ``cone_segment`` runs, without gathering the rows' rays and cones first)."""
    n = len(rows)
    t0, t1 = np.empty(n), np.empty(n)
    f64 = np.float64
    _lit_rows(np.ascontiguousarray(o, f64), np.ascontiguousarray(d, f64), np.ascontiguousarray(rows, np.int64),
              np.ascontiguousarray(e, np.int64), np.ascontiguousarray(lit, bool),
              *(np.ascontiguousarray(a, f64) for a in (apex, axis, cos_half, t_end)), t0, t1)
    return t0, t1


def _lit_numpy(o, d, rows, e, lit, apex, axis, cos_half, t_end, t0, t1):
    t0[:], t1[:] = 0.0, t_end
    c = np.flatnonzero(lit[e])
    if len(c):
        k, r = e[c], rows[c]
        a, b = np.empty(len(c)), np.empty(len(c))
        _cone_segment_numpy(o[r], d[r], apex[k], axis[k], cos_half[k], t_end[c], a, b)
        t0[c], t1[c] = a, b


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], int64[::1], int64[::1], boolean[::1], float64[:, ::1], "
                     "float64[:, ::1], float64[::1], float64[::1], float64[::1], float64[::1])", _lit_numpy)
def _lit_rows(o, d, rows, e, lit, apex, axis, cos_half, t_end, t0, t1):
    for i in range(rows.shape[0]):
        k, r = e[i], rows[i]
        if not lit[k]:
            t0[i], t1[i] = 0.0, t_end[i]
            continue
        t0[i], t1[i] = _cone_row(o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2], apex[k, 0], apex[k, 1],
                                 apex[k, 2], axis[k, 0], axis[k, 1], axis[k, 2], cos_half[k], t_end[i])


def stack_method(methods, stack):
    """(N,) DISTANCE / EQUIANGULAR / MIS of stacks (N, K), ``methods`` per
    medium id: any medium with MIS, or distance and equiangular media
    together, give MIS (Cycles' volume_stack_sample_method)."""
    n = len(stack)
    has = np.zeros((n, 3), bool)
    for k in range(stack.shape[1]):
        m = stack[:, k]
        use = m >= 0
        if use.any():
            has[np.flatnonzero(use), methods[m[use]]] = True
    out = np.full(n, DISTANCE)
    out[has[:, EQUIANGULAR]] = EQUIANGULAR
    out[has[:, MIS] | (has[:, DISTANCE] & has[:, EQUIANGULAR])] = MIS
    return out
