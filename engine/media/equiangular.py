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

DISTANCE, EQUIANGULAR, MIS = 0, 1, 2
METHODS = {"DISTANCE": DISTANCE, "EQUIANGULAR": EQUIANGULAR, "MULTIPLE_IMPORTANCE": MIS}


def _frame(o, d, P):
    delta = np.einsum("ij,ij->i", P - o, d)
    D = np.linalg.norm(P - o - d * delta[:, None], axis=1)
    return delta, D


def _angles(delta, D, t_end):
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.arctan2(-delta, D)
        b = np.where(np.isfinite(t_end), np.arctan2(np.where(np.isfinite(t_end), t_end, 0.0) - delta, D),
                     0.5 * np.pi)
    return a, b


def sample(o, d, P, t_end, xi):
    """(t, pdf) per row; pdf 0 where the light point is on the ray's line
    (no equiangular sample: the caller samples a distance instead)."""
    delta, D = _frame(o, d, P)
    a, b = _angles(delta, D, t_end)
    span = b - a
    ok = (D > 1e-12) & (span > 1e-9) & np.isfinite(delta)
    with np.errstate(invalid="ignore", over="ignore"):
        tt = D * np.tan(xi * b + (1.0 - xi) * a)
        t = np.clip(delta + tt, 0.0, np.where(np.isfinite(t_end), t_end, np.inf))
        pdf = D / (np.where(ok, span, 1.0) * (D * D + tt * tt))
    ok &= np.isfinite(t) & (pdf > 0) & np.isfinite(pdf)
    return np.where(ok, t, 0.0), np.where(ok, pdf, 0.0)


def pdf(o, d, P, t_end, t):
    """The equiangular pdf of distance t (0 where ``sample`` gives none)."""
    delta, D = _frame(o, d, P)
    a, b = _angles(delta, D, t_end)
    span = b - a
    ok = (D > 1e-12) & (span > 1e-9) & np.isfinite(delta) & (t >= 0) & (t <= t_end)
    with np.errstate(invalid="ignore", over="ignore"):
        tt = t - delta
        out = D / (np.where(ok, span, 1.0) * (D * D + tt * tt))
    return np.where(ok & np.isfinite(out), out, 0.0)


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
