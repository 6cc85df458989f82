"""Ambient Occlusion and Bevel (engine.nodes.ray_nodes) against analytic
answers: AO of a floor next to a tall wall (the cosine-weighted hemisphere
projects to the uniform unit disk, so the occluded share is a disk
segment), AO exactly 1 or 0 where geometry decides, Bevel exactly the face
normal on flat faces and symmetric on a cube's edge; the no-ray values
where Cycles does not ray-trace; and the integrator's hook (rays only from
path hits, reproducible sample ranges)."""
import numpy as np
import pytest

from ember_stats import detectable, family_level, power_line, z_threshold
from engine import textures
from engine.nodes import NodeRays, ShadingContext
from engine.render import prepare, render
from engine.sampler import Sampler
from engine.scene import (Camera, Instance, Material, Mesh, NodeCall, NodeOutput, RenderSettings, Scene,
                          World)
from engine.validate import validate_scene


def quad(corners):
    return Mesh(np.array(corners, float), np.array([[0, 1, 2], [0, 2, 3]]))


def cube_mesh(half=1.0):
    """Closed cube, outward winding, flat."""
    v = half * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    tris = []
    for a, b, c, d in [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]:
        tris += [(a, b, c), (a, c, d)]
    return Mesh(v, np.array(tris))


FLOOR = quad([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]])
WALL_X = 0.5
WALL = quad([[WALL_X, -10, 0], [WALL_X, 10, 0], [WALL_X, 10, 10], [WALL_X, -10, 10]])


def scene_of(meshes, material=None):
    material = material or Material("m")
    return Scene(list(meshes), [Instance(i, materials=[0]) for i in range(len(meshes))], [material],
                 camera=Camera())


def points_context(scene, xy, copies, z=5.0, d=(0.0, 0.0, -1.0), sharp=True, seed=1):
    """Shading points hit from above at xy, each ``copies`` times as
    samples 0..copies-1 of its own pixel (independent random numbers)."""
    ctx = prepare(scene, RenderSettings(samples=1))
    xy = np.asarray(xy, float)
    n = len(xy) * copies
    o = np.column_stack([np.repeat(xy, copies, axis=0), np.full(n, z)])
    dirs = np.tile(d, (n, 1))
    t, prim, bu, bv = ctx.accel.intersect(o, dirs, np.full(n, 100.0))
    assert (prim >= 0).all()
    sc = ShadingContext.at(ctx.triangles, prim, bu, bv, wo=-dirs)
    sampler = Sampler(seed, "random")
    pix = np.repeat(np.arange(len(xy)), copies)
    sc.rays = NodeRays.of_samples(ctx.accel, ctx.triangles, sampler, sampler.pixel_seeds(pix),
                                  np.tile(np.arange(copies, dtype=np.uint32), len(xy)), sharp=sharp)
    return sc


def evaluate(idname, output, ctx, inputs, props):
    return textures.Compiler().compile(NodeOutput(NodeCall(idname, inputs, props), output))[0](ctx)


def floor_ao(x, distance):
    """AO of a floor point at x before a wall at WALL_X rising past the
    distance: rays with dx > (WALL_X - x) / distance meet it."""
    c = min((WALL_X - x) / distance, 1.0)
    return 1.0 - (np.arccos(c) - c * np.sqrt(1.0 - c * c)) / np.pi


def test_ao_of_a_floor_before_a_wall_is_the_disk_segment():
    xs, copies, samples = [0.0, 0.25, 0.4], 1500, 16
    ctx = points_context(scene_of([FLOOR, WALL]), [(x, 0.0) for x in xs], copies)
    ao = evaluate("ShaderNodeAmbientOcclusion", "AO", ctx, {"Distance": 1.0}, {"samples": samples})
    level = family_level("ray nodes: AO floor before a wall, analytic", len(xs))
    for k, x in enumerate(xs):
        want = floor_ao(x, 1.0)
        got = ao[k * copies:(k + 1) * copies].mean()
        # Each sample averages 16 independent Bernoulli rays.
        se = np.sqrt(want * (1 - want) / (copies * samples))
        print(power_line(f"AO at x={x}", se / want, level), f"got {got:.4f} want {want:.4f}")
        assert detectable(se, level) < 0.02
        assert abs(got - want) / se < z_threshold(level), (x, got, want)


