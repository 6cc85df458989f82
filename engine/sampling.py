"""Warps from uniform random numbers to directions and points, with their pdfs.

All functions take arrays of uniforms in [0, 1) and work on whole batches.
Directions are in a local frame whose +Z is the pole (normal, cone axis).
"""
import numpy as np

from .kernels import clip, helper, kernel, loop_kernel, where
from .vec import column

TWO_PI = 2.0 * np.pi
INV_PI = 1.0 / np.pi


def concentric_disk(u1, u2):
    """Uniform point on the unit disk, Shirley-Chiu concentric map (x, y)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    first = np.abs(a) > np.abs(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(first, a, b)
        phi = np.where(first, (np.pi / 4) * (b / a), np.pi / 2 - (np.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +Z (Malley's method with the polar disk
    map: cheaper than the concentric map, and our samples are not stratified
    anyway); returns (dirs (N,3), pdf)."""
    r = np.sqrt(u1)
    phi = TWO_PI * u2
    d = np.empty((len(r), 3))
    d[:, 0] = r * np.cos(phi)
    d[:, 1] = r * np.sin(phi)
    d[:, 2] = np.sqrt(np.maximum(0.0, 1.0 - u1))
    return d, d[:, 2] * INV_PI


def cosine_hemisphere_pdf(cos_theta):
    return np.maximum(cos_theta, 0.0) * INV_PI


def uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return d, np.full(len(z), 1.0 / (4 * np.pi))


def uniform_cone(u1, u2, one_minus_cos_max):
    """Uniform direction in the cone cos(theta) >= 1 - one_minus_cos_max about +Z.

    Takes and works with 1 - cos so that tiny cones (a sun of half a degree, a
    far sphere light) keep their precision: callers compute it without
    cancellation (``sin_sq_to_one_minus_cos``, 2 sin^2(theta / 2))."""
    one_minus_cos = u1 * one_minus_cos_max
    cos_t = 1.0 - one_minus_cos
    sin_t = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = TWO_PI * u2
    d = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
    return d, uniform_cone_pdf(one_minus_cos_max)


def uniform_cone_pdf(one_minus_cos_max):
    return 1.0 / (TWO_PI * one_minus_cos_max)


def sin_sq_to_one_minus_cos(sin_sq):
    """1 - sqrt(1 - x) without cancellation for small x (Cycles' helper)."""
    return np.where(sin_sq < 0.0004, 0.5 * sin_sq + 0.125 * sin_sq * sin_sq,
                    1.0 - np.sqrt(np.maximum(0.0, 1.0 - sin_sq)))


def uniform_triangle(u1, u2):
    """Barycentrics (b1, b2) of a uniform point on a triangle (sqrt warp)."""
    su = np.sqrt(u1)
    return 1.0 - su, u2 * su


@kernel(2)
def power_heuristic(a, b):
    """w = a^2 / (a^2 + b^2), defined as 0 where that is not finite."""
    a2 = a * a
    w = a2 / (a2 + b * b)
    return where(np.isfinite(w), w, where(np.isinf(a) & np.isfinite(b), 1.0, 0.0))


