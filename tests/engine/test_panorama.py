"""Panoramic cameras (engine/panorama.py): Cycles 5.0's projections
(kernel/camera/projection.h) exactly, both ways; the rays, rim, footprint
and Vector pass of a panoramic CameraModel.  Render parity against live
Cycles: tests/addon/test_panoramic_camera_parity.py."""
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))

from engine.camera import CameraModel, PixelFilter  # noqa: E402
from engine.panorama import TYPES, Panorama, fisheye_sensor  # noqa: E402
from engine.scene import Camera, SceneError  # noqa: E402
from engine.validate import validate_camera  # noqa: E402

# Settings away from the defaults, so a swapped or dropped one shows.
SETTINGS = dict(fisheye_fov=3.6, fisheye_lens=8.0, latitude=(-1.1, 1.3), longitude=(-2.5, 2.9),
                fisheye_polynomial=(-0.001, -0.04, 0.0003, -2e-5, 1e-7), cylinder=(-2.0, 2.4, -0.8, 1.5, 1.3))


def pano_camera(kind, resolution=(64, 40), **extra):
    return Camera(kind="PANO", panorama_type=kind, resolution=resolution, **{**SETTINGS, **extra})


def grid(n=41):
    u, v = np.meshgrid(np.linspace(0.02, 0.98, n), np.linspace(0.03, 0.97, n))
    return u.ravel(), v.ravel()


@pytest.mark.parametrize("kind", TYPES)
def test_direction_round_trip(kind):
    """direction_to_X(X_to_direction(u, v)) = (u, v) wherever there is a
    direction, and every such direction has unit length (the cylinder's
    up to its normalization)."""
    pano = Panorama(pano_camera(kind))
    u, v = grid()
    d = pano.to_direction(u, v)
    inside = d.any(axis=1)
    assert inside.sum() > 0.4 * len(u)
    if kind != "CENTRAL_CYLINDRICAL":
        np.testing.assert_allclose(np.linalg.norm(d[inside], axis=1), 1.0, atol=1e-12)
    back_u, back_v = pano.from_direction(d[inside] * 2.5)       # the length does not matter
    np.testing.assert_allclose(back_u, u[inside], atol=1e-9)
    np.testing.assert_allclose(back_v, v[inside], atol=1e-9)


@pytest.mark.parametrize("kind", ["MIRRORBALL", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID",
                                  "FISHEYE_LENS_POLYNOMIAL"])
def test_rim(kind):
    """Beyond the rim there is no direction (Cycles' zero vector); the
    others reach every (u, v)."""
    pano = Panorama(pano_camera(kind, fisheye_fov=1.0))
    corners = pano.to_direction(np.array([0.0, 1.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0]))
    assert not corners.any()
    assert pano.to_direction(np.array([0.5]), np.array([0.5])).any()


