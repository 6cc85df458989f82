"""glibc malloc tuned for a wavefront's arrays.

Every stage of a bounce allocates its outputs afresh: some hundreds of
arrays of 0.1-30 MB a batch, freed a few stages later.  glibc's defaults
hand each back to the kernel (blocks above the dynamic mmap threshold are
unmapped when freed, the heap's top is trimmed above 128 KB), so the next
allocation of the same size takes fresh zeroed pages, one page fault per
4 KiB written.  Measured (docs/benchmarks.md "Page faults"): a Cornell
batch of 65,536 paths on one thread 0.20 -> 0.17 CPU-s; a 256x256 x 8 spp
render on two threads faults 270 pages instead of 47,600 (CPU -6 %).

Only blocks below 32 MB stay in the process: a film of a large render
(hundreds of MB) is still mapped and unmapped by itself, and what is kept
is reused by the next batch's arrays, so the peak resident memory does not
grow (a 7680x4320 1-spp render: 4721 -> 4113 MiB, less fragmentation).  Where malloc is not
glibc's (Blender's own builds link jemalloc; macOS, Windows), nothing
changes: ``tune`` returns False.
"""
import ctypes
import ctypes.util
import threading

# mallopt parameters (glibc malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3

MMAP_THRESHOLD = 32 << 20    # glibc's largest (DEFAULT_MMAP_THRESHOLD_MAX on 64-bit)
TRIM_THRESHOLD = 512 << 20

_state = {"tuned": None}
_lock = threading.Lock()


def _mallopt():
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.mallopt
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return fn


def tune():
    """Keep blocks below MMAP_THRESHOLD in glibc's heap and trim its top only
    above TRIM_THRESHOLD, once per process; True where glibc accepted both."""
    with _lock:
        if _state["tuned"] is None:
            fn = _mallopt()
            _state["tuned"] = bool(fn is not None and fn(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                                   and fn(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1)
        return _state["tuned"]
