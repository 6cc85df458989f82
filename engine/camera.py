"""Camera rays with Blender's framing rules, and the pixel filter.

The view plane follows Blender's ``BKE_camera_params_compute_viewplane``:
sensor fit, shift, pixel aspect and orthographic scale all give the same
framing as Cycles.  Depth of field is Cycles' thin lens (uniform disk, focus
plane at ``focus_distance`` along the view axis); clipping is measured along
the view axis as Cycles does.
"""
import numpy as np

from . import kernels
from .motion import decompose, transform_at
from . import stereo
from .panorama import Panorama
from .stereo import Stereo
from .sampling import concentric_disk, upper_bound
from .shutter import Shutter
from .vec import column

FILTER_TABLE_SIZE = 4096


def _blackman_harris(v, width):
    x = 2.0 * np.pi * (v / width + 0.5)
    return 0.35875 - 0.48829 * np.cos(x) + 0.14128 * np.cos(2 * x) - 0.01168 * np.cos(3 * x)


def _filter_sample_numpy(u, guide, cdf, slope, edges, out):
    sign = np.where(u < 0.5, -1.0, 1.0)
    v = np.where(u < 0.5, 2.0 * u, 2.0 * u - 1.0)
    cell = np.minimum((v * FILTER_TABLE_SIZE).astype(np.int64), FILTER_TABLE_SIZE - 1)
    j = guide[cell]
    span = guide[cell + 1] - j
    j = np.minimum(j + ((span == 1) & (cdf[np.minimum(j + 1, FILTER_TABLE_SIZE)] <= v)), FILTER_TABLE_SIZE - 1)
    wide = np.flatnonzero(span > 1)   # cells across many tiny bins (filter tails): rare
    if len(wide):
        j[wide] = _last_bin_at_most(cdf, v[wide])
    out[:] = sign * (slope[j] * (v - cdf[j]) + edges[j])


def _last_bin_at_most(cdf, v):
    """The last bin j with cdf[j] <= v (the bin np.interp uses)."""
    return np.minimum(np.searchsorted(cdf, v, side="right") - 1, FILTER_TABLE_SIZE - 1)


@kernels.loop_kernel("void(float64[:], int64[::1], float64[::1], float64[::1], float64[::1], float64[::1])",
                     _filter_sample_numpy)
def _filter_sample(u, guide, cdf, slope, edges, out):
    last = FILTER_TABLE_SIZE - 1
    for i in range(len(u)):
        x = u[i]
        sign = -1.0 if x < 0.5 else 1.0
        v = 2.0 * x if x < 0.5 else 2.0 * x - 1.0
        cell = min(np.int64(v * FILTER_TABLE_SIZE), last)
        j = guide[cell]
        span = guide[cell + 1] - j
        if span > 1:
            j = min(upper_bound(cdf, v, 0, len(cdf)) - 1, last)
        elif span == 1 and cdf[min(j + 1, FILTER_TABLE_SIZE)] <= v:
            j = min(j + 1, last)
        else:
            j = min(j, last)
        out[i] = sign * (slope[j] * (v - cdf[j]) + edges[j])


class PixelFilter:
    """Separable pixel filter sampled by inverse CDF (filter importance
    sampling): each camera sample lands in one pixel with weight 1.

    Supports as in Cycles: box spans ``width``; Gaussian spans 3 x width
    (sigma = width / 4); Blackman-Harris spans 2 x width.
    """

    def __init__(self, kind="BLACKMAN_HARRIS", width=1.5):
        width = max(float(width), 1e-6)
        if kind == "BOX":
            support = width
            func = lambda v: np.ones_like(v)
        elif kind == "GAUSSIAN":
            support = 3.0 * width
            func = lambda v: np.exp(-2.0 * (v * 6.0 / support) ** 2)
        elif kind == "BLACKMAN_HARRIS":
            support = 2.0 * width
            func = lambda v: _blackman_harris(v, support)
        else:
            raise ValueError(f"unknown pixel filter {kind!r}")
        self.kind = kind
        self.radius = 0.5 * support
        # Piecewise-constant density over |x| in [0, radius].
        edges = np.linspace(0.0, self.radius, FILTER_TABLE_SIZE + 1)
        mids = 0.5 * (edges[:-1] + edges[1:])
        values = np.maximum(func(mids), 0.0)
        self.edges = edges
        self.values = values
        cdf = np.concatenate([[0.0], np.cumsum(values)])
        self.cdf = cdf / cdf[-1]
        self.norm = 2.0 * cdf[-1] * (self.radius / FILTER_TABLE_SIZE)  # integral over [-r, r]
        self.slope = np.diff(self.edges) / np.where(np.diff(self.cdf) > 0, np.diff(self.cdf), 1.0)
        # Guide table: the bin holding v = g / FILTER_TABLE_SIZE.  A v in
        # cell g lies in bin guide[g] or a later one up to guide[g + 1].
        self.guide = _last_bin_at_most(self.cdf, np.arange(FILTER_TABLE_SIZE + 1) / FILTER_TABLE_SIZE)

    def sample(self, u):
        """Offsets in pixels from one uniform per sample (sign from its low
        bit).  The inverse CDF as np.interp(v, cdf, edges) computes it, bit
        for bit, but the bin comes from the guide table: one comparison for
        nearly every v instead of a binary search over 4096 bins."""
        u = np.atleast_1d(u)
        u = column(u, len(u), np.float64)
        out = np.empty(len(u))
        _filter_sample(u, self.guide, self.cdf, self.slope, self.edges, out)
        return out

    def pdf(self, x):
        """Density of ``sample`` at offset x (1D)."""
        ax = np.abs(x)
        idx = np.clip((ax / self.radius * FILTER_TABLE_SIZE).astype(np.int64), 0, FILTER_TABLE_SIZE - 1)
        return np.where(ax <= self.radius, self.values[idx] / self.norm, 0.0)


