"""The Vector pass of points and curves (engine/vector_pass.py) against
analytic answers, Cycles' rule (primitive_motion_vector): a point's hit
moves as the point's centre, a curve's as its segment's two keys mixed
linearly by u, each carried to frame - 1 / frame + 1 by the item's
``vector_motion`` (object-to-world) and ``vector_positions`` (its points
there, deformation) and projected by the camera at that step.

* Orthographic camera looking down: a sliding cloud, a sliding strand and
  a strand whose keys are moved (deformation) write exactly the motion in
  pixels wherever they are hit; a sheared strand writes each key mix's
  motion (channels in the ratio of the two steps; against the Position
  pass within the bound a narrow box filter gives).
* Perspective: a sphere coming towards the camera writes its centre's
  motion in every pixel it covers (the centre's rule; its surface points
  would spread by pixels), against the projection written out here.
* Zero with motion blur on; the camera's motion alone for a still cloud.
* Hostile steps: NaN, infinite and 1e300 give a finite pass and a warning
  naming the item; steps of the wrong shape are a named SceneError.
"""
import numpy as np
import pytest

from engine import embree_c
from engine.render import render
from engine.scene import (Camera, HairCurves, Material, PointCloud, RenderSettings, Scene, SceneError, World)

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")

W = H = 16
SCALE = 4.0                      # ortho scale: 4 m over 16 pixels, 0.25 m a pixel
PIXEL = SCALE / W
FILTER = 0.01                    # a box filter's width in pixels (the shear test)


def _top_camera(kind="ORTHO"):
    cam = np.eye(4)
    cam[:3, 3] = (0.0, 0.0, 5.0)
    return Camera(matrix=cam, kind=kind, ortho_scale=SCALE, resolution=(W, H))


def _scene(points=(), curves=(), camera=None):
    return Scene(meshes=[], instances=[], points=list(points), curves=list(curves), materials=[Material()],
                 camera=camera or _top_camera(), world=World(color=(0.1, 0.1, 0.1)))


def _steps(step):
    """Object-to-world at frame - 1, frame, frame + 1 moving ``step`` a frame."""
    out = np.repeat(np.eye(4)[None], 3, axis=0)
    for k in range(3):
        out[k, :3, 3] = np.asarray(step) * (k - 1)
    return out


def _cloud(**kw):
    """Nine spheres of radius 0.45 on a grid 1.2 apart in the plane z = 0."""
    g = np.arange(-1, 2) * 1.2
    p = np.array([(x, y, 0.0) for x in g for y in g])
    return PointCloud(p, np.full(len(p), 0.45), materials=[0], name="cloud", **kw)


def _strand(**kw):
    """One straight strand along x at y = z = 0 (radius 0.3), 13 keys 0.5
    apart from x = -3 to 3: evenly spaced collinear keys make the visible
    Catmull-Rom segments straight, C(u) = the keys' linear mix."""
    x = np.linspace(-3.0, 3.0, 13)
    p = np.c_[x, np.zeros_like(x), np.zeros_like(x)]
    return HairCurves(p, np.full(len(p), 0.3), np.array([0, len(p)]), materials=[0], name="strand", **kw)


def _render(scene, samples=4, **kw):
    r = render(scene, RenderSettings(samples=samples, samples_per_pass=samples, seed=1, max_bounces=0,
                                     passes=("Vector", "Position", "Depth"), **kw))
    hit = np.isfinite(r.passes["Depth"][..., 0]) & (r.passes["Depth"][..., 0] < 1e9)
    return r.passes["Vector"].astype(np.float64), r.passes["Position"].astype(np.float64), hit, r.warnings


def _covered(vector):
    """Pixels some sample of which hit (the pass is 0 where none did)."""
    return np.any(vector != 0.0, axis=2)


def test_a_sliding_cloud_moves_minus_its_motion_exactly():
    v, _, _, _ = _render(_scene(points=[_cloud(vector_motion=_steps((0.5, -0.25, 0.0)))]))
    on = _covered(v)
    assert on.sum() > 0.3 * W * H
    want = np.array([-0.5, 0.25, -0.5, 0.25]) / PIXEL
    assert np.allclose(v[on], want, rtol=0, atol=1e-4), v[on][:3]


