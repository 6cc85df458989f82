"""The Principled Hair BSDF's Huang model (Huang, Hullin and Hanika 2022,
"A Microfacet-based Hair Scattering Model"), as Cycles 5.0's
closure/bsdf_principled_hair_huang.h: elliptical fibres (Aspect Ratio),
GGX microfacets on a tilted mesonormal, the R lobe by Simpson quadrature
over the visible width, TT and TRT by Monte Carlo-Simpson quadrature, TRRT+
by Chiang's longitudinal lobe, the R / TT / TRT gains, absorption sigma.

The one source is the ``_huang_*`` helpers of engine/bsdf_loops.py (the
HAIR_HUANG branches of its loops); the NumPy kernels here run the same
helpers row by row.  Frames as engine/lobes/hair.py: x the curve's tangent,
z the round curve's normal, so h = -wo.y / |(wo.y, wo.z)|.  Cycles' local X
is perpendicular to the view on round fibres and the ellipse's major axis
otherwise: the per-ray ``fibre_axis`` ((y, z) in the shading frame, from
the curve's normal attribute: ``ellipse_axes`` below).

What Cycles does that shapes the lobe's contract:
* its eval and sample report pdf 1 (a stand-in for MIS, the value already
  holds the sampling weight), so the lobe is OWN_WEIGHT: the sample writes
  its own value, and a light sample's MIS weight sees pdf 1;
* its eval is stochastic (TT, TRT: microfacet normals drawn per quadrature
  node from the shading point's LCG); Ember seeds the LCG from the
  directions, the sample's from its three random numbers;
* far field everywhere but on camera rays that see a fibre wider than half
  a pixel (``pixel_coverage`` < the projected radius): there the sample
  keeps the hit's h and eval integrates over the pixel's part of the width;
* a hit outside the ellipse's projected width is a transparent closure:
  the sample passes straight through (delta), eval is 0.
"""
import numpy as np

from .registry import OWN_WEIGHT, REFLECTION, TRANSMISSION, LobeDef, register

HAIR_HUANG = 15
PARAMS = ("roughness", "ior", "absorption", "offset", "aspect_ratio", "hair_gains", "fibre_axis",
          "pixel_coverage")


# The compiled helpers this NumPy form runs row by row live in
# engine/bsdf_loops.py, which imports the lobe registry: engine/bsdf.py binds
# them here when it is imported (an import of them here would be a cycle).
_BOUND = {}


def bind(table_arrays, loops):
    """Called by engine/bsdf.py: its table tuple function and bsdf_loops."""
    _BOUND.update(table_arrays=table_arrays, loops=loops)


def _loops():
    if not _BOUND:
        raise RuntimeError("engine.lobes.hair_huang runs through engine.bsdf: import engine.bsdf first")
    return _BOUND["table_arrays"], _BOUND["loops"]


def _rows(lobes, rows):
    """Row indices (the kernels may get a slice)."""
    return np.arange(len(lobes.kind))[rows]


def _row_args(lobes, r, k):
    return (lobes.alpha[r, k], lobes.ior[r, k], np.ascontiguousarray(lobes.absorption[r, k]),
            lobes.offset[r, k], lobes.aspect_ratio[r, k], np.ascontiguousarray(lobes.fibre_axis[r, k]),
            np.ascontiguousarray(lobes.hair_gains[r, k]), lobes.pixel_coverage[r, k])


def eval_huang_f(lobes, rows, k, wo, wi):
    """(f (N, 3) without the weight, pdf (N,)) row by row."""
    table_arrays, loops = _loops()
    tables = table_arrays()
    rows = _rows(lobes, rows)
    f, pdf, out = np.zeros((len(rows), 3)), np.zeros(len(rows)), np.empty(3)
    for j, r in enumerate(rows):
        pdf[j] = loops._huang_eval(tables[2], tables[3], *_row_args(lobes, r, k), *wo[j], *wi[j], out)
        f[j] = out
    return f, pdf


