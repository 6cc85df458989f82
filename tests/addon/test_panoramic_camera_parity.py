"""Panoramic cameras against live Cycles (issue 23; engine/panorama.py):
every panorama_type of Blender 5.0 (equirectangular with a latitude and
longitude range, the equiangular cubemap face, the mirror ball, the
equidistant, equisolid and polynomial fisheyes, the central cylinder),
each with the frame shifted, on a 40 x 28 frame (the fisheyes' sensor fit
and aspect matter) of a room whose six walls have six colours, open at the
top onto a transparent film, with emitting objects about the camera.
Emission only (no bounce): what is compared is where each ray goes.  Both
renderers' RGBA seeds by seed_block_test (Welch t per 4 x 4 block and of
the image mean, power printed).  Beyond a fisheye's rim both are black and
opaque (Cycles traces nothing there, transparent film or not).  Also: the
panoramic depth of field, camera motion blur, and the Vector pass of a
moving panoramic camera against Cycles' pixel by pixel."""
import math
import os

import bpy
import numpy as np
import pytest

from ember_testlib import (add_object, empty_factory_scene, multilayer_output, node_material, read_multilayer_exr,
                           render_array, seed_block_test, setup_cycles, setup_ember, small_resolution)
from test_motion_parity import _linear_keys

WIDTH, HEIGHT = 40, 28
SEEDS, SPP = 6, 8
CYCLES_FACTOR = 16
VECTOR_SEEDS = 6

# Each type's settings, away from Blender's defaults where it has any.
PANORAMAS = {
    'EQUIRECTANGULAR': dict(latitude_min=-1.2, latitude_max=1.4, longitude_min=-2.8, longitude_max=2.6),
    'EQUIANGULAR_CUBEMAP_FACE': {},
    'MIRRORBALL': {},
    'FISHEYE_EQUIDISTANT': dict(fisheye_fov=3.4),
    'FISHEYE_EQUISOLID': dict(fisheye_lens=6.0, fisheye_fov=3.2),
    'FISHEYE_LENS_POLYNOMIAL': dict(fisheye_fov=2.0, fisheye_polynomial_k0=-1e-4, fisheye_polynomial_k1=-0.06,
                                    fisheye_polynomial_k2=1e-5, fisheye_polynomial_k3=2e-6,
                                    fisheye_polynomial_k4=-2e-8),
    'CENTRAL_CYLINDRICAL': dict(central_cylindrical_range_u_min=-2.0, central_cylindrical_range_u_max=2.2,
                                central_cylindrical_range_v_min=-1.1, central_cylindrical_range_v_max=0.9,
                                central_cylindrical_radius=1.3),
}
WALLS = ((0.9, 0.2, 0.2), (0.2, 0.8, 0.3), (0.2, 0.3, 0.9), (0.9, 0.8, 0.2), (0.7, 0.2, 0.8), (0.2, 0.8, 0.8))


def emission(name, color, strength=1.0):
    return node_material(name, 'ShaderNodeEmission', {'Color': (*color, 1.0), 'Strength': strength})


def room(scene, open_top=True):
    """A 12 m cube about the origin, one colour a wall; its top face removed
    (the world, on a transparent film, shows there) when ``open_top``."""
    import bmesh
    cube = add_object(bpy.ops.mesh.primitive_cube_add, "room", emission("wall0", WALLS[0]), size=12.0)
    for k, color in enumerate(WALLS[1:], 1):
        cube.data.materials.append(emission(f"wall{k}", color))
    mesh = bmesh.new()
    mesh.from_mesh(cube.data)
    mesh.faces.ensure_lookup_table()
    top = None
    for k, face in enumerate(mesh.faces):
        face.material_index = k
        if face.calc_center_median().z > 5.9:
            top = face
    if open_top:
        bmesh.ops.delete(mesh, geom=[top], context='FACES_ONLY')
    mesh.to_mesh(cube.data)
    mesh.free()
    things = ((bpy.ops.mesh.primitive_uv_sphere_add, (3.0, 1.0, 0.5), (1.0, 0.6, 0.3), dict(radius=0.9)),
              (bpy.ops.mesh.primitive_cube_add, (-2.0, 3.0, -1.0), (0.3, 1.0, 0.6), dict(size=1.4)),
              (bpy.ops.mesh.primitive_uv_sphere_add, (0.5, -3.0, 2.0), (2.0, 2.0, 2.0), dict(radius=0.6)),
              (bpy.ops.mesh.primitive_cone_add, (1.0, 0.5, -3.0), (0.2, 0.4, 1.5), dict(radius1=1.0, depth=1.5)),
              (bpy.ops.mesh.primitive_cube_add, (-3.5, -1.5, 1.5), (1.2, 1.2, 0.1), dict(size=1.0)))
    for k, (op, location, color, kwargs) in enumerate(things):
        add_object(op, f"thing{k}", emission(f"thing{k}", color), location=location, **kwargs)
    scene.world.color = (0.4, 0.4, 0.4)
    scene.render.film_transparent = True


