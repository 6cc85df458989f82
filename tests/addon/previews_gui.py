"""Renders material, world and light previews with Ember in a real Blender
with a window (Xvfb): Blender 3.4's background mode crashes in any preview
render (Cycles too), its window does not.

    blender --factory-startup -p 0 0 W H -P tests/addon/previews_gui.py -- OUT SITE

Registers the add-on from this repository (SITE holds the wheels the renderer
needs), asks Blender for the previews as the interface does (a preview job per
data-block, ``ed.lib_id_generate_preview``), waits for the jobs, and writes
what it measured to OUT/result.json; tests/addon/test_previews_34.py judges.
Every step runs in a bpy.app.timers callback: the jobs run in the event loop.
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

from addon import engine as ember_engine  # noqa: E402
from preview_scene import preview_datablocks  # noqa: E402

OUT = gui_session.OUT
gui_session.register()
RESULT = {'errors': [], 'version': bpy.app.version_string}
TIMEOUT = float(os.environ.get('EMBER_STEP_TIMEOUT', '100'))
state = {'started': time.perf_counter()}


def start():
    try:
        scene = bpy.context.scene
        scene.render.engine = 'EMBER'
        state['previews'] = preview_datablocks(scene)
        del ember_engine.RENDER_LOG[:]
        state['queue'] = list(state['previews'].values())
        request()
        bpy.app.timers.register(wait, first_interval=0.2)
    except Exception:  # noqa: BLE001 - recorded for the test
        RESULT['errors'].append(traceback.format_exc())
        finish()


def request():
    """One preview job at a time: a new one cancels the one running.  While
    Blender draws or ends the last job the operator refuses ("can't modify
    blend data in this state"): then it is asked again at the next tick."""
    window = bpy.context.window_manager.windows[0]
    try:
        with bpy.context.temp_override(window=window, screen=window.screen, id=state['queue'][0]):
            bpy.ops.ed.lib_id_generate_preview()
    except RuntimeError as exc:
        if "can't modify blend data in this state" not in str(exc):
            raise
        state['asked'] = False
        return
    state['asked'] = True


def pixels(datablock):
    preview = datablock.preview
    if preview is None or preview.image_size[0] == 0:
        return None
    return np.array(preview.image_pixels_float[:], np.float32).reshape(-1, 4)


def wait():
    try:
        if not state.get('asked') and time.perf_counter() - state['started'] <= TIMEOUT:
            request()
            return 0.1
        image = pixels(state['queue'][0])
        if image is not None and image[:, :3].max() > 0 and not bpy.app.is_job_running('RENDER_PREVIEW'):
            state['queue'].pop(0)
            if not state['queue']:
                record()
                finish()
                return None
            request()
        elif time.perf_counter() - state['started'] > TIMEOUT:
            RESULT['errors'].append(f"previews not rendered after {TIMEOUT} s")
            record()
            finish()
            return None
        return 0.1
    except Exception:  # noqa: BLE001 - recorded for the test
        RESULT['errors'].append(traceback.format_exc())
        finish()
        return None


def record():
    for kind, datablock in state['previews'].items():
        image = pixels(datablock)
        RESULT[kind] = None if image is None else {
            'size': list(datablock.preview.image_size), 'finite': bool(np.isfinite(image).all()),
            'max': float(image[:, :3].max()),
            'reddish': float(np.mean(image[:, 0] > 2 * image[:, 1] + 0.02))}
    RESULT['renders'] = [{key: info.get(key) for key in ('preview', 'error', 'seconds', 'triangles', 'cancelled', 'samples', 'traceback')}
                         for info in ember_engine.RENDER_LOG]
    RESULT['seconds'] = time.perf_counter() - state['started']


def finish():
    with open(os.path.join(OUT, 'result.json'), 'w', encoding='utf-8') as stream:
        json.dump(RESULT, stream, indent=1, default=str)
    try:
        bpy.ops.wm.quit_blender()
    except RuntimeError:   # "can't modify blend data in this state": a job still runs
        sys.stdout.flush()
        os._exit(0)


bpy.app.timers.register(start, first_interval=0.3)