def test_a_deformed_cloud_moves_each_point_by_its_own_steps():
    """Each point moved by its own offset (vector_positions): its pixels
    write its offset, the points beside it theirs."""
    cloud = _cloud()
    offsets = np.c_[np.linspace(-0.4, 0.4, 9), np.linspace(0.3, -0.3, 9), np.zeros(9)]
    cloud.vector_positions = np.stack([cloud.positions - offsets, cloud.positions, cloud.positions + 2 * offsets])
    v, _, _, _ = _render(_scene(points=[cloud]))
    # the centre pixel of each sphere: its point's offsets
    for (x, y, _), off in zip(cloud.positions, offsets):
        col, row = int((x + SCALE / 2) / PIXEL), int((SCALE / 2 - y) / PIXEL)
        want = np.r_[-off[:2], -2 * off[:2]] / PIXEL
        assert np.allclose(v[row, col], want, atol=1e-4), ((x, y), v[row, col], want)


@pytest.mark.parametrize("how", ["transform", "deformation"])
def test_a_sliding_strand_moves_exactly(how):
    """Transform motion, and deformation motion (every key moved alike), of a strand."""
    strand = _strand()
    if how == "transform":
        strand.vector_motion = _steps((0.0, 0.5, 0.0))
    else:
        strand.vector_positions = strand.points[None] + _steps((0.0, 0.5, 0.0))[:, None, :3, 3]
    v, _, _, _ = _render(_scene(curves=[strand]))
    on = _covered(v)
    assert on.sum() >= 2 * W, on.sum()          # the strand's 0.6 m width: two rows at least
    want = np.array([0.0, -0.5, 0.0, -0.5]) / PIXEL
    assert np.allclose(v[on], want, rtol=0, atol=1e-4), v[on][:3]


def test_a_sheared_strand_moves_by_its_keys_mixed_by_u():
    """Keys moved along y by -0.1 x at frame - 1 and +0.25 x at frame + 1:
    each hit writes (-0.1 x, -0.25 x) / pixel in y at the x of its keys'
    linear mix by u (on these straight segments the strand's own x).  A box
    filter FILTER pixels wide keeps every sample within FILTER / 2 pixels of
    the centre ray the Position pass reads, so each pixel is held to a bound
    derived from it, no statistics."""
    strand = _strand()
    x = strand.points[:, 0]
    shift = np.zeros((3,) + strand.points.shape)
    shift[0, :, 1], shift[2, :, 1] = -0.1 * x, 0.25 * x
    strand.vector_positions = strand.points[None] + shift
    v, pos, hit, _ = _render(_scene(curves=[strand]), samples=4, filter_type="BOX", filter_width=FILTER)
    rows = np.flatnonzero(np.all(hit, axis=1))        # rows whose centre rays all meet the strand
    assert len(rows) >= 2, rows
    v, pos = v[rows], pos[rows]
    assert np.allclose(v[..., 3], 2.5 * v[..., 1], rtol=1e-5, atol=1e-5)   # the two steps, per sample
    assert np.allclose(v[..., [0, 2]], 0.0, atol=1e-6)
    # |x_sample - x_centre| <= FILTER / 2 pixels: |pre - (-0.1 x_centre / pixel)| <= 0.1 FILTER / 2
    bound = 0.1 * FILTER / 2 + 1e-5
    gap = np.abs(v[..., 1] + 0.1 * pos[..., 0] / PIXEL)
    print(f"vector pass shear: max gap {gap.max():.1e} px over {gap.size} pixels (bound {bound:.1e}); "
          f"the keys' mix at u + 0.1 (or the wrong step) is off by {0.1 * 0.5 / PIXEL * 0.1:.1e} px or more")
    assert gap.max() <= bound, gap.max()


def _perspective_raster(p, cam, lens=50.0, sensor=36.0):
    """Full-frame raster (x, y up) of world points by a perspective camera
    (sensor fit horizontal, W >= H), written out apart from the engine's."""
    local = (p - cam[:3, 3]) @ cam[:3, :3]
    f = lens / sensor * W
    return np.stack([W / 2 + f * local[:, 0] / -local[:, 2], H / 2 + f * local[:, 1] / -local[:, 2]], axis=1)


