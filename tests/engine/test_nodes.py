"""The shader-node registry without Blender: every entry and case evaluates
to finite arrays of the declared shapes inside its declared value range,
validation knows every entry, and the shading context interpolates what
nodes read (Generated, Object coordinates, attributes, object info)."""
import numpy as np
import pytest

from engine import textures
from engine.nodes import REGISTRY, ShadingContext
from engine.nodes.hashing import hash_float, hash_int_to_floats, hash_uint
from engine.render import prepare
from engine.scene import (Camera, Instance, Material, Mesh, NodeCall, NodeOutput, RenderSettings, Scene,
                          SceneError)
from engine.validate import validate_scene


def _call(idname, case):
    entry = REGISTRY[idname]
    props = {name: default for name, default in entry.props}
    props.update({k: v for k, v in case.items() if k in props})
    if entry.translate is not None:
        props.update(_baked(idname))
    inputs = {}
    for name, kind in entry.inputs:
        value = case.get(name)
        if value is None and name not in ("Vector", "Normal"):
            value = 0.5 if kind == "float" else (0.5, 0.25, 0.75)
        if value is not None:
            inputs[name] = value
    return NodeCall(idname, inputs, props)


def _baked(idname):
    """What ``translate`` reads from Blender, made up here: a ramp or curve table."""
    table = np.linspace(0, 1, 257)[:, None] * np.array([[1.0, 0.5, 0.2, 1.0]])
    if idname == "ShaderNodeValToRGB":
        return {"table": table.tolist(), "constant": False}
    if idname in ("ShaderNodeRGBCurve", "ShaderNodeFloatCurve"):
        return {"table": (table[:, :3] ** 2).tolist(), "min_x": 0.0, "max_x": 1.0}
    return {"object_inverse": None}


def registry_cases():
    return [(idname, k, case) for idname, entry in sorted(REGISTRY.items())
            for k, case in enumerate(entry.cases or [{}])]


def random_context(n=400, seed=3):
    rng = np.random.default_rng(seed)
    ns = rng.normal(size=(n, 3))
    ns /= np.linalg.norm(ns, axis=1, keepdims=True)
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wo = np.where((np.einsum("ij,ij->i", wo, ns) < 0)[:, None], -wo, wo)
    return ShadingContext(n, p=rng.uniform(-3, 3, (n, 3)), ns=ns, ng=ns, wo=wo, back=rng.random(n) < 0.3,
                          uv=rng.uniform(-1, 2, (n, 2)))


@pytest.mark.parametrize("idname, k, case", registry_cases())
def test_every_node_case_is_finite_shaped_and_in_range(idname, k, case):
    """Every case of every node on random shading points: shape, finite,
    inside its declared range (``textures.value_range``).  A robustness
    check only: the values themselves are held to Cycles' pixel by pixel in
    tests/addon/test_node_parity.py (every registered node, float32
    tolerance; its coverage asserted by test_every_registered_node_is_in_the_scene)
    and the hash to its reference values below (issue 27)."""
    entry = REGISTRY[idname]
    ctx = random_context()
    call = _call(idname, case)
    for output, kind in entry.outputs:
        expr = NodeOutput(call, output)
        values = textures.Compiler().compile(expr)[0](ctx)
        assert values.shape == ((len(ctx),) if kind == "float" else (len(ctx), 3)), output
        assert np.isfinite(values).all(), output
        lo, hi = textures.value_range(expr)
        assert values.min() >= lo - 1e-6 and values.max() <= hi + 1e-6, (output, lo, hi)


def test_outputs_of_one_node_evaluate_once():
    calls = []
    entry = REGISTRY["ShaderNodeSeparateXYZ"]
    original = entry.evaluate
    entry.evaluate = lambda ctx, i, p: calls.append(1) or original(ctx, i, p)
    try:
        call = NodeCall("ShaderNodeSeparateXYZ", {"Vector": (1.0, 2.0, 3.0)})
        compiler = textures.Compiler()
        x = compiler.compile(NodeOutput(call, "X"))[0]
        y = compiler.compile(NodeOutput(call, "Y"))[0]
        ctx = random_context(5)
        assert x(ctx)[0] == 1.0 and y(ctx)[0] == 2.0
        assert len(calls) == 1
    finally:
        entry.evaluate = original


