"""The shading data of curves without Blender (engine/curve_attributes.py,
the Curves Info node and Geometry Tangent in engine/nodes/input_nodes.py,
engine/nodes/hair_random.py).

* Intercept and Length along the control polygon in object space (Cycles'
  export), 0 on a zero-length strand.
* At ray hits on strands: a point attribute is the linear mix of the
  segment's two keys by Embree's u (Cycles' curve_attribute), a curve
  attribute constant; Is Strand 1 (0 on the floor), Thickness twice the
  world radius, Tangent Normal a unit vector across the fibre, Geometry
  Tangent the normalized dC/du; the UV map is the named 2D attribute.
* The corners are made only when read; bad attributes are named errors.
* The Principled Hair randomization at Random 0.5 is the constant
  parametrization, and follows engine/lobes/hair.py's scalar form.
"""
from types import SimpleNamespace

import numpy as np
import pytest

from engine import embree_c
from engine.curve_attributes import curve_randoms, intercepts_and_lengths
from engine.integrator.stages import interaction
from engine.lobes import hair
from engine.nodes.context import IS_STRAND, ShadingContext
from engine.nodes.hashing import hash_uint, to_float
from engine.nodes.registry import REGISTRY
from engine.render import prepare, render
from engine.scene import Camera, HairCurves, Instance, Material, PointLight, RenderSettings, Scene, SceneError
from engine.testscenes import look_at, quad

needs_embree = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")
SCALE = 2.0


def _strands(**extra):
    """Three vertical strands of 5 keys at z = (k / 4)^2 (unevenly spaced),
    radius from 0.05 to 0.01, placed at twice their size."""
    z = np.linspace(0.0, 1.0, 5) ** 2
    points = np.concatenate([np.c_[np.full(5, 0.5 * i), np.zeros(5), z] for i in range(3)])
    return HairCurves(points, np.tile(np.linspace(0.05, 0.01, 5), 3), np.arange(0, 16, 5), materials=[0],
                      matrix=np.diag([SCALE, SCALE, SCALE, 1.0]), **extra)


def _scene(curves):
    floor = quad([[-3, -3, -0.2], [3, -3, -0.2], [3, 3, -0.2], [-3, 3, -0.2]])
    return Scene(meshes=[floor], instances=[Instance(0, materials=[0])], materials=[Material("m")],
                 lights=[PointLight((1, -1, 3), (300, 300, 300))],
                 camera=Camera(matrix=look_at((0, -4, 2), (0, 0, 0.3)), resolution=(16, 12)), curves=curves)


def _hits(curves, x=1.0, n=40):
    """The shading contexts of rays along +y into strand 1 (world x = 1) at
    heights over its length, and the rendering context."""
    ctx = prepare(_scene([curves]), RenderSettings(samples=1))
    o = np.c_[np.full(n, x + 0.01), np.full(n, -3.0), np.linspace(0.05, 1.95, n)]
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    t, prim, u, v = ctx.accel.intersect(o, d, np.full(n, np.inf))
    assert (prim >= 0).all() and ctx.strands.is_curve[prim].all()
    hit = interaction(ctx, SimpleNamespace(o=o, d=d), t, prim, u, v)
    return ShadingContext.of_hit(ctx.triangles, hit), hit, ctx


def test_intercept_and_length_along_the_control_polygon():
    points = np.array([[0, 0, 0], [0, 0, 1], [0, 3, 1], [5, 5, 5], [5, 5, 5], [1, 1, 1], [1, 1, 2]], float)
    intercept, length = intercepts_and_lengths(points, np.array([0, 3, 5, 7]))
    assert np.allclose(length, [4.0, 0.0, 1.0])
    assert np.allclose(intercept, [0, 0.25, 1.0, 0.0, 0.0, 0.0, 1.0])


def test_random_is_cycles_hash_of_the_curve_index():
    r = curve_randoms(5, first_curve=3)
    assert np.array_equal(r, to_float(hash_uint(np.arange(3, 8), np.zeros(5, np.int64))).astype(np.float64))
    assert ((0 <= r) & (r <= 1)).all() and len(set(r)) == 5


