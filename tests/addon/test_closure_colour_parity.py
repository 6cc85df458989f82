"""Closure colours as Cycles splits them (issue 26, item 3): Diffuse /
Glossy / Transmission Color hold each closure's albedo estimate (Cycles'
``bsdf_albedo``: closure weight x ``bsdf_microfacet_estimate_albedo``), and
the Direct / Indirect passes the light divided by it.  For a gold metal
Cycles' Glossy Color holds the tint; Ember wrote the untinted weight and put
the tint into the light passes (their products agreed).

One row of spheres, each one closure family: a Principled gold metal with
an F82 tint (Multiscatter GGX), a Principled dielectric with a specular
tint, a coated one, a sheen, a Principled transmission and a Glass BSDF.
Ember and Cycles seeds, the three colour passes side by side as nine
channels: Welch's t per 4x4 block and channel and on the image mean
(ember_testlib.seed_block_test: two families), power printed; the tables'
precision is the floor of each block's standard error.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import (multilayer_output, node_material, read_multilayer_exr, render_seeds, require,
                           seed_block_test, small_resolution)

SEEDS, SPP = 12, 16
# Ember's albedo tables (engine/data/build_tables.py: midpoint quadrature)
# and Cycles' (2^20 Sobol samples, printed to 6 decimals) are two estimates of
# the same integrals: the gold's estimate mix(F0, 1, s) differs by up to
# 7e-5 of its value (blue; s by about 1e-4), deterministic in every pixel.
TABLE_PRECISION = 1e-4
WIDTH, HEIGHT = 96, 16
COLOURS = ("Diffuse Color", "Glossy Color", "Transmission Color")
GOLD = (1.0, 0.766, 0.336)
SPHERES = (
    ("gold", 'ShaderNodeBsdfPrincipled', {'Base Color': GOLD + (1.0,), 'Metallic': 1.0, 'Roughness': 0.3,
                                          'Specular Tint': (0.9, 0.7, 0.5, 1.0)}),
    ("tinted", 'ShaderNodeBsdfPrincipled', {'Base Color': (0.2, 0.5, 0.8, 1.0), 'Roughness': 0.4,
                                            'Specular Tint': (1.0, 0.5, 0.3, 1.0)}),
    ("coat", 'ShaderNodeBsdfPrincipled', {'Base Color': (0.8, 0.2, 0.1, 1.0), 'Roughness': 0.5,
                                          'Coat Weight': 0.8, 'Coat Roughness': 0.1,
                                          'Coat Tint': (0.8, 0.9, 1.0, 1.0)}),
    ("sheen", 'ShaderNodeBsdfPrincipled', {'Base Color': (0.3, 0.3, 0.6, 1.0), 'Roughness': 0.6,
                                           'Sheen Weight': 1.0, 'Sheen Tint': (0.5, 0.8, 1.0, 1.0)}),
    ("transmission", 'ShaderNodeBsdfPrincipled', {'Base Color': (0.9, 0.7, 0.5, 1.0), 'Roughness': 0.2,
                                                  'Transmission Weight': 1.0}),
    ("glass", 'ShaderNodeBsdfGlass', {'Color': (0.8, 0.9, 0.7, 1.0), 'Roughness': 0.3}),
)


_material = node_material


def _scene():
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for i, (name, kind, inputs) in enumerate(SPHERES):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, segments=48, ring_count=24,
                                             location=(i - 2.5, 0.0, 0.0))
        obj = bpy.context.active_object
        bpy.ops.object.shade_smooth()
        obj.data.materials.append(_material(name, kind, inputs))
    bpy.ops.object.camera_add(location=(0.0, -5.0, 0.0), rotation=(np.pi / 2, 0.0, 0.0))
    camera = bpy.context.active_object
    camera.data.type = 'ORTHO'
    camera.data.ortho_scale = 6.0
    scene.camera = camera
    scene.world.use_nodes = True
    background = next(n for n in scene.world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (0.2, 0.2, 0.2, 1.0)
    small_resolution(scene, WIDTH, HEIGHT)
    layer = bpy.context.view_layer
    for name in COLOURS:
        setattr(layer, "use_pass_" + name.lower().replace(" ", "_"), True)
    multilayer_output(scene)
    return scene


@pytest.fixture(scope="module")
def colours(registered_addon, tmp_path_factory):
    require(bpy.app.version >= (4, 0, 0), "the Principled BSDF's coat, sheen and transmission inputs are 4.0's")
    folder = tmp_path_factory.mktemp("colours")

    def read(path):
        passes = read_multilayer_exr(path)
        return np.concatenate([passes[name][..., :3] for name in COLOURS], axis=-1)
    return render_seeds(_scene(), folder, "colours", SEEDS, SPP, 300, 0, read)


def test_closure_colours_match_cycles(colours):
    ember, cycles = colours['EMBER'], colours['CYCLES']
    assert np.isfinite(ember).all()
    for i, (name, _, _) in enumerate(SPHERES):
        centre = (slice(HEIGHT // 2 - 2, HEIGHT // 2 + 2), slice(16 * i + 6, 16 * i + 10))
        e, c = (x[:, centre[0], centre[1]].mean(axis=(0, 1, 2)) for x in (ember, cycles))
        print(f"{name}: centre colours (diffuse, glossy, transmission) Ember {np.round(e, 4).tolist()}, "
              f"Cycles {np.round(c, 4).tolist()}")
    seed_block_test("closure colours blocks", "closure colours image mean", "closure colours", ember, cycles,
                    storage=TABLE_PRECISION)

