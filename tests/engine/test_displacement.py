"""True displacement (engine/displacement.py) on small meshes: each vertex
moves by the height at its first displacing corner along its normal, the
normals of "Displacement Only" are the displaced mesh's, "Both" keeps them,
instances share one displaced copy, and non-finite or huge heights give
finite geometry or a named SceneError."""
import numpy as np
import pytest

from engine import scene as S
from engine.displacement import displaced_scene
from engine.render import prepare


def grid(n=4, smooth=True):
    """An n x n quad grid in z = 0 over [0, 1]^2, UVs = (x, y)."""
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    tris = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i
            tris += [(a, b, c), (a, c, d)]
    tris = np.array(tris, np.int64)
    normals = np.tile([0.0, 0.0, 1.0], (len(tris), 3, 1)) if smooth else None
    return S.Mesh(pos, tris, normals=normals, uvs=pos[tris][..., :2].copy(), name="grid")


def uv_x():
    """Height = the UV map's u (the Texture Coordinate node's UV x)."""
    call = S.NodeCall("ShaderNodeSeparateXYZ", {"Vector": S.NodeOutput(S.NodeCall("ShaderNodeTexCoord", {}), "UV")})
    return S.NodeOutput(call, "X")


def one(mesh, height, method="DISPLACEMENT", space="OBJECT", matrix=None, copies=1):
    mat = S.Material("d", (S.Lobe("diffuse"),), displacement=S.Displacement(height, space, method))
    inst = [S.Instance(0, np.eye(4) if matrix is None else matrix, (0,)) for _ in range(copies)]
    return S.Scene(meshes=[mesh], instances=inst, materials=[mat])


def test_vertices_move_by_the_height_along_the_normal():
    mesh = grid()
    out = displaced_scene(one(mesh, S.Math("MULTIPLY", uv_x(), 0.5)))
    pos = out.meshes[0].positions
    np.testing.assert_allclose(pos[:, :2], mesh.positions[:, :2], atol=0)
    np.testing.assert_allclose(pos[:, 2], 0.5 * mesh.positions[:, 0], atol=1e-6)


def test_displacement_only_recomputes_the_normals_and_both_keeps_them():
    mesh = grid()
    only = displaced_scene(one(mesh, uv_x())).meshes[0]
    # z = x: the displaced plane's normal is (-1, 0, 1) / sqrt 2 everywhere.
    expected = np.tile([-2 ** -0.5, 0, 2 ** -0.5], (only.normals.size // 3, 1))
    np.testing.assert_allclose(only.normals.reshape(-1, 3), expected, atol=1e-6)
    both = displaced_scene(one(mesh, uv_x(), method="BOTH")).meshes[0]
    np.testing.assert_array_equal(both.normals, mesh.normals)
    np.testing.assert_allclose(both.positions, only.positions)


def test_flat_mesh_moves_along_face_normals():
    mesh = grid(smooth=False)
    out = displaced_scene(one(mesh, 0.25)).meshes[0]
    np.testing.assert_allclose(out.positions[:, 2], 0.25)
    assert out.normals is None


def test_world_space_follows_the_object_scale():
    m = np.diag([1.0, 1.0, 2.0, 1.0])
    out = displaced_scene(one(grid(), 0.5, space="WORLD", matrix=m)).meshes[0]
    np.testing.assert_allclose(out.positions[:, 2], 0.25)   # 0.5 in world is 0.25 in object space
    obj = displaced_scene(one(grid(), 0.5, space="OBJECT", matrix=m)).meshes[0]
    np.testing.assert_allclose(obj.positions[:, 2], 0.5)


def test_instances_share_one_displaced_mesh():
    out = displaced_scene(one(grid(), 0.1, copies=3))
    assert len(out.meshes) == 1 and all(i.mesh == 0 for i in out.instances)
    assert out.meshes[0] is not None and np.allclose(out.meshes[0].positions[:, 2], 0.1)


def test_generated_stays_undisplaced():
    out = displaced_scene(one(grid(), uv_x())).meshes[0]
    np.testing.assert_allclose(out.orco, grid().positions[grid().triangles])
    assert out.texspace is not None


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_heights_move_nothing(bad):
    out = displaced_scene(one(grid(), S.Math("MULTIPLY", uv_x(), bad))).meshes[0]
    assert np.isfinite(out.positions).all()


def test_huge_heights_are_named():
    with pytest.raises(S.SceneError, match="displacement"):
        prepare(one(grid(), S.Math("MULTIPLY", uv_x(), 1e300)), S.RenderSettings())


def test_both_bumps_with_the_undisplaced_derivatives():
    """The bump of "Both" sees the undisplaced plane: on the plane z = x
    displaced from z = 0, a height gradient along the displaced surface
    maps back to the flat plane's (Cycles' NODE_ENTER_BUMP_EVAL)."""
    from engine.geometry import flatten
    from engine.textures import _on_undisplaced
    out = displaced_scene(one(grid(), uv_x(), method="BOTH"))
    assert out.meshes[0].undisplaced is not None
    tris = flatten(out)
    prim = np.arange(len(tris.ng))
    ctx = type("Ctx", (), {"prim": prim})()
    # H = u rises by 1 per unit x; along the tilted surface (x, 0, x) / sqrt 2 that is a
    # gradient (1, 0, 1) / 2 in the displaced triangle's plane.
    grad = np.tile([0.5, 0.0, 0.5], (len(prim), 1))
    grad0, ng0 = _on_undisplaced(grad, tris.ng[prim], tris, ctx)
    np.testing.assert_allclose(grad0, np.tile([1.0, 0.0, 0.0], (len(prim), 1)), atol=1e-12)
    np.testing.assert_allclose(ng0, np.tile([0.0, 0.0, 1.0], (len(prim), 1)), atol=1e-12)


def test_both_takes_the_footprint_differentials_of_the_undisplaced_surface():
    """The footprint bump of "Both" (engine.textures.footprint_bump): the
    hit's dPdx, dPdy on the displaced plane z = x become the same
    barycentric moves on the flat plane, as Cycles' NODE_ENTER_BUMP_EVAL
    differentiates the undisplaced position: (1, 0, 1) s / sqrt 2 there is
    (s / sqrt 2, 0, 0) here, and (0, s, 0) stays."""
    from engine.geometry import flatten
    from engine.textures import _undisplaced_differentials
    out = displaced_scene(one(grid(), uv_x(), method="BOTH"))
    tris = flatten(out)
    prim = np.arange(len(tris.ng))
    ctx = type("Ctx", (), {"prim": prim})()
    s = 0.01
    dx = np.tile([s / np.sqrt(2.0), 0.0, s / np.sqrt(2.0)], (len(prim), 1))
    dy = np.tile([0.0, s, 0.0], (len(prim), 1))
    dx0, dy0 = _undisplaced_differentials(dx, dy, tris, ctx)
    np.testing.assert_allclose(dx0, np.tile([s / np.sqrt(2.0), 0.0, 0.0], (len(prim), 1)), atol=1e-12)
    np.testing.assert_allclose(dy0, dy, atol=1e-12)
