"""Cycles parity for light sampling and ray visibility (issue 4).

Each scene is built with bpy (``reference_scene``) and rendered by Ember;
tools/cycles_references.py rendered it once with Cycles to convergence
(tests/data/cycles_light_<scene>.exr, with the variance of its mean).  The
image and quadrant totals and every block and channel are compared by
Welch's t with both noises, at the suite's family level
(ember_testlib.check_against_reference); results and power are printed.
Beside the comparison, each visibility scene checks in Ember's own image
that the flag has its effect (a shadow gone, an object missing).
"""
import math

import pytest

from parity_scenes import box, light, material, mesh_object, plane, top_camera
from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference

BLOCK = 8
IMAGE_POWER = 0.005     # the image mean must resolve a 0.5 % bias (issue 12) ...
BLOCK_POWER = 0.02      # ... and the median block 2 %, except in the scenes below (docs/testing.md)
# Ember's samples per scene: what reaches both targets (power printed).
# rect_close 640 -> 1280 and glossy_invisible_light 2048 -> 5120 spp (the channel sum's variance):
# they resolved 0.63 % and 3.22 % of the image (asked 0.5 % and 2.5 %).
SAMPLES = {'big_triangle': 2048, 'spot_blend': 768, 'rect_close': 1280, 'glossy_invisible_light': 5120}
EMBER_SPP = 256
# glossy_invisible_light: a glossy floor lit through reflections of two area
# lights, each hidden from one kind of ray, is noisy in both renderers and
# heavy-tailed: at 256 samples two quadrants came out 4.3 % and 5.7 % low
# (t -4.6, -5.6; the image +2.3 % +- 1.3 %) because the rare bright paths
# were missing from them, and their variance with them; at 2048 samples
# (seeds 2, 5) every quadrant is within 0.6 % +- 0.8 %, i.e. the normal
# approximation holds there.  2048 samples resolve about 2 % over the image,
# about 8 % per block (the targets would need some 20 times more).
WEAK = {'glossy_invisible_light': (0.025, 0.10)}


def rect_close(scene):
    """A 2 x 0.5 rectangle light 0.15 above a diffuse floor."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.0, 0.0, 0.15), 20.0, shape='RECTANGLE', size=2.0, size_y=0.5)
    top_camera(scene, 4.0)
    return 1


def big_triangle(scene):
    """A large emissive triangle 0.3 above a diffuse floor, seen from below
    its edge, and a small diffuse box under it."""
    plane("floor", material("floor", 'diffuse'))
    mesh_object("emitter", [(-2.0, -1.5, 0.3), (2.0, -1.0, 0.35), (0.0, 2.0, 0.25)], [(0, 1, 2)],
                material("emit", "emission", (1.0, 0.75, 0.5), 2.0))
    box("box", material("box", 'diffuse', (0.3, 0.6, 0.8)), (0.5, 0.0, 0.08), (0.3, 0.3, 0.16))
    top_camera(scene, 5.0, 30.0, location=(0.0, -3.0), tilt=0.55)
    return 1


def spot_blend(scene):
    """A spot with a wide blend over a floor and a box."""
    plane("floor", material("floor", 'diffuse'))
    box("box", material("box", 'diffuse', (0.8, 0.5, 0.3)), (0.3, 0.2, 0.25), (0.5, 0.5, 0.5))
    light('SPOT', (0.0, 0.0, 2.5), 300.0, spot_size=math.radians(60), spot_blend=0.6,
          shadow_soft_size=0.1)
    top_camera(scene, 6.0)
    return 1


def shadow_invisible(scene):
    """A box that casts no shadow (visible_shadow off) between a point light
    and the floor, next to one that does."""
    plane("floor", material("floor", 'diffuse'))
    ghost = box("ghost", material("ghost", 'diffuse', (0.2, 0.7, 0.2)), (-0.8, 0.0, 0.6), (0.4, 0.4, 0.4))
    ghost.visible_shadow = False
    box("solid", material("solid", 'diffuse', (0.7, 0.2, 0.2)), (0.8, 0.0, 0.6), (0.4, 0.4, 0.4))
    light('POINT', (0.0, 0.0, 2.0), 200.0, shadow_soft_size=0.05)
    top_camera(scene, 6.0)
    return 1


def glossy_invisible_light(scene):
    """A glossy floor and a diffuse wall under an area light that is
    invisible to glossy rays (no highlight, no glossy NEE), plus a light
    invisible to diffuse rays that only shows in the floor's reflection."""
    plane("floor", material("floor", 'glossy', (0.9, 0.9, 0.9), roughness=0.25))
    mesh_object("wall", [(-3, 1.5, 0), (3, 1.5, 0), (3, 1.5, 3), (-3, 1.5, 3)], [(0, 1, 2, 3)],
                material("wall", 'diffuse', (0.8, 0.8, 0.8)))
    a = light('AREA', (-0.8, 0.0, 1.2), 60.0, shape='SQUARE', size=0.6)
    a.visible_glossy = False
    b = light('AREA', (0.8, 0.3, 1.0), 40.0, rotation=(math.radians(-60), 0.0, 0.0), shape='SQUARE', size=0.4)
    b.visible_diffuse = False
    top_camera(scene, 5.0, 30.0, location=(0.0, -3.5), tilt=0.7)
    return 2


