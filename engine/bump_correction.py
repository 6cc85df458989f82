"""Cycles' Bump Map Correction: a normal per lobe.

Where a normal map or bump moved the shading normal, Cycles (5.0,
svm/closure.h) gives each closure its own normal: diffuse, Oren-Nayar and
sheen keep the bent normal N, every other closure (glossy, metal, glass,
refraction, translucent, subsurface) takes
``ensure_valid_specular_reflection(Ng, I, N)`` (closure/bsdf_util.h): N
turned towards Ng just enough that the view's mirror direction lies above
the surface by min(0.9 cos(I, Ng), 0.01).  That holds even where N faces
away from the view, where the diffuse lobes then see the view from behind
their normal (their eval does not look at the view).

Ember's shading frame is the corrected normal (the view always lies above
it); rows whose bent normal differs carry ``Lobes.diffuse_rot``, the
rotation from that frame into the bent normal's, and
``Lobes.diffuse_smooth`` (the smooth normal there, for Cycles' bump
shadowing term of the diffuse lobes).  bsdf.eval_pdf and bsdf.sample
evaluate and sample the diffuse lobes of those rows in their own frame
(``split_eval``, ``resample``); the integrator's side tests (a reflection
leaves above Ng) use ``sided``.
"""
import math

import numpy as np

from . import kernels
from .lobe_ids import DIFFUSE, OREN_NAYAR, SHEEN
from .microfacet import COS_EPS
from .vec import contiguous, dot, frame, frame_of

BENT_KINDS = (DIFFUSE, OREN_NAYAR, SHEEN)   # the closures Cycles leaves the bent normal


def ensure_valid_specular_reflection(ng, wi, n):
    """Cycles' ensure_valid_specular_reflection per row (world vectors:
    ng the geometric normal facing the view wi, n the bent normal)."""
    r = 2.0 * dot(n, wi)[:, None] * n - wi
    iz = dot(wi, ng)
    threshold = np.minimum(0.9 * iz, 0.01)
    keep = dot(ng, r) >= threshold
    x = n - dot(n, ng)[:, None] * ng
    length = np.sqrt(dot(x, x))
    x = np.where((length > 1e-30)[:, None], x / np.where(length > 1e-30, length, 1.0)[:, None], n)
    ix = dot(wi, x)
    a = ix * ix + iz * iz
    b = 2.0 * (a + iz * threshold)
    c = (threshold + iz) ** 2
    root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
    a_safe = np.where(a > 0, a, 1.0)
    nz2 = np.where(ix < 0, 0.25 * (b + root) / a_safe, 0.25 * (b - root) / a_safe)
    nx, nz = np.sqrt(np.maximum(1.0 - nz2, 0.0)), np.sqrt(np.maximum(nz2, 0.0))
    lifted = nx[:, None] * x + nz[:, None] * ng
    return np.where(keep[:, None], n, lifted)


def _corrected_numpy(ng, wo, bent, smooth, out):
    moved = np.any(bent != smooth, axis=1)
    out[:] = bent
    rows = np.flatnonzero(moved)
    if len(rows):
        out[rows] = ensure_valid_specular_reflection(ng[rows], wo[rows], bent[rows])


@kernels.helper
def _dot3(a0, a1, a2, b0, b1, b2):
    return (a0 * b0 + a2 * b2) + a1 * b1


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1])",
                     _corrected_numpy)
def _corrected_rows(ng, wo, bent, smooth, out):
    """ensure_valid_specular_reflection per row where bent != smooth."""
    for i in range(len(ng)):
        n0, n1, n2 = bent[i, 0], bent[i, 1], bent[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = n0, n1, n2
        if n0 == smooth[i, 0] and n1 == smooth[i, 1] and n2 == smooth[i, 2]:
            continue
        g0, g1, g2, w0, w1, w2 = ng[i, 0], ng[i, 1], ng[i, 2], wo[i, 0], wo[i, 1], wo[i, 2]
        nw = 2.0 * _dot3(n0, n1, n2, w0, w1, w2)
        iz = _dot3(w0, w1, w2, g0, g1, g2)
        threshold = min(0.9 * iz, 0.01)
        if _dot3(g0, g1, g2, nw * n0 - w0, nw * n1 - w1, nw * n2 - w2) >= threshold:
            continue
        ng_n = _dot3(n0, n1, n2, g0, g1, g2)
        x0, x1, x2 = n0 - ng_n * g0, n1 - ng_n * g1, n2 - ng_n * g2
        length = math.sqrt(_dot3(x0, x1, x2, x0, x1, x2))
        if length > 1e-30:
            x0, x1, x2 = x0 / length, x1 / length, x2 / length
        else:
            x0, x1, x2 = n0, n1, n2
        ix = _dot3(w0, w1, w2, x0, x1, x2)
        a = ix * ix + iz * iz
        b = 2.0 * (a + iz * threshold)
        c = (threshold + iz) ** 2
        root = math.sqrt(max(b * b - 4.0 * a * c, 0.0))
        a_safe = a if a > 0 else 1.0
        nz2 = 0.25 * (b + root) / a_safe if ix < 0 else 0.25 * (b - root) / a_safe
        nx, nz = math.sqrt(max(1.0 - nz2, 0.0)), math.sqrt(max(nz2, 0.0))
        out[i, 0], out[i, 1], out[i, 2] = nx * x0 + nz * g0, nx * x1 + nz * g1, nx * x2 + nz * g2


def corrected(ng, wo, bent, smooth):
    """The glossy normal of each row: bent lifted where the normal map or
    bump moved it (bent != smooth), bent elsewhere."""
    out = np.empty(np.shape(bent))
    _corrected_rows(contiguous(ng), contiguous(wo), contiguous(bent), contiguous(smooth), out)
    return out


def _rotations_numpy(tt, bb, ns, bent, split, rot):
    td, bd = frame(bent)
    main = np.stack([tt, bb, ns], axis=1)       # rows: the main frame's axes
    other = np.stack([td, bd, bent], axis=1)
    rot[:] = np.einsum("nij,nkj->nik", other, main)
    rot[~split] = np.eye(3)


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], bool_[::1], "
                     "float64[:, :, ::1])", _rotations_numpy)
