"""Perlin noise and its fractals as Cycles' SVM computes them
(kernel/svm/noise.h, fractal_noise.h), in float32 on (N,) / (N, D) arrays."""
import itertools

import numpy as np

from .. import kernels
from .hashing import hash_float, hash_uint

F = np.float32
SCALES = {1: F(0.25), 2: F(0.6616), 3: F(0.982), 4: F(0.8344)}


def _fade(t):
    return t * t * t * (t * (t * F(6.0) - F(15.0)) + F(10.0))


def _negate_if(v, cond):
    return np.where(cond != 0, -v, v)


def _grad(h, f):
    """Gradient dot offset for hash h and offsets f (list of D arrays)."""
    h = h.astype(np.int64)
    d = len(f)
    if d == 1:
        h = h & 15
        g = F(1.0) + (h & 7).astype(F)
        return _negate_if(g, h & 8) * f[0]
    if d == 2:
        h = h & 7
        u = np.where(h < 4, f[0], f[1])
        v = F(2.0) * np.where(h < 4, f[1], f[0])
        return _negate_if(u, h & 1) + _negate_if(v, h & 2)
    if d == 3:
        h = h & 15
        u = np.where(h < 8, f[0], f[1])
        vt = np.where((h == 12) | (h == 14), f[0], f[2])
        v = np.where(h < 4, f[1], vt)
        return _negate_if(u, h & 1) + _negate_if(v, h & 2)
    h = h & 31
    u = np.where(h < 24, f[0], f[1])
    v = np.where(h < 16, f[1], f[2])
    s = np.where(h < 8, f[2], f[3])
    return _negate_if(u, h & 1) + _negate_if(v, h & 2) + _negate_if(s, h & 4)


def perlin(p):
    """Signed Perlin noise (unscaled) of p (N, D) float32, D in 1..4."""
    d = p.shape[1]
    cell = np.floor(p)
    frac = (p - cell).astype(F)
    ci = cell.astype(np.int64)
    fade = _fade(frac)
    # Corner values, then lerp along x, y, z, w in turn (Cycles' bi/tri/quad mix).
    values = {}
    for corner in itertools.product((0, 1), repeat=d):
        h = hash_uint(*(ci[:, k] + corner[k] for k in range(d)))
        off = [frac[:, k] - F(corner[k]) for k in range(d)]
        values[corner] = _grad(h, off)
    for axis in range(d):
        t = fade[:, axis]
        merged = {}
        for corner, v in values.items():
            if corner[axis] == 0:
                other = corner[:axis] + (1,) + corner[axis + 1:]
                merged[corner] = (F(1.0) - t) * v + t * values[other]
        values = merged
    return values[(0,) * d]


def _snoise_numpy(p, out):
    """snoise of p (N, D) float32 into out (N,): the NumPy reference form."""
    with np.errstate(invalid="ignore"):   # non-finite points: NaN, as the compiled loop
        wrapped = np.fmod(p, F(100000.0))
        out[:] = SCALES[p.shape[1]] * perlin(wrapped)


# lookup3 on uint32 values held in int64 (every step masked to 32 bits): numba
# types int64 arithmetic without the uint64/int64 -> float64 promotion.
_M32 = 0xFFFFFFFF


@kernels.helper
def _rot32(x, k):
    return ((x << k) | (x >> (32 - k))) & _M32


