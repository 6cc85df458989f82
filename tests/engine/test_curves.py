"""Hair curves in the engine (engine/points.py Strands): round Catmull-Rom
curves traced by Embree through the C API.

* The hit point, moved onto the round curve around its centre C(u), is
  where Embree's ray met it (within its float32 distance), the normal
  points from C(u) to it and faces the ray.
* A straight strand of constant radius is a cylinder: rays across it hit
  at the closed-form distance.
* Hostile input: NaN radii and bad offsets are named errors; zero-length
  strands (every point at the root) and radius 0 render finite.
* Ribbons (Scene.curve_shape 'RIBBONS'): a straight ribbon is flat, 2 r
  wide, with the cylinder's normal at each x; ribbon_v is Embree's v.
"""
from dataclasses import replace

import numpy as np
import pytest

from engine import embree_c
from engine.points import curve_hits, curve_rate, ribbon_v
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


# -- ribbons (Scene.curve_shape 'RIBBONS': Cycles' Rounded Ribbons) -------------

def _ribbons(curves):
    return replace(_scene(curves), curve_shape="RIBBONS")


def test_a_straight_ribbon_is_flat_2r_wide_and_rounded_like_a_cylinder():
    """Rays across a straight ribbon of radius 0.05 hit where |x| < r (width
    2 r) on the flat strand facing them (t = 2 exactly: no round surface),
    and the shading normal is the cylinder's at that x (sin = v = x / r),
    facing the ray; never a back face."""
    ctx = prepare(_ribbons([_straight()]), RenderSettings(samples=1))
    assert ctx.strands.ribbon
    rng = np.random.default_rng(4)
    n = 4000
    x = rng.uniform(-0.06, 0.06, n)
    o = np.c_[x, np.full(n, -2.0), rng.uniform(0.2, 0.8, n)]
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    t, prim, u, v = ctx.accel.intersect(o, d, np.full(n, np.inf))
    strand = (prim >= 0) & ctx.strands.is_curve[np.maximum(prim, 0)]
    clear = np.abs(np.abs(x) - 0.05) > 1e-4
    assert np.array_equal(strand[clear], (np.abs(x) < 0.05)[clear])
    assert np.allclose(t[strand], 2.0, atol=1e-5)
    p, ng, back, radius = curve_hits(ctx.strands, o[strand], d[strand], t[strand], prim[strand], u[strand])
    s = x[strand] / 0.05
    cylinder = np.c_[s, -np.sqrt(np.maximum(1.0 - s * s, 0.0)), np.zeros(len(s))]
    assert np.allclose(ng, cylinder, atol=2e-4)
    assert np.allclose(p, o[strand] + 2.0 * d[strand], atol=1e-5)
    assert np.allclose(radius, 0.05, atol=1e-6) and not back.any()
    assert np.allclose(ribbon_v(ctx.strands.rows_at(prim[strand]), o[strand], d[strand], u[strand],
                                ctx.strands.rate), v[strand], atol=2e-5)


@pytest.mark.parametrize("subdivisions", [2, 0, 4])
def test_ribbon_v_is_embrees_on_wavy_strands(subdivisions):
    """ribbon_v (Embree's v rebuilt from the tessellated quad the ray met)
    against the v Embree returns, on tapering wavy strands seen from random
    directions, at Curve Subdivisions 2 (Cycles' default: 5 pieces a
    segment), 0 and 4 (2^4 + 1 pieces, which Embree clamps to 16); the rounded normal faces every ray."""
    rng = np.random.default_rng(3)
    count, keys = 30, 6
    k = np.arange(keys)[None, :]
    phase = rng.uniform(0, 6, (count, 1))
    base = np.c_[rng.uniform(-1, 1, (count, 2)), np.zeros(count)]
    wave = np.stack([0.15 * np.sin(0.9 * k + phase), 0.1 * np.cos(0.7 * k + phase), 0.18 * k + 0 * phase], axis=2)
    curves = HairCurves((base[:, None, :] + wave).reshape(-1, 3), np.tile(np.linspace(0.05, 0.02, keys), count),
                        np.arange(0, count * keys + 1, keys), materials=[0])
    ctx = prepare(replace(_ribbons([curves]), curve_subdivisions=subdivisions), RenderSettings(samples=1))
    assert ctx.strands.rate == curve_rate(subdivisions) == {0: 2, 2: 5, 4: 16}[subdivisions]
    n = 20000
    o = np.c_[rng.uniform(-1.2, 1.2, n), np.full(n, -4.0), rng.uniform(0.0, 1.0, n)]
    d = np.c_[rng.normal(0, 0.2, n), np.ones(n), rng.normal(0, 0.3, n)]
    t, prim, u, v = ctx.accel.intersect(o, d, np.full(n, np.inf))
    on = (prim >= 0) & ctx.strands.is_curve[np.maximum(prim, 0)]
    assert on.sum() > 1000 and np.abs(v[on]).max() > 0.99
    rebuilt = ribbon_v(ctx.strands.rows_at(prim[on]), o[on], d[on], u[on], ctx.strands.rate)
    assert np.abs(rebuilt - v[on]).max() < 5e-5
    _, ng, back, _ = curve_hits(ctx.strands, o[on], d[on], t[on], prim[on], u[on])
    assert np.all(np.einsum("ij,ij->i", ng, d[on]) < 0) and not back.any()


@pytest.mark.parametrize("field, value, message", [
    ("curve_shape", "FLAT", "curve_shape must be one of"),
    ("curve_subdivisions", -1, "curve_subdivisions must be a whole number"),
    ("curve_subdivisions", 2.5, "curve_subdivisions must be a whole number"),
])
def test_bad_curve_settings_are_named(field, value, message):
    with pytest.raises(SceneError, match=message):
        render(replace(_scene([_straight()]), **{field: value}), RenderSettings(samples=1))


def test_ribbons_render_finite():
    curves = _straight(4)
    points = curves.points.copy()
    points[5:10] = points[5]              # a zero-length strand
    radii = curves.radii.copy()
    radii[10:15] = 0.0                    # radius 0
    curves.points, curves.radii = points, radii
    result = render(_ribbons([curves]), RenderSettings(samples=8, samples_per_pass=8, max_bounces=2))
    assert np.isfinite(result.image).all() and result.image.max() > 0
