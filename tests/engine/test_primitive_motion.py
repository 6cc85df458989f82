"""Motion blur of points and curves (engine/primitive_motion.py): Embree
instances of time-stepped SPHERE_POINT / ROUND_CATMULL_ROM_CURVE geometries.

* Rays at random times find the sphere a brute-force float64 test finds
  first among the spheres where they are at that time (transform steps and
  deformation steps interpolated linearly); the hit point lies on that
  sphere.
* A vertical strand sliding along x (transform motion) and one swaying by
  its control points (deformation motion) are hit where they are at each
  ray's time; the hit point lies on the round curve there.
* Hostile: NaN motion positions, radii and steps of the wrong shape are
  named errors; a moving cloud of zero-radius points and one whose steps
  span 10 units render finite pixels.
"""
from dataclasses import replace

import numpy as np
import pytest

from engine import embree_c
from engine.render import prepare, render
from engine.scene import (Camera, HairCurves, Instance, Lobe, Material, PointCloud, PointLight, RenderSettings,
                          Scene, SceneError)
from engine.points import curve_hits, sphere_hits
from engine.testscenes import look_at, quad

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")


def _translations(xs):
    steps = np.repeat(np.eye(4)[None], len(xs), axis=0)
    steps[:, 0, 3] = xs
    return steps


def _scene(points=(), curves=()):
    floor = quad([[-3, -3, -1.2], [3, -3, -1.2], [3, 3, -1.2], [-3, 3, -1.2]])
    mats = [Material("things", lobes=(Lobe("diffuse", color=(0.7, 0.5, 0.3)),)), Material("floor")]
    return Scene(meshes=[floor], instances=[Instance(0, materials=[1])], points=list(points), curves=list(curves),
                 materials=mats, lights=[PointLight((1, -1, 3), (300, 300, 300))],
                 camera=Camera(matrix=look_at((0, -4, 2), (0, 0, 0)), resolution=(24, 16)))