@kernels.helper
def _lookup3(n, k0, k1, k2, k3):
    """hash_uint{,2,3,4} of n keys (util/hash.h), keys in [0, 2^32)."""
    a = b = c = (0xDEADBEEF + (n << 2) + 13) & _M32
    if n == 4:
        a = (a + k0) & _M32
        b = (b + k1) & _M32
        c = (c + k2) & _M32
        a = (a - c) & _M32; a ^= _rot32(c, 4); c = (c + b) & _M32
        b = (b - a) & _M32; b ^= _rot32(a, 6); a = (a + c) & _M32
        c = (c - b) & _M32; c ^= _rot32(b, 8); b = (b + a) & _M32
        a = (a - c) & _M32; a ^= _rot32(c, 16); c = (c + b) & _M32
        b = (b - a) & _M32; b ^= _rot32(a, 19); a = (a + c) & _M32
        c = (c - b) & _M32; c ^= _rot32(b, 4); b = (b + a) & _M32
        a = (a + k3) & _M32
    else:
        if n >= 3:
            c = (c + k2) & _M32
        if n >= 2:
            b = (b + k1) & _M32
        a = (a + k0) & _M32
    c ^= b; c = (c - _rot32(b, 14)) & _M32
    a ^= c; a = (a - _rot32(c, 11)) & _M32
    b ^= a; b = (b - _rot32(a, 25)) & _M32
    c ^= b; c = (c - _rot32(b, 16)) & _M32
    a ^= c; a = (a - _rot32(c, 4)) & _M32
    b ^= a; b = (b - _rot32(a, 14)) & _M32
    c ^= b; c = (c - _rot32(b, 24)) & _M32
    return c


@kernels.helper
def _signed(v, negate):
    # -v when negate != 0; a product by +-1 (exact), not a branch: an inlined
    # conditional expression trips numba's SSA pass (NumbaIRAssumptionWarning).
    return v * np.float32(1 - 2 * (negate != 0))


@kernels.helper
def _grad_scalar(h, d, f):
    """_grad for one point: hash h, offsets f[0:d] (float32)."""
    if d == 1:
        h = h & 15
        return _signed(np.float32(1.0) + np.float32(h & 7), h & 8) * f[0]
    if d == 2:
        h = h & 7
        u = f[0] if h < 4 else f[1]
        v = np.float32(2.0) * (f[1] if h < 4 else f[0])
        return _signed(u, h & 1) + _signed(v, h & 2)
    if d == 3:
        h = h & 15
        u = f[0] if h < 8 else f[1]
        f02 = f[0] if (h == 12) | (h == 14) else f[2]   # no short-circuit: selects, not branches
        v = f[1] if h < 4 else f02
        return _signed(u, h & 1) + _signed(v, h & 2)
    h = h & 31
    u = f[0] if h < 24 else f[1]
    v = f[1] if h < 16 else f[2]
    w = f[2] if h < 8 else f[3]
    return _signed(u, h & 1) + _signed(v, h & 2) + _signed(w, h & 4)


@kernels.loop_kernel("void(float32[:, ::1], float32[::1])", _snoise_numpy)
def _snoise_loop(p, out):
    n, d = p.shape
    scale = np.float32((0.25, 0.6616, 0.982, 0.8344)[d - 1])
    cell = np.empty(4, np.int64)
    frac = np.empty(4, np.float32)
    fade = np.empty(4, np.float32)
    off = np.empty(4, np.float32)
    keys = np.zeros(4, np.int64)
    values = np.empty(16, np.float32)
    one = np.float32(1.0)
    for i in range(n):
        for k in range(d):
            x = np.float32(np.fmod(np.float64(p[i, k]), 100000.0))   # exact in float64
            fl = np.float32(np.floor(x))
            cell[k] = np.int64(fl)
            t = x - fl
            frac[k] = t
            fade[k] = t * t * t * (t * (t * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))
        for corner in range(1 << d):
            for k in range(d):
                bit = (corner >> k) & 1
                keys[k] = (cell[k] + bit) & _M32
                off[k] = frac[k] - np.float32(bit)
            values[corner] = _grad_scalar(_lookup3(d, keys[0], keys[1], keys[2], keys[3]), d, off)
        # Lerp along x, y, z, w in turn, as the NumPy form (Cycles' nested mixes).
        for k in range(d):
            t = fade[k]
            for corner in range(1 << d):
                if (corner >> k) & 1 == 0:
                    values[corner] = (one - t) * values[corner] + t * values[corner | (1 << k)]
        out[i] = scale * values[0]