def test_ao_is_exactly_one_or_zero_where_geometry_decides():
    floor_wall = scene_of([FLOOR, WALL])
    ctx = points_context(floor_wall, [(-1.0, 0.0), (0.3, 2.0)], 64)
    ao = lambda c, **kw: evaluate("ShaderNodeAmbientOcclusion", "AO", c, {"Distance": kw.pop("d", 1.0)},
                                  {"samples": 8, **kw})
    a = ao(ctx)
    assert (a[:64] == 1.0).all()                     # the wall lies beyond the distance
    assert (a[64:] < 1.0).any()
    assert (ao(ctx, only_local=True) == 1.0).all()    # the wall is another object
    assert (ao(ctx, inside=True) == 1.0).all()        # nothing below the floor
    assert (ao(ctx, d=0.0) == 1.0).all() and (ao(ctx, d=-1.0) == 1.0).all()
    # Inside a closed cube every ray meets the cube: outside, from its top.
    cube = points_context(scene_of([cube_mesh()]), [(0.3, -0.2), (0.9, 0.9)], 16)
    assert (ao(cube, inside=True, d=10.0) == 0.0).all()
    assert (ao(cube, inside=True, only_local=True, d=10.0) == 0.0).all()
    assert (ao(cube, d=10.0) == 1.0).all()
    # Color output = Color x AO; the world's distance where Distance is 0
    # and unlinked (the exporter's global_distance).
    color = evaluate("ShaderNodeAmbientOcclusion", "Color", ctx, {"Distance": 1.0, "Color": (0.2, 0.4, 0.8)},
                     {"samples": 8})
    np.testing.assert_allclose(color, a[:, None] * [0.2, 0.4, 0.8])
    far = evaluate("ShaderNodeAmbientOcclusion", "AO", ctx, {"Distance": 0.0},
                   {"samples": 8, "global_distance": 100.0})
    assert (far[:64] < 1.0).any()


def test_without_rays_ao_is_one_and_bevel_the_shading_normal():
    """Contexts without a NodeRays (light samples, shadow rays, worlds,
    probes) get Cycles' values without the raytrace feature."""
    ctx = points_context(scene_of([FLOOR, WALL]), [(0.4, 0.0)], 8)
    ctx.rays = None
    assert (evaluate("ShaderNodeAmbientOcclusion", "AO", ctx, {"Distance": 1.0}, {}) == 1.0).all()
    ref = np.tile([0.0, 0.6, 0.8], (len(ctx), 1))
    out = evaluate("ShaderNodeBevel", "Normal", ctx, {"Radius": 0.5, "Normal": tuple(ref[0])}, {})
    np.testing.assert_array_equal(out, ctx.ns)


def test_bevel_on_a_flat_face_is_the_face_normal():
    ctx = points_context(scene_of([cube_mesh()]), [(0.0, 0.0), (0.5, -0.3)], 32)
    out = evaluate("ShaderNodeBevel", "Normal", ctx, {"Radius": 0.3}, {"samples": 4})
    np.testing.assert_allclose(out, np.tile([0.0, 0.0, 1.0], (len(out), 1)), atol=1e-12)
    # Seen from inside the cube (a back face): the normal faces the viewer.
    inner = points_context(scene_of([cube_mesh()]), [(0.0, 0.0)], 16, z=0.0, d=(0.0, 0.0, 1.0))
    out = evaluate("ShaderNodeBevel", "Normal", inner, {"Radius": 0.3}, {"samples": 4})
    np.testing.assert_allclose(out, np.tile([0.0, 0.0, -1.0], (len(out), 1)), atol=1e-12)


def test_bevel_rounds_a_cube_edge_and_only_its_own():
    """A point on the edge between the top (+z) and side (+x) faces: the
    mean bevel normal lies between the two (Cycles' estimator is not
    symmetric in them: the disk axes are picked around the top face's
    normal); near the edge it tilts less; a wall of another object changes
    nothing; a path after a blurry bounce is not bevelled (Cycles'
    min_ray_pdf < 8)."""
    copies = 2000
    ctx = points_context(scene_of([cube_mesh()]), [(1.0 - 1e-9, 0.0), (0.9, 0.0), (0.5, 0.0)], copies)
    out = evaluate("ShaderNodeBevel", "Normal", ctx, {"Radius": 0.2}, {"samples": 4})
    edge, near, far = (out[k * copies:(k + 1) * copies] for k in range(3))
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0)
    mean = edge.mean(axis=0)
    print(f"bevel on the edge: mean normal {mean}, se {edge.std(axis=0) / np.sqrt(copies)}")
    assert 0.45 < mean[0] < 0.65 and 0.45 < mean[2] < 0.65 and abs(mean[1]) < 0.02
    assert 0.05 < near[:, 0].mean() < mean[0]
    np.testing.assert_allclose(far, np.tile([0.0, 0.0, 1.0], (copies, 1)), atol=1e-12)
    walled = points_context(scene_of([cube_mesh(), quad([[0.95, -2, -2], [0.95, 2, -2], [0.95, 2, 2],
                                                         [0.95, -2, 2]])]), [(0.5, 0.0)], 64)
    out = evaluate("ShaderNodeBevel", "Normal", walled, {"Radius": 0.2}, {"samples": 4})
    np.testing.assert_allclose(out, np.tile([0.0, 0.0, 1.0], (64, 1)), atol=1e-12)
    blurry = points_context(scene_of([cube_mesh()]), [(1.0 - 1e-9, 0.0)], 16, sharp=False)
    out = evaluate("ShaderNodeBevel", "Normal", blurry, {"Radius": 0.2}, {"samples": 4})
    np.testing.assert_array_equal(out, blurry.ns)


