"""Embree 4's C API through ctypes, for what embreex does not wrap (ray time).

embreex 4.4 builds triangle scenes and traces rays with ``time = 0``.  The
library it bundles (``embreex.libs/libembree4*.so``) has the rest: geometry
time steps (motion blur), curves, points, instances.  This module calls that
very library (found among the loaded ones by ``engine.embree_upload``, never
a second copy) through ctypes: a device and a scene of its own, triangle
geometries with ``rtcSetGeometryTimeStepCount`` (one vertex buffer per time
step; Embree interpolates linearly between steps at each ray's time) and
queries by ``rtcIntersect1`` / ``rtcOccluded1``.

The per-ray loops are cached numba kernels (``_intersect_rays``,
``_occluded_rays``: nopython, nogil, so threads trace in parallel as with
embreex) calling rtcIntersect1 / rtcOccluded1 by address (``rtc_call``);
with the JIT off the same queries go through ``rtcIntersect16`` /
``rtcOccluded16`` packets filled by NumPy, one ctypes call per 16 rays.

Struct layouts (Embree 4's ``rtcore_ray.h``): ``RTCRay`` is 12 four-byte
words (org xyz, tnear, dir xyz, time, tfar, mask, id, flags; 48 bytes, 16
aligned), ``RTCHit`` follows it (Ng xyz, u, v, primID, geomID, instID[1],
and instPrimID[1] in builds with instance arrays, as 4.4's), so one
``RTCRayHit`` is given 96 bytes.  The packet ``RTCRayHit16`` is the same
words 16 wide: 12 x 16 ray words, then 8 (or 9) x 16 hit words; 21 x 16
are reserved.  The ``RTCIntersectArguments`` pointer is NULL (Embree's
defaults: the same as embreex's).
"""
import ctypes
import threading

import numpy as np

from . import embree_upload, kernels

RTC_GEOMETRY_TYPE_TRIANGLE = 0
RTC_GEOMETRY_TYPE_INSTANCE = 121
RTC_GEOMETRY_TYPE_SPHERE_POINT = 50
RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE = 16     # Cycles' linear 3D curves
RTC_GEOMETRY_TYPE_ROUND_CATMULL_ROM_CURVE = 58
RTC_GEOMETRY_TYPE_FLAT_CATMULL_ROM_CURVE = 59   # Cycles' ribbons
RTC_FORMAT_UINT = 0x5001
RTC_FORMAT_FLOAT4 = 0x9004
RTC_BUFFER_TYPE_INDEX = 0
RTC_BUFFER_TYPE_VERTEX = 1
RTC_FORMAT_UINT3 = 0x5003
RTC_FORMAT_FLOAT3 = 0x9003
INVALID_ID = 0xFFFFFFFF

RAYHIT_WORDS = 24            # 96 bytes per RTCRayHit
PACKET = 16
PACKET_WORDS = 21 * PACKET   # RTCRayHit16 with room for instPrimID
# word offsets inside RTCRayHit (one ray) and RTCRayHit16 (times 16)
ORG, TNEAR, DIR, TIME, TFAR, MASK, ID, FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
HIT_U, HIT_V, HIT_PRIM, HIT_GEOM, HIT_INST = 15, 16, 17, 18, 19

_state = {"lib": None}
_lock = threading.Lock()


def library():
    """libembree4 as embreex loaded it, with the functions this module calls
    declared; None when it is not to be found (embreex not importable)."""
    if _state["lib"] is not None:
        return _state["lib"]
    from .accel import _import_embreex   # loads embreex and its libembree4 (DEEPBIND, see accel)
    _import_embreex()
    lib = embree_upload._loaded_embree()
    if lib is None:
        return None
    vp, u32, size = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
    for name, res, args in (
            ("rtcNewDevice", vp, [ctypes.c_char_p]),
            ("rtcReleaseDevice", None, [vp]),
            ("rtcGetDeviceError", ctypes.c_int, [vp]),
            ("rtcNewScene", vp, [vp]),
            ("rtcReleaseScene", None, [vp]),
            ("rtcCommitScene", None, [vp]),
            ("rtcNewGeometry", vp, [vp, ctypes.c_int]),
            ("rtcReleaseGeometry", None, [vp]),
            ("rtcCommitGeometry", None, [vp]),
            ("rtcAttachGeometry", u32, [vp, vp]),
            ("rtcSetGeometryTimeStepCount", None, [vp, u32]),
            ("rtcSetNewGeometryBuffer", vp, [vp, ctypes.c_int, u32, ctypes.c_int, size, size]),
            ("rtcSetGeometryInstancedScene", None, [vp, vp]),
            ("rtcSetGeometryTessellationRate", None, [vp, ctypes.c_float]),
            ("rtcSetGeometryTransformQuaternion", None, [vp, u32, vp]),
            ("rtcIntersect16", None, [vp, vp, vp, vp]),
            ("rtcOccluded16", None, [vp, vp, vp, vp])):
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    _state["lib"] = lib
    return lib