@kernels.helper
def _grad3(h, x, y, z):
    """_grad_scalar for D = 3 with the offsets in registers."""
    h = h & 15
    u = x if h < 8 else y
    xz = x if (h == 12) | (h == 14) else z   # no short-circuit: selects, not branches
    v = y if h < 4 else xz
    return _signed(u, h & 1) + _signed(v, h & 2)


@kernels.helper
def _wrap(x):
    """fmod(x, 1e5) (exact in float64); the identity below 1e5, which is
    nearly every point, without the libm call."""
    if abs(x) < np.float32(100000.0):
        return x
    return np.float32(np.fmod(np.float64(x), 100000.0))


@kernels.helper
def _snoise3(x, y, z, memo, octave):
    """snoise_3d of one point (float32), unrolled: the generic loop keeps
    its corners in small arrays, at about 4x the cost.  memo[octave] holds
    the last lattice cell (columns 0-2) and its eight corner hashes (3-10):
    the bump's four copies of a point (engine/nodes/context.py
    shifted_pairs: consecutive rows) nearly always share their cells, so
    three of four skip the hashing, the dearest part (the hashes are a
    function of the cell: the values are the same)."""
    one = np.float32(1.0)
    x, y, z = _wrap(x), _wrap(y), _wrap(z)
    fx, fy, fz = np.float32(np.floor(x)), np.float32(np.floor(y)), np.float32(np.floor(z))
    ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
    m = memo[max(0, min(octave, memo.shape[0] - 1))]   # a shared row only misses more
    if ix != m[0] or iy != m[1] or iz != m[2]:
        a0, a1 = ix & _M32, (ix + 1) & _M32
        b0, b1 = iy & _M32, (iy + 1) & _M32
        c0, c1 = iz & _M32, (iz + 1) & _M32
        m[0], m[1], m[2] = ix, iy, iz
        m[3] = _lookup3(3, a0, b0, c0, 0)
        m[4] = _lookup3(3, a1, b0, c0, 0)
        m[5] = _lookup3(3, a0, b1, c0, 0)
        m[6] = _lookup3(3, a1, b1, c0, 0)
        m[7] = _lookup3(3, a0, b0, c1, 0)
        m[8] = _lookup3(3, a1, b0, c1, 0)
        m[9] = _lookup3(3, a0, b1, c1, 0)
        m[10] = _lookup3(3, a1, b1, c1, 0)
    x, y, z = x - fx, y - fy, z - fz
    u = x * x * x * (x * (x * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))
    v = y * y * y * (y * (y * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))
    w = z * z * z * (z * (z * np.float32(6.0) - np.float32(15.0)) + np.float32(10.0))
    x1, y1, z1 = x - one, y - one, z - one
    v000 = _grad3(m[3], x, y, z)
    v100 = _grad3(m[4], x1, y, z)
    v010 = _grad3(m[5], x, y1, z)
    v110 = _grad3(m[6], x1, y1, z)
    v001 = _grad3(m[7], x, y, z1)
    v101 = _grad3(m[8], x1, y, z1)
    v011 = _grad3(m[9], x, y1, z1)
    v111 = _grad3(m[10], x1, y1, z1)
    # Lerp along x, then y, then z (as the generic loop and Cycles' tri_mix).
    e00 = (one - u) * v000 + u * v100
    e10 = (one - u) * v010 + u * v110
    e01 = (one - u) * v001 + u * v101
    e11 = (one - u) * v011 + u * v111
    g0 = (one - v) * e00 + v * e10
    g1 = (one - v) * e01 + v * e11
    return np.float32(0.982) * ((one - w) * g0 + w * g1)


def _fbm3_numpy(p, detail, roughness, lacunarity, normalize, out):
    out[:] = _fbm_arrays(p, detail, roughness, lacunarity, normalize != 0)


@kernels.loop_kernel("void(float32[:, ::1], float32[::1], float32[::1], float32[::1], int64, float32[::1])",
                     _fbm3_numpy)
