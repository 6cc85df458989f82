"""HDRI worlds (issue 4): export of Environment Texture / Mapping worlds, and
renders lit by the HDRIs bpy ships (bpy/<version>/datafiles/studiolights/world).

* export: pixels (row 0 = top) equal the file's, Mapping rotation as Cycles'
  euler_to_transform, missing images magenta with a warning;
* Ember's MIS (environment sampling) agrees with its BSDF-only render of the
  same scene, with lower variance;
* Cycles parity: a diffuse and a glossy sphere on a plane under a rotated HDRI
  (block z-test, Welch over Ember passes and Cycles seeds, Sidak to 1%), and
  the HDRI seen directly by the camera pixel by pixel (a 0.01-pixel box
  filter makes each pixel one lookup: orientation and rotation exactly).
"""
import math
import os

import bpy
import numpy as np
import pytest

import ember_stats as stats
from ember_testlib import (check_against_reference, load_exr, per_pass_estimates, render_array, render_for_reference,
                           require, setup_cycles, setup_ember, small_resolution)

ROTATION = (math.radians(12.0), math.radians(-8.0), math.radians(75.0))


def hdri_path(name):
    folder = bpy.utils.system_resource('DATAFILES', path=os.path.join('studiolights', 'world'))
    path = os.path.join(folder or '', name + '.exr')
    require(os.path.isfile(path), f"bpy's studio light HDRI {path} is missing")
    return path


def hdri_world(scene, path, rotation=ROTATION, interpolation='Linear', strength=1.0,
               mapping_type='POINT', coordinate='Generated'):
    """Texture Coordinate -> Mapping -> Environment Texture -> Background."""
    world = scene.world or bpy.data.worlds.new("World")
    scene.world = world
    if bpy.app.version < (5, 0, 0):  # 5.0 always uses nodes (and deprecates the switch)
        world.use_nodes = True
    tree = world.node_tree
    nodes, links = tree.nodes, tree.links
    nodes.clear()
    out = nodes.new('ShaderNodeOutputWorld')
    background = nodes.new('ShaderNodeBackground')
    background.inputs['Strength'].default_value = strength
    env = nodes.new('ShaderNodeTexEnvironment')
    env.interpolation = interpolation
    if path is not None:
        image = bpy.data.images.load(path, check_existing=True) if os.path.isfile(path) else None
        if image is None:
            image = bpy.data.images.new(os.path.basename(path), 4, 4)
            image.source = 'FILE'
            image.filepath = path
        env.image = image
    links.new(env.outputs['Color'], background.inputs['Color'])
    links.new(background.outputs[0], out.inputs['Surface'])
    if rotation is not None:
        mapping = nodes.new('ShaderNodeMapping')
        mapping.vector_type = mapping_type
        mapping.inputs['Rotation'].default_value = rotation
        coords = nodes.new('ShaderNodeTexCoord')
        links.new(coords.outputs[coordinate], mapping.inputs['Vector'])
        links.new(mapping.outputs['Vector'], env.inputs['Vector'])
    return env


def export():
    from addon.export import scene as scene_export
    return scene_export.export_scene(bpy.context.evaluated_depsgraph_get())


def read_exr(path):
    """The file's pixels as Blender reads them (row 0 = top): an independent
    path from the exporter's (OpenImageIO when it is there)."""
    return load_exr(path)


# ----------------------------------------------------------------------------
# export

def test_export_environment_texture(factory_scene):
    from addon.export import world as world_export
    path = hdri_path('forest')
    hdri_world(factory_scene, path, strength=1.7)
    exported = export()
    tex = exported.scene.world.texture
    assert tex is not None and not [w for w in exported.warnings if 'World' in w]
    np.testing.assert_array_equal(tex.pixels, read_exr(path)[..., :3])   # row 0 = top, as the file
    assert tex.strength == pytest.approx(1.7) and tex.interpolation == 'Linear'
    from mathutils import Euler
    expected = np.array(Euler(ROTATION, 'XYZ').to_matrix())
    np.testing.assert_allclose(world_export.euler_matrix(np.array(ROTATION)), expected, atol=1e-7)
    np.testing.assert_allclose(tex.matrix, expected, atol=1e-7)


