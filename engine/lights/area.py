"""Area lights: one-sided squares, rectangles, disks and ellipses emitting
along their local -Z, radiance P / (pi A) (normalize on) or P / pi.
Rectangles seen under enough solid angle are sampled by it (Urena et al.),
the rest by area."""
import numpy as np

from ..geometry import visibility_bits
from ..kernels import helper, kernel, loop_kernel, where
from ..lightbounds import Bounds
from ..lightproxy import box_corners, proxy_margin
from ..sampling import concentric_disk, disk_point, rectangle_frame, rectangle_solid_angle, spherical_rectangle_warp
from ..scene import AREA_SHAPES, AreaLight, Scene, SceneError
from ..vec import column, rows3
from . import common
from .common import Falloff, check_falloff, check_rgb, check_size, selection_power, uniform_index, unit
from .registry import RAY, LightDef, LightExample, LightTable, register
from .shader import LightShaders, checker_of, path_rows, spread_directions

AREA = 2


class AreaLights(LightTable):
    def __init__(self, lights, camera=None):
        self.count = len(lights)
        self.lights = list(lights)
        self.falloff = Falloff.of(lights)
        self.shaders = LightShaders.of(lights, [l.matrix for l in lights], camera)
        u, v, c, n, area, ell = [], [], [], [], [], []
        for l in lights:
            m = np.asarray(l.matrix, float)
            sy = l.size_x if l.shape in ("SQUARE", "DISK") else l.size_y
            u.append(m[:3, 0] * l.size_x)
            v.append(m[:3, 1] * sy)
            c.append(m[:3, 3])
            n.append(unit(-m[:3, 2]))
            ellipse = l.shape in ("DISK", "ELLIPSE")
            a = np.linalg.norm(u[-1]) * np.linalg.norm(v[-1]) * (np.pi / 4 if ellipse else 1.0)
            area.append(a)
            ell.append(ellipse)
        self.u = np.array(u, float).reshape(-1, 3)
        self.v = np.array(v, float).reshape(-1, 3)
        self.c = np.array(c, float).reshape(-1, 3)
        self.n = np.array(n, float).reshape(-1, 3)
        self.area = np.array(area, float)
        self.ellipse = np.array(ell, bool)
        self.visible_camera = [l.visible_camera for l in lights]
        pw = np.array([l.power for l in lights], float).reshape(-1, 3)
        norm = np.array([l.normalize for l in lights], bool)
        self.power_rgb = pw
        inv_area = np.where(norm & (self.area > 0), 1.0 / np.maximum(self.area, 1e-300), 1.0)
        self.L = pw * (inv_area / np.pi)[:, None]
        # Projections onto the light's axes: local coords in [-0.5, 0.5].
        self.du = self.u / np.maximum(np.sum(self.u ** 2, axis=1), 1e-300)[:, None]
        self.dv = self.v / np.maximum(np.sum(self.v ** 2, axis=1), 1e-300)[:, None]
        # Rectangles (not sheared by the matrix) are sampled by solid angle.
        self.len_u = np.linalg.norm(self.u, axis=1)
        self.len_v = np.linalg.norm(self.v, axis=1)
        self.ex = self.u / np.maximum(self.len_u, 1e-300)[:, None]
        self.ey = self.v / np.maximum(self.len_v, 1e-300)[:, None]
        skew = np.abs(np.sum(self.ex * self.ey, axis=1))
        self.rect = ~self.ellipse & (self.area > 0) & (skew < 1e-9)

    def power(self, radius):
        if not self.count:
            return []
        scale = np.array([self._selection_scale(j) for j in range(self.count)])
        return selection_power(self.L) * np.pi * self.area * scale

    def _selection_scale(self, j, count=256):
        """The light's tree averaged over a lattice of its points, seen
        along directions of its emitting hemisphere (1 without a tree)."""
        if self.shaders is None:
            return 1.0
        k = np.arange(count)
        # Roberts' R2 lattice: even in both axes, aligned with no texture's cells.
        x, y = (0.5 + k * 0.7548776662466927) % 1.0 - 0.5, (0.5 + k * 0.5698402909980532) % 1.0 - 0.5
        if self.ellipse[j]:
            x, y = x * np.sqrt(0.5), y * np.sqrt(0.5)     # inside the inscribed ellipse
        q = self.c[j] + x[:, None] * self.u[j] + y[:, None] * self.v[j]
        d = spread_directions(count)
        wo = np.where((d @ self.n[j] < 0)[:, None], -d, d)
        return self.shaders.selection_scale(j, q, np.broadcast_to(self.n[j], q.shape), wo,
                                            np.stack([x + 0.5, y + 0.5], axis=1))

    def visibility(self):
        return np.array([visibility_bits(l) for l in self.lights], np.uint8)

    def bounds(self, j, phi):
        c, u, v = self.c[j], self.u[j], self.v[j]
        corners = c + 0.5 * np.array([u + v, u - v, -u + v, -u - v])
        # One-sided Lambertian: normals all equal (theta_o = 0), emission up to 90 degrees.
        return Bounds(corners.min(axis=0), corners.max(axis=0), phi, self.n[j], 1.0, 0.0, False, rect=(c, u, v))

    def proxy_boxes(self):
        """Thin boxes around rectangles, squares, disks and ellipses.  The exact
        test (``intersect``) meets the plane through c normal to the light's
        n, and accepts a point q when its projections on the unit axes of u
        and v stay within half their lengths: the parallelogram +-a e1 +-b e2
        of that plane, with (e1, e2) dual to those axes (u x v itself unless
        the light's matrix is sheared).  Ellipses lie inside it."""
        boxes = []
        for j in range(self.count):
            u, v, c, n = self.u[j], self.v[j], self.c[j], self.n[j]
            lu, lv = np.linalg.norm(u), np.linalg.norm(v)
            frame = np.array([u / max(lu, 1e-300), v / max(lv, 1e-300), n])
            if lu <= 0 or lv <= 0 or abs(np.linalg.det(frame)) < 1e-9:
                continue   # degenerate: the exact test finds no hit either
            dual = np.linalg.inv(frame)   # columns e1, e2 (in the plane) and n'
            corners = np.array([s * 0.5 * lu * dual[:, 0] + t * 0.5 * lv * dual[:, 1]
                                for s in (-1, 1) for t in (-1, 1)])
            ax = dual[:, 0] / np.linalg.norm(dual[:, 0])
            ay = np.cross(n, ax)
            half_x, half_y = np.abs(corners @ ax).max(), np.abs(corners @ ay).max()
            pad = proxy_margin(c, max(half_x, half_y))
            boxes.append(box_corners(c, np.array([ax * (half_x + pad), ay * (half_y + pad), n * pad])))
        return boxes

    def nearest(self, o, d, t, ray, bits, camera, path=None, tmin=None):
        """As PointLights.nearest, one light at a time."""
        n = len(o)
        hit_t = np.full(n, np.inf)
        index = np.full(n, -1, np.int64)
        Le = np.zeros((n, 3))
        pdf = np.zeros(n)
        for j in range(self.count):
            if camera and not self.visible_camera[j]:
                continue
            sees = True if ray is None else (ray & bits[j]) != 0
            if not np.any(sees):
                continue
            th, le, pw = self.intersect(j, o, d, path)
            closer = (th < t) & sees if tmin is None else (th < t) & (th > tmin) & sees
            if closer.any():
                t[closer] = th[closer]
                hit_t[closer] = th[closer]
                index[closer] = j
                Le[closer] = le[closer]
                pdf[closer] = pw[closer]
        return hit_t, index, Le, pdf

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        m = len(p)
        wi, t, pdf = np.empty((m, 3)), np.empty(m), np.empty(m)
        # One compiled pass per batch: the shape's point, the warp, direction and pdf
        # (the elementwise kernel's NumPy passes and gathers cost as much as its arithmetic).
        _area_sample_rows(column(j, m, np.int64), rows3(p)[0], column(u1, m, np.float64),
                          column(u2, m, np.float64), self.c, self.ex, self.ey, self.n, self.len_u, self.len_v,
                          self.area, self.rect, self.ellipse, common.MIN_SPHERICAL, wi, t, pdf)
        j = uniform_index(j)
        Le = self.L[j]
        if self.shaders is not None:
            Le = Le * self._shader(j, p + wi * t[:, None], -wi, t, path_rows(out.path, idx))
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, t, Le
        out.pdf[idx] = pdf

    def _shader(self, j, q, wo, dist=None, path=None):
        """The lights' node trees at points q (Incoming wo): UV = Parametric =
        the point in the light's axes shifted to [0, 1] (Cycles' area.h u, v)."""
        rel = q - self.c[j]
        uv = np.stack([dot_rows(rel, self.du[j]) + 0.5, dot_rows(rel, self.dv[j]) + 0.5], axis=1)
        n = np.broadcast_to(self.n[j], q.shape)
        return self.shaders.factor(j, q, n, wo, uv, dist, path)

    def intersect(self, j, o, d, path=None):
        n = len(o)
        o, d = rows3(o, d)
        t, pdf, ok = np.empty(n), np.empty(n), np.empty(n, bool)
        # One compiled pass: the plane, the shape, the area pdf and on rectangles NEE's
        # solid-angle pdf (the pdf NEE has for this point: the same choice of strategy).
        _area_hit_rows(o, d, int(j), self.c, self.n, self.du, self.dv, self.ex, self.ey, self.len_u, self.len_v,
                       self.area, self.rect, self.ellipse, common.MIN_SPHERICAL, t, pdf, ok)
        Le = np.tile(self.L[j], (n, 1))
        if self.shaders is not None and ok.any():
            rows = np.flatnonzero(ok)
            Le[rows] *= self._shader(j, o[rows] + d[rows] * t[rows, None], -d[rows], t[rows], path_rows(path, rows))
        return t, Le, pdf