def available():
    return library() is not None


def _compiled_loops():
    """(intersect, occluded): the compiled loops over rays calling
    rtcIntersect1 / rtcOccluded1 (``_intersect_rays``, ``_occluded_rays``,
    ordinary cached kernels through ``rtc_call``), or None with the JIT off
    (the render's choice: NumPy forms throughout)."""
    if not kernels.enabled():
        return None
    try:
        return tuple(k.compiled or kernels._wait_for(k) for k in (_intersect_rays, _occluded_rays))
    except RuntimeError:   # numba missing or failing: the packets serve
        return None


class TriangleScene:
    """An Embree scene of triangle geometries, each with one or more time
    steps.  ``parts``: a list of (vertices (S, V, 3), indices (T, 3), prims
    (T,)) where ``prims`` are the global triangle indices queries return for
    the part's triangles; S = 1 is a static part.  ``instances``: a list of
    (vertices, indices, prims, transforms) whose triangles (object space,
    S' steps) sit in a scene of their own that an instance geometry places
    with ``transforms`` (S'', 16) float32 ``RTCQuaternionDecomposition``
    rows (scale xyz, skew xy xz yz, shift xyz, quaternion r i j k,
    translation xyz), interpolated by Embree: quaternions by slerp, the
    rest linearly (Cycles' transform motion).  Time is in [0, 1] over the
    steps (step k at k / (S - 1)), Embree's default time range.  ``spheres``:
    (centres and radii (N, 4), prims) for one RTC_GEOMETRY_TYPE_SPHERE_POINT
    geometry, or None.  ``curves``: (control points and radii (V, 4), the
    first control point of each segment (S,), prims (S,), tessellation
    rate[, geometry type]) for one RTC_GEOMETRY_TYPE_ROUND_CATMULL_ROM_CURVE
    geometry (as Cycles' 3D curves; or the type given:
    RTC_GEOMETRY_TYPE_FLAT_CATMULL_ROM_CURVE for its ribbons,
    RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE for its linear curves: each start
    is then the segment's first key, rate None), or None.  ``moving``: moving points or curves, a
    list of (kind, control points (S, K, 4) object space per time step,
    each segment's first control point (P,) or None for points, prims (P,),
    tessellation rate or None, transforms (S'', 16)): each one geometry
    of S time steps in a scene of its own, placed as ``instances``."""

    def __init__(self, parts, instances=(), spheres=None, curves=None, moving=()):
        lib = library()
        if lib is None:
            raise RuntimeError("libembree4 (bundled with embreex) is not available")
        self.lib = lib
        self.device = lib.rtcNewDevice(None)
        if not self.device:
            raise RuntimeError("Embree could not create a device")
        self.scene = lib.rtcNewScene(self.device)
        self.children = []
        offsets, order = [], []
        first = 0
        self.nbytes = 0
        for geom_id, (vertices, indices, prims) in enumerate(parts):
            vertices = np.ascontiguousarray(vertices, np.float32)
            indices = np.ascontiguousarray(indices, np.uint32)
            self._add(vertices, indices, geom_id)
            offsets.append(first)
            order.append(np.asarray(prims, np.int64))
            first += len(indices)
            self.nbytes += vertices.nbytes + indices.nbytes
        for geom_id, (vertices, indices, prims, transforms) in enumerate(instances, start=len(parts)):
            vertices = np.ascontiguousarray(vertices, np.float32)
            indices = np.ascontiguousarray(indices, np.uint32)
            child = lib.rtcNewScene(self.device)
            self.children.append(child)
            self._add(vertices, indices, 0, scene=child)
            lib.rtcCommitScene(child)
            self._instance(child, np.ascontiguousarray(transforms, np.float32), geom_id)
            offsets.append(first)
            order.append(np.asarray(prims, np.int64))
            first += len(indices)
            self.nbytes += vertices.nbytes + indices.nbytes
        if spheres is not None:   # (x, y, z, r) rows
            xyzr, prims = spheres
            buffers = [(RTC_BUFFER_TYPE_VERTEX, RTC_FORMAT_FLOAT4, 16, np.ascontiguousarray(xyzr, np.float32))]
            first = self._primitives(RTC_GEOMETRY_TYPE_SPHERE_POINT, buffers, prims, None, offsets, order, first)
        if curves is not None:    # control points (x, y, z, r) and each segment's first one
            xyzr, starts, prims, rate, *kind = curves
            buffers = [(RTC_BUFFER_TYPE_VERTEX, RTC_FORMAT_FLOAT4, 16, np.ascontiguousarray(xyzr, np.float32)),
                       (RTC_BUFFER_TYPE_INDEX, RTC_FORMAT_UINT, 4, np.ascontiguousarray(starts, np.uint32))]
            first = self._primitives(kind[0] if kind else RTC_GEOMETRY_TYPE_ROUND_CATMULL_ROM_CURVE, buffers, prims,
                                     rate, offsets, order, first)
        for kind, steps, starts, prims, rate, transforms in moving:
            child = lib.rtcNewScene(self.device)
            self.children.append(child)
            buffers = [(RTC_BUFFER_TYPE_VERTEX, RTC_FORMAT_FLOAT4, 16, np.ascontiguousarray(step, np.float32))
                       for step in steps]
            if starts is not None:
                buffers.append((RTC_BUFFER_TYPE_INDEX, RTC_FORMAT_UINT, 4, np.ascontiguousarray(starts, np.uint32)))
            self._primitives(kind, buffers, prims, rate, [], [], 0, scene=child, steps=len(steps))
            lib.rtcCommitScene(child)
            self._instance(child, np.ascontiguousarray(transforms, np.float32), len(offsets))
            offsets.append(first)
            order.append(np.asarray(prims, np.int64))
            first += len(prims)
        lib.rtcCommitScene(self.scene)
        self._check("commit the scene")
        self.offsets = np.array(offsets or [0], np.int64)
        self.order = np.concatenate(order) if order else np.zeros(0, np.int64)
        self.handle = int(self.scene)

    def _instance(self, child, transforms, geom_id):
        lib = self.lib
        geom = lib.rtcNewGeometry(self.device, RTC_GEOMETRY_TYPE_INSTANCE)
        if not geom:
            raise MemoryError(f"Embree could not create an instance (error {lib.rtcGetDeviceError(self.device)})")
        try:
            lib.rtcSetGeometryInstancedScene(geom, child)
            lib.rtcSetGeometryTimeStepCount(geom, len(transforms))
            for step, row in enumerate(transforms):
                decomposition = _aligned(16)
                decomposition[:] = row
                lib.rtcSetGeometryTransformQuaternion(geom, step, decomposition.ctypes.data)
            lib.rtcCommitGeometry(geom)
            got = lib.rtcAttachGeometry(self.scene, geom)
        finally:
            lib.rtcReleaseGeometry(geom)
        if got != geom_id:
            raise RuntimeError(f"Embree gave instance id {got}, expected {geom_id}")
        self._check("place an instance")

    def _add(self, vertices, indices, geom_id, scene=None):
        lib = self.lib
        steps = len(vertices)
        geom = lib.rtcNewGeometry(self.device, RTC_GEOMETRY_TYPE_TRIANGLE)
        if not geom:
            raise MemoryError(f"Embree could not create a geometry (error {lib.rtcGetDeviceError(self.device)})")
        try:
            lib.rtcSetGeometryTimeStepCount(geom, steps)
            for step in range(steps):
                self._fill(geom, RTC_BUFFER_TYPE_VERTEX, step, RTC_FORMAT_FLOAT3, vertices[step])
            self._fill(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, indices)
            lib.rtcCommitGeometry(geom)
            got = lib.rtcAttachGeometry(self.scene if scene is None else scene, geom)
        finally:
            lib.rtcReleaseGeometry(geom)
        if got != geom_id:
            raise RuntimeError(f"Embree gave geometry id {got}, expected {geom_id}")
        self._check("take the triangles")

    def _fill(self, geom, kind, slot, fmt, array):
        buffer = self.lib.rtcSetNewGeometryBuffer(geom, kind, slot, fmt, 12, len(array))
        if not buffer:
            raise MemoryError(f"Embree could not allocate a buffer of {len(array)} rows "
                              f"(error {self.lib.rtcGetDeviceError(self.device)})")
        ctypes.memmove(buffer, array.ctypes.data, array.nbytes)

    def _primitives(self, kind, buffers, prims, rate, offsets, order, first, scene=None, steps=1):
        """One geometry of points or curves from its buffers (kind, format,
        stride, array; ``steps`` vertex buffers come first, one per time
        step) in ``scene`` (the top one); its primitives are ``prims``.
        Returns the next first."""
        lib = self.lib
        geom = lib.rtcNewGeometry(self.device, kind)
        if not geom:
            raise MemoryError(f"Embree could not create a geometry (error {lib.rtcGetDeviceError(self.device)})")
        try:
            if rate is not None:
                lib.rtcSetGeometryTessellationRate(geom, float(rate))
            lib.rtcSetGeometryTimeStepCount(geom, steps)
            for slot, (buffer_kind, fmt, stride, array) in enumerate(buffers):
                self._fill_raw(geom, buffer_kind, fmt, stride, array, slot if slot < steps else 0)
            lib.rtcCommitGeometry(geom)
            got = lib.rtcAttachGeometry(self.scene if scene is None else scene, geom)
        finally:
            lib.rtcReleaseGeometry(geom)
        if got != len(offsets):
            raise RuntimeError(f"Embree gave geometry id {got}, expected {len(offsets)}")
        self._check("take the points or curves")
        offsets.append(first)
        order.append(np.asarray(prims, np.int64))
        self.nbytes += sum(array.nbytes for *_, array in buffers)
        return first + len(prims)

    def _fill_raw(self, geom, kind, fmt, stride, array, slot=0):
        buffer = self.lib.rtcSetNewGeometryBuffer(geom, kind, slot, fmt, stride, len(array))
        if not buffer:
            raise MemoryError(f"Embree could not allocate a buffer of {len(array)} rows")
        ctypes.memmove(buffer, array.ctypes.data, array.nbytes)

    def _check(self, what):
        error = self.lib.rtcGetDeviceError(self.device)
        if error:
            raise RuntimeError(f"Embree failed to {what} (error {error})")

    def close(self):
        if self.scene:
            self.lib.rtcReleaseScene(self.scene)
            for child in self.children:
                self.lib.rtcReleaseScene(child)
            self.lib.rtcReleaseDevice(self.device)
            self.scene = self.device = None

    def __del__(self):
        try:
            self.close()
        except Exception:   # interpreter shutdown: the library may be gone
            pass

    # -- queries ---------------------------------------------------------------
    @staticmethod
    def _rays(o, d, tfar, time):
        n = len(tfar)
        o = np.ascontiguousarray(o, np.float32)
        d = np.ascontiguousarray(d, np.float32)
        tfar = np.ascontiguousarray(np.minimum(np.maximum(tfar, 0.0), 1e37), np.float32)
        time = np.ascontiguousarray(np.broadcast_to(np.clip(time, 0.0, 1.0), (n,)), np.float32)
        return o, d, tfar, time

    def intersect(self, o, d, tfar, time, loops=None):
        """Closest hits at each ray's time: (t float64 (inf on miss), prim
        int64 (-1), u, v float64)."""
        o, d, tfar, time = self._rays(o, d, tfar, time)
        n = len(tfar)
        t = np.empty(n, np.float32)
        prim = np.empty(n, np.int64)
        u = np.zeros(n, np.float32)
        v = np.zeros(n, np.float32)
        loops = _compiled_loops() if loops is None else loops
        if loops:
            loops[0](np.uint64(self.handle), _address("rtcIntersect1"), o, d, tfar, time, self.offsets, self.order,
                     _aligned(RAYHIT_WORDS), t, prim, u, v)
        else:
            _packets(self.lib, self.handle, self.offsets, self.order, o, d, tfar, time, (t, prim, u, v))
        return t.astype(np.float64), prim, u.astype(np.float64), v.astype(np.float64)

    def occluded(self, o, d, tfar, time, loops=None):
        """True where something lies between the origin and tfar at the ray's time."""
        o, d, tfar, time = self._rays(o, d, tfar, time)
        blocked = np.empty(len(tfar), np.bool_)
        loops = _compiled_loops() if loops is None else loops
        if loops:
            loops[1](np.uint64(self.handle), _address("rtcOccluded1"), o, d, tfar, time, _aligned(RAYHIT_WORDS),
                     blocked)
        else:
            _packets(self.lib, self.handle, self.offsets, self.order, o, d, tfar, time, None, blocked)
        return blocked


