"""Elementwise kernels: one source, run by NumPy or compiled by numba.

A kernel is a plain function of per-ray numbers written with NumPy ufuncs
(``np.sqrt``, ``np.maximum``...), this module's ``where`` and ``clip``, and
functions marked ``@helper``.  Called on arrays it is ordinary vectorized
NumPy code (a temporary array per operation).  With the JIT on, the very same
function is compiled by numba into a generalized ufunc that runs the whole
body per element in one loop: no temporaries, one pass over memory.  A kernel
may return one value or a tuple; the compiled form returns the same.
``@loop_kernel`` is an explicit row loop for work that is not elementwise
arithmetic, next to a NumPy reference form of the same computation.

The two forms are not bit-identical twins: numba calls libm, NumPy may run
its own SIMD transcendentals (AVX-512), so the last bits differ between
CPUs.  tests/engine/test_kernels.py holds them to a tolerance derived from
that rounding.  A render therefore never mixes them: ``for_render`` makes
the choice once per render (compiled, after waiting for the compile with
progress shown and cancel honoured; or NumPy with the JIT off) and the
render records it (``stats["kernels"]``).  A kernel first called while the
JIT is on but not compiled yet waits for the compile instead of running its
NumPy form.

The compiled loops are serial and release the GIL (NumPy runs ufunc loops
without it), so Ember's own thread pool (engine/render.py) keeps the cores
busy; numba's threading layer is never started (``parallel=True`` makes
Debian's Blender 3.4 crash at exit).

``configure(True)`` starts one background thread that imports numba and
compiles every kernel (or loads it from the disk cache): ``make setup`` and
the add-on (when it is enabled) start it early, so the cache is warm before
the first render.  ``python -m engine --compile-kernels`` fills the cache and waits.
The cache is ``NUMBA_CACHE_DIR`` or ``~/.cache/ember/numba`` (XDG_CACHE_HOME
respected), one sub-folder per version of the engine's sources, filled by
one process at a time (``cache_lock``).  The JIT is off with
``RenderSettings.use_jit = False``, with ``EMBER_JIT=0``, or when numba does
not import.
"""
import atexit
import contextlib
import hashlib
import importlib.util
import inspect
import os
import threading
import time

import numpy as np

try:
    import fcntl
    msvcrt = None
except ImportError:   # Windows
    import msvcrt
    fcntl = None


_ENGINE_DIR = os.path.dirname(os.path.abspath(__file__))


def source_hash():
    """Hash of the engine's sources, sub-packages included: numba
    invalidates a cached kernel only when its own file changes, not when a
    helper or a constant it inlines (in another module) does, so each
    version of the engine gets its own cache folder."""
    digest = hashlib.sha1()
    for root, dirs, files in os.walk(_ENGINE_DIR):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(root, name)
                with open(path, "rb") as handle:
                    digest.update(os.path.relpath(path, _ENGINE_DIR).encode() + handle.read())
    return digest.hexdigest()[:12]


def cache_dir():
    base = os.environ.get("NUMBA_CACHE_DIR")
    if not base:
        home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        base = os.path.join(home, "ember", "numba")
    return os.path.join(base, source_hash())


def _unavailable_reason():
    if os.environ.get("EMBER_JIT", "1").strip() == "0":
        return "EMBER_JIT=0"
    if importlib.util.find_spec("numba") is None:
        return "numba is not installed"
    return None


UNAVAILABLE = _unavailable_reason()
AVAILABLE = UNAVAILABLE is None
KERNELS = []      # every Kernel and LoopKernel, in definition order
HELPERS = []      # functions kernels call
compile_seconds = {}
_state = {"enabled": False, "thread": None, "numba": None, "started": None, "finished": None,
          "helpers_registered": 0}
_lock = threading.Lock()


def configure(use_jit):
    """Compiled kernels on or off for the renders that follow; returns
    whether they are on.  Turning them on starts the background compile."""
    _state["enabled"] = bool(use_jit) and AVAILABLE
    if _state["enabled"]:
        _start()
    return _state["enabled"]


def enabled():
    return _state["enabled"]


