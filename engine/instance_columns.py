"""The scene's instances as columns, read once per render preparation.

A million instances (geometry nodes, particles) made every consumer of
``scene.instances`` (validation, flattening, the shading context, passes,
holdout, shadow catchers, motion) loop over them in Python, each reading its
own few fields: about 9 s of a render's start.  ``columns(scene)`` reads every
field the preparation needs in one pass (``operator.attrgetter`` does the
reading in C) and turns them into arrays; ``prepared()`` keeps them for
the duration of one ``engine.render.prepare`` so that every stage shares one
read of each list.  Values of the wrong type read as the defaults (an
instance's own validation names it).  Outside a preparation, ``columns`` reads afresh (scenes may be edited
between renders).
"""
import operator
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Optional

import numpy as np

# Read in this order by one attrgetter; an item lacking one (a duck-typed
# row) is read field by field with the Instance defaults below.
FIELDS = ("mesh", "matrix", "materials", "color", "pass_index", "random", "holdout", "shadow_catcher",
          "motion", "visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
          "visible_shadow")
DEFAULTS = {"materials": (), "color": (1.0, 1.0, 1.0), "pass_index": 0, "random": 0.0, "holdout": False,
            "shadow_catcher": False, "motion": None, "visible_camera": True, "visible_diffuse": True,
            "visible_glossy": True, "visible_transmission": True, "visible_shadow": True}
_VISIBILITY_BITS = (1, 2, 4, 8, 16)   # geometry.VIS_CAMERA .. VIS_SHADOW, in FIELDS' order


@dataclass
class InstanceColumns:
    """mesh (N,) int64; matrix (N, 4, 4) float64, or None when some matrix
    is not a 4x4 of numbers (validation finds which); slot_sets: the distinct
    material-slot tuples, slot_set (N,) int64 each instance's; color (N, 3);
    pass_index, random (N,) float64; holdout, shadow_catcher, moving (N,)
    bool; visibility (N,) uint8 VIS_* bits."""
    mesh: np.ndarray
    matrix: Optional[np.ndarray]
    slot_sets: list
    slot_set: np.ndarray
    color: np.ndarray
    pass_index: np.ndarray
    random: np.ndarray
    holdout: np.ndarray
    shadow_catcher: np.ndarray
    moving: np.ndarray
    visibility: np.ndarray

    def __len__(self):
        return len(self.mesh)


def _rows(instances):
    read = operator.attrgetter(*FIELDS)
    try:
        return [read(inst) for inst in instances]
    except AttributeError:
        return [tuple(getattr(inst, name, DEFAULTS.get(name)) for name in FIELDS) for inst in instances]


def _matrices(values):
    try:
        matrices = np.array(values, dtype=np.float64)
    except (ValueError, TypeError):
        return None
    return matrices if matrices.shape == (len(values), 4, 4) else None


def read(instances):
    """InstanceColumns of a sequence of Instances, in one pass over them
    (an engine.instance_batch.InstanceBatch gives its own, from arrays)."""
    if hasattr(instances, "columns"):
        return instances.columns()
    n = len(instances)
    if n == 0:
        cols = [()] * len(FIELDS)
    else:
        cols = list(zip(*_rows(instances)))
    (mesh, matrix, materials, color, pass_index, random, holdout, catcher, motion, *visible) = cols
    interned = {}
    slot_set = np.fromiter((interned.setdefault(tuple(m), len(interned)) for m in materials), np.int64, n)
    visibility = np.zeros(n, np.uint8)
    for bit, column in zip(_VISIBILITY_BITS, visible):
        visibility |= np.fromiter(map(bool, column), bool, n).astype(np.uint8) * np.uint8(bit)
    return InstanceColumns(
        mesh=_numbers(mesh, np.int64, -1), matrix=_matrices(matrix) if n else np.zeros((0, 4, 4)),
        slot_sets=list(interned), slot_set=slot_set, color=_colors(color, n),
        pass_index=_numbers(pass_index, np.float64, 0.0), random=_numbers(random, np.float64, 0.0),
        holdout=np.fromiter(map(bool, holdout), bool, n), shadow_catcher=np.fromiter(map(bool, catcher), bool, n),
        moving=np.fromiter((m is not None for m in motion), bool, n), visibility=visibility)


def _numbers(values, dtype, fallback):
    """(N,) of ``dtype``; what is no finite number reads as ``fallback``."""
    try:
        out = np.array(values, dtype=dtype).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        out = np.array([_number(v, dtype, fallback) for v in values], dtype=dtype).reshape(-1)
    if len(out) != len(values):
        out = np.array([_number(v, dtype, fallback) for v in values], dtype=dtype).reshape(-1)
    if out.dtype.kind == "f":
        out[~np.isfinite(out)] = fallback   # None reads as NaN
    return out


def _number(value, dtype, fallback):
    try:
        if dtype is np.int64 and int(value) != value:
            return fallback
        return dtype(value)
    except (TypeError, ValueError, OverflowError):
        return fallback


def _colors(values, n):
    """(N, 3) float64 from tuples shared by many instances (each distinct one converted once)."""
    seen, rgb = {}, []

    def number(value):
        key = value if isinstance(value, tuple) else id(value)
        k = seen.get(key)
        if k is None:
            k = seen[key] = len(rgb)
            rgb.append(_rgb_key(value))
        return k
    index = np.fromiter(map(number, values), np.int64, n)
    return np.array(rgb, dtype=np.float64).reshape(-1, 3)[index] if n else np.zeros((0, 3))


def _rgb_key(value):
    try:
        rgb = tuple(float(v) for v in tuple(value)[:3])
    except (TypeError, ValueError):
        return (1.0, 1.0, 1.0)
    return rgb if len(rgb) == 3 else (1.0, 1.0, 1.0)


_active = threading.local()


def columns(instances):
    """The InstanceColumns of a scene's instance list: the preparation's
    shared read when one is active for this very list, else a fresh one."""
    kept = getattr(_active, "entries", None)
    if kept is not None:
        entry = kept.get(id(instances))
        if entry is not None and entry[0] is instances and len(instances) == entry[2]:
            return entry[1]
        cols = read(instances)
        kept[id(instances)] = (instances, cols, len(instances))   # holds the list: its id stays unique
        return cols
    return read(instances)


@contextmanager
def prepared():
    """Within this block (one render preparation, on this thread) each
    instance list is read once."""
    outer = getattr(_active, "entries", None)
    _active.entries = {} if outer is None else outer
    try:
        yield
    finally:
        if outer is None:
            _active.entries = None
