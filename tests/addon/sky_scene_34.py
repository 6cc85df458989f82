"""Run inside a Blender binary with Ember installed (test_other_blenders.py):
a diffuse plane under the version's Nishita sky (or, given 'HOSEK_WILKIE'
after the folder, a Hosek-Wilkie sky), rendered by Ember and by Cycles with
several seeds each; EXRs written to the folder given after '--'.
"""
import math
import os
import sys

import bpy

EMBER_SEEDS, EMBER_SPP = 8, 16      # 8 seeds: Welch dof near 7-18, not 3 (issue 27)
CYCLES_SEEDS, CYCLES_SPP = 12, 8


def sky_node(tree, sky_type):
    sky = tree.nodes.new('ShaderNodeTexSky')
    sky.sky_type = sky_type
    if sky_type == 'HOSEK_WILKIE':
        sky.sun_direction = (-0.3, 0.85, 0.4)
        sky.turbidity, sky.ground_albedo = 6.7, 0.2
    else:
        sky.sun_elevation = math.radians(30.0)
        sky.sun_rotation = math.radians(160.0)
        sky.altitude = 300.0
    return sky


def build(scene, sky_type):
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    scene.world = world
    tree = world.node_tree
    tree.nodes.clear()
    out = tree.nodes.new('ShaderNodeOutputWorld')
    background = tree.nodes.new('ShaderNodeBackground')
    background.inputs['Strength'].default_value = 1.0 if sky_type == 'HOSEK_WILKIE' else 0.05
    sky = sky_node(tree, sky_type)
    tree.links.new(sky.outputs['Color'], background.inputs['Color'])
    tree.links.new(background.outputs[0], out.inputs['Surface'])
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    camera = scene.camera
    camera.location = (0.0, -4.0, 1.2)
    camera.rotation_euler = (math.radians(78.0), 0.0, 0.0)
    camera.data.lens = 20.0
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 32, 24, 100
    render.image_settings.file_format = 'OPEN_EXR'
    render.image_settings.color_depth = '32'


def main():
    args = sys.argv[sys.argv.index('--') + 1:]
    folder, sky_type = args[0], (args[1:] or ['NISHITA'])[0]
    scene = bpy.context.scene
    build(scene, sky_type)
    scene.render.engine = 'EMBER'
    for seed in range(EMBER_SEEDS):
        e = scene.ember
        e.samples, e.seed, e.max_bounces, e.transparent_max_bounces = EMBER_SPP, 100 + seed, 1, 1
        e.use_adaptive_sampling, e.clamp, e.threads = False, 0.0, 2
        scene.render.filepath = os.path.join(folder, f'ember_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', CYCLES_SPP, False, False
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transparent_max_bounces = 1
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    for seed in range(CYCLES_SEEDS):
        c.seed = seed
        scene.render.filepath = os.path.join(folder, f'cycles_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    print("SKY SCENE DONE")


main()
