"""Gabor Texture (Blender 4.3+), as Cycles' kernel/svm/gabor.h: sparse
Gabor convolution with 8 impulses per cell over the 3x3 (2D) or 3x3x3 (3D)
cell neighbourhood, Hann-windowed Gaussian kernels in the complex phasor
form, Bernoulli weights; Value, Phase and Intensity from the summed phasor.
float32 throughout, in Cycles' order of operations."""
import numpy as np

from .hashing import hash_float, hash_to_float3
from .registry import node

F = np.float32
PI = F(np.pi)
IMPULSES = 8


def _kernel(d2, angle):
    """windowed Gaussian envelope * (cos, sin) of angle."""
    window = F(0.5) + F(0.5) * np.cos(PI * d2)
    envelope = np.exp(-PI * d2) * window
    return envelope * np.cos(angle), envelope * np.sin(angle)


def _noise_2d(q, frequency, isotropy, base):
    cell = np.floor(q)
    local = q - cell
    re = np.zeros(len(q), F)
    im = np.zeros(len(q), F)
    for j in (-1, 0, 1):
        for i in (-1, 0, 1):
            c = cell + np.array([i, j], F)
            pos = local - np.array([i, j], F)
            for k in range(IMPULSES):
                s0, s1, s2 = F(k * 3), F(k * 3 + 1), F(k * 3 + 2)
                full = lambda v: np.full(len(q), v, F)
                random_orientation = (hash_float(c[:, 0], c[:, 1], full(s0)) - F(0.5)) * PI
                orientation = base + random_orientation * isotropy
                # hash_float3_to_float2: the key, then the key rotated (z, x, y).
                centre = np.stack([hash_float(c[:, 0], c[:, 1], full(s1)),
                                   hash_float(full(s1), c[:, 0], c[:, 1])], axis=1)
                p = pos - centre
                d2 = p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1]
                inside = d2 < F(1.0)
                weight = np.where(hash_float(c[:, 0], c[:, 1], full(s2)) < F(0.5), F(-1.0), F(1.0))
                fx = frequency * np.cos(orientation)
                fy = frequency * np.sin(orientation)
                angle = F(2.0) * PI * (p[:, 0] * fx + p[:, 1] * fy)
                kr, ki = _kernel(d2, angle)
                re = re + np.where(inside, weight * kr, F(0))
                im = im + np.where(inside, weight * ki, F(0))
    return re, im


def _orientation_3d(base, isotropy, seed):
    """compute_3d_orientation: the base direction turned by random
    spherical angles scaled by the isotropy."""
    if np.all(isotropy == 0):
        return np.broadcast_to(base, (len(seed[0]), 3))
    inclination = np.arccos(base[..., 2])
    xy = np.sqrt(base[..., 0] * base[..., 0] + base[..., 1] * base[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        azimuth = np.where(base[..., 1] < 0, F(-1.0), F(1.0)) * np.arccos(base[..., 0] / xy)
    angles = hash_to_float3(*seed)[:, :2] * PI
    inclination = inclination + angles[:, 0] * isotropy
    azimuth = azimuth + angles[:, 1] * isotropy
    out = np.stack([np.sin(inclination) * np.cos(azimuth), np.sin(inclination) * np.sin(azimuth),
                    np.cos(inclination)], axis=1)
    return np.where((isotropy == 0)[:, None], base, out)


def _noise_3d(q, frequency, isotropy, base):
    cell = np.floor(q)
    local = q - cell
    n = len(q)
    re = np.zeros(n, F)
    im = np.zeros(n, F)
    full = lambda v: np.full(n, v, F)
    for kk in (-1, 0, 1):
        for j in (-1, 0, 1):
            for i in (-1, 0, 1):
                off = np.array([i, j, kk], F)
                c = cell + off
                pos = local - off
                for k in range(IMPULSES):
                    keys = (c[:, 0], c[:, 1], c[:, 2])
                    orientation = _orientation_3d(base, isotropy, keys + (full(F(k * 3)),))
                    centre = hash_to_float3(*keys, full(F(k * 3 + 1)))
                    p = pos - centre
                    d2 = (p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1]) + p[:, 2] * p[:, 2]
                    inside = d2 < F(1.0)
                    weight = np.where(hash_float(*keys, full(F(k * 3 + 2))) < F(0.5), F(-1.0), F(1.0))
                    fv = frequency[:, None] * orientation
                    angle = F(2.0) * PI * ((p[:, 0] * fv[:, 0] + p[:, 1] * fv[:, 1]) + p[:, 2] * fv[:, 2])
                    kr, ki = _kernel(d2, angle)
                    re = re + np.where(inside, weight * kr, F(0))
                    im = im + np.where(inside, weight * ki, F(0))
    return re, im


@node("ShaderNodeTexGabor",
      inputs=(("Vector", "vector"), ("Scale", "float"), ("Frequency", "float"), ("Anisotropy", "float"),
              ("Orientation 2D", "float"), ("Orientation 3D", "vector")),
      outputs=(("Value", "float"), ("Phase", "float"), ("Intensity", "float")),
      props=(("gabor_type", "2D"),), coords="generated",
      bounds=lambda p: {"Phase": (0.0, 1.0)},
      cases=[{"Scale": 5.0, "Frequency": 2.0, "Anisotropy": 0.3, "Orientation 2D": 0.6},
             {"gabor_type": "3D", "Scale": 4.0, "Frequency": 1.5, "Anisotropy": 0.6,
              "Orientation 3D": (0.3, 1.2, 0.5)},
             {"gabor_type": "3D", "Scale": 3.0, "Frequency": 3.0, "Anisotropy": 1.0,
              "Orientation 3D": (1.0, 0.0, 0.2)}])
def gabor(ctx, i, p):
    n = len(ctx)
    vector = np.asarray(i["Vector"], F).reshape(n, 3)
    scale = np.broadcast_to(np.asarray(i["Scale"], F), (n,))
    q = vector * scale[:, None]
    isotropy = F(1.0) - np.clip(np.broadcast_to(np.asarray(i["Anisotropy"], F), (n,)), F(0), F(1))
    frequency = np.maximum(F(0.001), np.broadcast_to(np.asarray(i["Frequency"], F), (n,)))
    if p.get("gabor_type", "2D") == "3D":
        o = np.asarray(i["Orientation 3D"], F).reshape(n, 3)
        length = np.sqrt((o[:, 0] * o[:, 0] + o[:, 1] * o[:, 1]) + o[:, 2] * o[:, 2])
        o = o / length[:, None]
        re, im = _noise_3d(q, frequency, isotropy, o)
        sd = np.sqrt(F(IMPULSES) * F(0.5) * (F(1.0) / (F(4.0) * F(np.sqrt(2.0)))))
    else:
        base = np.broadcast_to(np.asarray(i["Orientation 2D"], F), (n,))
        re, im = _noise_2d(q[:, :2], frequency, isotropy, base)
        sd = np.sqrt(F(IMPULSES) * F(0.5) * F(0.25))
    norm = F(6.0) * sd
    return {"Value": (im / norm) * F(0.5) + F(0.5),
            "Phase": (np.arctan2(im, re) + PI) / (F(2.0) * PI),
            "Intensity": np.sqrt(re * re + im * im) / norm}