def _area_hit_numpy(o, d, j, c, n, du, dv, ex, ey, len_u, len_v, area, rect, ellipse, min_spherical,
                    t_out, pdf_out, ok_out):
    normal = n[j]
    denom = d @ normal
    front = denom < -1e-12  # emits along its normal: seen from the front only
    with np.errstate(divide="ignore", invalid="ignore"):
        th = ((c[j] - o) @ normal) / denom
    q = o + d * th[:, None] - c[j]
    a = q @ du[j]
    b = q @ dv[j]
    if ellipse[j]:
        inside = 4.0 * (a * a + b * b) <= 1.0
    else:
        inside = (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5)
    ok = front & (th > 0) & inside & (area[j] > 0)
    t_out[:], pdf_out[:], ok_out[:] = np.inf, 0.0, ok
    t_out[ok] = th[ok]
    pdf_out[ok] = th[ok] ** 2 / (-denom[ok] * area[j])
    if rect[j] and ok.any():
        with np.errstate(all="ignore"):
            s, min_nz2 = rectangle_solid_angle.fn(o[ok, 0], o[ok, 1], o[ok, 2], *c[j], *ex[j], *ey[j],
                                                  len_u[j], len_v[j])
        use = (s >= min_spherical) & (min_nz2 < 1.0 - 1e-8)
        pdf_out[ok] = np.where(use, 1.0 / np.maximum(s, 1e-300), pdf_out[ok])