def panoramic_scene(kind, open_top=True):
    scene = empty_factory_scene()
    room(scene, open_top)
    camera = scene.camera
    camera.location = (0.31, -0.23, 0.12)
    camera.rotation_euler = (math.radians(80.0), math.radians(10.0), math.radians(30.0))
    data = camera.data
    data.type = 'PANO'
    data.panorama_type = kind
    for name, value in PANORAMAS[kind].items():
        setattr(data, name, value)
    data.shift_x, data.shift_y = 0.03, -0.02
    small_resolution(scene, WIDTH, HEIGHT)
    return scene


def seeds(scene, folder, name, spp=SPP, count=SEEDS):
    """Ember's and Cycles' RGBA seeds.  Cycles takes CYCLES_FACTOR times the
    samples: at few samples its pixel is not yet the filter's integral (its
    first sample sits at the pixel centre, and its tabulated Sobol sets are
    few), a difference a seed test reads on edges (+0.12 % +- 0.03 % of the
    equirectangular image against 8 Cycles samples, none against 128)."""
    out = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        images = []
        for seed in range(count):
            setup(scene, spp * (CYCLES_FACTOR if engine == 'CYCLES' else 1), seed, 0)
            images.append(render_array(scene, folder, f"{name}_{engine}_{seed}").astype(np.float64))
        out[engine] = np.array(images)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert not [w for w in log.get('warnings', ()) if 'camera' in w.lower()], log.get('warnings')
    return out['EMBER'], out['CYCLES']


@pytest.mark.parametrize("kind", list(PANORAMAS))
def test_panorama_matches_cycles(kind, registered_addon, needs_engine, tmp_path):
    require_type(kind)
    scene = panoramic_scene(kind)
    ember, cycles = seeds(scene, tmp_path, kind.lower())
    # the view must see several walls, the objects and, but for the cubemap face, the open top
    assert len(np.unique(np.round(cycles.mean(axis=0)[..., :3], 2).reshape(-1, 3), axis=0)) > 6
    if kind.startswith('FISHEYE') or kind == 'MIRRORBALL':
        rim = beyond_the_rim(scene)
        assert rim.sum() >= 20, "the frame must reach beyond the rim"
        for name, image in (('Ember', ember), ('Cycles', cycles)):
            assert (image[:, rim, :3] == 0).all() and (image[:, rim, 3] == 1).all(), name
    seed_block_test(f"panorama {kind} blocks", f"panorama {kind} mean", f"panorama {kind}", ember, cycles)


def beyond_the_rim(scene, radius=1.5):
    """(H, W) pixels whose whole filter footprint (Blackman-Harris 1.5: 1.5
    pixels about the centre) lies beyond the rim, by engine/panorama.py on
    the exported camera (the rim itself is tested exactly in
    tests/engine/test_panorama.py)."""
    return rim_coverage(scene, radius) == 0.0


def rim_coverage(scene, radius=1.5):
    """(H, W) share of each pixel's filter footprint (a square lattice) inside the rim."""
    from addon.export.camera import camera_from_blender
    from engine.panorama import Panorama
    cam, _ = camera_from_blender(scene.camera, scene.render)
    pano = Panorama(cam)
    f = np.linspace(-radius, radius, 13)
    x = (np.arange(WIDTH)[None, :, None, None] + 0.5 + f[None, None, :, None]) / WIDTH + pano.shift[0]
    y = ((HEIGHT - 1 - np.arange(HEIGHT))[:, None, None, None] + 0.5 + f[None, None, None, :]) / HEIGHT
    u, v = np.broadcast_arrays(x, y + pano.shift[1])
    inside = pano.to_direction(u.ravel(), v.ravel()).any(axis=1)
    return inside.reshape(HEIGHT, WIDTH, -1).mean(axis=2)


