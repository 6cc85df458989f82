"""One Voronoi octave (F1, F2, Smooth F1) as a compiled row loop.

The NumPy form (texture_nodes._voronoi_octave) walks the 3^D (Smooth F1:
5^D) neighbour cells over whole arrays: a dozen (N, D) temporaries per
neighbour, 27 neighbours in 3D.  This loop visits them per point with the
cell's PCG hash (Cycles' hash_pcg{2,3,4}d_i, Blender 5's integer cells) in
registers.  It covers 2D-4D with integer cell hashes; 1D and the float-bit
hashes of older Blenders and the Minkowski metric stay on the NumPy form.  Agreement is tested in
tests/engine/test_kernels.py (test_voronoi_octave_agrees).
"""
import numpy as np

from .. import kernels

FEATURES = {"F1": 0, "F2": 1, "SMOOTH_F1": 2}
METRICS = {"EUCLIDEAN": 0, "MANHATTAN": 1, "CHEBYCHEV": 2, "MINKOWSKI": 3}
# Minkowski's float32 powf rounds differently in libm and NumPy (up to 5
# ulp, beyond what the agreement test allows): it stays on the NumPy form.
COMPILED_METRICS = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV")
_S31 = 1 << 31
_M32 = 0xFFFFFFFF
_MUL, _ADD = 1664525, 1013904223


def supported(dim, feature, metric, pcg):
    return pcg and dim >= 2 and feature in FEATURES and metric in COMPILED_METRICS


# The NumPy reference, texture_nodes._voronoi_octave, handed in by
# texture_nodes when it imports this module (importing it from here would be
# an import cycle: texture_nodes calls the compiled loop).
_reference = []


def set_reference(octave):
    _reference[:] = [octave]


def _numpy_octave(q, rand, expo, smooth, feature, metric, dist, color, pos):
    """The NumPy reference: texture_nodes._voronoi_octave into the outputs."""
    _voronoi_octave, = _reference
    names = {v: k for k, v in FEATURES.items()}, {v: k for k, v in METRICS.items()}
    d, c, p = _voronoi_octave(q, names[0][feature], names[1][metric], expo, rand, smooth, True)
    dist[:], color[:], pos[:] = d, c, p


@kernels.helper
def _i32(x):
    """x (an int64 holding any integer below 2^62) wrapped to int32."""
    return ((x + _S31) & _M32) - _S31


@kernels.helper
def _pcg_into(k, d, out):
    """hash_pcg{2,3,4}d_i of int32 keys k[0:d] (d = 3 also serves 2D colours
    with k[2] = 0), each & 0x7FFFFFFF, into out[0:d]."""
    for j in range(d):
        out[j] = _i32(k[j] * _MUL + _ADD)
    for r in range(2):
        if d == 2:
            out[0] = _i32(out[0] + out[1] * _MUL)
            out[1] = _i32(out[1] + out[0] * _MUL)
        elif d == 3:
            out[0] = _i32(out[0] + out[1] * out[2])
            out[1] = _i32(out[1] + out[2] * out[0])
            out[2] = _i32(out[2] + out[0] * out[1])
        else:
            out[0] = _i32(out[0] + out[1] * out[3])
            out[1] = _i32(out[1] + out[2] * out[0])
            out[2] = _i32(out[2] + out[0] * out[1])
            out[3] = _i32(out[3] + out[1] * out[2])
        if r == 0:
            for j in range(d):
                out[j] = out[j] ^ (out[j] >> 16)   # arithmetic shift of a signed value
    for j in range(d):
        out[j] = out[j] & 0x7FFFFFFF


@kernels.helper
def _cell_colour(key, dim, h, colour):
    """hash_int{2,3,4}_to_float3 of the cell key[0:dim] into colour[0:3]."""
    inv = np.float32(1.0 / 2147483648.0)
    if dim == 2:
        key[2] = 0
        _pcg_into(key, 3, h)
    else:
        _pcg_into(key, dim, h)
    for j in range(3):
        colour[j] = np.float32(h[j]) * inv


@kernels.helper
def _metric(v, dim, metric):
    """texture_nodes._distance of one offset vector v[0:dim] (float32) for
    Euclidean, Manhattan and Chebychev; one accumulation and a single return
    (several returns trip numba's SSA pass: NumbaIRAssumptionWarning)."""
    total = np.float32(0.0)
    for j in range(dim):
        a = abs(v[j])
        if metric == 0:
            total += v[j] * v[j]
        elif metric == 1:
            total += a
        elif not a <= total and not np.isnan(total):   # Chebychev; NaN wins, as np.max
            total = a
    if metric == 0:
        total = np.float32(np.sqrt(total))
    return total


@kernels.helper
def _bound(off, local, r, dim, metric, squared, gap):
    """A lower bound of the distance (as the loop measures it) from the
    point to any feature point of the cell at offset off: each axis' gap
    between the point and the cell's box [off, off + r], shrunk by 1e-5
    (far above the float32 rounding of the distance, coordinates being
    O(1) there), so that the measured distance exceeds it whenever it is
    positive.  Rounding is monotonic, so the same sum over the gaps stays
    at or below the measured one."""
    zero = np.float32(0.0)
    eps = np.float32(1e-5)
    for j in range(dim):
        lo = off[j] - local[j]
        hi = lo + r
        g = zero
        if lo > zero:
            g = lo - eps
        elif hi < zero:
            g = -hi - eps
        gap[j] = g if g > zero else zero
    if squared:
        total = zero
        for j in range(dim):
            total += gap[j] * gap[j]
    else:
        total = _metric(gap, dim, metric)
    return total