def wait(timeout=None):
    """Block until every kernel is compiled (or failed); True when all are ready."""
    thread = _state["thread"]
    if thread is not None:
        thread.join(timeout)
    return all(k.compiled is not None for k in KERNELS)


class CompileCancelled(Exception):
    """``for_render`` was told to stop while waiting for the compile."""


def for_render(use_jit, progress=None, poll=0.1):
    """The kernels the next render runs, chosen once for all of it:
    'compiled' (after the background compile finished; ``progress.on_status
    (text, fraction)`` hears how far it is, ``progress.should_stop()`` may
    end the wait with ``CompileCancelled``) or 'numpy' (JIT off, numba
    missing, or its compile failed)."""
    if not configure(use_jit):
        return "numpy"
    while not wait(poll):
        if not _compiling():
            break   # finished, some kernels failed: UNAVAILABLE says why
        if progress is not None:
            on_status = getattr(progress, "on_status", None)
            if on_status is not None:
                done = sum(k.compiled is not None for k in KERNELS)
                on_status(f"Compiling kernels ({done}/{len(KERNELS)})", done / max(len(KERNELS), 1))
            should_stop = getattr(progress, "should_stop", None)
            if should_stop is not None and should_stop():
                raise CompileCancelled("stopped while compiling kernels")
    if all(k.compiled is not None for k in KERNELS):
        return "compiled"
    configure(False)
    return "numpy"


def _compiling():
    thread = _state["thread"]
    return thread is not None and thread.is_alive()


def _wait_for(k):
    """A kernel called with the JIT on before it was compiled (defined by a
    module imported late): compile it rather than run its NumPy form in a
    render that runs compiled."""
    _start()
    wait()
    if k.compiled is None:
        raise RuntimeError(f"kernel {k.__name__} did not compile: {UNAVAILABLE}")
    return k.compiled


def warm_up_seconds():
    """Seconds the background compile took (None while it runs)."""
    if _state["finished"] is None:
        return None
    return _state["finished"] - _state["started"]


# ----------------------------------------------------------------------------
# helpers usable in kernels: NumPy on arrays, scalar code when compiled

def where(cond, a, b):
    return np.where(cond, a, b)


def clip(x, lo, hi):
    return np.clip(x, lo, hi)


def helper(fn):
    """Mark a function kernels call: plain Python for NumPy, inlined when compiled."""
    HELPERS.append(fn)
    return fn


# ----------------------------------------------------------------------------
# kernels

class Kernel:
    """``fn`` called on arrays by NumPy, or its compiled gufunc once ready.

    inputs/outputs: how many per-element float64 values go in and come out.
    Inputs may be arrays of one shape or scalars (broadcast as NumPy does)."""

    def __init__(self, fn, inputs, outputs):
        self.fn = fn
        self.inputs = inputs
        self.outputs = outputs
        self.compiled = None
        self.__name__ = fn.__name__
        self.__doc__ = fn.__doc__
        KERNELS.append(self)

    def __call__(self, *args):
        # Each kernel defines its result where intermediates overflow or are
        # not numbers: no floating-point warnings, run either way.
        fn = self.fn if not _state["enabled"] else (self.compiled or _wait_for(self))
        return _quiet(fn, args)


if hasattr(np, "seterrobj"):
    def _quiet(fn, args):
        """fn(*args) with floating-point warnings off.  NumPy 1.x: its error
        object directly, as np.errstate does under its Python layer (about
        4 us a call there, 0.5 us here; kernels run some 20 times a bounce)."""
        saved = np.geterrobj()
        np.seterrobj([saved[0], 0, None])   # mask 0: every error ignored
        try:
            return fn(*args)
        finally:
            np.seterrobj(saved)
else:
    def _quiet(fn, args):
        """fn(*args) with floating-point warnings off (NumPy 2: errstate is
        a cheap context variable there)."""
        with np.errstate(all="ignore"):
            return fn(*args)


def kernel(inputs, outputs=1):
    """Decorator: an elementwise kernel of ``inputs`` float64 values."""
    def wrap(fn):
        return Kernel(fn, inputs, outputs)
    return wrap


