"""Render-farm shards: one sample range of one frame, saved as film sums.

A farm task (farm/ in the repository, or a Flamenco job) asks for a shard
through environment variables, which also works inside a Blender binary
(``--python-expr "import os; os.environ[...] = ..."`` before ``-f N``):

* ``EMBER_SHARD_DIR``: folder for the state files (turns shard mode on);
* ``EMBER_SHARD_START``: first sample index (default 0);
* ``EMBER_SHARD_SAMPLES``: how many sample indices (default: the scene's).

The render then traces sample indices [start, start + samples) of the scene's
seed and writes the film's state (sums, second moments, per-pixel counts and
weights, not averages) to ``<dir>/<shard_name(...)>.npz`` atomically, with the
metadata a merge checks: Ember version, blend-file hash, seed, sample range,
frame, resolution, settings.  Nothing changes for ordinary renders.
"""
import dataclasses
import hashlib
import json
import os
import socket
import time

import bpy
import numpy as np

from .version import VERSION

ENV_DIR = 'EMBER_SHARD_DIR'
ENV_START = 'EMBER_SHARD_START'
ENV_SAMPLES = 'EMBER_SHARD_SAMPLES'
FORMAT = 'ember-shard/1'
# Settings that may differ between shards of one frame without changing
# what a sample index computes.
PER_SHARD = ('samples', 'sample_start', 'threads', 'time_limit', 'max_paths', 'samples_per_pass')

_hash_cache = {}


def shard_name(frame, start, end, layer):
    safe = ''.join(c if c.isalnum() or c in '-_' else '_' for c in layer)
    return f"frame_{frame:06d}.s{start:09d}-{end:09d}.{safe}"


def file_sha256(path):
    """sha256 of a file, cached by (path, size, mtime): a chunk of frames
    hashes its blend once."""
    stat = os.stat(path)
    key = (path, stat.st_size, stat.st_mtime_ns)
    if key not in _hash_cache:
        digest = hashlib.sha256()
        with open(path, 'rb') as handle:
            for block in iter(lambda: handle.read(1 << 20), b''):
                digest.update(block)
        _hash_cache[key] = digest.hexdigest()
    return _hash_cache[key]


def _request(scene, layer):
    """The shard asked for by the environment, or None; reads bpy (main thread)."""
    folder = os.environ.get(ENV_DIR)
    if not folder:
        return None
    try:
        start = int(os.environ.get(ENV_START, '0'))
        samples = int(os.environ.get(ENV_SAMPLES, '0') or scene.ember.samples)
    except ValueError as err:
        raise ValueError(f"{ENV_START} and {ENV_SAMPLES} must be integers: {err}") from None
    if start < 0 or samples < 1:
        raise ValueError(f"bad shard sample range: start {start}, {samples} samples")
    blend = bpy.data.filepath
    if not blend:
        raise ValueError("a render-farm shard needs a saved .blend file")
    return {'folder': folder, 'start': start, 'samples': samples, 'frame': scene.frame_current,
            # Denoising waits for the merge (the film keeps albedo and normal for it).
            'denoise': bool(getattr(scene.ember, 'use_denoising', False)),
            'layer': layer, 'blend_path': blend, 'blend_sha256': file_sha256(blend),
            'ember_version': '.'.join(map(str, VERSION))}


def wrap(render, scene, layer, is_preview=False):
    """``render`` itself, or in shard mode a render function that traces the
    requested sample range and saves the film state afterwards."""
    request = None if is_preview else _request(scene, layer)
    if request is None:
        return render

    def render_shard(ember_scene, settings, progress=None):
        if not hasattr(settings, 'sample_start'):
            raise ValueError("this Ember renderer cannot render sample ranges (no sample_start)")
        settings = dataclasses.replace(settings, sample_start=request['start'],
                                       samples=request['samples'], time_limit=0.0)
        result = render(ember_scene, settings, progress)
        # (Fewer samples than asked are fine when adaptive sampling stopped
        # every pixel: the per-pixel counts say what was traced.)
        if getattr(progress, 'cancelled', False):
            raise RuntimeError(f"shard cancelled after {result.samples} of {request['samples']} samples: "
                               "not saved")
        save_state(request, settings, result.film.state())
        return result
    return render_shard


def save_state(request, settings, state):
    end = request['start'] + request['samples']
    meta = {key: request[key] for key in ('frame', 'layer', 'blend_path', 'blend_sha256', 'ember_version',
                                          'denoise')}
    meta.update(format=FORMAT, seed=settings.seed, sample_start=request['start'], sample_end=end,
                transparent=bool(settings.transparent), host=socket.gethostname(), created=time.time(),
                settings={k: v for k, v in dataclasses.asdict(settings).items() if k not in PER_SHARD})
    name = shard_name(request['frame'], request['start'], end, request['layer'])
    path = os.path.join(request['folder'], name + '.npz')
    arrays = {key: np.asarray(value) for key, value in state.items()}
    arrays['__meta__'] = np.array(json.dumps(meta, sort_keys=True, default=str))
    write_atomic(path, arrays)
    return path


def write_atomic(path, arrays):
    """np.savez into a temporary file beside ``path``, then rename: a reader
    sees the old file or the whole new one, never half of it."""
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    tmp = f"{path}.{socket.gethostname()}.{os.getpid()}.tmp"
    with open(tmp, 'wb') as handle:
        np.savez(handle, **arrays)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
