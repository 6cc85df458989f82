"""A Blender depsgraph -> one engine.scene.Scene plus warnings for the user."""
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import backend
from . import camera as camera_export
from . import instances as instance_export
from . import light as light_export
from . import material as material_export
from . import motion as motion_export
from . import udim
from . import world as world_export


MAX_PATHS = 1 << 17


class ExportError(Exception):
    """The scene cannot be rendered; the message is meant for the user."""


class ExportCancelled(Exception):
    """The user pressed Esc while the scene was being exported."""


def stop_checker(should_stop):
    """A function raising ExportCancelled once ``should_stop()`` is true."""
    def check():
        if should_stop is not None and should_stop():
            raise ExportCancelled("stopped while exporting")
    return check


@dataclass
class Export:
    scene: object                  # engine.scene.Scene
    warnings: list = field(default_factory=list)
    seconds: float = 0.0
    triangles: int = 0             # instanced triangles (what the renderer traces)


def scene_camera(depsgraph, camera_override=None):
    """The evaluated camera object to render from."""
    scene = depsgraph.scene
    camera = camera_override or scene.camera
    if camera is None:
        raise ExportError("The scene has no active camera")
    if camera.type != 'CAMERA':
        raise ExportError(f"The active camera '{camera.name}' is not a camera object")
    return camera.evaluated_get(depsgraph)


def export_scene(depsgraph, camera_override=None, should_stop=None, engine=None, is_preview=False,
                 require_camera=True, cache=None):
    """_export_scene's Export; final renders (not previews) also name the
    objects whose faces coincide (coincident_notes)."""
    exported = _export_scene(depsgraph, camera_override, should_stop, engine, is_preview, require_camera, cache)
    if not is_preview:
        start = time.perf_counter()
        exported.warnings += coincident_notes(exported.scene)
        exported.seconds += time.perf_counter() - start
    return exported


# Object pairs named in the coincident-faces warning; the rest are counted.
NAMED_PAIRS = 3


def coincident_notes(scene):
    """One warning naming objects whose faces lie in one plane and overlap
    (engine.coplanar): which of the two a ray meets there is left to
    rounding and BVH order, in Cycles as in Ember, so the two may differ."""
    pairs, left_out = backend.engine().coincident_pairs(scene)
    if not pairs:
        return []
    named = ", ".join(f"'{a}' and '{b}'" for a, b in pairs[:NAMED_PAIRS])
    more = f" (and {len(pairs) - NAMED_PAIRS} more pairs)" if len(pairs) > NAMED_PAIRS else ""
    unchecked = f"; {left_out} instanced triangles were not checked" if left_out else ""
    return [f"Coincident faces: {named}{more} have faces in one plane that overlap; which one a ray meets "
            f"there is left to rounding, so Ember and Cycles may render them differently (move one off the "
            f"plane){unchecked}"]


def _export_scene(depsgraph, camera_override=None, should_stop=None, engine=None, is_preview=False,
                  require_camera=True, cache=None):
    """Everything the renderer needs, read from an evaluated depsgraph.
    ``should_stop()`` is asked between objects and between the arrays of a
    mesh; once true, ExportCancelled is raised.  Given the RenderEngine
    (``engine``, whose frame_set evaluates other times), a render with motion
    blur is exported at its shutter's centre with the motion over the
    shutter (export/motion.py), and the frame is set back after.
    ``cache`` (a persistent.MeshCache, Persistent Data) keeps meshes between
    renders; motion blur exports without it (its frame changes would make
    the depsgraph's updates describe other times).  A bake
    (``require_camera`` False) needs no camera: without one the engine's
    default stands in, unused."""
    scene = depsgraph.scene
    blur = motion_export.shutter(scene, is_preview) if engine is not None else None
    if not require_camera and camera_override is None and scene.camera is None:
        return _export(depsgraph, None, should_stop, camera=False)
    if blur is None:
        if engine is None or not motion_export.wants_vector(depsgraph, blur, is_preview):
            return _export(depsgraph, camera_override, should_stop, cache=cache)
        # (the Vector pass's frame changes would make Persistent Data's
        # depsgraph updates describe other frames: exported without the cache)
        return _export_with_vector(engine, depsgraph, camera_override, should_stop)
    frame = scene.frame_current + scene.frame_subframe
    centre = motion_export.centre_time(scene, blur)
    try:
        motion_export.set_time(engine, centre)
        keys, sources = [], []
        exported = _export(depsgraph, camera_override, should_stop, keys, sources=sources)
        start = time.perf_counter()
        exported.warnings += motion_export.add_motion(engine, depsgraph, exported, keys, blur, centre,
                                                      scene_camera(depsgraph, camera_override), sources=sources)
        exported.seconds += time.perf_counter() - start
    finally:
        motion_export.set_time(engine, frame)
    return exported


