"""Mirror-ball worlds (issue 23): the Environment Texture's MIRROR_BALL
projection (Cycles' direction_to_mirrorball, kernel/camera/projection.h).

The scene is built here (mirror_ball_world): a 32 x 32 float image of
random texels (a generated image, so no file is needed) read through a
rotated Mapping, as the HDRI tests do.

* export: the projection comes through, no warning; an unlinked Mapping
  Vector reads the ball's centre (Cycles' zero vector);
* a diffuse and a glossy sphere on a plane lit by a ball with a small
  bright spot (so the environment's sampling table matters) against live
  Cycles: image, quadrant and block tests with their power printed;
* the background seen by the camera against live Cycles pixel by pixel: a
  long lens on 'Closest' texels, so a pixel inside one texel is that
  texel's value in both renderers (deterministic), and one across texel
  edges lies between the values it covers (orientation, the mapping and
  texel addressing exactly).
The sampler's pdf (chi-square) is tested in tests/engine/test_environment.py.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import (ReferenceCheck, live_cycles_reference, render_array, render_for_reference, setup_cycles,
                           setup_ember, small_resolution)
from test_world_hdri import EXACT_RTOL, ROTATION, export, hdri_world, sky_only, spheres_on_a_plane

SIZE = 32
# Points per pixel side at which the footprint's texels are found: finer than
# the HDRI test's 5, as the ball bends texel edges across a pixel.
GRID = 31


def ball_pixels(seed=11):
    """(SIZE, SIZE, 4) float32 RGBA, row 0 = the bottom (Blender's order):
    random texels, so a mirrored or shifted lookup reads other values."""
    rng = np.random.default_rng(seed)
    px = np.ones((SIZE, SIZE, 4), np.float32)
    px[..., :3] = 0.05 + rng.random((SIZE, SIZE, 3))
    return px


def mirror_ball_world(scene, interpolation='Closest', rotation=ROTATION, pixels=None):
    env = hdri_world(scene, None, rotation=rotation, interpolation=interpolation)
    image = bpy.data.images.new("mirror_ball", SIZE, SIZE, alpha=True, float_buffer=True)
    image.pixels.foreach_set((ball_pixels() if pixels is None else pixels).ravel())
    env.image = image
    env.projection = 'MIRROR_BALL'
    return env


def test_export_mirror_ball(factory_scene, needs_engine):
    mirror_ball_world(factory_scene)
    exported = export()
    texture = exported.scene.world.texture
    assert texture is not None and texture.projection == 'MIRROR_BALL'
    assert not [w for w in exported.warnings if 'projection' in w], exported.warnings
    np.testing.assert_allclose(texture.pixels, ball_pixels()[::-1, :, :3], rtol=0, atol=0)


def test_unlinked_mapping_vector_reads_the_centre(factory_scene, needs_engine):
    env = mirror_ball_world(factory_scene)
    tree = factory_scene.world.node_tree
    mapping = next(n for n in tree.nodes if n.type == 'MAPPING')
    for link in list(mapping.inputs['Vector'].links):
        tree.links.remove(link)
    world = export().scene.world
    assert world.texture is None
    centre = ball_pixels()[SIZE // 2, SIZE // 2, :3]
    np.testing.assert_allclose(world.color, centre, rtol=1e-6)
    assert env.projection == 'MIRROR_BALL'


def footprint_texels(scene, rotation):
    """(H, W, GRID*GRID) texel indices of the ball under a GRID x GRID
    lattice over each pixel, from Blender's camera frame, the Mapping
    rotation (mathutils) and direction_to_mirrorball."""
    from mathutils import Euler
    from engine.environment import direction_to_mirrorball
    camera = scene.camera
    frame = [np.array(v) for v in camera.data.view_frame(scene=scene)]
    top_left = next(v for v in frame if v[0] < 0 and v[1] > 0)
    top_right = next(v for v in frame if v[0] > 0 and v[1] > 0)
    bottom_left = next(v for v in frame if v[0] < 0 and v[1] < 0)
    width, height = scene.render.resolution_x, scene.render.resolution_y
    f = np.linspace(0.0, 1.0, GRID)
    xs = (np.arange(width)[:, None] + f[None, :]).ravel() / width
    ys = (np.arange(height)[:, None] + f[None, :]).ravel() / height
    local = (top_left[None, None] + xs[None, :, None] * (top_right - top_left)[None, None]
             + ys[:, None, None] * (bottom_left - top_left)[None, None])
    to_world = np.array(camera.matrix_world.to_3x3().normalized())
    lookup = np.array(Euler(rotation, 'XYZ').to_matrix())
    u, v = direction_to_mirrorball(local.reshape(-1, 3) @ (lookup @ to_world).T)
    texel = (np.floor(v * SIZE).astype(np.int64) % SIZE) * SIZE + np.floor(u * SIZE).astype(np.int64) % SIZE
    texel = texel.reshape(height, GRID, width, GRID).transpose(0, 2, 1, 3)
    return texel.reshape(height, width, GRID * GRID)


# Camera orientations (degrees): three views away from the ball's rim (+Y
# after the Mapping, where every texel of the rim meets).
VIEWS = ((90.0, 0.0, 180.0), (90.0, 0.0, -90.0), (20.0, 0.0, 40.0))


@pytest.mark.parametrize("view", VIEWS)
def test_mirror_ball_texels_match_cycles_exactly(view, factory_scene, tmp_path, needs_engine):
    mirror_ball_world(factory_scene)
    sky_only(factory_scene, view, 300.0, (48, 32))
    setup_ember(factory_scene, 4, seed=0, max_bounces=0, filter_type='BOX', filter_width=1.0)
    ember = render_array(factory_scene, tmp_path, "ember_ball")[..., :3].astype(np.float64)
    setup_cycles(factory_scene, 4, 0, 0, filter_type='BOX', filter_width=1.0)
    cycles = render_array(factory_scene, tmp_path, "cycles_ball")[..., :3].astype(np.float64)

    texels = footprint_texels(factory_scene, ROTATION)
    inside = (texels == texels[..., :1]).all(axis=2)
    values = ball_pixels()[..., :3].reshape(-1, 3).astype(np.float64)[texels]
    low, high = values.min(axis=2), values.max(axis=2)
    slack = EXACT_RTOL * high
    print(f"\nmirror ball view {view}: {inside.sum()} of {inside.size} pixels inside one texel; max relative "
          f"difference there {np.max(np.abs(ember - cycles)[inside] / np.maximum(cycles[inside], 1e-30)):.2e}; "
          f"{len(np.unique(texels))} texels seen")
    assert inside.sum() >= 100, "the view must put whole pixels inside texels"
    assert len(np.unique(texels)) >= 4, "the view must cross texel edges"
    for name, image in (('Ember', ember), ('Cycles', cycles)):
        np.testing.assert_allclose(image[inside], low[inside], rtol=EXACT_RTOL, atol=0,
                                   err_msg=f"{name}: a pixel inside one texel is not that texel's value")
        outside = ~((image >= low - slack) & (image <= high + slack)).all(axis=2)
        assert not outside.any(), (f"{name}: pixels {np.argwhere(outside)[:5].tolist()} lie outside the "
                                   f"values of the texels their footprint covers")


EMBER_SPP, CYCLES_SEEDS, CYCLES_SPP, BOUNCES, BLOCK = 128, 4, 64, 2, 8


def test_lit_by_a_mirror_ball_matches_cycles(tmp_path, tapped_engine):
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    pixels = ball_pixels()
    pixels[20:22, 9:11, :3] = (60.0, 50.0, 40.0)      # a bright spot: the table must find it
    mirror_ball_world(scene, 'Linear', pixels=pixels)
    spheres_on_a_plane(scene)
    small_resolution(scene, 32, 24)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, "mirror_ball", CYCLES_SEEDS, CYCLES_SPP, BOUNCES)
    image, var = render_for_reference(scene, tmp_path, "mirror_ball", tapped_engine, EMBER_SPP, 3, BOUNCES)
    image, var = image[..., :3].astype(np.float64), var[..., :3]
    print(f"mirror ball spheres: Ember mean {image.mean():.5g}, Cycles {ref.mean():.5g} "
          f"(ratio {image.mean() / ref.mean():.4f})")
    check = ReferenceCheck("mirror_ball_spheres", image, var, EMBER_SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.02, 0.15)
