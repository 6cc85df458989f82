"""Blender 5.0's 'MULTIPLE_SCATTERING' sky table, as Cycles precomputes it.

Blender 5.0 (intern/sky/source/sky_multiple_scattering.cpp) uses Fernando
Garcia Linan's spectral sky: four wavelengths (630, 560, 490, 430 nm), an
atmosphere of molecules, aerosols and ozone with analytic height profiles,
a transmittance table (256 x 64: cos(sun zenith) x altitude, 64 steps), and
in-scattering along each view ray (64 steps, Hillaire's energy-conserving
step integration) with an analytic fit of multiple scattering plus
second-order light from a grey ground (albedo 0.3).  Distances in km.

The table (512 x 256) is laid out as sky.py's 5.0 table: texel (x, y) looks
at azimuth 2 pi (x + 0.5) / 512 (the sun at azimuth pi) and elevation
sign(l) l^2 pi / 2, l = 2 (y + 0.5) / 256 - 1; rays towards the ground stop
there.  Computed in float32 with Cycles' operation order, vectorized.
"""
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

F = np.float32
PI = F(np.pi)
HALF_PI = F(np.pi / 2)
TWO_PI = F(2 * np.pi)
INV_4PI = F(1.0 / (4.0 * np.pi))

GROUND_ALBEDO = F(0.3)
RAYLEIGH_PHASE_SCALE = F(3.0 / 16.0) * F(1.0 / np.pi)
G = F(0.8)
SQR_G = G * G
EARTH_RADIUS = F(6371.0)
ATMOSPHERE_THICKNESS = F(100.0)
ATMOSPHERE_RADIUS = EARTH_RADIUS + ATMOSPHERE_THICKNESS
TRANSMITTANCE_STEPS = 64
IN_SCATTERING_STEPS = 64
TRANSMITTANCE_RES = (256, 64)

SUN_SPECTRAL_IRRADIANCE = np.array([1.679, 1.828, 1.986, 1.307], F)
MOLECULAR_SCATTERING_BASE = np.array([6.605e-3, 1.067e-2, 1.842e-2, 3.156e-2], F)
OZONE_ABSORPTION_CROSS_SECTION = np.array([3.472e-25, 3.914e-25, 1.349e-25, 11.03e-27], F)
OZONE_MEAN_DOBSON = F(334.5)
AEROSOL_ABSORPTION_CROSS_SECTION = np.array([2.8722e-24, 4.6168e-24, 7.9706e-24, 1.3578e-23], F)
AEROSOL_SCATTERING_CROSS_SECTION = np.array([1.5908e-22, 1.7711e-22, 2.0942e-22, 2.4033e-22], F)
AEROSOL_BASE_DENSITY = F(1.3681e20)
AEROSOL_BACKGROUND_DENSITY = F(2e6)
AEROSOL_HEIGHT_SCALE = F(0.73)
# The four wavelengths' radiance -> CIE XYZ (rows: wavelengths).
SPECTRAL_XYZ = np.array([[53.386917738564668023, 22.981337506691024754, 0.0],
                         [43.904844466369358263, 71.347795700053393866, 0.102506867965741307],
                         [1.6137278251608962005, 18.422960591455485011, 31.742921188390805758],
                         [20.762668673810577145, 2.3614213523314368527, 110.48009643252140334]], F)
MS_FIT = F(0.02) * np.array([0.217, 0.347, 0.594, 1.0], F)


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def sun_direction(cos_theta):
    cos_theta = np.asarray(cos_theta, F)
    return np.stack([-np.sqrt(F(1.0) - cos_theta * cos_theta), np.zeros_like(cos_theta), cos_theta], axis=-1)


def ray_sphere_intersection(pos, d, radius):
    """Distance along d to the sphere about the origin; -1 for none."""
    b = _dot(pos, d)
    c = _dot(pos, pos) - F(radius) * F(radius)
    disc = b * b - c
    root = np.sqrt(np.maximum(disc, F(0.0)))
    t = np.where(disc >= b * b, -b + root, -b - root)
    return np.where(((c > 0) & (b > 0)) | (disc < 0), F(-1.0), t).astype(F)