class Distribution1D:
    """Piecewise-constant discrete distribution sampled by inverse CDF."""

    def __init__(self, weights):
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 1 or len(w) == 0:
            raise ValueError("Distribution1D needs a non-empty 1D weight array")
        w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        total = w.sum()
        if total <= 0:
            w = np.ones_like(w)
            total = w.sum()
        self.pmf = w / total
        self.cdf = np.cumsum(self.pmf)
        # The CDF is exactly 1 from the last non-zero entry on: a rounded sum
        # just below 1 would let u in [sum, 1) pick a trailing zero entry.
        self.cdf[np.nonzero(self.pmf)[0][-1]:] = 1.0
        self.total = total

    def __len__(self):
        return len(self.pmf)

    def sample(self, u):
        """Index for each uniform u, and its probability."""
        idx = np.searchsorted(self.cdf, u, side="right")
        idx = np.minimum(idx, len(self.pmf) - 1)
        # Zero-probability entries have an empty CDF interval: searchsorted
        # never lands on them, except through the clamp above.
        return idx, self.pmf[idx]

    def sample_continuous(self, u):
        """Index, its probability and u remapped to [0, 1) inside that bin."""
        idx, p = self.sample(u)
        lo = np.where(idx > 0, self.cdf[np.maximum(idx - 1, 0)], 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            du = np.where(p > 0, (u - lo) / p, 0.0)
        return idx, p, np.clip(du, 0.0, np.nextafter(1.0, 0.0))


# ----------------------------------------------------------------------------
# Solid-angle sampling of planar emitters

@helper
def rectangle_frame(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz):
    """A rectangle (centre c, unit orthogonal axes ex, ey) seen from p: the
    centre's coordinates xc, yc along the axes, its height z0 along the
    normal z = ex x ey, and z.  Shared by sampling and the MIS pdf, so both
    pick the same strategy, bit for bit."""
    zx = exy * eyz - exz * eyy
    zy = exz * eyx - exx * eyz
    zz = exx * eyy - exy * eyx
    rx, ry, rz = cx - px, cy - py, cz - pz
    xc = rx * exx + ry * exy + rz * exz
    yc = rx * eyx + ry * eyy + rz * eyz
    z0 = rx * zx + ry * zy + rz * zz
    return xc, yc, z0, zx, zy, zz


@kernel(14, 2)
def rectangle_solid_angle(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz, len_u, len_v):
    """(solid angle, min_nz2) of the rectangle seen from p, as
    ``spherical_rectangle_warp`` computes them: min_nz2 near 1 means p lies
    almost in the rectangle's plane, where the warp loses precision."""
    xc, yc, z0, _, _, _ = rectangle_frame(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz)
    _, _, _, _, solid_angle, min_nz2 = _rectangle_angles(xc, yc, where(z0 > 0, -z0, z0), len_u, len_v)
    return solid_angle, min_nz2


@helper
def _nz(a, z0):
    """a / sqrt(a^2 + z0^2), 0 where undefined."""
    r = a / np.sqrt(a * a + z0 * z0)
    return where(np.isfinite(r), r, 0.0)


@kernel(7, 4)
def spherical_rectangle_warp(xc, yc, z0, len_u, len_v, u1, u2):
    """Urena et al. 2013, in the rectangle's frame (``rectangle_frame``; z0
    <= 0 here: minus the distance of p from the plane): the (x, y) of a
    point uniform in the solid angle the rectangle subtends, the solid angle
    and min_nz2.  Follows Cycles' area.h, whose asin form of the internal
    angles avoids the cancellation of the paper's acos sum for small lights."""
    x0 = xc - 0.5 * len_u
    x1 = xc + 0.5 * len_u
    y0 = yc - 0.5 * len_v
    y1 = yc + 0.5 * len_v
    n0, n2, g2, g3, solid_angle, min_nz2 = _rectangle_angles(xc, yc, z0, len_u, len_v)
    au = u1 * solid_angle + g2 + g3
    fu = (np.cos(au) * n0 + n2) / np.sin(au)
    cu = clip(np.copysign(1.0 / np.sqrt(fu * fu + n0 * n0), fu), -1.0, 1.0)
    xu = -(cu * z0) / np.maximum(np.sqrt(1.0 - cu * cu), 1e-300)
    xu = clip(where(np.isfinite(xu), xu, where(np.isnan(xu), 0.0, np.copysign(1.7976931348623157e308, xu))),
              x0, x1)
    d2 = xu * xu + z0 * z0
    h0 = y0 / np.sqrt(d2 + y0 * y0)
    h1 = y1 / np.sqrt(d2 + y1 * y1)
    hv = h0 + u2 * (h1 - h0)
    hv2 = hv * hv
    yv = clip(where(hv2 < 1.0 - 1e-12, hv * np.sqrt(d2 / (1.0 - hv2)), y1), y0, y1)
    return xu, yv, solid_angle, min_nz2


@helper
def _rectangle_angles(xc, yc, z0, len_u, len_v):
    """The rectangle's edge terms n0, n2, angles g2, g3, solid angle and
    min_nz2 (warp frame)."""
    x0 = xc - 0.5 * len_u
    x1 = xc + 0.5 * len_u
    y0 = yc - 0.5 * len_v
    y1 = yc + 0.5 * len_v
    n0 = _nz(-y0, z0)
    n1 = _nz(x1, z0)
    n2 = _nz(y1, z0)
    n3 = _nz(-x0, z0)
    g0 = np.arcsin(clip(-n0 * n1, -1.0, 1.0))
    g1 = np.arcsin(clip(-n1 * n2, -1.0, 1.0))
    g2 = np.arcsin(clip(-n2 * n3, -1.0, 1.0))
    g3 = np.arcsin(clip(-n3 * n0, -1.0, 1.0))
    solid_angle = np.maximum(-(g0 + g1 + g2 + g3), 0.0)
    min_nz2 = np.minimum(np.minimum(n0 * n0, n1 * n1), np.minimum(n2 * n2, n3 * n3))
    return n0, n2, g2, g3, solid_angle, min_nz2


def _unit_rows(v):
    length = np.sqrt(np.einsum("ij,ij->i", v, v))
    return v / np.where(length > 0, length, 1.0)[:, None]


def triangle_solid_angle(p, v0, v1, v2):
    """Solid angle of triangles (v0, v1, v2) seen from points p (Van Oosterom
    and Strackee), plus the unit vectors towards the corners."""
    a, b, c = _unit_rows(v0 - p), _unit_rows(v1 - p), _unit_rows(v2 - p)
    triple = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    denom = 1.0 + np.einsum("ij,ij->i", b, c) + np.einsum("ij,ij->i", a, c) + np.einsum("ij,ij->i", a, b)
    return 2.0 * np.arctan2(triple, denom), a, b, c


def spherical_triangle(p, v0, v1, v2, u1, u2):
    """Arvo 1995 (as Cycles' triangle.h): a direction from p uniform in the
    solid angle of triangle (v0, v1, v2).  Returns (dirs (N, 3), solid angle)."""
    solid_angle, A, B, C = triangle_solid_angle(p, v0, v1, v2)
    cos_b = np.einsum("ij,ij->i", A, C)
    cos_c = np.einsum("ij,ij->i", A, B)
    cos_alpha = np.clip(np.einsum("ij,ij->i", _unit_rows(np.cross(A, B)), _unit_rows(np.cross(A, C))),
                        -1.0, 1.0)
    sin_alpha = np.sqrt(np.maximum(0.0, 1.0 - cos_alpha * cos_alpha))
    alpha = np.arccos(cos_alpha)
    phi = u1 * solid_angle - alpha
    sin_phi, cos_phi = np.sin(phi), np.cos(phi)
    u = cos_phi - cos_alpha
    v = sin_phi + sin_alpha * cos_c
    num = (v * cos_phi - u * sin_phi) * cos_alpha - v
    den = (v * sin_phi + u * cos_phi) * sin_alpha
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.clip(np.where(den == 0.0, 1.0, num / den), -1.0, 1.0)
    U = _unit_rows(C - cos_b[:, None] * A)
    C_ = _unit_rows(q[:, None] * A + np.sqrt(1.0 - q * q)[:, None] * U)
    cos_cb = np.einsum("ij,ij->i", C_, B)
    z = 1.0 - u2 * (1.0 - cos_cb)
    w = _unit_rows(C_ - cos_cb[:, None] * B)
    d = z[:, None] * B + np.sqrt(np.maximum(0.0, 1.0 - z * z))[:, None] * w
    return _unit_rows(d), solid_angle


def _search_rows_numpy(flat_cdf, row, key, cols, out):
    out[:] = np.searchsorted(flat_cdf, key, side="right")


@loop_kernel("void(float64[::1], int64[:], float64[:], int64, int64[::1])", _search_rows_numpy)
def _search_rows(flat_cdf, row, key, cols, out):
    """searchsorted(flat_cdf, key, side="right") where key lies in row
    ``row``'s span [row, row + 1): entries before the row are <= row <= key
    and its last entry (row + 1) is > key, so the answer lies in the row
    and a binary search over its ``cols`` entries finds the same index
    (11 steps in L1 instead of 20 across the whole map)."""
    for i in range(len(key)):
        lo = row[i] * cols
        hi = lo + cols
        v = key[i]
        if v != v:   # NaN sorts last, as in NumPy
            out[i] = len(flat_cdf)
            continue
        if not (0 <= lo < len(flat_cdf) and flat_cdf[hi - 1] > v and (lo == 0 or flat_cdf[lo - 1] <= v)):
            lo, hi = 0, len(flat_cdf)   # outside its row (never for keys made by sample): search all
        out[i] = upper_bound(flat_cdf, v, lo, hi)


@helper
def upper_bound(a, v, lo, hi):
    """np.searchsorted(a, v, side="right") within a[lo:hi] (sorted): the
    first k in [lo, hi) with a[k] > v, hi if none."""
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@helper
def disk_point(u1, u2):
    """``concentric_disk``'s point (x, y) on the unit disk for one sample in compiled loops."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if a == 0 and b == 0:
        r, phi = b, 0.0
    elif abs(a) > abs(b):
        r, phi = a, (np.pi / 4) * (b / a)
    else:
        r, phi = b, np.pi / 2 - (np.pi / 4) * (a / b)
    return r * np.cos(phi), r * np.sin(phi)


@helper
def cone_point(u1, u2, one_minus_cos_max):
    """``uniform_cone``'s direction (x, y, cos) for one sample in compiled loops."""
    omc = u1 * one_minus_cos_max
    sin_t = np.sqrt(max(0.0, omc * (2.0 - omc)))
    phi = TWO_PI * u2
    return sin_t * np.cos(phi), sin_t * np.sin(phi), 1.0 - omc


class Distribution2D:
    """Piecewise-constant density on the unit square from a (rows, cols) grid
    of non-negative weights: a marginal distribution over rows and a
    conditional one per row (pbrt's Distribution2D; Cycles' background map).

    Coordinates are (x, y) in [0, 1)^2: x along columns, y along rows (row 0
    covers y in [0, 1/rows)).  Sampling is by inverse CDF with binary search,
    one ``searchsorted`` for the whole batch of rows, and for the columns one
    within each row (``_search_rows``).
    """

    def __init__(self, weights):
        w = np.asarray(weights, dtype=np.float64)
        if w.ndim != 2 or w.size == 0:
            raise ValueError("Distribution2D needs a non-empty 2D weight array")
        w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
        self.rows, self.cols = w.shape
        row_sums = w.sum(axis=1)
        self.marginal = Distribution1D(row_sums)
        # An empty row is never picked by the marginal; give it a uniform
        # conditional so that every row's CDF is well defined.
        w[row_sums <= 0] = 1.0
        self.pmf = w / w.sum(axis=1, keepdims=True)
        cdf = np.cumsum(self.pmf, axis=1)
        last = self.cols - 1 - np.argmax((self.pmf > 0)[:, ::-1], axis=1)
        cdf[np.arange(self.cols)[None, :] >= last[:, None]] = 1.0  # see Distribution1D
        # Row r's CDF shifted to [r, r + 1]: one sorted array for all rows.
        self.flat_cdf = (cdf + np.arange(self.rows)[:, None]).ravel()

    def sample(self, u_row, u_col):
        """Points (x, y) for uniforms (u_row picks the row) and their density."""
        row, p_row, du_row = self.marginal.sample_continuous(u_row)
        u_col = np.asarray(u_col, dtype=np.float64)
        key = row + np.minimum(u_col, np.nextafter(1.0, 0.0))
        k = np.empty(len(key), np.int64)
        _search_rows(self.flat_cdf, column(row, len(key), np.int64), column(key, len(key), np.float64),
                     self.cols, k)
        col = np.clip(k - row * self.cols, 0, self.cols - 1)
        p_col = self.pmf[row, col]
        lo = np.where(col > 0, self.flat_cdf[row * self.cols + np.maximum(col - 1, 0)] - row, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            du_col = np.where(p_col > 0, (u_col - lo) / p_col, 0.0)
        du_col = np.clip(du_col, 0.0, np.nextafter(1.0, 0.0))
        x = (col + du_col) / self.cols
        y = (row + du_row) / self.rows
        return x, y, p_row * p_col * (self.rows * self.cols)

    def pdf(self, x, y):
        """Density at points of the unit square (cells found by truncation)."""
        col = np.clip((np.asarray(x) * self.cols).astype(np.int64), 0, self.cols - 1)
        row = np.clip((np.asarray(y) * self.rows).astype(np.int64), 0, self.rows - 1)
        return self.marginal.pmf[row] * self.pmf[row, col] * (self.rows * self.cols)
