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
import numpy as np

from .lobe_ids import DIFFUSE, OREN_NAYAR, SHEEN
from .microfacet import COS_EPS
from .vec import dot, frame

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


def corrected(ng, wo, bent, smooth):
    """The glossy normal of each row: bent lifted where the normal map or
    bump moved it (bent != smooth), bent elsewhere."""
    moved = np.any(bent != smooth, axis=1)
    out = np.array(bent, copy=True)
    rows = np.flatnonzero(moved)
    if len(rows):
        out[rows] = ensure_valid_specular_reflection(ng[rows], wo[rows], bent[rows])
    return out


def rotations(tt, bb, ns, bent):
    """(N, 3, 3) rotations from the frame (tt, bb, ns) into a frame of the
    bent normal (z = bent) and which rows differ (None, None: none)."""
    split = np.any(bent != ns, axis=1)
    if not split.any():
        return None, None
    td, bd = frame(bent)
    main = np.stack([tt, bb, ns], axis=1)       # rows: the main frame's axes
    other = np.stack([td, bd, bent], axis=1)
    rot = np.einsum("nij,nkj->nik", other, main)
    rot[~split] = np.eye(3)
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