@loop_kernel("void(float64[:, :], float64[:, :], int64, float64[:, ::1], float64[:, ::1], float64[:, ::1], "
             "float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], "
             "boolean[::1], boolean[::1], float64, float64[::1], float64[::1], boolean[::1])", _area_hit_numpy)
def _area_hit_rows(o, d, j, c, n, du, dv, ex, ey, len_u, len_v, area, rect, ellipse, min_spherical,
                   t_out, pdf_out, ok_out):
    """Rays (o, d) meeting area light j from its front: distance (inf:
    missed), the pdf NEE has for the point (solid angle on rectangles seen
    under enough of it, else area) and whether it was hit, as the NumPy
    form computes them."""
    nx, ny, nz, cx, cy, cz = n[j, 0], n[j, 1], n[j, 2], c[j, 0], c[j, 1], c[j, 2]
    for i in range(len(o)):
        ox, oy, oz, dx, dy, dz = o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2]
        denom = (dx * nx + dy * ny) + dz * nz
        th = (((cx - ox) * nx + (cy - oy) * ny) + (cz - oz) * nz) / denom
        qx, qy, qz = (ox + dx * th) - cx, (oy + dy * th) - cy, (oz + dz * th) - cz
        a = (qx * du[j, 0] + qy * du[j, 1]) + qz * du[j, 2]
        b = (qx * dv[j, 0] + qy * dv[j, 1]) + qz * dv[j, 2]
        if ellipse[j]:
            inside = 4.0 * (a * a + b * b) <= 1.0
        else:
            inside = abs(a) <= 0.5 and abs(b) <= 0.5
        ok = denom < -1e-12 and th > 0 and inside and area[j] > 0
        t, pdf = np.inf, 0.0
        if ok:
            t, pdf = th, th * th / (-denom * area[j])
            if rect[j]:
                s, min_nz2 = _solid_angle_one(ox, oy, oz, cx, cy, cz, ex[j, 0], ex[j, 1], ex[j, 2],
                                              ey[j, 0], ey[j, 1], ey[j, 2], len_u[j], len_v[j])
                if s >= min_spherical and min_nz2 < 1.0 - 1e-8:
                    pdf = 1.0 / max(s, 1e-300)
        t_out[i], pdf_out[i], ok_out[i] = t, pdf, ok


