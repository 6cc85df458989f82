"""engine/stereo.py (Cycles' spherical_stereo_transform) in closed form,
and a camera's spherical stereo rays through CameraModel."""
import numpy as np
import pytest

from engine.camera import CameraModel, PixelFilter
from engine.scene import Camera, SceneError
from engine.stereo import Stereo, transform
from engine.validate import validate_camera


def unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_offset_is_sideways_and_rays_converge():
    rng = np.random.default_rng(3)
    d = unit(rng.normal(size=(500, 3)) * [1.0, 1.0, 0.4])
    o = rng.normal(size=(500, 3))
    eye = Stereo(offset=-0.03, convergence=2.5)
    o2, d2 = transform(eye, o, d)
    shift = o2 - o
    # Half the interocular distance, horizontal, at right angles to the ray.
    assert np.allclose(np.linalg.norm(shift, axis=1), 0.03)
    assert np.allclose(shift[:, 2], 0.0) and np.allclose(np.sum(shift * d, axis=1), 0.0)
    # The left eye (offset < 0) sits to the ray's left: cross(d, up) points right.
    assert (np.sum(shift * np.cross(d, [0.0, 0.0, 1.0]), axis=1) < 0).all()
    # The eye's ray meets the centre's at the convergence distance.
    assert np.allclose(np.linalg.norm(d2, axis=1), 1.0)
    meet = o + 2.5 * d
    along = np.sum((meet - o2) * d2, axis=1)
    assert np.allclose(o2 + along[:, None] * d2, meet, atol=1e-12)


def test_parallel_keeps_directions():
    d = unit([[1.0, 0.2, 0.1], [0.0, 1.0, -0.5]])
    o2, d2 = transform(Stereo(offset=0.5), np.zeros((2, 3)), d)
    assert np.array_equal(d2, d) and not np.allclose(o2, 0.0)


def test_pole_merge_fades_the_offset():
    altitude = np.radians([0.0, 30.0, 45.0, 55.0, 69.0, 71.0, 90.0])
    d = np.stack([np.cos(altitude), np.zeros(7), np.sin(altitude)], axis=1)
    eye = Stereo(offset=0.1, pole_merge=(np.radians(40.0), np.radians(70.0)))
    o2, _ = transform(eye, np.zeros((7, 3)), d)
    fac = np.clip((altitude - np.radians(40.0)) / np.radians(30.0), 0.0, 1.0)
    expected = np.where(altitude > np.radians(70.0), 0.0, 0.1 * np.cos(fac * np.pi / 2))
    assert np.allclose(np.linalg.norm(o2, axis=1), expected, atol=1e-15)


def test_straight_up_and_hostile_directions_stay_finite():
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    o2, d2 = transform(Stereo(offset=0.2, convergence=1e-3), np.zeros((3, 3)), d)
    assert np.isfinite(o2).all() and np.isfinite(d2).all()
    assert np.allclose(o2[:2], 0.0)     # no side to offset towards: Cycles' normalize(0) = 0


def test_camera_rays_of_each_eye():
    """An equirectangular camera's eyes: origins off the centre by the half
    interocular distance, opposite sides, and the eyes' rays cross at the
    convergence distance; the mono camera is unchanged."""
    base = dict(kind="PANO", panorama_type="EQUIRECTANGULAR", resolution=(16, 8), clip_start=0.0)
    pix = np.arange(128)
    u = np.full(128, 0.5)
    rays = {}
    for name, offset in (("mono", 0.0), ("left", -0.04), ("right", 0.04)):
        cam = Camera(**base, stereo_offset=offset, stereo_convergence=3.0)
        validate_camera(cam)
        rays[name] = CameraModel(cam, PixelFilter())._panoramic(*CameraModel(cam, PixelFilter())._raster(pix, u, u),
                                                                 u, u)
    assert np.allclose(rays["mono"][0], 0.0)
    for name in ("left", "right"):
        assert np.allclose(np.linalg.norm(rays[name][0], axis=1), 0.04)
    assert np.allclose(rays["left"][0], -rays["right"][0])
    for name in ("left", "right"):   # each eye's ray passes the centre's ray's point at 3 m
        o, d = rays[name]
        target = 3.0 * rays["mono"][1]
        along = np.sum((target - o) * d, axis=1)
        assert np.allclose(o + along[:, None] * d, target, atol=1e-12)


@pytest.mark.parametrize("field, value", [("stereo_offset", np.nan), ("stereo_offset", np.inf),
                                          ("stereo_convergence", 0.0), ("stereo_convergence", np.nan),
                                          ("stereo_pole_merge", (np.nan, 1.0))])
def test_hostile_stereo_settings_are_named(field, value):
    with pytest.raises(SceneError, match="stereo"):
        validate_camera(Camera(**{field: value}))
