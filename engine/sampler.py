"""Sample values addressed by (seed, pixel, sample index, dimension).

The default pattern is a shuffled, Owen-scrambled 4D Sobol sequence with
padding (Burley 2020, "Practical Hash-based Owen Scrambling"; Cycles'
default pattern since 3.5): every group of up to four dimensions (a
*dimension set*: the pixel filter and lens; at each path vertex the light
choice and point; the lobe choice, direction and roulette) reads a 4D
Sobol point whose index is shuffled per (pixel, set) and whose digits are
Owen-scrambled per (pixel, set, dimension).  Within a set the samples of a
pixel are stratified in all four dimensions; different sets and pixels
are decorrelated by their hashes.

Nothing depends on how samples are batched: any range of sample indices
[a, b) of a pixel is reproducible, and disjoint ranges merge into the
render of their union (farm shards rely on it).

The "random" pattern hashes the same address into independent uniforms
(for tests that need independent samples).

Everything is vectorized over uint32 arrays: the Sobol matrix-vector
product and the bit reversals are 16-bit table lookups (8-bit ones, all
four dimensions together, in the compiled loop).
"""
import numpy as np

from . import kernels

SOBOL = "sobol"
RANDOM = "random"
PATTERNS = (SOBOL, RANDOM)

# Dimension sets.  Camera: filter x, y and lens x, y.  Per path vertex
# (indexed by the wavefront step, so transparent passes get their own):
# LIGHT = selection, three numbers for the point; BSDF = lobe choice,
# direction (2), roulette; KIND = the bounce kind for ray visibility;
# MEDIUM = the colour channel and distance of a free flight in a volume
# (a path scattering in a volume uses its step's LIGHT and BSDF sets).
CAMERA = 0
# Motion blur: the time of a camera sample within the shutter (its first
# dimension), a set of its own so the camera's four stay as they are.
TIME = 0x20000000
LIGHT, BSDF, KIND, MEDIUM = 0, 1, 2, 3
_SETS_PER_STEP = 4


def vertex_set(step, which):
    """Dimension-set id of ``which`` (LIGHT, BSDF, KIND) at wavefront step ``step``."""
    return 1 + step * _SETS_PER_STEP + which


def subsurface_set(step, bounce, which):
    """Dimension-set id of a subsurface random walk's bounce ``bounce`` at
    wavefront step ``step`` (``which`` 0: channel, distance and direction;
    1: spare): disjoint from the vertex, node (bit 29) and all-lights (bit
    30) sets."""
    return 0x10000000 | ((int(step) & 0xFF) << 20) | ((int(bounce) & 0x3FFFF) << 1) | (int(which) & 1)


def emitter_set(step, emitter):
    """Dimension-set id for emitter ``emitter`` in all-lights mode."""
    return 0x40000000 | ((step & 0xff) << 22) | (int(emitter) & 0x3fffff)


def candidate_set(step, k):
    """Dimension-set id of light candidate ``k`` at wavefront step ``step``
    under resampled light selection (bit 31: disjoint from every other
    set); candidate 0 is the step's LIGHT set, the set after the last
    candidate gives the choice among them."""
    if k == 0:
        return vertex_set(step, LIGHT)
    return 0x80000000 | ((step & 0xff) << 22) | (int(k) & 0x3fffff)


# ---------------------------------------------------------------------------
# Tables

def _reverse16():
    r = np.arange(1 << 16, dtype=np.uint32)
    out = np.zeros(1 << 16, np.uint32)
    for b in range(16):
        out |= ((r >> b) & 1) << (15 - b)
    return out


_REV16 = _reverse16()


def reverse_bits(x):
    """Bit reversal of uint32 values."""
    x = np.asarray(x, np.uint32)
    return (_REV16[x & 0xFFFF] << np.uint32(16)) | _REV16[x >> np.uint32(16)]


def _direction_numbers():
    """(4, 32) MSB-aligned direction numbers of the first four Sobol
    dimensions: van der Corput, then the primitive polynomials x + 1,
    x^2 + x + 1 and x^3 + x + 1 with initial numbers (Joe and Kuo)
    1; 1, 3; 1, 3, 1."""
    v = np.zeros((4, 32), np.uint64)
    v[0] = [1 << (31 - k) for k in range(32)]
    for d, (s, a, m) in enumerate([(1, 0, [1]), (2, 1, [1, 3]), (3, 1, [1, 3, 1])], start=1):
        mk = list(m)
        for k in range(s, 32):
            new = mk[k - s] ^ (mk[k - s] << s)
            for j in range(1, s):
                if (a >> (s - 1 - j)) & 1:
                    new ^= mk[k - j] << j
            mk.append(new)
        v[d] = [mk[k] << (31 - k) for k in range(32)]
    return v.astype(np.uint32)