def _fbm3_loop(p, detail, roughness, lacunarity, normalize, out):
    """noise_fbm in 3D, all octaves of a point in one pass (the NumPy form
    makes a temporary per octave and operation)."""
    one, half = np.float32(1.0), np.float32(0.5)
    # One cell memo per octave (detail <= 15: 16 octaves and the partial
    # one); no int64 cell of a float32 below 1e5 is -2^62.
    memo = np.full((17, 11), -(1 << 62), np.int64)
    for i in range(p.shape[0]):
        px, py, pz = p[i, 0], p[i, 1], p[i, 2]
        d, rough, lac = detail[i], roughness[i], lacunarity[i]
        if not np.isfinite(d):   # the array form: no octave, 0 / 0
            out[i] = np.float32(np.nan)
            continue
        fscale, amp = one, one
        maxamp, total = np.float32(0.0), np.float32(0.0)
        octaves = np.int64(d) + 1
        for o in range(octaves):
            t = _snoise3(fscale * px, fscale * py, fscale * pz, memo, o)
            total = total + t * amp
            maxamp = maxamp + amp
            amp = amp * rough
            fscale = fscale * lac
        rmd = np.float32(d - np.float32(np.floor(d)))
        a = half * total / maxamp + half if normalize != 0 else total
        if rmd != 0:
            t = _snoise3(fscale * px, fscale * py, fscale * pz, memo, octaves)
            sum2 = total + t * amp
            b = half * sum2 / (maxamp + amp) + half if normalize != 0 else sum2
            a = (one - rmd) * a + rmd * b
        out[i] = a


def snoise(p):
    """Cycles' snoise_{1,2,3,4}d: wrapped at 1e5, scaled to about [-1, 1]."""
    p = np.ascontiguousarray(p, F)
    out = np.empty(len(p), F)
    if len(p):
        _snoise_loop(p, out)
    return out


def random_offset(dim, seed):
    """random_float{dim}_offset(seed): components in [100, 200]."""
    seed = np.array([seed], F)
    if dim == 1:
        return F(100.0) + hash_float(seed) * F(100.0)
    return np.array([F(100.0) + hash_float(seed, np.array([k], F))[0] * F(100.0) for k in range(dim)], F)


def fbm(p, detail, roughness, lacunarity, normalize):
    """noise_fbm; detail, roughness, lacunarity are (N,) float32 (in 3D by
    the fused loop, else over arrays)."""
    if p.ndim != 2 or p.shape[1] != 3:
        return _fbm_arrays(p, detail, roughness, lacunarity, normalize)
    n = len(p)
    out = np.empty(n, F)
    if n:
        _fbm3_loop(np.ascontiguousarray(p, F), *(np.array(np.broadcast_to(a, (n,)), F)
                                                 for a in (detail, roughness, lacunarity)),
                   int(bool(normalize)), out)
    return out


def _fbm_arrays(p, detail, roughness, lacunarity, normalize):
    """noise_fbm over arrays (the NumPy reference form, and 1D, 2D, 4D)."""
    n = len(p)
    fscale = np.ones(n, F)
    amp = np.ones(n, F)
    maxamp = np.zeros(n, F)
    total = np.zeros(n, F)
    octaves = detail.astype(np.int64)
    for i in range(int(octaves.max(initial=0)) + 1):
        live = i <= octaves
        t = snoise(fscale[:, None] * p)
        total = np.where(live, total + t * amp, total)
        maxamp = np.where(live, maxamp + amp, maxamp)
        amp = np.where(live, amp * roughness, amp)
        fscale = np.where(live, fscale * lacunarity, fscale)
    rmd = (detail - np.floor(detail)).astype(F)
    if not rmd.any():   # integer detail everywhere: no partial octave to blend
        with np.errstate(divide="ignore", invalid="ignore"):
            return F(0.5) * total / maxamp + F(0.5) if normalize else total
    t = snoise(fscale[:, None] * p)
    sum2 = total + t * amp
    with np.errstate(divide="ignore", invalid="ignore"):
        if normalize:
            a = F(0.5) * total / maxamp + F(0.5)
            b = F(0.5) * sum2 / (maxamp + amp) + F(0.5)
        else:
            a, b = total, sum2
    return np.where(rmd != 0, (F(1.0) - rmd) * a + rmd * b, a)