def border_window(cam):
    """(x0, y0, w, h) of the rendered window in full-frame pixels, y from the bottom."""
    full_w, full_h = int(cam.resolution[0]), int(cam.resolution[1])
    if cam.border is None:
        return 0, 0, full_w, full_h
    bx0, bx1, by0, by1 = cam.border
    x0 = int(np.floor(bx0 * full_w + 0.5))
    x1 = int(np.floor(bx1 * full_w + 0.5))
    y0 = int(np.floor(by0 * full_h + 0.5))
    y1 = int(np.floor(by1 * full_h + 0.5))
    x0, x1 = max(0, min(x0, full_w)), max(0, min(x1, full_w))
    y0, y1 = max(0, min(y0, full_h)), max(0, min(y1, full_h))
    if x1 <= x0 or y1 <= y0:
        raise ValueError("render border is empty")
    return x0, y0, x1 - x0, y1 - y0


def view_plane(cam):
    """(xmin, ymin, pixel_w, pixel_h) of the full frame at unit distance
    (perspective) or in metres (orthographic), Blender's rules."""
    winx, winy = float(cam.resolution[0]), float(cam.resolution[1])
    xasp, yasp = float(cam.pixel_aspect[0]), float(cam.pixel_aspect[1])
    ycor = yasp / xasp
    fit = cam.sensor_fit
    if cam.kind == "ORTHO":
        pixsize = cam.ortho_scale
    else:
        sensor = cam.sensor_height if fit == "VERTICAL" else cam.sensor_width
        pixsize = sensor / cam.lens
    if fit == "AUTO":
        fit = "HORIZONTAL" if xasp * winx >= yasp * winy else "VERTICAL"
    viewfac = winx if fit == "HORIZONTAL" else ycor * winy
    pixsize /= viewfac
    xmin = -0.5 * winx + cam.shift_x * viewfac
    ymin = -0.5 * ycor * winy + cam.shift_y * viewfac
    return xmin * pixsize, ymin * pixsize, pixsize, pixsize * ycor


def _zoom_steps(cam):
    """The view plane's scale at the shutter's start and end relative to
    its centre (tan of the half field of view goes as 1 / lens), or None:
    Cycles interpolates the ray's point on the near plane linearly between
    them (perspective only, its use_perspective_motion)."""
    lenses = getattr(cam, "lens_motion", None)
    if lenses is None or cam.kind != "PERSP":
        return None
    pre, post = (float(x) for x in lenses)
    if not all(np.isfinite(x) and x > 0 for x in (pre, post)) or (pre == cam.lens and post == cam.lens):
        return None
    return cam.lens / pre, cam.lens / post


def _zoom_at(zoom, time):
    pre, post = zoom
    time = np.asarray(time, np.float64)
    return np.where(time < 0.5, pre + (1.0 - pre) * (2.0 * time), 1.0 + (post - 1.0) * (2.0 * time - 1.0))