@kernel(24, 5)
def _area_light_sample(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz, len_u, len_v, nx, ny, nz,
                       area, rect, x, y, u1, u2, min_spherical):
    """Direction (x, y, z), distance and solid-angle pdf towards a point of
    an area light: the point (x, y) of the shape in its axes (area
    sampling), or for rectangles seen under at least ``min_spherical`` sr a
    point uniform in their solid angle (Urena et al.; tiny or grazing ones,
    where the warp loses precision, keep area sampling as Cycles' area.h)."""
    ax, ay = x * len_u, y * len_v
    qx = cx + ax * exx + ay * eyx
    qy = cy + ax * exy + ay * eyy
    qz = cz + ax * exz + ay * eyz
    xc, yc, z0, zx, zy, zz = rectangle_frame(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz)
    xu, yv, solid_angle, min_nz2 = _rectangle_warp(xc, yc, where(z0 > 0, -z0, z0), len_u, len_v, u1, u2)
    use = (rect > 0.0) & (solid_angle >= min_spherical) & (min_nz2 < 1.0 - 1e-8)
    qx = where(use, px + xu * exx + yv * eyx + z0 * zx, qx)
    qy = where(use, py + xu * exy + yv * eyy + z0 * zy, qy)
    qz = where(use, pz + xu * exz + yv * eyz + z0 * zz, qz)
    vx, vy, vz = qx - px, qy - py, qz - pz
    t = np.sqrt(vx * vx + vy * vy + vz * vz)
    inv = 1.0 / np.maximum(t, 1e-30)
    wx, wy, wz = vx * inv, vy * inv, vz * inv
    cos_l = -(wx * nx + wy * ny + wz * nz)
    ok = (cos_l > 1e-12) & (t > 0.0) & (area > 0.0)
    pdf = where(ok, t * t / (np.maximum(cos_l, 1e-12) * np.maximum(area, 1e-300)), 0.0)
    pdf = where(ok & use, 1.0 / np.maximum(solid_angle, 1e-300), pdf)
    return wx, wy, wz, t, pdf


_rectangle_warp = helper(spherical_rectangle_warp.fn)
_area_one = helper(_area_light_sample.fn)
_solid_angle_one = helper(rectangle_solid_angle.fn)


def _area_sample_numpy(j, p, u1, u2, c, ex, ey, n, len_u, len_v, area, rect, ellipse, min_spherical,
                       wi_out, t_out, pdf_out):
    x, y = u1 - 0.5, u2 - 0.5
    e = ellipse[j]
    if np.any(e):
        dx, dy = concentric_disk(u1[e], u2[e])
        x[e], y[e] = 0.5 * dx, 0.5 * dy
    c, ex, ey, n = c[j], ex[j], ey[j], n[j]
    with np.errstate(all="ignore"):
        wx, wy, wz, t, pdf = _area_light_sample.fn(
            p[:, 0], p[:, 1], p[:, 2], c[:, 0], c[:, 1], c[:, 2], ex[:, 0], ex[:, 1], ex[:, 2],
            ey[:, 0], ey[:, 1], ey[:, 2], len_u[j], len_v[j], n[:, 0], n[:, 1], n[:, 2],
            area[j], rect[j].astype(np.float64), x, y, u1, u2, min_spherical)
    wi_out[:, 0], wi_out[:, 1], wi_out[:, 2] = wx, wy, wz
    t_out[:], pdf_out[:] = t, pdf


@loop_kernel("void(int64[:], float64[:, :], float64[:], float64[:], float64[:, ::1], float64[:, ::1], "
             "float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], boolean[::1], "
             "boolean[::1], float64, float64[:, ::1], float64[::1], float64[::1])", _area_sample_numpy)
def _area_sample_rows(j, p, u1, u2, c, ex, ey, n, len_u, len_v, area, rect, ellipse, min_spherical,
                      wi_out, t_out, pdf_out):
    """A point on each row's area light j seen from p: the shape's point
    (disks and ellipses by the concentric map), then _area_light_sample's
    direction, distance and pdf, row by row as its NumPy form computes them."""
    for i in range(len(j)):
        k = j[i]
        a, b = u1[i], u2[i]
        x, y = a - 0.5, b - 0.5
        if ellipse[k]:
            dx, dy = disk_point(a, b)
            x, y = 0.5 * dx, 0.5 * dy
        wx, wy, wz, t, pdf = _area_one(p[i, 0], p[i, 1], p[i, 2], c[k, 0], c[k, 1], c[k, 2],
                                       ex[k, 0], ex[k, 1], ex[k, 2], ey[k, 0], ey[k, 1], ey[k, 2],
                                       len_u[k], len_v[k], n[k, 0], n[k, 1], n[k, 2], area[k],
                                       1.0 if rect[k] else 0.0, x, y, a, b, min_spherical)
        wi_out[i, 0], wi_out[i, 1], wi_out[i, 2] = wx, wy, wz
        t_out[i], pdf_out[i] = t, pdf


