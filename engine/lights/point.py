"""Point and spot lights: a sphere of radius r (sampled by its cone; from
inside, the uniform sphere to its far side, as Cycles 5.0 for volumes), with
soft falloff a disk of radius r facing the shading point (Cycles), or with
r = 0 a delta light of intensity P / (4 pi).  Radiance P / (pi * 4 pi r^2);
a spot multiplies it by smoothstep((cos - cos_half) / ((1 - cos_half) *
blend)) towards the shading point."""
import numpy as np

from ..geometry import visibility_bits
from ..kernels import helper, loop_kernel
from ..lightbounds import Bounds
from ..lightproxy import box_corners, proxy_margin
from ..sampling import (TWO_PI, concentric_disk, cone_point, disk_point, sin_sq_to_one_minus_cos, uniform_cone,
                        uniform_cone_pdf)
from ..scene import PointLight, Scene, SceneError, SpotLight
from ..vec import column, dot, frame, frame_of, rows3, to_world
from .common import (Falloff, check_direction, check_falloff, check_rgb, check_size, selection_power,
                     smoothstep, unit)
from .registry import RAY, LightDef, LightExample, LightTable, register
from .shader import LightShaders, checker_of, path_rows, spread_directions

POINT = 0
# Half-angle of emission beyond a spot cone: its light ends at the cone edge.
SPOT_MARGIN = 1e-3
# Solid-angle pdf of a light sample (and of a hit) from inside a sphere
# light: Cycles 5.0 samples the uniform sphere there for points with
# transmission (media); Ember does so at every inside point (its cosine
# hemisphere about N for opaque surfaces differs in noise only).
INSIDE_PDF = 1.0 / (4.0 * np.pi)


