"""Light node trees evaluated per light point (engine/lights/shader.py, as
Cycles' light_sample_shader_eval), against values computed here from the
sampled point alone:

* each NEE sample's radiance is the light's constant radiance times the
  node tree at the sampled point, whose coordinates (Position, Normal,
  Incoming, UV / Parametric, Object, object-space Normal) are derived in the
  test from Cycles' conventions (measured in bpy 5.0.1 with a camera seeing
  the light: area UV = the point in the light's axes shifted to [0, 1];
  point UV = map_to_sphere of the object-space normal; Object = the inverse
  object matrix), and a BSDF ray along the sample's direction sees the same;
* a checkered area light over a plane renders, with NEE alone, BSDF sampling
  alone and MIS, the irradiance of a quadrature of the checker over the
  light (the pdf does not change, only the radiance, so MIS stays unbiased);
* a node tree producing NaN and infinity renders finite pixels.
"""
import numpy as np
import pytest

import ember_stats
from analytic import analytic_scene, pixel_centres
from ember_stats import block_means_var, z_scores
from engine import bsdf, geometry, lights
from engine.lights.shader import MAX_VALUE, LightShaders
from engine.render import render
from engine.scene import AreaLight, MixColor, NodeCall, NodeOutput, PointLight, RenderSettings, Scene