def test_implicit_conversions_follow_cycles():
    """Vector to float = average, colour to float = luminance."""
    ctx = random_context(3)
    vec = NodeOutput(NodeCall("ShaderNodeCombineXYZ", {"X": 0.3, "Y": 0.6, "Z": 0.9}), "Vector")
    col = NodeOutput(NodeCall("ShaderNodeCombineColor", {"Red": 0.3, "Green": 0.6, "Blue": 0.9},
                              {"mode": "RGB"}), "Color")
    compiler = textures.Compiler()
    np.testing.assert_allclose(compiler.value(vec)(ctx), 0.6)
    np.testing.assert_allclose(compiler.value(col)(ctx), 0.3 * 0.2126 + 0.6 * 0.7152 + 0.9 * 0.0722)


def test_lookup3_matches_its_reference_values():
    """hashword-style lookup3 of single keys as Cycles' hash_uint: values
    from a direct scalar implementation of Bob Jenkins' final()."""
    def rot(x, k):
        return ((x << k) | (x >> (32 - k))) & 0xFFFFFFFF

    def scalar(k):
        a = b = c = (0xDEADBEEF + (1 << 2) + 13) & 0xFFFFFFFF
        a = (a + k) & 0xFFFFFFFF
        for x, y, r in (("c", "b", 14), ("a", "c", 11), ("b", "a", 25), ("c", "b", 16), ("a", "c", 4),
                        ("b", "a", 14), ("c", "b", 24)):
            v = {"a": a, "b": b, "c": c}
            v[x] = ((v[x] ^ v[y]) - rot(v[y], r)) & 0xFFFFFFFF
            a, b, c = v["a"], v["b"], v["c"]
        return c
    keys = np.array([0, 1, 7, 12345, 0xFFFFFFFF], dtype=np.uint32)
    assert hash_uint(keys).tolist() == [scalar(int(k)) for k in keys]
    # -0.0 and 0.0 hash differently (float bits), as in Cycles.
    assert hash_float(np.float32([0.0]))[0] != hash_float(np.float32([-0.0]))[0]
    assert ((hash_int_to_floats(np.arange(-50, 50), np.arange(100)) >= 0)
            & (hash_int_to_floats(np.arange(-50, 50), np.arange(100)) <= 1)).all()


def test_unknown_node_and_input_are_scene_errors():
    quad = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    for bad, message in ((NodeOutput(NodeCall("ShaderNodeNope", {}), "Color"), "unknown shader node"),
                         (NodeOutput(NodeCall("ShaderNodeInvert", {"Bogus": 1.0}), "Color"), "no input"),
                         (NodeOutput(NodeCall("ShaderNodeInvert", {}), "Fac"), "no output")):
        scene = Scene([quad], [Instance(0, materials=[0])], [Material("m", emission=bad)], camera=Camera())
        with pytest.raises(SceneError, match=message):
            validate_scene(scene)


def quad_scene(material, matrix=None, mesh=None):
    mesh = mesh or Mesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float),
                        np.array([[0, 1, 2], [0, 2, 3]]))
    inst = Instance(0, np.eye(4) if matrix is None else matrix, [0], color=(0.2, 0.4, 0.6), pass_index=7,
                    random=0.25)
    return Scene([mesh], [inst], [material], camera=Camera(kind="ORTHO", ortho_scale=4.0, resolution=(8, 8),
                                                          matrix=_camera_matrix()))


def _camera_matrix():
    m = np.eye(4)
    m[2, 3] = 5.0
    return m