class PointLights(LightTable):
    """Point and spot lights (sphere, soft-falloff disk, or delta)."""

    def __init__(self, lights, camera=None):
        self.count = len(lights)
        self.lights = list(lights)
        self.falloff = Falloff.of(lights)
        self.shaders = LightShaders.of(lights, [_matrix(l) for l in lights], camera)
        self.pos = np.array([l.position for l in lights], float).reshape(-1, 3)
        self.radius = np.array([max(0.0, l.radius) for l in lights], float)
        self.sphere = np.array([not l.soft_falloff for l in lights], bool)
        self.visible_camera = [l.visible_camera for l in lights]
        pw = np.array([l.power for l in lights], float).reshape(-1, 3)
        area = 4.0 * np.pi * self.radius ** 2
        # Cycles: eval_fac = 1 / (pi * area); area 0 counts as 4 (delta).
        self.L = pw / (np.pi * np.where(area > 0, area, 4.0))[:, None]
        self.power_rgb = pw
        spot = [isinstance(l, SpotLight) for l in lights]
        self.spot = np.array(spot, bool)
        self.dir = np.array([unit(l.direction) if s else (0, 0, -1) for l, s in zip(lights, spot)],
                            float).reshape(-1, 3)
        half = np.array([0.5 * l.spot_size if s else np.pi for l, s in zip(lights, spot)], float)
        self.cos_half = np.cos(half)
        with np.errstate(divide="ignore"):
            self.half_cot = np.where(self.spot, 0.5 / np.tan(half), 0.0)   # Cycles' half_cot_half_spot_angle
        blend = np.array([l.spot_blend if s else 0.0 for l, s in zip(lights, spot)], float)
        with np.errstate(divide="ignore"):
            self.smooth = 1.0 / ((1.0 - self.cos_half) * blend)

    def power(self, radius):
        if not self.count:
            return []
        return selection_power(self.power_rgb) * np.array([self._selection_scale(j) for j in range(self.count)])

    def _selection_scale(self, j, count=256):
        """The light's tree averaged over the directions it emits to (1 without one)."""
        if self.shaders is None:
            return 1.0
        wo = spread_directions(count)
        q = self.pos[j] + wo * self.radius[j]
        return self.shaders.selection_scale(j, q, wo, wo, self._shader_uv(np.full(count, j), wo, wo))

    def is_delta(self):
        return self.radius <= 0

    def visibility(self):
        return np.array([visibility_bits(l) for l in self.lights], np.uint8)

    def bounds(self, j, phi):
        r = self.radius[j]
        c = self.pos[j]
        if self.spot[j]:
            # Emission inside the cone only, from anywhere on the sphere/disk:
            # the box's angular size adds that spread at the shading point.
            return Bounds(c - r, c + r, phi, self.dir[j], self.cos_half[j], np.cos(SPOT_MARGIN), False)
        return Bounds(c - r, c + r, phi, (0.0, 0.0, 1.0), -1.0, 0.0, False)

    def proxy_boxes(self):
        """Boxes around sphere and disk lights (a disk faces the shading point,
        so it lies in the sphere of its radius too); lights of radius 0 cannot
        be hit and get none."""
        boxes = []
        for j in range(self.count):
            r = self.radius[j]
            if r > 0:
                half = r + proxy_margin(self.pos[j], r)
                boxes.append(box_corners(self.pos[j], np.eye(3) * half))
        return boxes

    def _spot_factor(self, j, to_p):
        """Spot attenuation for unit directions from the light towards points."""
        cos = to_p @ self.dir[j] if np.ndim(j) == 0 else dot(to_p, self.dir[j])
        with np.errstate(invalid="ignore"):
            x = (cos - self.cos_half[j]) * self.smooth[j]  # inf * 0 at a hard edge
        x = np.where(np.isnan(x), 0.0, x)
        return np.where(self.spot[j], smoothstep(x), 1.0)

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        n = len(p)
        wi, t, le, pdf, delta = np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n, bool)
        _point_sample(column(j, n, np.int64), rows3(p)[0],
                      column(u1, n, np.float64), column(u2, n, np.float64), self.pos, self.radius, self.sphere,
                      self.L, self.spot, self.dir, self.cos_half, self.smooth, wi, t, le, pdf, delta)
        if self.shaders is not None:
            le *= self._shader(np.broadcast_to(j, (n,)), p + wi * t[:, None], -wi, t, path_rows(out.path, idx))
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, t, le
        out.pdf[idx], out.delta[idx] = pdf, delta

    def _shader(self, j, q, wo, dist=None, path=None):
        """The lights' node trees at points q seen along Incoming wo: N is the
        sphere's normal at q, or (soft falloff, delta) Incoming itself, the disk
        facing the shading point; UV = Parametric = map_to_sphere of N in
        object space for point lights, Cycles' spot_light_uv of Incoming in
        the spot's axes for spots (as Cycles 5.0 renders them)."""
        sphere = (self.sphere[j] & (self.radius[j] > 0))[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            radial = (q - self.pos[j]) / np.maximum(self.radius[j], 1e-300)[:, None]
        n = np.where(sphere, radial, wo)
        return self.shaders.factor(j, q, n, wo, self._shader_uv(j, n, wo), dist, path)

    def _shader_uv(self, j, n, wo):
        uv = self.shaders.sphere_uv(j, n)
        spot = np.flatnonzero(self.spot[j])
        if len(spot):
            uv[spot] = self._spot_uv(j[spot], wo[spot])
        return uv

    def _spot_uv(self, j, wo):
        """Cycles' spot_light_uv: the direction in the spot's unit axes (z
        along the cone) projected so that the cone spans [0, 1]^2."""
        axes = self.shaders.matrix[j][:, :3, :3]
        axes = axes / np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-300)
        x, y = np.einsum("nij,ni->nj", axes, wo)[:, :2].T
        z = -np.einsum("ni,ni->n", axes[:, :, 2], wo)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(z > 0, self.half_cot[j] / np.where(z > 0, z, 1.0), 0.0)
        return np.stack([x * f + 0.5, y * f + 0.5], axis=1)

    def nearest(self, o, d, t, ray, bits, camera, path=None, tmin=None):
        """The nearest of these lights each ray meets past tmin (None: 0) and
        before t: t (updated in place), the hit distance (inf = none), light
        index (-1), Le and pdf.  ray: per-ray VIS_* bits or None (every ray sees every light);
        bits: the lights' VIS_* bits; camera: camera rays, which see only
        lights with visible_camera; path: what the node trees read of the
        rays' paths (shader.emission_path) or None.  All lights in one
        compiled loop."""
        n = len(o)
        light_bits = bits if ray is not None else np.full(self.count, 0xFF)
        if camera:
            light_bits = np.where(self.visible_camera, light_bits, 0)
        ray_bits = ray if ray is not None else np.full(n, 0xFF, np.uint8)
        hit_t, index, pdf = np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n)
        tmin = np.zeros(n) if tmin is None else np.array(np.broadcast_to(tmin, (n,)), np.float64)
        _nearest_point(np.ascontiguousarray(o, np.float64), np.ascontiguousarray(d, np.float64), t, tmin,
                       np.ascontiguousarray(ray_bits, np.uint8), self.pos, self.radius, self.sphere,
                       np.ascontiguousarray(light_bits, np.uint8), hit_t, index, pdf)
        Le = np.zeros((n, 3))
        rows = np.flatnonzero(index >= 0)
        if len(rows):
            j = index[rows]
            # No spot attenuation from inside a sphere (Cycles: d_sq > r_sq only).
            oc = o[rows] - self.pos[j]
            inside = self.sphere[j] & (dot(oc, oc) <= self.radius[j] ** 2)
            Le[rows] = self.L[j] * np.where(inside, 1.0, self._spot_factor(j, -d[rows]))[:, None]
            if self.shaders is not None:
                Le[rows] *= self._shader(j, o[rows] + d[rows] * hit_t[rows, None], -d[rows], hit_t[rows],
                                         path_rows(path, rows))
        return hit_t, index, Le, pdf


