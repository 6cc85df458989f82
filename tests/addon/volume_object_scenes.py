"""Volume objects for the tests (issue 21): .vdb files written with the
openvdb module Blender bundles, loaded as Volume objects."""
import os

import bpy
import numpy as np

from test_volume_parity import _camera, _floor, _material, _volume_settings, _world

N = 24


def sphere_density(n=N):
    """(X, Y, Z) float32: a ball of radius 0.45 n whose density rises
    along x (so a half-voxel shift or a mirrored axis shows), 0 outside."""
    c = (np.arange(n) + 0.5) / n - 0.5
    x, y, z = np.meshgrid(c, c, c, indexing='ij')
    r = np.sqrt(x * x + y * y + z * z)
    return np.where(r < 0.45, (0.4 + 1.6 * (x + 0.5)) * (1.0 - (r / 0.45) ** 2), 0.0).astype(np.float32)


def write_vdb(path, grids, voxel=1.0 / N, origin=(-0.5, -0.5, -0.5), ijk=(0, 0, 0)):
    """Write {name: (X, Y, Z) or (X, Y, Z, 3) array} as grids of one file
    with the index-to-object transform voxel size ``voxel`` at ``origin``,
    each array's first element at index ``ijk``."""
    from addon.export.volume_object import openvdb_module
    vdb = openvdb_module()
    out = []
    for name, array in grids.items():
        grid = vdb.Vec3SGrid() if array.ndim == 4 else vdb.FloatGrid()
        grid.copyFromArray(np.ascontiguousarray(array, np.float32), ijk=tuple(ijk), tolerance=0.0)
        grid.name = name
        m = [[voxel, 0, 0, 0], [0, voxel, 0, 0], [0, 0, voxel, 0], [origin[0], origin[1], origin[2], 1]]
        grid.transform = vdb.createLinearTransform(m)
        out.append(grid)
    vdb.write(path, grids=out)
    return path


def volume_object(path, material=None, name="Smoke"):
    data = bpy.data.volumes.new(name)
    data.filepath = path
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    if material is not None:
        data.materials.append(material)
    return obj


def smoke_material(density=6.0):
    def volume(tree):
        node = tree.nodes.new('ShaderNodeVolumePrincipled')
        node.inputs['Color'].default_value = (0.85, 0.7, 0.55, 1.0)
        node.inputs['Density'].default_value = density
        node.inputs['Anisotropy'].default_value = 0.3
        return node.outputs[0]
    return _material("VDBSmoke", volume=volume)


def scene_vdb_smoke(scene, folder, sampling=None):
    """A rotated, scaled, moved VDB ball of rising density over a floor
    under a point light and a grey world (``sampling``: the material's
    Volume > Sampling, default Multiple Importance)."""
    material = smoke_material()
    if sampling is not None:
        material.cycles.volume_sampling = sampling
    path = write_vdb(os.path.join(folder, "ball.vdb"), {"density": sphere_density()})
    return _vdb_scene(scene, path, material)


def scene_vdb_default(scene, folder):
    """scene_vdb_smoke's ball with no material: Cycles renders it with its
    default volume (a Principled Volume of Cycles' defaults reading the
    'density' grid, Multiple Importance sampling)."""
    path = write_vdb(os.path.join(folder, "ball.vdb"), {"density": sphere_density()})
    return _vdb_scene(scene, path, None)


# The ball of scene_vdb_generated: 16 voxels wide from index OFFSET, so its
# active voxels (1..14 of them: 3..16, 11..24, 1..14) sit off-centre in its
# leaf nodes' box (8^3-voxel blocks: 0..23, 8..31, 0..15) along x and y.
# Blender 5.2's Cycles normalises Generated to that box (0.15..0.69 in x
# over the active voxels), bpy 5.0's gives the object-space point (-0.4..0.4
# in x), Ember before issue 21's fix normalised it to the active voxels' box
# padded by a voxel (0.09..0.91).
GENERATED_N, GENERATED_OFFSET = 16, (2, 10, 0)


def generated_material():
    """Principled Volume (Distance sampling) whose Density is 12 gx gy of
    the Generated coordinates (gx, gy), times the 'density' grid."""
    def volume(tree):
        coords = tree.nodes.new('ShaderNodeTexCoord')
        split = tree.nodes.new('ShaderNodeSeparateXYZ')
        tree.links.new(coords.outputs['Generated'], split.inputs[0])
        product = _math(tree, 'MULTIPLY', split.outputs['X'], split.outputs['Y'])
        density = _math(tree, 'MULTIPLY', product, 12.0)
        node = tree.nodes.new('ShaderNodeVolumePrincipled')
        node.inputs['Color'].default_value = (0.85, 0.7, 0.55, 1.0)
        node.inputs['Anisotropy'].default_value = 0.3
        tree.links.new(density, node.inputs['Density'])
        return node.outputs[0]
    material = _material("VDBGenerated", volume=volume)
    material.cycles.volume_sampling = 'DISTANCE'
    return material


def _math(tree, operation, a, b):
    node = tree.nodes.new('ShaderNodeMath')
    node.operation = operation
    for socket, value in zip(node.inputs, (a, b)):
        if isinstance(value, float):
            socket.default_value = value
        else:
            tree.links.new(value, socket)
    return node.outputs[0]


def scene_vdb_generated(scene, folder):
    """scene_vdb_smoke's set-up with the ball of GENERATED_N voxels at index
    GENERATED_OFFSET (centred in object space as before) and
    generated_material, whose density shows where Generated coordinates
    run 0..1 (addon/export/volume_object.py generated_bounds)."""
    n, offset = GENERATED_N, np.array(GENERATED_OFFSET)
    origin = tuple(float(v) for v in -0.5 - offset / n)
    path = write_vdb(os.path.join(folder, "offset_ball.vdb"), {"density": sphere_density(n)}, voxel=1.0 / n,
                     origin=origin, ijk=GENERATED_OFFSET)
    return _vdb_scene(scene, path, generated_material())


def _vdb_scene(scene, path, material):
    _floor((0.6, 0.6, 0.6))
    obj = volume_object(path, material)
    obj.location = (0.1, 0.0, 1.2)
    obj.rotation_euler = (0.3, 0.0, 0.9)
    obj.scale = (2.2, 1.6, 2.0)
    light = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT'))
    light.data.energy, light.data.shadow_soft_size = 500.0, 0.5
    light.location = (-1.5, -1.0, 3.2)
    scene.collection.objects.link(light)
    _world(scene, (0.25, 0.28, 0.32))
    _camera(scene, (0.0, -5.5, 2.0), (0.0, 0.0, 1.1))
    _volume_settings(scene)
    return 4
