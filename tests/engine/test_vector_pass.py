"""The Vector pass (engine/vector_pass.py) against its analytic answer:
an orthographic camera looking down at a plane, the plane or the camera
sliding, the plane's mesh stretching; zero with motion blur on; finite with
NaN steps.  Cycles' sign: (pre - centre, centre - post) in raster pixels."""
import numpy as np

from engine.render import render
from engine.scene import Camera, Instance, Material, Scene, World, RenderSettings
from engine.testscenes import quad
from ember_stats import family_level, power_line, z_threshold

W = H = 16
SCALE = 4.0                      # ortho scale: 4 m over 16 pixels, 0.25 m a pixel
PIXEL = SCALE / W


def _scene(shift=(0.0, 0.0, 0.0)):
    plane = quad([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]])
    cam = np.eye(4)
    cam[:3, 3] = (0.0, 0.0, 5.0)
    camera = Camera(matrix=cam, kind="ORTHO", ortho_scale=SCALE, resolution=(W, H))
    return Scene(meshes=[plane], instances=[Instance(mesh=0, matrix=np.eye(4), materials=[0])],
                 materials=[Material()], camera=camera, world=World(color=(0.1, 0.1, 0.1)))


def _steps(step):
    """Object-to-world at frame - 1, frame, frame + 1 moving ``step`` a frame."""
    out = np.repeat(np.eye(4)[None], 3, axis=0)
    for k in range(3):
        out[k, :3, 3] = np.asarray(step) * (k - 1)
    return out


def _vector(scene, **kw):
    r = render(scene, RenderSettings(samples=4, samples_per_pass=4, seed=1, max_bounces=0,
                                     passes=("Vector", "Position"), **kw))
    return r.passes["Vector"].astype(np.float64), r.passes["Position"].astype(np.float64)


def test_a_sliding_plane_moves_minus_its_motion():
    scene = _scene()
    scene.instances[0].vector_motion = _steps((0.5, -0.25, 0.0))
    v, _ = _vector(scene)
    want = np.array([-0.5, 0.25, -0.5, 0.25]) / PIXEL
    assert np.allclose(v, want, atol=1e-4), v.reshape(-1, 4)[:3]


def test_a_moving_camera_moves_the_still_plane_the_other_way():
    scene = _scene()
    scene.camera.vector_motion = _steps((0.0, 0.5, 0.0)) + np.array([[0, 0, 0, 0], [0, 0, 0, 0],
                                                                       [0, 0, 0, 5.0], [0, 0, 0, 0]])
    v, _ = _vector(scene)
    assert np.allclose(v, np.array([0.0, 2.0, 0.0, 2.0]), atol=1e-4), v.reshape(-1, 4)[:3]


def test_a_stretching_mesh_moves_each_point_by_its_stretch():
    scene = _scene()
    p = scene.meshes[0].positions
    stretch = np.array([0.8, 1.0, 1.25])       # x scale at frame - 1, frame, frame + 1
    scene.meshes[0].vector_motion = np.array([p * [s, 1.0, 1.0] for s in stretch])
    v, pos = _vector(scene)
    # pre = (0.8 - 1) x / pixel, post = (1 - 1.25) x / pixel at each sample's
    # x: their ratio is exact per pixel, whatever the filter's offsets
    assert np.allclose(v[..., 2], 1.25 * v[..., 0], rtol=1e-5, atol=1e-5)
    assert np.allclose(v[..., [1, 3]], 0.0, atol=1e-6)
    # the mean over pixels of the samples' offset from the centre is 0 (a
    # symmetric filter): z-test with the measured standard error
    d = (v[..., 0] - (0.8 - 1.0) * pos[..., 0] / PIXEL).ravel()
    se = d.std(ddof=1) / np.sqrt(d.size)
    level = family_level("vector pass: stretching mesh", 1)
    print(power_line("vector pass stretch (pixels)", se, level))
    assert abs(d.mean()) <= z_threshold(level) * se, (d.mean(), se)
    # the slope is resolved: a wrong factor (e.g. using the next step) moves
    # pixels at |x| ~ 1 m by 0.2 pixel, far beyond the noise of the mean
    assert z_threshold(level) * se < 0.05


def test_zero_with_motion_blur_on():
    scene = _scene()
    scene.instances[0].vector_motion = _steps((0.5, 0.0, 0.0))
    scene.instances[0].motion = _steps((0.1, 0.0, 0.0))
    v, _ = _vector(scene)
    assert np.all(v == 0.0)


def test_nan_steps_give_a_finite_pass():
    scene = _scene()
    bad = _steps((0.5, 0.0, 0.0))
    bad[0, 0, 3] = np.nan
    scene.instances[0].vector_motion = bad
    cam = np.repeat(np.asarray(scene.camera.matrix)[None], 3, axis=0)
    cam[2, 1, 1] = np.inf
    scene.camera.vector_motion = cam
    v, _ = _vector(scene)
    assert np.isfinite(v).all() and np.all(v == 0.0)


def test_still_scene_writes_zero():
    v, _ = _vector(_scene())
    assert np.all(v == 0.0)
