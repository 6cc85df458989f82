"""Named extra passes (AOVs): what each one means, and their per-pixel sums.

A render asks for passes by name (``RenderSettings.passes``); only those are
allocated, so passes cost nothing when off.  The integrator reports events
(``pass_events``); each event adds per-sample values to the named sums of the
batch's ``Tile``; ``Film.merge`` adds the tiles up and ``images`` turns the
sums into (H, W, C) float32 pictures.  Sums are float32 (8K frames: a
3-channel pass is 400 MB in float64, 200 MB in float32).

Names and meanings follow Blender 5.0's Cycles passes (the add-on renames
them for older Blenders).  How each sum becomes a picture:

- MEAN: the sum over the pixel's camera samples / their count (Cycles'
  filtered passes: Normal, Position, light passes' numerators ...).
- FIRST: the value of one ray through the pixel centre (Cycles writes
  Depth, Position, Object and Material Index from its sample 0, at the
  pixel centre: an index must not be averaged).
- RATIO: sum / the sum of a weight channel (a mean over the events that
  happened, e.g. MIS Weight Light over the light samples that hit a light).
- DIVIDE: the mean divided by another pass's mean where that is non-zero,
  else 0 (Cycles' light passes: Diffuse Direct = light / Diffuse Color).
- ONE_MINUS: 1 - mean (Cycles' Mist accumulates (1 - mist) x coverage).
- Cryptomatte: per pixel the coverage of every id met, ranked (``crypto``).
"""
from dataclasses import dataclass, field

import numpy as np

MEAN, FIRST, RATIO, DIVIDE, ONE_MINUS = "mean", "first", "ratio", "divide", "one_minus"

STRATEGY = ("Strategy Light", "Strategy BSDF", "Strategy Light Unweighted", "Strategy BSDF Unweighted")
LIGHT_CLASSES = ("Diffuse", "Glossy", "Transmission")
VOLUME_PASSES = ("Volume Direct", "Volume Indirect")
CRYPTO = ("CryptoObject", "CryptoMaterial", "CryptoAsset")

# name: (channels, kind, divisor or weight channel)
DEFS = {
    "Strategy Light": (3, MEAN, None),
    "Strategy BSDF": (3, MEAN, None),
    "Strategy Light Unweighted": (3, MEAN, None),
    "Strategy BSDF Unweighted": (3, MEAN, None),
    "MIS Weight Light": (1, RATIO, "MIS Weight Light:n"),
    "Mist": (1, ONE_MINUS, None),
    "Position": (3, FIRST, None),
    "Normal": (3, MEAN, None),
    "UV": (3, MEAN, None),
    # Screen-space motion of the first hit (engine/vector_pass.py), averaged
    # over the samples that hit a surface (Cycles' pass_motion_weight: the
    # background does not dilute it); 0 with motion blur on.
    "Vector": (4, RATIO, "Vector:n"),
    "Depth": (1, FIRST, None),
    "Object Index": (1, FIRST, None),
    "Material Index": (1, FIRST, None),
    "Denoising Albedo": (3, MEAN, None),
    "Denoising Normal": (3, MEAN, None),
    "Emission": (3, MEAN, None),
    "Environment": (3, MEAN, None),
    "Ambient Occlusion": (3, MEAN, None),
    # Light of paths whose first scattering vertex is in a volume (Cycles'
    # PATH_RAY_VOLUME_PASS): at that vertex (Direct) and after (Indirect).
    # Not divided: Cycles has no Volume Color.
    "Volume Direct": (3, MEAN, None),
    "Volume Indirect": (3, MEAN, None),
}
for _c in LIGHT_CLASSES:
    DEFS[_c + " Color"] = (3, MEAN, None)
    DEFS[_c + " Direct"] = (3, DIVIDE, _c + " Color")
    DEFS[_c + " Indirect"] = (3, DIVIDE, _c + " Color")
# Passes the film derives from what it keeps anyway (no extra sums).
FILM_PASSES = {"Variance": 3, "Sample Count": 1, "Shadow Catcher": 3}
ALL_PASSES = tuple(DEFS) + tuple(FILM_PASSES) + CRYPTO