def test_export_mapping_variants(factory_scene):
    from addon.export import world as world_export
    path = hdri_path('courtyard')
    rot = world_export.euler_matrix(np.array(ROTATION))
    env = hdri_world(factory_scene, path, interpolation='Closest', mapping_type='TEXTURE')
    mapping = env.inputs['Vector'].links[0].from_node
    mapping.inputs['Scale'].default_value = (2.0, 2.0, 2.0)
    mapping.inputs['Location'].default_value = (1.0, 0.0, 0.0)
    exported = export()
    tex = exported.scene.world.texture
    assert tex.interpolation == 'Closest'
    np.testing.assert_allclose(tex.matrix, 0.5 * rot.T, atol=1e-7)
    assert any("location" in w and mapping.name in w for w in exported.warnings)

    env.interpolation = 'Cubic'
    mapping.vector_type = 'VECTOR'
    exported = export()
    np.testing.assert_allclose(exported.scene.world.texture.matrix, 2.0 * rot, atol=1e-7)
    assert exported.scene.world.texture.interpolation == 'Linear'
    assert any("Cubic" in w for w in exported.warnings)

    # Object coordinates of another object: its inverse rotation comes first.
    coords = mapping.inputs['Vector'].links[0].from_node
    empty = bpy.data.objects.new("frame", None)
    empty.rotation_euler = (0.0, 0.0, 0.5)
    factory_scene.collection.objects.link(empty)
    coords.object = empty
    factory_scene.world.node_tree.links.new(coords.outputs['Object'], mapping.inputs['Vector'])
    bpy.context.view_layer.update()
    exported = export()
    frame = np.array(empty.matrix_world)[:3, :3]
    np.testing.assert_allclose(exported.scene.world.texture.matrix, 2.0 * rot @ frame.T, atol=1e-6)


def test_unlinked_mapping_vector_is_one_texel_colour(factory_scene):
    """Cycles looks up the zero vector, (u, v) = (0, 0): bilinear between the
    four corner texels."""
    path = hdri_path('forest')
    env = hdri_world(factory_scene, path, strength=2.0)
    mapping = env.inputs['Vector'].links[0].from_node
    tree = factory_scene.world.node_tree
    tree.links.remove(mapping.inputs['Vector'].links[0])
    exported = export()
    px = read_exr(path)[..., :3].astype(np.float64)
    corners = (px[0, 0] + px[0, -1] + px[-1, 0] + px[-1, -1]) / 4
    assert exported.scene.world.texture is None
    np.testing.assert_allclose(exported.scene.world.color, 2.0 * corners, rtol=1e-6)
    assert any("unlinked" in w for w in exported.warnings)


def test_generated_image_comes_through_blender_pixels(factory_scene):
    env = hdri_world(factory_scene, None, rotation=None)
    image = bpy.data.images.new("painted", 8, 4, float_buffer=True)
    values = np.random.default_rng(1).random((4, 8, 4)).astype(np.float32)   # Blender rows: bottom first
    values[..., 3] = 1.0
    image.pixels.foreach_set(values.ravel())
    env.image = image
    tex = export().scene.world.texture
    np.testing.assert_allclose(tex.pixels, values[::-1, :, :3], rtol=1e-6)
    np.testing.assert_allclose(tex.matrix, np.eye(3))