def require_type(kind):
    from ember_testlib import require
    items = bpy.types.Camera.bl_rna.properties['panorama_type'].enum_items.keys()
    require(kind in items, f"this Blender has no {kind} panorama")


def test_panoramic_depth_of_field_matches_cycles(registered_addon, needs_engine, tmp_path):
    """Cycles' panoramic lens: the aperture perpendicular to each ray, the
    focus at a distance along the ray (objects at 3 to 4 m, focused at 2)."""
    scene = panoramic_scene('EQUIRECTANGULAR')
    dof = scene.camera.data.dof
    dof.use_dof, dof.focus_distance, dof.aperture_fstop = True, 2.0, 0.04
    ember, cycles = seeds(scene, tmp_path, "pano_dof", spp=16)
    seed_block_test("panorama dof blocks", "panorama dof mean", "panorama depth of field", ember, cycles)


def test_panoramic_camera_motion_blur_matches_cycles(registered_addon, needs_engine, tmp_path):
    """A fisheye turning 30 degrees and moving 0.4 m over the shutter."""
    scene = panoramic_scene('FISHEYE_EQUIDISTANT')
    camera = scene.camera
    start = tuple(camera.rotation_euler)
    _linear_keys(camera, 'rotation_euler', [start, (start[0], start[1], start[2] + math.radians(60.0))])
    _linear_keys(camera, 'location', [(0.3, -0.6, 0.1), (0.3, 0.2, 0.1)])
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.5
    scene.frame_set(2)
    ember, cycles = seeds(scene, tmp_path, "pano_blur", spp=16)
    seed_block_test("panorama blur blocks", "panorama blur mean", "panorama camera motion blur", ember, cycles)


def test_panoramic_vector_pass_matches_cycles(registered_addon, needs_engine, tmp_path):
    """The Vector pass of an equisolid fisheye moving and turning between
    frames 1 and 3 (motion blur off, frame 2; Cycles' direction_to_panorama
    at each step), in a closed room, per block and per pixel over the seeds."""
    scene = panoramic_scene('FISHEYE_EQUISOLID', open_top=False)
    camera = scene.camera
    start = tuple(camera.rotation_euler)
    _linear_keys(camera, 'rotation_euler', [(start[0] - 0.2, start[1], start[2] - 0.3),
                                            (start[0] + 0.2, start[1], start[2] + 0.3)])
    _linear_keys(camera, 'location', [(0.3, -0.8, 0.1), (0.3, 0.4, 0.4)])
    scene.frame_set(2)
    bpy.context.view_layer.use_pass_vector = True
    multilayer_output(scene)
    out = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        images = []
        for seed in range(VECTOR_SEEDS):
            setup(scene, SPP * (CYCLES_FACTOR if engine == 'CYCLES' else 1), seed, 0)
            scene.render.filepath = os.path.join(str(tmp_path), f"{engine}_{seed}.exr")
            bpy.ops.render.render(write_still=True)
            images.append(read_multilayer_exr(scene.render.filepath)['Vector'])
        out[engine] = np.array(images, np.float64)
    ember, cycles = out['EMBER'], out['CYCLES']
    coverage = rim_coverage(scene)
    rim = coverage == 0.0
    assert rim.sum() >= 20 and (ember[:, rim] == 0).all() and (cycles[:, rim] == 0).all()
    # Pixels across the rim are left out: the pass is a ratio over the samples that hit, so one
    # that finds the rim's inside writes its whole vector (all or nothing at so few samples).
    keep = (coverage == 1.0) | rim
    # the camera moves: most pixels carry more than a pixel of motion a frame
    assert (np.linalg.norm(cycles.mean(axis=0), axis=2)[~rim] > 1.0).mean() > 0.5
    seed_block_test("panorama vector blocks", "panorama vector mean", "panorama Vector", ember, cycles, keep=keep)
    # and pixel by pixel: each pixel repeated 4 x 4 is a block of its own (a pixel whose samples
    # all see one surface is the same in every seed: held to float32 rounding)
    still = ((ember.var(axis=0) == 0) & (cycles.var(axis=0) == 0)).all(axis=2) & ~rim
    print(f"\npanorama Vector: {still.sum()} of {(~rim).sum()} pixels inside the rim the same in every seed")
    def pixels(x):
        return np.repeat(np.repeat(x, 4, axis=1), 4, axis=2)
    seed_block_test("panorama vector pixels", "panorama vector pixel mean", "panorama Vector per pixel",
                    pixels(ember), pixels(cycles), keep=pixels(keep[None, ..., None])[0, ..., 0])