def _moving_cloud(n=200, seed=0):
    """A cloud sliding x -0.6 -> 0.6 (3 transform steps) while its points
    drift by their own offsets (3 deformation steps, radii changing too)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, (n, 3))
    r = rng.uniform(0.03, 0.12, n)
    drift = rng.normal(0, 0.3, (n, 3))
    steps = np.stack([p - drift, p, p + drift])
    radii = np.stack([0.5 * r, r, 1.5 * r])
    return PointCloud(p, r, materials=[0], motion=_translations([-0.6, 0.0, 0.6]), motion_positions=steps,
                      motion_radii=radii)


def _at(steps, time):
    """Linear interpolation of (3, ...) steps at times (n,) -> (n, ...)."""
    f = np.clip(time, 0, 1) * 2
    k = np.minimum(np.floor(f).astype(int), 1)
    a = (f - k).reshape((-1,) + (1,) * (steps.ndim - 1))
    return steps[k] + (steps[k + 1] - steps[k]) * a


def test_moving_spheres_are_hit_where_they_are_at_the_ray_time():
    cloud = _moving_cloud()
    ctx = prepare(_scene(points=[cloud]), RenderSettings(samples=1))
    spheres = ctx.spheres
    rng = np.random.default_rng(5)
    n = 6000
    o = rng.uniform(-1.5, 1.5, (n, 3)) + [0.0, 0.0, 4.0]
    d = rng.normal(0, 0.3, (n, 3)) + [0.0, 0.0, -1.0]
    d /= np.linalg.norm(d, axis=1)[:, None]
    time = rng.uniform(0, 1, n)
    t, prim, _, _ = ctx.accel.intersect(o, d, np.full(n, np.inf), time)
    local = ctx.triangles.shading.local[spheres.rows]          # point of each sphere slot
    shift = _at(np.array([-0.6, 0.0, 0.6]), time)
    centres = _at(cloud.motion_positions[:, local], time) + (shift[:, None] * [1.0, 0.0, 0.0])[:, None, :]
    radii = _at(cloud.motion_radii[:, local], time)
    oc = o[:, None, :] - centres
    b = np.einsum("nkj,nj->nk", oc, d)
    disc = b * b - (np.einsum("nkj,nkj->nk", oc, oc) - radii ** 2)
    root = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    root = np.where(root > 0, root, np.inf)
    first = np.argmin(root, axis=1)
    t_ref = root[np.arange(n), first]
    hit_sphere = (prim >= 0) & spheres.is_point[np.maximum(prim, 0)]
    edge = np.abs(disc[np.arange(n), first]) < 1e-4
    edge |= (prim >= 0) & ~hit_sphere & (t < t_ref)   # (the floor before a sphere that sank below it)
    assert np.array_equal(hit_sphere[~edge], np.isfinite(t_ref)[~edge])
    both = hit_sphere & np.isfinite(t_ref) & ~edge
    assert both.sum() > 500
    assert np.array_equal(spheres.rows[first[both]], prim[both])
    assert np.allclose(t[both], t_ref[both], rtol=1e-4, atol=1e-4)
    p, ng, back = sphere_hits(spheres, o[both], d[both], t[both], prim[both], time[both])
    c, r = centres[both, first[both]], radii[both, first[both]]
    assert np.allclose(np.linalg.norm(p - c, axis=1), r, rtol=0, atol=1e-6)   # (steps kept in float32)
    assert np.all(np.einsum("ij,ij->i", ng, d[both]) <= 0) and not back.any()


def _vertical_strand(x=0.0, radius=0.1, **kw):
    points = np.array([[x, 0.0, z] for z in np.linspace(-1.0, 1.0, 5)])
    return HairCurves(points, np.full(5, radius), np.array([0, 5]), materials=[0], **kw)


@pytest.mark.parametrize("how, shape", [("transform", "THICK"), ("deformation", "THICK"),
                                        ("transform", "THICK_LINEAR"), ("deformation", "THICK_LINEAR")])
def test_a_moving_strand_is_hit_where_it_is_at_the_ray_time(how, shape):
    """Rays along y at height z = 0 sweep x; the strand's axis at time t is
    x = -0.5 + t (sliding), or x = (-0.5 + t) at z = 0 (every point moved);
    as Catmull-Rom curves and as linear ones (Embree's round linear curves
    with time steps)."""
    if how == "transform":
        strand = _vertical_strand(motion=_translations([-0.5, 0.0, 0.5]))
    else:
        base = _vertical_strand().points
        strand = _vertical_strand(motion_positions=np.stack([base + [dx, 0, 0] for dx in (-0.5, 0.0, 0.5)]))
    ctx = prepare(replace(_scene(curves=[strand]), curve_shape=shape), RenderSettings(samples=1))
    assert ctx.strands.linear == (shape == "THICK_LINEAR")
    rng = np.random.default_rng(8)
    n = 4000
    time = rng.uniform(0, 1, n)
    x = rng.uniform(-0.8, 0.8, n)
    o = np.stack([x, np.full(n, -3.0), np.zeros(n)], axis=1)
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    t, prim, u, _ = ctx.accel.intersect(o, d, np.full(n, np.inf), time)
    axis = -0.5 + time
    inside = np.abs(x - axis) < 0.1 - 2e-3
    outside = np.abs(x - axis) > 0.1 + 2e-3
    strand_hit = (prim >= 0) & ctx.strands.is_curve[np.maximum(prim, 0)]
    assert strand_hit[inside].all() and not strand_hit[outside].any()
    on = np.flatnonzero(strand_hit & inside)
    p, ng, back, radius = curve_hits(ctx.strands, o[on], d[on], t[on], prim[on], u[on], time[on])
    assert np.allclose(np.hypot(p[:, 0] - axis[on], p[:, 1]), 0.1, atol=1e-9)
    assert np.allclose(radius, 0.1) and not back.any()
    expect_y = -np.sqrt(np.maximum(0.01 - (x[on] - axis[on]) ** 2, 0))
    assert np.allclose(o[on, 1] + t[on], expect_y, atol=2e-3)   # Embree's distance (float32 curves)


@pytest.mark.parametrize("mutate, message", [
    (lambda c: setattr(c, "motion_positions", np.full((3, 200, 3), np.nan)), "motion_positions: 1800 values are NaN"),
    (lambda c: setattr(c, "motion_positions", np.zeros((3, 7, 3))), r"motion_positions: expected shape"),
    (lambda c: setattr(c, "motion_radii", -c.motion_radii), "negative motion radius"),
    (lambda c: setattr(c, "motion", np.full((3, 4, 4), np.inf)), "motion: 48 values are NaN or infinite"),
])
def test_bad_point_motion_is_a_named_error(mutate, message):
    cloud = _moving_cloud()
    mutate(cloud)
    with pytest.raises(SceneError, match=r"point cloud 0 \('points'\).*" + message):
        render(_scene(points=[cloud]), RenderSettings(samples=1))


def test_nan_curve_motion_is_a_named_error():
    base = _vertical_strand().points
    steps = np.stack([base, base, base])
    steps[2, 3, 0] = np.nan
    with pytest.raises(SceneError, match=r"curves 0 \('points'\).*motion_positions: 1 values are NaN"):
        render(_scene(curves=[_vertical_strand(motion_positions=steps)]), RenderSettings(samples=1))


def test_hostile_moving_points_and_curves_render_finite():
    """Zero radii over the shutter, steps 10 units apart (a shutter of 10
    frames), a strand collapsing to a point at one step, one step of scale 0."""
    cloud = _moving_cloud()
    cloud.motion_radii = np.zeros_like(cloud.motion_radii)
    far = _moving_cloud(seed=2)
    far.motion = _translations([-10.0, 0.0, 10.0])
    base = _vertical_strand().points
    collapse = _vertical_strand(motion_positions=np.stack([np.zeros_like(base), base, base * 3.0]))
    flat = _translations([0.0, 0.0, 0.0])
    flat[0, :3, :3] = 0.0
    squashed = _vertical_strand(x=0.5, motion=flat)
    result = render(_scene(points=[cloud, far], curves=[collapse, squashed]),
                    RenderSettings(samples=8, samples_per_pass=8, max_bounces=2))
    assert np.isfinite(result.image).all() and result.image.max() > 0