def test_missing_image_renders_magenta_with_a_warning(factory_scene, tmp_path, needs_engine):
    from addon import engine as ember_engine
    hdri_world(factory_scene, str(tmp_path / "no_such_sky.exr"), strength=0.5)
    exported = export()
    assert exported.scene.world.texture is None
    assert exported.scene.world.color == pytest.approx((0.5, 0.0, 0.5))
    assert any("no_such_sky.exr" in w and "magenta" in w for w in exported.warnings)
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    small_resolution(factory_scene, 8, 6)
    setup_ember(factory_scene, 1, seed=0, max_bounces=0)
    image = render_array(factory_scene, tmp_path, "missing")
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None and any("no_such_sky.exr" in w for w in log['warnings'])
    np.testing.assert_allclose(image[..., :3], np.broadcast_to([0.5, 0.0, 0.5], image[..., :3].shape),
                               atol=1e-6)


# ----------------------------------------------------------------------------
# renders

def material(name, kind, color, roughness=0.35):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    out = nodes.new('ShaderNodeOutputMaterial')
    if kind == 'glossy':
        node = nodes.new('ShaderNodeBsdfGlossy')
        node.distribution = 'GGX'    # Ember is single-scatter GGX (5.0 defaults to multiscatter)
        node.inputs['Roughness'].default_value = roughness
    else:
        node = nodes.new('ShaderNodeBsdfDiffuse')
    node.inputs['Color'].default_value = (*color, 1.0)
    mat.node_tree.links.new(node.outputs[0], out.inputs['Surface'])
    return mat


def spheres_on_a_plane(scene):
    """A diffuse and a glossy sphere on a diffuse plane, seen from above."""
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    floor = material("floor", 'diffuse', (0.6, 0.6, 0.6))
    bpy.ops.mesh.primitive_plane_add(size=8.0)
    bpy.context.active_object.data.materials.append(floor)
    for x, mat in ((-1.1, material("clay", 'diffuse', (0.8, 0.6, 0.4))),
                   (1.1, material("chrome", 'glossy', (0.9, 0.9, 0.9)))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(x, 0.0, 1.0), segments=32, ring_count=16)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(mat)
    camera = scene.camera
    camera.location = (0.0, -7.0, 4.0)
    camera.rotation_euler = (math.radians(62.0), 0.0, 0.0)
    camera.data.lens = 35.0


def ember_batches(scene, tmp_path, taps, spp, name, strategy='MIS', bounces=2, seed=3):
    setup_ember(scene, spp, seed=seed, max_bounces=bounces)
    scene.ember.strategy = strategy
    render_array(scene, tmp_path, name)
    return per_pass_estimates(taps[-1].images)[..., :3]


def test_environment_sampling_agrees_with_bsdf_sampling(factory_scene, tmp_path, tapped_engine):
    """courtyard.exr lights the spheres: Ember with environment sampling
    (MIS) and with BSDF sampling only agree block by block; MIS is less
    noisy.  (Under forest.exr's small sun, BSDF-only estimates are too
    heavy-tailed for a z-test at a test's sample count: their error bars
    are unreliable; MIS there is checked against Cycles below.)"""
    hdri_world(factory_scene, hdri_path('courtyard'))
    spheres_on_a_plane(factory_scene)
    small_resolution(factory_scene, 32, 24)
    mis = ember_batches(factory_scene, tmp_path, tapped_engine, 64, "mis")
    bsdf = ember_batches(factory_scene, tmp_path, tapped_engine, 256, "bsdf", strategy='BSDF', seed=4)  # independent
    var_mis, var_bsdf = mis.var(axis=0, ddof=1).mean(), bsdf.var(axis=0, ddof=1).mean()
    failures, details = stats.failing_blocks(stats.block_means(mis, 4), stats.block_means(bsdf, 4))
    print(f"\ncourtyard: MIS vs BSDF relative mean error {details['relative_mean_error']:.4f}, max |t| "
          f"{details['max_abs_t']:.2f}; per-sample variance MIS {var_mis:.4g}, BSDF {var_bsdf:.4g}")
    assert len(failures) == 0, f"MIS and BSDF sampling disagree: {failures[:10].tolist()}; {details}"
    tests, level = stats.region_mean_tests(mis, bsdf, name="courtyard MIS vs BSDF means")
    wrong = stats.report_mean_tests("courtyard: MIS against BSDF sampling", tests, level)
    assert not wrong, f"MIS and BSDF sampling disagree on the image or region means: {wrong}"
    assert var_mis < 0.5 * var_bsdf


