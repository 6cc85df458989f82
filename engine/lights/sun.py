"""Suns: distant lights of irradiance E (W/m^2) on a surface facing them,
radiance E / (pi sin^2(angle / 2)) over their cone; angle 0 is a delta
light of irradiance E.  BSDF rays see them when they leave the scene."""
import numpy as np

from ..geometry import visibility_bits
from ..kernels import loop_kernel
from ..sampling import TWO_PI, cone_point, uniform_cone, uniform_cone_pdf
from ..scene import Scene, SunLight
from ..vec import column, frame, frame_of, to_world
from .common import check_direction, check_rgb, check_size, selection_power, unit
from .registry import ESCAPE, LightDef, LightExample, LightTable, register

SUN = 1


class SunLights(LightTable):
    def __init__(self, lights):
        self.count = len(lights)
        self.lights = list(lights)
        self.dir = np.array([unit(l.direction) for l in lights], float).reshape(-1, 3)
        self.E = np.array([l.strength for l in lights], float).reshape(-1, 3)
        half = np.array([0.5 * l.angle for l in lights], float)
        self.one_minus_cos = 2.0 * np.sin(0.5 * half) ** 2
        self.delta = half <= 0
        sin2 = np.sin(half) ** 2
        self.L = self.E / np.where(self.delta, 1.0, np.pi * sin2)[:, None]

    def power(self, radius):
        return selection_power(self.E) * np.pi * radius ** 2 if self.count else []

    def is_delta(self):
        return self.delta

    def visibility(self):
        return np.array([visibility_bits(l) for l in self.lights], np.uint8)

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        n = len(p)
        wi, pdf = np.empty((n, 3)), np.empty(n)
        _sun_sample(column(j, n, np.int64), column(u1, n, np.float64), column(u2, n, np.float64),
                    -self.dir, self.one_minus_cos, self.delta, wi, pdf)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, np.inf, self.L[j]
        out.pdf[idx], out.delta[idx] = pdf, self.delta[j]

    def escape_hits(self, d):
        """(mask, sun, Le, pdf) per sun disk with angle > 0 that rays leaving
        the scene in directions d may see."""
        hits = []
        for j in range(self.count):
            res = self.hit(j, d)
            if res is not None:
                hits.append((res[0], j) + res[1:])
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



def validate(light, what):
    check_rgb(light.strength, f"{what} strength", nonnegative=True)
    check_direction(light.direction, f"{what}: direction")
    check_size(light.angle, f"{what}: angle", 0.0, np.pi)


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
            LightExample("delta", lambda: Scene(lights=[SunLight(down, E, 0.0)]), (0, 0, 0), irradiance=lit)]


def _set(field, value):
    return lambda s: setattr(s.lights[0], field, value)


register(LightDef(
    "sun", SUN, 1, lambda inputs: SunLights(inputs.lights), ESCAPE, "suns", scene_types=(SunLight,),
    validate=validate, examples=_examples,
    hostile=(("NaN strength", _set("strength", (1.0, np.nan, 1.0)), "strength"),
             ("negative strength", _set("strength", (1.0, -2.0, 1.0)), "strength"),
             ("zero direction", _set("direction", (0.0, 0.0, 0.0)), "direction"),
             ("NaN direction", _set("direction", (np.nan, 0.0, -1.0)), "direction"),
             ("negative angle", _set("angle", -0.1), "angle"),
             ("angle above pi", _set("angle", 4.0), "angle"))))
