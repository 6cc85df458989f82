"""Merging shards of one frame into the image of all their samples.

A merge takes exactly one shard per planned sample range (a task retried on
another worker writes the same file again, and duplicates given on the
command line are counted once), refuses shards that belong to another blend
file, Ember version, seed, frame, view layer or render setting, and refuses
ranges that overlap or leave a gap.  The film states are added by the
engine's own ``Film.merge_state``; only then is the image formed and, when
the scene asks for it, denoised (with the merged albedo and normal).  Output
files are written atomically.
"""
import os
import sys

from .shardfile import ShardError, read

# Metadata every shard of one image must share.
SHARED = ('ember_version', 'blend_sha256', 'seed', 'frame', 'layer', 'transparent', 'settings', 'denoise')


def select(metas, plan=None):
    """One shard per sample range: returns the chosen metadata in range order.

    ``plan``: the list of (start, end) ranges the job planned; without it
    the ranges must tile [0, N) exactly."""
    if not metas:
        raise ShardError("no shards to merge")
    first = metas[0]
    chosen = {}
    for meta in metas:
        # A range rendered twice (a retried task, a file given twice) counts once.
        kept = chosen.setdefault((meta['sample_start'], meta['sample_end']), meta)
        _check_same(kept, meta)
    if plan is not None:
        # Shards of other plans (an earlier job with another split) are left out.
        planned = sorted(tuple(r) for r in plan)
        missing = sorted(set(planned) - set(chosen))
        if missing:
            raise ShardError(f"frame {first['frame']}: planned sample ranges {missing} have no shard")
        chosen = {r: chosen[r] for r in planned}
    ranges = sorted(chosen)
    position = 0
    for start, end in ranges:
        if start != position:
            kind = "overlap" if start < position else "gap"
            raise ShardError(f"frame {first['frame']}: sample ranges {kind} at sample {min(start, position)} "
                             f"(ranges {ranges})")
        position = end
    picked = [chosen[r] for r in ranges]
    for meta in picked[1:]:
        _check_same(picked[0], meta)
    return picked


def _check_same(a, b):
    for key in SHARED:
        if a.get(key) != b.get(key):
            raise ShardError(f"{b['path']} and {a['path']} differ in {key}: {b.get(key)!r} vs {a.get(key)!r}")


def film_class():
    from engine.film import Film
    if not hasattr(Film, 'from_state') or not hasattr(Film, 'merge_state'):
        raise ShardError("this Ember engine has no Film.from_state/merge_state: cannot merge shards")
    return Film


def merge_states(states):
    """A Film holding the sum of the given film states."""
    film = film_class().from_state(states[0])
    for state in states[1:]:
        film.merge_state(state)
    return film


def merge_files(paths, plan=None, expect=None):
    """(Film, metadata) of the merged shards.  ``expect``: metadata values the
    job requires (e.g. its blend hash), checked on every shard."""
    loaded = [read(p) for p in dict.fromkeys(os.path.abspath(p) for p in paths)]
    metas = [meta for _, meta in loaded]
    for meta in metas:
        for key, value in (expect or {}).items():
            if value is not None and meta.get(key) != value:
                raise ShardError(f"{meta['path']}: {key} is {meta.get(key)!r}, the job expects {value!r}")
    chosen = select(metas, plan)
    by_path = {meta['path']: state for state, meta in loaded}
    film = merge_states([by_path[meta['path']] for meta in chosen])
    meta = dict(chosen[0])
    meta.update(sample_start=chosen[0]['sample_start'], sample_end=chosen[-1]['sample_end'],
                shards=[m['path'] for m in chosen])
    return film, meta


def write_image(path, image):
    """EXR (linear float RGBA) written beside ``path``, then renamed."""
    from engine.imageio import write_image as write
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    base, ext = os.path.splitext(os.path.basename(path))
    tmp = os.path.join(folder, f".{base}.{os.getpid()}.tmp{ext}")
    write(tmp, image)
    os.replace(tmp, path)
    return path


def denoiser():
    """addon/denoise.py (it imports no bpy), loaded without the add-on package."""
    import importlib.util
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'addon', 'denoise.py')
    spec = importlib.util.spec_from_file_location('ember_farm_denoise', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def final_image(film, meta):
    """The merged image, denoised when the scene asked for it (only here,
    after the merge: a shard's noise is not the frame's)."""
    image = film.image(meta['transparent'])
    if not meta.get('denoise'):
        return image
    try:
        denoise = denoiser()
        rgb = denoise.denoise(image[..., :3], film.aov('albedo'), film.aov('normal'))
    except Exception as err:  # noqa: BLE001 - the noisy frame is still a frame
        print(f"farm: frame {meta['frame']} is not denoised: {err}", file=sys.stderr)
        return image
    image = image.copy()
    image[..., :3] = rgb
    return image


def merge_to_image(paths, out_path, plan=None, expect=None):
    film, meta = merge_files(paths, plan, expect)
    write_image(out_path, final_image(film, meta))
    return meta
