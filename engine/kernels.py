"""Elementwise kernels: one source, run by NumPy or compiled by numba.

A kernel is a plain function of per-ray numbers written with NumPy ufuncs
(``np.sqrt``, ``np.maximum``...) and this module's ``where`` and ``clip``.
Called on arrays it is ordinary vectorized NumPy code (a temporary array per
operation).  With the JIT on, the very same function is compiled by numba
into a generalized ufunc that runs the whole body per element in one loop:
no temporaries, one pass over memory.  A kernel may return one value or a
tuple; the compiled form returns the same.

The compiled loops are serial and release the GIL (NumPy runs ufunc loops
without it), so Ember's own thread pool (engine/render.py) keeps both cores
busy; numba's threading layer is never started (``parallel=True`` makes
Debian's Blender 3.4 crash at exit, see docs/benchmarks.md).

The JIT is on when numba imports, ``EMBER_JIT`` is not ``0`` and the render
asks for it (``RenderSettings.use_jit``, set by ``configure`` before a
render).  Compiled code is cached on disk in ``NUMBA_CACHE_DIR`` (default
``~/.cache/ember/numba``, or under ``XDG_CACHE_HOME``), so only the first
render on a machine pays for compilation.
"""
import hashlib
import inspect
import os
import threading
import time

import numpy as np


def source_hash():
    """Hash of the engine's sources: numba invalidates a cached kernel only
    when its own file changes, not when a helper it inlines (in another
    module) does, so each version of the engine gets its own cache folder."""
    digest = hashlib.sha1()
    folder = os.path.dirname(os.path.abspath(__file__))
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            with open(os.path.join(folder, name), "rb") as handle:
                digest.update(name.encode() + handle.read())
    return digest.hexdigest()[:12]


def cache_dir():
    """NUMBA_CACHE_DIR if set, else ~/.cache/ember/numba (XDG_CACHE_HOME
    respected); one sub-folder per engine version."""
    base = os.environ.get("NUMBA_CACHE_DIR")
    if not base:
        home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        base = os.path.join(home, "ember", "numba")
    return os.path.join(base, source_hash())


def _import_numba():
    if os.environ.get("EMBER_JIT", "1").strip() == "0":
        return None, "EMBER_JIT=0"
    try:
        import numba
    except Exception as exc:  # noqa: BLE001 - any failure means: run NumPy code
        return None, f"numba unavailable: {type(exc).__name__}: {exc}"
    # Read by numba's cache locator whenever a function is cached.
    numba.config.CACHE_DIR = cache_dir()
    return numba, None


_numba, UNAVAILABLE = _import_numba()
AVAILABLE = _numba is not None
_state = {"enabled": AVAILABLE}
_lock = threading.Lock()
compile_seconds = {}


def configure(use_jit):
    """Turn compiled kernels on or off for the renders that follow; returns
    whether they are on (off when numba is unavailable or EMBER_JIT=0)."""
    _state["enabled"] = bool(use_jit) and AVAILABLE
    return _state["enabled"]


def enabled():
    return _state["enabled"]


# ----------------------------------------------------------------------------
# helpers usable in kernels: NumPy on arrays, scalar code when compiled

def where(cond, a, b):
    return np.where(cond, a, b)


def clip(x, lo, hi):
    return np.clip(x, lo, hi)


if AVAILABLE:
    from numba.extending import overload

    @overload(where)
    def _where_scalar(cond, a, b):
        def impl(cond, a, b):
            return a if cond else b
        return impl

    @overload(clip)
    def _clip_scalar(x, lo, hi):
        def impl(x, lo, hi):
            return np.minimum(np.maximum(x, lo), hi)  # NaN propagates, as np.clip
        return impl


def helper(fn):
    """A function kernels call: plain Python for NumPy, inlined when compiled."""
    if AVAILABLE:
        from numba.extending import register_jitable
        return register_jitable(inline="always")(fn)
    return fn


# ----------------------------------------------------------------------------
# kernels

class Kernel:
    """``fn`` called on arrays by NumPy, or its compiled gufunc.

    inputs/outputs: how many per-element float64 values go in and come out.
    Inputs may be arrays of one shape or scalars (broadcast as NumPy does)."""

    def __init__(self, fn, inputs, outputs):
        self.fn = fn
        self.inputs = inputs
        self.outputs = outputs
        self.compiled = None
        self.__name__ = fn.__name__
        self.__doc__ = fn.__doc__

    def __call__(self, *args):
        # Each kernel defines its result where intermediates overflow or are
        # not numbers: no floating-point warnings, run either way.
        if not _state["enabled"]:
            with np.errstate(all="ignore"):
                return self.fn(*args)
        if self.compiled is None:
            self._compile()
        with np.errstate(all="ignore"):
            return self.compiled(*args)

    def _compile(self):
        with _lock:
            if self.compiled is not None:
                return
            t0 = time.perf_counter()
            self.compiled = _gufunc(self.fn, self.inputs, self.outputs)
            compile_seconds[self.__name__] = time.perf_counter() - t0


def _gufunc(fn, inputs, outputs):
    """numba gufunc with scalar core dimensions that stores fn's results."""
    inner = _numba.njit(inline="always", cache=True)(fn)
    ins = [f"a{i}" for i in range(inputs)]
    outs = [f"o{i}" for i in range(outputs)]
    if outputs == 1:
        stores = "    o0[0] = r\n"
    else:
        stores = "".join(f"    o{i}[0] = r[{i}]\n" for i in range(outputs))
    source = f"def {fn.__name__}({', '.join(ins + outs)}):\n    r = inner({', '.join(ins)})\n{stores}"
    namespace = {"inner": inner}
    # Compiled as if from the kernel's own file: numba's disk cache is keyed
    # on that file, so editing a kernel recompiles it.
    exec(compile(source, inspect.getfile(fn), "exec"), namespace)  # noqa: S102
    signature = "void(" + ", ".join(["float64"] * inputs + ["float64[:]"] * outputs) + ")"
    layout = ",".join(["()"] * inputs) + "->" + ",".join(["()"] * outputs)
    wrapper = namespace[fn.__name__]
    wrapper.__module__ = fn.__module__
    wrapper.__qualname__ = fn.__name__ + "_gufunc"
    return _numba.guvectorize([signature], layout, nopython=True, cache=True)(wrapper)


def kernel(inputs, outputs=1):
    """Decorator: an elementwise kernel of ``inputs`` float64 values."""
    def wrap(fn):
        return Kernel(fn, inputs, outputs)
    return wrap


def warm_up(kernels):
    """Compile (or load from the cache) the given kernels now; returns seconds."""
    t0 = time.perf_counter()
    if _state["enabled"]:
        for k in kernels:
            k(*([np.zeros(1)] * k.inputs))
    return time.perf_counter() - t0