class LoopKernel:
    """An explicit loop over arrays (for work that is not elementwise float
    arithmetic: integer hashing with table lookups), compiled by numba with
    ``signature``, next to the vectorized NumPy reference ``numpy_fn``.
    Both take the same arguments and fill ``out`` (the last argument) with
    the same values within rounding (tests/engine/test_kernels.py).  The
    loop is never run by the interpreter: with the JIT off ``numpy_fn``
    runs."""

    def __init__(self, fn, signature, numpy_fn):
        self.fn = fn
        self.signature = signature
        self.numpy_fn = numpy_fn
        self.compiled = None
        self.__name__ = fn.__name__
        KERNELS.append(self)

    def __call__(self, *args):
        if not _state["enabled"]:
            return self.numpy_fn(*args)
        return (self.compiled or _wait_for(self))(*args)

    def build(self, numba):
        # NumPy's floating-point rules (x / 0 is inf or NaN, no exception).
        return numba.njit(self.signature, nogil=True, cache=True, error_model="numpy")(self.fn)


def loop_kernel(signature, numpy_fn):
    """Decorator: a LoopKernel compiled with ``signature`` (numba's string form)."""
    def wrap(fn):
        return LoopKernel(fn, signature, numpy_fn)
    return wrap


# ----------------------------------------------------------------------------
# compilation (background thread)

def _start():
    """Compile, in one background thread, every kernel not compiled yet.
    Kernels of modules imported later start a new thread at the next
    ``configure`` or at their first call."""
    with _lock:
        thread = _state["thread"]
        if thread is not None and thread.is_alive():
            return   # it picks up kernels defined meanwhile
        if _state.get("stop") or UNAVAILABLE is not None or not _pending():
            return
        if thread is None:
            atexit.register(stop)
        _state["started"], _state["finished"] = time.perf_counter(), None
        thread = threading.Thread(target=_compile_all, name="ember-jit", daemon=True)
        _state["thread"] = thread
        thread.start()


def _pending():
    return [k for k in list(KERNELS) if k.compiled is None]


def stop():
    """Let the compile thread finish its current kernel, start no other,
    and end (renders after this run on NumPy unless every kernel was
    compiled).  Also run at exit: a thread killed inside LLVM could crash
    the exit of a command-line render."""
    _state["stop"] = True
    thread = _state["thread"]
    if thread is not None:
        thread.join()


def _compile_all():
    try:
        numba = _import_numba()
        with cache_lock(cache_dir(), lambda: _state.get("stop")) as locked:
            while locked and not _state.get("stop"):
                todo = _pending()
                if not todo:
                    break
                _register_helpers(numba)
                for k in todo:
                    if _state.get("stop"):
                        break
                    _compile(numba, k)
    except Exception as exc:  # noqa: BLE001 - the NumPy path keeps working
        global UNAVAILABLE
        UNAVAILABLE = f"numba failed: {type(exc).__name__}: {exc}"
    finally:
        _state["finished"] = time.perf_counter()


