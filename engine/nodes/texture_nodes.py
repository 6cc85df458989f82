"""Procedural texture nodes as Cycles' SVM evaluates them (float32)."""
import itertools

import numpy as np

from . import noise
from .hashing import hash_float, hash_int_to_float3, hash_int_to_floats, hash_same_dim, hash_to_float3
from . import voronoi_loop
from .registry import node, one_of, wanted

F = np.float32
DIMS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}
UNIT = {"Fac": (0.0, 1.0), "Color": (0.0, 1.0)}


def f32(a):
    return np.asarray(a, dtype=F)


def _coords(vector, w, dim):
    """(N, dim) float32 coordinates from a vector (N, 3) and W (N,)."""
    if dim == 1:
        return w[:, None]
    if dim == 2:
        return vector[:, :2]
    if dim == 3:
        return vector
    return np.concatenate([vector, w[:, None]], axis=1)


def _grey(f):
    return np.repeat(f[:, None], 3, axis=1)


# ----------------------------------------------------------------------------
# Checker

@node("ShaderNodeTexChecker",
      inputs=(("Vector", "vector"), ("Color1", "color"), ("Color2", "color"), ("Scale", "float")),
      outputs=(("Color", "color"), ("Fac", "float")), coords="generated",
      bounds=lambda p: {"Fac": (0.0, 1.0)},
      cases=[{"Scale": 5.0}])
def checker(ctx, i, p):
    q = f32(i["Vector"]) * f32(i["Scale"])[:, None]
    q = (q + F(1e-6)) * F(0.999999)
    parity = np.abs(np.floor(q).astype(np.int64)) % 2
    f = np.where((parity[:, 0] == parity[:, 1]) == (parity[:, 2] == 1), 1.0, 0.0)
    color = np.where(f[:, None] == 1.0, i["Color1"], i["Color2"])
    return {"Color": color, "Fac": f}


# ----------------------------------------------------------------------------
# Gradient

def _gradient(kind, q):
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    if kind == "LINEAR":
        return x
    if kind == "QUADRATIC":
        r = np.maximum(x, F(0.0))
        return r * r
    if kind == "EASING":
        r = np.clip(x, F(0.0), F(1.0))
        t = r * r
        return F(3.0) * t - F(2.0) * t * r
    if kind == "DIAGONAL":
        return (x + y) * F(0.5)
    if kind == "RADIAL":
        return np.arctan2(y, x) / F(2.0 * np.pi) + F(0.5)
    length = np.sqrt(x * x + y * y + z * z)
    r = np.maximum(F(0.999999) - length, F(0.0))
    if kind == "QUADRATIC_SPHERE":
        return r * r
    return r  # SPHERICAL


@node("ShaderNodeTexGradient", inputs=(("Vector", "vector"),),
      outputs=(("Color", "color"), ("Fac", "float")), props=(("gradient_type", "LINEAR"),),
      coords="generated", bounds=lambda p: UNIT,
      cases=[{"gradient_type": t} for t in ("LINEAR", "QUADRATIC", "EASING", "DIAGONAL", "RADIAL",
                                             "QUADRATIC_SPHERE", "SPHERICAL")])
def gradient(ctx, i, p):
    f = np.clip(_gradient(p["gradient_type"], f32(i["Vector"])), F(0.0), F(1.0))
    return {"Color": _grey(f), "Fac": f}


# ----------------------------------------------------------------------------
# Noise

NOISE_INPUTS = (("Vector", "vector"), ("W", "float"), ("Scale", "float"), ("Detail", "float"),
                ("Roughness", "float"), ("Lacunarity", "float"), ("Offset", "float"), ("Gain", "float"),
                ("Distortion", "float"))