def _rotation_rows(tt, bb, ns, bent, split, rot):
    """rot[i, a, b] = (td, bd, bent)[a] . (tt, bb, ns)[b] where split, else I."""
    for i in range(len(tt)):
        for a in range(3):
            for b in range(3):
                rot[i, a, b] = 1.0 if a == b else 0.0
        if not split[i]:
            continue
        n0, n1, n2 = bent[i, 0], bent[i, 1], bent[i, 2]
        s0, s1, s2, t0, t1, t2 = frame_of(n0, n1, n2)
        for b in range(3):
            m = tt if b == 0 else (bb if b == 1 else ns)
            m0, m1, m2 = m[i, 0], m[i, 1], m[i, 2]
            rot[i, 0, b] = _dot3(s0, s1, s2, m0, m1, m2)
            rot[i, 1, b] = _dot3(t0, t1, t2, m0, m1, m2)
            rot[i, 2, b] = _dot3(n0, n1, n2, m0, m1, m2)


def rotations(tt, bb, ns, bent):
    """(N, 3, 3) rotations from the frame (tt, bb, ns) into a frame of the
    bent normal (z = bent) and which rows differ (None, None: none)."""
    split = (bent[:, 0] != ns[:, 0]) | (bent[:, 1] != ns[:, 1]) | (bent[:, 2] != ns[:, 2])
    if not split.any():
        return None, None
    rot = np.empty((len(split), 3, 3))
    _rotation_rows(contiguous(tt), contiguous(bb), contiguous(ns), contiguous(bent), split, rot)
    return rot, split


def apply(rot, v):
    return np.einsum("nij,nj->ni", rot, v)


def apply_t(rot, v):
    return np.einsum("nji,nj->ni", rot, v)


def view_above(wo_d):
    """The view in the bent normal's frame as the lobes' kernels accept it
    (above the horizon): where it lies below, moved to just above it along
    its azimuth.  Lambert does not read the view; Oren-Nayar (nv = 0 there,
    as Cycles' max(dot, 0)) and sheen see this one instead of the true one."""
    low = wo_d[:, 2] <= 4.0 * COS_EPS
    if not low.any():
        return wo_d
    out = np.array(wo_d, copy=True)
    xy = out[low, :2]
    length = np.sqrt(xy[:, 0] ** 2 + xy[:, 1] ** 2)
    xy = np.where((length > 0)[:, None], xy / np.where(length > 0, length, 1.0)[:, None], [1.0, 0.0])
    z = 4.0 * COS_EPS
    out[low, :2] = xy * np.sqrt(1.0 - z * z)
    out[low, 2] = z
    return out


def sided(lobes, wi_l, wi=None, ng=None, reflected=None):
    """wi_l's z as the integrator's side test reads it (a sample counts
    where (Ng . wi > 0) == (z > 0)): unchanged on rows without a second
    normal; on the others, whose lobes judge their own side, the light
    samples' z takes the sign of Ng . wi (world directions ``wi`` and
    normals ``ng``, read only when some row has a second normal: Cycles'
    eval does not test Ng), a
    sample of a bent-normal lobe counts as a reflection (``reflected``,
    Cycles' diffuse sample rejects directions below Ng)."""
    split = getattr(lobes, "diffuse_split", None)
    if split is None or not split.any():
        return wi_l
    out = np.array(wi_l, copy=True)
    z = np.abs(out[:, 2])
    if reflected is None:
        sign = np.where(np.einsum("ij,ij->i", wi, ng) > 0, 1.0, -1.0)
        out[:, 2] = np.where(split, sign * z, out[:, 2])
    else:
        out[:, 2] = np.where(split & reflected, z, out[:, 2])
    return out
