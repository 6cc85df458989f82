"""The arithmetic of a light sample's contribution (next-event estimation),
between the BSDF evaluation and the shadow ray, in one pass over the rows.

``contribution`` gives, per shading point: the MIS weight of the light
sample (power heuristic against the BSDF's pdf; 1 for delta lights and
without MIS), the radiance it adds if unoccluded, beta f Le |cos| w /
(p_select p_light), and whether that is positive anywhere (the rows that
need a shadow ray).  A sample counts where its pdf is positive and its
direction leaves on the same side of the geometric and the shading surface
(lights behind the surface count for transmitting lobes, whose f is 0
otherwise) and its light was picked with a positive probability (the light
tree gives 0 to lights behind a point without transmission).  The compiled row loop and the NumPy form agree bit for bit.
``add_rows`` adds the light of the samples whose shadow rays are free.

``resample`` is resampled importance sampling (Talbot et al. 2005) over a
vertex's light candidates: each candidate is an ordinary light sample
(drawn by the selection pmf, the light's own pdf, weighed by MIS against
the BSDF with that pdf), and its unshadowed contribution, BSDF included,
is the target.  One candidate is kept with probability proportional to
its target and scaled by (sum of targets) / (M target): the expected value
of the kept sample, shadow included, is the mean of the M candidates'
estimates, so the estimator is unbiased whatever the target, while its one
shadow ray goes where the BSDF and the light agree.
"""
import numpy as np

from . import kernels
from .sampling import power_heuristic
from .vec import column, dot, row_any_positive, rows3


def _contribution_numpy(wi_l, wi, ng, light_pdf, p_sel, p_mis, pdf_b, delta, mis, beta, f, le, contrib, w, live):
    cos = np.abs(wi_l[:, 2])
    p_light = p_sel * light_pdf
    g = dot(wi, ng)
    ok = (light_pdf > 0) & (p_sel > 0) & (cos > 0) & (g != 0) & ((g > 0) == (wi_l[:, 2] > 0))
    w[:] = np.where(delta, 1.0, power_heuristic(p_mis * light_pdf, pdf_b)) if mis else 1.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        scale = np.where(ok, cos * w / np.where(ok, p_light, 1.0), 0.0)
        contrib[:] = beta * f * le * scale[:, None]
    live[:] = row_any_positive(contrib)


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:], float64[:], float64[:], "
                     "float64[:], boolean[:], boolean, float64[:, :], float64[:, :], float64[:, :], "
                     "float64[:, ::1], float64[::1], boolean[::1])", _contribution_numpy)
def _contribution_rows(wi_l, wi, ng, light_pdf, p_sel, p_mis, pdf_b, delta, mis, beta, f, le, contrib, w, live):
    for i in range(len(wi_l)):
        z = wi_l[i, 2]
        cos = abs(z)
        p_light = p_sel[i] * light_pdf[i]
        g = (wi[i, 0] * ng[i, 0] + wi[i, 2] * ng[i, 2]) + wi[i, 1] * ng[i, 1]   # einsum's order
        ok = light_pdf[i] > 0 and p_sel[i] > 0 and cos > 0 and g != 0 and (g > 0) == (z > 0)
        weight = 1.0
        if mis and not delta[i]:
            q = p_mis[i] * light_pdf[i]
            a2 = q * q
            b = pdf_b[i]
            weight = a2 / (a2 + b * b)
            if not np.isfinite(weight):   # sampling.power_heuristic's rule
                weight = 1.0 if np.isinf(q) and np.isfinite(b) else 0.0
        w[i] = weight
        scale = cos * weight / p_light if ok else 0.0
        any_positive = False
        for k in range(3):
            c = beta[i, k] * f[i, k] * le[i, k] * scale
            contrib[i, k] = c
            any_positive = any_positive or c > 0
        live[i] = any_positive


def contribution(wi_l, wi, ng, light_pdf, p_sel, pdf_b, delta, mis, beta, f, le, p_mis=None):
    """(contrib (N, 3), MIS weight (N,), live (N,) bool) of light samples.
    p_mis: the selection probability the MIS weight takes (the one BSDF
    rays that meet the light are weighed with; None: p_sel)."""
    n = len(wi_l)
    wi_l, wi, ng = rows3(wi_l, wi, ng)
    contrib, w, live = np.empty((n, 3)), np.empty(n), np.empty(n, bool)
    columns = [column(a, n, np.float64) for a in (light_pdf, p_sel, p_sel if p_mis is None else p_mis, pdf_b)]
    _contribution_rows(wi_l, wi, ng, *columns, column(delta, n, bool), bool(mis), *rows3(beta, f, le),
                       contrib, w, live)
    return contrib, w, live


