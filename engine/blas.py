"""One BLAS thread while Ember renders.

NumPy's OpenBLAS starts a thread per core for any matrix product, even a
(N, 3) x (3,) one, and those threads busy-wait for more work after each call:
a single-threaded render measured 1.0 s of CPU per 0.5 s of wall, and with
Ember's own two batch threads the spinning BLAS threads took about a sixth
of the machine (tools/bench_engine.py: +18 % paths/s with one BLAS thread).
Ember's products are all tiny, so BLAS threads never help it.

threadpoolctl finds whichever BLAS NumPy loaded (OpenBLAS, MKL, BLIS,
FlexiBLAS, on Linux, macOS and Windows) and sets its thread count; the
original count comes back when the last concurrent render ends.  Without
threadpoolctl renders still work, only slower.
"""
import threading

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # optional: speed only
    threadpool_limits = None

_lock = threading.Lock()
_state = {"depth": 0, "limits": None}


class single_threaded_blas:
    """Context manager, re-entrant and safe across threads (the viewport
    and F12 may render at once): the first to enter limits BLAS to one
    thread, the last to leave restores it."""

    def __enter__(self):
        with _lock:
            _state["depth"] += 1
            if _state["depth"] == 1 and threadpool_limits is not None:
                _state["limits"] = threadpool_limits(limits=1, user_api="blas")
        return self

    def __exit__(self, *exc):
        with _lock:
            _state["depth"] -= 1
            if _state["depth"] == 0 and _state["limits"] is not None:
                _state["limits"].restore_original_limits()
                _state["limits"] = None
        return False
