"""Holdout and Shadow Catcher (issue 26), as Cycles.

Holdout: the Holdout shader and the object's Holdout mask
(kernel/integrator/shade_surface.h, integrate_surface_holdout).

Camera rays, and their passes through transparent surfaces, that meet a
holdout uncover the film's alpha by the holdout weight times their
throughput, whether Film > Transparent is on or not, and add no light
there; a full holdout ends them.  Every other ray sees a holdout object as
an ordinary one, and a Holdout shader's part as black.

Scene: a floor under an area light, a sphere with the object's Holdout
mask (its light on the floor stays), a cube whose material mixes a diffuse
with a Holdout (factor 0.5); film transparent off, then on.

Shadow Catcher (kernel/integrator/shadow_catcher.h, kernel/film/read.h):
the same view with the floor a shadow catcher under a cube and a sphere
(ordinary objects) and the area light: Combined is Cycles' matte with the
approximate shadow, its alpha the shadow on a transparent film, the
background times the shadow on an opaque one.

With the Shadow Catcher pass on (opaque film), Combined keeps the shadow in
its alpha and the pass holds Cycles' ratio (Combined - matte) / catcher light.

Ember and Cycles seeds, the five renders side by side (23 channels):
Welch's t per 4x4 block and channel and on the image mean
(ember_testlib.seed_block_test: two families), power printed.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import (add_object, empty_factory_scene, multilayer_output, read_multilayer_exr, render_array,
                           render_seeds, require, rough_material, seed_block_test, setup_ember, small_resolution)

SEEDS, SPP, BOUNCES = 6, 32, 3
WIDTH, HEIGHT = 32, 24


_diffuse = rough_material


def _half_holdout():
    mat, bsdf = _diffuse("HalfHoldout", (0.8, 0.3, 0.2))
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    holdout = tree.nodes.new('ShaderNodeHoldout')
    mix = tree.nodes.new('ShaderNodeMixShader')
    mix.inputs[0].default_value = 0.5
    tree.links.new(bsdf.outputs[0], mix.inputs[1])
    tree.links.new(holdout.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs['Surface'])
    return mat


_add = add_object


def _catcher_scene():
    scene = empty_factory_scene()
    mesh = bpy.ops.mesh
    floor = _add(mesh.primitive_plane_add, "Catcher", _diffuse("Floor", (0.6, 0.6, 0.6))[0], size=12,
                 location=(0, 0, -1))
    floor.is_shadow_catcher = True
    _add(mesh.primitive_uv_sphere_add, "Ball", _diffuse("Ball", (0.2, 0.7, 0.3))[0], radius=0.9,
         location=(-1.2, 0.3, 0.0))
    bpy.ops.object.shade_smooth()
    _add(mesh.primitive_cube_add, "Box", _diffuse("Box", (0.8, 0.3, 0.2))[0], size=1.4, location=(1.3, -0.2, -0.3))
    _light_and_world(scene)
    return scene


def _light_and_world(scene):
    bpy.ops.object.light_add(type='AREA', location=(1.0, -1.5, 4.0))
    light = bpy.context.active_object
    light.data.energy = 400.0
    light.data.size = 2.0
    world = scene.world
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (0.1, 0.12, 0.2, 1.0)
    small_resolution(scene, WIDTH, HEIGHT)


def _scene():
    scene = empty_factory_scene()
    mesh = bpy.ops.mesh
    _add(mesh.primitive_plane_add, "Floor", _diffuse("Floor", (0.6, 0.6, 0.6))[0], size=12, location=(0, 0, -1))
    sphere = _add(mesh.primitive_uv_sphere_add, "Masked", _diffuse("Sphere", (0.2, 0.7, 0.3))[0], radius=0.9,
                  location=(-1.2, 0.3, 0.0))
    bpy.ops.object.shade_smooth()
    sphere.is_holdout = True
    _add(mesh.primitive_cube_add, "Half", _half_holdout(), size=1.4, location=(1.3, -0.2, -0.3))
    _light_and_world(scene)
    return scene


@pytest.fixture(scope="module")
def renders(registered_addon, tmp_path_factory):
    require('is_holdout' in bpy.types.Object.bl_rna.properties, "Object.is_holdout is Blender 3.0's")
    folder = tmp_path_factory.mktemp("holdout")
    out = {}
    for kind, build in (("holdout", _scene), ("catcher", _catcher_scene)):
        scene = build()
        for transparent in (False, True):
            scene.render.film_transparent = transparent
            for engine, images in render_seeds(scene, folder, f"{kind}_{transparent}", SEEDS, SPP, 500,
                                               BOUNCES).items():
                out[kind, engine, transparent] = images
    # The Shadow Catcher pass on (opaque film): Combined is the matte alone,
    # and the pass holds the shadow ratio.
    scene = _catcher_scene()
    scene.render.film_transparent = False
    bpy.context.view_layer.cycles.use_pass_shadow_catcher = True
    multilayer_output(scene)

    def read(path):
        layers = read_multilayer_exr(path)
        return np.concatenate([layers['Combined'], layers['Shadow Catcher'][..., :3]], axis=-1)
    for engine, images in render_seeds(scene, folder, "pass", SEEDS, SPP, 500, BOUNCES, read).items():
        out['pass', engine, False] = images
    return out


def test_holdouts_and_shadow_catchers_match_cycles(renders):
    """Both scenes and both films, and the catcher scene with the Shadow
    Catcher pass, in one comparison (23 channels, two families)."""
    middle = (slice(8, 11), slice(12, 15))    # the masked sphere's middle: no light, no alpha
    for transparent in (False, True):
        ember, cycles = renders['holdout', 'EMBER', transparent], renders['holdout', 'CYCLES', transparent]
        assert np.isfinite(ember).all() and np.isfinite(renders['catcher', 'EMBER', transparent]).all()
        assert np.abs(cycles[:, middle[0], middle[1]]).max() < 1e-6, "the sphere is not where the test thinks"
        assert np.abs(ember[:, middle[0], middle[1]]).max() < 1e-6, "Ember's holdout sphere is not empty"
    # On a transparent film the catcher floor away from the shadows is clear.
    corner = renders['catcher', 'EMBER', True][:, 20:, :3, 3]
    assert corner.max() < 0.05, f"the catcher's unshadowed floor is not transparent: {corner.max()}"
    sets = [(kind, t) for kind in ("holdout", "catcher") for t in (False, True)] + [("pass", False)]
    ember, cycles = (np.concatenate([renders[kind, engine, t] for kind, t in sets], axis=-1)
                     for engine in ('EMBER', 'CYCLES'))
    seed_block_test("holdout parity blocks", "holdout parity image mean",
                    "holdout and shadow catcher (opaque | transparent film)", ember, cycles)



def test_emissive_shadow_catcher_is_named(registered_addon, tmp_path):
    """Hostile input: a shadow catcher that is also a light renders finite
    pixels and is named in a warning."""
    from addon.export.scene import export_scene
    scene = _catcher_scene()
    tree = bpy.data.materials["Floor"].node_tree
    bsdf = next(n for n in tree.nodes if n.type == 'BSDF_PRINCIPLED')
    bsdf.inputs['Emission Strength'].default_value = 3.0
    bsdf.inputs['Emission Color'].default_value = (1.0, 0.9, 0.8, 1.0)
    export = export_scene(bpy.context.evaluated_depsgraph_get())
    assert any("'Catcher'" in w and "shadow catcher" in w for w in export.warnings), export.warnings
    setup_ember(scene, 4, 1, 1)
    for transparent in (False, True):
        scene.render.film_transparent = transparent
        assert np.isfinite(render_array(scene, tmp_path, f"glowing_{transparent}")).all()