N = 4000
CHECKER = ((1.0, 0.5, 0.2), (0.1, 0.2, 0.3))
STRATEGIES = ("light", "bsdf", "mis")
BLOCK = 4
SPP = {"light": 1024, "bsdf": 2048, "mis": 1024}
# One family: every 4 x 4 block and the image mean, per channel and strategy.
Z_MAX = ember_stats.family_z(__name__, len(STRATEGIES) * 3 * ((40 // BLOCK) ** 2 + 1))


def node(idname, output, **inputs):
    props = inputs.pop("props", {})
    return NodeOutput(NodeCall(idname, inputs, props), output)


def shifted(expr):
    """expr + 2 per channel (light radiance is clipped at 0)."""
    return node("ShaderNodeVectorMath", "Vector", Vector=expr, Vector_001=(2.0, 2.0, 2.0), props={"operation": "ADD"})


def rotation(ax, ay, az):
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def object_matrix(location, angles, scale):
    m = np.eye(4)
    m[:3, :3] = rotation(*angles) * np.asarray(scale, float)[None, :]
    m[:3, 3] = location
    return m


def sample_and_hit(light, p, seed=4):
    """NEE samples of the scene's one light from p, and what BSDF rays along
    their directions see: (sample, Le seen by the rays, constant radiance)."""
    scene = Scene(lights=[light])
    tris = geometry.flatten(scene)
    ls = lights.LightSet(scene, tris, bsdf.MaterialTable(geometry.material_table(scene)), "power")
    u = np.random.default_rng(seed).random((3, N))
    points = np.tile(p, (N, 1))
    s = ls.sample(np.zeros(N, np.int64), points, *u)
    _, emitter, seen, pdf = ls.intersect(points, s.wi, np.full(N, np.inf))
    ok = s.pdf > 0
    assert ok.mean() > 0.5 and (emitter[ok] == 0).all()
    np.testing.assert_allclose(pdf[ok], s.pdf[ok], rtol=1e-9)
    return s, ok, points + s.wi * s.dist[:, None], seen


def map_to_sphere(v):
    """Cycles' map_to_sphere, written out: u from atan2(x, y), v from acos(z)."""
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    return np.stack([0.5 - np.arctan2(v[:, 0], v[:, 1]) / (2 * np.pi), 1.0 - np.arccos(v[:, 2]) / np.pi], axis=1)


def area_coordinates(m, size, q, wi):
    """What Cycles' light shader reads at points q of an area light with
    object matrix m and size (x, y), seen along wi."""
    inv = np.linalg.inv(m)
    local = q @ inv[:3, :3].T + inv[:3, 3]
    n_world = -m[:3, 2] / np.linalg.norm(m[:3, 2])
    uv = np.zeros_like(q)
    uv[:, 0], uv[:, 1] = local[:, 0] / size[0] + 0.5, local[:, 1] / size[1] + 0.5
    normal = np.tile(n_world, (len(q), 1))
    obj_n = normal @ m[:3, :3]
    obj_n /= np.linalg.norm(obj_n, axis=1, keepdims=True)
    return {("ShaderNodeTexCoord", "UV"): uv, ("ShaderNodeNewGeometry", "Parametric"): uv,
            ("ShaderNodeTexCoord", "Object"): local, ("ShaderNodeTexCoord", "Generated"): local,
            ("ShaderNodeTexCoord", "Normal"): obj_n, ("ShaderNodeNewGeometry", "Normal"): normal,
            ("ShaderNodeNewGeometry", "Position"): q, ("ShaderNodeNewGeometry", "Incoming"): -wi}


def point_coordinates(m, centre, radius, sphere, q, wi):
    normal = (q - centre) / radius if sphere else -wi
    obj_n = normal @ m[:3, :3]
    obj_n /= np.linalg.norm(obj_n, axis=1, keepdims=True)
    uv = np.zeros_like(q)
    uv[:, :2] = map_to_sphere(obj_n)
    inv = np.linalg.inv(m)
    return {("ShaderNodeTexCoord", "UV"): uv, ("ShaderNodeNewGeometry", "Parametric"): uv,
            ("ShaderNodeTexCoord", "Object"): q @ inv[:3, :3].T + inv[:3, 3],
            ("ShaderNodeTexCoord", "Normal"): obj_n, ("ShaderNodeNewGeometry", "Normal"): normal,
            ("ShaderNodeNewGeometry", "Incoming"): -wi, ("ShaderNodeNewGeometry", "Position"): q}


AREA_M = object_matrix((0.3, -0.2, 1.5), (0.3, -0.2, 0.7), (1.3, 0.8, 1.0))
POINT_M = object_matrix((0.2, 0.1, 1.2), (0.4, 0.1, -0.5), (1.0, 1.0, 1.0))
OUTPUTS = sorted(area_coordinates(AREA_M, (1, 1), np.ones((1, 3)), np.ones((1, 3))))


@pytest.mark.parametrize("idname, output", OUTPUTS, ids=[f"{i[13:]}-{o}" for i, o in OUTPUTS])
def test_area_light_shader_reads_cycles_coordinates(idname, output):
    size = (1.2, 0.7)
    shader = shifted(node(idname, output))
    light = AreaLight(AREA_M, (40.0, 30.0, 20.0), "RECTANGLE", *size, shader=shader)
    s, ok, q, seen = sample_and_hit(light, np.array([0.1, 0.2, 0.0]))
    area = size[0] * np.linalg.norm(AREA_M[:3, 0]) * size[1] * np.linalg.norm(AREA_M[:3, 1])
    base = np.array([40.0, 30.0, 20.0]) / (np.pi * area)        # Cycles: P / (pi A), normalized
    want = area_coordinates(AREA_M, size, q, s.wi)[(idname, output)] + 2.0
    np.testing.assert_allclose(s.Le[ok] / base, want[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(seen[ok], s.Le[ok], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("sphere", [True, False], ids=["sphere", "soft disk"])
@pytest.mark.parametrize("idname, output", sorted(point_coordinates(POINT_M, 0, 1, True, np.ones((1, 3)),
                                                                    np.ones((1, 3)))),
                         ids=lambda v: v if isinstance(v, str) and not v.startswith("Shader") else "")
def test_point_light_shader_reads_cycles_coordinates(idname, output, sphere):
    centre, r = POINT_M[:3, 3], 0.3
    shader = shifted(node(idname, output))
    light = PointLight(tuple(centre), (30.0, 20.0, 10.0), radius=r, soft_falloff=not sphere, shader=shader,
                       matrix=POINT_M)
    s, ok, q, seen = sample_and_hit(light, np.array([-0.2, 0.1, 0.0]))
    base = np.array([30.0, 20.0, 10.0]) / (np.pi * 4 * np.pi * r * r)   # Cycles: P / (pi 4 pi r^2)
    want = point_coordinates(POINT_M, centre, r, sphere, q, s.wi)[(idname, output)] + 2.0
    np.testing.assert_allclose(s.Le[ok] / base, want[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(seen[ok], s.Le[ok], rtol=1e-9, atol=1e-12)


def checker_colour(u, v, scale):
    """Cycles' svm_checker on (u, v, 0) * scale, written out."""
    x = np.floor((u * scale + 1e-6) * 0.999999).astype(np.int64) % 2
    y = np.floor((v * scale + 1e-6) * 0.999999).astype(np.int64) % 2
    first = (x != y)[..., None]      # z = 0: parity(x) == parity(y) must differ from (z odd) = False
    return np.where(first, CHECKER[0], CHECKER[1])


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_checkered_area_light_irradiance_every_strategy(strategy):
    """A 1.6 x 1.2 rectangle at height 0.8 whose colour is a Checker (scale 4)
    on its UV: the plane's radiance is rho / pi times the quadrature of L
    cos_l cos_r / t^2 over the light, the checker evaluated in the test."""
    a, b, h, P, scale = 1.6, 1.2, 0.8, 30.0, 4.0
    m = np.eye(4)
    m[:3, 3] = (0.2, 0.0, h)
    uv = node("ShaderNodeTexCoord", "UV")
    shader = node("ShaderNodeTexChecker", "Color", Vector=uv, Color1=CHECKER[0], Color2=CHECKER[1], Scale=scale)
    scene, rho = analytic_scene(AreaLight(m, (P, P, P), "RECTANGLE", a, b, shader=shader))
    spp = SPP[strategy]
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, seed=21, strategy=strategy,
                                     filter_type="BOX", filter_width=1e-3))
    k = 192                                             # 48 points per checker cell side
    g = (np.arange(k) + 0.5) / k
    gu, gv = np.meshgrid(g, g)
    L = P / (np.pi * a * b) * checker_colour(gu, gv, scale)          # (k, k, 3)
    lx, ly = (gu - 0.5) * a + 0.2, (gv - 0.5) * b
    x, y = pixel_centres(40, 4.0)
    E = np.empty(x.shape + (3,))
    for i in range(x.shape[0]):
        dx = lx[None] - x[i][:, None, None]
        dy = ly[None] - y[i][:, None, None]
        w = h * h / (dx * dx + dy * dy + h * h) ** 2                  # cos_l cos_r / t^2
        E[i] = np.einsum("pij,ijc->pc", w, L) * (a * b / k ** 2)
    check_blocks(r, rho / np.pi * E, f"checkered area light ({strategy})")


def check_blocks(result, expected, label):
    """z-tests of every block and channel, and of the image mean per
    channel, against the quadrature (one family for the three strategies)."""
    m, v = block_means_var(result.image[..., :3].astype(np.float64), result.variance[..., :3].astype(np.float64),
                           BLOCK)
    e, _ = block_means_var(expected, np.zeros_like(expected), BLOCK)
    z = z_scores(m, v, e, 0.0)
    rel = m.mean(axis=(0, 1)) / e.mean(axis=(0, 1)) - 1.0
    rel_se = np.sqrt(v.sum(axis=(0, 1))) / (m.shape[0] * m.shape[1]) / e.mean(axis=(0, 1))
    print(f"{label}: max block |z| {np.abs(z).max():.2f} (limit {Z_MAX:.2f}); image mean per channel "
          f"{np.round(rel, 4)} +- {np.round(rel_se, 4)}, detects {Z_MAX * rel_se.max():.2%} with probability 1/2, "
          f"a median block {Z_MAX * np.median(np.sqrt(v) / e):.1%}")
    assert (np.abs(rel) < Z_MAX * rel_se).all(), f"{label}: the image mean is off by {rel} +- {rel_se}"
    assert np.abs(z).max() < Z_MAX, f"{label}: blocks off by up to {np.abs(z).max():.1f} standard errors"


def test_nan_producing_light_tree_renders_finite():
    """A light tree whose product overflows to infinity and whose difference
    of infinities is NaN: the light's points get 0 there (and an overflowing
    value the largest Ember renders), never a NaN pixel."""
    huge = MixColor("MULTIPLY", 1.0, (1e200, 1e200, 1e200), node("ShaderNodeTexCoord", "UV"), clamp_factor=False)
    nan = MixColor("SUBTRACT", 1.0, huge, huge, clamp_factor=False)
    m = np.eye(4)
    m[:3, 3] = (0, 0, 1.0)
    scene, _ = analytic_scene(AreaLight(m, (10.0, 10.0, 10.0), "SQUARE", 1.0, visible_camera=True, shader=nan))
    r = render(scene, RenderSettings(samples=4, samples_per_pass=4, seed=1))
    assert np.isfinite(r.image).all() and np.isfinite(r.variance).all()
    assert r.image[..., :3].max() == 0.0     # NaN emission is no emission
    shaders = LightShaders.of([AreaLight(m, (1.0, 1.0, 1.0), shader=huge)], [m])
    q = np.random.default_rng(2).random((64, 3))
    value = shaders.factor(0, q, np.tile((0.0, 0.0, -1.0), (64, 1)), -q, q[:, :2])
    assert np.isfinite(value).all() and value.max() <= MAX_VALUE and value.min() >= 0.0


# Measured in bpy 5.0.1 (Cycles, one sample per pixel centre, a camera below
# the light looking up, so Incoming is (0, 0, -1)): a point or spot light
# at Euler XYZ (0.2, 0.1, 0.5), soft falloff, seen along Incoming; the spot
# with Spot Size 2.5 rad.  Values to the 4 decimals they were read with.
CYCLES_SEEN = {
    "point": {("ShaderNodeTexCoord", "UV"): (0.0744, 0.0711, 0.0),
              ("ShaderNodeTexCoord", "Normal"): (0.0998, -0.1977, -0.9752),
              ("ShaderNodeNewGeometry", "Normal"): (0.0, 0.0, -1.0)},
    "spot": {("ShaderNodeTexCoord", "UV"): (0.517, 0.4663, 0.0),
             ("ShaderNodeTexCoord", "Normal"): (0.0998, -0.1977, -0.9752)},
}


@pytest.mark.parametrize("kind", sorted(CYCLES_SEEN))
def test_point_and_spot_coordinates_as_cycles_renders_them(kind):
    from engine.scene import SpotLight
    m = object_matrix((0.3, -0.2, 0.5), (0.2, 0.1, 0.5), (1.0, 1.0, 1.0))
    for (idname, output), want in CYCLES_SEEN[kind].items():
        shader = shifted(node(idname, output))
        common = dict(radius=0.0, soft_falloff=True, shader=shader, matrix=m)
        if kind == "spot":
            light = SpotLight(tuple(m[:3, 3]), (1.0, 1.0, 1.0), direction=tuple(-m[:3, 2]), spot_size=2.5,
                              spot_blend=0.0, **common)
        else:
            light = PointLight(tuple(m[:3, 3]), (1.0, 1.0, 1.0), **common)
        scene = Scene(lights=[light])
        ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
        p = m[:3, 3] + (0.0, 0.0, -5.0)                  # seen along Incoming (0, 0, -1)
        s = ls.sample(np.zeros(1, np.int64), p[None], np.full(1, 0.5), np.full(1, 0.5), np.full(1, 0.5))
        base = 1.0 / (4 * np.pi * 25.0)                   # a delta light: P / (4 pi) / d^2
        np.testing.assert_allclose(s.Le[0] / base - 2.0, want, atol=1.5e-4, err_msg=f"{kind} {output}")


def test_light_selection_weighs_the_tree():
    """Light selection weighs a textured light by its tree's mean: a
    checker of (10, 20) on one of two equal area lights gives it 15 times
    the other's power (the lattice samples both colours alike), and a
    point light's IES-like factor does the same; the images do not depend
    on it, only their noise."""
    m0, m1 = np.eye(4), np.eye(4)
    m0[:3, 3], m1[:3, 3] = (-1.0, 0.0, 1.0), (1.0, 0.0, 1.0)
    uv = node("ShaderNodeTexCoord", "UV")
    checker = node("ShaderNodeTexChecker", "Color", Vector=uv, Color1=(10.0,) * 3, Color2=(20.0,) * 3, Scale=4.0)
    scene = Scene(lights=[AreaLight(m0, (5.0,) * 3, "SQUARE", 1.0), AreaLight(m1, (5.0,) * 3, "SQUARE", 1.0,
                                                                             shader=checker),
                          PointLight((0.0, 0.0, 2.0), (5.0,) * 3, radius=0.1),
                          PointLight((0.0, 1.0, 2.0), (5.0,) * 3, radius=0.1, shader=checker)])
    ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
    power = ls.power
    points, areas = power[:2], power[2:]
    assert areas[1] / areas[0] == pytest.approx(15.0, rel=0.02)
    assert points[1] / points[0] == pytest.approx(15.0, rel=0.02)


def sun_coordinates(m, angle, wi):
    """What Cycles 5.0's distant light shader reads along directions wi
    towards a sun of object matrix m: P = N = Incoming = -wi; UV: the
    direction on the disk, radius sin(theta / 2) / (2 sin(angle / 4)) for
    theta the angle to the sun's axis, turned as the direction's object x, y."""
    axis = m[:3, 2] / np.linalg.norm(m[:3, 2])            # towards the sun (object +Z)
    theta = np.arccos(np.clip(wi @ axis, -1.0, 1.0))
    local = wi @ np.linalg.inv(m)[:3, :3].T
    phi = np.arctan2(local[:, 1], local[:, 0])
    r = np.sin(0.5 * theta) / (2.0 * np.sin(0.25 * angle))
    uv = np.zeros_like(wi)
    uv[:, 0], uv[:, 1] = 0.5 + r * np.cos(phi), 0.5 + r * np.sin(phi)
    inv = np.linalg.inv(m)
    travel = -wi
    return {("ShaderNodeTexCoord", "UV"): uv, ("ShaderNodeNewGeometry", "Parametric"): uv,
            ("ShaderNodeNewGeometry", "Incoming"): travel, ("ShaderNodeNewGeometry", "Normal"): travel,
            ("ShaderNodeNewGeometry", "Position"): travel,
            ("ShaderNodeTexCoord", "Object"): travel @ inv[:3, :3].T + inv[:3, 3]}


SUN_M = object_matrix((0.4, -0.3, 0.3), (0.5, -0.3, 0.8), (1.0, 1.0, 1.0))


@pytest.mark.parametrize("idname, output", sorted(sun_coordinates(SUN_M, 0.5, np.ones((1, 3)) / np.sqrt(3))),
                         ids=lambda v: v if isinstance(v, str) and not v.startswith("Shader") else "")
def test_sun_shader_reads_cycles_coordinates(idname, output):
    """Each NEE sample of a textured sun carries the tree at the sampled
    direction, and the escaping ray along it sees the same radiance."""
    from engine.scene import SunLight
    angle = 0.5
    light = SunLight(tuple(-SUN_M[:3, 2]), (2.0, 3.0, 4.0), angle, shader=shifted(node(idname, output)), matrix=SUN_M)
    scene = Scene(lights=[light])
    ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)), "power")
    u = np.random.default_rng(7).random((3, N))
    s = ls.sample(np.zeros(N, np.int64), np.zeros((N, 3)), *u)
    base = np.array([2.0, 3.0, 4.0]) / (np.pi * np.sin(0.5 * angle) ** 2)
    want = sun_coordinates(SUN_M, angle, s.wi)[(idname, output)] + 2.0
    np.testing.assert_allclose(s.Le / base, want, rtol=1e-9, atol=1e-9)
    ((mask, _, seen, pdf),) = ls.sun_hits(s.wi)
    assert mask.all()
    np.testing.assert_allclose(seen, s.Le, rtol=1e-9)
    np.testing.assert_allclose(pdf, s.pdf, rtol=1e-9)


def test_light_path_ray_length_on_lights():
    """Light Path's Ray Length on a light point is the distance from the
    shading point (Cycles' ls->t); on a sun FLT_MAX (held to MAX_VALUE)."""
    from engine.scene import SunLight
    length = node("ShaderNodeLightPath", "Ray Length")
    colour = MixColor("MULTIPLY", 1.0, (1.0, 1.0, 1.0), length, clamp_factor=False)
    point = PointLight((0.0, 0.0, 2.0), (1.0, 1.0, 1.0), radius=0.2, shader=colour)
    sun = SunLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), 0.2, shader=colour)
    for light, want in ((point, None), (sun, MAX_VALUE)):
        scene = Scene(lights=[light])
        ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
        u = np.random.default_rng(3).random((3, 256))
        s = ls.sample(np.zeros(256, np.int64), np.zeros((256, 3)), *u)
        ok = s.pdf > 0
        plain = lights.LightSet(Scene(lights=[type(light)(**{**light.__dict__, "shader": None})]),
                                geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
        base = plain.sample(np.zeros(256, np.int64), np.zeros((256, 3)), *u).Le
        ratio = s.Le[ok, 0] / base[ok, 0]
        np.testing.assert_allclose(ratio, s.dist[ok] if want is None else want, rtol=1e-9)


def test_nan_producing_sun_tree_renders_finite():
    """A sun seen by the camera whose tree gives NaN and infinity renders
    finite pixels (NaN emission is none)."""
    from engine.scene import SunLight
    huge = MixColor("MULTIPLY", 1.0, (1e200, 1e200, 1e200), node("ShaderNodeTexCoord", "UV"), clamp_factor=False)
    nan = MixColor("SUBTRACT", 1.0, huge, huge, clamp_factor=False)
    for shader in (nan, huge):
        scene, _ = analytic_scene(SunLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), 3.0, visible_camera=True,
                                           shader=shader))
        r = render(scene, RenderSettings(samples=4, samples_per_pass=4, seed=1))
        assert np.isfinite(r.image).all() and np.isfinite(r.variance).all()


