"""Drives Ember's Rendered viewport in a real Blender with a window (Xvfb).

    blender --factory-startup -p 0 0 W H cornell.blend -P tests/addon/viewport_gui.py -- OUT SITE

Registers the add-on from this repository (SITE holds the wheels the renderer
needs), maximises the largest 3D view, looks through the camera with the frame
fitted to the view, switches to Rendered shading, waits for the viewport
samples, takes a screenshot; renders F12 at low resolution; moves ShortBox,
waits again, takes a second screenshot.  Everything measured goes to
OUT/result.json; tests/addon/test_viewport.py judges the pictures.  Every step
runs in a bpy.app.timers callback: the window must exist and redraw between
steps.
"""
import json
import os
import sys
import time
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gui_session  # noqa: E402  (the repository and SITE on sys.path)

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from bpy_extras import view3d_utils  # noqa: E402

from addon import viewport  # noqa: E402

OUT = gui_session.OUT
gui_session.register()
RESULT = {'errors': []}
STEP_TIMEOUT = float(os.environ.get('EMBER_STEP_TIMEOUT', '100'))
# EMBER_GALLERY=1: keep Blender's interface, denoise, and save the whole
# window (docs/gallery/viewport.png); stops after that picture.
GALLERY = os.environ.get('EMBER_GALLERY') == '1'
MOVED = 'ShortBox'
F12_SIZE = 48
F12_SAMPLES = 64


def view3d():
    window = bpy.context.window_manager.windows[0]
    areas = [a for a in window.screen.areas if a.type == 'VIEW_3D']
    area = max(areas, key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == 'WINDOW')
    return window, area, region


def session():
    live = [s for s in viewport.SESSIONS if not s.closed]
    return live[-1] if live else None


def finished(s):
    """The session's job ran to its end and its last image is on screen."""
    return (s is not None and s.job_number is not None and s.thread.finished_job == s.job_number
            and s.drawn_generation == s.thread.image_generation and not s.thread.busy)


def screenshot(name):
    window, area, region = view3d()
    path = os.path.join(OUT, name)
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.screen.screenshot_area(filepath=path)
    RESULT[name] = {'path': path, 'area': [area.x, area.y, area.width, area.height],
                    'region': [region.x, region.y, region.width, region.height]}


def camera_frame():
    """The camera frame's rectangle in region pixels (x0, y0, x1, y1), y up."""
    scene = bpy.context.scene
    _, _, region = view3d()
    rv3d = region.data
    cam = scene.camera
    corners = [cam.matrix_world @ v for v in cam.data.view_frame(scene=scene)]
    points = [view3d_utils.location_3d_to_region_2d(region, rv3d, c) for c in corners]
    xs, ys = [p.x for p in points], [p.y for p in points]
    return [min(xs), min(ys), max(xs), max(ys)]


def setup():
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    settings = scene.ember
    # EMBER_VIEWPORT_SAMPLES: more samples for a picture (docs/gallery), not the test.
    settings.viewport_samples = int(os.environ.get('EMBER_VIEWPORT_SAMPLES', '2'))
    settings.max_bounces = 4
    settings.seed = 0
    scene.view_settings.view_transform = 'Standard'
    scene.view_settings.look = 'None'
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.dither_intensity = 0.0
    settings.use_preview_denoising = GALLERY
    if GALLERY:
        return
    window, area, region = view3d()
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.screen.screen_full_area(use_hide_panels=True)


def look_through_camera():
    window, area, region = view3d()
    space = area.spaces.active
    for name in () if GALLERY else ('show_region_header', 'show_region_toolbar', 'show_region_ui', 'show_region_tool_header'):
        if hasattr(space, name):
            setattr(space, name, False)
    space.overlay.show_overlays = GALLERY
    space.show_gizmo = GALLERY
    space.region_3d.view_perspective = 'CAMERA'
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.view3d.view_center_camera()
    RESULT['region_size'] = [region.width, region.height]
    RESULT['started'] = time.perf_counter()
    space.shading.type = 'RENDERED'


