"""Cycles parity of the Light Path node on emitters (engine/nodes/input_nodes.py
light_path; the integrator tracks ray kinds and depths when a material reads
the node: Context.light_path).  Lamps over a diffuse floor and beside a
glossy sphere, each lamp's strength gated by one output.

Cycles evaluates a light sample's emission with PATH_RAY_EMISSION: 'Is ...
Ray' outputs read 0 there, so a lamp gated by Is Diffuse Ray lights only
through BSDF hits, MIS-weighted against light samples that bring nothing;
its image then depends on the light-selection probability, which Ember
computes its own way.  So such a lamp is tested alone (probability 1 in
both engines): scene 'diffuse'.  Scene 'consistent' holds the outputs that
read alike in light samples and BSDF hits: Is Camera Ray (seen, lighting
nothing), Is Shadow Ray (0 everywhere), Ray Depth (a light sample reads
one bounce further, as Cycles) and Transparent Depth (behind a transparent
pane: light samples read the path's passes).  Before Ember tracked them, an 'Is Camera Ray' lamp lit
the floor 30x too bright and an 'Is Diffuse Ray' lamp crashed the MIS
weight.  Cycles is rendered here (8 seeds); Ember against it by the suite's
region and block tests, power printed."""
import bpy
import numpy as np
import pytest

from parity_scenes import empty_material, material, mesh_object, plane
from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)

SIZE = (48, 32)
BLOCK = 8
BOUNCES = 3
EMBER_SPP = 512
# consistent: 512 resolved 3.44 % of the image, not 3 % (the channel sum's variance)
SAMPLES = {'consistent': 1024}
CYCLES_SEEDS, CYCLES_SPP = 8, 128
SCENES = {'consistent': ('Is Camera Ray', 'Is Shadow Ray', 'Ray Depth', 'Transparent Depth'),
          'diffuse': ('Is Diffuse Ray',)}


def gated_lamp(name, output, location, strength=20.0):
    mat, nt, out = empty_material(name)
    emission = nt.nodes.new('ShaderNodeEmission')
    gain = nt.nodes.new('ShaderNodeMath')
    gain.operation = 'MULTIPLY'
    gain.inputs[1].default_value = strength
    nt.links.new(nt.nodes.new('ShaderNodeLightPath').outputs[output], gain.inputs[0])
    nt.links.new(gain.outputs[0], emission.inputs['Strength'])
    nt.links.new(emission.outputs[0], out.inputs['Surface'])
    x, y, z = location
    h = 0.3
    return mesh_object(name, [(x - h, y - h, z), (x + h, y - h, z), (x + h, y + h, z), (x - h, y + h, z)],
                       [(0, 3, 2, 1)], mat)


def transparent_pane(location):
    mat = bpy.data.materials.new('pane')
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    node = nt.nodes.new('ShaderNodeBsdfTransparent')
    nt.links.new(node.outputs[0], nt.nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    x, y, z = location
    return mesh_object('pane', [(x - 0.5, y, z - 0.5), (x + 0.5, y, z - 0.5), (x + 0.5, y, z + 0.5),
                                (x - 0.5, y, z + 0.5)], [(0, 1, 2, 3)], mat)


def scene_of_lamps(scene, outputs):
    plane('floor', material('floor', 'diffuse', (0.7, 0.7, 0.7)), half=4.0)
    for k, output in enumerate(outputs):
        gated_lamp(f"lamp {output}", output, (-1.0 + k if len(outputs) > 1 else 0.0, 0.6, 0.9))
    transparent_pane((2.0, 0.2, 0.9))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(0.0, -0.4, 0.45), segments=32, ring_count=16)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.data.materials.append(material('mirror', 'glossy', (0.9, 0.9, 0.9), roughness=0.05))
    background = scene.world.node_tree.nodes.get('Background')
    if background is not None:
        background.inputs['Color'].default_value = (0.02, 0.02, 0.02, 1.0)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, -5.0, 2.2), (np.radians(70.0), 0.0, 0.0)
    cam.data.lens = 32.0
    small_resolution(scene, *SIZE)


@pytest.mark.parametrize('name', sorted(SCENES))
def test_light_path_outputs_match_cycles(tmp_path, tapped_engine, name):
    scene = empty_factory_scene()
    scene_of_lamps(scene, SCENES[name])
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, CYCLES_SPP, BOUNCES)
    spp = SAMPLES.get(name, EMBER_SPP)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 5, BOUNCES)
    check = ReferenceCheck(f'light_path_{name}', image[..., :3].astype(np.float64), var, spp, ref, ref_var,
                           header, BLOCK)
    check.assert_agrees(0.03, 0.15)