def dot_rows(a, b):
    """Row-wise dot of (N, 3) a with b, (3,) or (N, 3)."""
    return np.einsum("ij,ij->i", a, np.broadcast_to(b, a.shape))



def validate(light, what):
    check_rgb(light.power, f"{what} power", nonnegative=True)
    m = np.asarray(light.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError(f"{what}: matrix must be 4x4")
    if not np.all(np.isfinite(m)):
        raise SceneError(f"{what}: matrix has NaN or infinite values")
    if light.shape not in AREA_SHAPES:
        raise SceneError(f"{what}: unknown shape {light.shape!r}")
    for name in ("size_x", "size_y"):
        # 0 is allowed: a light without area emits nothing (rendered as such).
        check_size(getattr(light, name), f"{what}: {name}")
    check_falloff(light, what)


def _facing_down(height):
    m = np.diag([1.0, 1.0, 1.0, 1.0])   # emits along -Z: down onto the origin
    m[2, 3] = height
    return m


def _examples():
    P, h = np.array([40.0, 30.0, 20.0]), 2.0

    def scene(shape, sx, sy=1.0, **kw):
        return lambda: Scene(lights=[AreaLight(_facing_down(h), tuple(P), shape, sx, sy, **kw)])
    R = 0.75
    L_disk = P / (np.pi * np.pi * R * R)
    a, b = 1.0, 0.6                              # rectangle half sizes 0.5 x 0.3
    half_x, half_y = 0.5 * a, 0.5 * b
    rect_sa = 4 * np.arcsin(half_x * half_y / np.sqrt((half_x ** 2 + h * h) * (half_y ** 2 + h * h)))
    return [
        # A disk of radiance L, radius R at height h, on its axis: E = pi L R^2 / (h^2 + R^2).
        LightExample("disk", scene("DISK", 2 * R), (0, 0, 0), solid_angle=2 * np.pi * (1 - h / np.hypot(h, R)),
                     irradiance=tuple(np.pi * L_disk * R * R / (h * h + R * R))),
        LightExample("rectangle", scene("RECTANGLE", a, b), (0, 0, 0), solid_angle=rect_sa),
        LightExample("square near", scene("SQUARE", 3.0), (0.2, 0.1, 1.5)),
        LightExample("ellipse", scene("ELLIPSE", 1.2, 0.5, normalize=False), (0.3, 0, 0)),
        LightExample("disk linear", scene("DISK", 2 * R, falloff="LINEAR", falloff_smooth=0.5), (0, 0, 0)),
        # A node tree varying over the light changes the radiance, never the pdf.
        LightExample("rectangle checker", scene("RECTANGLE", a, b, shader=checker_of("ShaderNodeTexCoord", "UV", 4.0)),
                     (0, 0, 0), solid_angle=rect_sa),
        LightExample("disk object checker", scene("DISK", 2 * R, shader=checker_of("ShaderNodeTexCoord", "Object", 3.0)),
                     (0.2, 0, 0)),
    ]


def _set(field, value):
    return lambda s: setattr(s.lights[0], field, value)


register(LightDef(
    "area", AREA, 2, lambda inputs: AreaLights(inputs.lights, getattr(inputs.scene, "camera", None)), RAY, "areas", scene_types=(AreaLight,),
    validate=validate, examples=_examples,
    hostile=(("NaN power", _set("power", (1.0, 1.0, np.nan)), "power"),
             ("negative power", _set("power", (1.0, -1.0, 1.0)), "power"),
             ("NaN matrix", _set("matrix", np.full((4, 4), np.nan)), "matrix"),
             ("3x3 matrix", _set("matrix", np.eye(3)), "matrix"),
             ("unknown shape", _set("shape", "STAR"), "shape"),
             ("negative size", _set("size_x", -1.0), "size_x"),
             ("NaN size", _set("size_y", np.nan), "size_y"),
             ("unknown falloff", _set("falloff", "INVERSE"), "falloff"),
             ("shader not a colour", _set("shader", "red"), "shader"))))