@needs_embree
def test_curves_info_and_attributes_at_hits():
    keys = np.linspace(0.0, 1.0, 15)[:, None] * [1.0, 2.0, 3.0]
    curves = _strands(point_attributes={"w": keys}, curve_attributes={"f": np.array([[0.1], [0.2], [0.3]]),
                                                                      "uvs": np.array([[0, 1], [2, 3], [4, 5.0]])},
                      uv="uvs")
    sc, hit, ctx = _hits(curves)
    info = REGISTRY["ShaderNodeHairInfo"].evaluate(sc, {}, {})
    seg = ctx.strands.slot[hit.prim]
    local = ctx.triangles.shading.local[hit.prim]
    k0 = 5 + local - 4          # strand 1's segments: keys 5..9, its rows after strand 0's four
    u = hit.bary[:, 0]
    assert len(set(seg)) > 1
    w = REGISTRY["ShaderNodeAttribute"].evaluate(sc, {}, {"attribute_name": "w"})["Color"]
    assert np.allclose(w, (1 - u)[:, None] * keys[k0] + u[:, None] * keys[k0 + 1])
    f = REGISTRY["ShaderNodeAttribute"].evaluate(sc, {}, {"attribute_name": "f"})["Fac"]
    assert np.allclose(f, 0.2)
    assert np.allclose(sc.uv, [2.0, 3.0]) and np.allclose(sc.uv_map("uvs"), [2.0, 3.0])
    assert np.allclose(info["Is Strand"], 1.0)
    z = (np.linspace(0.0, 1.0, 5) ** 2)
    intercept = z / z[-1]
    assert np.allclose(info["Intercept"], (1 - u) * intercept[k0 - 5] + u * intercept[k0 - 4])
    assert np.allclose(info["Length"], 1.0)                 # object space, as Cycles
    radius = np.linspace(0.05, 0.01, 5)
    assert np.allclose(info["Thickness"], 2 * SCALE * ((1 - u) * radius[k0 - 5] + u * radius[k0 - 4]))
    assert np.allclose(info["Random"], curve_randoms(3)[1])
    tn = info["Tangent Normal"]
    assert np.allclose(np.linalg.norm(tn, axis=1), 1.0)
    assert np.allclose(np.einsum("ij,ij->i", tn, hit.fibre), 0.0, atol=1e-9)
    tangent = REGISTRY["ShaderNodeNewGeometry"].evaluate(sc, {}, {})["Tangent"]
    assert np.allclose(tangent, hit.fibre / np.linalg.norm(hit.fibre, axis=1, keepdims=True))


@needs_embree
def test_strands_without_attributes_read_zero_and_the_floor_is_no_strand():
    sc, hit, ctx = _hits(_strands())
    assert REGISTRY["ShaderNodeAttribute"].evaluate(sc, {}, {"attribute_name": "w"})["Fac"].max() == 0.0
    assert np.allclose(sc.uv, 0.0)
    floor = ShadingContext.at(ctx.triangles, np.array([0, 1]), np.array([0.2, 0.3]), np.array([0.3, 0.1]))
    info = REGISTRY["ShaderNodeHairInfo"].evaluate(floor, {}, {})
    assert all(np.all(value == 0.0) for value in info.values())


@needs_embree
def test_corners_are_made_only_when_read():
    ctx = prepare(_scene([_strands(point_attributes={"w": np.ones((15, 3))})]), RenderSettings(samples=1))
    attrs = ctx.triangles.shading.scene.meshes[-1].attributes
    assert set(attrs) >= {"w", IS_STRAND} and not attrs._made


@pytest.mark.parametrize("extra, message", [
    ({"point_attributes": {"w": np.full((15, 1), np.nan)}}, r"point_attributes 'w': 15 values are NaN"),
    ({"curve_attributes": {"f": np.ones((4, 1))}}, r"curve_attributes 'f' must be \(3, C\)"),
    ({"uv": "nothing"}, "the UV map 'nothing' is none of its attributes"),
])
def test_bad_curve_attributes_are_named(extra, message):
    with pytest.raises(SceneError, match=message):
        render(_scene([_strands(**extra)]), RenderSettings(samples=1))


@pytest.mark.parametrize("random, amount", [(0.5, 0.7), (0.1, 0.4), (0.9, 1.0)])
def test_hair_randomization_follows_the_parametrization(random, amount):
    props = {name: default for name, default in REGISTRY["EmberPrincipledHairRandom"].props}
    props.update(melanin=0.6, redness=0.3, random_color=amount, random_roughness=amount)
    out = REGISTRY["EmberPrincipledHairRandom"].evaluate(ShadingContext(1), {"Random": np.array([random])}, props)
    factor = 1 + 2 * (random - 0.5) * amount
    assert np.allclose(out["Roughness"], 0.3 * factor) and np.allclose(out["Radial Roughness"], 0.3 * factor)
    expect = hair.sigma_from_melanin(0.6, 0.3, (1.0, 1.0, 1.0), 0.3 * factor, random=random, random_color=amount)
    assert np.allclose(out["Absorption"][0], expect)


def test_hair_randomization_off_strands_reads_the_socket_value():
    """Cycles reads the Random socket where no curve attribute is found (a mesh)."""
    entry = REGISTRY["EmberPrincipledHairRandom"]
    props = {name: default for name, default in entry.props}
    props.update(random_roughness=1.0, random_default=0.8)
    out = entry.evaluate(ShadingContext(2), {"Random": np.array([0.1, 0.1]), "Is Strand": np.array([1.0, 0.0])},
                         props)
    assert np.allclose(out["Roughness"], [0.3 * (1 + 2 * (0.1 - 0.5)), 0.3 * (1 + 2 * (0.8 - 0.5))])


@needs_embree
def test_generated_on_strands_is_cycles():
    """Curves objects: the object-space position (Cycles' fallback without a
    generated attribute); particle hair (a texture space given): the root
    mapped through it, constant along the strand."""
    sc, hit, _ = _hits(_strands())
    assert np.allclose(sc.generated, hit.p / SCALE)
    loc, size = np.array([0.1, 0.0, 0.2]), np.array([2.0, 1.0, 0.5])
    sc, hit, _ = _hits(_strands(texspace=(tuple(loc), tuple(size))))
    root = np.array([0.5, 0.0, 0.0])          # strand 1's first key, object space
    assert np.allclose(sc.generated, (root - loc) * 0.5 / size + 0.5)
