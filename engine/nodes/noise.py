"""Perlin noise and its fractals as Cycles' SVM computes them
(kernel/svm/noise.h, fractal_noise.h), in float32 on (N,) / (N, D) arrays."""
import itertools

import numpy as np

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


def snoise(p):
    """Cycles' snoise_{1,2,3,4}d: wrapped at 1e5, scaled to about [-1, 1]."""
    p = np.fmod(p.astype(F), F(100000.0))
    return SCALES[p.shape[1]] * perlin(p)


def random_offset(dim, seed):
    """random_float{dim}_offset(seed): components in [100, 200]."""
    seed = np.array([seed], F)
    if dim == 1:
        return F(100.0) + hash_float(seed) * F(100.0)
    return np.array([F(100.0) + hash_float(seed, np.array([k], F))[0] * F(100.0) for k in range(dim)], F)


def fbm(p, detail, roughness, lacunarity, normalize):
    """noise_fbm; detail, roughness, lacunarity are (N,) float32."""
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
