"""Goodness-of-fit helpers for the sampling tests (NumPy only, no SciPy).

Mitsuba's ChiSquareTest, reduced to what the engine tests need:

* ``chi2_sf`` (from ember_stats): survival function of the chi-square
  distribution;
* ``chi2_test``: Pearson's statistic with cells of expected count < 5 pooled;
  a cell with observations where the pdf integrates to zero is a failure;
* ``integrate_cells``: per-cell integral of a density on a tensor grid of
  arbitrary (non-uniform) edges: Gauss-Legendre in each cell, refined with a
  fine midpoint rule on cells where the density switches on or off (the
  silhouette of a light, the horizon) and on their neighbours;
* direction coordinates (phi, theta) about any axis (solid angle
  sin(theta) dtheta dphi), theta taken from the chord so that tiny cones keep
  their precision; solid angles of triangles/polygons; polygon clipping;
* ``sidak`` / ``z_threshold`` (from ember_stats) for the family-wise level.
"""
import math

import numpy as np

# ----------------------------------------------------------------------------
# Distributions and levels: one module for the suite (tests/ember_stats.py)

from ember_stats import chi2_sf, normal_two_sided_p, sidak, z_threshold  # noqa: E402,F401


# ----------------------------------------------------------------------------
# Pearson's test with pooling

class Chi2Result:
    def __init__(self, stat, dof, p, pooled, message="", total=0.0):
        self.stat, self.dof, self.p, self.pooled, self.message = stat, dof, p, pooled, message
        self.total = total      # the expected counts' sum: the samples tested

    def __repr__(self):
        return (f"chi2={self.stat:.2f} dof={self.dof} p={self.p:.3g} pooled_cells={self.pooled}"
                + (f" {self.message}" if self.message else ""))

    def detects(self, level):
        """The smallest rms relative error of the sampled density over the
        cells (weighted by their probability) that the test at ``level``
        detects with probability about 1/2: its noncentrality N eps^2 puts
        the statistic's mean dof + N eps^2 on the threshold."""
        return density_error_detected(level, self.dof, self.total)

    def power_line(self, level):
        return (f"{self}; detects a density error of {self.detects(level):.2%} (rms over the cells) "
                f"with probability 1/2 at level {level:.2g}")


def density_error_detected(level, dof, total):
    """``Chi2Result.detects`` of a chi-square test with ``dof`` degrees of
    freedom over ``total`` samples."""
    if dof < 1 or total <= 0:
        return float("nan")
    return math.sqrt(max(chi2_threshold(level, dof) - dof, 0.0) / total)


def chi2_threshold(level, dof):
    """The chi-square statistic whose upper tail is ``level`` (bisection)."""
    lo, hi = 0.0, float(dof) + 10.0
    while chi2_sf(hi, dof) > level:
        lo, hi = hi, 2.0 * hi
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if chi2_sf(mid, dof) > level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def chi2_test(observed, expected, min_expected=5.0):
    """Pearson chi-square of counts against expected counts (same shape).

    Cells are sorted by expected count; those below ``min_expected`` are
    pooled into one cell (Mitsuba), and the pool keeps absorbing the next
    smallest cells until it reaches ``min_expected`` itself.  Cells with no
    expected mass must be empty, otherwise the sampler produces what its pdf
    says is impossible: p = 0."""
    obs = np.asarray(observed, dtype=np.float64).ravel()
    exp = np.asarray(expected, dtype=np.float64).ravel()
    if np.any(~np.isfinite(exp)) or np.any(exp < 0):
        return Chi2Result(np.inf, 0, 0.0, 0, "expected counts not finite/non-negative")
    bad = (exp <= 0) & (obs > 0)
    if bad.any():
        return Chi2Result(np.inf, 0, 0.0, 0,
                          f"{int(obs[bad].sum())} samples in {int(bad.sum())} cells of zero pdf "
                          f"(cells {np.nonzero(bad)[0][:10].tolist()})")
    keep = exp > 0
    obs, exp = obs[keep], exp[keep]
    order = np.argsort(exp, kind="stable")
    obs, exp = obs[order], exp[order]
    stat = 0.0
    cells = 0
    pool_o = pool_e = 0.0
    pooled = 0
    for o, e in zip(obs, exp):
        if e < min_expected or (pooled and pool_e < min_expected):
            pool_o += o
            pool_e += e
            pooled += 1
        else:
            stat += (o - e) ** 2 / e
            cells += 1
    if pooled:
        stat += (pool_o - pool_e) ** 2 / pool_e
        cells += 1
    dof = cells - 1
    if dof < 1:
        return Chi2Result(stat, dof, 1.0, pooled, "fewer than two cells: nothing to test")
    return Chi2Result(stat, dof, chi2_sf(stat, dof), pooled, total=float(exp.sum()))