@node("ShaderNodeTexNoise", inputs=NOISE_INPUTS, outputs=(("Fac", "float"), ("Color", "color")),
      props=(("noise_dimensions", "3D"), ("noise_type", "FBM"), ("normalize", True)), coords="generated",
      input_defaults={"Lacunarity": 2.0, "Gain": 1.0},
      accepts=one_of(noise_type=("FBM", "MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HYBRID_MULTIFRACTAL",
                                 "HETERO_TERRAIN"), noise_dimensions=tuple(DIMS)),
      # Octaves reach Scale x Lacunarity^Detail (about 230 in a case): the
      # float32 rounding of P that Cycles starts from shows at that frequency.
      tolerance=5e-5,
      bounds=lambda p: UNIT if p.get("noise_type", "FBM") == "FBM" and p.get("normalize", True) else {},
      cases=[{"Scale": 5.0, "Detail": 2.0}, {"noise_dimensions": "2D", "Scale": 3.0, "Detail": 3.5},
             {"noise_dimensions": "1D", "W": 0.3, "Scale": 4.0},
             {"noise_dimensions": "4D", "W": 1.7, "Scale": 4.0, "Distortion": 0.7},
             {"normalize": False, "Scale": 6.0, "Detail": 4.0, "Roughness": 0.6, "Lacunarity": 2.5},
             {"noise_type": "MULTIFRACTAL", "Scale": 4.0, "Detail": 3.0},
             {"noise_type": "RIDGED_MULTIFRACTAL", "Scale": 4.0, "Detail": 3.0},
             {"noise_type": "HYBRID_MULTIFRACTAL", "Scale": 4.0, "Detail": 3.3},
             {"noise_type": "HETERO_TERRAIN", "Scale": 4.0, "Detail": 2.5}])
def noise_texture(ctx, i, p):
    dim = DIMS[p["noise_dimensions"]]
    scale = f32(i["Scale"])
    q = _coords(f32(i["Vector"]) * scale[:, None], f32(i["W"]) * scale, dim)
    detail = np.clip(f32(i["Detail"]), F(0.0), F(15.0))
    rough = np.maximum(f32(i["Roughness"]), F(0.0))
    lac, offset, gain, dist = (f32(i[k]) for k in ("Lacunarity", "Offset", "Gain", "Distortion"))
    kind, norm = p["noise_type"], bool(p["normalize"])
    if np.any(dist != 0):
        shift = np.stack([noise.snoise(q + noise.random_offset(dim, float(k))) for k in range(dim)], axis=1)
        q = np.where((dist != 0)[:, None], q + shift * dist[:, None], q)
    fac = noise.fractal(kind, q, detail, rough, lac, offset, gain, norm)
    out = {"Fac": fac}
    if "Color" in p.get("_outputs", ("Color",)):
        seeds = (dim, dim + 1)
        g, b = (noise.fractal(kind, q + noise.random_offset(dim, float(s)), detail, rough, lac, offset, gain, norm)
                for s in seeds)
        out["Color"] = np.stack([fac, g, b], axis=1)
    return out


# ----------------------------------------------------------------------------
# White noise

@node("ShaderNodeTexWhiteNoise", inputs=(("Vector", "vector"), ("W", "float")),
      outputs=(("Value", "float"), ("Color", "color")), props=(("noise_dimensions", "3D"),),
      bounds=lambda p: {"Value": (0.0, 1.0), "Color": (0.0, 1.0)},
      # Hashes of float bits: only bit-identical inputs agree, so the cases
      # feed constants (a continuous coordinate differs in its last bits).
      cases=[{"Vector": (0.3, -0.7, 1.1)}, {"noise_dimensions": "1D", "W": 0.25},
             {"noise_dimensions": "2D", "Vector": (2.5, 0.0, 0.0)},
             {"noise_dimensions": "4D", "Vector": (-0.0, 1.5, 3.0), "W": 0.5}])
def white_noise(ctx, i, p):
    dim = DIMS[p["noise_dimensions"]]
    q = _coords(f32(i["Vector"]), f32(i["W"]), dim)
    keys = [q[:, k] for k in range(dim)]
    return {"Value": hash_float(*keys), "Color": hash_to_float3(*keys)}


# ----------------------------------------------------------------------------
# Voronoi

def _distance(d, metric, exponent):
    a = np.abs(d)
    if metric == "EUCLIDEAN":
        return np.sqrt(np.sum(d * d, axis=-1))
    if metric == "MANHATTAN":
        return np.sum(a, axis=-1)
    if metric == "CHEBYCHEV":
        return np.max(a, axis=-1)
    e = exponent[:, None] if a.ndim == 2 else exponent
    return np.power(np.sum(np.power(a, e), axis=-1), F(1.0) / exponent)


