"""Panoramic cameras as Cycles 5.0 renders them (kernel/camera/projection.h,
camera.h's camera_sample_panorama, blender/camera.cpp's sync).

A panoramic camera maps the frame's (u, v) in [0, 1]^2 (u = x / width +
shift_x, v = y / height + shift_y, y up) to a direction in Cycles'
panorama space, where the view axis is +X and +Z is up (the mirror ball
looks down -Y).  ``to_local`` turns that space into Blender's camera
frame (looking down -Z, +Y up), as Cycles' blender_camera_matrix does.
Fisheye and mirror-ball frames have a rim: (u, v) beyond it has no
direction (a zero row), and Cycles traces nothing there (the sample counts,
its radiance is 0).  ``from_direction`` is the inverse (Cycles'
direction_to_panorama), which the Vector pass, the Window coordinate and
the rays' footprints use.
"""
import numpy as np

from .projection import direction_to_mirrorball

TYPES = ("EQUIRECTANGULAR", "EQUIANGULAR_CUBEMAP_FACE", "MIRRORBALL", "FISHEYE_EQUIDISTANT",
         "FISHEYE_EQUISOLID", "FISHEYE_LENS_POLYNOMIAL", "CENTRAL_CYLINDRICAL")


def _fisheye_direction(theta, u, v, r):
    """Cycles' fisheye_to_direction: polar angle theta about +X, azimuth from (u, v)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_phi = np.clip(np.where(r != 0.0, u / np.where(r != 0.0, r, 1.0), 0.0), -1.0, 1.0)
    phi = np.arccos(cos_phi)
    phi = np.where(v < 0.0, -phi, phi)
    s = np.sin(theta)
    return np.stack([np.cos(theta), -np.cos(phi) * s, np.sin(phi) * s], axis=1)


def _rim_uv(r, d, width, height):
    """(u, v) at radius r on the sensor along the direction's azimuth
    (safe_normalize of its (y, z): the view axis maps to the centre)."""
    yz = np.hypot(d[:, 1], d[:, 2])
    safe = np.where(yz > 0, yz, 1.0)
    ny, nz = np.where(yz > 0, d[:, 1] / safe, 0.0), np.where(yz > 0, d[:, 2] / safe, 0.0)
    return 0.5 - r * ny / width, r * nz / height + 0.5


def _unit(d):
    length = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.where(length > 0, length, 1.0)


class Panorama:
    """One panoramic camera's projection (engine.scene.Camera with kind 'PANO')."""

    def __init__(self, cam):
        self.type = cam.panorama_type
        if self.type not in TYPES:
            raise ValueError(f"unknown panorama type {self.type!r}")
        self.fov = float(cam.fisheye_fov)
        self.lens = float(cam.fisheye_lens)
        lat0, lat1 = (float(x) for x in cam.latitude)
        lon0, lon1 = (float(x) for x in cam.longitude)
        # Cycles' equirectangular_range
        self.equirect = (lon0 - lon1, -lon0, lat0 - lat1, -lat0 + 0.5 * np.pi)
        self.poly = tuple(float(k) for k in cam.fisheye_polynomial)
        u0, u1, v0, v1, radius = (float(x) for x in cam.cylinder)
        self.cylinder = (-u0, -u1, v0 / radius, v1 / radius)    # Cycles' central_cylindrical_range
        self.sensor = fisheye_sensor(cam)
        self.shift = (float(cam.shift_x), float(cam.shift_y))

    # -- (u, v) -> direction --------------------------------------------------

    def to_direction(self, u, v):
        """(N, 3) directions in panorama space (unit length but the central
        cylinder's), zero rows beyond a fisheye's or the ball's rim."""
        u = np.asarray(u, np.float64)
        v = np.asarray(v, np.float64)
        kind = self.type
        if kind == "EQUIRECTANGULAR":
            rx, ry, rz, rw = self.equirect
            phi, theta = rx * u + ry, rz * v + rw
            return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
        if kind == "EQUIANGULAR_CUBEMAP_FACE":
            return _unit(np.stack([np.ones_like(u), np.tan((0.5 - u) * 0.5 * np.pi),
                                   np.tan((v - 0.5) * 0.5 * np.pi)], axis=1))
        if kind == "MIRRORBALL":
            return self._mirrorball(u, v)
        if kind == "CENTRAL_CYLINDRICAL":
            rx, ry, rz, rw = self.cylinder
            theta, z = rx + (ry - rx) * u, rz + (rw - rz) * v
            return np.stack([np.cos(theta), np.sin(theta), z], axis=1)
        if kind == "FISHEYE_EQUIDISTANT":
            x, y = (u - 0.5) * 2.0, (v - 0.5) * 2.0
            r = np.hypot(x, y)
            return np.where((r <= 1.0)[:, None], _fisheye_direction(r * self.fov * 0.5, x, y, r), 0.0)
        width, height = self.sensor
        x, y = (u - 0.5) * width, (v - 0.5) * height
        r = np.hypot(x, y)
        if kind == "FISHEYE_LENS_POLYNOMIAL":
            k0, k1, k2, k3, k4 = self.poly
            theta = -(k0 + r * (k1 + r * (k2 + r * (k3 + r * k4))))
            inside = np.abs(theta) <= 0.5 * self.fov
        else:   # FISHEYE_EQUISOLID
            inside = r <= 2.0 * self.lens * np.sin(self.fov * 0.25)
            theta = 2.0 * np.arcsin(np.clip(r / (2.0 * self.lens), -1.0, 1.0))
        return np.where(inside[:, None], _fisheye_direction(theta, x, y, r), 0.0)

    @staticmethod
    def _mirrorball(u, v):
        x, z = 2.0 * u - 1.0, 2.0 * v - 1.0
        inside = x * x + z * z <= 1.0
        y = -np.sqrt(np.maximum(1.0 - x * x - z * z, 0.0))
        n = np.stack([x, y, z], axis=1)
        # The reflection of I = -Y about the ball's normal: 2 (n . I) n - I.
        d = 2.0 * (-y)[:, None] * n
        d[:, 1] += 1.0
        return np.where(inside[:, None], d, 0.0)

    # -- direction -> (u, v) --------------------------------------------------

    def from_direction(self, d):
        """(u, v) of panorama-space directions (N, 3) of any length (Cycles'
        direction_to_panorama of the normalized direction), without the shift."""
        d = _unit(np.asarray(d, np.float64))
        kind = self.type
        x, y, z = d[:, 0], d[:, 1], d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if kind == "EQUIRECTANGULAR":
                rx, ry, rz, rw = self.equirect
                return (np.arctan2(y, x) - ry) / rx, (np.arccos(np.clip(z, -1.0, 1.0)) - rw) / rz
            if kind == "EQUIANGULAR_CUBEMAP_FACE":
                return 0.5 - np.arctan2(y, x) * 2.0 / np.pi, np.arctan2(z, x) * 2.0 / np.pi + 0.5
            if kind == "MIRRORBALL":
                return self._to_mirrorball(d)
            if kind == "CENTRAL_CYLINDRICAL":
                rx, ry, rz, rw = self.cylinder
                return (np.arctan2(y, x) - rx) / (ry - rx), (z / np.hypot(x, y) - rz) / (rw - rz)
            if kind == "FISHEYE_EQUIDISTANT":
                return _rim_uv(np.arctan2(np.hypot(y, z), x) / self.fov, d, 1.0, 1.0)
            width, height = self.sensor
            theta = np.arccos(np.clip(x, -1.0, 1.0))
            if kind == "FISHEYE_LENS_POLYNOMIAL":
                return _rim_uv(self._polynomial_radius(-theta), d, width, height)
            return _rim_uv(2.0 * self.lens * np.sin(theta * 0.5), d, width, height)

    def _polynomial_radius(self, theta):
        """The sensor radius r whose polynomial angle is theta: Newton's
        method from the linear term's root, as Cycles (20 steps at most,
        stopping where a step moves r by less than 1e-6)."""
        k0, k1, k2, k3, k4 = self.poly
        r = (theta - k0) / k1
        moving = np.ones(len(r), bool)
        for _ in range(20):
            f = theta - (k0 + r * (k1 + r * (k2 + r * (k3 + r * k4))))
            df = k1 + r * (2.0 * k2 + r * (3.0 * k3 + r * 4.0 * k4))
            step = np.where(moving, f / df, 0.0)
            r = r + step
            moving &= np.abs(step) >= 1e-6
            if not moving.any():
                break
        return r

    @staticmethod
    def _to_mirrorball(d):
        return direction_to_mirrorball(d)

    # -- frames ---------------------------------------------------------------

    def to_local(self, p):
        """Panorama-space vectors (N, 3) in Blender's camera frame."""
        if self.type == "MIRRORBALL":
            return np.stack([p[:, 0], p[:, 2], p[:, 1]], axis=1)
        return np.stack([-p[:, 1], p[:, 2], -p[:, 0]], axis=1)

    def from_local(self, q):
        """Blender camera-frame vectors (N, 3) in panorama space."""
        if self.type == "MIRRORBALL":
            return np.stack([q[:, 0], q[:, 2], q[:, 1]], axis=1)
        return np.stack([-q[:, 2], -q[:, 0], q[:, 1]], axis=1)

    def aperture(self, p, lens_x, lens_y, focus):
        """Cycles' panoramic depth of field: rays through lens points
        (lens_x, lens_y), already scaled by the aperture, on the plane
        through the camera perpendicular to each direction p, meeting the
        unshifted ray at ``focus`` along it.  Returns (origins, directions)
        in panorama space."""
        dfocus = _unit(p)
        # U: +X made perpendicular to the direction (the view axis itself
        # has none: any perpendicular serves, a zero-measure set).
        u = np.array([1.0, 0.0, 0.0]) - dfocus[:, :1] * dfocus
        flat = np.linalg.norm(u, axis=1) < 1e-12
        u[flat] = (0.0, 1.0, 0.0)
        u = _unit(u)
        w = np.cross(dfocus, u)
        origin = u * lens_x[:, None] + w * lens_y[:, None]
        return origin, _unit(dfocus * focus - origin)


def fisheye_sensor(cam):
    """(width, height) in mm of the equisolid and polynomial fisheyes'
    sensor: the fitted side is the camera's sensor size, the other follows
    the frame's aspect (Cycles' blender_camera_sync; AUTO fits the wider side
    and always reads sensor_width)."""
    xr = float(cam.resolution[0]) * float(cam.pixel_aspect[0])
    yr = float(cam.resolution[1]) * float(cam.pixel_aspect[1])
    fit = cam.sensor_fit
    horizontal = xr > yr if fit == "AUTO" else fit == "HORIZONTAL"
    size = cam.sensor_height if fit == "VERTICAL" else cam.sensor_width
    return (size, size * yr / xr) if horizontal else (size * xr / yr, size)
