"""Reading the film-state files that the add-on writes (addon/shards.py):
an .npz of NumPy arrays plus a JSON ``__meta__`` entry."""
import glob
import json
import os

import numpy as np

FORMAT = 'ember-shard/1'


class ShardError(ValueError):
    """A shard cannot be used; the message says why."""


def read(path):
    """(state dict, metadata dict) of one shard file."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError) as err:
        raise ShardError(f"{path}: not a readable shard ({err})") from None
    if '__meta__' not in arrays:
        raise ShardError(f"{path}: no metadata (not written by Ember's shard hook)")
    meta = json.loads(str(arrays.pop('__meta__')))
    if meta.get('format') != FORMAT:
        raise ShardError(f"{path}: format {meta.get('format')!r}, expected {FORMAT!r}")
    meta['path'] = path
    return arrays, meta


def read_meta(path):
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data['__meta__']))


def find(folder, frame, start, end):
    """Shard files of one frame and sample range (one per view layer)."""
    pattern = os.path.join(folder, f"frame_{frame:06d}.s{start:09d}-{end:09d}.*.npz")
    return sorted(glob.glob(pattern))


def write_atomic(path, arrays, meta):
    """Same layout as the add-on writes (used for merged states and tests)."""
    tmp = f"{path}.{os.getpid()}.tmp"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(tmp, 'wb') as handle:
        np.savez(handle, __meta__=np.array(json.dumps(meta, sort_keys=True, default=str)), **arrays)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)
