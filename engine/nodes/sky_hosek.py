"""The Sky Texture's 'HOSEK_WILKIE' model as Cycles evaluates it.

Hosek and Wilkie, "An Analytic Model for Full Spectral Sky-Dome Radiance"
(SIGGRAPH 2012), CIE XYZ version.  Per channel, nine parameters A..I and a
radiance scale, each a quintic Bezier over the solar elevation's cube root,
interpolated linearly in turbidity (1..10) and ground albedo (0..1) between
the published fits (engine/data/hosek_xyz.npz, engine/data/build_hosek.py).
Per direction (theta from the zenith, gamma from the sun):

    F = (1 + A exp(B / (cos theta + 0.01)))
        (C + D exp(E gamma) + F cos^2 gamma + G chi(H, gamma) + I sqrt(cos theta)),
    chi = (1 + cos^2 gamma) / (1 + H^2 - 2 H cos gamma)^1.5,

(the fits store the parameters in the order A..G, I, H), theta clamped just
above the horizon (below it the horizon's values are
repeated, with gamma of the true direction).  X, Y, Z = F x radiance, to
linear Rec.709 clamped at zero, times 2 pi / 683 (Cycles' strength).  No sun
disc.  As Cycles: the host precompute (scene/shader_nodes.cpp,
sky_texture_precompute_hosek; intern/sky's ArHosekSkyModel_Cook*) in double
from float32 inputs, cast to float32; the kernel (svm/sky.h) in float32.

Out-of-range inputs follow Cycles' arithmetic where it is defined: the sun
direction is normalized (Blender's sync does), a zero or NaN one puts the sun
at the zenith (Cycles' clamp of a NaN angle gives 0) and makes every gamma pi
(its safe_acosf of NaN); turbidity clamps to 1..10 (Cycles clamps to 0..10 and reads before its
table below 1; Blender's property stops at 1).  The registry entry (sky.py)
refuses a NaN turbidity and an albedo outside Blender's 0..1 (NaN included),
where Cycles' sky is undefined or extrapolated to nonsense.
"""
import os
from functools import lru_cache

import numpy as np

F = np.float32
HALF_PI = F(np.pi / 2)
STRENGTH = F(2.0 * np.pi) / F(683.0)     # Cycles: M_2PI_F / 683
TABLES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "hosek_xyz.npz")


@lru_cache(maxsize=1)
def tables():
    """(sky (3, 2, 10, 6, 9), radiance (3, 2, 10, 6)) float64."""
    with np.load(TABLES) as data:
        return data["sky"], data["radiance"]


def _max(a, b):
    """Cycles' max: (a > b) ? a : b (a NaN a gives b)."""
    return np.where(a > b, a, b)


def _min(a, b):
    return np.where(a < b, a, b)


def _clamp(a, lo, hi):
    return _min(_max(a, lo), hi)


def _bezier(control, s):
    """The quintic Bezier of the 6 control points (axis -2) at s, in the
    source's order of terms."""
    t = 1.0 - s
    weights = (t ** 5, 5.0 * t ** 4 * s, 10.0 * t ** 3 * s ** 2, 10.0 * t ** 2 * s ** 3, 5.0 * t * s ** 4, s ** 5)
    total = weights[0] * control[..., 0, :]
    for k in range(1, 6):
        total = total + weights[k] * control[..., k, :]
    return total


def cook(turbidity, albedo, elevation):
    """(configs (3, 9), radiances (3,)) float64 as intern/sky's
    ArHosekSkyModel_CookConfiguration / _CookRadianceConfiguration."""
    sky, radiance = tables()
    low = int(turbidity)
    rem = turbidity - float(low)
    s = (elevation / (np.pi / 2.0)) ** (1.0 / 3.0)
    blocks = [((1.0 - albedo) * (1.0 - rem), 0, low - 1), (albedo * (1.0 - rem), 1, low - 1)]
    if low != 10:
        blocks += [((1.0 - albedo) * rem, 0, low), (albedo * rem, 1, low)]
    configs, radiances = np.zeros((3, 9)), np.zeros(3)
    for weight, a, t in blocks:
        configs = configs + weight * _bezier(sky[:, a, t], s)
        radiances = radiances + weight * _bezier(radiance[:, a, t][..., None], s)[..., 0]
    return configs, radiances


def precompute(sun_direction, turbidity, albedo):
    """(sun theta, sun phi, configs (3, 9), radiances (3,)) float32 as
    Cycles' sky_texture_precompute_hosek."""
    d = np.asarray(sun_direction, F)
    with np.errstate(all="ignore"):      # overflow and NaN as in Cycles' float32
        d = d / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])   # Blender's sync normalizes it
        theta = np.arccos(d[2])
        phi = np.arctan2(d[0], d[1])
    theta = F(_clamp(theta, F(0.0), HALF_PI))
    t = float(_clamp(F(turbidity), F(1.0), F(10.0)))
    elevation = float(HALF_PI - theta)
    configs, radiances = cook(t, float(F(albedo)), elevation)
    return theta, F(phi), configs.astype(F), radiances.astype(F)


def radiance_internal(c, theta, gamma):
    """F(theta, gamma) for one channel's parameters c (9,), float32."""
    ctheta = np.cos(theta)
    cgamma = np.cos(gamma)
    exp_m = np.exp(c[4] * gamma)
    ray_m = cgamma * cgamma
    mie_m = (F(1.0) + ray_m) / np.power(F(1.0) + c[8] * c[8] - F(2.0) * c[8] * cgamma, F(1.5))
    zenith = np.sqrt(ctheta)
    return (F(1.0) + c[0] * np.exp(c[1] / (ctheta + F(0.01)))) * (
        c[2] + c[3] * exp_m + c[5] * ray_m + c[6] * mie_m + c[7] * zenith)


def evaluate(d, props, xyz_to_rgb):
    """Linear RGB (N, 3) float32 for lookup vectors d (N, 3)."""
    d = np.asarray(d, F)
    sun_theta, sun_phi, configs, radiances = precompute(
        props.get("sun_direction", (0.0, 0.0, 1.0)), props.get("turbidity", 2.2), props.get("ground_albedo", 0.3))
    with np.errstate(all="ignore"):
        theta = np.arccos(np.clip(d[:, 2], F(-1.0), F(1.0)))
        phi = np.arctan2(d[:, 0], d[:, 1])
        cos_psi = (np.sin(theta) * np.sin(sun_theta) * np.cos(sun_phi - phi)
                   + np.cos(theta) * np.cos(sun_theta))
        gamma = np.arccos(_clamp(cos_psi, F(-1.0), F(1.0)))
        theta = np.minimum(theta, HALF_PI - F(0.001))
        xyz = np.stack([radiance_internal(configs[c], theta, gamma) * radiances[c] for c in range(3)], axis=1)
        rgb = np.maximum(xyz @ xyz_to_rgb.T, F(0.0)) * STRENGTH
    return np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)