@pytest.mark.parametrize("output", ["Ray Depth", "Diffuse Depth", "Transparent Depth", "Portal Depth", "Is Camera Ray",
                                    "Is Volume Scatter Ray"])
def test_light_path_depths_on_lights(output):
    """A light tree's Light Path reads the path that reaches the light
    (shader.emission_path, as Cycles' PATH_RAY_EMISSION): Ray Depth is the
    bounce handed over + 1, the per-kind and transparent depths are the
    path's columns, and every ray kind reads 0; light samples, BSDF rays
    that hit the light and sun hits alike.  2 + the output, so a 0 is seen."""
    from engine.lights.shader import emission_path
    from engine.nodes.context import PATH_COLUMNS
    from engine.scene import SunLight
    colour = shifted(MixColor("MULTIPLY", 1.0, (1.0, 1.0, 1.0), node("ShaderNodeLightPath", output),
                              clamp_factor=False))
    n = 64
    rng = np.random.default_rng(5)
    bounce = rng.integers(0, 4, n)
    columns = rng.integers(0, 3, (n, len(PATH_COLUMNS))).astype(float)
    path = emission_path(bounce, columns)
    want = {"Ray Depth": bounce + 1.0, "Is Camera Ray": np.zeros(n), "Is Volume Scatter Ray": np.zeros(n)}.get(output)
    want = 2.0 + (columns[:, PATH_COLUMNS.index(output)] if want is None else want)
    at = np.eye(4)
    at[2, 3] = 2.0   # emitting along -Z, towards the origin
    area = AreaLight(at, (1.0, 1.0, 1.0), "SQUARE", 1.0, shader=colour)
    sun = SunLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), 0.2, shader=colour)
    for light in (PointLight((0.0, 0.0, 2.0), (1.0, 1.0, 1.0), radius=0.2, shader=colour), area, sun):
        scene = Scene(lights=[light])
        ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
        assert ls.light_path
        plain = lights.LightSet(Scene(lights=[type(light)(**{**light.__dict__, "shader": None})]),
                                geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
        u = rng.random((3, n))
        o = np.zeros((n, 3))
        s = ls.sample(np.zeros(n, np.int64), o, *u, path=path)
        base = plain.sample(np.zeros(n, np.int64), o, *u).Le
        ok = s.pdf > 0
        np.testing.assert_allclose(s.Le[ok, 0] / base[ok, 0], want[ok], rtol=1e-9)
        if isinstance(light, SunLight):
            ((mask, _, seen, _),) = ls.sun_hits(s.wi, path=path)
            np.testing.assert_allclose(seen[:, 0] / base[mask, 0], want[mask], rtol=1e-9)
            continue
        t, emitter, le, _ = ls.intersect(o, s.wi, np.full(n, np.inf), path=path)
        _, _, le_plain, _ = plain.intersect(o, s.wi, np.full(n, np.inf))
        hit = emitter >= 0
        assert hit.sum() > n // 2
        np.testing.assert_allclose(le[hit, 0] / le_plain[hit, 0], want[hit], rtol=1e-9)


def test_sun_tree_rows_follow_ray_visibility():
    """A sun with a tree, unseen by glossy rays: sun_hits keeps the tree's
    radiance of the rows that still see it (a Light Path tree tracks the
    ray kinds, so the mask and the per-row radiance must stay aligned)."""
    from engine.geometry import VIS_DIFFUSE, VIS_GLOSSY
    from engine.scene import SunLight
    sun = SunLight((0.0, 0.0, -1.0), (1.0, 1.0, 1.0), 0.3, visible_glossy=False,
                   shader=shifted(node("ShaderNodeTexCoord", "UV")))
    scene = Scene(lights=[sun])
    ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
    n = 256
    s = ls.sample(np.zeros(n, np.int64), np.zeros((n, 3)), *np.random.default_rng(7).random((3, n)))
    ray = np.where(np.arange(n) % 2 == 0, VIS_DIFFUSE, VIS_GLOSSY).astype(np.uint8)
    ((mask, _, seen, _),) = ls.sun_hits(s.wi, ray)
    assert mask.sum() == n // 2 and not mask[1::2].any()
    np.testing.assert_allclose(seen, s.Le[mask], rtol=1e-9)
