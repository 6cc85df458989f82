"""Cycles parity of rough refraction lit from outside its refraction cone
(issue 26: the Transmission bake's gap, seen in a render).

Cycles' bsdf_microfacet_eval scores every refraction pair, also those no
microfacet refracts between ("TODO: check if the refraction configuration
is valid"), so its light sampling brings direct light through rough glass
from directions its sampler never draws; the MIS weight of such a light
sample uses that same pdf.  Ember does as Cycles (engine/lobes/glass.py).

Scene: the camera looks straight down at two rough panes side by side (a
Refraction BSDF and a Glass BSDF, GGX roughness 0.3, IOR 1.45) under a
dim grey world, nothing else in the scene; a sphere light (radius 0.4, no soft falloff: BSDF rays hit
it, so the MIS weight matters) sits beside and below the panes at a grazing
angle, 60-75 degrees from the panes' -N, outside the 46 degree cone a view
along the normal refracts into.  All the direct light on the panes is that
light.  Ember (EMBER_SPP) against live Cycles (SEEDS x CYCLES_SPP), image
and region means and 8 x 8 blocks (one family each), power printed and
asserted; Cycles' render without the light shows that most of the panes'
light is that direct light (the panes see nothing else lit).
"""
import numpy as np

from parity_scenes import light, mesh_object, top_camera
from ember_testlib import ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference
from ember_testlib import small_resolution

BOUNCES = 4
BLOCK = 16
EMBER_SPP = 512
SEEDS = 8
CYCLES_SPP = 256


def pane(name, node_type, x0, x1):
    """A rough dielectric pane [x0, x1] x [-1.2, 1.2] at z 0."""
    import bpy
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    node = nodes.new(node_type)
    node.distribution = 'GGX'
    node.inputs['Roughness'].default_value = 0.3
    node.inputs['IOR'].default_value = 1.45
    node.inputs['Color'].default_value = (0.9, 0.8, 0.6, 1.0)
    mat.node_tree.links.new(node.outputs[0], nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    h = 1.2
    return mesh_object(name, [(x0, -h, 0.0), (x1, -h, 0.0), (x1, h, 0.0), (x0, h, 0.0)], [(0, 1, 2, 3)], mat)


def rough_panes(scene):
    pane("refraction", 'ShaderNodeBsdfRefraction', -1.2, 0.0)
    pane("glass", 'ShaderNodeBsdfGlass', 0.0, 1.2)
    light('POINT', (2.0, 0.4, -0.35), 1500.0, shadow_soft_size=0.4, use_soft_falloff=False)
    top_camera(scene, 4.0)
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.005, 0.005, 0.005, 1.0)
    small_resolution(scene, 64, 48)
    return BOUNCES


def test_rough_refraction_outside_the_cone_matches_cycles(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    rough_panes(scene)
    image, var = render_for_reference(scene, tmp_path, 'rough_panes', tapped_engine, EMBER_SPP, 1, BOUNCES)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'rough_panes', SEEDS, CYCLES_SPP, BOUNCES)
    check = ReferenceCheck('rough refraction', image[..., :3].astype(np.float64), var, EMBER_SPP, ref, ref_var,
                           header, BLOCK)
    # Cycles without the light: the panes show the world alone (nothing else reaches them), so what
    # the light adds is its direct light from outside the cone (what Ember used to leave out).
    next(o for o in scene.objects if o.type == 'LIGHT').hide_render = True
    dark, _var, _header = live_cycles_reference(scene, tmp_path, 'rough_panes_dark', 1, 64, BOUNCES)
    panes, unlit = ref[12:36, 16:44].mean(), dark[12:36, 16:44].mean()
    print(f"rough refraction: the panes, Cycles {panes:.4f} ({unlit:.4f} without the light), "
          f"Ember {image[12:36, 16:44, :3].mean():.4f}")
    assert panes > 1.5 * unlit, "Cycles shows little light from outside the cone: the test would see nothing"
    check.assert_agrees(0.005, 0.1)
