"""The world as a light: an HDRI (or a baked procedural world) sampled by
its environment map (engine/environment.py); BSDF rays that leave the scene
see it.  A constant world is no emitter (Cycles only BSDF-samples it)."""
import numpy as np

from ..environment import EnvironmentMap
from ..scene import EnvironmentTexture, Scene, World
from .registry import WORLD, LightDef, LightExample, LightTable, register

ENV = 4


class EnvironmentLight(LightTable):
    """An HDRI world as one emitter (a constant world is not one: Cycles
    only BSDF-samples it)."""

    def __init__(self, texture, compensate):
        self.map = EnvironmentMap(texture, compensate) if texture is not None else None
        self.count = int(texture is not None)

    def power(self, radius):
        # Like a sun from every direction: flux through the scene's disk.
        return [self.map.power() * np.pi * radius ** 2] if self.count else []

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        wi, pdf = self.map.sample(u1, u2)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, np.inf, self.map.eval(wi)
        out.pdf[idx] = pdf



def _examples():
    c = np.array([0.5, 0.25, 1.0])

    def world():
        rng = np.random.default_rng(4)
        px = np.empty((16, 32, 3), np.float32)
        px[:] = c
        px[3:5, 7:9] *= 1 + 20 * rng.random((2, 2, 1))     # a bright patch in the upper hemisphere
        return Scene(world=World((0.0, 0.0, 0.0), EnvironmentTexture(px)))

    def uniform():
        return Scene(world=World((0.0, 0.0, 0.0), EnvironmentTexture(np.tile(c.astype(np.float32), (8, 16, 1)))))
    # A uniform world of radiance c: E = pi c on any surface.
    return [LightExample("uniform", uniform, (0, 0, 0), solid_angle=4 * np.pi, irradiance=tuple(np.pi * c)),
            LightExample("patch", world, (0, 0, 0), solid_angle=4 * np.pi)]


def _set_pixels(value):
    def mutate(scene):
        scene.world.texture.pixels = scene.world.texture.pixels.copy()
        scene.world.texture.pixels[0, 0, 0] = value
    return mutate


register(LightDef(
    "world", ENV, 3, lambda inputs: EnvironmentLight(inputs.scene.world.texture, inputs.env_compensation),
    WORLD, "env", source="world", examples=_examples,
    hostile=(("NaN pixel", _set_pixels(np.nan), "NaN"),
             ("infinite strength", lambda s: setattr(s.world.texture, "strength", np.inf), "strength"),
             ("singular matrix", lambda s: setattr(s.world.texture, "matrix", np.zeros((3, 3))), "singular"))))
