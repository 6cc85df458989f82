"""The Sky Texture node, as Cycles evaluates it (the registry entry is at
the end; sky_multiple.py and sky_preetham.py hold the other models).

For its Nishita models Cycles precomputes a table of sky radiance (CIE XYZ)
per direction on the host (Blender's intern/sky: sky_nishita.cpp in 3.x /
4.x, sky_single_scattering.cpp and sky_multiple_scattering.cpp in 5.0) and
the sun disc's radiance at its bottom and top edge; the kernel (svm/sky.h)
looks the table up bilinearly and draws the disc with limb darkening.  This
module does the same in float32, vectorized:

* ``sky_table`` / ``sun_pixels``: the single-scattering precompute.  32
  ray-march steps per direction, the sun's optical depth by 8-point
  Gauss-Laguerre quadrature, 21 wavelengths folded into XYZ.  Only half the
  columns are computed; the sky is mirrored about the sun's azimuth (Cycles'
  own layout, including its one-texel asymmetry).
* ``evaluate``: the kernel per direction (sky, sun disc, ground), XYZ to
  linear Rec.709 clamped at zero.

Layouts: Blender 3.4 / 4.2 ('NISHITA'): 512 x 128 texels over elevations 0
to 90 degrees (row y at elevation (pi/2 + half a row) (y / 128)^2), the
ground a fade of the horizon row, the disc replacing the sky.  Blender 5.0
('SINGLE_SCATTERING'): 512 x 256 texels over -90 to 90 degrees (the lower
half the horizon row faded), the disc added to the sky.  Blender 5.0
'MULTIPLE_SCATTERING': its own table (sky_multiple.py) and sun, looked up by
the same 5.0 kernel.  'PREETHAM' (sky_preetham.py) and 'HOSEK_WILKIE'
(sky_hosek.py, from the published coefficient tables) are analytic.
"""
from functools import lru_cache

import numpy as np

from ..scene import SunGuide
from .registry import node
from . import sky_hosek, sky_multiple, sky_preetham
from .sky_multiple import in_threads

F = np.float32
PI = F(np.pi)
HALF_PI = F(np.pi / 2)
TWO_PI = F(2 * np.pi)

RAYLEIGH_SCALE = F(8e3)
MIE_SCALE = F(1.2e3)
MIE_COEFF = F(2e-5)
MIE_G = F(0.76)
SQR_G = MIE_G * MIE_G
EARTH_RADIUS = F(6360e3)
ATMOSPHERE_RADIUS = F(6420e3)
STEPS = 32
STEP_LAMBDA = F(20.0)

IRRADIANCE = np.array([
    1.45756829855592995315, 1.56596305559738380175, 1.65148449067670455293,
    1.71496242737209314555, 1.75797983805020541226, 1.78256407885924539336,
    1.79095108475838560302, 1.78541550133410664714, 1.76815554864306845317,
    1.74122069647250410362, 1.70647127164943679389, 1.66556087452739887134,
    1.61993437242451854274, 1.57083597368892080581, 1.51932335059305478886,
    1.46628494965214395407, 1.41245852740172450623, 1.35844961970384092709,
    1.30474913844739281998, 1.25174963272610817455, 1.19975998755420620867], F)
RAYLEIGH_COEFF = np.array([
    0.00005424820087636473, 0.00004418549866505454, 0.00003635151910165377,
    0.00003017929012024763, 0.00002526320226989157, 0.00002130859310621843,
    0.00001809838025320633, 0.00001547057129129042, 0.00001330284977336850,
    0.00001150184784075764, 0.00000999557429990163, 0.00000872799973630707,
    0.00000765513700977967, 0.00000674217203751443, 0.00000596134125832052,
    0.00000529034598065810, 0.00000471115687557433, 0.00000420910481110487,
    0.00000377218381260133, 0.00000339051255477280, 0.00000305591531679811], F)