def _half_tables():
    """Tables giving the bit-reversed Sobol value of an index from the two
    16-bit halves of its bit-reversed form: high half = index bits 0..15,
    low half = index bits 16..31."""
    v = _direction_numbers()
    h = np.arange(1 << 16, dtype=np.uint32)
    hi = np.zeros((4, 1 << 16), np.uint32)
    lo = np.zeros((4, 1 << 16), np.uint32)
    for d in range(4):
        rv = reverse_bits(v[d])
        for k in range(16):
            # Bit k of the index is bit 15 - k of the high half.
            hi[d] ^= np.where((h >> (15 - k)) & 1, rv[k], 0).astype(np.uint32)
            lo[d] ^= np.where((h >> (15 - k)) & 1, rv[k + 16], 0).astype(np.uint32)
    return hi, lo


_HI, _LO = _half_tables()


def _byte_tables(hi, lo):
    """The same map byte by byte, (4 bytes, 256, 4 dimensions): the Sobol
    value is linear over XOR, so table(a ^ b) = table(a) ^ table(b).  16 KB
    that stay in the L1 cache, all four dimensions of a byte in one line,
    where the half tables (2 MB) cost a cache miss per lookup."""
    b = np.arange(256)
    parts = (lo[:, b], lo[:, b << 8], hi[:, b], hi[:, b << 8])   # idx bits 0-7, 8-15, 16-23, 24-31
    return np.ascontiguousarray(np.stack([part.T for part in parts]))


_BYTES = _byte_tables(_HI, _LO)


# ---------------------------------------------------------------------------
# Hashes (uint32 arithmetic wraps modulo 2^32)

def hash32(x):
    """A well-mixed 32-bit integer hash (Wellons' lowbias32)."""
    x = np.asarray(x, np.uint32).copy()
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def _hash_scalar(x):
    """``hash32`` of one integer (its low 32 bits) in Python integers: the
    same value without NumPy's per-call cost (it runs once per dimension
    set a batch asks for: every bounce of a subsurface walk)."""
    x = int(x) & 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    x ^= x >> 16
    return x


def owen_reversed(x, seed):
    """Nested uniform (Owen) scramble of bit-reversed values: each bit is
    flipped by a hash of the bits below it (Burley's Laine-Karras variant).
    ``seed`` is a scalar or an array like ``x``."""
    x = x ^ (x * np.uint32(0x3D20ADEA))
    x += seed
    x *= (seed >> np.uint32(16)) | np.uint32(1)
    x ^= x * np.uint32(0x05526C56)
    x ^= x * np.uint32(0x53A22864)
    return x


def pixel_seed(seed, pix):
    """Per-pixel scramble seed (uint32) for a render seed."""
    return hash32(np.asarray(pix, np.uint32) ^ np.uint32(_hash_scalar(seed * 0x9E3779B9 + 0x632BE5AB)))


_SHUFFLE_SALT = 0xC2C1A055
_DIM_SALT = (0x39468210, 0xE9D8A845, 0x5F32B482, 0x1524CC56)
_TO_UNIT = 1.0 / 4294967296.0


def sobol4(pseed, sample, dim_set):
    """(N, 4) float64 values in [0, 1) of dimension set ``dim_set`` for
    paths with pixel seeds ``pseed`` and sample indices ``sample``."""
    pseed = np.ascontiguousarray(pseed, np.uint32)
    sample = np.ascontiguousarray(sample, np.uint32)
    out = np.empty((len(pseed), 4))
    _sobol4_into(pseed, sample, np.uint32(_hash_scalar(dim_set)), out, _HI, _LO, _DIM_SALT64, _BYTES)
    return out


def _sobol4_numpy(pseed, sample, set_hash, out, hi_table, lo_table, salts, byte_table):
    seed = pseed ^ set_hash
    idx = owen_reversed(reverse_bits(sample), seed ^ np.uint32(_SHUFFLE_SALT))
    hi = idx >> np.uint32(16)
    lo = idx & np.uint32(0xFFFF)
    for d in range(4):
        r = hi_table[d][hi] ^ lo_table[d][lo]
        r = owen_reversed(r, seed ^ salts[d].astype(np.uint32))
        out[:, d] = reverse_bits(r) * _TO_UNIT