@contextlib.contextmanager
def cache_lock(folder, give_up=lambda: False, poll=0.1):
    """Hold ``folder``'s lock file while compiling into it.  Two processes
    filling one numba cache at once (two Blenders, farm workers on one
    machine) can leave an index pointing at the other's machine code, and
    the next process to load it crashes (seen: a segfault loading a gufunc).
    The later process waits here, then loads what the first one wrote.
    The lock is this engine copy's: numba files another copy's kernels
    (the add-on vendored into a Blender, a checkout's venvs) apart by
    their source folder, so one copy's compile never waits for another's
    (a Blender 3.4 render waited minutes for the venvs' compiles).
    Yields False when ``give_up()`` turned true while waiting."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, f".lock-{_copy_key()}"), "a+b") as handle:
        while not _try_lock(handle):
            if give_up():
                yield False
                return
            time.sleep(poll)
        try:
            yield True
        finally:
            _unlock(handle)


def _try_lock(handle):
    try:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        else:
            handle.seek(0)
            msvcrt.locking(handle.fileno(), msvcrt.LK_NBLCK, 1)
        return True
    except OSError:
        return False


def _unlock(handle):
    if fcntl is not None:
        fcntl.flock(handle, fcntl.LOCK_UN)
    else:
        handle.seek(0)
        msvcrt.locking(handle.fileno(), msvcrt.LK_UNLCK, 1)


def _compile(numba, k):
    t0 = time.perf_counter()
    if isinstance(k, LoopKernel):
        k.compiled = k.build(numba)   # compiled for its signature at once
    else:
        k.compiled = _gufunc(numba, k.fn, k.inputs, k.outputs)
        with np.errstate(all="ignore"):
            k.compiled(*([np.zeros(1)] * k.inputs))   # load or build the machine code now
    compile_seconds[k.__name__] = time.perf_counter() - t0


def _register_helpers(numba):
    """Make helpers defined since the last call callable from compiled code."""
    from numba.extending import register_jitable
    for fn in HELPERS[_state["helpers_registered"]:]:
        register_jitable(inline="always")(fn)
    _state["helpers_registered"] = len(HELPERS)


def _import_numba():
    if _state["numba"] is not None:
        return _state["numba"]
    import numba
    from numba.extending import overload
    numba.config.CACHE_DIR = cache_dir()   # read by the cache locator when a function is cached

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

    _state["numba"] = numba
    return numba


def _gufunc(numba, fn, inputs, outputs):
    """numba gufunc with scalar core dimensions that stores fn's results."""
    inner = numba.njit(inline="always", cache=True)(fn)
    ins = [f"a{i}" for i in range(inputs)]
    outs = [f"o{i}" for i in range(outputs)]
    if outputs == 1:
        stores = "    o0[0] = r\n"
    else:
        stores = "".join(f"    o{i}[0] = r[{i}]\n" for i in range(outputs))
    source = f"def {fn.__name__}({', '.join(ins + outs)}):\n    r = inner({', '.join(ins)})\n{stores}"
    namespace = {"inner": inner}
    # Compiled as if from the kernel's own file, where numba's cache looks.
    exec(compile(source, inspect.getfile(fn), "exec"), namespace)  # noqa: S102
    signature = "void(" + ", ".join(["float64"] * inputs + ["float64[:]"] * outputs) + ")"
    layout = ",".join(["()"] * inputs) + "->" + ",".join(["()"] * outputs)
    wrapper = namespace[fn.__name__]
    wrapper.__module__ = fn.__module__
    wrapper.__qualname__ = fn.__name__ + "_gufunc"
    return numba.guvectorize([signature], layout, nopython=True, cache=True)(wrapper)


def import_all():
    """Import every engine module, so that every kernel is defined."""
    import importlib
    import pkgutil
    package = __package__ or __name__.rpartition(".")[0]
    for info in pkgutil.walk_packages([_ENGINE_DIR], package + "."):
        if not info.name.endswith("__main__"):
            importlib.import_module(info.name)


def _complete_marker():
    """numba keys its cache by the source files' folder, so a copy of the
    engine elsewhere (the add-on's vendored one) has a cache of its own."""
    return os.path.join(cache_dir(), f".complete-{_copy_key()}")


def _copy_key():
    """This engine copy's name in the shared cache folder (its source folder, hashed)."""
    return hashlib.sha1(_ENGINE_DIR.encode()).hexdigest()[:12]


def cache_complete():
    """True once every kernel of this engine copy is in the disk cache (or
    when there is nothing to compile: the JIT is off or numba missing)."""
    return not AVAILABLE or os.path.exists(_complete_marker())


def warm_cache():
    """Import every engine module, compile all kernels into the disk cache
    and return the seconds it took (``make setup``, the add-on on enable)."""
    import_all()
    t0 = time.perf_counter()
    if not configure(True):
        raise RuntimeError(f"compiled kernels unavailable: {UNAVAILABLE}")
    wait()
    missing = [k.__name__ for k in KERNELS if k.compiled is None]
    if missing:
        raise RuntimeError(f"{len(missing)} kernels did not compile ({UNAVAILABLE}): {', '.join(missing[:5])}")
    with open(_complete_marker(), "w"):
        pass
    return time.perf_counter() - t0