OZONE_COEFF = np.array([
    0.00000000325126849861, 0.00000000585395365047, 0.00000001977191155085,
    0.00000007309568762914, 0.00000020084561514287, 0.00000040383958096161,
    0.00000063551335912363, 0.00000096707041180970, 0.00000154797400424410,
    0.00000209038647223331, 0.00000246128056164565, 0.00000273551299461512,
    0.00000215125863128643, 0.00000159051840791988, 0.00000112356197979857,
    0.00000073527551487574, 0.00000046450130357806, 0.00000033096079921048,
    0.00000022512612292678, 0.00000014879129266490, 0.00000016828623364192], F)
CMF_XYZ = np.array([
    [0.00136800000, 0.00003900000, 0.00645000100], [0.01431000000, 0.00039600000, 0.06785001000],
    [0.13438000000, 0.00400000000, 0.64560000000], [0.34828000000, 0.02300000000, 1.74706000000],
    [0.29080000000, 0.06000000000, 1.66920000000], [0.09564000000, 0.13902000000, 0.81295010000],
    [0.00490000000, 0.32300000000, 0.27200000000], [0.06327000000, 0.71000000000, 0.07824999000],
    [0.29040000000, 0.95400000000, 0.02030000000], [0.59450000000, 0.99500000000, 0.00390000000],
    [0.91630000000, 0.87000000000, 0.00165000100], [1.06220000000, 0.63100000000, 0.00080000000],
    [0.85444990000, 0.38100000000, 0.00019000000], [0.44790000000, 0.17500000000, 0.00002000000],
    [0.16490000000, 0.06100000000, 0.00000000000], [0.04677000000, 0.01700000000, 0.00000000000],
    [0.01135916000, 0.00410200000, 0.00000000000], [0.00289932700, 0.00104700000, 0.00000000000],
    [0.00069007860, 0.00024920000, 0.00000000000], [0.00016615050, 0.00006000000, 0.00000000000],
    [0.00004150994, 0.00001499000, 0.00000000000]], F)
# Gauss-Laguerre nodes and weights (exp(x) folded in), scaled to the ray.
QUADRATURE_NODES = np.array([0.006811185292, 0.03614807107, 0.09004346519, 0.1706680068,
                             0.2818362161, 0.4303406404, 0.6296271457, 0.9145252695], F)
QUADRATURE_WEIGHTS = np.array([0.01750893642, 0.04135477391, 0.06678839063, 0.09507698807,
                               0.1283416365, 0.1707430204, 0.2327233347, 0.3562490486], F)
# CIE XYZ (D65) -> linear Rec.709, Blender's scene linear space (as the
# Wavelength node; Cycles reads it from the OpenColorIO config).
XYZ_TO_REC709 = np.array([[3.2409699, -1.5373832, -0.4986108], [-0.9692436, 1.8759675, 0.0415551],
                          [0.0556301, -0.2039770, 1.0569715]], F)
# Blender 3.4 and 4.2: their OpenColorIO configs give Cycles the classic sRGB
# (D65) matrix, 4 digits apart from 5.0's (fitted to Cycles' Preetham sky,
# residual 3e-5, which Ember's 5.0 matrix leaves at 2.4e-4 there; versions
# between 4.2 and 5.0 were not measured and get this one).
XYZ_TO_REC709_LEGACY = np.array([[3.2404542, -1.5371385, -0.4985314], [-0.9692660, 1.8760108, 0.0415560],
                                 [0.0556434, -0.2040259, 1.0572252]], F)


def xyz_to_rgb_matrix(props):
    version = tuple(props.get("_blender_version") or (5, 0, 0))
    return XYZ_TO_REC709 if version >= (5, 0, 0) else XYZ_TO_REC709_LEGACY