class Atmosphere:
    """Cycles' SkyMultipleScattering for the node's densities."""

    def __init__(self, air, aerosol, ozone):
        self.air, self.aerosol, self.ozone = F(air), F(aerosol), F(ozone)
        self.lut = None

    def coefficients(self, h):
        """Extinction and the two scattering coefficients (..., 4) at altitudes h (km)."""
        aerosol = AEROSOL_BASE_DENSITY * (np.exp(-h / AEROSOL_HEIGHT_SCALE)
                                          + AEROSOL_BACKGROUND_DENSITY / AEROSOL_BASE_DENSITY)
        aerosol = (aerosol * self.aerosol)[..., None]
        log_h = np.log(np.maximum(h, F(1e-4)))
        ozone = F(3.78547397e20) * np.exp(-np.square(log_h - F(3.22261)) * F(5.55555555) - log_h)
        molecular_absorption = OZONE_ABSORPTION_CROSS_SECTION * OZONE_MEAN_DOBSON * ozone[..., None] * self.ozone
        molecular_scattering = (MOLECULAR_SCATTERING_BASE
                                * np.exp(F(-0.07771971) * np.power(h, F(1.16364243)))[..., None] * self.air)
        aerosol_scattering = AEROSOL_SCATTERING_CROSS_SECTION * aerosol
        extinction = (AEROSOL_ABSORPTION_CROSS_SECTION * aerosol + aerosol_scattering + molecular_absorption
                      + molecular_scattering)
        return extinction, molecular_scattering, aerosol_scattering

    def transmittance(self, cos_theta, normalized_altitude):
        """Transmittance (..., 4) towards the sun from an altitude (get_transmittance)."""
        cos_theta = np.asarray(cos_theta, F)
        d = sun_direction(cos_theta)
        r = EARTH_RADIUS + np.asarray(normalized_altitude, F) * (ATMOSPHERE_RADIUS - EARTH_RADIUS)
        origin = np.zeros(d.shape, F)
        origin[..., 2] = r
        t_step = ray_sphere_intersection(origin, d, ATMOSPHERE_RADIUS) / F(TRANSMITTANCE_STEPS)
        total = np.zeros(d.shape[:-1] + (4,), F)
        for step in range(TRANSMITTANCE_STEPS):
            t = (F(step) + F(0.5)) * t_step
            x = origin + d * t[..., None]
            altitude = np.maximum(np.sqrt(_dot(x, x)) - EARTH_RADIUS, F(0.0))
            total += self.coefficients(altitude)[0] * t_step[..., None]
        return np.exp(-total)

    def precompute_lut(self):
        w, h = TRANSMITTANCE_RES
        u = np.arange(w, dtype=F) / F(w - 1)
        v = np.arange(h, dtype=F) / F(h - 1)
        vv, uu = np.meshgrid(v, u, indexing="ij")
        self.lut = self.transmittance(uu * F(2.0) - F(1.0), vv)      # (64, 256, 4)
        self.flat = np.ascontiguousarray(self.lut.reshape(-1, 4))
        self.ground_to_sun = self.lut[0, -1]     # _to_sun(0): the last column's first row

    def lookup(self, cos_theta, normalized_altitude):
        """Bilinear lookup of the transmittance table (Cycles' indices: the
        lower corner by truncation, the upper one clamped)."""
        w, h = TRANSMITTANCE_RES
        x = F(w - 1) * np.clip(cos_theta * F(0.5) + F(0.5), F(0.0), F(1.0))
        y = F(h - 1) * np.clip(normalized_altitude, F(0.0), F(1.0))
        x1, y1 = x.astype(np.intp), y.astype(np.intp)
        x2, y2 = np.minimum(x1 + 1, w - 1), np.minimum(y1 + 1, h - 1)
        fx, fy = (x - x1)[..., None], (y - y1)[..., None]
        flat = self.flat
        a, b = np.take(flat, y1 * w + x1, axis=0), np.take(flat, y1 * w + x2, axis=0)
        c, d = np.take(flat, y2 * w + x1, axis=0), np.take(flat, y2 * w + x2, axis=0)
        bottom = a + fx * (b - a)
        top = c + fx * (d - c)
        return bottom + fy * (top - bottom)

    def _lookup_rows(self, cos_theta, normalized_altitude):
        """``lookup`` for cos_theta (R, C, S) at altitudes (R, S) shared by a
        row's columns: the altitude interpolation is done once per (row,
        step) on whole table rows, then one interpolation in cos_theta."""
        w, h = TRANSMITTANCE_RES
        y = F(h - 1) * np.clip(normalized_altitude, F(0.0), F(1.0))
        y1 = y.astype(np.intp)
        y2 = np.minimum(y1 + 1, h - 1)
        fy = (y - y1)[..., None, None]
        rows = self.lut[y1] + fy * (self.lut[y2] - self.lut[y1])           # (R, S, W, 4)
        flat = rows.reshape(-1, 4)
        x = F(w - 1) * np.clip(cos_theta * F(0.5) + F(0.5), F(0.0), F(1.0))
        x1 = x.astype(np.intp)
        x2 = np.minimum(x1 + 1, w - 1)
        fx = (x - x1)[..., None]
        r, c, s = cos_theta.shape
        base = (np.arange(r)[:, None, None] * s + np.arange(s)[None, None, :]) * w
        a, b = np.take(flat, base + x1, axis=0), np.take(flat, base + x2, axis=0)
        return a + fx * (b - a)

    def _at_ground(self, cos_theta):
        w = TRANSMITTANCE_RES[0]
        x = F(w - 1) * np.clip(cos_theta * F(0.5) + F(0.5), F(0.0), F(1.0))
        x1 = x.astype(np.intp)
        x2 = np.minimum(x1 + 1, w - 1)
        fx = (x - x1)[..., None]
        a, b = np.take(self.lut[0], x1, axis=0), np.take(self.lut[0], x2, axis=0)
        return a + fx * (b - a)

    def _to_sun(self, normalized_altitude):
        h = TRANSMITTANCE_RES[1]
        y = F(h - 1) * np.clip(normalized_altitude, F(0.0), F(1.0))
        y1 = y.astype(np.intp)
        y2 = np.minimum(y1 + 1, h - 1)
        fy = (y - y1)[..., None]
        col = np.ascontiguousarray(self.lut[:, -1])
        a, b = np.take(col, y1, axis=0), np.take(col, y2, axis=0)
        return a + fy * (b - a)

    def multiscattering(self, cos_theta, normalized_altitude, distance):
        omega = TWO_PI * (F(1.0) - np.sqrt(np.maximum(F(1.0) - np.square(EARTH_RADIUS / distance), F(0.0))))
        to_ground = self._at_ground(cos_theta)
        ground_to_sample = self.ground_to_sun / self._to_sun(normalized_altitude)
        ground = (INV_4PI * omega)[..., None] * (GROUND_ALBEDO * F(1.0 / np.pi)) * to_ground * ground_to_sample \
            * cos_theta[..., None]
        fit = MS_FIT * (F(1.0) / (F(1.0) + F(5.0) * np.exp(F(-17.92) * cos_theta)))[..., None]
        return fit + ground

    def inscattering_rows(self, sun_dir, r0, elev, azimuth):
        """In-scattered spectral radiance (R, C, 4) for view rays at
        elevations elev (R,) and azimuths (C,) from height r0 (km from the
        centre) (Cycles' get_inscattering).  Along a ray everything but the
        sun's angle depends on the elevation alone (the origin is on the z
        axis), so altitudes, coefficients and the view transmittance are
        computed per (row, step) and only the sun terms per column."""
        rows = len(elev)
        d = np.stack([np.cos(elev)[:, None] * np.cos(azimuth)[None], np.cos(elev)[:, None] * np.sin(azimuth)[None],
                      np.broadcast_to(np.sin(elev)[:, None], (rows, len(azimuth)))], axis=-1).astype(F)
        origin = np.array([0.0, 0.0, r0], F)
        column = d[:, :1]                                                  # (R, 1, 3): the geometry of the row
        o = np.broadcast_to(origin, column.shape)
        atmos = ray_sphere_intersection(o, column, ATMOSPHERE_RADIUS)
        ground = ray_sphere_intersection(o, column, EARTH_RADIUS)
        t_d = np.where(ground < 0, atmos, ground)[:, 0]                   # (R,)
        dt = t_d / F(IN_SCATTERING_STEPS)
        t = (np.arange(IN_SCATTERING_STEPS, dtype=F)[None, :] + F(0.5)) * dt[:, None]   # (R, S)
        x = origin + column[:, 0, None, :] * t[..., None]                  # (R, S, 3)
        distance = np.sqrt(_dot(x, x))
        altitude = np.maximum(distance - EARTH_RADIUS, F(0.0))
        normalized = altitude / ATMOSPHERE_THICKNESS
        extinction, molecular, aerosol = self.coefficients(altitude)       # (R, S, 4)
        step_t = np.exp(-dt[:, None, None] * extinction)
        before = np.cumprod(np.concatenate([np.ones_like(step_t[:, :1]), step_t[:, :-1]], axis=1), axis=1,
                            dtype=F)
        weight = before * (F(1.0) - step_t) / np.maximum(extinction, F(1e-7)) * SUN_SPECTRAL_IRRADIANCE
        omega = TWO_PI * (F(1.0) - np.sqrt(np.maximum(F(1.0) - np.square(EARTH_RADIUS / distance), F(0.0))))
        ground_ratio = (INV_4PI * omega)[..., None] * (GROUND_ALBEDO * F(1.0 / np.pi)) * (
            self.ground_to_sun / self._to_sun(normalized))                 # (R, S, 4)
        # Per column: the phase functions and the sun's angle at each step.
        cos_view = d @ -sun_dir                                            # (R, C)
        molecular_phase = RAYLEIGH_PHASE_SCALE * (F(1.0) + cos_view * cos_view)
        den = F(1.0) + SQR_G + F(2.0) * G * cos_view
        aerosol_phase = INV_4PI * (F(1.0) - SQR_G) / (den * np.sqrt(den))
        along = (d @ sun_dir)[:, :, None] * t[:, None, :] + r0 * sun_dir[2]  # x_t . sun
        sample_cos = along / distance[:, None, :]                          # (R, C, S)
        to_sun = self._lookup_rows(sample_cos, normalized)                # (R, C, S, 4)
        ground_light = self._at_ground(sample_cos) * sample_cos[..., None]
        fit = F(1.0) / (F(1.0) + F(5.0) * np.exp(F(-17.92) * sample_cos))  # (R, C, S)
        # sum over steps of weight x (molecular (phase_m T + ms) + aerosol (phase_a T + ms)),
        # ms = MS_FIT fit + ground_ratio ground_light, with the factors that
        # depend on (row, step) only taken out of the per-column products.
        scattering = molecular + aerosol
        sum_t_molecular = np.einsum("rsk,rcsk->rck", weight * molecular, to_sun)
        sum_t_aerosol = np.einsum("rsk,rcsk->rck", weight * aerosol, to_sun)
        sum_fit = np.einsum("rsk,rcs->rck", weight * scattering, fit)
        sum_ground = np.einsum("rsk,rcsk->rck", weight * scattering * ground_ratio, ground_light)
        return (molecular_phase[..., None] * sum_t_molecular + aerosol_phase[..., None] * sum_t_aerosol
                + MS_FIT * sum_fit + sum_ground).astype(F)