def _point_sample_numpy(j, p, u1, u2, pos, radius, sphere, L, spot, sdir, cos_half, smooth,
                        wi_out, t_out, le_out, pdf_out, delta_out):
    c = pos[j]
    r = radius[j]
    dvec = p - c
    d2 = dot(dvec, dvec)
    dist = np.sqrt(d2)
    light_n = dvec / np.maximum(dist, 1e-30)[:, None]
    wi = -light_n
    t = dist.copy()
    pdf = np.ones(len(p))
    delta = r <= 0
    Le = L[j] / np.where(delta, np.maximum(d2, 1e-30), 1.0)[:, None]
    sph = sphere[j] & ~delta
    inside = sph & (d2 <= r * r)
    s = np.nonzero(sph & ~inside)[0]
    if len(s):
        omc = sin_sq_to_one_minus_cos(r[s] ** 2 / d2[s])
        local, pdf[s] = uniform_cone(u1[s], u2[s], omc)
        tt, bb = frame(-light_n[s])
        wi[s] = to_world(local, tt, bb, -light_n[s])
        cos_t = local[:, 2]
        t[s] = dist[s] * cos_t - np.sqrt(np.maximum(0.0, r[s] ** 2 - d2[s] * (1.0 - cos_t ** 2)))
    dsk = np.nonzero(~sphere[j] & ~delta)[0]
    if len(dsk):
        x, y = concentric_disk(u1[dsk], u2[dsk])
        tt, bb = frame(light_n[dsk])
        q = c[dsk] + (x[:, None] * tt + y[:, None] * bb) * r[dsk, None]
        v = q - p[dsk]
        t[dsk] = np.linalg.norm(v, axis=1)
        wi[dsk] = v / np.maximum(t[dsk], 1e-30)[:, None]
        cos_l = np.abs(dot(light_n[dsk], -wi[dsk]))
        pdf[dsk] = t[dsk] ** 2 / (np.pi * r[dsk] ** 2 * np.maximum(cos_l, 1e-30))
    s = np.nonzero(inside)[0]
    if len(s):
        # Cycles 5.0 inside a sphere (points in media, SD_BSDF_HAS_TRANSMISSION):
        # the uniform sphere, t to the far side by the law of cosines.
        wi[s], pdf[s] = _inside_direction(u1[s], u2[s])
        cos_t = dot(wi[s], -light_n[s])
        t[s] = dist[s] * cos_t + np.sqrt(np.maximum(0.0, r[s] ** 2 - d2[s] * (1.0 - cos_t ** 2)))
    # Spot attenuation towards the point (vec.dot's order on unit-stride rows);
    # none inside the sphere (Cycles: d_sq > r_sq only).
    with np.errstate(invalid="ignore"):
        x = (dot(-wi, sdir[j]) - cos_half[j]) * smooth[j]   # inf * 0 at a hard edge
    x = np.where(np.isnan(x), 0.0, x)
    Le *= np.where(spot[j] & ~inside, smoothstep(x), 1.0)[:, None]
    wi_out[:], t_out[:], le_out[:], pdf_out[:], delta_out[:] = wi, t, Le, pdf, delta