# Table sizes per layout (Cycles' SkyLoader::load_metadata).
LEGACY = "legacy"          # Blender 3.4 - 4.x 'NISHITA'
SINGLE = "single"          # Blender 5.0 'SINGLE_SCATTERING'
MULTIPLE = "multiple"      # Blender 5.0 'MULTIPLE_SCATTERING' (sky_multiple.py)
TABLE_SIZE = {LEGACY: (512, 128), SINGLE: (512, 256), MULTIPLE: (512, 256)}
# Altitude clamps of the precomputes (metres).
MAX_ALTITUDE = {LEGACY: 59999.0, SINGLE: 59999.0, MULTIPLE: 99999.0}


def geographical_to_direction(lat, lon):
    lat, lon = F(lat), F(lon)
    return np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], F)


def _densities(height):
    """Rayleigh, Mie and ozone densities at heights (any shape) -> (..., 3)."""
    ozone = np.maximum(F(0.0), F(1.0) - np.abs(height - F(25000.0)) / F(15000.0))
    ozone = np.where((height >= F(10000.0)) & (height < F(40000.0)), ozone, F(0.0))
    return np.stack([np.exp(-height / RAYLEIGH_SCALE), np.exp(-height / MIE_SCALE), ozone], axis=-1)


def _atmosphere_distance(pos, d):
    """Distance along unit d (..., 3) from pos (..., 3) to the atmosphere's edge."""
    b = F(-2.0) * np.einsum("...i,...i->...", d, -pos)
    c = np.einsum("...i,...i->...", pos, pos) - ATMOSPHERE_RADIUS * ATMOSPHERE_RADIUS
    t = (-b + np.sqrt(np.maximum(b * b - F(4.0) * c, F(0.0)))) / F(2.0)
    end = pos + d * t[..., None]
    return np.sqrt(np.einsum("...i,...i->...", end - pos, end - pos))


def _optical_depth(origin, d):
    """Rayleigh, Mie, ozone optical depths (..., 3) from origin along unit d
    to the atmosphere's edge (Cycles' ray_optical_depth)."""
    length = _atmosphere_distance(origin, d)
    segment = length[..., None] * d
    depth = np.zeros(origin.shape[:-1] + (3,), F)
    for node, weight in zip(QUADRATURE_NODES, QUADRATURE_WEIGHTS):
        p = origin + node * segment
        height = np.sqrt(np.einsum("...i,...i->...", p, p)) - EARTH_RADIUS
        depth += _densities(height) * weight
    return depth * length[..., None]


def _hits_earth(p, d):
    """Cycles' surface_intersection for points p (..., 3) along a unit d (3,)."""
    if d[2] >= 0:
        return np.zeros(p.shape[:-1], bool)
    b = F(-2.0) * (p @ -d)
    c = np.einsum("...i,...i->...", p, p) - EARTH_RADIUS * EARTH_RADIUS
    return b * b - F(4.0) * c >= F(0.0)


def _phases(mu):
    rayleigh = F(3.0) / (F(16.0) * PI) * (F(1.0) + mu * mu)
    mie = (F(3.0) * (F(1.0) - SQR_G) * (F(1.0) + mu * mu)) / (
        F(8.0) * PI * (F(2.0) + SQR_G) * np.power(F(1.0) + SQR_G - F(2.0) * MIE_G * mu, F(1.5)))
    return rayleigh, mie