def _smoothstep(e0, e1, x):
    t = (x - e0) / (e1 - e0)
    return np.where(x < e0, F(0.0), np.where(x >= e1, F(1.0), (F(3.0) - F(2.0) * t) * (t * t)))


def _cell_hash(key, cell_int, dim, pcg):
    """Feature-point offsets of cells: float bits hashed with lookup3 (1D
    always; 2D-4D up to Blender 4.2), or the integer cell with PCG (5.0)."""
    if dim == 1 or not pcg:
        return hash_same_dim(*(key[:, k] for k in range(dim)))
    return hash_int_to_floats(*(cell_int[:, k] for k in range(dim)))


def _cell_color(key, cell_int, dim, pcg):
    if dim == 1 or not pcg:
        return hash_to_float3(*(key[:, k] for k in range(dim)))
    return hash_int_to_float3(*(cell_int[:, k] for k in range(dim)))


def _pcg_cells(props):
    """Whether the exporting Blender hashes Voronoi cells as integers
    (measured: 3.4 and 4.2 hash float bits, 5.0 integer cells)."""
    return tuple(props.get("_blender_version", (5, 0, 0))) >= (5, 0, 0)


def _octave(q, feature, metric, exponent, randomness, smoothness, pcg, colour):
    """One octave by the compiled loop where it covers the case, else by
    the NumPy form (colour skipped when nobody reads it)."""
    n, dim = q.shape
    if not voronoi_loop.supported(dim, feature, metric, pcg):
        return _voronoi_octave(q, feature, metric, exponent, randomness, smoothness, pcg, colour)
    dist, color, pos = np.empty(n, F), np.empty((n, 3), F), np.empty((n, dim), F)
    if n:
        voronoi_loop.voronoi_octave_loop(
            np.ascontiguousarray(q, F), *(np.array(np.broadcast_to(a, (n,)), F)
                                          for a in (randomness, exponent, smoothness)),
            voronoi_loop.FEATURES[feature], voronoi_loop.METRICS[metric], dist, color, pos)
    return dist, color, pos


def _voronoi_octave(q, feature, metric, exponent, randomness, smoothness, pcg=True, colour=True):
    """F1, F2 or smooth F1 of one octave: distance (N,), colour (N, 3),
    position (N, dim).  F1 compares squared Euclidean distances (Cycles'
    voronoi_distance_bound) and measures the winner after."""
    n, dim = q.shape
    cell = np.floor(q)
    local = q - cell
    cell_int = cell.astype(np.int64).astype(np.int32)
    smooth = feature == "SMOOTH_F1"
    reach = 2 if smooth else 1
    offsets = [np.array(o[::-1], F) for o in itertools.product(range(-reach, reach + 1), repeat=dim)]
    big = F(np.finfo(np.float32).max)
    d1 = np.full(n, big, F)
    d2 = np.full(n, big, F)
    o1 = np.zeros((n, dim), F)
    o2 = np.zeros((n, dim), F)
    p1 = np.zeros((n, dim), F)
    p2 = np.zeros((n, dim), F)
    sd = np.zeros(n, F)
    sc = np.zeros((n, 3), F)
    sp = np.zeros((n, dim), F)
    first = True
    for off in offsets:
        key = cell + off
        key_int = cell_int + off.astype(np.int32)
        point = off + _cell_hash(key, key_int, dim, pcg) * randomness[:, None]
        if feature == "F1" and metric == "EUCLIDEAN" and dim > 1 and pcg:
            d = point - local
            dist = np.sum(d * d, axis=-1).astype(F)
        else:
            dist = _distance(point - local, metric, exponent).astype(F)
        if smooth:
            if first:
                h = np.ones(n, F)
                first = False
            else:
                h = _smoothstep(F(0.0), F(1.0), F(0.5) + F(0.5) * (sd - dist) / smoothness)
            corr = smoothness * h * (F(1.0) - h)
            sd = (F(1.0) - h) * sd + h * dist - corr
            corr = corr / (F(1.0) + F(3.0) * smoothness)
            color = _cell_color(key, key_int, dim, pcg)
            sc = (F(1.0) - h)[:, None] * sc + h[:, None] * color - corr[:, None]
            sp = (F(1.0) - h)[:, None] * sp + h[:, None] * point - corr[:, None]
            continue
        closer = dist < d1
        second = ~closer & (dist < d2)
        d2 = np.where(closer, d1, np.where(second, dist, d2))
        o2 = np.where(closer[:, None], o1, np.where(second[:, None], off, o2))
        p2 = np.where(closer[:, None], p1, np.where(second[:, None], point, p2))
        d1 = np.where(closer, dist, d1)
        o1 = np.where(closer[:, None], off, o1)
        p1 = np.where(closer[:, None], point, p1)
    if smooth:
        return sd, sc, cell + sp
    d, o, pos = (d2, o2, p2) if feature == "F2" else (d1, o1, p1)
    if feature == "F1" and dim > 1 and pcg:
        d = _distance(pos - local, metric, exponent).astype(F)
    c = _cell_color(cell + o, cell_int + o.astype(np.int32), dim, pcg) if colour else np.zeros((n, 3), F)
    return d, c, pos + cell


