"""A path's throughput after its BSDF sample, in one pass over the rows.

``update`` multiplies beta by the sample's weight, absorbs samples that
would leak light through the surface (a reflection below the geometric
surface or a transmission above it, as Cycles does) or whose weight is not
finite and positive, and plays Russian roulette from ``rr_depth`` on:
survival probability min(max(beta), 0.95), survivors divided by it.  The
compiled row loop and the NumPy form agree bit for bit.
"""
import numpy as np

from . import kernels
from .vec import column, dot, row_all_finite, row_any_positive, row_max, rows3


def _update_numpy(wi, ng, wi_l, weight, beta, bounce, rr_depth, u_rr, ok, beta_out):
    g = dot(wi, ng)
    ok[:] = (g != 0) & ((g > 0) == (wi_l[:, 2] > 0)) & row_all_finite(weight) & row_any_positive(weight)
    b = beta * weight
    rr = bounce >= rr_depth
    if rr.any():
        q = np.where(rr, np.minimum(row_max(b), 0.95), 1.0)
        survive = u_rr < q
        b = b / np.where(survive, np.maximum(q, 1e-30), 1.0)[:, None]
        ok &= survive
    beta_out[:] = b


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64[:, :], int32[:], "
                     "int64, float64[:], boolean[::1], float64[:, ::1])", _update_numpy)
def _update_rows(wi, ng, wi_l, weight, beta, bounce, rr_depth, u_rr, ok, beta_out):
    for i in range(len(wi)):
        g = (wi[i, 0] * ng[i, 0] + wi[i, 2] * ng[i, 2]) + wi[i, 1] * ng[i, 1]   # einsum's order
        good = g != 0 and (g > 0) == (wi_l[i, 2] > 0)
        finite, positive = True, False
        for k in range(3):
            finite = finite and np.isfinite(weight[i, k])
            positive = positive or weight[i, k] > 0
        b0, b1, b2 = beta[i, 0] * weight[i, 0], beta[i, 1] * weight[i, 1], beta[i, 2] * weight[i, 2]
        alive = good and finite and positive
        if bounce[i] >= rr_depth:
            q = np.minimum(np.maximum(np.maximum(b0, b1), b2), 0.95)   # NaN stays NaN, as row_max
            if u_rr[i] < q:
                q = np.maximum(q, 1e-30)
                b0, b1, b2 = b0 / q, b1 / q, b2 / q
            else:
                alive = False
        ok[i] = alive
        beta_out[i, 0], beta_out[i, 1], beta_out[i, 2] = b0, b1, b2


def update(wi, ng, wi_l, weight, beta, bounce, rr_depth, u_rr):
    """(ok (N,) bool: the path lives on, new beta (N, 3))."""
    n = len(wi)
    ok, beta_out = np.empty(n, bool), np.empty((n, 3))
    _update_rows(*rows3(wi, ng, wi_l, weight, beta), column(bounce, n, np.int32), int(rr_depth),
                 column(u_rr, n, np.float64), ok, beta_out)
    return ok, beta_out