def diffuse_camera_invisible(scene):
    """A red wall invisible to diffuse rays (no red bounce light on the
    floor, but seen by the camera) and a box invisible to the camera that
    still casts its shadow and bounces light."""
    plane("floor", material("floor", 'diffuse'))
    wall = mesh_object("red", [(-1.0, -2, 0), (-1.0, 2, 0), (-1.0, 2, 2), (-1.0, -2, 2)], [(0, 1, 2, 3)],
                       material("red", 'diffuse', (0.9, 0.1, 0.1)))
    wall.visible_diffuse = False
    hidden = box("hidden", material("hidden", 'diffuse', (0.2, 0.2, 0.9)), (0.8, 0.0, 0.5), (0.4, 0.4, 0.4))
    hidden.visible_camera = False
    light('POINT', (0.0, 0.0, 2.0), 200.0, shadow_soft_size=0.1)
    top_camera(scene, 6.0)
    return 2


def light_over_lit_world(scene):
    """A large area light over a diffuse floor under a grey-blue world: in
    Cycles a BSDF ray that meets a light adds its emission and goes on to the
    world behind it, so the light must not hide the sky from the floor."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.0, 0.0, 0.6), 30.0, shape='SQUARE', size=1.5)
    top_camera(scene, 5.0)
    sky = (0.3, 0.35, 0.4)
    scene.world.color = sky
    if scene.world.use_nodes and 'Background' in scene.world.node_tree.nodes:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (*sky, 1.0)
    return 1


SCENES = {'rect_close': rect_close, 'light_over_lit_world': light_over_lit_world, 'big_triangle': big_triangle, 'spot_blend': spot_blend,
          'shadow_invisible': shadow_invisible, 'glossy_invisible_light': glossy_invisible_light,
          'diffuse_camera_invisible': diffuse_camera_invisible}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_light_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    spp = SAMPLES.get(name, EMBER_SPP)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 2, bounces)
    check = check_against_reference('light_' + name, scene, bounces, image, var, spp, BLOCK)
    assert image[..., :3].mean() > 1e-3, "black image"
    check_effect(name, image[..., :3])
    check.assert_agrees(*WEAK.get(name, (IMAGE_POWER, BLOCK_POWER)))


def check_effect(name, rgb):
    """Each visibility flag visibly does something in Ember's own image
    (camera 6 m above the floor: 0.19 m per pixel, centre at column 16, row 12)."""
    if name == 'shadow_invisible':
        # The point light is between the boxes: their shadows fall outwards.
        ghost_side = rgb[11:14, 7:10].mean()
        solid_side = rgb[11:14, 22:25].mean()
        assert ghost_side > 1.5 * solid_side, f"the ghost box casts a shadow: {ghost_side} vs {solid_side}"
    if name == 'diffuse_camera_invisible':
        under_hidden = rgb[11:14, 19:22].mean(axis=(0, 1))
        assert under_hidden[2] < 1.2 * under_hidden[0], f"the camera sees the hidden box: {under_hidden}"
        near_wall = rgb[8:16, 12:14].mean(axis=(0, 1))
        assert near_wall[0] < 1.1 * near_wall[1], f"red bleeds from a wall invisible to diffuse: {near_wall}"
