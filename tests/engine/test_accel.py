"""The Embree upload of flattened instances (engine.geometry.flatten,
engine.accel, engine.embree_upload): the same triangles as the corner soup
it replaced, and the same hits, on a scene with several instances
(rotated, scaled, mirrored, with a degenerate triangle)."""
import sys

import numpy as np
import pytest

from engine import accel as accel_module
from engine import embree_upload
from engine.accel import Accel
from engine.geometry import flatten
from engine.scene import Instance, Mesh, Scene
from engine.testscenes import WHITE, RED, box, translate_rotate_z, uv_sphere


def _sphere_with_degenerate():
    """A smooth sphere plus one zero-area triangle (flatten drops it)."""
    sphere = uv_sphere(0.5, segments=24, rings=12)
    triangles = np.vstack([sphere.triangles, [[0, 0, 1]]])
    normals = np.concatenate([sphere.normals, sphere.normals[:1]])
    slots = np.arange(len(triangles)) % 2
    return Mesh(sphere.positions, triangles, normals=normals, material_slots=slots, name="sphere")


def _instances():
    mirror = translate_rotate_z((0.0, 2.0, 0.3), 30.0)
    mirror[:3, 0] *= -1.0   # det < 0: winding and normals flip
    skew = translate_rotate_z((2.0, -1.0, 0.0), 10.0, scale=1.7)
    skew[2, 0] = 0.4
    placements = [(0, np.eye(4)), (0, translate_rotate_z((1.5, 0.5, 0.2), 45.0, 0.8)), (0, mirror),
                  (1, translate_rotate_z((-1.5, 0.0, 0.0), 20.0)), (0, skew),
                  (1, translate_rotate_z((0.5, -2.0, 0.5), -60.0, 0.6))]
    slots = [(0, 1), (1,), (), (0, 1, 7), (1, 0), (0, 1)]   # 7: past the table -> default
    return [Instance(mesh, matrix, materials=mats, visible_shadow=(i % 3 != 1))
            for i, ((mesh, matrix), mats) in enumerate(zip(placements, slots))]


@pytest.fixture(scope="module")
def scene():
    return Scene(meshes=[_sphere_with_degenerate(), box((1.0, 0.6, 0.8))], instances=_instances(),
                 materials=[WHITE, RED])


@pytest.fixture(scope="module")
def triangles(scene):
    return flatten(scene, with_instance=True)


def _corner_soup(scene):
    """What flatten computed before shared vertices: every instance's
    corners transformed one triangle at a time, degenerate ones dropped."""
    p0, e1, e2, ns, smooth = [], [], [], [], []
    for inst in scene.instances:
        mesh = scene.meshes[inst.mesh]
        lin, off = inst.matrix[:3, :3], inst.matrix[:3, 3]
        world = np.asarray(mesh.positions, np.float64)[mesh.triangles] @ lin.T + off
        p0.append(world[:, 0])
        e1.append(world[:, 1] - world[:, 0])
        e2.append(world[:, 2] - world[:, 0])
        normals = mesh.normals if mesh.normals is not None else np.ones((len(world), 3, 3))
        ns.append(normals @ np.linalg.inv(lin))
        smooth.append(np.full(len(world), mesh.normals is not None))
    p0, e1, e2, ns = np.concatenate(p0), np.concatenate(e1), np.concatenate(e2), np.concatenate(ns)
    c = np.cross(e1, e2)
    clen = np.linalg.norm(c, axis=1)
    keep = np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)
    ng = c[keep] / clen[keep, None]
    ns = ns[keep] / np.linalg.norm(ns[keep], axis=2)[..., None]
    flat = ~np.concatenate(smooth)[keep]
    ns[flat] = ng[flat, None, :]
    return p0[keep], e1[keep], e2[keep], ng, ns, 0.5 * clen[keep]