def _export_with_vector(engine, depsgraph, camera_override, should_stop):
    """The scene at its frame, with frame - 1 and frame + 1 for the Vector pass."""
    scene = depsgraph.scene
    frame = scene.frame_current + scene.frame_subframe
    keys, sources = [], []
    exported = _export(depsgraph, camera_override, should_stop, keys, sources=sources)
    start = time.perf_counter()
    try:
        exported.warnings += motion_export.add_vector_motion(engine, depsgraph, exported, keys, frame,
                                                             scene_camera(depsgraph, camera_override), sources)
    finally:
        motion_export.set_time(engine, frame)
    exported.seconds += time.perf_counter() - start
    return exported


def _export(depsgraph, camera_override=None, should_stop=None, keys=None, camera=True, cache=None, sources=None):
    check = stop_checker(should_stop)
    start = time.perf_counter()
    renderer = backend.engine()
    scene = depsgraph.scene
    override = getattr(depsgraph.view_layer, 'material_override', None)
    materials = material_export.MaterialTable(override)
    for bulk in (True, False):
        points, curves, links = [], [], {}
        light_collector = light_export.LightCollector(links)
        try:
            meshes, instances, warnings = instance_export.collect_instances(
                depsgraph, materials.slots, check, keys, points, curves, cache, light_collector.add, sources,
                bulk=bulk)
            break
        except instance_export.bulk_instances.BulkMismatch as mismatch:
            print(f"Ember: geometry-nodes instances read one by one ({mismatch})")
    check()
    lights, light_warnings = light_collector.lights, light_collector.warnings
    world, world_warning = world_export.world_from_blender(scene.world)
    if camera:
        camera, camera_warnings = _camera(depsgraph, camera_override, renderer)
    else:
        camera, camera_warnings = renderer.Camera(), []
    shape, subdivisions, shape_warnings = _curve_shape(scene, curves)
    result = renderer.Scene(
        meshes=meshes, instances=instances, points=points, curves=curves, materials=materials.materials,
        lights=lights, world=world, camera=camera, cycles_version=tuple(bpy.app.version), light_links=links,
        curve_shape=shape, curve_subdivisions=subdivisions)
    udim.cull_tiles(result)
    warnings = (materials.warnings + warnings + light_warnings + camera_warnings + shape_warnings
                + _catcher_notes(result))
    if world_warning:
        warnings.append(world_warning)
    sizes = np.array([len(mesh.triangles) for mesh in meshes] + [0], np.int64)
    triangles = int(sizes[renderer.instance_meshes(instances)].sum()) if len(instances) else 0
    return Export(result, warnings, time.perf_counter() - start, triangles)


def _curve_shape(scene, curves):
    """(the engine's curve_shape, curve_subdivisions, warnings) of Render >
    Curves: Rounded Ribbons, 3D Curves and Linear 3D Curves as Cycles; any
    other shape as 3D curves (warned)."""
    settings = getattr(scene, 'cycles_curves', None)
    shape = getattr(settings, 'shape', 'THICK')
    warnings = []
    if curves and shape not in SHAPES:
        warnings.append(f"Curves are rendered as 3D curves; Ember has no {str(shape).lower()} (Render > Curves > Shape)")
    return (shape if shape in SHAPES else 'THICK'), max(int(getattr(settings, 'subdivisions', 2)), 0), warnings


# Render > Curves > Shape values the engine traces as Cycles does.
SHAPES = ('THICK', 'RIBBONS', 'THICK_LINEAR')


def _camera(depsgraph, camera_override, renderer):
    camera_object = scene_camera(depsgraph, camera_override)
    try:
        camera, warnings = camera_export.camera_from_blender(camera_object, depsgraph.scene.render)
        renderer.validate_camera(camera)
    except ValueError as err:  # engine.scene.SceneError is a ValueError
        message = str(err).removeprefix('camera: ')
        raise ExportError(f"Camera '{camera_object.name}': {message}") from err
    return camera, warnings