@loop_kernel("void(int64[:], float64[:, :], float64[:], float64[:], float64[:, ::1], float64[::1], boolean[::1], "
             "float64[:, ::1], boolean[::1], float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], "
             "float64[::1], float64[:, ::1], float64[::1], boolean[::1])", _point_sample_numpy)
def _point_sample(j, p, u1, u2, pos, radius, sphere, L, spot, sdir, cos_half, smooth,
                  wi_out, t_out, le_out, pdf_out, delta_out):
    """A point on each ray's point or spot light: the cone of a sphere
    light seen from p, the disk facing p (soft falloff), or the centre
    (radius 0: delta), as the NumPy form computes it term by term."""
    for i in range(len(j)):
        k = j[i]
        r = radius[k]
        dx, dy, dz = p[i, 0] - pos[k, 0], p[i, 1] - pos[k, 1], p[i, 2] - pos[k, 2]
        d2 = (dx * dx + dz * dz) + dy * dy
        dist = np.sqrt(d2)
        m = max(dist, 1e-30)
        n0, n1, n2 = dx / m, dy / m, dz / m                  # light_n: from the light to p
        w0, w1, w2 = -n0, -n1, -n2
        t = dist
        pdf = 1.0
        delta = r <= 0
        scale = max(d2, 1e-30) if delta else 1.0
        le0, le1, le2 = L[k, 0] / scale, L[k, 1] / scale, L[k, 2] / scale
        if sphere[k] and not delta:
            if d2 <= r * r:                                   # inside: the uniform sphere
                cos_z = 1.0 - 2.0 * u1[i]
                sin_z = np.sqrt(max(0.0, 1.0 - cos_z * cos_z))
                w0, w1, w2 = sin_z * np.cos(TWO_PI * u2[i]), sin_z * np.sin(TWO_PI * u2[i]), cos_z
                pdf = INSIDE_PDF
                cos_t = (w0 * -n0 + w2 * -n2) + w1 * -n1
                t = dist * cos_t + np.sqrt(max(0.0, r * r - d2 * (1.0 - cos_t * cos_t)))
            else:
                x = r * r / d2
                omc = 0.5 * x + 0.125 * x * x if x < 0.0004 else 1.0 - np.sqrt(max(0.0, 1.0 - x))
                lx, ly, cos_t = cone_point(u1[i], u2[i], omc)
                pdf = 1.0 / (TWO_PI * omc)
                a0, a1, a2 = -n0, -n1, -n2                    # the cone's axis: towards the light
                s0, s1, s2, t0, t1, t2 = frame_of(a0, a1, a2)
                w0 = (lx * s0 + ly * t0) + cos_t * a0
                w1 = (lx * s1 + ly * t1) + cos_t * a1
                w2 = (lx * s2 + ly * t2) + cos_t * a2
                t = dist * cos_t - np.sqrt(max(0.0, r * r - d2 * (1.0 - cos_t * cos_t)))
        elif not sphere[k] and not delta:
            x, y = disk_point(u1[i], u2[i])
            s0, s1, s2, t0, t1, t2 = frame_of(n0, n1, n2)
            v0 = (pos[k, 0] + (x * s0 + y * t0) * r) - p[i, 0]
            v1 = (pos[k, 1] + (x * s1 + y * t1) * r) - p[i, 1]
            v2 = (pos[k, 2] + (x * s2 + y * t2) * r) - p[i, 2]
            t = np.sqrt((v0 * v0 + v1 * v1) + v2 * v2)
            mt = max(t, 1e-30)
            w0, w1, w2 = v0 / mt, v1 / mt, v2 / mt
            cos_l = abs((n0 * -w0 + n2 * -w2) + n1 * -w1)
            pdf = t * t / (np.pi * (r * r) * max(cos_l, 1e-30))
        fac = 1.0
        if spot[k] and not (sphere[k] and not delta and d2 <= r * r):
            cos = (-w0 * sdir[k, 0] + -w2 * sdir[k, 2]) + -w1 * sdir[k, 1]
            x = (cos - cos_half[k]) * smooth[k]
            if x != x:
                x = 0.0
            x = min(max(x, 0.0), 1.0)
            fac = x * x * (3.0 - 2.0 * x)
        wi_out[i, 0], wi_out[i, 1], wi_out[i, 2] = w0, w1, w2
        t_out[i] = t
        le_out[i, 0], le_out[i, 1], le_out[i, 2] = le0 * fac, le1 * fac, le2 * fac
        pdf_out[i] = pdf
        delta_out[i] = delta


