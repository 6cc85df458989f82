"""Small analytic scenes shared by the engine tests (a helper module: test
modules do not import each other)."""
import numpy as np

from engine.scene import Camera, Instance, Lobe, Material, Scene, World
from engine.testscenes import look_at, quad


def ortho_camera(eye, target, size, scale, up=(0.0, 1.0, 0.0)):
    return Camera(look_at(eye, target, up), kind="ORTHO", ortho_scale=scale,
                  resolution=size, clip_start=0.01, clip_end=100.0)


def big_plane(material=0, half=50.0):
    return quad([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]]), \
        Instance(0, materials=[material])


def analytic_scene(light):
    mesh, inst = big_plane()
    cam = ortho_camera((0, 0, 5), (0, 0, 0), (40, 40), 4.0)
    rho = 0.5
    mat = Material("grey", (Lobe("diffuse", (rho, rho, rho)),))
    return Scene([mesh], [inst], [mat], [light], World((0.0, 0.0, 0.0)), cam), rho


def pixel_centres(n, scale):
    c = (np.arange(n) + 0.5) / n * scale - 0.5 * scale
    x, y = np.meshgrid(c, -c)   # row 0 at the top = +y
    return x, y
