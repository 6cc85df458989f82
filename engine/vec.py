"""Small vector helpers on (N, 3) float arrays."""
import numpy as np

from . import kernels


def dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def norm(a):
    return np.sqrt(dot(a, a))


def normalize(a):
    n = norm(a)
    return a / np.where(n > 0, n, 1.0)[:, None]


# Row reductions of (N, k) arrays with small k, column by column: NumPy's
# reductions along a short last axis cost 5-10x a few elementwise ops
# (np.any(x > 0, axis=1) on (N, 3): 25 ns per row; these: 3-5 ns).
# Same results, NaN included (np.maximum propagates it as max does).

def row_max(x):
    m = x[:, 0]
    for k in range(1, x.shape[1]):
        m = np.maximum(m, x[:, k])
    return m


def row_any_positive(x):
    out = x[:, 0] > 0
    for k in range(1, x.shape[1]):
        out |= x[:, k] > 0
    return out


def row_all_finite(x):
    out = np.isfinite(x[:, 0])
    for k in range(1, x.shape[1]):
        out &= np.isfinite(x[:, k])
    return out


def cross(a, b):
    return np.cross(a, b)


def _frame_numpy(n, s, t):
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s[:] = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t[:] = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)


# The per-row loops below run where the compiled kernels are on: the values
# of their NumPy forms within rounding, without an (N,) temporary per product.

@kernels.helper
def frame_of(n0, n1, n2):
    """``frame`` of one unit normal in compiled loops: s0, s1, s2, t0, t1, t2.
    The sign is arithmetic, not a conditional expression: inlined into
    loops that branch, a conditional's phi node tripped numba's SSA check
    (NumbaIRAssumptionWarning: variable not in scope)."""
    sign = 2.0 * (n2 >= 0.0) - 1.0
    a = -1.0 / (sign + n2)
    b = n0 * n1 * a
    return 1.0 + sign * (n0 * n0) * a, sign * b, -sign * n0, b, sign + (n1 * n1) * a, -n1


@kernels.loop_kernel("void(float64[:, :], float64[:, ::1], float64[:, ::1])", _frame_numpy)
def _frame_rows(n, s, t):
    for i in range(len(n)):
        s[i, 0], s[i, 1], s[i, 2], t[i, 0], t[i, 1], t[i, 2] = frame_of(n[i, 0], n[i, 1], n[i, 2])


def frame(n):
    """Orthonormal tangents (s, t) for unit normals n (Duff et al. 2017)."""
    n = _loopable(n)
    s, t = np.empty(n.shape), np.empty(n.shape)
    _frame_rows(n, s, t)
    return s, t


def _to_local_numpy(v, s, t, n, out):
    out[:] = np.stack([dot(v, s), dot(v, t), dot(v, n)], axis=1)


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64[:, ::1])",
                     _to_local_numpy)
def _to_local_rows(v, s, t, n, out):
    for i in range(len(v)):
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        out[i, 0] = (v0 * s[i, 0] + v2 * s[i, 2]) + v1 * s[i, 1]
        out[i, 1] = (v0 * t[i, 0] + v2 * t[i, 2]) + v1 * t[i, 1]
        out[i, 2] = (v0 * n[i, 0] + v2 * n[i, 2]) + v1 * n[i, 1]


def _to_world_numpy(v, s, t, n, out):
    out[:] = v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n


@kernels.loop_kernel("void(float64[:, :], float64[:, :], float64[:, :], float64[:, :], float64[:, ::1])",
                     _to_world_numpy)
def _to_world_rows(v, s, t, n, out):
    for i in range(len(v)):
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        for k in range(3):
            out[i, k] = (v0 * s[i, k] + v1 * t[i, k]) + v2 * n[i, k]


def rows3(*arrays):
    """The arrays as float64 rows of unit stride when all are (N, 3) of one
    N (the loops' case).  einsum sums in another order where an operand's
    rows are strided, so those are copied: both forms then agree."""
    arrays = [_loopable(a) for a in arrays]
    shape = arrays[0].shape
    if len(shape) == 2 and shape[1] == 3 and all(a.shape == shape for a in arrays):
        return arrays
    return None


def contiguous(a, dtype=np.float64):
    """C-contiguous and writable (numba's signatures take no read-only
    arrays): a copy only where the array is not so already.  The checks
    first: most arrays already are, and this runs some 150 times a bounce."""
    if type(a) is np.ndarray and a.ndim and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable:
        return a
    a = np.ascontiguousarray(a, dtype)
    return a if a.flags.writeable else a.copy()


def column(a, n, dtype):
    """``a`` as a writable (n,) array of ``dtype`` (a scalar repeated)."""
    a = np.asarray(a, dtype)
    return a if a.shape == (n,) and a.flags.writeable else np.array(np.broadcast_to(a, (n,)))


def _loopable(a):
    """float64, rows of unit stride, writable (numba's signatures here take
    no read-only arrays); a copy only where that is not so already."""
    a = np.asarray(a, np.float64)
    if a.ndim == 2 and (a.strides[1] != 8 or not a.flags.writeable):
        return np.array(a, order="C")
    return a


def to_local(v, s, t, n):
    rows = rows3(v, s, t, n)
    if rows is None:
        return np.stack([dot(v, s), dot(v, t), dot(v, n)], axis=1)
    out = np.empty(rows[0].shape)
    _to_local_rows(*rows, out)
    return out


def to_world(v, s, t, n):
    rows = rows3(v, s, t, n)
    if rows is None:
        return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n
    out = np.empty(rows[0].shape)
    _to_world_rows(*rows, out)
    return out


def luminance(rgb):
    """Rec.709 luminance, Blender's default scene-linear space."""
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def transform_points(m, p):
    return p @ m[:3, :3].T + m[:3, 3]


def transform_vectors(m, v):
    return v @ m[:3, :3].T


def subset(mask):
    """Index for the True entries of mask: a slice when all are True, so the
    common single-material or single-light case works on views, not copies."""
    if mask.all():
        return slice(None)
    return np.nonzero(mask)[0]


def count(index, n):
    return n if isinstance(index, slice) else len(index)