def _catcher_notes(scene):
    """A shadow catcher that emits light (Cycles renders it: its emission
    enters the shadow ratio, which can exceed 1) is named in a warning."""
    notes, seen = [], set()
    for inst in backend.engine().distinct_instances(scene.instances):
        if not getattr(inst, 'shadow_catcher', False) or inst.name in seen:
            continue
        seen.add(inst.name)
        for m in inst.materials:
            mat = scene.materials[m] if 0 <= m < len(scene.materials) else None
            emission = getattr(mat, 'emission', (0.0, 0.0, 0.0))
            if mat is not None and (backend.engine().value_range(emission)[1] > 0
                                    if not isinstance(emission, tuple) else max(emission) > 0):
                notes.append(f"Object '{inst.name}' is a shadow catcher that emits light (material "
                             f"'{mat.name}'): its emission enters the shadow catcher's ratio")
                break
    return notes


# Material, world and light previews stop after this many bounces: they must
# feel interactive, and a sphere on a floor shows little past the fourth.
PREVIEW_MAX_BOUNCES = 4


def render_settings(scene, is_preview=False):
    """engine.scene.RenderSettings from the scene's Ember and Blender settings."""
    settings = scene.ember
    return backend.engine().RenderSettings(
        samples=settings.preview_samples if is_preview else settings.samples,
        max_bounces=min(settings.max_bounces, PREVIEW_MAX_BOUNCES) if is_preview else settings.max_bounces,
        transparent_max_bounces=settings.transparent_max_bounces,
        diffuse_bounces=settings.diffuse_bounces,
        glossy_bounces=settings.glossy_bounces,
        transmission_bounces=settings.transmission_bounces,
        filter_glossy=settings.filter_glossy,
        volume_bounces=settings.volume_bounces,
        seed=settings.seed,
        light_selection=settings.light_selection.lower(),
        strategy=settings.strategy.lower(),
        clamp=settings.clamp,
        filter_type=settings.filter_type,
        # Cycles ignores the width of its box filter: always one pixel.
        filter_width=1.0 if settings.filter_type == 'BOX' else settings.filter_width,
        mis_compensation=settings.mis_compensation,
        transparent=bool(scene.render.film_transparent),
        threads=settings.threads,
        time_limit=0.0 if is_preview else settings.time_limit,
        # Paths in flight: 2^17 keeps the path state near 200 MB; a batch of
        # 64k paths costs 5-9 % less CPU per path than one of 32k (2^16).
        # Esc does not wait for running batches (engine/render.py abandons them).
        max_paths=MAX_PATHS,
        # One sample first, then passes of about a second (not one sample
        # each: a pass ends at a barrier where a core waits for the other).
        samples_per_pass=0,
        sampling_pattern=settings.sampling_pattern.lower(),
        adaptive_threshold=settings.adaptive_threshold if settings.use_adaptive_sampling else 0.0,
        adaptive_min_samples=settings.adaptive_min_samples,
        # The film keeps first-hit AOVs only for the denoiser (memory: the
        # Depth and Normal passes come from the pass accumulators).
        aovs=("normal", "albedo") if settings.use_denoising and not is_preview else (),
        use_jit=getattr(settings, 'use_jit', True),
        persistent=persistent_data(scene, is_preview),
        **path_guiding(scene, is_preview),
    )


def path_guiding(scene, is_preview=False):
    """Path guiding from Cycles' own settings (Render > Sampling > Path
    Guiding: Guiding with Surface Guiding on, Training Samples, 0 = all):
    engine/integrator/path_guide.py.  Not in previews (too few samples to learn from)."""
    cycles = getattr(scene, 'cycles', None)
    on = bool(getattr(cycles, 'use_guiding', False)) and bool(getattr(cycles, 'use_surface_guiding', True))
    return {'path_guiding': on and not is_preview,
            'path_guiding_training_samples': int(getattr(cycles, 'guiding_training_samples', 128))}


def persistent_data(scene, is_preview=False):
    """Render > Performance > Final Render > Persistent Data (final renders only)."""
    return bool(getattr(scene.render, 'use_persistent_data', False)) and not is_preview
