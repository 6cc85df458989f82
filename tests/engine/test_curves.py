"""Hair curves in the engine (engine/points.py Strands): round Catmull-Rom
curves traced by Embree through the C API.

* The hit point, moved onto the round curve around its centre C(u), is
  where Embree's ray met it (within its float32 distance), the normal
  points from C(u) to it and faces the ray.
* A straight strand of constant radius is a cylinder: rays across it hit
  at the closed-form distance.
* Hostile input: NaN radii and bad offsets are named errors; zero-length
  strands (every point at the root) and radius 0 render finite.
"""
import numpy as np
import pytest

from engine import embree_c
from engine.points import curve_hits
from engine.render import prepare, render
from engine.scene import Camera, HairCurves, Instance, Material, PointLight, RenderSettings, Scene, SceneError
from engine.testscenes import look_at, quad

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")


def _scene(curves):
    floor = quad([[-3, -3, -0.2], [3, -3, -0.2], [3, 3, -0.2], [-3, 3, -0.2]])
    return Scene(meshes=[floor], instances=[Instance(0, materials=[0])], materials=[Material("m")],
                 lights=[PointLight((1, -1, 3), (300, 300, 300))],
                 camera=Camera(matrix=look_at((0, -4, 2), (0, 0, 0.3)), resolution=(24, 16)), curves=curves)


def _straight(n_curves=5, radius=0.05):
    """Vertical strands of 5 points along z at x = 0, 0.5, 1.0, ..."""
    z = np.linspace(0.0, 1.0, 5)
    points = np.concatenate([np.c_[np.full(5, 0.5 * i), np.zeros(5), z] for i in range(n_curves)])
    return HairCurves(points, np.full(len(points), radius), np.arange(0, 5 * n_curves + 1, 5), materials=[0])


def test_a_straight_strand_is_a_cylinder():
    ctx = prepare(_scene([_straight()]), RenderSettings(samples=1))
    rng = np.random.default_rng(2)
    n = 4000
    x = rng.uniform(-0.06, 0.06, n)      # across strand 0
    z = rng.uniform(0.2, 0.8, n)
    o = np.c_[x, np.full(n, -2.0), z]
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    t, prim, u, v = ctx.accel.intersect(o, d, np.full(n, np.inf))
    inside = np.abs(x) < 0.05 * 0.999
    strand = (prim >= 0) & ctx.strands.is_curve[np.maximum(prim, 0)]
    assert np.array_equal(strand[np.abs(np.abs(x) - 0.05) > 1e-4], inside[np.abs(np.abs(x) - 0.05) > 1e-4])
    expect = 2.0 - np.sqrt(np.maximum(0.05 ** 2 - x ** 2, 0.0))
    ok = strand & inside
    assert np.allclose(t[ok], expect[ok], atol=2e-4)
    p, ng, back, radius = curve_hits(ctx.strands, o[ok], d[ok], t[ok], prim[ok], u[ok])
    assert np.allclose(radius, 0.05, atol=1e-6)
    assert np.allclose(np.hypot(p[:, 0], p[:, 1]), 0.05, atol=1e-9)
    assert np.all(np.einsum("ij,ij->i", ng, d[ok]) <= 0) and not back.any()
    assert np.allclose(p, o[ok] + d[ok] * t[ok, None], atol=2e-4)


@pytest.mark.parametrize("mutate, message", [
    (lambda c: c.radii.__setitem__(2, np.nan), r"curves 0 \('points'\) radii: 1 values are NaN"),
    (lambda c: setattr(c, "offsets", np.array([0, 5, 3, 25])), "offsets must rise"),
])
def test_bad_curves_are_named(mutate, message):
    curves = _straight()
    curves.radii = curves.radii.copy()
    mutate(curves)
    with pytest.raises(SceneError, match=message):
        render(_scene([curves]), RenderSettings(samples=1))


def test_zero_length_and_zero_radius_strands_render_finite():
    curves = _straight(4)
    points = curves.points.copy()
    points[5:10] = points[5]              # strand 1: every point at its root
    radii = curves.radii.copy()
    radii[10:15] = 0.0                    # strand 2: radius 0
    curves.points, curves.radii = points, radii
    result = render(_scene([curves]), RenderSettings(samples=8, samples_per_pass=8, max_bounces=2))
    assert np.isfinite(result.image).all() and result.image.max() > 0