def test_export_of_panoramic_settings(registered_addon, needs_engine):
    """Every setting reaches the engine camera as Blender holds it, with no
    warning; a custom (OSL) camera is still named and rendered as perspective."""
    from addon.export import scene as scene_export
    scene = panoramic_scene('FISHEYE_LENS_POLYNOMIAL')
    data = scene.camera.data
    for name, value in {**PANORAMAS['EQUIRECTANGULAR'], **PANORAMAS['CENTRAL_CYLINDRICAL']}.items():
        setattr(data, name, value)
    data.fisheye_lens = 7.5
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    cam = exported.scene.camera
    assert not [w for w in exported.warnings if 'amera' in w], exported.warnings
    assert cam.kind == 'PANO' and cam.panorama_type == 'FISHEYE_LENS_POLYNOMIAL'
    f32 = lambda x: np.float32(x).item()      # noqa: E731  (Blender stores floats)
    assert cam.fisheye_lens == f32(7.5) and cam.fisheye_fov == f32(2.0)
    assert cam.latitude == (f32(-1.2), f32(1.4)) and cam.longitude == (f32(-2.8), f32(2.6))
    assert cam.fisheye_polynomial == tuple(f32(PANORAMAS['FISHEYE_LENS_POLYNOMIAL'][f"fisheye_polynomial_k{i}"])
                                           for i in range(5))
    assert cam.cylinder == (f32(-2.0), f32(2.2), f32(-1.1), f32(0.9), f32(1.3))
    assert (cam.shift_x, cam.shift_y) == (f32(0.03), f32(-0.02))
    if 'CUSTOM' in bpy.types.Camera.bl_rna.properties['type'].enum_items.keys():
        data.type = 'CUSTOM'
        exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
        assert exported.scene.camera.kind == 'PERSP'
        assert [w for w in exported.warnings if 'custom cameras are not supported' in w], exported.warnings


@pytest.mark.parametrize("kind", list(PANORAMAS))
def test_panoramic_depth_pass_matches_cycles(kind, registered_addon, needs_engine, tmp_path):
    """The Depth pass of each panorama type against Cycles' pixel by pixel:
    both write it from the ray through the pixel's centre (Cycles' sample
    0), as the hit's distance from the camera (camera_z_depth; along the
    view axis it was up to 3x short at the equirectangular frame's sides);
    the open top and beyond a fisheye's rim 1e10 (nothing hit, nothing written),
    and a pixel whose every sample falls beyond the rim still has its
    centre's depth.  Cycles' centre sits 0.00056 px right and up of the
    exact one (fitted to the depth's gradient, the same in every type: its
    filter table), up to 3.5e-4 of the depth at a slanted wall (1.4e-3 at
    the mirror ball's rim): each pixel is held to 1e-3 of its depth, 5e-3
    where its footprint straddles a rim."""
    require_type(kind)
    scene = panoramic_scene(kind)
    bpy.context.view_layer.use_pass_z = True
    multilayer_output(scene)
    depth = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        setup(scene, 1, 0, 0)
        scene.render.filepath = os.path.join(str(tmp_path), f"{engine}.exr")
        bpy.ops.render.render(write_still=True)
        depth[engine] = read_multilayer_exr(scene.render.filepath)['Depth'][..., 0].astype(np.float64)
    ember, cycles = depth['EMBER'], depth['CYCLES']
    hit = cycles < 1e9
    # the room is 12 m wide about a camera near its centre: walls at 6 m or more, objects nearer
    assert hit.mean() > 0.2 and cycles[hit].min() < 4.0 and cycles[hit].max() > 6.0
    # 1e-3 as test_passes_parity; 5e-3 where the pixel straddles a rim (the projection is steepest there)
    coverage = rim_coverage(scene) if kind.startswith('FISHEYE') or kind == 'MIRRORBALL' else np.ones(hit.shape)
    tolerance = np.where((coverage > 0.0) & (coverage < 1.0), 5e-3, 1e-3)
    close = np.abs(ember - cycles) <= tolerance * (1.0 + np.abs(cycles))
    print(f"\npanorama {kind} Depth: {close.mean():.4f} of {close.size} pixels agree "
          f"(largest relative difference {np.max(np.abs(ember - cycles) / (1.0 + np.abs(cycles))):.2e})")
    assert close.all(), f"{int((~close).sum())} pixels differ, at {np.argwhere(~close)[:8].tolist()}"

