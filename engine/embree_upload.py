"""Triangle buffers into an embreex scene at memory speed.

embreex's ``TriangleMesh`` copies vertices and indices into Embree's buffers
with a loop that indexes the NumPy arrays at Python level: about 0.6 us per
vertex and 0.8 us per triangle (2.4 s for the 2.1 M instanced triangles of
the bench's 'instanced' scene; 4 s for the same triangles as a corner soup).
Embree itself takes the buffers as plain memory, so this module calls
libembree4 through ctypes with the scene embreex created, and copies each
buffer with one memmove.

That needs the scene's RTCScene handle, which embreex keeps in a C field of
its EmbreeScene object (``cdef RTCScene scene_i`` in rtcore_scene.pxd,
declared before ``is_committed`` and ``device``).  The field's address is
checked before use: the object's size must be the one that declaration
gives, ``is_committed`` (public) must read back at the address after it, the
``device`` field must hold the very EmbreeDevice object passed in, and
Embree must name that device as the scene's.  If any check fails (another
embreex layout, another platform, no libembree4 found), ``upload`` returns
False and the caller uses embreex's own loop: slower, never wrong.
"""
import ctypes
import os
import sys

import numpy as np

RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_BUFFER_TYPE_INDEX = 0
RTC_BUFFER_TYPE_VERTEX = 1
RTC_FORMAT_UINT3 = 0x5003
RTC_FORMAT_FLOAT3 = 0x9003

_PTR = ctypes.sizeof(ctypes.c_void_p)
_HEAD = 2 * _PTR                       # PyObject_HEAD: refcount, type
_SCENE_AT = _HEAD                      # cdef RTCScene scene_i
_COMMITTED_AT = _HEAD + _PTR           # cdef public int is_committed
_DEVICE_AT = _HEAD + 2 * _PTR          # cdef EmbreeDevice device (after padding)
_SCENE_SIZE = _HEAD + 3 * _PTR
_DEVICE_HANDLE_AT = _HEAD              # EmbreeDevice: cdef RTCDevice device
_MAGIC = 0x5A17C0DE

_state = {"lib": None, "reason": "embreex not loaded yet"}


def _loaded_embree():
    """The libembree4 embreex's extensions loaded (the same instance: its
    scenes and devices are only valid there), or None.  bpy loads its own
    libembree4 too: the one inside embreex's install wins."""
    embreex = sys.modules.get("embreex")
    if embreex is None or not sys.platform.startswith("linux"):
        return None
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps
                     if "libembree4" in line and "/" in line}
    except OSError:
        return None
    # A wheel's copy sits in embreex.libs (or embreex/.libs) next to the package.
    site = os.path.dirname(os.path.dirname(os.path.realpath(embreex.__file__)))
    own = {p for p in paths if p.startswith(os.path.join(site, "embreex"))}
    if len(own) != 1 and len(paths) != 1:
        return None
    try:
        # RTLD_NOLOAD: only a library already in the process, never a new copy.
        return ctypes.CDLL((own or paths).pop(), mode=os.RTLD_NOW | os.RTLD_NOLOAD)
    except OSError:
        return None


def _declare(lib):
    vp, size = ctypes.c_void_p, ctypes.c_size_t
    lib.rtcNewGeometry.restype, lib.rtcNewGeometry.argtypes = vp, [vp, ctypes.c_int]
    lib.rtcSetNewGeometryBuffer.restype = vp
    lib.rtcSetNewGeometryBuffer.argtypes = [vp, ctypes.c_int, ctypes.c_uint, ctypes.c_int, size, size]
    lib.rtcCommitGeometry.restype, lib.rtcCommitGeometry.argtypes = None, [vp]
    lib.rtcAttachGeometry.restype, lib.rtcAttachGeometry.argtypes = ctypes.c_uint, [vp, vp]
    lib.rtcReleaseGeometry.restype, lib.rtcReleaseGeometry.argtypes = None, [vp]
    lib.rtcGetSceneDevice.restype, lib.rtcGetSceneDevice.argtypes = vp, [vp]
    lib.rtcReleaseDevice.restype, lib.rtcReleaseDevice.argtypes = None, [vp]
    lib.rtcGetDeviceError.restype, lib.rtcGetDeviceError.argtypes = ctypes.c_int, [vp]
    return lib