def _inside_direction(u1, u2):
    """Cycles' sample_uniform_sphere in world axes, and its pdf."""
    z = 1.0 - 2.0 * u1
    sin_z = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = TWO_PI * u2
    return np.stack([sin_z * np.cos(phi), sin_z * np.sin(phi), z], axis=1), np.full(len(z), INSIDE_PDF)


def _point_hit(o, d, c, r, sphere):
    """Distance (inf = miss) and solid-angle pdf of rays (o, d) meeting a
    point light of radius r > 0 at c: its sphere (sampled by its cone; from
    inside, its far side), or with soft falloff its disk facing the ray's
    origin.  A spot's far side too: Cycles' one-sided spot_light_intersect
    hides it from rays leaving the centre, which NEE's uniform sphere
    there does not, so its MIS render would miss that light."""
    n = len(o)
    t = np.full(n, np.inf)
    pdf = np.zeros(n)
    oc = o - c
    d2 = dot(oc, oc)
    if sphere:
        b = dot(oc, d)
        disc = b * b - (d2 - r * r)
        inside = d2 <= r * r
        ok = disc >= 0
        th = np.where(inside, -b + np.sqrt(np.maximum(disc, 0.0)), -b - np.sqrt(np.maximum(disc, 0.0)))
        ok &= th > 0
        t[ok] = th[ok]
        out = ok & ~inside
        pdf[out] = uniform_cone_pdf(sin_sq_to_one_minus_cos(r * r / d2[out]))
        pdf[ok & inside] = INSIDE_PDF
    else:
        light_n = oc / np.sqrt(np.maximum(d2, 1e-30))[:, None]
        denom = dot(d, light_n)
        with np.errstate(divide="ignore", invalid="ignore"):
            th = -dot(oc, light_n) / denom
        q = o + d * th[:, None]
        ok = (denom < 0) & (th > 0) & (np.sum((q - c) ** 2, axis=1) <= r * r)
        t[ok] = th[ok]
        pdf[ok] = th[ok] ** 2 / (np.pi * r * r * np.abs(denom[ok]))
    return t, pdf


def _nearest_point_numpy(o, d, t, tmin, ray_bits, pos, radius, sphere, light_bits, hit_t, index, pdf):
    for j in range(len(radius)):
        sees = (ray_bits & light_bits[j]) != 0
        if radius[j] <= 0 or not sees.any():
            continue
        th, pw = _point_hit(o, d, pos[j], radius[j], sphere[j])
        closer = (th < t) & (th > tmin) & sees
        t[closer] = hit_t[closer] = th[closer]
        index[closer] = j
        pdf[closer] = pw[closer]


@helper
def _dot3(ax, ay, az, bx, by, bz):
    """A row of vec.dot (einsum adds the middle term last)."""
    return (ax * bx + az * bz) + ay * by


@loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], uint8[::1], float64[:, ::1], "
             "float64[::1], boolean[::1], uint8[::1], float64[::1], int64[::1], float64[::1])", _nearest_point_numpy)
def _nearest_point(o, d, t, tmin, ray_bits, pos, radius, sphere, light_bits, hit_t, index, pdf):
    """The nearest point or spot light past tmin and before t per ray (a
    light already passed on the ray's straight line, before a transparent
    surface, is not met again)."""
    for i in range(len(t)):
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        for j in range(len(radius)):
            r = radius[j]
            if r <= 0 or (ray_bits[i] & light_bits[j]) == 0:
                continue
            ox, oy, oz = o[i, 0] - pos[j, 0], o[i, 1] - pos[j, 1], o[i, 2] - pos[j, 2]
            d2 = _dot3(ox, oy, oz, ox, oy, oz)
            if sphere[j]:
                b = _dot3(ox, oy, oz, dx, dy, dz)
                disc = b * b - (d2 - r * r)
                if d2 <= r * r:   # inside: the far side
                    th = -b + np.sqrt(np.maximum(disc, 0.0))
                    if not (th > 0 and th > tmin[i] and th < t[i]):
                        continue
                    pw = INSIDE_PDF
                else:
                    th = -b - np.sqrt(np.maximum(disc, 0.0))
                    if not (disc >= 0 and th > 0 and th > tmin[i] and th < t[i]):
                        continue
                    x = r * r / d2
                    omc = 0.5 * x + 0.125 * x * x if x < 0.0004 else 1.0 - np.sqrt(np.maximum(0.0, 1.0 - x))
                    pw = 1.0 / (2.0 * np.pi * omc)
            else:
                inv = np.sqrt(np.maximum(d2, 1e-30))
                nx, ny, nz = ox / inv, oy / inv, oz / inv
                denom = _dot3(dx, dy, dz, nx, ny, nz)
                th = -_dot3(ox, oy, oz, nx, ny, nz) / denom
                qx = (o[i, 0] + dx * th) - pos[j, 0]
                qy = (o[i, 1] + dy * th) - pos[j, 1]
                qz = (o[i, 2] + dz * th) - pos[j, 2]
                if not (denom < 0 and th > tmin[i] and (qx * qx + qy * qy) + qz * qz <= r * r and th < t[i]):
                    continue
                pw = th * th / (np.pi * r * r * np.abs(denom))
            t[i] = th
            hit_t[i] = th
            index[i] = j
            pdf[i] = pw



def _matrix(light):
    """The light object's matrix (what its node tree's Object coordinates
    read), or a translation to its position."""
    if light.matrix is not None:
        return np.asarray(light.matrix, np.float64)
    m = np.eye(4)
    m[:3, 3] = light.position
    return m


