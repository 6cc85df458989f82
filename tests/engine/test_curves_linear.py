"""Linear 3D curves in the engine (Scene.curve_shape 'THICK_LINEAR', Cycles'
Render > Curves > Shape = Linear 3D Curves): Embree's round linear curves,
cones between the keys as they are, capped by spheres.

* A bent strand of constant radius is a straight cylinder along each
  segment (no Catmull-Rom bulge): rays across its second segment hit at the
  closed-form distance, with the cylinder's normal and u the place along
  the segment.
* The strand's ends are spheres (Embree reports u = 0 or 1 there): a ray
  along the last segment's axis meets the tip at t = distance - r with the
  normal along the axis.
* The radius and the tangent along a segment are linear in u (the chord).
* Hostile: zero-length strands and segments, radius 0 render finite.
Motion blur: tests/engine/test_primitive_motion.py (THICK_LINEAR cases).
"""
from dataclasses import replace

import numpy as np
import pytest

from engine import embree_c
from engine.points import curve_hits, curve_tangents
from engine.render import prepare, render
from engine.scene import Camera, HairCurves, Instance, Material, PointLight, RenderSettings, Scene
from engine.testscenes import look_at, quad

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")

KEYS = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.4, 0.0, 1.0]])
R = 0.05


def _scene(radii=(R, R, R), shape="THICK_LINEAR"):
    floor = quad([[-3, -3, -0.2], [3, -3, -0.2], [3, 3, -0.2], [-3, 3, -0.2]])
    strand = HairCurves(KEYS, np.asarray(radii, np.float64), np.array([0, 3]), materials=[0])
    return Scene(meshes=[floor], instances=[Instance(0, materials=[0])], materials=[Material("m")],
                 lights=[PointLight((1, -1, 3), (300, 300, 300))],
                 camera=Camera(matrix=look_at((0, -4, 2), (0, 0, 0.3)), resolution=(24, 16)),
                 curves=[strand], curve_shape=shape)


def _across_second_segment(n, seed=5):
    """Rays along +y through the bent strand's second segment: (o, d, s the
    place along it, h the signed distance from its axis in the x-z plane)."""
    rng = np.random.default_rng(seed)
    chord = KEYS[2] - KEYS[1]
    side = np.array([chord[2], 0.0, -chord[0]]) / np.linalg.norm(chord)
    s, h = rng.uniform(0.15, 0.85, n), rng.uniform(-0.999 * R, 0.999 * R, n)
    q = KEYS[1] + s[:, None] * chord + h[:, None] * side
    return q - [0.0, 2.0, 0.0], np.tile([0.0, 1.0, 0.0], (n, 1)), s, h, side


def test_a_linear_segment_is_a_straight_cylinder():
    ctx = prepare(_scene(), RenderSettings(samples=1))
    assert ctx.strands.linear and not ctx.strands.ribbon
    o, d, s, h, side = _across_second_segment(3000)
    t, prim, u, v = ctx.accel.intersect(o, d, np.full(len(o), np.inf))
    assert (prim >= 0).all() and ctx.strands.is_curve[prim].all()
    across = np.sqrt(R * R - h * h)
    assert np.abs(t - (2.0 - across)).max() < 2e-4
    assert np.abs(u - s).max() < 2e-3
    p, ng, back, radius = curve_hits(ctx.strands, o, d, t, prim, u)
    cylinder = (h[:, None] * side - across[:, None] * [0.0, 1.0, 0.0]) / R
    assert np.abs(ng - cylinder).max() < 5e-3 and not back.any()
    assert np.allclose(radius, R, atol=1e-6)
    tangent = curve_tangents(ctx.strands, prim, u)
    assert np.allclose(tangent, KEYS[2] - KEYS[1], atol=1e-6)


def test_catmull_rom_curves_bulge_where_linear_ones_do_not():
    """The same rays on the same keys as 3D curves (Catmull-Rom through the
    keys) miss the straight cylinder's distance: the test above can fail."""
    ctx = prepare(_scene(shape="THICK"), RenderSettings(samples=1))
    o, d, s, h, _ = _across_second_segment(3000)
    t, prim, _, _ = ctx.accel.intersect(o, d, np.full(len(o), np.inf))
    hit = prim >= 0
    off = np.abs(t[hit] - (2.0 - np.sqrt(R * R - h[hit] ** 2))) > 1e-3
    assert (~hit).sum() + off.sum() > 300


def test_the_ends_are_spheres():
    """A ray back along the last segment's axis meets the tip's sphere at
    u = 1; one up the first segment's axis meets the root's at u = 0; both
    through the sphere's centre, tilted by 1e-3 (a ray exactly on a
    segment's axis is Embree's degenerate case: it passes the cap)."""
    ctx = prepare(_scene(), RenderSettings(samples=1))
    axis = (KEYS[2] - KEYS[1]) / np.linalg.norm(KEYS[2] - KEYS[1])
    d = np.array([-axis + [0.0, 1e-3, 0.0], [0.0, 1e-3, 1.0]])
    d /= np.linalg.norm(d, axis=1)[:, None]
    centres = np.array([KEYS[2], KEYS[0]])
    o = centres - [[2.0], [0.15]] * d
    t, prim, u, _ = ctx.accel.intersect(o, d, np.full(2, np.inf))
    assert np.allclose(t, [2.0 - R, 0.15 - R], atol=2e-4)
    assert np.allclose(u, [1.0, 0.0], atol=1e-6)
    p, ng, back, _ = curve_hits(ctx.strands, o, d, t, prim, u)
    assert np.allclose(ng, -d, atol=1e-3) and not back.any()
    assert np.allclose(p, centres - R * d, atol=2e-4)


def test_the_radius_is_linear_along_a_segment():
    """A strand tapering 0.06 -> 0.04 -> 0.02: the hit radius at u on the
    second segment is 0.04 - 0.02 u (Catmull-Rom would curve it)."""
    ctx = prepare(_scene(radii=(0.06, 0.04, 0.02)), RenderSettings(samples=1))
    o, d, s, h, _ = _across_second_segment(2000, seed=6)
    o = o - (h[:, None] * np.array([KEYS[2, 2] - KEYS[1, 2], 0.0, KEYS[1, 0] - KEYS[2, 0]])
             / np.linalg.norm(KEYS[2] - KEYS[1]))   # through the axis
    t, prim, u, _ = ctx.accel.intersect(o, d, np.full(len(o), np.inf))
    assert (prim >= 0).all()
    _, _, _, radius = curve_hits(ctx.strands, o, d, t, prim, u)
    assert np.allclose(radius, 0.04 - 0.02 * u, atol=1e-9)
    assert np.abs(t - (2.0 - (0.04 - 0.02 * s))).max() < 2e-3


def test_zero_length_and_zero_radius_linear_strands_render_finite():
    """Strands whose keys all sit at the root (zero-length segments), of
    radius 0, and with one repeated key in the middle render finite."""
    z = np.linspace(0.0, 1.0, 4)
    strands = [np.c_[np.full(4, 0.4 * i), np.zeros(4), z] for i in range(4)]
    strands[1][:] = strands[1][0]          # every key at the root
    strands[3][2] = strands[3][1]          # a repeated key: one zero-length segment
    radii = np.full(16, 0.05)
    radii[8:12] = 0.0                      # strand 2: radius 0
    curves = HairCurves(np.concatenate(strands), radii, np.arange(0, 17, 4), materials=[0])
    scene = replace(_scene(), curves=[curves])
    result = render(scene, RenderSettings(samples=8, samples_per_pass=8, max_bounces=2))
    assert np.isfinite(result.image).all() and result.image.max() > 0