def test_a_sphere_coming_closer_writes_its_centres_motion_everywhere():
    camera = _top_camera("PERSP")
    cloud = PointCloud(np.array([[0.3, 0.2, 0.0]]), np.array([1.0]), materials=[0], name="ball",
                       vector_motion=_steps((0.2, 0.0, 0.8)))
    v, _, _, _ = _render(_scene(points=[cloud], camera=camera))
    on = _covered(v)
    assert on.sum() > 20, on.sum()
    m = np.asarray(camera.matrix, np.float64)
    c = np.array([[0.3, 0.2, 0.0]])
    centre = _perspective_raster(c, m)
    pre = _perspective_raster(c - [0.2, 0.0, 0.8], m) - centre
    post = centre - _perspective_raster(c + [0.2, 0.0, 0.8], m)
    want = np.r_[pre[0], post[0]]
    assert np.allclose(v[on], want, rtol=1e-5, atol=1e-4), (v[on][:3], want)
    # the surface points' motion would differ by pixels over the sphere: the
    # rule is told apart (a pixel at its rim, 1 m off the centre's depth)
    rim = np.array([[0.3 + 0.9, 0.2, 0.0]])
    rim_pre = _perspective_raster(rim - [0.2, 0.0, 0.8], m) - _perspective_raster(rim, m)
    assert abs(rim_pre[0, 0] - pre[0, 0]) > 0.2


def test_zero_with_motion_blur_on():
    cloud = _cloud(vector_motion=_steps((0.5, 0.0, 0.0)), motion=_steps((0.1, 0.0, 0.0)))
    v, _, _, _ = _render(_scene(points=[cloud], curves=[_strand(vector_motion=_steps((0.5, 0.0, 0.0)))]))
    assert np.all(v == 0.0)


def test_a_moving_camera_moves_still_points_and_strands_the_other_way():
    camera = _top_camera()
    camera.vector_motion = _steps((0.0, 0.5, 0.0)) + np.array([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 5.0],
                                                               [0, 0, 0, 0]])
    v, _, _, _ = _render(_scene(points=[_cloud()], curves=[_strand()], camera=camera))
    on = _covered(v)
    assert on.sum() > 0.3 * W * H
    assert np.allclose(v[on], np.array([0.0, 2.0, 0.0, 2.0]), atol=1e-4), v[on][:3]


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e300])
@pytest.mark.parametrize("field", ["vector_motion", "vector_positions"])
def test_hostile_steps_give_a_finite_pass_and_a_named_warning(bad, field):
    cloud, strand = _cloud(vector_motion=_steps((0.5, 0.0, 0.0))), _strand(vector_motion=_steps((0.5, 0.0, 0.0)))
    for item, points in ((cloud, cloud.positions), (strand, strand.points)):
        steps = (_steps((0.5, 0.0, 0.0)) if field == "vector_motion"
                 else np.repeat(np.asarray(points, np.float64)[None], 3, axis=0))
        steps[0].flat[1] = bad
        setattr(item, field, steps)
    v, _, _, warnings = _render(_scene(points=[cloud], curves=[strand]))
    assert np.isfinite(v).all() and np.all(v == 0.0)    # both taken as still, the camera is
    for name in ("'cloud'", "'strand'"):
        assert any(name in w and "Vector" in w for w in warnings), warnings


def test_a_huge_finite_step_writes_a_finite_pass():
    """Steps of 1e30 (finite in float32): vectors beyond float32's sums are written as 0."""
    cloud = _cloud(vector_motion=_steps((1e30, 0.0, 0.0)))
    v, _, _, _ = _render(_scene(points=[cloud]))
    assert np.isfinite(v).all()


@pytest.mark.parametrize("field, value", [
    ("vector_motion", np.zeros((2, 4, 4))),
    ("vector_motion", np.zeros((3, 3, 3))),
    ("vector_positions", np.zeros((3, 5, 3))),
    ("vector_positions", np.zeros((3, 9, 2))),
    ("vector_positions", np.array([["a"] * 3] * 3)),
])
def test_steps_of_the_wrong_shape_are_a_named_error(field, value):
    cloud = _cloud()
    setattr(cloud, field, value)
    with pytest.raises(SceneError, match=f"point cloud 0 \\('cloud'\\) {field}"):
        _render(_scene(points=[cloud]))