@kernels.helper
def _cell_distance(cell_i, off, local, r, dim, metric, squared, key, h, point, v):
    """The distance (squared for Euclidean F1) to the feature point of the
    cell at offset off, its point (relative to the point's cell) in point."""
    inv = np.float32(1.0 / 2147483648.0)
    for j in range(dim):
        key[j] = _i32(cell_i[j] + np.int64(off[j]))
    _pcg_into(key, dim, h)
    for j in range(dim):
        point[j] = off[j] + (np.float32(h[j]) * inv) * r
        v[j] = point[j] - local[j]
    if squared:
        dd = np.float32(0.0)
        for j in range(dim):
            dd += v[j] * v[j]
    else:
        dd = _metric(v, dim, metric)
    return dd


@kernels.loop_kernel("void(float32[:, ::1], float32[::1], float32[::1], float32[::1], int64, int64, "
                     "float32[::1], float32[:, ::1], float32[:, ::1])", _numpy_octave)
def voronoi_octave_loop(q, rand, expo, smooth, feature, metric, dist, color, pos):
    """dist, color, pos of one octave at q (N, D); expo (Minkowski's
    exponent) is the NumPy form's argument, unused by the compiled metrics."""
    n, dim = q.shape
    one, zero, half = np.float32(1.0), np.float32(0.0), np.float32(0.5)
    big = np.float32(3.4028234663852886e38)
    inv = np.float32(1.0 / 2147483648.0)
    reach = 2 if feature == 2 else 1
    side = 2 * reach + 1
    count = side ** dim
    cell = np.empty(4, np.float32)
    local = np.empty(4, np.float32)
    cell_i = np.empty(4, np.int64)
    key = np.zeros(4, np.int64)
    h = np.zeros(4, np.int64)
    off = np.empty(4, np.float32)
    point = np.empty(4, np.float32)
    v = np.empty(4, np.float32)
    gap = np.empty(4, np.float32)
    d0 = big
    o1 = np.zeros(4, np.float32)
    o2 = np.zeros(4, np.float32)
    p1 = np.zeros(4, np.float32)
    p2 = np.zeros(4, np.float32)
    sp = np.zeros(4, np.float32)
    sc = np.zeros(3, np.float32)
    colour = np.zeros(3, np.float32)
    squared = feature == 0 and metric == 0
    for i in range(n):
        r, s = rand[i], smooth[i]
        for j in range(dim):
            c = np.float32(np.floor(q[i, j]))
            cell[j] = c
            local[j] = q[i, j] - c
            # NumPy's int64 cast of what does not fit is INT64_MIN: 0 as int32.
            cell_i[j] = _i32(np.int64(c)) if abs(c) < np.float32(9.2e18) else 0
        d1 = big
        d2 = big
        sd = zero
        for j in range(4):
            o1[j] = zero
            o2[j] = zero
            p1[j] = zero
            p2[j] = zero
            sp[j] = zero
        for j in range(3):
            sc[j] = zero
        if feature == 0:
            # F1: the point's own cell first; a cell whose box lies farther
            # cannot hold the nearest point and is not hashed.  Exact: the
            # cells skipped measure more than one that is visited, so the
            # first nearest in Cycles' order is the same (NaN skips none).
            for j in range(dim):
                off[j] = zero
            d0 = _cell_distance(cell_i, off, local, r, dim, metric, squared, key, h, point, v)
        for idx in range(count):
            rest = idx
            for j in range(dim):
                off[j] = np.float32(rest % side - reach)
                rest //= side
            if feature == 0 and _bound(off, local, r, dim, metric, squared, gap) > d0:
                continue
            dd = _cell_distance(cell_i, off, local, r, dim, metric, squared, key, h, point, v)
            if feature == 2:
                if idx == 0:
                    w = one
                else:
                    x = half + half * (sd - dd) / s
                    if x < zero:
                        w = zero
                    elif x >= one:
                        w = one
                    else:
                        w = (np.float32(3.0) - np.float32(2.0) * x) * (x * x)
                corr = s * w * (one - w)
                sd = (one - w) * sd + w * dd - corr
                corr = corr / (one + np.float32(3.0) * s)
                for j in range(dim):
                    key[j] = _i32(cell_i[j] + np.int64(off[j]))
                _cell_colour(key, dim, h, colour)
                for j in range(3):
                    sc[j] = (one - w) * sc[j] + w * colour[j] - corr
                for j in range(dim):
                    sp[j] = (one - w) * sp[j] + w * point[j] - corr
                continue
            if dd < d1:
                d2 = d1
                d1 = dd
                for j in range(dim):
                    o2[j] = o1[j]
                    p2[j] = p1[j]
                    o1[j] = off[j]
                    p1[j] = point[j]
            elif dd < d2:
                d2 = dd
                for j in range(dim):
                    o2[j] = off[j]
                    p2[j] = point[j]
        if feature == 2:
            dist[i] = sd
            for j in range(3):
                color[i, j] = sc[j]
            for j in range(dim):
                pos[i, j] = cell[j] + sp[j]
            continue
        if feature == 1:
            dist[i] = d2
            for j in range(dim):
                o1[j] = o2[j]
                p1[j] = p2[j]
        else:
            # F1 measures its winner after comparing (squared Euclidean).
            for j in range(dim):
                v[j] = p1[j] - local[j]
            dist[i] = _metric(v, dim, metric)
        for j in range(dim):
            key[j] = _i32(cell_i[j] + np.int64(o1[j]))
            pos[i, j] = p1[j] + cell[j]
        _cell_colour(key, dim, h, colour)
        for j in range(3):
            color[i, j] = colour[j]