# 320: at 256 the median block resolved 2.0% once the family budget grew to 250 (its t threshold 1% higher)
HDRI_SPP, HDRI_BLOCK = 512, 10   # 320 resolved 0.57 % of the image, not 0.5 % (the channel sum's variance)
BACKGROUND_SPP = 128
IMAGE_POWER, BLOCK_POWER = 0.005, 0.02   # issue 12's targets, asserted (docs/testing.md)


def reference_scene(name, folder=None):
    """The scene 'spheres' or 'background' and its bounces (as
    tools/cycles_references.py renders it)."""
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    if name == 'spheres':
        hdri_world(scene, hdri_path('forest'))
        spheres_on_a_plane(scene)
        small_resolution(scene, 40, 30)
        return scene, 2
    hdri_world(scene, hdri_path('city'))
    sky_only(scene, (80.0, 0.0, 30.0), 12.0, (64, 40))
    return scene, 0


def test_hdri_scene_matches_cycles(tmp_path, tapped_engine):
    """forest.exr (a small bright sun) through a rotated Mapping lights a
    diffuse and a glossy sphere: Ember agrees with converged Cycles over the
    image, its quadrants and block by block."""
    scene, bounces = reference_scene('spheres')
    image, var = render_for_reference(scene, tmp_path, "spheres", tapped_engine, HDRI_SPP, 3, bounces)
    check = check_against_reference('hdri_spheres', scene, bounces, image, var, HDRI_SPP, HDRI_BLOCK)
    check.assert_agrees(IMAGE_POWER, BLOCK_POWER)


def sky_only(scene, rotation_euler, lens, size):
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    camera = scene.camera
    camera.location = (0.0, 0.0, 0.0)
    camera.rotation_euler = [math.radians(a) for a in rotation_euler]
    camera.data.lens = lens
    small_resolution(scene, *size)


# Camera orientations (degrees): at the horizon, looking up, looking down.
VIEWS = ((90.0, 0.0, 30.0), (150.0, 0.0, -60.0), (25.0, 0.0, 120.0))


# float32 results: each renderer sums 4 equal samples and scales (at most 2
# roundings of 2^-24 each); the two may round differently.
EXACT_RTOL = 4 * 2.0 ** -24
GRID = 5            # points per pixel side at which the footprint's texels are found


def footprint_texels(scene, image_size, rotation):
    """(H, W, GRID*GRID) texel indices of the HDRI ('Closest') under a GRID x
    GRID lattice over each pixel's square, from Blender's camera frame and
    the Mapping rotation (mathutils), and Cycles' equirectangular mapping
    (u = (pi - atan2(y, x)) / 2 pi, v = 1 - acos(z) / pi)."""
    from mathutils import Euler
    from engine.environment import direction_to_equirect
    camera = scene.camera
    frame = [np.array(v) for v in camera.data.view_frame(scene=scene)]
    top_left = next(v for v in frame if v[0] < 0 and v[1] > 0)
    top_right = next(v for v in frame if v[0] > 0 and v[1] > 0)
    bottom_left = next(v for v in frame if v[0] < 0 and v[1] < 0)
    width, height = scene.render.resolution_x, scene.render.resolution_y
    f = np.linspace(0.0, 1.0, GRID)
    xs = (np.arange(width)[:, None] + f[None, :]).ravel() / width        # (W * GRID)
    ys = (np.arange(height)[:, None] + f[None, :]).ravel() / height      # rows from the top
    local = (top_left[None, None] + xs[None, :, None] * (top_right - top_left)[None, None]
             + ys[:, None, None] * (bottom_left - top_left)[None, None])
    to_world = np.array(camera.matrix_world.to_3x3().normalized())
    lookup = np.array(Euler(rotation, 'XYZ').to_matrix())
    e = local.reshape(-1, 3) @ (lookup @ to_world).T
    u, v = direction_to_equirect(e)
    tw, th = image_size
    texel = (np.floor(v * th).astype(np.int64) % th) * tw + np.floor(u * tw).astype(np.int64) % tw
    texel = texel.reshape(height, GRID, width, GRID).transpose(0, 2, 1, 3)
    return texel.reshape(height, width, GRID * GRID)