def single_scattering_xyz(dirs, sun_dir, altitude, air, dust, ozone):
    """In-scattered XYZ (N, 3) along unit directions dirs (N, 3) seen from
    the altitude (Cycles' single_scattering + spec_to_xyz)."""
    cam = np.array([0.0, 0.0, EARTH_RADIUS + F(altitude)], F)
    length = _atmosphere_distance(np.broadcast_to(cam, dirs.shape), dirs)
    seg_len = length / F(STEPS)
    segment = dirs * seg_len[:, None]
    scale = np.array([air, dust, ozone], F)
    rayleigh_phase, mie_phase = _phases(dirs @ sun_dir)
    # Midpoints of the steps: (N, STEPS, 3), accumulated as Cycles does.
    steps = np.arange(STEPS, dtype=F)[None, :, None] + F(0.5)
    p = cam + steps * segment[:, None, :]
    height = np.sqrt(np.einsum("nsi,nsi->ns", p, p)) - EARTH_RADIUS
    density = scale * _densities(height)
    view_depth = np.cumsum(density * seg_len[:, None, None], axis=1, dtype=F)
    lit = ~_hits_earth(p, sun_dir)
    light_depth = scale * _optical_depth(p, np.broadcast_to(sun_dir, p.shape))
    total = view_depth + light_depth
    extinction = np.stack([RAYLEIGH_COEFF, np.full(21, F(1.11) * MIE_COEFF, F), OZONE_COEFF])
    attenuation = np.exp(-(total @ extinction))                          # (N, S, 21)
    scattering = (density[..., 0:1] * rayleigh_phase[:, None, None] * RAYLEIGH_COEFF
                  + (density[..., 1] * mie_phase[:, None] * MIE_COEFF)[..., None])
    per_step = np.where(lit[..., None], attenuation * scattering, F(0.0))
    spectrum = per_step.sum(axis=1, dtype=F) * IRRADIANCE * seg_len[:, None]
    return (spectrum @ CMF_XYZ) * STEP_LAMBDA


def _sun_xyz(elevation, altitude, air, dust, solid_angle):
    cam = np.array([[0.0, 0.0, EARTH_RADIUS + F(altitude)]], F)
    d = geographical_to_direction(elevation, 0.0)[None]
    depth = _optical_depth(cam, d)[0]
    transmittance = RAYLEIGH_COEFF * depth[0] * F(air) + F(1.11) * MIE_COEFF * depth[1] * F(dust)
    spectrum = IRRADIANCE * np.exp(-transmittance) / F(solid_angle)
    return (spectrum @ CMF_XYZ) * STEP_LAMBDA


@lru_cache(maxsize=16)
def sun_pixels(layout, elevation, diameter, altitude, air, dust, ozone=1.0):
    """XYZ radiance at the bottom and top edge of the sun disc (Cycles'
    SKY_nishita_skymodel_precompute_sun / SKY_single_scattering_... /
    SKY_multiple_scattering_...)."""
    if layout == MULTIPLE:
        return sky_multiple.sun_pixels(elevation, diameter, altitude, air, dust, ozone)
    half = F(diameter) / F(2.0)
    solid_angle = TWO_PI * (F(1.0) - np.cos(half))
    bottom, top = F(elevation) - half, F(elevation) + half
    if layout == SINGLE and not top > 0:
        return np.zeros(3, F), np.zeros(3, F)
    if not solid_angle > 0:
        return np.zeros(3, F), np.zeros(3, F)
    return (_sun_xyz(max(bottom, F(0.0)), altitude, air, dust, solid_angle),
            _sun_xyz(max(top, F(0.0)), altitude, air, dust, solid_angle))


def sky_table(layout, elevation, altitude, air, dust, ozone):
    """The precomputed XYZ table (H, W, 3), row 0 = the lowest elevation,
    as Cycles' SkyLoader fills it.  Cached: a render reuses it."""
    return _sky_table(layout, TABLE_SIZE[layout], elevation, altitude, air, dust, ozone)


sky_table.cache_clear = lambda: _sky_table.cache_clear()


