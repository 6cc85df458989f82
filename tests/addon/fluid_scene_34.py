"""Run inside Debian's Blender 3.4 binary with Ember installed
(test_fluid_parity.py): a smoke-and-fire fluid domain simulated for a few
frames (cache 'REPLAY', stepped by frame_set: the bpy modules' Mantaflow
cannot simulate), then rendered by Ember and by Cycles with several seeds
each, twice: as smoke (Principled Volume scattering, density x the density
grid, under a sun) and as fire (emission only: blackbody of Temperature x
the temperature grid).  EXRs go to the folder given after '--';
grids.npz there holds the simulated density / temperature grids.
"""
import math
import os
import sys
import time

import bpy
import numpy as np

FRAMES, RESOLUTION = 6, 20
EMBER_SEEDS, EMBER_SPP = 8, 16
CYCLES_SEEDS, CYCLES_SPP = 8, 16


def simulate(folder):
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 0.0, 1.0))
    domain = bpy.context.active_object
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(0.15, 0.0, 0.45))
    flow = bpy.context.active_object
    mod = flow.modifiers.new('Fluid', 'FLUID')
    mod.fluid_type = 'FLOW'
    mod.flow_settings.flow_type = 'BOTH'
    mod.flow_settings.flow_behavior = 'INFLOW'
    flow.hide_render = True
    mod = domain.modifiers.new('Fluid', 'FLUID')
    mod.fluid_type = 'DOMAIN'
    settings = mod.domain_settings
    settings.domain_type = 'GAS'
    settings.resolution_max = RESOLUTION
    settings.cache_type = 'REPLAY'
    settings.cache_directory = os.path.join(folder, 'cache')
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, FRAMES
    for frame in range(1, FRAMES + 1):
        scene.frame_set(frame)
    evaluated = domain.evaluated_get(bpy.context.evaluated_depsgraph_get()).modifiers['Fluid'].domain_settings
    res = tuple(evaluated.domain_resolution)[::-1]
    np.savez(os.path.join(folder, 'grids.npz'), density=np.array(evaluated.density_grid).reshape(res),
             temperature=np.array(evaluated.temperature_grid).reshape(res))
    return domain


def material(domain, kind):
    mat = bpy.data.materials.new(kind)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new('ShaderNodeOutputMaterial')
    volume = tree.nodes.new('ShaderNodeVolumePrincipled')
    if kind == 'smoke':
        volume.inputs['Density'].default_value = 6.0
        volume.inputs['Color'].default_value = (0.8, 0.7, 0.6, 1.0)
    else:
        volume.inputs['Density'].default_value = 0.0
        volume.inputs['Blackbody Intensity'].default_value = 1.0
        volume.inputs['Temperature'].default_value = 1000.0
    tree.links.new(volume.outputs['Volume'], out.inputs['Volume'])
    domain.data.materials.clear()
    domain.data.materials.append(mat)


def stage(scene):
    world = bpy.data.worlds.new('grey')
    world.use_nodes = True
    world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.05, 0.06, 0.08, 1.0)
    scene.world = world
    sun = bpy.data.objects.new('sun', bpy.data.lights.new('sun', 'SUN'))
    sun.data.energy = 4.0
    sun.data.angle = 0.0
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(30.0))
    scene.collection.objects.link(sun)
    camera = scene.camera
    camera.location = (0.0, -5.5, 1.0)
    camera.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    camera.data.lens = 45.0
    render = scene.render
    render.resolution_x = render.resolution_y = 32
    render.resolution_percentage = 100
    render.image_settings.file_format = 'OPEN_EXR'
    render.image_settings.color_depth = '32'


def render(scene, folder, kind):
    scene.render.engine = 'EMBER'
    e = scene.ember
    t0 = time.time()
    for seed in range(EMBER_SEEDS):
        e.samples, e.seed, e.max_bounces, e.volume_bounces = EMBER_SPP, 100 + seed, 1, 0
        e.use_adaptive_sampling, e.clamp, e.threads = False, 0.0, 2
        scene.render.filepath = os.path.join(folder, f'{kind}_ember_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    t1 = time.time()
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', CYCLES_SPP, False, False
    c.max_bounces, c.volume_bounces, c.transparent_max_bounces = 1, 0, 1
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    # Ray marching (3.4) at a quarter voxel: its step bias far under the noise.
    c.volume_step_rate = 0.25
    for seed in range(CYCLES_SEEDS):
        c.seed = seed
        scene.render.filepath = os.path.join(folder, f'{kind}_cycles_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    print(f"FLUID {kind}: Ember {t1 - t0:.1f} s, Cycles {time.time() - t1:.1f} s")


def main():
    folder = sys.argv[sys.argv.index('--') + 1]
    scene = bpy.context.scene
    t0 = time.time()
    domain = simulate(folder)
    print(f"FLUID simulated {FRAMES} frames at {RESOLUTION} in {time.time() - t0:.1f} s")
    stage(scene)
    for kind in ('smoke', 'fire'):
        material(domain, kind)
        render(scene, folder, kind)
    print("FLUID SCENE DONE")


main()