def _hit_context(scene, points):
    ctx = prepare(scene, RenderSettings(samples=1))
    tris = ctx.triangles
    o = np.column_stack([points, np.full(len(points), 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(len(points), 10.0))
    assert (prim >= 0).all()
    return ShadingContext.at(tris, prim, bu, bv, wo=-d)


def test_context_reads_generated_object_and_object_info():
    """Object at x + 10, scaled 2: Object = inverse(M) P; Generated maps the
    mesh's bounding box to [0, 1] (a flat z extent gives 0.5)."""
    matrix = np.diag([2.0, 2.0, 2.0, 1.0])
    matrix[0, 3] = 10.0
    scene = quad_scene(Material("m"), matrix=matrix)
    scene.camera.matrix[0, 3] = 10.0
    pts = np.array([[10.5, 1.0], [9.0, -1.5]])
    ctx = _hit_context(scene, pts)
    obj = np.column_stack([(pts[:, 0] - 10.0) / 2.0, pts[:, 1] / 2.0, np.zeros(2)])
    np.testing.assert_allclose(ctx.object_coords, obj, atol=1e-6)   # float32 barycentrics
    np.testing.assert_allclose(ctx.generated, np.column_stack([(obj[:, :2] + 1) / 2, [0.5, 0.5]]), atol=1e-6)
    np.testing.assert_allclose(ctx.object_info("color"), [[0.2, 0.4, 0.6]] * 2)
    np.testing.assert_allclose(ctx.object_info("pass_index"), [7, 7])
    np.testing.assert_allclose(ctx.object_info("random"), [0.25, 0.25])


def test_context_interpolates_colour_attributes_and_named_uv_maps():
    mesh = Mesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    corner_rgba = np.array([[1.0, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1], [1, 1, 1, 0]])
    mesh.attributes = {"Col": corner_rgba[mesh.triangles]}
    second = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    mesh.uvs = (second / 2)[mesh.triangles]
    mesh.uv_maps = {"UVMap": mesh.uvs, "Big": second[mesh.triangles]}
    ctx = _hit_context(quad_scene(Material("m"), mesh=mesh), np.array([[0.0, -1.0 + 1e-9]]))
    # Midway along the bottom edge: half corner 0, half corner 1.
    np.testing.assert_allclose(ctx.attribute("Col")[0], [0.5, 0.5, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(ctx.uv_map("Big")[0], [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(ctx.uv[0], [0.5, 0.0], atol=1e-6)
    assert ctx.attribute("Missing") is None


def test_bump_on_a_procedural_height_follows_its_position_gradient():
    """Height = Generated x (a Gradient texture, linear) on a 2 m quad: the
    surface gradient is (0.5, 0, 0) per metre."""
    from engine.scene import Bump
    height = NodeOutput(NodeCall("ShaderNodeTexGradient", {}, {"gradient_type": "LINEAR"}), "Fac")
    scene = quad_scene(Material("bumped", normal=Bump(height, 1.0, 0.4)))
    ctx = prepare(scene, RenderSettings(samples=1))
    from types import SimpleNamespace
    from engine.integrator import _interaction
    o = np.array([[0.2, 0.3, 5.0], [-0.5, 0.1, 5.0]])
    d = np.tile([0.0, 0.0, -1.0], (2, 1))
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(2, 10.0))
    hit = _interaction(ctx, SimpleNamespace(o=o, d=d), t, prim, bu, bv)
    got = ctx.materials.textures.perturb(hit, ctx.triangles)
    want = np.array([-0.4 * 0.5, 0.0, 1.0])
    np.testing.assert_allclose(got, [want / np.linalg.norm(want)] * 2, atol=2e-5)   # float32 heights


@pytest.mark.parametrize("space, strength", [("OBJECT", 1.0), ("BLENDER_OBJECT", 1.0), ("WORLD", 1.0),
                                             ("OBJECT", 0.5)])
def test_object_and_world_space_normal_maps(space, strength):
    """Colour (0.8, 0.5, 0.9) is the normal (0.6, 0, 0.8); Blender's spaces
    negate y and z; object space turns with the object (here 90 degrees
    about z); strength blends linearly from the shading normal (Cycles)."""
    from types import SimpleNamespace
    from engine.integrator import _interaction
    from engine.scene import NormalMap
    rot = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    color = (0.8, 0.5, 0.1) if space == "BLENDER_OBJECT" else (0.8, 0.5, 0.9)
    scene = quad_scene(Material("mapped", normal=NormalMap(color, strength, space)), matrix=rot)
    ctx = prepare(scene, RenderSettings(samples=1))
    o = np.array([[0.2, 0.3, 5.0]])
    d = np.array([[0.0, 0.0, -1.0]])
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(1, 10.0))
    hit = _interaction(ctx, SimpleNamespace(o=o, d=d), t, prim, bu, bv)
    got = ctx.materials.textures.perturb(hit, ctx.triangles)[0]
    want = np.array([0.6, 0.0, 0.8]) if space == "WORLD" else np.array([0.0, 0.6, 0.8])
    if strength != 1.0:
        n = np.array([0.0, 0.0, 1.0])
        want = n + (want - n) * strength
        want /= np.linalg.norm(want)
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_unevaluated_properties_are_rejected_by_validation():
    quad = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    attr = NodeOutput(NodeCall("ShaderNodeAttribute", {}, {"attribute_type": "PARTICLE"}), "Fac")
    scene = Scene([quad], [Instance(0, materials=[0])], [Material("m", emission=attr)], camera=Camera())
    with pytest.raises(SceneError, match="PARTICLE"):
        validate_scene(scene)


def test_context_subsets_keep_missing_attributes_missing():
    scene = quad_scene(Material("m"))
    ctx = _hit_context(scene, np.array([[0.0, 0.0], [0.5, 0.5]]))
    assert ctx.attribute("Nope") is None
    sub = ctx.take(np.array([1]))
    assert sub.attribute("Nope") is None and len(sub) == 1


def test_subset_contexts_read_their_parents_rows():
    """take() and shifted_pairs() pick a field's rows when it is first read:
    every field, nested subsets and cached values equal the eager gathers,
    a value cached after the subset was taken stays the subset's own, and
    a field set on a subset replaces the deferred one."""
    scene = quad_scene(Material("m"))
    pts = np.random.default_rng(4).uniform(-0.9, 0.9, (40, 2))
    ctx = _hit_context(scene, pts)
    ctx.depth = np.arange(40, dtype=np.int32)
    obj = ctx.object_coords.copy()
    rows = np.arange(40)[::-3]
    sub = ctx.take(rows)
    inner = sub.take(np.array([4, 0, 2]))
    for name in ("prim", "bary", "p", "ng", "ns", "wo", "back", "depth", "ray"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(ctx, name)[rows], err_msg=name)
        np.testing.assert_array_equal(getattr(inner, name), getattr(ctx, name)[rows[[4, 0, 2]]], err_msg=name)
    assert sub.path is None and inner.fibre is None
    np.testing.assert_array_equal(inner.object_coords, obj[rows[[4, 0, 2]]])
    np.testing.assert_allclose(sub.uv, ctx.uv[rows])
    sub.depth = np.zeros(len(rows), np.int32)
    assert not sub.depth.any() and ctx.depth[rows].any()
    with pytest.raises(AttributeError):
        sub.no_such_field
    steps = (np.full((40, 3), [1e-3, 0.0, 0.0]), np.full((40, 3), [0.0, 1e-3, 0.0]))
    pairs = sub.shifted_pairs(tuple(s[rows] for s in steps))
    # A point's four copies are consecutive: +s0, -s0, +s1, -s1.
    repeated = np.repeat(np.arange(len(rows)), 4)
    for name in ("prim", "ng", "ns", "wo", "back", "depth", "ray"):
        np.testing.assert_array_equal(getattr(pairs, name), getattr(sub, name)[repeated], err_msg=name)
    moves = np.array([[1e-3, 0.0, 0.0], [-1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0], [0.0, -1e-3, 0.0]])
    np.testing.assert_allclose(pairs.p, ctx.p[rows][repeated] + np.tile(moves, (len(rows), 1)), atol=1e-12)
    # The quad's object is unscaled: Object coordinates move with the point;
    # so do the barycentrics (the interpolated position is the moved point).
    np.testing.assert_allclose(pairs.object_coords[1::4], obj[rows] - [1e-3, 0.0, 0.0], atol=1e-12)
    tris = ctx.tris
    moved = (tris.p0[pairs.prim] + pairs.bary[:, :1] * tris.e1[pairs.prim] + pairs.bary[:, 1:] * tris.e2[pairs.prim])
    np.testing.assert_allclose(moved, pairs.p, atol=1e-6)   # float32 hit barycentrics


def test_pointiness_welds_and_blurs_as_cycles():
    """A tetrahedron's tip is pointier than a flat vertex (0.5); a copy of
    a vertex at the same place is welded (same value); the blur averages a
    vertex with its edge neighbours."""
    from engine import mesh_attributes
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 1.0], [0.3, 0.3, 1.0]], np.float32)
    edges = np.array([[0, 1], [1, 2], [2, 0], [0, 3], [1, 4], [2, 3]])
    normals = np.array([[-1, -1, -1], [1, -1, -0.2], [-1, 1, -0.2], [0, 0, 1], [0, 0, 1]], np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    p = mesh_attributes.pointiness(pos, normals, edges)
    assert p[3] == p[4]
    assert (p > 0.5).all() and np.isfinite(p).all()


def test_island_roots_follow_cycles_disjoint_set():
    """Union by rank, the first edge vertex's root kept on ties: (1, 0)
    roots {0, 1} at 1, (2, 3) roots {2, 3} at 2, (3, 0) joins the two
    rank-1 roots under 2 (3's); 4 stays alone."""
    from engine import mesh_attributes
    roots = mesh_attributes.island_roots(5, np.array([[1, 0], [2, 3], [3, 0]]))
    assert roots.tolist() == [2, 2, 2, 2, 4]
    value = mesh_attributes.random_per_island(5, np.array([[1, 0], [2, 3], [3, 0]]), np.array([[0, 1, 2], [4, 4, 4]]))
    assert value[0] != value[1] and 0 <= value.min() and value.max() <= 1