voronoi_loop.set_reference(_voronoi_octave)


def _offsets(dim, reach=1):
    return [np.array(o[::-1], F) for o in itertools.product(range(-reach, reach + 1), repeat=dim)]


def _points(q, randomness, pcg):
    """cell, local coordinates and a function giving the feature point of
    the cell at an offset (N, dim), relative to the cell."""
    cell = np.floor(q)
    local = q - cell
    cell_int = cell.astype(np.int64).astype(np.int32)
    dim = q.shape[1]

    def point(off):
        off = np.broadcast_to(off, q.shape).astype(F)
        return off + _cell_hash(cell + off, cell_int + off.astype(np.int32), dim, pcg) * randomness[:, None]
    return local, point


def _distance_to_edge(q, randomness, pcg):
    """Cycles' voronoi_distance_to_edge (1D: the two midpoints)."""
    n, dim = q.shape
    local, point = _points(q, randomness, pcg)
    if dim == 1:
        mid, left, right = point(F(0.0)), point(F(-1.0)), point(F(1.0))
        return np.minimum(np.abs((mid + left) / F(2.0) - local), np.abs((mid + right) / F(2.0) - local))[:, 0]
    big = F(np.finfo(np.float32).max)
    best = np.full(n, big, F)
    closest = np.zeros((n, dim), F)
    vectors = [point(off) - local for off in _offsets(dim)]
    for v in vectors:
        d = np.sum(v * v, axis=1)
        closer = d < best
        best = np.where(closer, d, best)
        closest = np.where(closer[:, None], v, closest)
    edge = np.full(n, big, F)
    for v in vectors:
        perp = v - closest
        length2 = np.sum(perp * perp, axis=1)
        ok = length2 > F(0.0001)
        unit = perp / np.sqrt(np.where(ok, length2, F(1.0)))[:, None]
        dist = np.sum((closest + v) / F(2.0) * unit, axis=1)
        edge = np.where(ok, np.minimum(edge, dist), edge)
    return edge


def _n_sphere_radius(q, randomness, pcg):
    """Cycles' voronoi_n_sphere_radius: half the distance from the closest
    feature point to its own nearest neighbour."""
    n, dim = q.shape
    local, point = _points(q, randomness, pcg)
    big = F(np.finfo(np.float32).max)
    best = np.full(n, big, F)
    closest = np.zeros((n, dim), F)
    closest_off = np.zeros((n, dim), F)
    for off in _offsets(dim):
        pt = point(off)
        d = np.sum((pt - local) ** 2, axis=1)
        closer = d < best
        best, closest = np.where(closer, d, best), np.where(closer[:, None], pt, closest)
        closest_off = np.where(closer[:, None], off, closest_off)
    best = np.full(n, big, F)
    other = np.zeros((n, dim), F)
    for off in _offsets(dim):
        if not off.any():
            continue
        pt = point(off + closest_off)
        d = np.sum((closest - pt) ** 2, axis=1)
        closer = d < best
        best, other = np.where(closer, d, best), np.where(closer[:, None], pt, other)
    return np.sqrt(np.sum((other - closest) ** 2, axis=1)) / F(2.0)


