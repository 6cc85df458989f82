"""Blender's dupli random_id reproduced (addon/export/dupli_random.py) and
the bulk read of geometry-nodes instancers (addon/export/bulk_instances.py)
against ``depsgraph.object_instances``, instance by instance (issue 25)."""
import bpy
import numpy as np
import pytest

from addon.export import bulk_instances, dupli_random
from addon.export import scene as scene_export
import dupli_scenes


def _kind(inst):
    """What made a copy: the top-level instancer's kind, and whether it is nested."""
    parent = inst.parent
    levels = sum(1 for v in inst.persistent_id if v != dupli_random.UNUSED_LEVEL)
    nested = levels > (2 if parent.modifiers or parent.particle_systems else 1)
    if parent.particle_systems:
        kind = 'particles'
    elif parent.modifiers:
        kind = 'geometry nodes'
    elif parent.instance_type == 'COLLECTION':
        kind = 'collection'
    else:
        kind = 'vertices'
    return kind + (' nested' if nested else '')


def test_random_id_bit_exact_for_every_kind_of_instance(factory_scene):
    dupli_scenes.every_kind()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    seen, wrong = {}, []
    for inst in depsgraph.object_instances:
        if not inst.is_instance:
            continue
        obj, parent = inst.object, inst.parent
        root = None if obj.original == parent.original else parent.name
        got = int(dupli_random.random_ids(obj.name, [tuple(inst.persistent_id)], root)[0])
        kind = _kind(inst)
        seen[kind] = seen.get(kind, 0) + 1
        if got != int(inst.random_id) & 0xFFFFFFFF:
            wrong.append((kind, parent.name, obj.name, tuple(inst.persistent_id)))
    print(seen)
    # (particles of a collection pick one object each: no nesting below them)
    for kind in ('geometry nodes', 'geometry nodes nested', 'collection', 'collection nested', 'particles',
                 'vertices'):
        assert seen.get(kind, 0) > 0, kind
    assert not wrong, wrong[:5]


def test_hash_string_of_non_ascii_names():
    # Blender hashes the UTF-8 bytes as unsigned (checked above on 'Stöne').
    assert dupli_random.hash_string('') == 0
    assert dupli_random.hash_string('A') == 65
    assert dupli_random.hash_string('é') == (0xC3 * 37 + 0xA9)


@pytest.mark.parametrize('name, distribute', [('GNGrid', False), ('GNIds', True)])
def test_plan_matches_the_walk(factory_scene, monkeypatch, name, distribute):
    monkeypatch.setattr(bulk_instances, 'BULK_MIN', 1)
    dupli_scenes.gn_instancer(name, 'grid', side=6, distribute=distribute, rotate=True)
    host = bpy.data.objects[name]
    host.location, host.scale = (0.3, -0.2, 0.1), (1.0, 2.0, 0.5)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    plan = bulk_instances.plan(host.evaluated_get(depsgraph))
    walk = [(tuple(i.persistent_id), int(i.random_id) & 0xFFFFFFFF, np.array(i.matrix_world))
            for i in depsgraph.object_instances if i.is_instance and i.parent.name == name]
    assert plan is not None and len(plan) == len(walk) > 8
    assert [w[0] for w in walk] == [tuple(int(v) for v in row) for row in plan.persistent]
    assert np.array_equal([w[1] for w in walk], plan.random_id)
    assert np.allclose(np.stack([w[2] for w in walk]), plan.matrix, atol=1e-6)


def _export(bulk, monkeypatch):
    monkeypatch.setattr(bulk_instances, 'BULK_MIN', 1 if bulk else 10 ** 12)
    return scene_export.export_scene(bpy.context.evaluated_depsgraph_get())


def _columns(exported):
    from engine import instance_columns
    cols = instance_columns.columns(exported.scene.instances)
    names = [i.name for i in exported.scene.instances]
    return cols, names


def _assert_same_export(a, b):
    (ca, na), (cb, nb) = _columns(a), _columns(b)
    assert na == nb and len(ca) == len(cb)
    for field in ('mesh', 'color', 'pass_index', 'random', 'holdout', 'shadow_catcher', 'moving', 'visibility'):
        assert np.array_equal(getattr(ca, field), getattr(cb, field)), field
    assert [ca.slot_sets[k] for k in ca.slot_set] == [cb.slot_sets[k] for k in cb.slot_set]
    assert np.allclose(ca.matrix, cb.matrix, rtol=0, atol=1e-6)
    assert [m.name for m in a.scene.meshes] == [m.name for m in b.scene.meshes]
    assert sorted(a.warnings) == sorted(b.warnings)
    assert a.triangles == b.triangles