@dataclass
class PassConfig:
    """Settings of the passes that need some.  Mist as the world's Mist Pass
    panel (falloff exponent: quadratic 2, linear 1, inverse quadratic 0.5);
    ao_distance as the world's AO distance; strategy_first_vertex: strategy
    passes from the first vertex only (else every vertex's direct light);
    object/material/asset names: per instance, material id and instance,
    for Cryptomatte; pass indices per instance and material."""
    mist_start: float = 5.0
    mist_depth: float = 25.0
    mist_falloff: float = 2.0
    vector: object = None   # engine.vector_pass.VectorMotion when the Vector pass is written
    ao_distance: float = 10.0
    strategy_first_vertex: bool = False
    crypto_levels: int = 6
    object_names: tuple = ()
    material_names: tuple = ()
    asset_names: tuple = ()
    object_pass_index: tuple = ()
    material_pass_index: tuple = ()
    # Light groups (Cycles' Combined_<group>): object or light name -> group,
    # the world's group ("" = none).
    lightgroup_of: dict = field(default_factory=dict)
    world_lightgroup: str = ""
    group_parts: object = None   # filled by pass_events.configure
    aov_tables: object = None    # filled by pass_events.configure


LIGHT_GROUP_PREFIX = "Combined_"


AOV_COLOR, AOV_VALUE = "AOV Color:", "AOV Value:"


def unknown(names):
    return [n for n in names if n not in ALL_PASSES and not is_light_group(n) and not is_aov(n)]


def is_aov(name):
    """Shader AOV passes: 'AOV Color:<name>' (RGBA, A = the share of samples
    whose material wrote it, as Cycles) or 'AOV Value:<name>'."""
    return name.startswith((AOV_COLOR, AOV_VALUE)) and len(name.split(":", 1)[1]) > 0


def is_light_group(name):
    return name.startswith(LIGHT_GROUP_PREFIX) and len(name) > len(LIGHT_GROUP_PREFIX)


def light_groups(names):
    """The light-group names among requested passes, in order."""
    return tuple(n[len(LIGHT_GROUP_PREFIX):] for n in names if is_light_group(n))


def _definition(name):
    if is_light_group(name):
        return (3, MEAN, None)
    if is_aov(name):
        return (4 if name.startswith(AOV_COLOR) else 1, MEAN, None)
    return DEFS[name]


def sums_needed(names):
    """Named sums to allocate for the requested passes (with divisors and
    weight channels), as {name: channels}."""
    need = {}
    for name in names:
        if name in DEFS or is_light_group(name) or is_aov(name):
            channels, kind, other = _definition(name)
            need[name] = channels
            if kind == RATIO:
                need[other] = 1
            elif kind == DIVIDE:
                need[other] = DEFS[other][0]
    return need