def test_flatten_matches_the_corner_soup(triangles, scene):
    p0, e1, e2, ng, ns, area = _corner_soup(scene)
    assert triangles.dropped == sum(inst.mesh == 0 for inst in scene.instances)  # one per sphere
    assert len(triangles) == len(p0)
    for name, expected in (("p0", p0), ("e1", e1), ("e2", e2), ("ng", ng), ("ns", ns), ("area", area)):
        np.testing.assert_array_equal(getattr(triangles, name), expected, err_msg=name)


def test_flatten_on_several_threads_is_the_same(triangles, scene, monkeypatch):
    """Big scenes flatten on every core (jobs write disjoint rows): forced
    here onto three threads, every array is the one-thread result."""
    from engine import geometry
    monkeypatch.setattr(geometry, "PARALLEL_ROWS", 1)
    monkeypatch.setattr(geometry.os, "cpu_count", lambda: 3)
    assert geometry._Workers(1).threads == 3 and geometry._Workers(1, threads=1).threads == 1
    threaded = flatten(scene, with_instance=True)
    for name in ("p0", "e1", "e2", "ng", "ns", "area", "material", "smooth", "visibility", "instance",
                 "vertices", "indices", "kept"):
        np.testing.assert_array_equal(getattr(threaded, name), getattr(triangles, name), err_msg=name)


def test_flatten_per_triangle_instance_data(triangles, scene):
    """Materials (each instance's slot table), visibility, instance and
    triangle-in-mesh indices, as one instance at a time would give them."""
    material, visible, owner, local = [], [], [], []
    n_mat = len(scene.materials)
    for index, inst in enumerate(scene.instances):
        mesh = scene.meshes[inst.mesh]
        slots = np.zeros(len(mesh.triangles), int) if mesh.material_slots is None else mesh.material_slots
        table = [m if 0 <= m < n_mat else n_mat for m in inst.materials] + [n_mat]
        material.append([table[min(s, len(table) - 1)] for s in slots])
        visible.append(np.full(len(slots), 15 if not inst.visible_shadow else 31))
        owner.append(np.full(len(slots), index))
        local.append(np.arange(len(slots)))
    keep = triangles.kept
    for name, got, expected in (("material", triangles.material, material),
                                ("visibility", triangles.visibility, visible),
                                ("instance", triangles.instance, owner),
                                ("local", triangles.shading.local, local)):
        np.testing.assert_array_equal(got, np.concatenate(expected)[keep], err_msg=name)


def test_shared_vertices_give_the_triangles(triangles):
    v, i = triangles.vertices, triangles.indices
    assert i.shape == (len(triangles), 3)
    np.testing.assert_array_equal(v[i[:, 0]], triangles.p0)
    np.testing.assert_array_equal(v[i[:, 1]] - v[i[:, 0]], triangles.e1)
    np.testing.assert_array_equal(v[i[:, 2]] - v[i[:, 0]], triangles.e2)
    vertices, indices = triangles.indexed_float32()
    # The float32 corners Embree gets are the old corner soup's, p0 + e1 and
    # p0 + e2 rounded; they differ only where that float64 sum is not exact
    # (a coordinate near 0 on a triangle far from 0), below a float32 ulp.
    soup = triangles.corners_float32()
    ulp = np.finfo(np.float32).eps * np.abs(soup).max(axis=(1, 2))
    assert np.all(np.abs(vertices[indices] - soup) <= ulp[:, None, None])


