"""One way to take rows of a struct of arrays: the integrator's records
and the pass observer's lobe subsets use it (a module of its own, so
that pass_events needs no import of the integrator package)."""
from dataclasses import fields, replace

import numpy as np


def rows_of(keep):
    """Indices of a boolean mask (indices pass through)."""
    keep = np.asarray(keep)
    return np.flatnonzero(keep) if keep.dtype == bool else keep


def take_rows(a, idx):
    """np.take(a, idx, axis=0), but an array with no columns ((N, 0): the
    state of a feature the scene does not use) is made empty: NumPy's take
    of one costs as much as of an (N, 3) array."""
    if a.ndim > 1 and 0 in a.shape[1:]:
        return np.empty((len(idx),) + a.shape[1:], a.dtype)
    return np.take(a, idx, axis=0)


def take_arrays(record, keep, n=None):
    """``record`` (a dataclass) with the rows ``keep`` of every per-row
    array field taken (fields of another length, and non-arrays, stay);
    ``n``: the row count (every array field counts when None)."""
    idx = rows_of(keep)
    return replace(record, **{f.name: take_rows(getattr(record, f.name), idx) for f in fields(record)
                              if isinstance(getattr(record, f.name), np.ndarray)
                              and (n is None or len(getattr(record, f.name)) == n)})