def _fractal_edge(q, detail, rough, lac, rand, normalize, pcg):
    """fractal_voronoi_distance_to_edge."""
    n = len(q)
    max_dist = F(0.5) + F(0.5) * rand
    amp = np.ones(n, F)
    max_amp = max_dist.copy()
    fscale = np.ones(n, F)
    dist = np.full(n, F(8.0))
    zero = (detail == 0) | (rough == 0)
    rmd = detail - np.floor(detail)
    for k in range(int(np.ceil(detail.max(initial=0.0))) + 1):
        octave = _distance_to_edge(q * fscale[:, None], rand, pcg)
        first_only = zero & (k == 0)
        full = ~zero & (k <= detail)
        part = ~zero & (k > detail) & (k <= np.ceil(detail)) & (rmd != 0)
        lerp_amp = (F(1.0) - amp) * max_amp + amp * (max_dist / fscale)
        lerp_dist = (F(1.0) - amp) * dist + amp * np.minimum(dist, octave / fscale)
        max_amp = np.where(full, lerp_amp, np.where(part, (F(1.0) - rmd) * max_amp + rmd * lerp_amp, max_amp))
        dist = np.where(first_only, octave, np.where(full, lerp_dist, np.where(
            part, (F(1.0) - rmd) * dist + rmd * np.minimum(dist, lerp_dist), dist)))
        fscale = np.where(full, fscale * lac, fscale)
        amp = np.where(full, amp * rough, amp)
    return dist / max_amp if normalize else dist


def _position_out(pos, dim):
    n = len(pos)
    vec = np.zeros((n, 3), F)
    w = np.zeros(n, F)
    if dim == 1:
        w = pos[:, 0]
    elif dim == 2:
        vec[:, :2] = pos
    else:
        vec[:] = pos[:, :3]
        if dim == 4:
            w = pos[:, 3]
    return vec, w


@node("ShaderNodeTexVoronoi",
      inputs=(("Vector", "vector"), ("W", "float"), ("Scale", "float"), ("Detail", "float"),
              ("Roughness", "float"), ("Lacunarity", "float"), ("Smoothness", "float"),
              ("Exponent", "float"), ("Randomness", "float")),
      outputs=(("Distance", "float"), ("Color", "color"), ("Position", "vector"), ("W", "float"),
               ("Radius", "float")),
      props=(("voronoi_dimensions", "3D"), ("feature", "F1"), ("distance", "EUCLIDEAN"), ("normalize", False)),
      coords="generated",
      input_defaults={"Roughness": 0.5, "Lacunarity": 2.0, "Smoothness": 1.0, "Exponent": 0.5,
                      "Randomness": 1.0},
      accepts=one_of(feature=("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS"),
                     voronoi_dimensions=tuple(DIMS),
                     distance=("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")),
      cases=[{"Scale": 5.0}, {"feature": "F2", "Scale": 4.0}, {"feature": "SMOOTH_F1", "Scale": 4.0},
             {"voronoi_dimensions": "2D", "distance": "MANHATTAN", "Scale": 6.0},
             {"voronoi_dimensions": "2D", "distance": "CHEBYCHEV", "Scale": 6.0, "Randomness": 0.6},
             {"distance": "MINKOWSKI", "Exponent": 1.5, "Scale": 4.0},
             {"voronoi_dimensions": "1D", "W": 0.4, "Scale": 3.0},
             {"voronoi_dimensions": "4D", "W": 0.4, "Scale": 3.0},
             {"Scale": 3.0, "Detail": 2.5, "Roughness": 0.6, "normalize": True},
             {"feature": "DISTANCE_TO_EDGE", "Scale": 4.0}, {"feature": "N_SPHERE_RADIUS", "Scale": 4.0},
             {"feature": "DISTANCE_TO_EDGE", "voronoi_dimensions": "2D", "Scale": 3.0, "Detail": 1.5,
              "normalize": True},
             {"feature": "DISTANCE_TO_EDGE", "voronoi_dimensions": "1D", "W": 0.3, "Scale": 3.0},
             {"feature": "N_SPHERE_RADIUS", "voronoi_dimensions": "2D", "Scale": 5.0}])
