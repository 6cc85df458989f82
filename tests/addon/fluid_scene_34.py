"""Run inside Debian's Blender 3.4 binary with Ember installed
(test_fluid_parity.py): two smoke-and-fire fluid domains side by side
simulated for a few frames (cache 'REPLAY', stepped by frame_set: the bpy
modules' Mantaflow cannot simulate), the left one's material smoke
(Principled Volume scattering, density x the density grid, under a sun),
the right one's fire (emission only: blackbody of Temperature x the
temperature grid), rendered by Ember and by Cycles with several seeds each
(one image holds both: the render's fixed cost is paid once).  EXRs go to
the folder given after '--'; grids.npz there holds the fire domain's
simulated density / temperature grids.
"""
import math
import os
import sys
import time

import bpy
import numpy as np

FRAMES, RESOLUTION = 10, 20
WIDTH, HEIGHT = 40, 24
EMBER_SEEDS, EMBER_SPP = 8, int(os.environ.get('FLUID_EMBER_SPP', '48'))
CYCLES_SEEDS, CYCLES_SPP = 8, int(os.environ.get('FLUID_CYCLES_SPP', '16'))
STEP_RATE = float(os.environ.get('FLUID_STEP_RATE', '0.25'))


def domain_with_flow(folder, name, x):
    """A 2 m gas domain centred at x, a sphere inflowing smoke and fire at
    its bottom; returns the domain."""
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(x, 0.0, 1.0))
    domain = bpy.context.active_object
    domain.name = name
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(x + 0.15, 0.0, 0.45))
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
    settings.cache_directory = os.path.join(folder, 'cache_' + name)
    return domain


def simulate(folder):
    """The smoke domain (left) and the fire domain (right), each with its
    own flow (the flows' objects are hidden from renders)."""
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    domains = [domain_with_flow(folder, 'smoke', -1.05), domain_with_flow(folder, 'fire', 1.05)]
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, FRAMES
    for frame in range(1, FRAMES + 1):
        scene.frame_set(frame)
    evaluated = domains[1].evaluated_get(bpy.context.evaluated_depsgraph_get()).modifiers['Fluid'].domain_settings
    res = tuple(evaluated.domain_resolution)[::-1]
    np.savez(os.path.join(folder, 'grids.npz'), density=np.array(evaluated.density_grid).reshape(res),
             temperature=np.array(evaluated.temperature_grid).reshape(res))
    return domains


def material(domain, kind):
    """Smoke: Principled Volume scattering (Density 6 x the density grid);
    fire: emission only (Density 0, the blackbody of 1000 K x the
    temperature grid, 1.5-3 between flame_ignition and flame_max_temp)."""
    mat = bpy.data.materials.new(kind)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes['Principled BSDF'])      # a volume only: no surface
    out = tree.nodes['Material Output']
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
    camera.location = (0.1, -5.6, 0.85)
    camera.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    camera.data.lens = 50.0
    render = scene.render
    render.resolution_x, render.resolution_y = WIDTH, HEIGHT
    render.resolution_percentage = 100
    render.image_settings.file_format = 'OPEN_EXR'
    render.image_settings.color_depth = '32'


def render(scene, folder):
    scene.render.engine = 'EMBER'
    e = scene.ember
    t0 = time.time()
    for seed in range(EMBER_SEEDS):
        e.samples, e.seed, e.max_bounces, e.volume_bounces = EMBER_SPP, 100 + seed, 1, 0
        e.transparent_max_bounces = 8
        e.use_adaptive_sampling, e.clamp, e.threads = False, 0.0, 2
        scene.render.filepath = os.path.join(folder, f'ember_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    t1 = time.time()
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', CYCLES_SPP, False, False
    # Shadow rays from the smoke to the sun cross the fire domain's two
    # faces: transparent bounces enough for both (at 1 Cycles 3.4 stops them).
    c.max_bounces, c.volume_bounces, c.transparent_max_bounces = 1, 0, 8
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    # Ray marching (3.4) at a quarter voxel: its step bias far under the noise.
    c.volume_step_rate = STEP_RATE
    for seed in range(CYCLES_SEEDS):
        c.seed = seed
        scene.render.filepath = os.path.join(folder, f'cycles_{seed}.exr')
        bpy.ops.render.render(write_still=True)
    print(f"FLUID renders: Ember {t1 - t0:.1f} s, Cycles {time.time() - t1:.1f} s")


def main():
    folder = sys.argv[sys.argv.index('--') + 1]
    scene = bpy.context.scene
    t0 = time.time()
    domains = simulate(folder)
    print(f"FLUID simulated {FRAMES} frames at {RESOLUTION} in {time.time() - t0:.1f} s")
    stage(scene)
    for domain, kind in zip(domains, ('smoke', 'fire')):
        material(domain, kind)
    render(scene, folder)
    print("FLUID SCENE DONE")
    # Blender 3.4 segfaults at exit after the simulation (Mantaflow's
    # solvers, also with the modifiers removed): leave without the teardown.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


main()
