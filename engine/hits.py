"""Surface hits from Embree's answers: the world-space point and normals.

Embree returns t and barycentrics in float32.  The hit point is recomputed
in float64 by intersecting the triangle's plane again, so hit points (and
the shadow rays leaving them) sit on the surface even on large triangles;
the geometric normal faces the incoming ray; the shading normal is the
interpolated vertex normal on the same side, or the geometric one where it
would face away from the viewer (the BSDF would see wo below its horizon).

``hit_geometry`` is a compiled loop (one pass, no temporaries) next to its
NumPy form, which defines the result bit for bit (tests/engine/test_kernels.py).
"""
import numpy as np

from .kernels import loop_kernel


def _dot(a, b):
    """Row dot products summed left to right, as the compiled loop does
    (einsum adds the middle term last)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _hit_geometry_numpy(o, d, t, prim, bu, bv, tri_ng, tri_p0, tri_ns, smooth, p_out, ng_out, ns_out, back_out):
    ng = np.take(tri_ng, prim, axis=0)
    cos = _dot(d, ng)
    with np.errstate(divide="ignore", invalid="ignore"):
        t64 = _dot(np.take(tri_p0, prim, axis=0) - o, ng) / cos
    t = np.where(np.isfinite(t64) & (np.abs(cos) > 1e-6), t64, t)
    p_out[:] = o + d * t[:, None]
    back = _dot(d, ng) > 0
    ng = np.where(back[:, None], -ng, ng)
    if smooth:
        c = np.take(tri_ns, prim, axis=0)
        ns = (1.0 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
        ns /= np.maximum(np.sqrt(_dot(ns, ns)), 1e-30)[:, None]
        ns = np.where((_dot(ns, ng) < 0)[:, None], -ns, ns)
        ns = np.where((_dot(ns, -d) <= 1e-6)[:, None], ng, ns)
    else:
        ns = ng
    ng_out[:], ns_out[:], back_out[:] = ng, ns, back


@loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[::1], int64[::1], float64[::1], float64[::1], "
             "float64[:, ::1], float64[:, ::1], float64[:, :, ::1], boolean, float64[:, ::1], float64[:, ::1], "
             "float64[:, ::1], boolean[::1])", _hit_geometry_numpy)
def _hit_geometry(o, d, t, prim, bu, bv, tri_ng, tri_p0, tri_ns, smooth, p_out, ng_out, ns_out, back_out):
    for i in range(len(t)):
        k = prim[i]
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        gx, gy, gz = tri_ng[k, 0], tri_ng[k, 1], tri_ng[k, 2]
        cos = dx * gx + dy * gy + dz * gz
        t64 = ((tri_p0[k, 0] - o[i, 0]) * gx + (tri_p0[k, 1] - o[i, 1]) * gy
               + (tri_p0[k, 2] - o[i, 2]) * gz) / cos
        ti = t64 if np.isfinite(t64) and np.abs(cos) > 1e-6 else t[i]
        p_out[i, 0] = o[i, 0] + dx * ti
        p_out[i, 1] = o[i, 1] + dy * ti
        p_out[i, 2] = o[i, 2] + dz * ti
        back = cos > 0
        if back:
            gx, gy, gz = -gx, -gy, -gz
        back_out[i] = back
        ng_out[i, 0], ng_out[i, 1], ng_out[i, 2] = gx, gy, gz
        if not smooth:
            ns_out[i, 0], ns_out[i, 1], ns_out[i, 2] = gx, gy, gz
            continue
        b1, b2 = bu[i], bv[i]
        b0 = 1.0 - b1 - b2
        nx = b0 * tri_ns[k, 0, 0] + b1 * tri_ns[k, 1, 0] + b2 * tri_ns[k, 2, 0]
        ny = b0 * tri_ns[k, 0, 1] + b1 * tri_ns[k, 1, 1] + b2 * tri_ns[k, 2, 1]
        nz = b0 * tri_ns[k, 0, 2] + b1 * tri_ns[k, 1, 2] + b2 * tri_ns[k, 2, 2]
        length = np.maximum(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-30)
        nx, ny, nz = nx / length, ny / length, nz / length
        if nx * gx + ny * gy + nz * gz < 0:
            nx, ny, nz = -nx, -ny, -nz
        if nx * -dx + ny * -dy + nz * -dz <= 1e-6:
            nx, ny, nz = gx, gy, gz
        ns_out[i, 0], ns_out[i, 1], ns_out[i, 2] = nx, ny, nz


_NO_NORMALS = np.zeros((1, 3, 3))


def hit_geometry(tr, o, d, t, prim, bu, bv):
    """(p, ng, ns, back) of the hits ``prim`` at barycentrics (bu, bv) of
    rays (o, d) with Embree's distances t."""
    n = len(t)
    p, ng, ns = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    back = np.empty(n, bool)
    smooth = tr.ns is not None
    _hit_geometry(_c(o), _c(d), _c(t), np.ascontiguousarray(prim, np.int64), _c(bu), _c(bv), _c(tr.ng), _c(tr.p0),
                  _c(tr.ns) if smooth else _NO_NORMALS, smooth, p, ng, ns, back)
    return p, ng, ns, back


def _c(a):
    return np.ascontiguousarray(a, np.float64)