def multi_fractal(p, detail, roughness, lacunarity):
    n = len(p)
    value = np.ones(n, F)
    pwr = np.ones(n, F)
    p = p.copy()
    octaves = detail.astype(np.int64)
    for i in range(int(octaves.max(initial=0)) + 1):
        live = (i <= octaves)
        value = np.where(live, value * (pwr * snoise(p) + F(1.0)), value)
        pwr = np.where(live, pwr * roughness, pwr)
        p = np.where(live[:, None], p * lacunarity[:, None], p)
    rmd = (detail - np.floor(detail)).astype(F)
    if not rmd.any():
        return value
    return np.where(rmd != 0, value * (rmd * pwr * snoise(p) + F(1.0)), value)


def hetero_terrain(p, detail, roughness, lacunarity, offset):
    pwr = roughness.copy()
    value = offset + snoise(p)
    p = p * lacunarity[:, None]
    octaves = detail.astype(np.int64)
    for i in range(1, int(octaves.max(initial=0)) + 1):
        live = i <= octaves
        inc = (snoise(p) + offset) * pwr * value
        value = np.where(live, value + inc, value)
        pwr = np.where(live, pwr * roughness, pwr)
        p = np.where(live[:, None], p * lacunarity[:, None], p)
    rmd = (detail - np.floor(detail)).astype(F)
    if not rmd.any():
        return value
    inc = (snoise(p) + offset) * pwr * value
    return np.where(rmd != 0, value + rmd * inc, value)


def hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    n = len(p)
    pwr = np.ones(n, F)
    value = np.zeros(n, F)
    weight = np.ones(n, F)
    octaves = detail.astype(np.int64)
    for i in range(int(octaves.max(initial=0)) + 1):
        live = (weight > F(0.001)) & (i <= octaves)
        weight = np.where(live, np.minimum(weight, F(1.0)), weight)
        signal = (snoise(p) + offset) * pwr
        pwr = np.where(live, pwr * roughness, pwr)
        value = np.where(live, value + weight * signal, value)
        weight = np.where(live, weight * gain * signal, weight)
        p = np.where(live[:, None], p * lacunarity[:, None], p)
    rmd = (detail - np.floor(detail)).astype(F)
    ok = (rmd != 0) & (weight > F(0.001))
    if not ok.any():
        return value
    w = np.minimum(weight, F(1.0))
    signal = (snoise(p) + offset) * pwr
    return np.where(ok, value + rmd * w * signal, value)


def ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    pwr = roughness.copy()
    signal = offset - np.abs(snoise(p))
    signal = signal * signal
    value = signal
    octaves = detail.astype(np.int64)
    for i in range(1, int(octaves.max(initial=0)) + 1):
        live = i <= octaves
        p = np.where(live[:, None], p * lacunarity[:, None], p)
        weight = np.clip(signal * gain, F(0.0), F(1.0))
        s = offset - np.abs(snoise(p))
        s = s * s * weight
        value = np.where(live, value + s * pwr, value)
        signal = np.where(live, s, signal)
        pwr = np.where(live, pwr * roughness, pwr)
    return value


def fractal(kind, p, detail, roughness, lacunarity, offset, gain, normalize):
    if kind == "FBM":
        return fbm(p, detail, roughness, lacunarity, normalize)
    if kind == "MULTIFRACTAL":
        return multi_fractal(p, detail, roughness, lacunarity)
    if kind == "HETERO_TERRAIN":
        return hetero_terrain(p, detail, roughness, lacunarity, offset)
    if kind == "HYBRID_MULTIFRACTAL":
        return hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if kind == "RIDGED_MULTIFRACTAL":
        return ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    raise ValueError(f"unknown noise type {kind!r}")
