"""Jenkins lookup3 hashes as Cycles uses them (util/hash.h), vectorized.

Arithmetic wraps in uint32.  Float keys are hashed by their float32 bit
patterns, so callers pass float32 arrays (-0.0 and 0.0 differ, as in Cycles).
"""
import numpy as np

U32 = np.uint32
INV_UINT_MAX = np.float32(1.0 / 4294967296.0)   # Cycles' 1.0f / (float)0xFFFFFFFFu


def _rot(x, k):
    return (x << U32(k)) | (x >> U32(32 - k))


def _final(a, b, c):
    c ^= b; c -= _rot(b, 14)
    a ^= c; a -= _rot(c, 11)
    b ^= a; b -= _rot(a, 25)
    c ^= b; c -= _rot(b, 16)
    a ^= c; a -= _rot(c, 4)
    b ^= a; b -= _rot(a, 14)
    c ^= b; c -= _rot(b, 24)
    return a, b, c


def _mix(a, b, c):
    a -= c; a ^= _rot(c, 4); c += b
    b -= a; b ^= _rot(a, 6); a += c
    c -= b; c ^= _rot(b, 8); b += a
    a -= c; a ^= _rot(c, 16); c += b
    b -= a; b ^= _rot(a, 19); a += c
    c -= b; c ^= _rot(b, 4); b += a
    return a, b, c


def _u32(x):
    x = np.asarray(x)
    if x.dtype == np.float32:
        return x.view(U32).copy()
    return x.astype(np.int64).astype(U32) if x.dtype != U32 else x.copy()


def hash_uint(*keys):
    """lookup3 of 1-4 uint32 keys (int arrays wrap to uint32)."""
    keys = [_u32(k) for k in keys]
    shape = np.broadcast_shapes(*(k.shape for k in keys))
    keys = [np.broadcast_to(k, shape).copy() for k in keys]
    n = len(keys)
    init = U32((0xDEADBEEF + (n << 2) + 13) & 0xFFFFFFFF)
    a, b, c = (np.full(shape, init, U32) for _ in range(3))
    with np.errstate(over="ignore"):
        if n == 4:
            a += keys[0]; b += keys[1]; c += keys[2]
            a, b, c = _mix(a, b, c)
            a += keys[3]
        else:
            if n >= 3:
                c += keys[2]
            if n >= 2:
                b += keys[1]
            a += keys[0]
        a, b, c = _final(a, b, c)
    return c


def to_float(h):
    """uint32 -> float32 in [0, 1] as uint_to_float_incl."""
    return h.astype(np.float32) * INV_UINT_MAX


def hash_float(*keys):
    """hash_float{,2,3,4}_to_float: float32 keys by their bits."""
    return to_float(hash_uint(*(np.asarray(k, dtype=np.float32) for k in keys)))


ONE, TWO, THREE = np.float32(1.0), np.float32(2.0), np.float32(3.0)


def hash_to_float2(x, y):
    return np.stack([hash_float(x, y), hash_float(x, y, _full(x, ONE))], axis=-1)


def hash_to_float3(*k):
    """hash_float{,2,3,4}_to_float3 for 1-4 float32 components."""
    if len(k) == 1:
        x, = k
        return np.stack([hash_float(x), hash_float(x, _full(x, ONE)), hash_float(x, _full(x, TWO))], axis=-1)
    if len(k) == 2:
        x, y = k
        return np.stack([hash_float(x, y), hash_float(x, y, _full(x, ONE)),
                         hash_float(x, y, _full(x, TWO))], axis=-1)
    if len(k) == 3:
        x, y, z = k
        return np.stack([hash_float(x, y, z), hash_float(x, y, z, _full(x, ONE)),
                         hash_float(x, y, z, _full(x, TWO))], axis=-1)
    x, y, z, w = k
    return np.stack([hash_float(x, y, z, w), hash_float(z, x, w, y), hash_float(w, z, y, x)], axis=-1)


def hash_to_float4(x, y, z, w):
    return np.stack([hash_float(x, y, z, w), hash_float(w, x, y, z), hash_float(z, w, x, y),
                     hash_float(y, z, w, x)], axis=-1)


def hash_same_dim(*k):
    """hash_float{N}_to_float{N}: Voronoi feature-point offsets."""
    if len(k) == 1:
        return hash_float(k[0])[..., None]
    if len(k) == 2:
        return hash_to_float2(*k)
    if len(k) == 3:
        return hash_to_float3(*k)
    return hash_to_float4(*k)


def _full(like, value):
    return np.full(np.shape(like), value, np.float32)


# ----------------------------------------------------------------------------
# PCG hashes on signed int32 cells (Cycles >= 4.x Voronoi in 2D-4D)

I32 = np.int32
PCG_MUL, PCG_ADD = I32(1664525), I32(1013904223)
INV_INT_MAX = np.float32(1.0 / 2147483648.0)   # Cycles' 1.0f / (float)0x7FFFFFFFu


def _pcg(v):
    """hash_pcg{2,3,4}d_i on a list of int32 arrays (wrapping, arithmetic shift)."""
    with np.errstate(over="ignore"):
        v = [x.astype(I32) * PCG_MUL + PCG_ADD for x in v]
        for _ in range(2):
            if len(v) == 2:
                v[0] = v[0] + v[1] * PCG_MUL
                v[1] = v[1] + v[0] * PCG_MUL
            elif len(v) == 3:
                v[0] = v[0] + v[1] * v[2]
                v[1] = v[1] + v[2] * v[0]
                v[2] = v[2] + v[0] * v[1]
            else:
                v[0] = v[0] + v[1] * v[3]
                v[1] = v[1] + v[2] * v[0]
                v[2] = v[2] + v[0] * v[1]
                v[3] = v[3] + v[1] * v[2]
            if _ == 0:
                v = [x ^ (x >> I32(16)) for x in v]
    return [x & I32(0x7FFFFFFF) for x in v]


def hash_int_to_floats(*k):
    """hash_int{2,3,4}_to_float{2,3,4}: (N, D) float32 in [0, 1]."""
    return np.stack([h.astype(np.float32) * INV_INT_MAX for h in _pcg(list(k))], axis=-1)


def hash_int_to_float3(*k):
    """hash_int{2,4}_to_float3 and hash_int3_to_float3."""
    if len(k) == 2:
        return hash_int_to_floats(k[0], k[1], np.zeros_like(k[0]))
    return hash_int_to_floats(*k)[..., :3]