def in_threads(fn, chunks):
    """fn over chunks on the machine's cores (NumPy releases the GIL), in order."""
    workers = max(1, min(len(chunks), os.cpu_count() or 1))
    if workers == 1:
        return [fn(c) for c in chunks]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, chunks))


def spectral_to_xyz(spectrum):
    return spectrum @ SPECTRAL_XYZ


def sky_table(size, elevation, altitude, air, aerosol, ozone):
    """The (H, W, 3) XYZ table, row 0 = elevation -90 degrees."""
    width, height = size
    atmosphere = Atmosphere(air, aerosol, ozone)
    atmosphere.precompute_lut()
    altitude = np.clip(F(altitude), F(1.0), F(99999.0)) / F(1000.0)
    sun_dir = sun_direction(np.cos(HALF_PI - F(elevation)))
    azimuth = TWO_PI * ((np.arange(width // 2, dtype=F) + F(0.5)) / F(width))
    l = (np.arange(height, dtype=F) + F(0.5)) / F(height) * F(2.0) - F(1.0)
    elev = np.copysign(l * l, l) * HALF_PI
    def rows(chunk):
        return spectral_to_xyz(atmosphere.inscattering_rows(sun_dir, EARTH_RADIUS + altitude, elev[chunk], azimuth))
    half = np.concatenate(in_threads(rows, np.array_split(np.arange(height), max(1, height // 4))))
    table = np.empty((height, width, 3), F)
    table[:, :width // 2] = half
    table[:, width // 2:] = half[:, ::-1]
    return table


def sun_pixels(elevation, diameter, altitude, air, aerosol, ozone):
    """XYZ radiance at the bottom and top edge of the disc."""
    atmosphere = Atmosphere(air, aerosol, ozone)
    altitude = np.clip(F(altitude), F(1.0), F(99999.0)) / F(1000.0)
    half = F(diameter) / F(2.0)
    solid_angle = TWO_PI * (F(1.0) - np.cos(half))
    normalized = altitude / ATMOSPHERE_THICKNESS

    def xyz(e):
        transmittance = atmosphere.transmittance(np.cos(HALF_PI - F(e))[None], np.array([normalized], F))[0]
        return spectral_to_xyz(SUN_SPECTRAL_IRRADIANCE * transmittance / solid_angle)
    return xyz(F(elevation) - half), xyz(F(elevation) + half)