# The same numbers one path at a time, for numba (engine/kernels.py): uint32
# arithmetic done in uint64 and masked, every constant typed (a plain int
# would turn uint64 maths into float64).  Tables come in as arguments (as
# globals, or as a loop over the index bits, numba's code was 3-10x slower).
_M32 = np.uint64(0xFFFFFFFF)
_1, _2, _4, _8, _16 = (np.uint64(v) for v in (1, 2, 4, 8, 16))
_B1, _B2, _B4, _B8, _B16 = (np.uint64(v) for v in (0x55555555, 0x33333333, 0x0F0F0F0F, 0x00FF00FF, 0xFFFF))
_B8L, _24 = np.uint64(0xFF), np.uint64(24)
_O1, _O2, _O3 = (np.uint64(v) for v in (0x3D20ADEA, 0x05526C56, 0x53A22864))
_SHUFFLE64 = np.uint64(_SHUFFLE_SALT)
_DIM_SALT64 = np.array(_DIM_SALT, np.uint64)


@kernels.helper
def _rev32(x):
    x = ((x >> _1) & _B1) | ((x & _B1) << _1)
    x = ((x >> _2) & _B2) | ((x & _B2) << _2)
    x = ((x >> _4) & _B4) | ((x & _B4) << _4)
    x = ((x >> _8) & _B8) | ((x & _B8) << _8)
    return (((x >> _16) & _B16) | ((x & _B16) << _16)) & _M32


@kernels.helper
def _owen64(x, seed):
    x ^= (x * _O1) & _M32
    x = (x + seed) & _M32
    x = (x * ((seed >> _16) | _1)) & _M32
    x ^= (x * _O2) & _M32
    x ^= (x * _O3) & _M32
    return x


@kernels.helper
def _sobol4_one(ps, smp, set_hash, salts, byte_table, out):
    """The four values of one path's dimension set into ``out`` (the
    compiled loop below, and the subsurface walk's per-step numbers)."""
    seed = np.uint64(ps ^ set_hash)
    idx = _owen64(_rev32(np.uint64(smp)), seed ^ _SHUFFLE64)
    b0 = np.int64(idx & _B8L)
    b1 = np.int64((idx >> _8) & _B8L)
    b2 = np.int64((idx >> _16) & _B8L)
    b3 = np.int64(idx >> _24)
    for d in range(4):
        r = np.uint64(byte_table[0, b0, d] ^ byte_table[1, b1, d] ^ byte_table[2, b2, d] ^ byte_table[3, b3, d])
        # via int64: numba converts uint64 to float64 slowly
        out[d] = np.float64(np.int64(_rev32(_owen64(r, seed ^ salts[d])))) * _TO_UNIT


@kernels.loop_kernel("void(uint32[::1], uint32[::1], uint32, float64[:, ::1], uint32[:, ::1], uint32[:, ::1], "
                     "uint64[::1], uint32[:, :, ::1])", _sobol4_numpy)
def _sobol4_into(pseed, sample, set_hash, out, hi_table, lo_table, salts, byte_table):
    for i in range(len(pseed)):
        _sobol4_one(pseed[i], sample[i], set_hash, salts, byte_table, out[i])


def random4(pseed, sample, dim_set):
    """(N, 4) independent uniforms hashed from the same address."""
    base = hash32(pseed ^ hash32(np.asarray(sample, np.uint32) + np.uint32(_hash_scalar(dim_set))))
    out = np.empty((len(base), 4))
    for d in range(4):
        out[:, d] = hash32(base ^ np.uint32(_DIM_SALT[d])) * _TO_UNIT
    return out


class Sampler:
    """Sample values for paths identified by pixel seed and sample index."""

    def __init__(self, seed=0, pattern=SOBOL):
        if pattern not in PATTERNS:
            raise ValueError(f"unknown sampling pattern {pattern!r}; expected one of {PATTERNS}")
        self.seed = int(seed)
        self.pattern = pattern
        self._get = sobol4 if pattern == SOBOL else random4

    def pixel_seeds(self, pix):
        return pixel_seed(self.seed, pix)

    def get(self, pseed, sample, dim_set):
        """(N, 4) values of one dimension set."""
        return self._get(pseed, sample, dim_set)


def is_class_a(sample):
    """Splits samples into two halves for adaptive sampling's error
    estimate; each half stays well stratified in the 4D Sobol pattern
    (the parity of the odd-position bits, as Cycles classifies them)."""
    s = np.asarray(sample, np.uint32) & np.uint32(0xAAAAAAAA)
    # popcount parity by folding
    s ^= s >> np.uint32(16)
    s ^= s >> np.uint32(8)
    s ^= s >> np.uint32(4)
    s ^= s >> np.uint32(2)
    s ^= s >> np.uint32(1)
    return (s & np.uint32(1)) == 0