def test_bulk_export_equals_the_walk(factory_scene, monkeypatch):
    """Every kind of instance in one scene: the geometry-nodes grids read in
    bulk, everything else walked; the exported arrays are the walk's."""
    dupli_scenes.every_kind()
    bulk, walked = _export(True, monkeypatch), _export(False, monkeypatch)
    from engine import InstanceBatch
    assert isinstance(bulk.scene.instances, InstanceBatch) and not isinstance(walked.scene.instances, InstanceBatch)
    _assert_same_export(bulk, walked)


def test_mismatch_falls_back_to_the_walk(factory_scene, monkeypatch, capsys):
    dupli_scenes.gn_instancer('GNGrid', 'grid', side=5)
    walked = _export(False, monkeypatch)
    real = dupli_random.random_ids
    monkeypatch.setattr(dupli_random, 'random_ids', lambda *a, **k: real(*a, **k) ^ np.uint32(1))
    fallback = _export(True, monkeypatch)
    assert 'read one by one' in capsys.readouterr().out
    _assert_same_export(fallback, walked)


def test_attribute_nodes_walk_their_copies(factory_scene, monkeypatch):
    """A material reading an Instancer attribute has per-copy values: those
    copies go through the walk, with the same result."""
    host = dupli_scenes.gn_instancer('GNGrid', 'grid', side=4)
    mat = bpy.data.materials.new('ReadsAttr')
    mat.use_nodes = True
    attr = mat.node_tree.nodes.new('ShaderNodeAttribute')
    attr.attribute_type, attr.attribute_name = 'INSTANCER', 'pass_index'
    bsdf = mat.node_tree.nodes['Principled BSDF']
    mat.node_tree.links.new(attr.outputs['Color'], bsdf.inputs['Base Color'])
    host.data.materials.append(mat)
    bulk, walked = _export(True, monkeypatch), _export(False, monkeypatch)
    _assert_same_export(bulk, walked)


def test_hostile_nan_and_zero_instances(factory_scene, monkeypatch):
    """NaN instance transforms are left out with a warning naming the
    object; an instancer with no instances exports nothing."""
    host = dupli_scenes.gn_instancer('GNNaN', 'grid', side=4)
    tree = host.modifiers[0].node_group
    scale = tree.nodes.new('GeometryNodeScaleInstances')
    place = next(n for n in tree.nodes if n.bl_idname == 'GeometryNodeInstanceOnPoints')
    out = next(n for n in tree.nodes if n.bl_idname == 'NodeGroupOutput')
    index = tree.nodes.new('GeometryNodeInputIndex')
    compare = tree.nodes.new('FunctionNodeCompare')
    compare.data_type, compare.operation = 'INT', 'EQUAL'
    compare.inputs[3].default_value = 5
    tree.links.new(index.outputs[0], compare.inputs[2])
    tree.links.new(place.outputs[0], scale.inputs['Instances'])
    tree.links.new(compare.outputs[0], scale.inputs['Selection'])
    scale.inputs['Scale'].default_value = (float('nan'),) * 3
    tree.links.new(scale.outputs[0], out.inputs[0])
    empty = dupli_scenes.gn_instancer('GNEmpty', 'grid', side=4)
    empty_grid = next(n for n in empty.modifiers[0].node_group.nodes if n.bl_idname == 'GeometryNodeMeshGrid')
    empty_grid.inputs['Vertices X'].default_value = 0
    bulk, walked = _export(True, monkeypatch), _export(False, monkeypatch)
    from engine import InstanceBatch
    assert isinstance(bulk.scene.instances, InstanceBatch)
    _assert_same_export(bulk, walked)
    names = [i.name for i in bulk.scene.instances]
    assert names.count('GNNaN') == 15 and 'GNEmpty' not in names
    assert any("'GNNaN'" in w and 'NaN' in w for w in bulk.warnings)


def test_bulk_scene_renders_the_walks_image(factory_scene, monkeypatch, needs_engine):
    """Both exports of one geometry-nodes scene rendered by the engine with
    one seed, Cryptomatte object names included: the same image (matrices
    agree to float32 rounding, so a pixel may differ where a ray grazes an
    edge; none does here)."""
    import dataclasses
    from addon import backend
    dupli_scenes.gn_instancer('GNGrid', 'grid', side=20, rotate=True)
    factory_scene.render.resolution_x, factory_scene.render.resolution_y = 32, 24
    bulk, walked = _export(True, monkeypatch), _export(False, monkeypatch)
    settings = dataclasses.replace(scene_export.render_settings(factory_scene), samples=2, threads=1,
                                   passes=('CryptoObject',))
    renderer = backend.engine()
    a, b = renderer.render(bulk.scene, settings), renderer.render(walked.scene, settings)
    np.testing.assert_allclose(a.image, b.image, atol=1e-5)
    assert a.passes and set(a.passes) == set(b.passes) and a.pass_metadata == b.pass_metadata
    for name in a.passes:
        np.testing.assert_allclose(a.passes[name], b.passes[name], atol=1e-5, err_msg=name)