class Sums:
    """Per-pixel sums of named passes over the pixel range [lo, hi)."""

    def __init__(self, names, lo, hi, crypto_levels=None):
        """crypto_levels: the film's Cryptomatte slots per pixel (a tile,
        None, keeps its few (pixel, id) pairs compactly instead)."""
        self.lo, self.hi = lo, hi
        self.need = sums_needed(names)
        self.arrays = {name: np.zeros((hi - lo, c), np.float32) for name, c in self.need.items()}
        # FIRST passes: the rank (distance to the pixel centre) of the sample held.
        self.first = {name: np.full(hi - lo, np.inf, np.float32)
                      for name in self.need if name in DEFS and DEFS[name][1] == FIRST}
        self.crypto = {kind: Coverage() if crypto_levels is None else Slots(hi - lo, crypto_levels)
                       for kind in CRYPTO if kind in names}

    def wants(self, name):
        return name in self.arrays

    def add(self, name, pix, values, rank=None):
        """Add per-sample values ((N,) or (N, C)) of pixels ``pix``; FIRST
        passes keep the value of the lowest ``rank`` instead."""
        arr = self.arrays.get(name)
        if arr is None or len(pix) == 0:
            return
        values = np.asarray(values, np.float64).reshape(len(pix), -1)
        values = np.where(np.isfinite(values), values, 0.0)
        if name in self.first:
            self._keep_first(name, pix - self.lo, values, rank)
            return
        n, c = arr.shape
        # One bincount over (pixel, channel) pairs.
        idx = ((pix - self.lo)[:, None] * c + np.arange(c)).ravel()
        arr += np.bincount(idx, weights=values.ravel(), minlength=n * c).reshape(n, c)

    def add_crypto(self, kind, pix, ids, weight):
        cov = self.crypto.get(kind)
        if cov is not None and len(pix):
            cov.add(pix - self.lo, ids, weight)

    def _keep_first(self, name, local, values, rank):
        """Per pixel, the value of the lowest-ranked sample seen so far."""
        order = np.lexsort((rank, local))
        local, values, rank = local[order], values[order], rank[order]
        head = np.ones(len(local), bool)
        head[1:] = local[1:] != local[:-1]
        local, values, rank = local[head], values[head], rank[head]
        better = rank < self.first[name][local]
        self.arrays[name][local[better]] = values[better]
        self.first[name][local[better]] = rank[better]

    def merge(self, other, offset):
        """Add another Sums whose range starts ``offset`` pixels into ours."""
        s = slice(offset, offset + other.hi - other.lo)
        for name, arr in other.arrays.items():
            if name in self.first:
                take = other.first[name] < self.first[name][s]
                self.arrays[name][s][take] = arr[take]
                self.first[name][s][take] = other.first[name][take]
            else:
                self.arrays[name][s] += arr
        for kind, cov in other.crypto.items():
            self.crypto[kind].merge(cov, offset)


class Coverage:
    """A tile's Cryptomatte samples: per (pixel, id) the number of samples
    that saw id first, kept as sorted unique keys pixel * 2^32 + id."""

    def __init__(self):
        self.keys = np.zeros(0, np.int64)
        self.weights = np.zeros(0, np.float32)

    def add(self, pix, ids, weight):
        keys = pix.astype(np.int64) * (1 << 32) + ids.astype(np.int64)
        self._combine(keys, np.asarray(weight, np.float64))

    def merge(self, other, offset):
        self._combine(other.keys + np.int64(offset) * (1 << 32), other.weights)

    def _combine(self, keys, weights):
        keys = np.concatenate([self.keys, keys])
        weights = np.concatenate([self.weights.astype(np.float64), weights])
        self.keys, inverse = np.unique(keys, return_inverse=True)
        self.weights = np.bincount(inverse, weights=weights).astype(np.float32)


class Slots:
    """The film's Cryptomatte accumulator, as Cycles': per pixel ``levels``
    (id, samples) slots, filled in the order ids arrive; an id arriving at
    a pixel whose slots are full is dropped (Cycles does the same)."""

    def __init__(self, npix, levels):
        self.ids = np.full((npix, levels), -1, np.int32)
        self.weights = np.zeros((npix, levels), np.float32)

    def merge(self, cov, offset):
        if len(cov.keys) == 0:
            return
        pix = (cov.keys >> 32) + offset
        ids = (cov.keys & 0xffffffff).astype(np.int32)
        match = self.ids[pix] == ids[:, None]
        known = match.any(axis=1)
        rows = np.nonzero(known)[0]
        self.weights[pix[rows], match[rows].argmax(axis=1)] += cov.weights[rows]
        new = np.nonzero(~known)[0]
        if len(new) == 0:
            return
        p = pix[new]   # sorted by pixel: the keys are
        rank = np.arange(len(p)) - np.searchsorted(p, p, side="left")
        slot = (self.ids[p] >= 0).sum(axis=1) + rank
        fits = slot < self.ids.shape[1]
        self.ids[p[fits], slot[fits]] = ids[new][fits]
        self.weights[p[fits], slot[fits]] = cov.weights[new][fits]


def images(sums, count, width, height, names, film=None, config=None):
    """{name: (H, W, C) float32} for the requested passes."""
    out = {}
    c = np.maximum(count.astype(np.float64), 1.0)[:, None]
    for name in names:
        if name in FILM_PASSES:
            img = _film_pass(name, film, count)
        elif name in CRYPTO:
            img = crypto_image(sums.crypto[name], count, config, name)
        else:
            img = _pass_image(sums, name, c)
        out[name] = img.reshape(height, width, -1).astype(np.float32)
    return out


