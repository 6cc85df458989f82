"""One way to take rows of a struct of arrays: the integrator's records
and the pass observer's lobe subsets use it (a module of its own, so
that pass_events needs no import of the integrator package)."""
from dataclasses import fields, replace

import numpy as np


def rows_of(keep):
    """Indices of a boolean mask (indices pass through)."""
    keep = np.asarray(keep)
    return np.flatnonzero(keep) if keep.dtype == bool else keep


def take_arrays(record, keep, n=None):
    """``record`` (a dataclass) with the rows ``keep`` of every per-row
    array field taken (fields of another length, and non-arrays, stay);
    ``n``: the row count (every array field counts when None)."""
    idx = rows_of(keep)
    return replace(record, **{f.name: np.take(getattr(record, f.name), idx, axis=0) for f in fields(record)
                              if isinstance(getattr(record, f.name), np.ndarray)
                              and (n is None or len(getattr(record, f.name)) == n)})