def _library():
    if _state["lib"] is None:   # until found (embreex may load later)
        lib = _loaded_embree()
        if lib is None:
            _state["reason"] = "libembree4 not found among the loaded libraries"
        else:
            try:
                _state["lib"] = _declare(lib)
                _state["reason"] = "ok"
            except AttributeError as exc:
                _state["reason"] = f"libembree4 lacks {exc}"
    return _state["lib"]


def _read_pointer(address):
    return ctypes.c_void_p.from_address(address).value


def scene_handle(scene, device, lib):
    """The RTCScene of an embreex EmbreeScene created with ``device``, or
    None if its memory layout is not the one this module knows."""
    if type(scene).__basicsize__ != _SCENE_SIZE or type(device).__basicsize__ != _HEAD + _PTR:
        return None
    base = id(scene)
    if _read_pointer(base + _DEVICE_AT) != id(device):
        return None
    committed = scene.is_committed
    try:
        scene.is_committed = _MAGIC
        same = ctypes.c_int.from_address(base + _COMMITTED_AT).value == _MAGIC
    finally:
        scene.is_committed = committed
    if not same:
        return None
    handle = _read_pointer(base + _SCENE_AT)
    device_handle = _read_pointer(id(device) + _DEVICE_HANDLE_AT)
    if not handle or not device_handle:
        return None
    # Both fields check out; Embree confirms the scene belongs to the device.
    owner = lib.rtcGetSceneDevice(handle)
    if owner:
        lib.rtcReleaseDevice(owner)  # rtcGetSceneDevice added a reference
    return handle if owner == device_handle else None


def upload(scene, device, vertices, indices):
    """Add one triangle geometry (``vertices`` (V, 3) float32, ``indices``
    (T, 3) int32 into them; primID = row of ``indices``) to an uncommitted
    embreex scene.  False if this module cannot (the caller falls back)."""
    lib = _library()
    if lib is None:
        return False
    handle = scene_handle(scene, device, lib)
    if handle is None:
        _state["reason"] = "unknown embreex EmbreeScene layout"
        return False
    device_handle = _read_pointer(id(device) + _DEVICE_HANDLE_AT)
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    indices = np.ascontiguousarray(indices, dtype=np.uint32)
    geom = lib.rtcNewGeometry(device_handle, RTC_GEOMETRY_TYPE_TRIANGLE)
    if not geom:
        raise MemoryError(f"Embree could not create a geometry (error {lib.rtcGetDeviceError(device_handle)})")
    try:
        _fill(lib, geom, RTC_BUFFER_TYPE_VERTEX, RTC_FORMAT_FLOAT3, vertices, device_handle)
        _fill(lib, geom, RTC_BUFFER_TYPE_INDEX, RTC_FORMAT_UINT3, indices, device_handle)
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(handle, geom)
    finally:
        lib.rtcReleaseGeometry(geom)  # the scene holds its own reference
    error = lib.rtcGetDeviceError(device_handle)
    if error:
        raise RuntimeError(f"Embree failed to take the triangles (error {error})")
    return True


def _fill(lib, geom, kind, fmt, array, device_handle):
    """A new Embree buffer of len(array) rows of 12 bytes, filled from array."""
    buffer = lib.rtcSetNewGeometryBuffer(geom, kind, 0, fmt, 12, len(array))
    if not buffer:
        raise MemoryError(f"Embree could not allocate a buffer of {len(array)} rows "
                          f"(error {lib.rtcGetDeviceError(device_handle)})")
    ctypes.memmove(buffer, array.ctypes.data, array.nbytes)


def unavailable_reason():
    """Why ``upload`` falls back, or 'ok'."""
    _library()
    return _state["reason"]