def eval_huang(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_huang_f(lobes, rows, k, wo, wi)
    up = wo[:, 2] > 0
    return w * np.where(up[:, None], f, 0.0), sel * np.where(up, pdf, 0.0)


def sample_huang_dir(lobes, rows, k, wo, u_lobe, u1, u2):
    """(wi, value f |cos| (N, 3), ok, transparent) row by row."""
    table_arrays, loops = _loops()
    tables = table_arrays()
    rows = _rows(lobes, rows)
    n = len(rows)
    wi, value = np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros((n, 3))
    ok, passing, out = np.zeros(n, bool), np.zeros(n, bool), np.empty(3)
    for j, r in enumerate(rows):
        args = _row_args(lobes, r, k)
        if loops._huang_transparent(args[4], args[5][0], args[5][1], *wo[j]):
            passing[j] = True
            wi[j] = -wo[j]
            continue
        x, y, z, good = loops._huang_sample(tables[2], tables[3], *args, *wo[j], u_lobe[j], u1[j], u2[j], out)
        if good and abs(z) > 1e-12:
            wi[j], value[j], ok[j] = (x, y, z), out, True
    return wi, value, ok, passing


def sample_huang(lobes, rows, s):
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        wi, value, ok, passing = sample_huang_dir(lobes, r, k, s.wo[r], s.u_sub[r], s.u1[r], s.u2[r])
        s.wi[r] = wi
        cos = np.where(ok, np.abs(wi[:, 2]), 1.0)
        s.weight[r] = np.where(ok[:, None], s.w[r, k] * value / cos[:, None], 0.0)
        s.pdf[r] = np.where(ok, s.p_lobe[r], 0.0)
        s.kind[r] = np.where(ok | passing, s.kind[r], -1)
        # Outside the projected width: Cycles' transparent closure, a delta pass.
        p = r[passing]
        s.weight[p] = s.w[p, k] / s.p_lobe[p, None]
        s.pdf[p] = s.p_lobe[p]
        s.delta[p] = True


# ----------------------------------------------------------------------------
# The ellipse's axis per ray (bsdf_hair_huang_setup's bsdf->N)

def make_orthonormals(n):
    """Cycles' make_orthonormals(N): (a, b) for unit rows n."""
    same = (n[:, 0] == n[:, 1]) & (n[:, 0] == n[:, 2])
    a = np.where(same[:, None], np.stack([n[:, 2] - n[:, 1], n[:, 0] + n[:, 2], -n[:, 1] - n[:, 0]], axis=1),
                 np.stack([n[:, 2] - n[:, 1], n[:, 0] - n[:, 2], n[:, 1] - n[:, 0]], axis=1))
    a = a / np.maximum(np.linalg.norm(a, axis=1), 1e-300)[:, None]
    return a, np.cross(n, a)


def ellipse_axes(tangent, normal, tt, bb, ns):
    """(N, 2): the major axis Cycles takes for elliptical fibres, the curve's
    ``normal`` made perpendicular to the ``tangent`` (world space), in the
    shading frame's (y, z) (tt, bb, ns its axes).  A zero normal (particle
    hair: Cycles exports none) gives make_orthonormals' axis about the tangent."""
    t = tangent / np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    axis = normal - t * np.einsum("ij,ij->i", normal, t)[:, None]
    length = np.linalg.norm(axis, axis=1)
    good = np.isfinite(length) & (length > 1e-12)
    axis = np.where(good[:, None], axis / np.where(good, length, 1.0)[:, None], 0.0)
    if not good.all():
        _, fallback = make_orthonormals(t[~good])
        axis[~good] = fallback
    return np.stack([np.einsum("ij,ij->i", axis, bb), np.einsum("ij,ij->i", axis, ns)], axis=1)


register(LobeDef(HAIR_HUANG, "hair_huang", "glossy", REFLECTION | TRANSMISSION | OWN_WEIGHT, sample_huang,
                 eval_huang, "both", params=PARAMS, reciprocal=False, has_transmission=True,
                 doc="Principled Hair BSDF, Huang model (Cycles' bsdf_principled_hair_huang.h) on curves: x the "
                     "fibre's tangent, z its normal",
                 cases=[dict(color=(1, 1, 1), roughness=0.3, ior=1.55, offset=0.0349, aspect_ratio=1.0,
                             absorption=(0.42, 0.68, 1.2)),
                        # (elliptical fibres pass some rays straight through, which the
                        # registry's flags test cannot tell: tests/engine/test_hair_huang.py)
                        dict(color=(1, 1, 1), roughness=0.5, ior=1.55, offset=0.0349, aspect_ratio=1.0,
                             absorption=(0.0, 0.0, 0.0), hair_gains=(0.5, 1.0, 2.0))]))