def test_cycles_values():
    """Points of Cycles' formulas worked by hand: the frame's centre looks
    down the view axis (+X in panorama space, the mirror ball's -Y), the
    equidistant fisheye's radius is linear in angle, the equisolid's
    2 f sin(theta / 2), the polynomial's theta = -(k0 + k1 r + ...)."""
    centre = np.array([0.5]), np.array([0.5])
    for kind in ("EQUIANGULAR_CUBEMAP_FACE", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID"):
        np.testing.assert_allclose(Panorama(pano_camera(kind)).to_direction(*centre), [[1.0, 0.0, 0.0]],
                                   atol=1e-12)
    # the ball's centre, normal -Y, reflects I = -Y into -Y: the view axis of a camera looking down -Y
    np.testing.assert_allclose(Panorama(pano_camera("MIRRORBALL")).to_direction(*centre), [[0.0, -1.0, 0.0]],
                               atol=1e-12)
    d = Panorama(pano_camera("MIRRORBALL")).to_direction(np.array([1.0]), np.array([0.5]))
    np.testing.assert_allclose(d, [[0.0, 1.0, 0.0]], atol=1e-12)   # the rim reflects +Y (grazing)
    fov = SETTINGS["fisheye_fov"]
    d = Panorama(pano_camera("FISHEYE_EQUIDISTANT")).to_direction(np.array([0.75]), np.array([0.5]))
    # u' = 0.5: theta = fov / 4, towards -Y (Cycles' -cos(phi) sin(theta))
    np.testing.assert_allclose(d, [[np.cos(fov / 4), -np.sin(fov / 4), 0.0]], atol=1e-12)
    cam = pano_camera("FISHEYE_EQUISOLID")
    width, height = fisheye_sensor(cam)
    assert (width, height) == (36.0, 36.0 * 40 / 64)
    d = Panorama(cam).to_direction(np.array([0.5]), np.array([0.5 + 3.0 / height]))
    theta = 2.0 * np.arcsin(3.0 / (2.0 * SETTINGS["fisheye_lens"]))
    np.testing.assert_allclose(d, [[np.cos(theta), 0.0, np.sin(theta)]], atol=1e-12)
    d = Panorama(pano_camera("FISHEYE_LENS_POLYNOMIAL")).to_direction(np.array([0.5]),
                                                                     np.array([0.5 + 2.0 / height]))
    k = SETTINGS["fisheye_polynomial"]
    theta = -(k[0] + k[1] * 2 + k[2] * 4 + k[3] * 8 + k[4] * 16)
    np.testing.assert_allclose(d, [[np.cos(theta), 0.0, np.sin(theta)]], atol=1e-12)
    # equirectangular: u = 0 is longitude min (measured to the camera's right, -Y here: Cycles'
    # phi = range.x u + range.y = -longitude), v = 0 latitude min
    d = Panorama(pano_camera("EQUIRECTANGULAR")).to_direction(np.array([0.0]), np.array([0.0]))
    lat, lon = SETTINGS["latitude"][0], -SETTINGS["longitude"][0]
    np.testing.assert_allclose(d, [[np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]],
                               atol=1e-12)
    u0, u1, v0, v1, radius = SETTINGS["cylinder"]
    d = Panorama(pano_camera("CENTRAL_CYLINDRICAL")).to_direction(np.array([1.0]), np.array([1.0]))
    np.testing.assert_allclose(d, [[np.cos(-u1), np.sin(-u1), v1 / radius]], atol=1e-12)


def test_sensor_fit():
    """Cycles' fisheye sensor: AUTO fits the wider side with sensor_width
    (a square frame fits vertically), VERTICAL reads sensor_height."""
    assert fisheye_sensor(pano_camera("FISHEYE_EQUISOLID", (30, 60))) == (18.0, 36.0)
    assert fisheye_sensor(pano_camera("FISHEYE_EQUISOLID", (40, 40))) == (36.0, 36.0)
    assert fisheye_sensor(pano_camera("FISHEYE_EQUISOLID", (60, 30), sensor_fit="VERTICAL")) == (48.0, 24.0)
    cam = pano_camera("FISHEYE_EQUISOLID", (60, 30), sensor_fit="HORIZONTAL", pixel_aspect=(1.0, 2.0))
    assert fisheye_sensor(cam) == (36.0, 36.0)


def model(kind, **extra):
    return CameraModel(pano_camera(kind, **extra), PixelFilter("BOX", 1.0))


def centre_rays(cam_model):
    pix = np.arange(cam_model.width * cam_model.height)
    half = np.full(len(pix), 0.5)
    return pix, cam_model.generate(pix, half, half, half, half)


def test_rays_start_at_the_near_clip_along_the_ray():
    cm = model("EQUIRECTANGULAR", clip_start=0.25, clip_end=40.0,
               matrix=np.array([[0, -1, 0, 1.0], [1, 0, 0, 2.0], [0, 0, 1, 3.0], [0, 0, 0, 1]]))
    pix, (o, d, tmax) = centre_rays(cm)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(o, np.array([1.0, 2.0, 3.0]) + 0.25 * d, atol=1e-12)
    np.testing.assert_allclose(tmax, 39.75)
    # The pixel at the frame's centre looks down the camera's -Z (here world -Z: the matrix turns about z).
    w, h = cm.width, cm.height
    centre = (h // 2) * w + w // 2
    u, v = (w // 2 + 0.5) / w, (h - 1 - h // 2 + 0.5) / h
    expected = cm.pano.to_local(cm.pano.to_direction(np.array([u]), np.array([v]))) @ cm.rot.T
    np.testing.assert_allclose(d[centre], expected[0], atol=1e-12)


def test_outside_the_rim():
    cm = model("FISHEYE_EQUIDISTANT", fisheye_fov=np.pi)
    pix = np.arange(cm.width * cm.height)
    half = np.full(len(pix), 0.5)
    out = cm.outside(pix, half, half)
    px, py = pix % cm.width, cm.height - 1 - pix // cm.width
    r = np.hypot((px + 0.5) / cm.width - 0.5, (py + 0.5) / cm.height - 0.5) * 2.0
    np.testing.assert_array_equal(out, r > 1.0)
    assert out[0] and not out[(cm.height // 2) * cm.width + cm.width // 2]
    assert not model("EQUIRECTANGULAR").outside(pix, half, half).any()


def test_spread_is_the_angle_per_pixel():
    """An equirectangular frame of W pixels over 360 degrees: at the
    equator one pixel turns the ray by 2 pi / W across and pi / H up."""
    cm = model("EQUIRECTANGULAR", latitude=(-0.5 * np.pi, 0.5 * np.pi), longitude=(-np.pi, np.pi),
               resolution=(360, 180))
    dp, dd = cm.spread(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]))
    expected = 0.5 * (2 * np.sin(np.pi / 360) + 2 * np.sin(np.pi / 360))   # chords of 1 degree
    np.testing.assert_allclose(dd, expected, rtol=1e-6)
    np.testing.assert_array_equal(dp, 0.0)
    # at the rim of a fisheye, one pixel outward has no direction: the inward step is used
    fish = model("FISHEYE_EQUIDISTANT", fisheye_fov=np.pi, resolution=(64, 64))
    edge = fish.pano.to_local(fish.pano.to_direction(np.array([0.999]), np.array([0.5])))
    _, dd = fish.spread(edge)

    def equidistant(x, y):      # Cycles' fisheye_to_direction at theta = r fov / 2, fov = pi
        r, phi = np.hypot(x, y), np.arctan2(y, x)
        theta = r * np.pi / 2
        return np.array([np.cos(theta), -np.cos(phi) * np.sin(theta), np.sin(phi) * np.sin(theta)])
    across = 2 * np.sin(np.pi / 64 / 2)                 # one pixel inwards: pi / 64 of polar angle
    up = np.linalg.norm(equidistant(0.998, 2 / 64) - equidistant(0.998, 0.0))
    np.testing.assert_allclose(dd, 0.5 * (across + up), rtol=1e-6)


def test_depth_of_field_focuses_along_the_ray():
    """Cycles' panoramic lens: every ray of a pixel passes through its
    unshifted direction's point at the focus distance, from a lens point
    perpendicular to that direction."""
    cm = model("EQUIRECTANGULAR", aperture_radius=0.3, focus_distance=4.0, clip_start=0.0)
    n = 500
    rng = np.random.default_rng(3)
    pix = rng.integers(0, cm.width * cm.height, n)
    half = np.full(n, 0.5)
    o, d, _ = cm.generate(pix, half, half, rng.random(n), rng.random(n))
    _, (o0, d0, _) = centre_rays(cm)
    focus = d0[pix] * 4.0 + cm.pos
    t = np.einsum("ij,ij->i", focus - o, d)
    np.testing.assert_allclose(o + d * t[:, None], focus, atol=1e-9)
    offset = o - cm.pos
    np.testing.assert_allclose(np.einsum("ij,ij->i", offset, d0[pix]), 0.0, atol=1e-12)
    assert np.linalg.norm(offset, axis=1).max() <= 0.3 + 1e-12 and np.linalg.norm(offset, axis=1).mean() > 0.1


def _turn(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


# A camera looking along world +X, up +Z (Blender's camera frame: -Z ahead).
LEVEL = np.array([[0, 0, -1, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])


def test_vector_pass_of_a_turning_equirectangular_camera():
    """Cycles' panoramic motion vector: (u, v) of the point's direction by
    the camera at each step, times the frame's size.  A full equirectangular
    camera turning by a about its up axis moves every still point by
    a / 2 pi of the width, and not up or down: (pre - centre, centre - post)
    = (-a W / 2 pi, 0, -a W / 2 pi, 0) away from the seam."""
    from engine.render import render
    from engine.scene import Instance, Material, RenderSettings, Scene, World
    from engine.testscenes import quad
    angle, w, h = 0.1, 64, 32
    camera = Camera(kind="PANO", panorama_type="EQUIRECTANGULAR", matrix=LEVEL, resolution=(w, h),
                    vector_motion=np.array([_turn(-angle) @ LEVEL, LEVEL, _turn(angle) @ LEVEL]))
    floor = quad([[-50, -50, -1], [50, -50, -1], [50, 50, -1], [-50, 50, -1]])
    scene = Scene(meshes=[floor], instances=[Instance(mesh=0, matrix=np.eye(4), materials=[0])],
                  materials=[Material()], camera=camera, world=World(color=(0.1, 0.1, 0.1)))
    r = render(scene, RenderSettings(samples=2, samples_per_pass=2, seed=1, max_bounces=0, passes=("Vector",)))
    vector = r.passes["Vector"].astype(np.float64).reshape(h, w, 4)
    below = vector[h // 2 + 2:, 2:-2]          # the floor, away from the horizon and the seam
    want = -angle * w / (2 * np.pi)
    np.testing.assert_allclose(below[..., 0], want, atol=1e-4)
    np.testing.assert_allclose(below[..., 2], want, atol=1e-4)
    np.testing.assert_allclose(below[..., [1, 3]], 0.0, atol=1e-4)


def test_validation():
    for bad in (dict(panorama_type="FISHEYE_STEREOGRAPHIC"), dict(fisheye_lens=0.0),
                dict(fisheye_fov=float("nan")), dict(cylinder=(-1, 1, -1, 1, 0.0)),
                dict(latitude=(0.0, float("inf")))):
        cam = pano_camera("FISHEYE_EQUISOLID")
        for key, value in bad.items():
            setattr(cam, key, value)
        with pytest.raises(SceneError):
            validate_camera(cam)
    validate_camera(pano_camera("FISHEYE_EQUISOLID"))


def test_window_coordinate():
    """Cycles' camera_world_to_ndc for a panoramic camera: (u, v) of the
    point's direction (direction_to_panorama, no shift), z = 0."""
    from engine.nodes.input_nodes import _window_coords

    class Points:
        def __init__(self, camera, p):
            self.camera, self.p = camera, p

        def __len__(self):
            return len(self.p)
    cam = pano_camera("FISHEYE_EQUIDISTANT", matrix=LEVEL.copy(), shift_x=0.1)
    cam.matrix[:3, 3] = (1.0, 2.0, 3.0)
    pano = Panorama(cam)
    u, v = np.array([0.5, 0.3, 0.62]), np.array([0.5, 0.7, 0.41])
    d = pano.to_local(pano.to_direction(u, v)) @ LEVEL[:3, :3].T
    points = np.array([1.0, 2.0, 3.0]) + d * np.array([[2.0], [0.5], [7.0]])
    out = _window_coords(Points(cam, points))
    np.testing.assert_allclose(out, np.stack([u, v, np.zeros(3)], axis=1), atol=1e-12)