def validate(light, what):
    check_rgb(light.power, f"{what} power", nonnegative=True)
    check_rgb(light.position, f"{what} position")
    check_size(light.radius, f"{what}: radius")
    check_falloff(light, what)
    if light.matrix is not None:
        m = np.asarray(light.matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise SceneError(f"{what}: matrix must be a finite 4x4")
    if isinstance(light, SpotLight):
        check_direction(light.direction, f"{what}: direction")
        size = check_size(light.spot_size, f"{what}: spot_size", 0.0, np.pi)
        if size <= 0:
            raise SceneError(f"{what}: spot_size must be > 0 (a cone), got {size}")
        check_size(light.spot_blend, f"{what}: spot_blend", 0.0, 1.0)


def _examples():
    P, d, r = np.array([30.0, 20.0, 10.0]), 2.0, 0.3

    def scene(**kw):
        kind = SpotLight if "direction" in kw else PointLight
        return lambda: Scene(lights=[kind((0.0, 0.0, d), tuple(P), **kw)])
    delta = tuple(P / (4 * np.pi * d * d))
    cone = 2 * np.pi * (1 - np.sqrt(1 - r * r / (d * d)))
    disk = 2 * np.pi * (1 - d / np.hypot(d, r))
    return [
        # A sphere light of radiance P / (4 pi^2 r^2): E = pi L (r / d)^2 = P / (4 pi d^2).
        LightExample("sphere", scene(radius=r), (0, 0, 0), solid_angle=cone, irradiance=delta),
        # The disk facing p: E = pi L r^2 / (d^2 + r^2).
        LightExample("soft disk", scene(radius=r, soft_falloff=True), (0, 0, 0), solid_angle=disk,
                     irradiance=tuple(P / (4 * np.pi * (d * d + r * r)))),
        LightExample("delta", scene(radius=0.0), (0, 0, 0), irradiance=delta),
        LightExample("spot", scene(radius=0.1, direction=(0, 0, -1), spot_size=2.0, spot_blend=0.1), (0, 0, 0),
                     solid_angle=2 * np.pi * (1 - np.sqrt(1 - 0.01 / (d * d))), irradiance=delta),
        # Light Falloff: the intensity P / (4 pi) at distance d times d (Linear),
        # d^2 (Constant), and d^2 / (smooth + d^2).
        LightExample("delta linear", scene(radius=0.0, falloff="LINEAR"), (0, 0, 0),
                     irradiance=tuple(np.array(delta) * d)),
        LightExample("delta constant smooth", scene(radius=0.0, falloff="CONSTANT", falloff_smooth=1.5), (0, 0, 0),
                     irradiance=tuple(np.array(delta) * d * d * d * d / (1.5 + d * d))),
        LightExample("sphere linear", scene(radius=r, falloff="LINEAR"), (0, 0, 0), solid_angle=cone),
        # Node trees varying over the light: the radiance changes, the pdf does not.
        LightExample("sphere normal checker", scene(radius=r, shader=checker_of("ShaderNodeTexCoord", "Normal", 3.0)),
                     (0, 0, 0), solid_angle=cone),
        LightExample("soft disk incoming checker",
                     scene(radius=r, soft_falloff=True, shader=checker_of("ShaderNodeNewGeometry", "Incoming", 20.0)),
                     (0.3, 0, 0)),
        LightExample("spot uv checker", scene(radius=0.1, direction=(0, 0, -1), spot_size=2.0, spot_blend=0.1,
                                              shader=checker_of("ShaderNodeTexCoord", "UV", 9.0)), (0, 0, 0)),
    ]


def _unknown_node():
    from ..scene import NodeCall, NodeOutput
    return NodeOutput(NodeCall("ShaderNodeNope", {}), "Color")


def _set(field, value):
    return lambda s: setattr(s.lights[0], field, value)


def _spot(**kw):
    """Replace the example's light by a spot with these fields."""
    return lambda s: s.lights.__setitem__(0, SpotLight((0.0, 0.0, 1.0), (1.0, 1.0, 1.0), **kw))


register(LightDef(
    "point", POINT, 0, lambda inputs: PointLights(inputs.lights, getattr(inputs.scene, "camera", None)), RAY, "points",
    scene_types=(PointLight, SpotLight), validate=validate, examples=_examples,
    hostile=(("NaN power", _set("power", (np.nan, 1.0, 1.0)), "power"),
             ("negative power", _set("power", (-1.0, 1.0, 1.0)), "power"),
             ("NaN position", _set("position", (0.0, np.nan, 0.0)), "position"),
             ("negative radius", _set("radius", -0.1), "radius"),
             ("NaN radius", _set("radius", np.nan), "radius"),
             ("unknown falloff", _set("falloff", "CUBIC"), "falloff"),
             ("NaN matrix", _set("matrix", np.full((4, 4), np.nan)), "matrix"),
             ("shader of an unknown node", _set("shader", _unknown_node()), "ShaderNodeNope"),
             ("negative smooth", _set("falloff_smooth", -1.0), "smooth"),
             ("zero spot size", _spot(spot_size=0.0), "spot_size"),
             ("zero spot direction", _spot(direction=(0.0, 0.0, 0.0)), "direction"),
             ("spot blend above 1", _spot(spot_blend=2.0), "spot_blend"))))