def voronoi(ctx, i, p):
    dim = DIMS[p["voronoi_dimensions"]]
    feature, metric = p["feature"], p["distance"]
    scale = f32(i["Scale"])
    q = _coords(f32(i["Vector"]) * scale[:, None], f32(i["W"]) * scale, dim)
    detail = np.clip(f32(i["Detail"]), F(0.0), F(15.0))
    rough = np.clip(f32(i["Roughness"]), F(0.0), F(1.0))
    lac = f32(i["Lacunarity"])
    rand = np.clip(f32(i["Randomness"]), F(0.0), F(1.0))
    if feature in ("DISTANCE_TO_EDGE", "N_SPHERE_RADIUS"):
        n = len(q)
        zeros = {"Distance": np.zeros(n, F), "Color": np.zeros((n, 3), F), "Position": np.zeros((n, 3), F),
                 "W": np.zeros(n, F), "Radius": np.zeros(n, F)}
        if feature == "N_SPHERE_RADIUS":
            zeros["Radius"] = _n_sphere_radius(q, rand, _pcg_cells(p))
        else:
            zeros["Distance"] = _fractal_edge(q, detail, rough, lac, rand, bool(p["normalize"]), _pcg_cells(p))
        return zeros
    smooth = np.clip(f32(i["Smoothness"]) / F(2.0), F(0.0), F(0.5))
    expo = f32(i["Exponent"])
    half = F(0.5) + F(0.5) * rand
    if dim == 1:
        max_dist = half
    else:
        max_dist = _distance(np.repeat(half[:, None], dim, axis=1), metric, expo).astype(F)
    if feature == "F2":
        max_dist = max_dist * F(2.0)
    if feature == "SMOOTH_F1" and np.all(smooth == 0):
        feature = "F1"
    n = len(q)
    zero = (detail == 0) | (rough == 0)
    amp = np.ones(n, F)
    max_amp = np.zeros(n, F)
    fscale = np.ones(n, F)
    dist = np.zeros(n, F)
    color = np.zeros((n, 3), F)
    pos = np.zeros((n, dim), F)
    top = int(np.ceil(detail.max(initial=0.0)))
    for k in range(top + 1):
        d, c, ps = _octave(q * fscale[:, None], feature, metric, expo, rand, smooth,
                           _pcg_cells(p), wanted(p, "Color"))
        ps = ps / fscale[:, None]
        first_only = zero & (k == 0)
        full = ~zero & (k <= detail)
        rmd = detail - np.floor(detail)
        part = ~zero & (k > detail) & (k <= np.ceil(detail)) & (rmd != 0)
        max_amp = np.where(first_only, F(1.0), np.where(full, max_amp + amp,
                           np.where(part, (F(1.0) - rmd) * max_amp + rmd * (max_amp + amp), max_amp)))
        dist = np.where(first_only, d, np.where(full, dist + d * amp,
                        np.where(part, dist + rmd * d * amp, dist)))
        color = np.where(first_only[:, None], c, np.where(full[:, None], color + c * amp[:, None],
                         np.where(part[:, None], color + (rmd * amp)[:, None] * c, color)))
        mixed = (F(1.0) - amp)[:, None] * pos + amp[:, None] * ps
        pos = np.where(first_only[:, None], ps, np.where(full[:, None], mixed,
                       np.where(part[:, None], (F(1.0) - rmd)[:, None] * pos + rmd[:, None] * mixed, pos)))
        fscale = np.where(full, fscale * lac, fscale)
        amp = np.where(full, amp * rough, amp)
    if p["normalize"]:
        dist = dist / (max_amp * max_dist)
        color = color / max_amp[:, None]
    pos = np.where(scale[:, None] != 0, pos / np.where(scale != 0, scale, F(1.0))[:, None], F(0.0))
    vec, w = _position_out(pos, dim)
    return {"Distance": dist, "Color": color, "Position": vec, "W": w, "Radius": np.zeros(n, F)}