def _rays(triangles, n=20000, seed=7):
    """Rays from random points around the scene aimed at random points of
    random triangles (mostly hits, some grazing), plus some random rays."""
    rng = np.random.default_rng(seed)
    lo = triangles.p0.min(axis=0) - 1.0
    hi = triangles.p0.max(axis=0) + 1.0
    origins = lo + (hi - lo) * rng.random((n, 3))
    prim = rng.integers(0, len(triangles), n)
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1.0
    a, b = np.where(flip, 1.0 - a, a), np.where(flip, 1.0 - b, b)
    targets = triangles.p0[prim] + a[:, None] * triangles.e1[prim] + b[:, None] * triangles.e2[prim]
    d = targets - origins
    d[: n // 10] = rng.normal(size=(n // 10, 3))
    return origins, d / np.linalg.norm(d, axis=1)[:, None], np.full(n, np.inf)


class _Soup:
    """Triangles as the old upload saw them: corners only."""

    def __init__(self, triangles):
        self.triangles = triangles

    def __len__(self):
        return len(self.triangles)

    def corners_float32(self):
        return self.triangles.corners_float32()


def _assert_same_hits(new, old, rays):
    t_new, prim_new, u_new, v_new = new.intersect(*rays)
    t_old, prim_old, u_old, v_old = old.intersect(*rays)
    assert np.count_nonzero(prim_old >= 0) > 0.8 * len(prim_old)
    np.testing.assert_array_equal(prim_new, prim_old)
    np.testing.assert_array_equal(t_new, t_old)
    np.testing.assert_array_equal(u_new, u_old)
    np.testing.assert_array_equal(v_new, v_old)
    np.testing.assert_array_equal(new.occluded(*rays), old.occluded(*rays))


@pytest.fixture(scope="module")
def soup_accel(triangles):
    """The old upload: the corner soup through embreex's own TriangleMesh."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(embree_upload, "upload", lambda *args: False)
        accel = Accel(_Soup(triangles))
    assert accel.upload == "embreex"
    return accel


def test_direct_upload_gives_the_corner_soups_hits(triangles, soup_accel):
    new = Accel(triangles)
    if sys.platform.startswith("linux"):   # where embreex wheels put libembree4
        assert new.upload == "direct", embree_upload.unavailable_reason()
    _assert_same_hits(new, soup_accel, _rays(triangles))


def test_embreex_fallback_gives_the_same_hits(triangles, soup_accel, monkeypatch):
    monkeypatch.setattr(embree_upload, "upload", lambda *args: False)
    new = Accel(triangles)
    assert new.upload == "embreex"
    _assert_same_hits(new, soup_accel, _rays(triangles, n=5000, seed=8))


def test_scene_handle_refuses_a_foreign_device():
    """The layout checks hold for the scene's own device and refuse
    another: a wrong guess never reaches Embree."""
    _, rs = accel_module._import_embreex()
    from embreex import rtcore
    device, other = rtcore.EmbreeDevice(), rtcore.EmbreeDevice()
    scene = rs.EmbreeScene(device)
    lib = embree_upload._library()
    if lib is None:
        pytest.fail(f"no libembree4 to check against: {embree_upload.unavailable_reason()}")
    assert embree_upload.scene_handle(scene, device, lib) is not None
    assert embree_upload.scene_handle(scene, other, lib) is None
    assert scene.is_committed == 0  # the probe put the field back


def test_persistent_bvh_is_reused_only_for_the_same_triangles(scene, triangles):
    """Persistent Data: a BuiltScenes hands the last BVH to an Accel of the
    same triangles (hits unchanged), and builds anew when any vertex moved."""
    cache = accel_module.BuiltScenes()
    first = Accel(triangles, reuse=cache)
    again = Accel(flatten(scene, with_instance=True), reuse=cache)
    assert (first.reused, again.reused, cache.builds, cache.hits) == (False, True, 1, 1)
    rng = np.random.default_rng(4)
    o = rng.uniform(-3, 3, (256, 3))
    d = -o / np.linalg.norm(o, axis=1, keepdims=True)
    tmax = np.full(len(o), np.inf)
    np.testing.assert_array_equal(first.intersect(o, d, tmax)[1], again.intersect(o, d, tmax)[1])
    nudged = [i.matrix.copy() for i in scene.instances]
    nudged[0][0, 3] += 1e-3
    moved = Scene(meshes=scene.meshes, materials=scene.materials,
                  instances=[Instance(i.mesh, m, materials=i.materials, visible_shadow=i.visible_shadow)
                             for i, m in zip(scene.instances, nudged)])
    rebuilt = Accel(flatten(moved, with_instance=True), reuse=cache)
    assert not rebuilt.reused and cache.builds == 2
    cache.clear()
    assert cache.entry is None
