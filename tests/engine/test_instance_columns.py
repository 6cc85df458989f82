"""engine.instance_columns: the instances read once as arrays, and the
stages that use them (flatten, validation, the shading context) giving
what each instance says, one by one."""
import numpy as np
import pytest

from engine import instance_columns
from engine.geometry import VIS_ALL, flatten, visibility_bits
from engine.nodes import SceneShading
from engine.scene import Instance, Mesh, Scene, SceneError
from engine.testscenes import box, quad
from engine.validate import validate_instances


def _meshes():
    two_slots = box()
    two_slots.material_slots = np.arange(len(two_slots.triangles)) % 2
    flat = quad([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    return [two_slots, flat, empty]


def _instances(rng, count):
    """Instances of the three meshes in a shuffled order, with varied
    slots, visibility, colours and Object Info."""
    out = []
    slot_choices = [(0, 1), (1,), (), (2, -1), (5,)]
    for k in range(count):
        m = np.eye(4)
        m[:3, :3] = rng.normal(size=(3, 3)) + 3 * np.eye(3)
        m[:3, 3] = rng.uniform(-5, 5, 3)
        out.append(Instance(mesh=int(rng.integers(0, 3)), matrix=m,
                            materials=slot_choices[k % len(slot_choices)], name=f"i{k}",
                            visible_camera=bool(k % 3), visible_shadow=bool(k % 4), holdout=k % 7 == 0,
                            shadow_catcher=k % 5 == 0, color=(k / count, 0.5, 1.0), pass_index=k % 9,
                            random=float(rng.uniform())))
    return out


def test_columns_hold_each_instances_fields():
    rng = np.random.default_rng(3)
    insts = _instances(rng, 200)
    cols = instance_columns.read(insts)
    assert len(cols) == 200
    for k, inst in enumerate(insts):
        assert cols.mesh[k] == inst.mesh
        np.testing.assert_array_equal(cols.matrix[k], inst.matrix)
        assert cols.slot_sets[cols.slot_set[k]] == tuple(inst.materials)
        assert cols.visibility[k] == visibility_bits(inst)
        np.testing.assert_array_equal(cols.color[k], inst.color)
        assert (cols.pass_index[k], cols.random[k]) == (inst.pass_index, inst.random)
        assert (cols.holdout[k], cols.shadow_catcher[k], cols.moving[k]) == (inst.holdout, inst.shadow_catcher,
                                                                              False)


def test_columns_of_duck_typed_and_hostile_rows():
    class Row:
        mesh, matrix, materials = 0, np.eye(4), (0,)
    hostile = Instance(mesh=0, color="red", pass_index=None, random="x")
    cols = instance_columns.read([Row(), hostile])
    assert cols.visibility.tolist() == [VIS_ALL, VIS_ALL]
    np.testing.assert_array_equal(cols.color, np.ones((2, 3)))   # Instance's default for a colour it cannot read
    assert cols.pass_index.tolist() == [0.0, 0.0] and cols.random.tolist() == [0.0, 0.0]
    assert instance_columns.read([Instance(mesh=0, matrix=np.eye(3))]).matrix is None


def test_flatten_places_every_instance_as_it_says():
    """Rows in instance order; each triangle its own instance's transform,
    slot material (the default past the table) and visibility bits."""
    rng = np.random.default_rng(5)
    meshes, insts = _meshes(), _instances(rng, 150)
    scene = Scene(meshes=meshes, instances=insts, materials=[object()] * 3)
    tris = flatten(scene, with_instance=True)
    owner = tris.instance
    assert np.all(np.diff(owner) >= 0)
    expected_rows = sum(len(meshes[i.mesh].triangles) for i in insts)
    assert len(tris) == expected_rows
    default = 3
    for k in np.unique(owner):
        inst, mesh = insts[k], meshes[insts[k].mesh]
        rows = np.flatnonzero(owner == k)
        world = mesh.positions @ inst.matrix[:3, :3].T + inst.matrix[:3, 3]
        np.testing.assert_allclose(tris.p0[rows], world[mesh.triangles[:, 0]], atol=1e-12)
        slots = mesh.material_slots if mesh.material_slots is not None else np.zeros(len(mesh.triangles), int)
        table = [m if 0 <= m < 3 else default for m in inst.materials] + [default]
        want = [table[min(s, len(table) - 1)] for s in slots]
        assert tris.material[rows].tolist() == want
        bits = visibility_bits(inst)
        assert np.all((tris.visibility[rows] if tris.visibility is not None else VIS_ALL) == bits)


def test_shading_context_reads_the_columns():
    rng = np.random.default_rng(7)
    insts = _instances(rng, 80)
    scene = Scene(meshes=_meshes(), instances=insts, materials=[object()] * 3)
    shading = SceneShading(scene, np.zeros(0, np.int32), np.zeros(0, np.int32))
    np.testing.assert_array_equal(shading.matrix, np.array([i.matrix for i in insts]))
    np.testing.assert_allclose(shading.inverse[5] @ insts[5].matrix, np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(shading.random, [i.random for i in insts])
    np.testing.assert_array_equal(shading.color, [i.color for i in insts])


def test_validation_names_the_first_bad_instance_among_many():
    rng = np.random.default_rng(9)
    for field, value, message in (("matrix", np.full((4, 4), np.nan), "instance 71"),
                                  ("mesh", 7, "instance 71"), ("materials", (0, 9), "instance 71")):
        insts = _instances(rng, 100)
        for inst in insts:
            inst.materials = (0,)
        setattr(insts[71], field, value)
        setattr(insts[90], field, value)
        with pytest.raises(SceneError, match=message):
            validate_instances(insts, 3, 3)


def test_one_read_per_list_within_a_preparation(monkeypatch):
    insts = _instances(np.random.default_rng(1), 10)
    calls = []
    real = instance_columns.read
    monkeypatch.setattr(instance_columns, "read", lambda items: calls.append(1) or real(items))
    with instance_columns.prepared():
        first = instance_columns.columns(insts)
        assert instance_columns.columns(insts) is first
        instance_columns.columns(list(insts))   # another list: read on its own
    instance_columns.columns(insts)             # outside: read afresh
    assert len(calls) == 3