# ----------------------------------------------------------------------------
# Wave

@node("ShaderNodeTexWave",
      inputs=(("Vector", "vector"), ("Scale", "float"), ("Distortion", "float"), ("Detail", "float"),
              ("Detail Scale", "float"), ("Detail Roughness", "float"), ("Phase Offset", "float")),
      outputs=(("Color", "color"), ("Fac", "float")),
      props=(("wave_type", "BANDS"), ("bands_direction", "X"), ("rings_direction", "X"),
             ("wave_profile", "SIN")),
      coords="generated", bounds=lambda p: UNIT,
      # Bands and rings run at Scale x 20 per unit: float32 rounding of P shows.
      tolerance=5e-5,
      cases=[{"Scale": 2.0}, {"wave_type": "RINGS", "rings_direction": "SPHERICAL", "wave_profile": "SAW"},
             {"bands_direction": "DIAGONAL", "wave_profile": "TRI", "Distortion": 3.0, "Detail": 2.0},
             {"wave_type": "RINGS", "rings_direction": "Z", "Phase Offset": 1.0}])
def wave(ctx, i, p):
    q = f32(i["Vector"]) * f32(i["Scale"])[:, None]
    q = (q + F(1e-6)) * F(0.999999)
    if p["wave_type"] == "BANDS":
        axis = p["bands_direction"]
        n = (q[:, 0] + q[:, 1] + q[:, 2]) * F(10.0) if axis == "DIAGONAL" else q[:, "XYZ".index(axis)] * F(20.0)
    else:
        keep = {"X": (0, 1, 1), "Y": (1, 0, 1), "Z": (1, 1, 0), "SPHERICAL": (1, 1, 1)}[p["rings_direction"]]
        rp = q * np.array(keep, F)
        n = np.sqrt(np.sum(rp * rp, axis=1)) * F(20.0)
    n = n + f32(i["Phase Offset"])
    dist = f32(i["Distortion"])
    if np.any(dist != 0):
        fbm = noise.fbm(q * f32(i["Detail Scale"])[:, None], np.clip(f32(i["Detail"]), F(0), F(15)),
                        f32(i["Detail Roughness"]), np.full(len(q), F(2.0)), True)
        n = np.where(dist != 0, n + dist * (fbm * F(2.0) - F(1.0)), n)
    profile = p["wave_profile"]
    if profile == "SIN":
        f = F(0.5) + F(0.5) * np.sin(n - F(np.pi / 2))
    elif profile == "SAW":
        n = n / F(2 * np.pi)
        f = n - np.floor(n)
    else:
        n = n / F(2 * np.pi)
        f = np.abs(n - np.floor(n + F(0.5))) * F(2.0)
    return {"Color": _grey(f), "Fac": f}


# ----------------------------------------------------------------------------
# Magic

@node("ShaderNodeTexMagic", inputs=(("Vector", "vector"), ("Scale", "float"), ("Distortion", "float")),
      outputs=(("Color", "color"), ("Fac", "float")), props=(("turbulence_depth", 2),), coords="generated",
      tolerance=2e-4,
      cases=[{}, {"turbulence_depth": 5, "Distortion": 2.0, "Scale": 3.0}, {"turbulence_depth": 0}])
