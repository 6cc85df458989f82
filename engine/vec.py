"""Small vector helpers on (N, 3) float arrays."""
import numpy as np


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


def frame(n):
    """Orthonormal tangents (s, t) for unit normals n (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return s, t


def to_local(v, s, t, n):
    return np.stack([dot(v, s), dot(v, t), dot(v, n)], axis=1)


def to_world(v, s, t, n):
    return v[:, 0:1] * s + v[:, 1:2] * t + v[:, 2:3] * n


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