def _packets(lib, handle, offsets, order, o, d, tfar, time, hits, blocked=None):
    """The queries as RTCRayHit16 packets filled by NumPy (no numba)."""
    n = len(tfar)
    count = -(-n // PACKET)
    pad = count * PACKET - n
    buf = _aligned(count * PACKET_WORDS).reshape(count, 21, PACKET)
    words = buf.view(np.uint32)

    def put(row, values):
        lane = np.zeros(count * PACKET, np.float32)
        lane[:n] = values
        buf[:, row, :] = lane.reshape(count, PACKET)

    for k in range(3):
        put(ORG + k, o[:, k])
        put(DIR + k, d[:, k])
    buf[:, TNEAR] = 0.0
    put(TIME, time)
    put(TFAR, tfar)
    words[:, MASK], words[:, ID], words[:, FLAGS] = INVALID_ID, 0, 0
    words[:, 12 + 6] = INVALID_ID    # hit.geomID (hit words start at 12)
    words[:, 12 + 7] = INVALID_ID    # hit.instID[0]
    valid = _aligned(count * PACKET).view(np.int32)   # read as one aligned 64-byte vector
    valid[:] = -1
    valid[n:] = 0
    fn = lib.rtcOccluded16 if hits is None else lib.rtcIntersect16
    base, vbase, step = buf.ctypes.data, valid.ctypes.data, PACKET_WORDS * 4
    for k in range(count):
        fn(vbase + 64 * k, handle, base + step * k, None)
    if hits is None:
        blocked[:] = buf[:, TFAR, :].reshape(-1)[:n] < 0.0
        return
    t, prim, u, v = hits
    geom = words[:, 12 + 6, :].reshape(-1)[:n]
    inst = words[:, 12 + 7, :].reshape(-1)[:n]
    local = words[:, 12 + 5, :].reshape(-1)[:n].astype(np.int64)
    hit = geom != INVALID_ID
    g = np.where(hit, np.where(inst != INVALID_ID, inst, geom), 0).astype(np.int64)
    prim[:] = np.where(hit, order[np.where(hit, offsets[g] + local, 0)], -1)
    t[:] = np.where(hit, buf[:, TFAR, :].reshape(-1)[:n], np.inf)
    u[:] = np.where(hit, buf[:, 12 + 3, :].reshape(-1)[:n], 0.0)
    v[:] = np.where(hit, buf[:, 12 + 4, :].reshape(-1)[:n], 0.0)


def _aligned(words):
    """A float32 array of ``words`` words starting on a 64-byte boundary."""
    raw = np.empty(words + 16, np.float32)
    start = (-raw.ctypes.data % 64) // 4
    return raw[start:start + words]


# -- calls into Embree from cached compiled loops ---------------------------------
# The loops above call rtcIntersect1 through a ctypes function pointer, a
# constant of this process, so numba compiles them again in every process.
# ``rtc_call`` instead takes the function's address as an argument (an
# integer cast to a function pointer in the generated code), so a loop calling
# it is an ordinary cached kernel (engine.kernels): the subsurface walk
# (engine/integrator/subsurface.py) traces its steps with it.

def rtc_call(fn, a, b, c):
    """In compiled code: call the C function at address ``fn`` with three
    pointer-sized arguments (``rtcIntersect1(scene, rayhit, NULL)``), all
    uint64.  Registered with numba by ``register_rtc_call``."""
    raise RuntimeError("rtc_call runs in compiled code only")


def register_rtc_call(numba):
    """Make ``rtc_call`` callable from nopython code (once per process)."""
    with _lock:
        if _state.get("rtc_call"):
            return
        from llvmlite import ir
        from numba.core import types
        from numba.extending import intrinsic, overload

        @intrinsic
        def _call(typingctx, fn, a, b, c):
            sig = types.void(types.uint64, types.uint64, types.uint64, types.uint64)

            def codegen(context, builder, signature, args):
                i64 = ir.IntType(64)
                pointer = builder.inttoptr(args[0], ir.FunctionType(ir.VoidType(), [i64, i64, i64]).as_pointer())
                builder.call(pointer, list(args[1:]))
                return context.get_dummy_value()
            return sig, codegen

        @overload(rtc_call)
        def _rtc_call(fn, a, b, c):
            def impl(fn, a, b, c):
                _call(fn, a, b, c)
            return impl
        _state["rtc_call"] = True


def intersect1_address():
    """The address of rtcIntersect1 in the loaded libembree4 (0 without it)."""
    lib = library()
    return 0 if lib is None else int(ctypes.cast(lib.rtcIntersect1, ctypes.c_void_p).value)


def ray_buffer():
    """One RTCRayHit's words, 64-byte aligned, for ``rtc_call`` loops."""
    return _aligned(RAYHIT_WORDS)


def embree_loop_kernel(signature, numpy_fn):
    """engine.kernels.loop_kernel for a loop that calls ``rtc_call``."""
    from . import kernels

    class Loop(kernels.LoopKernel):
        def build(self, numba):
            register_rtc_call(numba)
            return super().build(numba)

    def wrap(fn):
        return Loop(fn, signature, numpy_fn)
    return wrap


def _address(name):
    """np.uint64 address of ``name`` (rtcIntersect1, rtcOccluded1) in the loaded libembree4."""
    key = "address " + name
    if key not in _state:
        _state[key] = np.uint64(ctypes.cast(getattr(library(), name), ctypes.c_void_p).value)
    return _state[key]


# -- the per-ray query loops ----------------------------------------------------

@kernels.helper
def _ray_words(buf, w, o, d, tfar, time, i):
    """Ray i into the RTCRay words of buf (w: the same words as uint32)."""
    buf[0], buf[1], buf[2], buf[3] = o[i, 0], o[i, 1], o[i, 2], 0.0
    buf[4], buf[5], buf[6], buf[7] = d[i, 0], d[i, 1], d[i, 2], time[i]
    buf[8] = tfar[i]
    w[9], w[10], w[11] = 0xFFFFFFFF, 0, 0


# Cached kernels (no compile per process: the loops used to call ctypes
# function pointers, constants numba compiled again in every process, 1-3 s
# on a motion scene's first query).  Their NumPy forms are the packet queries.

def _intersect_numpy(scene, fn, o, d, tfar, time, offsets, order, buf, t_out, prim_out, u_out, v_out):
    _packets(library(), int(scene), offsets, order, o, d, tfar, time, (t_out, prim_out, u_out, v_out))


def _occluded_numpy(scene, fn, o, d, tfar, time, buf, blocked):
    _packets(library(), int(scene), None, None, o, d, tfar, time, None, blocked)


@embree_loop_kernel("void(uint64, uint64, float32[:, ::1], float32[:, ::1], float32[::1], float32[::1], int64[::1], "
                    "int64[::1], float32[::1], float32[::1], int64[::1], float32[::1], float32[::1])",
                    _intersect_numpy)
def _intersect_rays(scene, fn, o, d, tfar, time, offsets, order, buf, t_out, prim_out, u_out, v_out):
    """Closest hits of rays at their times, one rtcIntersect1 (at ``fn``)
    each: t inf and prim -1 on a miss, else prim the global row
    (``order[offsets[geometry or instance] + primID]``)."""
    w = buf.view(np.uint32)
    addr = np.uint64(buf.ctypes.data)
    for i in range(len(tfar)):
        _ray_words(buf, w, o, d, tfar, time, i)
        w[18], w[19] = 0xFFFFFFFF, 0xFFFFFFFF
        rtc_call(fn, scene, addr, np.uint64(0))
        if w[18] == 0xFFFFFFFF:
            prim_out[i] = -1
            t_out[i] = np.inf
        else:
            g = w[19] if w[19] != 0xFFFFFFFF else w[18]   # an instance's id, or the geometry's
            prim_out[i] = order[offsets[np.int64(g)] + np.int64(w[17])]
            t_out[i] = buf[8]
            u_out[i] = buf[15]
            v_out[i] = buf[16]


@embree_loop_kernel("void(uint64, uint64, float32[:, ::1], float32[:, ::1], float32[::1], float32[::1], float32[::1], "
                    "boolean[::1])", _occluded_numpy)
def _occluded_rays(scene, fn, o, d, tfar, time, buf, blocked):
    """Whether anything lies on each ray before tfar at its time (rtcOccluded1 at ``fn``)."""
    w = buf.view(np.uint32)
    addr = np.uint64(buf.ctypes.data)
    for i in range(len(tfar)):
        _ray_words(buf, w, o, d, tfar, time, i)
        rtc_call(fn, scene, addr, np.uint64(0))
        blocked[i] = buf[8] < 0.0
