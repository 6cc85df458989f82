"""Suns: distant lights of irradiance E (W/m^2) on a surface facing them,
radiance E / (pi sin^2(angle / 2)) over their cone; angle 0 is a delta
light of irradiance E.  BSDF rays see them when they leave the scene.

A sun's node tree (``shader``) is evaluated per direction, as Cycles 5.0's
distant light sets up its shader (kernel/light/distant.h, light/sample.h):
Position = Normal = True Normal = Incoming = the direction the light
travels along (-D, a unit vector), UV = Parametric = the direction mapped
onto the sun's disk ``distant_light_uv`` (the light object's x and y axes,
the cone's rim at 0 and 1), Object = the inverse object matrix applied to
that direction as a point, Ray Length FLT_MAX.  NEE samples and BSDF rays
that see the disk evaluate the same function of the direction, so MIS
stays unbiased."""
import numpy as np

from ..geometry import visibility_bits
from ..kernels import loop_kernel
from ..sampling import TWO_PI, cone_point, uniform_cone, uniform_cone_pdf
from ..scene import Scene, SceneError, SunLight
from ..vec import column, frame, frame_of, to_world
from .common import check_direction, check_rgb, check_size, selection_power, unit
from .registry import ESCAPE, LightDef, LightExample, LightTable, register
from .shader import FLT_MAX, LightShaders, checker_of, path_rows

SUN = 1


class SunLights(LightTable):
    def __init__(self, lights, camera=None):
        self.count = len(lights)
        self.lights = list(lights)
        self.dir = np.array([unit(l.direction) for l in lights], float).reshape(-1, 3)
        self.E = np.array([l.strength for l in lights], float).reshape(-1, 3)
        half = np.array([0.5 * l.angle for l in lights], float)
        self.one_minus_cos = 2.0 * np.sin(0.5 * half) ** 2
        self.delta = half <= 0
        sin2 = np.sin(half) ** 2
        self.L = self.E / np.where(self.delta, 1.0, np.pi * sin2)[:, None]
        # Cycles' half_inv_sin_half_angle (0.5 / sin(angle / 4)); 0 for delta suns.
        with np.errstate(divide="ignore"):
            self.uv_scale = np.where(self.delta, 0.0, 0.5 / np.sin(0.5 * np.maximum(half, 1e-300)))
        self.shaders = None
        if any(getattr(l, "shader", None) is not None for l in lights):
            self.shaders = LightShaders(lights, [sun_matrix(l) for l in lights], camera)

    def power(self, radius):
        if not self.count:
            return []
        scale = np.array([self._selection_scale(j) for j in range(self.count)])
        return selection_power(self.E) * np.pi * radius ** 2 * scale

    def _selection_scale(self, j, count=256):
        """The sun's tree averaged over a lattice of its cone (1 without one)."""
        if self.shaders is None or j not in self.shaders.fns:
            return 1.0
        k = np.arange(count)
        u1, u2 = (0.5 + k * 0.7548776662466927) % 1.0, (0.5 + k * 0.5698402909980532) % 1.0
        wi, pdf = np.empty((count, 3)), np.empty(count)
        _sun_sample(np.full(count, j, np.int64), u1, u2, -self.dir, self.one_minus_cos, self.delta, wi, pdf)
        travel = -wi
        return self.shaders.selection_scale(j, travel, travel, travel, self._uv(np.full(count, j), wi))

    def _uv(self, j, d):
        """Cycles' distant_light_uv of directions d towards sun j, as the
        (u, v) Texture Coordinate UV reads: (u_ + 0.5, v_ + 0.5)."""
        inv = self.shaders.inverse[j][:, :3, :3]
        local = np.einsum("nij,nj->ni", inv, d)
        diff = d - self.dir[j]
        with np.errstate(invalid="ignore", divide="ignore"):
            fac = self.uv_scale[j] / np.sqrt(np.einsum("ij,ij->i", diff, diff))
        fac = np.where(np.isfinite(fac), fac, 0.0)
        return np.stack([local[:, 0] * fac + 0.5, local[:, 1] * fac + 0.5], axis=1)

    def _shader(self, j, d, path=None):
        """(N, 3) the suns' node trees along directions d towards them
        (path: shader.emission_path of the rays, or None)."""
        travel = -d
        return self.shaders.factor(j, travel, travel, travel, self._uv(j, d), np.full(len(d), FLT_MAX), path)

    def is_delta(self):
        return self.delta

    def visibility(self):
        return np.array([visibility_bits(l) for l in self.lights], np.uint8)

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        n = len(p)
        wi, pdf = np.empty((n, 3)), np.empty(n)
        _sun_sample(column(j, n, np.int64), column(u1, n, np.float64), column(u2, n, np.float64),
                    -self.dir, self.one_minus_cos, self.delta, wi, pdf)
        Le = self.L[j]
        if self.shaders is not None:
            Le = Le * self._shader(np.broadcast_to(j, (n,)), wi, path_rows(out.path, idx))
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, np.inf, Le
        out.pdf[idx], out.delta[idx] = pdf, self.delta[j]

    def escape_hits(self, d, path=None):
        """(mask, sun, Le, pdf) per sun disk with angle > 0 that rays leaving
        the scene in directions d may see; Le is (3,), or per masked row
        (mask.sum(), 3) for a sun with a node tree (path: what the trees
        read of the rays' paths, shader.emission_path, or None)."""
        hits = []
        for j in range(self.count):
            res = self.hit(j, d)
            if res is None:
                continue
            mask, Le, pdf = res
            if self.shaders is not None and j in self.shaders.fns:
                rows = np.flatnonzero(mask)
                Le = Le * self._shader(np.full(len(rows), j), d[rows], path_rows(path, rows))
            hits.append((mask, j, Le, pdf))
        return hits

    def hit(self, j, d):
        if self.delta[j]:
            return None
        omc = self.one_minus_cos[j]
        # 1 - cos(angle to the axis) as |d - axis|^2 / 2: no cancellation for tiny suns.
        diff = d + self.dir[j]
        mask = 0.5 * np.einsum("ij,ij->i", diff, diff) <= omc
        return mask, self.L[j], uniform_cone_pdf(omc)


