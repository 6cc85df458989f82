"""Volume objects (OpenVDB grids) against Cycles (issue 21): a .vdb written
here with Blender's bundled openvdb module (tests/addon/volume_object_scenes.py:
a 24^3 ball whose density rises along x), loaded as a Volume object that is
moved, rotated and scaled non-uniformly, over a floor under a point light:
Ember against live Cycles (null scattering) by the image and region totals
and block by block (ember_testlib.ReferenceCheck, power printed).  The
density rising along x makes a mirrored axis, a wrong rotation or a shifted
grid show in the blocks; the scale checks Cycles' object-space density
(Volume > Render > Space 'Object': 1 / |M (1, 1, 1) / sqrt 3|).  Cycles'
defaults too: a Volume object without a material renders with its default
volume, and Generated coordinates are the object-space point (bpy 5.0;
from 5.2 normalised to the grids' leaf-node box).

Hostile Volume objects render finite pixels and name the object: NaN / inf
voxels, an empty grid, a missing file, a grid whose active box is 10^6
voxels wide (averaged over blocks, in bounded memory); a Geometry Nodes
Volume Cube (grids in memory only) is read through ``grids.save``.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import (ReferenceCheck, live_cycles_reference, render_array, render_for_reference,
                           setup_ember, small_resolution, empty_factory_scene)
import volume_object_scenes as scenes

WIDTH, HEIGHT = 64, 48
EMBER_SPP = 256
CYCLES_SEEDS, CYCLES_SPP = 4, 256
BLOCK = 8
POWER = (0.005, 0.02)    # asserted (issue 12's targets); measured: image 0.05%, median block 0.3% (Distance)


def _openvdb():
    from addon.export.volume_object import openvdb_module
    if openvdb_module() is None:
        pytest.skip("no openvdb module loads here (bpy 4.2 without Debian's python3-openvdb)")


# MULTIPLE_IMPORTANCE was a strict xfail (image +0.36 % +- 0.02 %, up to +10 % in blocks at the ball's lit
# edge) until direct-light points in textured media took the medium's g at the point, not the free
# flight's (0 where it did not scatter; tests/engine/test_media_equiangular_voxels.py): now image
# -0.004 % +- 0.014 % (t -0.27), max block |t| 2.45, image detects 0.07 %, median block 0.4 %.
@pytest.mark.parametrize("sampling", ['DISTANCE', 'MULTIPLE_IMPORTANCE'])
def test_vdb_volume_object_matches_cycles(sampling, tmp_path, tapped_engine):
    _openvdb()
    scene = empty_factory_scene()
    bounces = scenes.scene_vdb_smoke(scene, str(tmp_path), sampling)
    _assert_matches_live_cycles(f'vdb_volume_object_{sampling.lower()}', scene, bounces, tmp_path, tapped_engine)


def test_vdb_without_material_renders_the_default_volume(tmp_path, tapped_engine):
    """A Volume object with no material renders as Cycles' default volume
    (scene/shader.cpp add_default: a Principled Volume of Cycles' defaults,
    Density 1 x the 'density' grid; Multiple Importance sampling), not as
    nothing (Ember before: the ball missing, a warning)."""
    _openvdb()
    scene = empty_factory_scene()
    bounces = scenes.scene_vdb_default(scene, str(tmp_path))
    _assert_matches_live_cycles('vdb_default_volume', scene, bounces, tmp_path, tapped_engine)


def test_vdb_generated_coordinates_match_cycles(tmp_path, tapped_engine):
    """Generated coordinates inside a Volume object as this Blender's Cycles
    gives them (volume_object.generated_bounds: bpy 5.0, the object-space
    point; 5.2+, normalised to the grids' leaf-node box), not normalised to
    the active voxels' box (Ember before): a density of 12 gx gy on a ball
    off-centre in its leaf nodes (volume_object_scenes.GENERATED_OFFSET)."""
    _openvdb()
    scene = empty_factory_scene()
    bounces = scenes.scene_vdb_generated(scene, str(tmp_path))
    _assert_matches_live_cycles('vdb_generated', scene, bounces, tmp_path, tapped_engine)


def _assert_matches_live_cycles(name, scene, bounces, tmp_path, taps):
    """Ember against Cycles rendered now, image, regions and blocks (no
    warning about the Volume or a material)."""
    small_resolution(scene, WIDTH, HEIGHT)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, CYCLES_SPP, bounces)
    scene.render.engine = 'EMBER'
    image, var = render_for_reference(scene, tmp_path, name, taps, EMBER_SPP, 1, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings', ())
    assert not [w for w in warnings if 'Volume' in w or 'aterial' in w], warnings
    check = ReferenceCheck(name, image[..., :3].astype(np.float64), var, EMBER_SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(*POWER)


def _render_warnings(scene, tmp_path, name):
    small_resolution(scene, 16, 12)
    scene.render.engine = 'EMBER'
    setup_ember(scene, 4, 1, 4)
    image = render_array(scene, str(tmp_path), name)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert np.isfinite(image).all()
    return log.get('warnings', ())


def _hostile_scene(tmp_path, grids, name):
    scene = empty_factory_scene()
    scenes.scene_vdb_smoke(scene, str(tmp_path))
    bpy.data.objects.remove(bpy.data.objects['Smoke'])
    path = str(tmp_path / f"{name}.vdb")
    if grids is not None:
        scenes.write_vdb(path, grids)
    scenes.volume_object(path, scenes.smoke_material(), name=name)
    return scene


@pytest.mark.parametrize("case", ["nan_inf", "empty", "missing", "wide"])
def test_hostile_volume_objects_are_finite_and_named(case, tmp_path, needs_engine):
    _openvdb()
    ball = scenes.sphere_density()
    if case == "nan_inf":
        ball[10:12, 10:12, 10:12] = np.nan
        ball[5, 5, 5] = np.inf
        grids, words = {"density": ball}, ("infinite",)   # NaN voxels: openvdb keeps them inactive
    elif case == "empty":
        grids, words = {"density": np.zeros((4, 4, 4), np.float32)}, ("no active voxels",)
    elif case == "missing":
        grids, words = None, ("not rendered",)
    else:
        grids, words = None, ("averaged over blocks",)
    scene = _hostile_scene(tmp_path, grids, case)
    if case == "wide":
        _write_wide(str(tmp_path / "wide.vdb"))
    warnings = _render_warnings(scene, tmp_path, case)
    named = [w for w in warnings if f"'{case}'" in w]
    assert named and all(any(word in w for w in named) for word in words), warnings


def _write_wide(path):
    """Two dense 8^3 blobs 10^6 voxels apart (a 10^18-voxel box)."""
    from addon.export.volume_object import openvdb_module
    vdb = openvdb_module()
    grid = vdb.FloatGrid()
    grid.name = "density"
    blob = np.full((8, 8, 8), 2.0, np.float32)
    grid.copyFromArray(blob, ijk=(0, 0, 0))
    grid.copyFromArray(blob, ijk=(1000000, 1000000, 1000000))
    v = 1e-3   # 1 km wide (openvdb refuses a determinant much below 1e-9)
    grid.transform = vdb.createLinearTransform([[v, 0, 0, 0], [0, v, 0, 0], [0, 0, v, 0], [-500, -500, -500, 1]])
    vdb.write(path, grids=[grid])


def test_wide_grid_reads_in_bounded_memory(tmp_path, registered_addon):
    """The 10^6-voxel-wide grid becomes at most MAX_VOXELS voxels whose
    block means keep the blobs' total density (mass is conserved)."""
    _openvdb()
    from addon.export import volume_object
    path = str(tmp_path / "wide.vdb")
    _write_wide(path)
    data = bpy.data.volumes.new("wide")
    data.filepath = path
    obj = bpy.data.objects.new("wide", data)
    bpy.context.scene.collection.objects.link(obj)
    read = volume_object.read_volume(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    grid = read.arrays["density"]
    assert grid.size <= volume_object.MAX_VOXELS * 1.1 and np.isfinite(grid).all()
    step = round((1e6 + 8) / (grid.shape[0] - 2) + 0.5)
    assert any("averaged over blocks" in w for w in read.warnings), read.warnings
    total = float(grid.astype(np.float64).sum())
    assert total * step ** 3 == pytest.approx(2 * 512 * 2.0, rel=0.05), (total, step)


def test_empty_slots_use_the_default_volume(empty_scene, tmp_path):
    """A Volume object without materials, or with an empty slot, gets
    Cycles' default volume in each slot (one material for the scene); a
    mesh's empty slot stays the default surface (-1)."""
    _openvdb()
    from addon.export.material import DEFAULT_VOLUME, MaterialTable
    path = scenes.write_vdb(str(tmp_path / "bare.vdb"), {"density": scenes.sphere_density()})
    bare = scenes.volume_object(path, name="bare")
    slotted = scenes.volume_object(path, name="slotted")
    slotted.data.materials.append(None)
    slotted.data.materials.append(scenes.smoke_material())
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    cube.data.materials.append(None)
    table = MaterialTable()
    default = table.slots(bare)
    assert len(default) == 1 and table.materials[default[0]].name == DEFAULT_VOLUME
    assert table.slots(slotted)[0] == default[0] and table.slots(slotted)[1] not in (default[0], -1)
    assert table.slots(cube) == [-1]
    volume = table.materials[default[0]].volume
    assert volume.sampling == 'MULTIPLE_IMPORTANCE' and volume.anisotropy == 0.0


def test_generated_box_follows_the_blender_version(tmp_path, registered_addon):
    """The box a Volume object's Generated coordinates run 0..1 over
    (read_volume's ``generated``): before Blender 5.2 the unit box (Generated
    is the object-space point: measured in the Cycles of 4.2, 4.5, 5.0 and
    5.1); from 5.2 its bound_box, each grid's leaf-node box
    (evalLeafBoundingBox) grown by half a voxel in object space
    (BKE_volume_min_max), which for scene_vdb_generated's ball is
    24 x 24 x 16 voxels where its active voxels' box is 14^3."""
    _openvdb()
    from addon.export import volume_object
    n, offset = scenes.GENERATED_N, np.array(scenes.GENERATED_OFFSET)
    origin = tuple(float(v) for v in -0.5 - offset / n)
    path = scenes.write_vdb(str(tmp_path / "offset.vdb"), {"density": scenes.sphere_density(n)}, voxel=1.0 / n,
                            origin=origin, ijk=scenes.GENERATED_OFFSET)
    obj = scenes.volume_object(path, name="offset")
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    read = volume_object.read_volume(evaluated)
    grid = volume_object.openvdb_module().readAll(path)[0][0]
    lo, hi = (np.array(c, np.float64) for c in grid.evalLeafBoundingBox())
    leaf_box = (np.array(origin) + (lo - 0.5) / n, np.array(origin) + (hi + 0.5) / n)
    later = volume_object.generated_bounds(evaluated, read.bounds, volume_object.NORMALISED_GENERATED)
    assert np.allclose(np.array(later), np.array(leaf_box), atol=1e-6), (later, leaf_box)
    unit = volume_object.generated_bounds(evaluated, read.bounds, (5, 1, 0))
    assert np.allclose(np.array(unit), [[0, 0, 0], [1, 1, 1]]), unit
    now = leaf_box if bpy.app.version >= volume_object.NORMALISED_GENERATED else unit
    assert np.allclose(np.array(read.generated), np.array(now), atol=1e-6), (read.generated, now)
    assert tuple(hi - lo + 1) == (24, 24, 16), (lo, hi)
    first, last = (np.array(c) for c in grid.evalActiveVoxelBoundingBox())
    assert tuple(last - first + 1) == (14, 14, 14), (first, last)


def test_geometry_nodes_volume_cube_is_read(empty_scene):
    """A Geometry Nodes Volume Cube has its grid only in memory: it is
    written by grids.save and read back, inside the cube's bounds."""
    _openvdb()
    from addon.export import scene as scene_export
    me = bpy.data.meshes.new("gn")
    obj = bpy.data.objects.new("gn", me)
    empty_scene.collection.objects.link(obj)
    tree = bpy.data.node_groups.new("cube", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    out = tree.nodes.new('NodeGroupOutput')
    cube = tree.nodes.new('GeometryNodeVolumeCube')
    paint = tree.nodes.new('GeometryNodeSetMaterial')
    paint.inputs['Material'].default_value = scenes.smoke_material()
    tree.links.new(cube.outputs[0], paint.inputs['Geometry'])
    tree.links.new(paint.outputs[0], out.inputs[0])
    obj.modifiers.new("gn", 'NODES').node_group = tree
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    volumes = [inst for inst in exported.scene.instances if inst.voxel_placements]
    assert len(volumes) == 1, exported.warnings
    density = volumes[0].voxels['density']
    assert density.max() == pytest.approx(1.0) and density.min() == 0.0   # the padding
    box = exported.scene.meshes[volumes[0].mesh].positions
    assert np.allclose(box.min(axis=0), -1.0, atol=0.1) and np.allclose(box.max(axis=0), 1.0, atol=0.1)


def test_frame_sequence_follows_the_scene_frame(tmp_path, registered_addon):
    """A .vdb sequence (name_0001.vdb, name_0002.vdb) reads the file of the
    scene's frame (grids.frame_filepath)."""
    _openvdb()
    from addon.export import volume_object
    for frame in (1, 2):
        scenes.write_vdb(str(tmp_path / f"seq_{frame:04d}.vdb"), {"density": scenes.sphere_density() * frame})
    data = bpy.data.volumes.new("seq")
    data.filepath = str(tmp_path / "seq_0001.vdb")
    data.is_sequence, data.frame_start, data.frame_duration = True, 1, 2
    obj = bpy.data.objects.new("seq", data)
    bpy.context.scene.collection.objects.link(obj)
    peaks = []
    for frame in (1, 2):
        bpy.context.scene.frame_set(frame)
        read = volume_object.read_volume(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()))
        peaks.append(float(read.arrays["density"].max()))
    assert peaks[1] == pytest.approx(2 * peaks[0], rel=1e-6) and peaks[0] > 1.0, peaks