# ----------------------------------------------------------------------------
# Cell integrals

def _gauss(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w          # on [0, 1]


def _midpoint(n):
    return (np.arange(n) + 0.5) / n, np.full(n, 1.0 / n)


def _integrate(density, x0, x1, y0, y1, nodes):
    """Integrals over the cells [x0, x1] x [y0, y1] (1D arrays of equal
    length) with the tensor rule ``nodes`` = (t, w) on [0, 1]; also whether
    each cell's density values are all zero / all non-zero."""
    t, w = nodes
    n = len(t)
    dx, dy = x1 - x0, y1 - y0
    cells = len(x0)
    out = np.zeros(cells)
    any_zero = np.zeros(cells, bool)
    any_pos = np.zeros(cells, bool)
    chunk = max(1, 2_000_000 // (n * n))
    for s in range(0, cells, chunk):
        e = slice(s, s + chunk)
        xs = x0[e, None, None] + dx[e, None, None] * t[None, :, None]
        ys = y0[e, None, None] + dy[e, None, None] * t[None, None, :]
        xs, ys = np.broadcast_arrays(xs, ys)
        v = np.asarray(density(xs.ravel(), ys.ravel()), dtype=np.float64).reshape(xs.shape)
        if np.any(~np.isfinite(v)):
            raise AssertionError("density is not finite inside the domain")
        out[e] = np.einsum("cij,i,j->c", v, w, w) * dx[e] * dy[e]
        any_zero[e] = np.any(v == 0, axis=(1, 2))
        any_pos[e] = np.any(v != 0, axis=(1, 2))
    return out, any_zero, any_pos


def _cell_args(xedges, yedges, cells):
    ny = len(yedges) - 1
    ix, iy = np.divmod(np.asarray(cells), ny)
    return xedges[ix], xedges[ix + 1], yedges[iy], yedges[iy + 1]


def integrate_cells(density, xedges, yedges, n=6, refine=64, periodic_x=False, smooth=False):
    """(len(xedges)-1, len(yedges)-1) integrals of ``density(x, y)``.

    Gauss-Legendre n x n per cell.  Unless ``smooth``, cells where the
    density is zero at some nodes and non-zero at others (a discontinuity),
    together with their 8 neighbours, are integrated again with a ``refine`` x
    ``refine`` midpoint rule, whose error on a jump curve crossing the cell
    is a small random fraction of one sub-cell."""
    xedges = np.asarray(xedges, float)
    yedges = np.asarray(yedges, float)
    nx, ny = len(xedges) - 1, len(yedges) - 1
    val, zero, pos = _integrate(density, *_cell_args(xedges, yedges, np.arange(nx * ny)), _gauss(n))
    val, zero, pos = val.reshape(nx, ny), zero.reshape(nx, ny), pos.reshape(nx, ny)
    if smooth:
        return val
    mixed = zero & pos
    padded = np.pad(mixed, 1, mode="wrap" if periodic_x else "constant")
    if periodic_x:
        padded[:, 0] = padded[:, -1] = False       # y never wraps
    grow = np.zeros_like(mixed)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            grow |= padded[1 + dx:1 + dx + nx, 1 + dy:1 + dy + ny]
    return refine_cells(density, xedges, yedges, val, grow, refine)


def refine_cells(density, xedges, yedges, values, mask, n):
    """``values`` with the cells in ``mask`` integrated again with an n x n
    midpoint rule."""
    values = np.array(values, float)
    sel = np.nonzero(np.asarray(mask).ravel())[0]
    if len(sel):
        fine, _, _ = _integrate(density, *_cell_args(np.asarray(xedges, float), np.asarray(yedges, float),
                                                     sel), _midpoint(n))
        values.ravel()[sel] = fine
    return values


def integrate_1d(density, edges, n=64):
    """Per-bin integrals of a 1D density with an n-point midpoint rule."""
    edges = np.asarray(edges, float)
    t, w = _midpoint(n)
    a, b = edges[:-1], edges[1:]
    x = a[:, None] + (b - a)[:, None] * t[None, :]
    v = np.asarray(density(x.ravel()), float).reshape(x.shape)
    return (v * w).sum(axis=1) * (b - a)


def histogram2d(x, y, xedges, yedges):
    """Counts on a tensor grid and the number of points outside it."""
    ix = np.searchsorted(xedges, x, side="right") - 1
    iy = np.searchsorted(yedges, y, side="right") - 1
    nx, ny = len(xedges) - 1, len(yedges) - 1
    # The last edge is inclusive.
    ix = np.where(x == xedges[-1], nx - 1, ix)
    iy = np.where(y == yedges[-1], ny - 1, iy)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny) & np.isfinite(x) & np.isfinite(y)
    counts = np.bincount(ix[inside] * ny + iy[inside], minlength=nx * ny).reshape(nx, ny)
    return counts, int((~inside).sum())


# ----------------------------------------------------------------------------
# Directions about an axis

def frame(axis):
    """Orthonormal (s, t, a) with a the unit axis."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    s = np.cross(helper, a)
    s /= np.linalg.norm(s)
    t = np.cross(a, s)
    return s, t, a


def to_phi_theta(d, axis_frame, phi0=0.0):
    """Spherical coordinates of unit directions about the frame's axis:
    phi in [phi0, phi0 + 2 pi), theta from the half chord |d - a| / 2 =
    sin(theta / 2), which keeps full precision in tiny cones."""
    s, t, a = axis_frame
    phi = np.mod(np.arctan2(d @ t, d @ s) - phi0, 2.0 * np.pi) + phi0
    diff = d - a
    half_chord = 0.5 * np.sqrt(np.einsum("ij,ij->i", diff, diff))
    return phi, 2.0 * np.arcsin(np.clip(half_chord, 0.0, 1.0))


def from_phi_theta(phi, theta, axis_frame):
    s, t, a = axis_frame
    st = np.sin(theta)
    return ((st * np.cos(phi))[:, None] * s + (st * np.sin(phi))[:, None] * t
            + np.cos(theta)[:, None] * a)


def theta_of_w(w):
    """theta for w = 1 - cos(theta), without cancellation."""
    return 2.0 * np.arcsin(np.sqrt(np.clip(0.5 * np.asarray(w, float), 0.0, 1.0)))


def w_of_theta(theta):
    return 2.0 * np.sin(0.5 * np.asarray(theta, float)) ** 2


def mixture_edges(lo, hi, center, scale, k, uniform_weight=0.3, table=200001):
    """k + 1 edges on [lo, hi] equally spaced in the CDF of a mixture of a
    uniform and a Cauchy(center, scale) density: fine cells where a lobe
    concentrates its mass, coarse ones elsewhere."""
    x = np.linspace(lo, hi, table)
    c = np.arctan((x - center) / scale)
    c = (c - c[0]) / (c[-1] - c[0])
    cdf = uniform_weight * (x - lo) / (hi - lo) + (1.0 - uniform_weight) * c
    edges = np.interp(np.linspace(0.0, 1.0, k + 1), cdf, x)
    edges[0], edges[-1] = lo, hi
    return edges


# ----------------------------------------------------------------------------
# Geometry helpers

def triangle_solid_angle(a, b, c):
    """Solid angle of triangles (rows of a, b, c: vertices relative to the
    viewpoint), Van Oosterom & Strackee 1983."""
    a, b, c = (np.atleast_2d(np.asarray(v, float)) for v in (a, b, c))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
           + np.einsum("ij,ij->i", b, c) * la)
    return 2.0 * np.arctan2(num, den)


def convex_polygon_solid_angle(p, vertices):
    """Solid angle of a planar convex polygon seen from p (fan from its centroid)."""
    v = np.asarray(vertices, float) - np.asarray(p, float)
    centre = v.mean(axis=0)
    nxt = np.roll(v, -1, axis=0)
    return float(triangle_solid_angle(np.tile(centre, (len(v), 1)), v, nxt).sum())


def clip_polygon_area(poly, x0, x1, y0, y1):
    """Area of a convex 2D polygon clipped to [x0, x1] x [y0, y1]
    (Sutherland-Hodgman, then the shoelace formula)."""
    pts = [np.asarray(q, float) for q in poly]
    for axis, bound, keep_ge in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        out = []
        for i in range(len(pts)):
            p, q = pts[i], pts[(i + 1) % len(pts)]
            pin = p[axis] >= bound if keep_ge else p[axis] <= bound
            qin = q[axis] >= bound if keep_ge else q[axis] <= bound
            if pin:
                out.append(p)
            if pin != qin:
                t = (bound - p[axis]) / (q[axis] - p[axis])
                out.append(p + t * (q - p))
        pts = out
        if len(pts) < 3:
            return 0.0
    xy = np.array(pts)
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
