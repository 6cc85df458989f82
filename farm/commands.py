"""Blender command lines for farm tasks.

One task is one Blender process: a Blender binary with the Ember add-on
installed (``blender -b FILE --addons ember -E EMBER ... -f A..B``), or the bpy
module running ``farm/bpy_render.py`` with the same arguments.  What differs
between tasks (samples, threads, EXR output, the shard's sample range) is set
by a ``--python-expr`` that runs after the file is loaded and before the
render, so the same command works on any worker, Flamenco's included.
"""
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BPY_RENDER = os.path.join(ROOT, 'farm', 'bpy_render.py')

# After each render: stop Blender with exit status 1 if Ember recorded an
# error (Blender itself exits 0 and saves a black image).
ERROR_CHECK = """
import sys as _s
def _ember_farm_check(*_args):
    for _name, _mod in list(_s.modules.items()):
        _log = getattr(_mod, 'RENDER_LOG', None) if _name.split('.')[-1] == 'engine' else None
        if _log and _log[-1].get('error'):
            print('EMBER-FARM-ERROR:', _log[-1]['error'], flush=True)
            import os as _o
            _o._exit(1)
bpy.app.handlers.render_post.append(_ember_farm_check)
"""


def setup_code(samples=0, threads=0, shard=None):
    """Python run inside Blender before rendering.  ``shard``: (folder, start, count)."""
    lines = ["import bpy, os",
             "s = bpy.context.scene",
             "s.render.engine = 'EMBER'",
             f"s.ember.threads = {int(threads)}",
             "st = s.render.image_settings",
             "if hasattr(st, 'media_type'): st.media_type = 'IMAGE'",
             "st.file_format = 'OPEN_EXR'",
             "st.color_depth = '32'",
             "s.render.use_file_extension = True"]
    if samples:
        lines.append(f"s.ember.samples = {int(samples)}")
    if shard is not None:
        folder, start, count = shard
        lines += [f"os.environ['EMBER_SHARD_DIR'] = {str(folder)!r}",
                  f"os.environ['EMBER_SHARD_START'] = '{int(start)}'",
                  f"os.environ['EMBER_SHARD_SAMPLES'] = '{int(count)}'"]
    return "\n".join(lines) + "\n" + ERROR_CHECK


def frame_arg(frames):
    """Blender's -f argument: '7', '1..4' or '1,3,9'."""
    frames = list(frames)
    if len(frames) > 1 and frames == list(range(frames[0], frames[-1] + 1)):
        return f"{frames[0]}..{frames[-1]}"
    return ",".join(str(f) for f in frames)


def render_command(job, frames, out_pattern, shard=None):
    """argv of one Blender process rendering ``frames`` to ``out_pattern``
    (with #### for the frame number)."""
    code = setup_code(job.samples, job.threads, shard)
    tail = ['-o', out_pattern, '-F', 'OPEN_EXR', '--python-expr', code, '-f', frame_arg(frames)]
    if job.blender:
        addons = ['--addons', 'ember'] if getattr(job, 'addons', 'ember') else []
        # --addons before the file, so the file's EMBER engine exists when it loads.
        return [job.blender, '-b', *addons, job.blend, '-E', 'EMBER', *tail]
    python = job.python or sys.executable
    return [python, '-P', BPY_RENDER, job.blend, *tail]
