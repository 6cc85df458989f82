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


def write_vdb(path, grids, voxel=1.0 / N, origin=(-0.5, -0.5, -0.5)):
    """Write {name: (X, Y, Z) or (X, Y, Z, 3) array} as grids of one file
    with the index-to-object transform voxel size ``voxel`` at ``origin``."""
    from addon.export.volume_object import openvdb_module
    vdb = openvdb_module()
    out = []
    for name, array in grids.items():
        grid = vdb.Vec3SGrid() if array.ndim == 4 else vdb.FloatGrid()
        grid.copyFromArray(np.ascontiguousarray(array, np.float32), ijk=(0, 0, 0), tolerance=0.0)
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
    _floor((0.6, 0.6, 0.6))
    path = write_vdb(os.path.join(folder, "ball.vdb"), {"density": sphere_density()})
    material = smoke_material()
    if sampling is not None:
        material.cycles.volume_sampling = sampling
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