def test_bevel_keeps_a_linked_normal_as_cycles():
    """normalize(ref + (bevel - N)): on a flat face bevel = N, so the
    result is the normalized reference."""
    ctx = points_context(scene_of([cube_mesh()]), [(0.0, 0.0)], 8)
    out = evaluate("ShaderNodeBevel", "Normal", ctx, {"Radius": 0.2, "Normal": (0.0, 3.0, 4.0)}, {})
    np.testing.assert_allclose(out, np.tile([0.0, 0.6, 0.8], (8, 1)), atol=1e-12)


# ----------------------------------------------------------------------------
# through the integrator

def ao_emission_scene():
    ao = NodeOutput(NodeCall("ShaderNodeAmbientOcclusion", {"Distance": 1.0}, {"samples": 4}), "Color")
    material = Material("ao", lobes=(), emission=ao)
    m = np.eye(4)
    m[:3, 3] = (0.0, 0.0, 5.0)
    return Scene([FLOOR, WALL], [Instance(0, materials=[0]), Instance(1, materials=[0])], [material],
                 camera=Camera(kind="ORTHO", ortho_scale=4.0, resolution=(16, 16), matrix=m),
                 world=World((0.0, 0.0, 0.0)))


def test_path_hits_cast_node_rays_and_sample_ranges_merge():
    """Seen by the camera, the floor's AO emission darkens towards the wall
    and is exactly 1 beyond the distance; samples [0, 4) and [4, 8)
    rendered apart give the [0, 8) render (node rays are addressed by
    sample index)."""
    scene = ao_emission_scene()
    settings = dict(max_bounces=0, filter_type="BOX", filter_width=1.0, seed=3)
    whole = render(scene, RenderSettings(samples=8, **settings))
    img = whole.image[..., 0]
    # Columns: x from -2 to 2; the wall stands at x = 0.5 (column 10).
    assert (img[:, :5] == 1.0).all()
    assert img[:, 7:10].mean() < 0.9
    first = render(scene, RenderSettings(samples=4, **settings))
    second = render(scene, RenderSettings(samples=4, sample_start=4, **settings))
    merged = (first.image[..., 0] + second.image[..., 0]) / 2
    np.testing.assert_allclose(merged, img, rtol=1e-6, atol=1e-7)


def test_a_bevel_output_as_the_material_normal():
    """Material.normal may be a vector node's output: the shading normal
    becomes the Bevel normal of the same context (the same rays)."""
    from types import SimpleNamespace
    bevel = NodeOutput(NodeCall("ShaderNodeBevel", {"Radius": 0.2}, {"samples": 4}), "Normal")
    scene = scene_of([cube_mesh()], Material("bevelled", normal=bevel))
    validate_scene(scene)
    ctx = points_context(scene, [(0.97, 0.0), (0.0, 0.0)], 64)
    tex = textures.MaterialTextures(scene.materials)
    hit = SimpleNamespace(ns=ctx.ns, ng=ctx.ng, wo=ctx.wo, mat=np.zeros(len(ctx), int), back=ctx.back,
                          p=ctx.p, prim=ctx.prim, shading=ctx)
    ns = tex.perturb(hit, ctx.tris)
    want = evaluate("ShaderNodeBevel", "Normal", ctx, {"Radius": 0.2}, {"samples": 4})
    # Also where the viewer sees it from behind (the shading stage then
    # gives the glossy lobes Cycles' corrected normal: engine/bump_correction.py).
    np.testing.assert_allclose(ns, want, atol=1e-12)
    assert (ns[:64, 0] > 0.05).mean() > 0.3 and np.allclose(ns[64:], [0.0, 0.0, 1.0])


def test_nodes_cast_rays_in_bounded_chunks_with_the_same_result(monkeypatch):
    """At most MAX_RAYS rays per node call at a time; chunking changes no value."""
    import engine.nodes.ray_nodes as ray_nodes
    ctx = points_context(scene_of([FLOOR, WALL, cube_mesh(0.3)]), [(0.97, 0.0), (0.4, 0.2), (0.2, 0.1)], 40)
    calls = [("ShaderNodeBevel", "Normal", {"Radius": 0.2}, {"samples": 4}),
             ("ShaderNodeAmbientOcclusion", "Color", {"Distance": 1.0, "Color": (0.5, 0.2, 0.1)}, {"samples": 8})]
    whole = [evaluate(idname, out, ctx, i, p) for idname, out, i, p in calls]
    monkeypatch.setattr(ray_nodes, "MAX_RAYS", 24)
    for (idname, out, i, p), want in zip(calls, whole):
        np.testing.assert_array_equal(evaluate(idname, out, ctx, i, p), want)