def _sun_sample_numpy(j, u1, u2, axes, one_minus_cos, delta, wi, pdf):
    axis = axes[j]
    wi[:] = axis
    pdf[:] = 1.0
    s = np.nonzero(~delta[j])[0]
    if len(s):
        local, pdf[s] = uniform_cone(u1[s], u2[s], one_minus_cos[j[s]])
        tt, bb = frame(axis[s])
        wi[s] = to_world(local, tt, bb, axis[s])


@loop_kernel("void(int64[:], float64[:], float64[:], float64[:, ::1], float64[::1], boolean[::1], "
             "float64[:, ::1], float64[::1])", _sun_sample_numpy)
def _sun_sample(j, u1, u2, axes, one_minus_cos, delta, wi, pdf):
    """Directions uniform in each sun's cone about its axis (delta suns: the
    axis), as uniform_cone, vec.frame and vec.to_world compute them."""
    for i in range(len(j)):
        k = j[i]
        n0, n1, n2 = axes[k, 0], axes[k, 1], axes[k, 2]
        if delta[k]:
            wi[i, 0], wi[i, 1], wi[i, 2] = n0, n1, n2
            pdf[i] = 1.0
            continue
        x, y, cos_t = cone_point(u1[i], u2[i], one_minus_cos[k])
        s0, s1, s2, t0, t1, t2 = frame_of(n0, n1, n2)
        wi[i, 0] = (x * s0 + y * t0) + cos_t * n0
        wi[i, 1] = (x * s1 + y * t1) + cos_t * n1
        wi[i, 2] = (x * s2 + y * t2) + cos_t * n2
        pdf[i] = 1.0 / (TWO_PI * one_minus_cos[k])



def sun_matrix(light):
    """The sun object's matrix (its UV axes and Object coordinates), or a
    frame at the origin whose -Z is the sun's direction."""
    if getattr(light, "matrix", None) is not None:
        return np.asarray(light.matrix, np.float64)
    z = -unit(light.direction)
    s, t = frame(z[None])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = s[0], t[0], z
    return m


def validate(light, what):
    check_rgb(light.strength, f"{what} strength", nonnegative=True)
    check_direction(light.direction, f"{what}: direction")
    check_size(light.angle, f"{what}: angle", 0.0, np.pi)
    if light.matrix is not None:
        m = np.asarray(light.matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise SceneError(f"{what}: matrix must be a finite 4x4")


def _examples():
    E = (3.0, 2.0, 1.0)
    half = 0.1
    tilt = np.radians(30.0)
    down = (np.sin(tilt), 0.0, -np.cos(tilt))
    cone = 2 * np.pi * (1 - np.cos(half))
    # A disk of constant radiance E / (pi sin^2 half) seen at angle tilt:
    # E cos(tilt) exactly (the cone lies above the horizon).
    lit = tuple(np.array(E) * np.cos(tilt))
    return [LightExample("disk", lambda: Scene(lights=[SunLight(down, E, 2 * half)]), (0, 0, 0), solid_angle=cone,
                         irradiance=lit),
            LightExample("delta", lambda: Scene(lights=[SunLight(down, E, 0.0)]), (0, 0, 0), irradiance=lit),
            # A node tree varying over the disk: the radiance changes per direction, the pdf does not.
            LightExample("disk uv checker", lambda: Scene(lights=[SunLight(
                down, E, 2 * half, shader=checker_of("ShaderNodeTexCoord", "UV", 5.0))]), (0, 0, 0),
                solid_angle=cone)]


def _set(field, value):
    return lambda s: setattr(s.lights[0], field, value)


register(LightDef(
    "sun", SUN, 1, lambda inputs: SunLights(inputs.lights, getattr(inputs.scene, "camera", None)), ESCAPE, "suns",
    scene_types=(SunLight,),
    validate=validate, examples=_examples,
    hostile=(("NaN strength", _set("strength", (1.0, np.nan, 1.0)), "strength"),
             ("negative strength", _set("strength", (1.0, -2.0, 1.0)), "strength"),
             ("zero direction", _set("direction", (0.0, 0.0, 0.0)), "direction"),
             ("NaN direction", _set("direction", (np.nan, 0.0, -1.0)), "direction"),
             ("negative angle", _set("angle", -0.1), "angle"),
             ("angle above pi", _set("angle", 4.0), "angle"),
             ("NaN matrix", _set("matrix", np.full((4, 4), np.nan)), "matrix"))))