@pytest.mark.parametrize("view", VIEWS)
def test_background_texels_match_cycles_exactly(view, factory_scene, tmp_path, needs_engine):
    """A long lens on a 'Closest' HDRI through a rotated Mapping: a pixel
    whose footprint lies inside one texel is that texel's value in both
    renderers (deterministic), so orientation, rotation and texel addressing
    must match Cycles exactly there; a pixel across texel edges lies between
    the values of the texels it covers, in both.  (Cycles' box filter is
    always 1 pixel wide.)"""
    env = hdri_world(factory_scene, hdri_path('city'), interpolation='Closest')
    sky_only(factory_scene, view, 1200.0, (48, 32))
    setup_ember(factory_scene, 4, seed=0, max_bounces=0, filter_type='BOX', filter_width=1.0)
    ember = render_array(factory_scene, tmp_path, "ember_sky")[..., :3].astype(np.float64)
    setup_cycles(factory_scene, 4, 0, 0, filter_type='BOX', filter_width=1.0)
    cycles = render_array(factory_scene, tmp_path, "cycles_sky")[..., :3].astype(np.float64)

    texels = footprint_texels(factory_scene, tuple(env.image.size), ROTATION)
    inside = (texels == texels[..., :1]).all(axis=2)
    texel_rgb = read_exr(env.image.filepath_from_user())[::-1, :, :3].reshape(-1, 3).astype(np.float64)
    values = texel_rgb[texels]                                    # (H, W, GRID^2, 3)
    low, high = values.min(axis=2), values.max(axis=2)
    slack = EXACT_RTOL * high
    print(f"\nview {view}: {inside.sum()} of {inside.size} pixels inside one texel; max relative difference "
          f"there {np.max(np.abs(ember - cycles)[inside] / np.maximum(cycles[inside], 1e-30)):.2e}")
    assert inside.sum() >= 100, "the view must put whole pixels inside texels"
    for name, image in (('Ember', ember), ('Cycles', cycles)):
        np.testing.assert_allclose(image[inside], low[inside], rtol=EXACT_RTOL, atol=0,
                                   err_msg=f"{name}: a pixel inside one texel is not that texel's value")
        outside = ~((image >= low - slack) & (image <= high + slack)).all(axis=2)
        assert not outside.any(), (f"{name}: pixels {np.argwhere(outside)[:5].tolist()} lie outside the "
                                   f"values of the texels their footprint covers")
    # The view is not symmetric: a mirrored or upside-down image would fail.
    for flipped in (cycles[:, ::-1], cycles[::-1]):
        assert not np.allclose(flipped[inside], cycles[inside], rtol=EXACT_RTOL, atol=0)


def test_background_matches_cycles(tmp_path, tapped_engine):
    """A wide view of the rotated HDRI (bilinear, Blackman-Harris filter):
    Ember agrees with converged Cycles over the image, its quadrants and
    block by block."""
    scene, bounces = reference_scene('background')
    image, var = render_for_reference(scene, tmp_path, "sky", tapped_engine, BACKGROUND_SPP, 3, bounces)
    check = check_against_reference('hdri_background', scene, bounces, image, var, BACKGROUND_SPP, 8)
    check.assert_agrees(IMAGE_POWER, BLOCK_POWER)