def magic(ctx, i, p):
    q = np.fmod(f32(i["Vector"]), F(2 * np.pi))
    s = f32(i["Scale"]) * F(5.0)
    d = f32(i["Distortion"])
    px, py, pz = q[:, 0], q[:, 1], q[:, 2]
    x = np.sin((px + py + pz) * s)
    y = np.cos((-px + py - pz) * s)
    z = -np.cos((-px - py + pz) * s)
    depth = int(p["turbulence_depth"])
    if depth > 0:
        x, y, z = x * d, y * d, z * d
        y = -np.cos(x - y + z) * d
        steps = [("x", lambda x, y, z: np.cos(x - y - z)), ("z", lambda x, y, z: np.sin(-x - y - z)),
                 ("x", lambda x, y, z: -np.cos(-x + y - z)), ("y", lambda x, y, z: -np.sin(-x + y + z)),
                 ("y", lambda x, y, z: -np.cos(-x + y + z)), ("x", lambda x, y, z: np.cos(x + y + z)),
                 ("z", lambda x, y, z: np.sin(x + y - z)), ("x", lambda x, y, z: -np.cos(-x - y + z)),
                 ("y", lambda x, y, z: -np.sin(x - y + z))]
        for target, fn in steps[:max(depth - 1, 0)]:
            value = fn(x, y, z) * d
            if target == "x":
                x = value
            elif target == "y":
                y = value
            else:
                z = value
    scale2 = np.where(d != 0, d * F(2.0), F(1.0))
    color = np.stack([F(0.5) - x / scale2, F(0.5) - y / scale2, F(0.5) - z / scale2], axis=1)
    return {"Color": color, "Fac": color.mean(axis=1, dtype=F)}


# ----------------------------------------------------------------------------
# Brick

def _brick_noise(n):
    n = n.astype(np.int64).astype(np.uint32)
    with np.errstate(over="ignore"):
        n = (n + np.uint32(1013)) & np.uint32(0x7FFFFFFF)
        n = (n >> np.uint32(13)) ^ n
        nn = (n * (n * n * np.uint32(60493) + np.uint32(19990303)) + np.uint32(1376312589)) & np.uint32(0x7FFFFFFF)
    return F(0.5) * (nn.astype(F) / F(1073741824.0))


@node("ShaderNodeTexBrick",
      inputs=(("Vector", "vector"), ("Color1", "color"), ("Color2", "color"), ("Mortar", "color"),
              ("Scale", "float"), ("Mortar Size", "float"), ("Mortar Smooth", "float"), ("Bias", "float"),
              ("Brick Width", "float"), ("Row Height", "float")),
      outputs=(("Color", "color"), ("Fac", "float")),
      props=(("offset", 0.5), ("offset_frequency", 2), ("squash", 1.0), ("squash_frequency", 2)),
      coords="generated", bounds=lambda p: {"Fac": (0.0, 1.0)},
      cases=[{}, {"Mortar Smooth": 0.3, "Bias": 0.2, "offset": 0.3, "squash": 0.7, "Scale": 3.0}])
def brick(ctx, i, p):
    q = f32(i["Vector"]) * f32(i["Scale"])[:, None]
    mortar_size, mortar_smooth, bias = f32(i["Mortar Size"]), f32(i["Mortar Smooth"]), f32(i["Bias"])
    width, height = f32(i["Brick Width"]), f32(i["Row Height"])
    off_freq, sq_freq = int(p["offset_frequency"]), int(p["squash_frequency"])
    row = np.floor(q[:, 1] / height).astype(np.int64)
    offset = np.zeros(len(q), F)
    if off_freq and sq_freq:
        width = np.where(np.fmod(row, sq_freq) != 0, width, width * F(p["squash"]))
        offset = np.where(np.fmod(row, off_freq) != 0, F(0.0), width * F(p["offset"]))
    bricknum = np.floor((q[:, 0] + offset) / width).astype(np.int64)
    x = (q[:, 0] + offset) - width * bricknum.astype(F)
    y = q[:, 1] - height * row.astype(F)
    key = ((row << 16) + (bricknum & 0xFFFF)) & 0xFFFFFFFF
    tint = np.clip(_brick_noise(key) + bias, F(0.0), F(1.0))
    min_dist = np.minimum(np.minimum(x, y), np.minimum(width - x, height - y))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.clip((F(1.0) - min_dist / mortar_size) / mortar_smooth, F(0.0), F(1.0))
        smooth = F(3.0) * t * t - F(2.0) * t * t * t
    mortar = np.where(min_dist >= mortar_size, F(0.0), np.where(mortar_smooth == 0, F(1.0), smooth))
    c1 = np.where((mortar != 1.0)[:, None], (F(1.0) - tint)[:, None] * i["Color1"] + tint[:, None] * i["Color2"],
                  i["Color1"])
    color = c1 * (F(1.0) - mortar)[:, None] + i["Mortar"] * mortar[:, None]
    return {"Color": color, "Fac": mortar}
