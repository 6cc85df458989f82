"""Camera framing: Ember's pixels land exactly where Cycles' do.

The scene is a wall of emissive tiles, each its own colour, under a black
world: a pixel's value names the tile seen through its centre.  Both
renderers use a 0.01-pixel box filter, so every sample goes through the pixel
centre; a pixel where all samples saw one tile is "pure".  Every pixel that is
pure in both images must be identical: one pixel of offset, a flipped axis, a
wrong sensor fit, shift, pixel aspect or border shows up as a mismatch.
"""
import math

import bpy
import numpy as np
import pytest

from ember_testlib import render_array, setup_cycles, setup_ember

SPP = 8


def tile_wall(scene, columns=10, rows=8, size=2.0, depth=-10.0):
    """Emissive tiles (with black gaps) in the plane z = depth, facing +Z."""
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    scene.world = None
    for row in range(rows):
        for column in range(columns):
            x0 = (column - columns / 2) * size
            y0 = (row - rows / 2) * size
            inset = 0.1 * size
            verts = [(x0 + inset, y0 + inset, depth), (x0 + size - inset, y0 + inset, depth),
                     (x0 + size - inset, y0 + size - inset, depth), (x0 + inset, y0 + size - inset, depth)]
            mesh = bpy.data.meshes.new(f"Tile{row}_{column}")
            mesh.from_pydata(verts, [], [(0, 1, 2, 3)])
            material = bpy.data.materials.new(f"Tile{row}_{column}")
            material.use_nodes = True
            tree = material.node_tree
            tree.nodes.clear()
            emission = tree.nodes.new('ShaderNodeEmission')
            color = ((column + 1) / columns, (row + 1) / rows, 0.25 + 0.5 * ((row + column) % 2))
            emission.inputs['Color'].default_value = (*color, 1.0)
            out = tree.nodes.new('ShaderNodeOutputMaterial')
            tree.links.new(emission.outputs[0], out.inputs['Surface'])
            mesh.materials.append(material)
            scene.collection.objects.link(bpy.data.objects.new(mesh.name, mesh))


def configure(scene, case):
    render = scene.render
    cam = scene.camera
    cam.location = (0.0, 0.0, 0.0)
    cam.rotation_euler = (0.0, 0.0, 0.0)
    data = cam.data
    data.type, data.lens, data.sensor_fit = 'PERSP', 50.0, 'AUTO'
    data.sensor_width, data.sensor_height = 36.0, 24.0
    data.shift_x = data.shift_y = 0.0
    data.clip_start, data.clip_end = 0.1, 100.0
    data.dof.use_dof = False
    render.resolution_x, render.resolution_y, render.resolution_percentage = 48, 32, 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.use_border = False
    render.film_transparent = False
    for key, value in case.items():
        target, attr = key.split('.', 1)
        obj = {'render': render, 'cam': data, 'obj': cam}[target]
        setattr(obj, attr, value)


CASES = {
    'landscape_auto': {},
    'portrait_auto': {'render.resolution_x': 32, 'render.resolution_y': 48},
    'horizontal_fit_portrait': {'render.resolution_x': 32, 'render.resolution_y': 48,
                                'cam.sensor_fit': 'HORIZONTAL', 'cam.sensor_width': 30.0},
    'vertical_fit_landscape': {'cam.sensor_fit': 'VERTICAL', 'cam.sensor_height': 20.0},
    'shift': {'cam.shift_x': 0.2, 'cam.shift_y': -0.1},
    'pixel_aspect_x2': {'render.pixel_aspect_x': 2.0},
    'pixel_aspect_y2_portrait': {'render.resolution_x': 32, 'render.resolution_y': 48,
                                 'render.pixel_aspect_y': 2.0},
    'percentage': {'render.resolution_x': 96, 'render.resolution_y': 64, 'render.resolution_percentage': 50},
    'border_crop': {'render.use_border': True, 'render.use_crop_to_border': True,
                    'render.border_min_x': 0.2, 'render.border_max_x': 0.7,
                    'render.border_min_y': 0.3, 'render.border_max_y': 0.9},
    'border_no_crop': {'render.use_border': True, 'render.use_crop_to_border': False,
                       'render.border_min_x': 0.13, 'render.border_max_x': 0.61,
                       'render.border_min_y': 0.05, 'render.border_max_y': 0.55},
    'ortho_shift': {'cam.type': 'ORTHO', 'cam.ortho_scale': 9.0, 'cam.shift_x': -0.15},
    'rolled_camera': {'obj.rotation_euler': (0.05, -0.08, math.radians(25)), 'obj.location': (0.7, -0.4, 1.0)},
}


def pure_mask(image, spp):
    """Pixels whose every sample saw the same thing (value is a tile colour or 0).

    A mixed pixel of two colours is an average; detecting purity from the value
    alone is done by comparing with the palette of tile colours.
    """
    palette = np.array([[0.0, 0.0, 0.0]] + [
        [(c + 1) / 10, (r + 1) / 8, 0.25 + 0.5 * ((r + c) % 2)] for r in range(8) for c in range(10)])
    distance = np.abs(image[..., None, :3] - palette[None, None]).max(axis=-1)
    return distance.min(axis=-1) < 1e-4


@pytest.mark.parametrize("case", sorted(CASES))
def test_framing_matches_cycles(case, factory_scene, tmp_path, needs_engine):
    scene = factory_scene
    tile_wall(scene)
    configure(scene, CASES[case])
    setup_cycles(scene, SPP, 0, 1, filter_type='BLACKMAN_HARRIS', filter_width=0.01)
    cycles = render_array(scene, tmp_path, "cycles")
    setup_ember(scene, SPP, 0, 1, filter_type='BLACKMAN_HARRIS', filter_width=0.01)
    ember = render_array(scene, tmp_path, "ember")
    assert ember.shape == cycles.shape
    both = pure_mask(ember, SPP) & pure_mask(cycles, SPP)
    assert both.mean() > 0.98, f"too few pure pixels ({both.mean():.2f}): images disagree or are noisy"
    mismatch = both & (np.abs(ember[..., :3] - cycles[..., :3]).max(axis=-1) > 1e-4)
    assert not mismatch.any(), f"{mismatch.sum()} pixels differ, first at (row, col) {np.argwhere(mismatch)[:5].tolist()}"