def add_rows(L, rows, values):
    """L[rows] += values[rows] (rows unique): the light of the samples
    whose shadow rays are free, in one compiled loop."""
    if L.flags.c_contiguous and values.flags.c_contiguous and values.dtype == L.dtype == np.float64:
        _add_rows_loop(L, np.ascontiguousarray(rows, np.int64), values)
    else:
        _add_rows_numpy(L, rows, values)


def _add_rows_numpy(L, rows, values):
    """A dense masked add when rows are most of L: row-wise fancy indexing
    of (N, 3) arrays costs several times a pass over the whole array."""
    if len(rows) * 4 < len(L):
        L[rows] += np.take(values, rows, axis=0)
        return
    use = np.zeros(len(L), bool)
    use[rows] = True
    L += np.where(use[:, None], values, 0.0)


@kernels.loop_kernel("void(float64[:, ::1], int64[::1], float64[:, ::1])", _add_rows_numpy)
def _add_rows_loop(L, rows, values):
    for r in rows:
        for k in range(3):
            L[r, k] += values[r, k]


def resample(targets, u):
    """Resampled importance sampling among M candidates per row: targets
    (M, N) >= 0 (a candidate's unshadowed contribution), u (N,) uniform.
    Returns the candidate kept per row (N,) and the factor its estimate is
    multiplied by, sum(targets) / (M targets[kept]) (0 where every target
    is 0: no candidate brings light)."""
    m = len(targets)
    cum = np.cumsum(targets, axis=0)
    total = cum[-1]
    # The first candidate whose cumulative target passes u * total has a
    # positive target (u < 1, so u * total < total where total > 0).
    kept = np.minimum((cum <= (u * total)[None, :]).sum(axis=0), m - 1)
    chosen = np.take_along_axis(targets, kept[None, :], axis=0)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(chosen > 0, total / (m * np.where(chosen > 0, chosen, 1.0)), 0.0)
    return kept, factor


def tree_normals(ns, kind, weights, transmitting):
    """(N, 4) the normal the light tree reads at each vertex (its shading
    normal ns) and 1 where no lobe of ``kind`` (N, K) int8 with a positive
    weight (N, K, 3) is one of the ``transmitting`` kinds (Cycles'
    SD_BSDF_HAS_TRANSMISSION unset), in one compiled pass."""
    out = np.empty((len(ns), 4))
    _tree_normals_rows(ns, np.asarray(kind, np.int8), weights, _kind_table(transmitting), out)
    return out


_KIND_TABLES = {}


def _kind_table(kinds):
    """A 256-entry table, True at the int8 lobe ids ``kinds`` (as uint8)."""
    table = _KIND_TABLES.get(kinds)
    if table is None:
        table = np.zeros(256, bool)
        table[np.asarray(kinds, np.int8).view(np.uint8)] = True
        _KIND_TABLES[kinds] = table
    return table


def _tree_normals_numpy(ns, kind, weights, table, out):
    through = table[kind.view(np.uint8)] & (weights.max(axis=2) > 0)
    out[:, :3] = ns
    out[:, 3] = ~through.any(axis=1)


@kernels.loop_kernel("void(float64[:, :], int8[:, :], float64[:, :, :], boolean[::1], float64[:, ::1])",
                     _tree_normals_numpy)
def _tree_normals_rows(ns, kind, weights, table, out):
    for i in range(len(ns)):
        for c in range(3):
            out[i, c] = ns[i, c]
        one_sided = 1.0
        for k in range(kind.shape[1]):
            if not table[kind[i, k] & 255]:
                continue
            # weights.max(axis=2) > 0, NaN included (a NaN max is not > 0)
            positive, nan = False, False
            for c in range(weights.shape[2]):
                x = weights[i, k, c]
                nan = nan or x != x
                positive = positive or x > 0
            if positive and not nan:
                one_sided = 0.0
        out[i, 3] = one_sided