def save_float_image(name):
    """The viewport's own scene-linear image (what view_draw was given)."""
    s = session()
    np.save(os.path.join(OUT, name), s.thread.image)
    RESULT['pixel_size'] = int(s.engine.get_preview_pixel_size(bpy.context.scene))


def first_screenshot():
    if GALLERY:
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window):
            bpy.ops.screen.screenshot(filepath=os.path.join(OUT, 'window.png'))
        del STEPS[3:]
        return
    RESULT['frame'] = camera_frame()
    screenshot('viewport.png')
    save_float_image('viewport.npy')
    RESULT['stats_before_move'] = dict(viewport.STATS, errors=list(viewport.STATS['errors']))


def render_f12():
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = F12_SIZE
    scene.render.resolution_percentage = 100
    scene.ember.samples = F12_SAMPLES
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    scene.render.filepath = os.path.join(OUT, 'f12.exr')
    bpy.ops.render.render(write_still=True)
    # The frame's aspect is unchanged (square): the viewport must not restart
    # for the resolution either, but it may; wait for it below.


def move_object():
    RESULT['mesh_exports_before_move'] = viewport.STATS['mesh_exports']
    RESULT['restarts_before_move'] = viewport.STATS['restarts']
    RESULT['first_draws_before_move'] = len(viewport.STATS['first_draw_seconds'])
    bpy.data.objects[MOVED].location.z += 0.4


def second_screenshot():
    screenshot('viewport_moved.png')
    save_float_image('viewport_moved.npy')
    RESULT['stats_after_move'] = dict(viewport.STATS, errors=list(viewport.STATS['errors']))
    RESULT['mesh_exports_after_move'] = viewport.STATS['mesh_exports']


def leave_rendered():
    """Back to Solid shading: Blender frees the engine, the session must stop."""
    _, area, _ = view3d()
    RESULT['threads_before_leaving'] = sum(s.thread.thread.is_alive() for s in viewport.SESSIONS)
    area.spaces.active.shading.type = 'SOLID'
    RESULT['left_at'] = time.perf_counter()


def sessions_gone():
    import gc
    gc.collect()
    return all(s.closed and not s.thread.thread.is_alive() for s in viewport.SESSIONS)


def record_cleanup():
    RESULT['render_threads_left'] = sum(s.thread.thread.is_alive() for s in viewport.SESSIONS)
    RESULT['cleanup_seconds'] = time.perf_counter() - RESULT['left_at']


STEPS = [
    (setup, None),
    (look_through_camera, None),
    (first_screenshot, lambda: finished(session()) and session().thread.status.endswith(
        '(denoised)') == GALLERY),
    (render_f12, None),
    (move_object, lambda: finished(session())),
    (second_screenshot, lambda: finished(session()) and viewport.STATS['restarts'] > RESULT['restarts_before_move']),
    (leave_rendered, None),
    (record_cleanup, sessions_gone),
]
state = {'index': 0, 'since': time.perf_counter()}


def finish():
    with open(os.path.join(OUT, 'result.json'), 'w', encoding='utf-8') as stream:
        json.dump(RESULT, stream, indent=1, default=str)
    bpy.ops.wm.quit_blender()


def tick():
    try:
        index = state['index']
        if index >= len(STEPS):
            finish()
            return None
        step, ready = STEPS[index]
        if ready is not None and not ready():
            if time.perf_counter() - state['since'] > STEP_TIMEOUT:
                RESULT['errors'].append(f"timed out before {step.__name__}")
                finish()
                return None
            return 0.1
        step()
        RESULT.setdefault('steps', []).append(step.__name__)
        state['index'] += 1
        state['since'] = time.perf_counter()
        return 0.3  # let the window redraw
    except Exception:  # noqa: BLE001 - reported to the test
        RESULT['errors'].append(traceback.format_exc())
        finish()
        return None


bpy.app.timers.register(tick, first_interval=1.0)