def _pass_image(sums, name, c):
    arr = sums.arrays[name].astype(np.float64)
    kind, other = _definition(name)[1:]
    if kind == FIRST:
        return arr
    if kind == RATIO:
        n = sums.arrays[other].astype(np.float64)
        return np.where(n > 0, arr / np.where(n > 0, n, 1.0), 0.0)
    mean = arr / c
    if kind == ONE_MINUS:
        return 1.0 - mean
    if kind == DIVIDE:
        col = sums.arrays[other].astype(np.float64) / c
        return np.where(col > 0, mean / np.where(col > 0, col, 1.0), 0.0)
    return mean


def _film_pass(name, film, count):
    if name == "Variance":
        return film.variance().reshape(-1, 3)
    if name == "Sample Count":
        return count.astype(np.float32)
    if name == "Shadow Catcher":
        if film.catcher is None:
            return np.ones((len(count), 3), np.float32)
        return film.shadow_catcher(film.combined_alpha).astype(np.float32)
    raise KeyError(name)


# ----------------------------------------------------------------------------
# Cryptomatte (Friedman & Jones 2015; Cycles' cryptomatte.h, Blender's
# BKE_cryptomatte): ids are MurmurHash3_x86_32 of the name (seed 0), stored as
# the float with those bits, the exponent kept away from 0 and 255.

def murmur3_32(data, seed=0):
    data = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    c1, c2, mask = 0xcc9e2d51, 0x1b873593, 0xffffffff
    h = seed & mask
    n = len(data) // 4 * 4
    for i in range(0, n, 4):
        k = int.from_bytes(data[i:i + 4], "little")
        k = (k * c1) & mask
        k = ((k << 15) | (k >> 17)) & mask
        h ^= (k * c2) & mask
        h = ((h << 13) | (h >> 19)) & mask
        h = (h * 5 + 0xe6546b64) & mask
    tail = data[n:]
    if tail:
        k = int.from_bytes(tail, "little")
        k = (k * c1) & mask
        k = ((k << 15) | (k >> 17)) & mask
        h ^= (k * c2) & mask
    h ^= len(data)
    h ^= h >> 16
    h = (h * 0x85ebca6b) & mask
    h ^= h >> 13
    h = (h * 0xc2b2ae35) & mask
    h ^= h >> 16
    return h


def crypto_hash(name):
    """The uint32 Cryptomatte id of a name (Blender's hash_to_float bits)."""
    h = murmur3_32(name)
    exponent = (h >> 23) & 255
    if exponent == 0 or exponent == 255:
        h ^= 1 << 23
    return h


def crypto_float(name):
    return np.array([crypto_hash(name)], np.uint32).view(np.float32)[0]


def crypto_names(config, kind):
    return {"CryptoObject": config.object_names, "CryptoMaterial": config.material_names,
            "CryptoAsset": config.asset_names}[kind]


def crypto_manifest(config, kind):
    """{name: "hex id"} as the manifest metadata Blender's node reads."""
    return {n: f"{crypto_hash(n):08x}" for n in sorted(set(crypto_names(config, kind)))}


def crypto_image(slots, count, config, kind):
    """(npix, 2 * levels) float32: per pixel the ids it saw, by decreasing
    coverage, as (id, coverage) pairs, two per RGBA layer."""
    levels = slots.ids.shape[1]
    names = crypto_names(config, kind)
    floats = np.array([crypto_hash(n) for n in names] or [0], np.uint32).view(np.float32)
    order = np.argsort(-slots.weights, axis=1, kind="stable")
    ids = np.take_along_axis(slots.ids, order, axis=1)
    cover = np.take_along_axis(slots.weights, order, axis=1) / np.maximum(count, 1.0)[:, None]
    out = np.zeros((len(count), 2 * levels), np.float32)
    used = ids >= 0
    out[:, 0::2] = np.where(used, floats[np.clip(ids, 0, len(floats) - 1)], 0.0)
    out[:, 1::2] = np.where(used, cover, 0.0)
    return out