@lru_cache(maxsize=4)
def _sky_table(layout, size, elevation, altitude, air, dust, ozone):
    if layout == MULTIPLE:
        table = sky_multiple.sky_table(size, elevation, altitude, air, dust, ozone)
        table.setflags(write=False)
        return table
    width, height = size
    sun_dir = geographical_to_direction(elevation, 0.0)
    if layout == LEGACY:
        lat_step = HALF_PI / F(height)
        rows = np.arange(height)
        lat = (HALF_PI + lat_step / F(2.0)) * np.square(rows.astype(F) / F(height))
    else:
        rows = np.arange(height // 2, height)
        lat = HALF_PI * np.square(rows.astype(F) / F(height // 2) - F(1.0))
    lon = TWO_PI / F(width) * np.arange(width // 2, dtype=F) - PI
    la, lo = np.meshgrid(lat.astype(F), lon, indexing="ij")
    dirs = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1).reshape(-1, 3)
    def scatter(chunk):
        with np.errstate(all="ignore"):   # as Cycles, float32 may overflow to inf (-> exp(-inf) = 0)
            return single_scattering_xyz(chunk, sun_dir, altitude, air, dust, ozone)
    xyz = np.concatenate(in_threads(scatter, np.array_split(dirs, max(1, len(dirs) // 2048))))
    xyz = np.nan_to_num(xyz, nan=0.0, posinf=0.0, neginf=0.0)
    half = xyz.reshape(len(rows), width // 2, 3)
    table = np.zeros((height, width, 3), F)
    table[rows, :width // 2] = half
    table[rows, width // 2:] = half[:, ::-1]
    if layout == SINGLE:
        _fade_lower_half(table)
    table.setflags(write=False)
    return table


def _fade_lower_half(table):
    """Blender 5.0: rows below the horizon are the horizon row faded by
    (1 - 2.5 z)^3, z the sine of the row's (mirrored) elevation, 0 from 0.4."""
    half = table.shape[0] // 2
    lat = HALF_PI * np.square(np.arange(half, dtype=F) / F(half) - F(1.0))
    z = np.sin(lat)
    fade = F(1.0) - z * F(2.5)
    fade = np.where(z < F(0.4), fade * fade * fade, F(0.0)).astype(F)
    table[:half] = table[half][None] * fade[:, None, None]


def lookup_extend(table, x, y):
    """Cycles' bilinear image lookup with EXTEND (clamped) addressing;
    table row 0 is y = 0."""
    h, w = table.shape[:2]
    fx = x.astype(F) * F(w) - F(0.5)
    fy = y.astype(F) * F(h) - F(0.5)
    ix, iy = np.floor(fx), np.floor(fy)
    tx, ty = (fx - ix)[:, None], (fy - iy)[:, None]
    ix, iy = ix.astype(np.int64), iy.astype(np.int64)
    x0, x1 = np.clip(ix, 0, w - 1), np.clip(ix + 1, 0, w - 1)
    y0, y1 = np.clip(iy, 0, h - 1), np.clip(iy + 1, 0, h - 1)
    one = F(1.0)
    return ((one - ty) * (one - tx) * table[y0, x0] + (one - ty) * tx * table[y0, x1]
            + ty * (one - tx) * table[y1, x0] + ty * tx * table[y1, x1])


# ----------------------------------------------------------------------------
# Node parameters as Cycles compiles them

def kernel_params(props):
    """The node's properties as Cycles' kernel sees them: layout, wrapped sun
    elevation and rotation, clamped altitude, densities, disc."""
    version = tuple(props.get("_blender_version") or (5, 0, 0))
    if version < (5, 0, 0):
        layout = LEGACY
    else:
        layout = MULTIPLE if props.get("sky_type") == "MULTIPLE_SCATTERING" else SINGLE
    elevation = F(props.get("sun_elevation", np.radians(15.0)))
    rotation = F(props.get("sun_rotation", 0.0))
    if version >= (3, 6, 0):
        elevation, rotation = _simplify(elevation, rotation)
    else:
        rotation = np.fmod(rotation, TWO_PI)
        rotation = TWO_PI - (rotation + TWO_PI if rotation < 0 else rotation)
    return dict(
        layout=layout, xyz_to_rgb=xyz_to_rgb_matrix(props), elevation=float(elevation), rotation=float(F(rotation)),
        altitude=float(np.clip(F(props.get("altitude", 1.0)), F(1.0), F(MAX_ALTITUDE[layout]))),
        raw_altitude=float(F(props.get("altitude", 1.0))),
        air=float(F(props.get("air_density", 1.0))), dust=float(F(props.get("dust_density", 1.0))),
        ozone=float(F(props.get("ozone_density", 1.0))),
        diameter=float(F(props.get("sun_size", 0.009512))), disc=bool(props.get("sun_disc", True)),
        intensity=float(F(props.get("sun_intensity", 1.0))))


def _simplify(elevation, rotation):
    """Cycles' SkyTextureNode::simplify_settings (3.6 and newer)."""
    elevation = np.fmod(elevation, TWO_PI)
    if abs(elevation) >= PI:
        elevation = F(elevation - np.copysign(F(2.0), elevation) * PI)
    if elevation >= HALF_PI or elevation <= -HALF_PI:
        elevation = F(np.copysign(PI, elevation) - elevation)
        rotation = F(rotation + PI)
    rotation = np.fmod(rotation, TWO_PI)
    if rotation < 0:
        rotation = F(rotation + TWO_PI)
    return F(elevation), F(TWO_PI - rotation)


def sun_direction(k):
    """Unit direction of the sun disc's centre in the node's coordinates."""
    return geographical_to_direction(k["elevation"], F(k["rotation"]) + HALF_PI).astype(np.float64)


def earth_intersection_angle(altitude):
    """Minus Blender 5.0's SKY_earth_intersection_angle (its multiple-scattering
    model's Earth of 6371 km, the node's unclamped altitude in metres): the
    elevation below which a view ray from the altitude meets the ground."""
    radius = F(6371.0)
    return float(-(HALF_PI - np.arcsin(radius / (radius + F(altitude) / F(1000.0)))))


def disc_visible(k):
    """Whether any of the sun disc is drawn: above the horizon in 3.4 -
    4.x, above the Earth's edge seen from the altitude in 5.0."""
    if not k["disc"]:
        return False
    top = k["elevation"] + 0.5 * k["diameter"]
    if k["layout"] == LEGACY:
        return top > 0
    return top > earth_intersection_angle(k["raw_altitude"])


def _precise_angle(a, b):
    return F(2.0) * np.arctan2(np.linalg.norm(a - b, axis=1), np.linalg.norm(a + b, axis=1))


def evaluate(d, k, include_sun=True):
    """Linear Rec.709 radiance (N, 3) float32 for lookup vectors d (N, 3)."""
    # Extreme properties overflow float32 as in Cycles (e.g. a disc of size
    # 0 divides by zero where no direction is inside it); the result is
    # made finite at the end.
    with np.errstate(all="ignore"):
        return _evaluate(np.asarray(d, F), k, include_sun)


def _evaluate(d, k, include_sun):
    table = sky_table(k["layout"], k["elevation"], k["altitude"], k["air"], k["dust"], k["ozone"])
    bottom, top = sun_pixels(k["layout"], k["elevation"], k["diameter"], k["altitude"], k["air"], k["dust"],
                             k["ozone"])
    theta = np.arccos(np.clip(d[:, 2], F(-1.0), F(1.0)))
    dir_elevation = HALF_PI - theta
    rotation = F(k["rotation"])
    if k["layout"] == LEGACY:
        xyz = _legacy_sky(d, table, dir_elevation, rotation)
    else:
        phi = np.arctan2(d[:, 1], d[:, 0])
        x = (-phi - HALF_PI + rotation) * F(1.0 / (2.0 * np.pi))
        x = x - np.floor(x)
        y = np.copysign(np.sqrt(np.abs(dir_elevation) * F(2.0 / np.pi)), dir_elevation) * F(0.5) + F(0.5)
        xyz = lookup_extend(table, x, y)
    if k["disc"] and include_sun:
        xyz = _add_sun(d, xyz, dir_elevation, k, bottom, top)
    rgb = xyz @ k["xyz_to_rgb"].T
    return np.maximum(np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0), F(0.0))


def _legacy_sky(d, table, dir_elevation, rotation):
    """Blender 3.4 - 4.x: the table above the horizon, a cubic fade of its
    horizon row down to dir.z = -0.4, black below."""
    phi = np.arctan2(d[:, 0], d[:, 1])
    x = (phi + PI + rotation) / TWO_PI
    x = np.where(x > F(1.0), x - F(1.0), x)
    above = d[:, 2] >= 0
    y = np.where(above, np.sqrt(np.maximum(dir_elevation / HALF_PI, F(0.0))), F(-0.5))
    xyz = lookup_extend(table, x, y)
    fade = F(1.0) + d[:, 2] * F(2.5)
    fade = np.where(above, F(1.0), np.where(d[:, 2] < F(-0.4), F(0.0), fade * fade * fade))
    return xyz * fade[:, None]


def _add_sun(d, xyz, dir_elevation, k, bottom, top):
    """The sun disc with limb darkening (replacing the sky in 3.4 - 4.x,
    added to it in 5.0)."""
    sun = sun_direction(k).astype(F)
    angle = _precise_angle(d, sun[None])
    diameter = F(k["diameter"])
    half = diameter * F(0.5)
    elevation = F(k["elevation"])
    if k["layout"] == LEGACY:
        inside = (d[:, 2] >= 0) & (angle < half)
        if elevation - half > 0:
            y = (dir_elevation - elevation) / diameter + F(0.5)
        elif elevation + half > 0:
            y = dir_elevation / (elevation + half)
        else:
            inside &= False
            y = np.zeros(len(d), F)
    else:
        inside = (angle < half) & (dir_elevation > F(earth_intersection_angle(k["raw_altitude"])))
        y = (dir_elevation - elevation) / diameter + F(0.5)
    if not inside.any():
        return xyz
    with np.errstate(invalid="ignore"):
        limb = F(1.0) - F(0.6) * (F(1.0) - np.sqrt(np.maximum(F(1.0) - np.square(angle / half), F(0.0))))
    disc = (bottom + (top - bottom) * y[:, None]) * F(k["intensity"]) * limb[:, None]
    if k["layout"] == LEGACY:
        return np.where(inside[:, None], disc, xyz)
    return xyz + np.where(inside[:, None], disc, F(0.0))


def sun_luminance_integral(k):
    """Luminance of the disc integrated over its solid angle (W/m^2 seen
    head-on): the centre's radiance x the solid angle x 0.8, the mean of
    the limb darkening 1 - 0.6 (1 - sqrt(1 - r^2)) over the disc."""
    if not k["disc"]:
        return 0.0
    bottom, top = sun_pixels(k["layout"], k["elevation"], k["diameter"], k["altitude"], k["air"], k["dust"],
                             k["ozone"])
    rgb = np.maximum(k["xyz_to_rgb"] @ ((bottom + top) * F(0.5)), 0.0) * k["intensity"]
    lum = float(rgb @ np.array([0.2126, 0.7152, 0.0722]))
    half = 0.5 * k["diameter"]
    return lum * 2.0 * np.pi * (1.0 - np.cos(half)) * 0.8


def sun_guide(props, matrix):
    """The SunGuide of a Sky Texture's disc (Cycles' sun guiding) for a sky
    looked up at M d (``matrix`` M, world direction d), or None where no disc
    is seen (Cycles would aim at the hidden disc: nothing to guide to)."""
    k = kernel_params(props)
    if not k["diameter"] > 0 or not disc_visible(k):
        return None
    direction = np.linalg.solve(matrix, sun_direction(k))
    direction /= np.linalg.norm(direction)
    return SunGuide(tuple(float(c) for c in direction), 0.5 * k["diameter"], sun_luminance_integral(k))


# ----------------------------------------------------------------------------
# The registry entry

SKY_TYPES = ("NISHITA", "SINGLE_SCATTERING", "MULTIPLE_SCATTERING", "PREETHAM", "HOSEK_WILKIE")


def _translate(node):
    """Blender 5.0 renamed Dust to Aerosol."""
    aerosol = getattr(node, "aerosol_density", None)
    return {} if aerosol is None else {"dust_density": float(aerosol)}


def _accepts(props):
    kind = props.get("sky_type")
    if kind not in SKY_TYPES:
        return f"sky type {kind!r} is not rendered yet"
    if kind == "HOSEK_WILKIE":
        # Cycles' Hosek-Wilkie sky is undefined here (NaN, or a table read
        # out of bounds): named rather than guessed.
        turbidity, albedo = _number(props.get("turbidity", 2.2)), _number(props.get("ground_albedo", 0.3))
        if np.isnan(turbidity):        # an infinite one clamps to 10, as in Cycles
            return f"Hosek-Wilkie turbidity {props.get('turbidity')!r} is not a number"
        if not 0.0 <= albedo <= 1.0:   # Blender's range; Cycles would extrapolate the fits
            return f"Hosek-Wilkie ground albedo {props.get('ground_albedo')!r} is outside 0..1"
    return None


def _number(value):
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


@node("ShaderNodeTexSky", inputs=(("Vector", "vector"),), outputs=(("Color", "color"),),
      props=(("sky_type", "NISHITA"), ("sun_disc", True), ("sun_size", 0.009512), ("sun_intensity", 1.0),
             ("sun_elevation", 0.2617994), ("sun_rotation", 0.0), ("altitude", 1.0), ("air_density", 1.0),
             ("dust_density", 1.0), ("ozone_density", 1.0), ("sun_direction", (0.0, 0.0, 1.0)),
             ("turbidity", 2.2), ("ground_albedo", 0.3)),
      translate=_translate, coords="generated", accepts=_accepts,
      bounds=lambda p: {"Color": (0.0, np.inf)},
      # The tables' measured precision against Cycles (tests/engine/test_sky.py:
      # 1e-4 - 4e-4 relative, 32 ray-march steps x 21 wavelengths in float32),
      # at the values of order 1 the cases give: not the parity test's 2e-5.
      tolerance=4e-4,
      # In a material the Vector is Generated (in [0, 1]^3: the upper sky, not
      # unit vectors; Cycles uses them as they are, so does Ember).
      cases=[{"sky_type": "SINGLE_SCATTERING", "sun_elevation": 0.5, "sun_rotation": 1.0, "altitude": 500.0},
             {"sky_type": "SINGLE_SCATTERING", "sun_size": 0.4, "sun_elevation": 0.7, "sun_rotation": 3.9,
              "air_density": 2.0, "ozone_density": 3.0, "sun_intensity": 1e-5},
             {"sky_type": "MULTIPLE_SCATTERING", "sun_size": 0.3, "sun_elevation": 0.4, "sun_rotation": 2.0,
              "aerosol_density": 3.0, "sun_intensity": 1e-5},
             {"sky_type": "PREETHAM", "sun_direction": (0.3, -0.5, 0.6), "turbidity": 3.5},
             {"sky_type": "HOSEK_WILKIE", "sun_direction": (-0.4, 0.2, 0.5), "turbidity": 4.5,
              "ground_albedo": 0.6}])
def sky_texture(ctx, i, p):
    if p.get("sky_type") == "PREETHAM":
        return {"Color": sky_preetham.evaluate(i["Vector"], p, xyz_to_rgb_matrix(p)).astype(np.float64)}
    if p.get("sky_type") == "HOSEK_WILKIE":
        return {"Color": sky_hosek.evaluate(i["Vector"], p, xyz_to_rgb_matrix(p)).astype(np.float64)}
    k = kernel_params(p)
    include_sun = not getattr(ctx, "importance_bake", False)
    return {"Color": evaluate(np.asarray(i["Vector"], F), k, include_sun).astype(np.float64)}