class CameraModel:
    def __init__(self, cam, pixel_filter):
        self.cam = cam
        self.filter = pixel_filter
        m = np.asarray(cam.matrix, dtype=np.float64)
        rot = m[:3, :3]
        # Blender cameras may carry scale; rays need a rigid frame.
        self.rot = rot / np.linalg.norm(rot, axis=0, keepdims=True)
        self.pos = m[:3, 3]
        self.x0, self.y0, self.width, self.height = border_window(cam)
        self.xmin, self.ymin, self.pw, self.ph = view_plane(cam)
        self.aperture = cam.aperture_radius
        if self.aperture <= 0 and cam.fstop > 0:
            self.aperture = cam.lens * 1e-3 / (2.0 * cam.fstop)
        motion = getattr(cam, "motion", None)
        # Camera motion blur: the decomposed camera-to-world at the shutter's steps.
        self.motion = None if motion is None else decompose(motion)
        self.shutter = Shutter(cam)
        self.zoom = _zoom_steps(cam)
        self.pano = Panorama(cam) if cam.kind == "PANO" else None
        offset = float(getattr(cam, "stereo_offset", 0.0))
        # Spherical stereo (Cycles: panoramic and perspective cameras only).
        self.stereo = (Stereo(offset, float(cam.stereo_convergence), tuple(cam.stereo_pole_merge))
                       if offset != 0.0 and cam.kind != "ORTHO" else None)

    @property
    def forward(self):
        return -self.rot[:, 2]

    def z_depth(self, p):
        """The Depth pass at world points ``p`` (Cycles' camera_z_depth):
        along the view axis for perspective and orthographic cameras, the
        distance from the camera for panoramic ones."""
        if self.pano is not None:
            return np.linalg.norm(p - self.pos, axis=-1)
        return (p - self.pos) @ self.forward

    def generate(self, pixel, u_fx, u_fy, u_l1, u_l2, time=None):
        """Rays for window pixel indices (row-major, row 0 at the top), from
        the camera where it is at each ray's shutter ``time`` when it moves.

        Returns world origins, unit directions and the distance to the far clip.
        """
        fx, fy = self._raster(pixel, u_fx, u_fy)
        if self.pano is not None:
            o, d = self._panoramic(fx, fy, u_l1, u_l2)
            return self._to_world(o, d, time) + (np.full(len(d), self.cam.clip_end - self.cam.clip_start),)
        sx = self.xmin + fx * self.pw
        sy = self.ymin + fy * self.ph
        if self.zoom is not None and time is not None:
            scale = _zoom_at(self.zoom, time)
            sx, sy = sx * scale, sy * scale
        n = len(pixel)
        if self.cam.kind == "ORTHO":
            o = np.stack([sx, sy, np.zeros(n)], axis=1)
            d = np.tile([0.0, 0.0, -1.0], (n, 1))
        else:
            o = np.zeros((n, 3))
            d = np.stack([sx, sy, -np.ones(n)], axis=1)
        if self.aperture > 0:
            o, d = self._thin_lens(o, d, u_l1, u_l2)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        # Clip distances are along the view axis, as in Cycles.
        inv_z = 1.0 / np.maximum(-d[:, 2], 1e-12)
        tmax = (self.cam.clip_end - self.cam.clip_start) * inv_z
        if self.stereo is not None:   # Cycles: in world space, before the near clip
            o, d = stereo.transform(self.stereo, *self._to_world(o, d, time))
            return o + d * (self.cam.clip_start * inv_z)[:, None], d, tmax
        o = o + d * (self.cam.clip_start * inv_z)[:, None]
        return self._to_world(o, d, time) + (tmax,)

    def _raster(self, pixel, u_fx, u_fy):
        """Full-frame raster positions (y up) of camera samples in window pixels."""
        px = pixel % self.width
        py = pixel // self.width
        fx = self.x0 + px + 0.5 + self.filter.sample(u_fx)
        fy = self.y0 + (self.height - 1 - py) + 0.5 + self.filter.sample(u_fy)
        return fx, fy

    def _to_world(self, o, d, time):
        """Camera-frame rays in the world, by the camera at ``time`` when it moves."""
        if self.motion is not None and time is not None:
            rot, pos = transform_at(self.motion, time)
            rot = rot / np.linalg.norm(rot, axis=1, keepdims=True)   # rigid, as self.rot
            return np.einsum("nij,nj->ni", rot, o) + pos, np.einsum("nij,nj->ni", rot, d)
        return o @ self.rot.T + self.pos, d @ self.rot.T

    def _pano_uv(self, fx, fy):
        full_w, full_h = float(self.cam.resolution[0]), float(self.cam.resolution[1])
        return fx / full_w + self.pano.shift[0], fy / full_h + self.pano.shift[1]

    def _panoramic(self, fx, fy, u_l1, u_l2):
        """Camera-frame rays of a panoramic camera (Cycles'
        camera_sample_panorama), starting at the near clip along the ray
        (not the view axis).  Samples beyond a fisheye's rim get the view
        axis: ``outside`` tells them, and they are not traced."""
        p = self.pano.to_direction(*self._pano_uv(fx, fy))
        p[~p.any(axis=1)] = self.pano.from_local(np.array([[0.0, 0.0, -1.0]]))[0]
        o = np.zeros_like(p)
        if self.aperture > 0:
            lx, ly = concentric_disk(u_l1, u_l2)
            o, p = self.pano.aperture(p, lx * self.aperture, ly * self.aperture, self.cam.focus_distance)
        if self.stereo is not None:   # Cycles: in the panorama's camera space (z up)
            o, p = stereo.transform(self.stereo, o, p / np.linalg.norm(p, axis=1, keepdims=True))
        o, d = self.pano.to_local(o), self.pano.to_local(p)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return o + d * self.cam.clip_start, d

    def outside(self, pixel, u_fx, u_fy):
        """Which camera samples fall beyond a fisheye's or mirror ball's rim
        (all False for other cameras): Cycles counts them with nothing
        written (a zero throughput), so they add 0 to the pixel's mean."""
        if self.pano is None:
            return np.zeros(len(pixel), bool)
        p = self.pano.to_direction(*self._pano_uv(*self._raster(pixel, u_fx, u_fy)))
        return ~p.any(axis=1)

    def spread(self, d):
        """Cycles' compact differentials of camera rays along world directions
        d (N, 3), per pixel: (dP at the origin, dD per unit distance), what
        a hit's sd->dP = dP + t dD is made of (lens and zoom left out)."""
        c = np.asarray(d, np.float64) @ self.rot
        n = len(c)
        if self.pano is not None:
            return np.zeros(n), self._pano_spread(c)
        if self.cam.kind == "ORTHO":
            return np.full(n, 0.5 * (self.pw + self.ph)), np.zeros(n)
        z = np.maximum(-c[:, 2], 1e-12)
        sx, sy = c[:, 0] / z, c[:, 1] / z
        l2 = sx * sx + sy * sy + 1.0
        # |d normalize(P) / dx| = sqrt(|P|^2 - x^2) / |P|^2 for P = (x, y, -1)
        return np.zeros(n), 0.5 * (self.pw * np.sqrt(sy * sy + 1.0) + self.ph * np.sqrt(sx * sx + 1.0)) / l2

    def _pano_spread(self, c):
        """Cycles' dD of panoramic rays along camera-frame directions c: the
        mean length of the unit direction's change one pixel right and one
        up (one pixel back where that leaves the rim; 0 where neither is
        defined)."""
        p = self.pano.from_local(c)
        u, v = self.pano.from_direction(p)
        centre = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-300)
        step = 1.0 / float(self.cam.resolution[0]), 1.0 / float(self.cam.resolution[1])
        total = np.zeros(len(c))
        for du, dv in ((step[0], 0.0), (0.0, step[1])):
            done = np.zeros(len(c), bool)
            for sign in (1.0, -1.0):
                q = self.pano.to_direction(u + sign * du, v + sign * dv)
                length = np.linalg.norm(q, axis=1)
                ok = (length > 0) & ~done
                total[ok] += np.linalg.norm(q[ok] / length[ok, None] - centre[ok], axis=1)
                done |= ok
        return np.where(np.isfinite(total), 0.5 * total, 0.0)

    def origin_spread(self, d):
        """``spread`` at the rays' origins on the near clip plane, as Cycles
        moves ray->dP by nearclip * ray->dD there (along the ray for a
        panoramic camera)."""
        dp, dd = self.spread(d)
        if self.pano is not None:
            return dp + dd * self.cam.clip_start, dd
        z = np.maximum(-(np.asarray(d, np.float64) @ self.rot)[:, 2], 1e-12)
        return dp + dd * (self.cam.clip_start / z), dd

    def shutter_times(self, pixel, u):
        """Each camera sample's time in the shutter from its number ``u``
        (the shutter curve, and the rolling shutter by the pixel's row)."""
        row = self.y0 + (self.height - 1 - np.asarray(pixel) // self.width)
        return self.shutter.times(u, row)

    def _thin_lens(self, o, d, u1, u2):
        lx, ly = concentric_disk(u1, u2)
        focus = o + d * (self.cam.focus_distance / -d[:, 2])[:, None]
        o = o + np.stack([lx * self.aperture, ly * self.aperture, np.zeros(len(lx))], axis=1)
        return o, focus - o
