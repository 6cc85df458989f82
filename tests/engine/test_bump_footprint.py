"""Cycles' bump over the ray footprint (engine.textures.footprint_bump): the
height at P, P + w dPdx and P + w dPdy with the compact ray differential
(stages.footprint), and the differentials carried along a path."""
from types import SimpleNamespace

import numpy as np
import pytest

from engine.camera import CameraModel, PixelFilter
from engine.integrator import _interaction
from engine.integrator.stages import footprint, spread_from
from engine.nodes.rays import make_orthonormals
from engine.render import prepare
from engine.scene import (Bump, Camera, Instance, Material, Math, Mesh, NodeCall, NodeOutput, RenderSettings,
                          Scene)


def _quad_scene(material):
    mesh = Mesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    cam = np.eye(4)
    cam[2, 3] = 5.0
    return Scene([mesh], [Instance(0, np.eye(4), [0])], [material],
                 camera=Camera(kind="ORTHO", ortho_scale=4.0, resolution=(8, 8), matrix=cam))


def _gradient():
    """Generated x on the 2 m quad: g = (x + 1) / 2 (a linear Gradient texture)."""
    return NodeOutput(NodeCall("ShaderNodeTexGradient", {}, {"gradient_type": "LINEAR"}), "Fac")


def _bent(height, xy, dp, distance=0.4, width=0.1):
    """The perturbed normals at points xy of the quad seen from above, with
    ray footprints of radius dp there (None: no differentials)."""
    bump = Bump(height, 1.0, distance)
    bump.filter_width = width
    ctx = prepare(_quad_scene(Material("bumped", normal=bump)), RenderSettings(samples=1))
    o = np.column_stack([xy, np.full(len(xy), 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (len(xy), 1))
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(len(xy), 10.0))
    paths = SimpleNamespace(o=o, d=d, mis_o=o)
    if dp is not None:
        paths.spread = np.column_stack([np.full(len(xy), dp), np.zeros(len(xy))])
    hit = _interaction(ctx, paths, t, prim, bu, bv)
    return ctx.materials.textures.perturb(hit, ctx.triangles)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


XY = np.array([[0.2, 0.3], [-0.5, 0.1], [0.6, -0.7]])


@pytest.mark.parametrize("dp", [1e-3, 0.05, 0.5])
def test_a_linear_height_bends_as_the_limit_at_any_footprint(dp):
    """h = g rises 0.5 per metre along x: forward differences are exact, so
    every footprint gives normalize(n - distance grad h)."""
    want = _unit(np.array([-0.4 * 0.5, 0.0, 1.0]))
    np.testing.assert_allclose(_bent(_gradient(), XY, dp), [want] * len(XY), atol=2e-4 if dp < 0.01 else 2e-6)


def test_a_curved_height_is_differenced_forward_over_the_footprint():
    """h = g^2 (curvature 1/2 per square metre along x): Cycles' normal is
    normalize(n - distance sum_i (h(P + s a_i) - h(P)) / s a_i) with s =
    width x dP along make_orthonormals(Ng) (a_i orthonormal in the plane,
    n = Ng), which differs from the limit normal by the footprint's
    curvature term; no footprint keeps the limit."""
    height = Math("MULTIPLY", _gradient(), _gradient())
    dp, width, distance = 0.5, 0.1, 0.4
    s = width * dp
    a, b = make_orthonormals(np.array([[0.0, 0.0, 1.0]]))
    h = lambda p: ((p[..., 0] + 1.0) / 2.0) ** 2
    p = np.column_stack([XY, np.zeros(len(XY))])
    g_fd = sum(((h(p + s * axis) - h(p)) / s)[:, None] * axis for axis in (a, b))
    want = _unit(np.array([0.0, 0.0, 1.0]) - distance * g_fd)
    g = (XY[:, 0] + 1.0) / 2.0
    limit = _unit(np.column_stack([-distance * g, np.zeros(len(XY)), np.ones(len(XY))]))
    got = _bent(height, XY, dp, distance, width)
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert np.abs(want - limit).max() > 1e-3      # the curvature term is seen
    np.testing.assert_allclose(_bent(height, XY, None, distance, width), limit, atol=2e-5)


def test_a_zero_filter_width_bends_nothing():
    """Width 0: the three heights coincide and Cycles' normalize(0) keeps n."""
    np.testing.assert_allclose(_bent(_gradient(), XY, 0.1, width=0.0), [[0.0, 0.0, 1.0]] * len(XY), atol=1e-12)


def test_the_footprint_grows_along_the_path_and_keeps_its_spread():
    """sd->dP = ray dP + t dD from the ray's last vertex; a bounce makes the
    hit's footprint the next ray's dP and keeps dD (Cycles' compact
    differentials)."""
    paths = SimpleNamespace(mis_o=np.zeros((2, 3)), spread=np.array([[0.01, 0.002], [0.0, 0.001]]))
    p = np.array([[0.0, 3.0, 4.0], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose(footprint(paths, p), [0.01 + 5 * 0.002, 0.001])
    np.testing.assert_allclose(spread_from(paths, p), [[0.02, 0.002], [0.001, 0.001]])
    assert footprint(SimpleNamespace(mis_o=p, spread=np.full((2, 2), np.nan)), p) is None


def test_camera_rays_start_with_the_pixel_spread_at_the_near_clip():
    """Perspective: dD at the image centre is the pixel's angular size, and
    the ray starts clip_start along the axis with dP = clip_start dD;
    orthographic: dP is the pixel size and dD 0."""
    cam = Camera(kind="PERSP", resolution=(100, 100), lens=50.0, sensor_width=36.0, clip_start=0.5)
    model = CameraModel(cam, PixelFilter("BOX", 1.0))
    dp, dd = model.origin_spread(np.array([[0.0, 0.0, -1.0]]))
    pixel = 36.0 / 50.0 / 100.0
    np.testing.assert_allclose(dd, [pixel], rtol=1e-12)
    np.testing.assert_allclose(dp, [0.5 * pixel], rtol=1e-12)
    ortho = CameraModel(Camera(kind="ORTHO", ortho_scale=4.0, resolution=(8, 8)), PixelFilter("BOX", 1.0))
    dp, dd = ortho.origin_spread(np.array([[0.0, 0.0, -1.0]]))
    np.testing.assert_allclose([dp[0], dd[0]], [0.5, 0.0])


def _set_bump_arrays(normal, dx, dy, heights, strength, d, w):
    """svm_node_set_bump in whole-array NumPy (the form set_bump_rows replaced)."""
    rx, ry = np.cross(dy, normal), np.cross(normal, dx)
    det = np.einsum("ij,ij->i", dx, rx)
    grad = (heights[:, 1] - heights[:, 0])[:, None] * rx + (heights[:, 2] - heights[:, 0])[:, None] * ry
    out = (w * np.abs(det))[:, None] * normal - (d * np.sign(det))[:, None] * grad
    out = out / np.linalg.norm(out, axis=1, keepdims=True)
    out = strength[:, None] * out + (1.0 - strength[:, None]) * normal
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def test_bump_kernels_match_the_array_formulas():
    """textures.bump_steps gives make_orthonormals(Ng) times dP, the steps
    times the width and context._bary_of_offsets' moves; set_bump the
    whole-array svm_node_set_bump, within rounding (whichever form runs)."""
    from engine.nodes.context import _bary_of_offsets
    from engine.textures import bump_steps, set_bump
    rng = np.random.default_rng(5)
    n = 500
    ng = rng.normal(size=(n, 3))
    ng /= np.linalg.norm(ng, axis=1)[:, None]
    dp, w = rng.random(n) * 1e-2, rng.random(n) * 0.2
    tris = SimpleNamespace(e1=rng.normal(size=(n, 3)), e2=rng.normal(size=(n, 3)))
    out = bump_steps(*ng.T, dp, w, *tris.e1.T, *tris.e2.T)
    a, b = make_orthonormals(ng)
    dx, dy = a * dp[:, None], b * dp[:, None]
    np.testing.assert_allclose(np.column_stack(out[:6]), np.column_stack([dx, dy]), rtol=1e-12, atol=1e-18)
    steps = [dx * w[:, None], dy * w[:, None]]
    np.testing.assert_allclose(np.column_stack(out[6:12]), np.column_stack(steps), rtol=1e-12, atol=1e-18)
    moves = _bary_of_offsets(tris, np.arange(n), steps)
    np.testing.assert_allclose(np.column_stack(out[12:]), np.column_stack(moves), rtol=1e-9, atol=1e-15)
    heights = rng.normal(size=(n, 3)) * 1e-3
    strength, d = rng.random(n), rng.random(n) * 0.5
    for invert in (False, True):
        want = _set_bump_arrays(ng, dx, dy, heights, strength, -d if invert else d, w)
        np.testing.assert_allclose(set_bump(ng, dx, dy, heights, strength, d, invert, w), want,
                                   rtol=1e-9, atol=1e-12)
