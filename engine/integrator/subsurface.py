"""Subsurface scattering: Cycles 5.0's random walk (and Christensen-Burley's
disk probes, ``disk``) as a stage of the bounce (kernel/integrator/subsurface.h,
subsurface_random_walk.h, subsurface_disk.h, closure/bssrdf.h).

At a vertex whose material has a subsurface lobe (engine/lobes/subsurface.py)
``split`` takes the first part of the lobe-choice number, of the size of
the subsurface lobes' selection probability, for the BSSRDF; the BSDF lobes
share the rest (their weights and pdfs scaled by its size, so next-event
estimation's MIS, which sees the subsurface lobe as zero, stays unbiased).
A path that chose it gets Cycles' entry bounce (a refraction through a GGX
microfacet, or for Skin half the time a cosine direction) and the closure
weight over its selection probability; ``walk`` then follows it through the
medium Cycles derives from the albedo and radius (``coefficients``: the
radius remap of bssrdf_setup_radius, Christensen-Burley's albedo fit
inverted into a single-scattering albedo, sigma_t = 1 / radius) until it
meets the object's own surface again (the object's triangles alone, as
Cycles' scene_intersect_local), choosing the colour channel of each
distance by one-sample MIS (Cycles' volume_sample_channel, the balance
heuristic over the three channels).  Its exit point is the next vertex:
the path's ray is set to come from just outside towards it, the next
bounce takes the recorded triangle without tracing, collects no emission
there and shades it as a white diffuse lobe under the exit's shading
normal (Cycles' subsurface_shader_data_setup).  As in Cycles the entry is
no bounce: the exit vertex has the entry's bounce count (and the entry
counts no bounce kind).  A walk that leaves no exit
within 256 bounces, or whose throughput falls below 1e-6, ends the path.

The walk is Cycles' guided one (Dwivedi sampling towards and away from
the surface, MIS-combined with the classic walk), with its similarity
relation past the 9th bounce (isotropic with the reduced scattering
coefficient).  Each walk runs start to exit in one compiled loop
(``_walk_paths``), tracing every step with rtcIntersect1 in an Embree scene
of the object's own triangles; its NumPy form is the wavefront
(``_wavefront``: all walks a bounce at a time).
"""
import threading
import weakref

import numpy as np

from .. import bsdf, embree_c
from ..bsdf import kind_in
from ..lobe_ids import DIFFUSE, NONE
from ..lobes import EXTRA_PARAMS, table_value
from ..lobes.subsurface import G_RANGE, IDS, IOR_RANGE, SUBSURFACE_BURLEY, SUBSURFACE_SKIN
from ..lobes.subsurface import entry as lobe_entry
from ..lobes import REGISTRY, SUBSURFACE, kinds_of_class
from ..media import open_meshes
from ..kernels import helper, loop_kernel
from ..media.phase import G_LIMIT
from ..vec import frame_of
from ..nodes.rays import NodeRays, local_accel, make_orthonormals
from ..sampler import RANDOM, SOBOL, _hash_scalar, hash32, subsurface_set
# The sampler's own per-path Sobol arithmetic and tables (``_numbers_one``).
from ..sampler import _16, _BYTES, _DIM_SALT64, _HI, _LO, _M32, _TO_UNIT
from ..sampler import _sobol4_into, _sobol4_one
from ..scene import Lobe

MAX_BOUNCES = 256           # BSSRDF_MAX_BOUNCES
THROUGHPUT_EPSILON = 1e-6   # VOLUME_THROUGHPUT_EPSILON
SIMILARITY_LEVEL = 9        # SUBSURFACE_RANDOM_WALK_SIMILARITY_LEVEL
MIN_ALPHA = 0.2             # subsurface_random_walk_coefficients' min_alpha
MIN_RADIUS = 1e-8           # BSSRDF_MIN_RADIUS
_WHITE = Lobe("diffuse", (1.0, 1.0, 1.0))   # the exit point's lobe


def in_scene(materials):
    """Whether any material has a subsurface lobe."""
    return bool(np.any(kind_in(materials.kind, IDS)))


def open_mesh_warnings(scene):
    """One warning per object whose subsurface material's triangles do not
    close: walks entering there may never come out (Cycles loses them too)."""
    def uses(material):
        return any(REGISTRY[lobe.kind].has(SUBSURFACE) for lobe in material.lobes if lobe.kind in REGISTRY)
    return [f"material {', '.join(repr(m) for m in mats)} on object {name!r}: subsurface scattering on a mesh "
            "that is not closed; light entering it may never come out (rendered darker)"
            for name, mats in open_meshes(scene, uses)]


# ----------------------------------------------------------------------------
# Cycles' coefficients (float64 here; Cycles computes them in float32)

def dipole_rd(alpha_prime, fourthird_a):
    """bssrdf_dipole_compute_Rd."""
    s = np.sqrt(3.0 * (1.0 - alpha_prime))
    return 0.5 * alpha_prime * (1.0 + np.exp(-fourthird_a * s)) * np.exp(-s)


def dipole_alpha_prime(rd, fourthird_a):
    """bssrdf_dipole_compute_alpha_prime: 12 bisection steps on [0, 1]."""
    rd = np.asarray(rd, np.float64)
    x0, x1 = np.zeros_like(rd), np.ones_like(rd)
    for _ in range(12):
        mid = 0.5 * (x0 + x1)
        low = dipole_rd(mid, fourthird_a) < rd
        x0, x1 = np.where(low, mid, x0), np.where(low, x1, mid)
    return np.where(rd < 1e-4, 0.0, np.where(rd >= 0.995, 0.999999, mid))   # Cycles returns the last midpoint


def remapped_radius(radius, albedo, ior, skin):
    """bssrdf_setup_radius (5.0): Random Walk scales the radius by 1 / (4 pi);
    Skin by sqrt(3 (1 - alpha')), alpha' the dipole albedo of Jensen's Fdr
    for the IOR.  radius, albedo (N, 3); ior, skin (N,)."""
    inv = 1.0 / ior
    f_dr = inv * (-1.440 * inv + 0.710) + 0.668 + 0.0636 * ior
    fourthird_a = (4.0 / 3.0) * (1.0 + f_dr) / (1.0 - f_dr)
    alpha_prime = dipole_alpha_prime(albedo, fourthird_a[:, None])
    skin_scale = np.sqrt(3.0 * (1.0 - alpha_prime))
    return radius * np.where(skin[:, None], skin_scale, 0.25 / np.pi)


# subsurface_random_walk_remap's fit: polynomials in g of degree 7 (B and E:
# constant + factor x exp(polynomial without constant term)).
_FIT = {
    "A": (1.8260523782, -1.28451056436, -1.79904629312, 9.19393289202, -22.8215585862, 32.0234874259,
          -23.6264803333, 7.21067002658),
    "B": (0.0, 31.1491581433, -201.847017512, 841.576016723, -2018.09288505, 2731.71560286, -1935.41424244,
          559.009054474),
    "C": (1.09686102424, -0.394704063468, 1.05258115941, -8.83963712726, 28.8643230661, -46.8802913581,
          38.5402837518, -12.7181042538),
    "D": (0.496310210422, 0.360146581622, -2.15139309747, 17.8896899217, -55.2984010333, 82.065982243,
          -58.5106008578, 15.8478295021),
    "E": (0.0, 76.7316253952, -594.356773233, 2448.8834203, -5576.68528998, 7116.60171912, -4763.54467887,
          1303.5318055),
    "F": (2.40602999408, -2.51814844609, 9.18494908356, -79.2191708682, 259.082868209, -403.613804597,
          302.85712436, -87.4370473567),
}
_FIT_B = (4.98511194385, 0.127355959438)
_FIT_E = (4.23190299701, 0.00310603949088)


def _poly(coeffs, g):
    """sum_k coeffs[k] g^k, in Cycles' order of terms."""
    out = coeffs[0] + 0.0 * g
    power = g
    for c in coeffs[1:]:
        out = out + c * power
        power = power * g
    return out


def single_scatter_albedo(albedo, g):
    """subsurface_random_walk_remap: the single-scattering albedo whose
    multiple-scattering albedo is the surface colour (a fit by g)."""
    g = np.asarray(g, np.float64)[..., None]
    a, c, d, f = (_poly(_FIT[k], g) for k in "ACDF")
    b = _FIT_B[0] + _FIT_B[1] * np.exp(_poly(_FIT["B"], g))
    e = _FIT_E[0] + _FIT_E[1] * np.exp(_poly(_FIT["E"], g))
    albedo = np.maximum(albedo, 0.0)
    blend = albedo ** 0.25
    alpha = (1.0 - blend) * a * np.arctan(b * albedo) ** c + blend * d * np.arctan(e * albedo) ** f
    return np.clip(alpha, 0.0, 0.999999)


def coefficients(albedo, radius, g):
    """subsurface_random_walk_coefficients: (sigma_t, single-scattering
    albedo, throughput factor) per channel for a closure whose weight
    already holds the albedo (divided out here: scattering adds it back);
    albedos below 0.2 are raised to it with the throughput lowered to match."""
    alpha = single_scatter_albedo(albedo, g)
    sigma_t = 1.0 / (np.maximum(radius, 1e-16) * (1.0 - np.asarray(g)[..., None]))
    factor = np.where(albedo > 0, 1.0 / np.where(albedo > 0, albedo, 1.0), 0.0)
    low = alpha < MIN_ALPHA
    factor = np.where(low, factor * alpha / MIN_ALPHA, factor)
    return sigma_t, np.where(low, MIN_ALPHA, alpha), factor


# ----------------------------------------------------------------------------
# the stage

def split(v, u_lobe):
    """The vertices that take a subsurface lobe: returns (rows, slot, the
    selection left to the BSDF lobes (renormalized), their u_lobe, the
    BSDF lobes' share (N,))."""
    sel = v.lobes_wo[0]
    ss = kind_in(v.lobes.kind, IDS)
    q = np.where(ss, sel, 0.0)
    q_total = q.sum(axis=1)
    chose = u_lobe < q_total
    rows = np.flatnonzero(chose)
    cdf = np.cumsum(q[rows], axis=1)
    slot = np.minimum((u_lobe[rows, None] >= cdf).sum(axis=1), sel.shape[1] - 1)
    rest = 1.0 - q_total
    safe = np.where(rest > 0, rest, 1.0)
    bsdf_sel = np.where(ss, 0.0, sel) / safe[:, None]
    u_bsdf = np.clip((u_lobe - q_total) / safe, 0.0, 1.0 - 1e-12)
    return rows, slot, bsdf_sel, u_bsdf, rest


def sample(v, u):
    """The vertex's sample (bsdf.sample's (wi_l, weight, pdf, delta)) with
    the subsurface lobes taking their share of the lobe choice u[:, 0]:
    their rows get the entry bounce (``entry``), recorded in ``v.bssrdf``
    for ``walk``; the BSDF lobes' weights and pdfs include their share."""
    rows, slot, bsdf_sel, u_bsdf, share = split(v, u[:, 0])
    bent = np.zeros(len(u), bool)
    wi_l, weight, pdf, delta = bsdf.sample(v.lobes, v.wo_l, u_bsdf, u[:, 1], u[:, 2], bsdf_sel, v.lobes_wo[1],
                                           bent=bent)
    weight = weight / np.where(share > 0, share, 1.0)[:, None]
    pdf = pdf * share
    entry(v, rows, slot, u[:, 1], u[:, 2], wi_l, weight, pdf, delta)
    v.bssrdf = (rows, slot)
    bent[rows] = False
    v.sampled_bent = bent
    # Which rows sampled a diffuse-class lobe (Cycles' PATH_RAY_DIFFUSE_ANCESTOR
    # after the bounce), by the choice bsdf.sample made.
    cdf = np.cumsum(bsdf_sel, axis=1)
    chosen = np.minimum((u_bsdf[:, None] >= cdf).sum(axis=1), bsdf_sel.shape[1] - 1)
    kind = v.lobes.kind[np.arange(len(chosen)), chosen]
    diffuse = kind_in(kind, tuple(k for k in kinds_of_class("diffuse") if k not in IDS))
    diffuse[rows] = False
    v.sampled_diffuse = diffuse
    return wi_l, weight, pdf, delta


def entry(v, rows, slot, u1, u2, wi_l, weight, pdf, delta):
    """Cycles' subsurface_bounce for ``rows``: the entry direction and the
    closure weight over its selection probability, written into the
    sample arrays (wi_l, weight, pdf, delta) in place."""
    lobes = v.lobes
    sel, w = v.lobes_wo
    wi, ok = lobe_entry(lobes.kind[rows, slot], v.wo_l[rows], lobes.alpha[rows, slot], lobes.ior[rows, slot],
                        u1[rows], u2[rows])
    p = sel[rows, slot]
    wi_l[rows] = wi
    weight[rows] = np.where(ok[:, None], w[rows, slot] / np.where(p > 0, p, 1.0)[:, None], 0.0)
    pdf[rows] = p
    delta[rows] = True


def walk(ctx, paths, v, alive, depth):
    """The random walks (Christensen-Burley: the disk probes, ``disk``) of
    the paths that chose a subsurface lobe at ``v`` (``v.bssrdf``, set by
    ``sample``) and live on, from their new ray (inside the object).
    Updates their throughput and, for those that leave, points their ray
    at the exit from just outside and records its triangle
    (Paths.exit_prim, exit_hit).  Returns ``alive`` with the walks that
    found no exit ended."""
    rows, slot = v.bssrdf
    # Cycles' subsurface_bounce is no bounce (path_state_next is not called):
    # the exit vertex has the entry's bounce count.
    paths.bounce[rows] -= 1
    paths.diffuse_ancestor |= v.sampled_diffuse & alive
    keep = alive[rows]
    rows, slot = rows[keep], slot[keep]
    if len(rows) == 0:
        return alive
    alive = alive.copy()
    burley = v.lobes.kind[rows, slot] == SUBSURFACE_BURLEY
    for part, method in ((~burley, _walk_rows), (burley, disk)):
        if part.any():
            r = rows[part]
            beta, o, d, exit_prim, exit_bary = method(ctx, paths, v, r, slot[part], depth)
            alive[r[exit_prim < 0]] = False
            _leave(ctx, paths, r, beta, o, d, exit_prim, exit_bary)
    return alive


def _walk_rows(ctx, paths, v, rows, slot, depth):
    """``random_walk`` of the Random Walk and Skin rows."""
    albedo, radius, g = _params(v.lobes, rows, slot)
    sigma_t, alpha, factor = coefficients(albedo, radius, g)
    instance = ctx.triangles.shading.instance[v.hit.prim[rows]]
    return random_walk(ctx, paths.o[rows], paths.d[rows], paths.beta[rows] * factor, sigma_t, alpha, g, instance,
                       paths.pseed[rows], paths.sample[rows], depth, normal=v.hit.ns[rows], entry=v.hit.p[rows])


def _leave(ctx, paths, rows, beta, o, d, exit_prim, exit_bary):
    """The rows that found an exit at o, leaving along d: their throughput,
    the ray from just outside towards the exit (Cycles pretends the ray
    comes from outside) and the recorded triangle."""
    out = exit_prim >= 0
    rows, o, d = rows[out], o[out], d[out]
    s = ctx.accel.offset_scale(o)
    paths.beta[rows] = beta[out]
    paths.o[rows] = o + d * s[:, None]
    paths.d[rows] = -d
    paths.tmax[rows] = 2.0 * s
    paths.mis_o[rows] = paths.o[rows]
    paths.self_prim[rows] = -1
    paths.exit_prim[rows] = exit_prim[out]
    paths.exit_hit[rows] = np.column_stack([exit_bary[out], s])


# ----------------------------------------------------------------------------
# Christensen-Burley (kernel/integrator/subsurface_disk.h, closure/bssrdf.h)

BURLEY_TRUNCATE = 16.0
BURLEY_TRUNCATE_CDF = 0.9963790093708328


def burley_pdf(d, r):
    """bssrdf_burley_pdf: the normalized profile (times 2 pi, as its CDF)
    truncated at 16 d, over the truncated CDF; 0 at r = 0 and for d = 0."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        e3 = np.exp(-r / (3.0 * d))
        value = (e3 * e3 * e3 + e3) / (4.0 * d)
    ok = (d > 0) & (r < BURLEY_TRUNCATE * d) & (r != 0)
    return np.where(ok, value, 0.0) / BURLEY_TRUNCATE_CDF


def burley_root(xi):
    """bssrdf_burley_root_find: the scaled radius whose CDF is xi (Newton,
    Cycles' initial guess, at most 10 steps)."""
    r = np.where(xi <= 0.9, np.exp(xi * xi * 2.4) - 1.0, 15.0)
    going = np.ones(len(r), bool)
    for _ in range(10):
        e3 = np.exp(-r / 3.0)
        f = 1.0 - 0.25 * e3 * e3 * e3 - 0.75 * e3 - xi
        df = 0.25 * e3 * e3 * e3 + 0.25 * e3
        going &= ~((np.abs(f) < 1e-6) | (df == 0.0))
        r = np.where(going, np.maximum(r - f / np.where(df != 0, df, 1.0), 0.0), r)
    return r


def disk(ctx, paths, v, rows, slot, depth):
    """Cycles' subsurface_disk for ``rows``: a radius from the Burley profile
    of a channel (uniform over those with a radius), one of the three axes
    of the geometric normal's frame (1/2, 1/4, 1/4), a probe ray through
    the disk along it finding every surface of the object within the
    profile's reach, each hit weighted by the profile over the disk pdf
    and by the power heuristic over the axes, one hit resampled by weight.
    Returns (beta, exit points, outward normals there, exit triangle (-1:
    none), barycentrics) as ``random_walk``."""
    m = len(rows)
    hit = v.hit
    p, ng = hit.p[rows], hit.ng[rows]
    d = np.maximum(v.lobes.radius[rows, slot], 0.0) * (0.25 / np.pi)
    d = np.where(v.lobes.radius[rows, slot] < MIN_RADIUS, 0.0, d)
    u = ctx.sampler.get(paths.pseed[rows], paths.sample[rows], subsurface_set(depth, 0, 1))
    valid = d > 0
    channels = valid.sum(axis=1)
    xi = u[:, 0] * channels
    rank = np.minimum(np.floor(xi), np.maximum(channels - 1, 0))
    xi = xi - rank
    order = np.cumsum(valid, axis=1) - 1
    channel = np.argmax(valid & (order == rank[:, None]), axis=1)
    dc = d[np.arange(m), channel]
    disk_r = burley_root(xi * BURLEY_TRUNCATE_CDF) * dc
    height = np.sqrt(np.maximum((BURLEY_TRUNCATE * dc) ** 2 - disk_r ** 2, 0.0))
    t_axis, b_axis = make_orthonormals(ng)
    a = u[:, 1]
    pick = np.where(a < 0.5, 0, np.where(a < 0.75, 1, 2))
    a = np.where(pick == 0, 2.0 * a, np.where(pick == 1, (a - 0.5) * 4.0, (a - 0.75) * 4.0))
    axes = np.stack([ng, t_axis, b_axis], axis=1)            # N, T, B before the swap
    rows_m = np.arange(m)
    n_axis = axes[rows_m, pick]
    tt = np.where((pick == 1)[:, None], ng, t_axis)          # T <-> N when T is picked
    bb = np.where((pick == 2)[:, None], ng, b_axis)          # B <-> N when B is picked
    pick_pdf = np.array([0.5, 0.25, 0.25])   # of the axes N, T, B
    phi = 2.0 * np.pi * a
    offset = tt * (disk_r * np.cos(phi))[:, None] + bb * (disk_r * np.sin(phi))[:, None]
    origin = p + n_axis * height[:, None] + offset
    rays = NodeRays(ctx.accel, ctx.triangles, ctx.sampler, depth, {})
    instance = ctx.triangles.shading.instance[hit.prim[rows]]
    r_idx, prim, t, bu, bv = rays.local_hits(origin, -n_axis, 2.0 * height, instance)
    order_hits = np.lexsort((t, r_idx))
    r_idx, prim, t, bu, bv = r_idx[order_hits], prim[order_hits], t[order_hits], bu[order_hits], bv[order_hits]
    hit_p = origin[r_idx] - n_axis[r_idx] * t[:, None]
    hit_ng = rays.outward_normal(prim)
    if hit.back is not None:
        hit_ng = np.where(hit.back[rows][r_idx, None], -hit_ng, hit_ng)
    cos = np.abs(np.einsum("hkj,hj->hk", axes[r_idx], hit_ng))   # |N.Ng|, |T.Ng|, |B.Ng| (original frame)
    pdfs = pick_pdf * cos
    with np.errstate(divide="ignore", invalid="ignore"):
        # The power heuristic over the axes, the picked one's pdf over the sum of squares.
        w = pdfs[np.arange(len(r_idx)), pick[r_idx]] / np.sum(pdfs * pdfs, axis=1)
        r = np.linalg.norm(hit_p - p[r_idx], axis=1)
        value = burley_pdf(d[r_idx], r[:, None])
        pdf = burley_pdf(d[r_idx], disk_r[r_idx, None]).sum(axis=1) / np.maximum(channels[r_idx], 1)
        weight = np.where((pdf > 0)[:, None], value / np.where(pdf > 0, pdf, 1.0)[:, None], 0.0) * w[:, None]
    weight = np.where(np.isfinite(weight), weight, 0.0)
    sample_weight = np.abs(weight).mean(axis=1)
    total = np.bincount(r_idx, sample_weight, minlength=m)
    # Importance resampling: one hit per row in proportion to its weight.
    running = np.cumsum(sample_weight)
    start = np.concatenate([[0.0], running])[np.searchsorted(r_idx, rows_m)]
    target = u[:, 2] * total
    inside = running - start[r_idx]
    chosen = (inside > target[r_idx]) & (sample_weight > 0)
    hits_chosen = np.flatnonzero(chosen)
    first_by_row = np.full(m, len(r_idx), np.int64)
    np.minimum.at(first_by_row, r_idx[hits_chosen], hits_chosen)
    found = (first_by_row < len(r_idx)) & (total > 0)
    k = first_by_row[found]
    beta = np.zeros((m, 3))
    beta[found] = paths.beta[rows[found]] * weight[k] * (total[found] / sample_weight[k])[:, None]
    exit_prim = np.full(m, -1, np.int64)
    exit_prim[found] = prim[k]
    out_o, out_d = p.copy(), ng.copy()
    out_o[found], out_d[found] = hit_p[k], hit_ng[k]
    bary = np.zeros((m, 2))
    bary[found] = np.column_stack([bu[k], bv[k]])
    return beta, out_o, out_d, exit_prim, bary


# Columns of a walk's state row (``_walk_state``): position, direction,
# throughput, extinction and scattering (and their reduced forms past the
# similarity level), single-scattering albedo, g, entry normal and point,
# whether an opposite side was found and its distance, the guide's
# diffusion length, log term and guided share.
O, D, B, ST, SS, ST_STAR, SS_STAR, A, G, N, P0, HAVE, OPP, DL, PLOG, GF = (
    0, 3, 6, 9, 12, 15, 18, 21, 24, 25, 28, 31, 32, 33, 34, 35)
WIDTH = 36


def random_walk(ctx, o, d, beta, sigma_t, alpha, g, instance, pseed, sample, depth, normal=None, entry=None,
                guided=True, whole=True):
    """Cycles' subsurface_random_walk for N walks from o along d inside
    objects ``instance`` with extinction sigma_t (N, 3), single-scattering
    albedo alpha (N, 3) and Henyey-Greenstein g (N,), throughput beta
    (N, 3); ``normal`` (N, 3) is the entry's shading normal (outwards,
    default -d) and ``entry`` the entry point (default o), which the guided
    sampling steers by (``guided`` False: the classic walk alone).  Returns
    (beta, exit points, directions there, exit triangle (-1: no exit), its
    barycentrics).  Each walk runs from start to exit in one compiled loop
    (``_walk_paths``: every step traced by rtcIntersect1 in the object's
    own Embree scene); its NumPy form, and the form without Embree's C API
    (or ``whole`` False), is the wavefront ``_wavefront``: one state row per
    live walk, all walks a bounce at a time."""
    n = len(o)
    state = _walk_state(o, d, beta, sigma_t, alpha, g, normal, entry, guided)
    out_beta, out_o, out_d = np.zeros((n, 3)), np.array(o, np.float64), np.array(d, np.float64)
    exit_prim = np.full(n, -1, np.int64)
    exit_bary = np.zeros((n, 2))
    # Cycles gives up on a walk whose diffusion length is 1 (an infinite guided phase).
    ok = np.isfinite(state[:, DL]) & (state[:, DL] > 1.0)
    instance = np.asarray(instance, np.int64)
    start = np.flatnonzero(ok)
    start = start[np.argsort(instance[start], kind="stable")]
    if len(start) == 0:
        return out_beta, out_o, out_d, exit_prim, exit_bary
    inst = instance[start]
    pseed = np.ascontiguousarray(np.asarray(pseed)[start], np.uint32)
    sample = np.ascontiguousarray(np.asarray(sample)[start], np.uint32)
    state = np.ascontiguousarray(state[start])
    similar_fraction = 0.75 if guided else 0.0   # Cycles' isotropic heuristic past the similarity level
    outs = (out_beta[start], out_o[start], out_d[start], exit_prim[start], exit_bary[start])
    pattern = getattr(ctx.sampler, "pattern", None)
    scenes = _local_scenes(ctx, np.unique(inst)) if whole and pattern in (SOBOL, RANDOM) else None
    if scenes is None:
        numbers = _sampler_numbers(ctx.sampler, pseed, sample, depth)
        _wavefront(state, numbers, _accel_hits(ctx, inst), similar_fraction, outs)
    else:
        handles, prim_start, prims, index = scenes
        _walk_paths(state, index[inst], pseed, sample, _set_hashes(depth), pattern == RANDOM, handles, prim_start,
                    prims, np.uint64(embree_c.intersect1_address()), similar_fraction, _DIM_SALT64, _BYTES,
                    embree_c.ray_buffer(), *outs)
    out_beta[start], out_o[start], out_d[start], exit_prim[start], exit_bary[start] = outs
    return out_beta, out_o, out_d, exit_prim, exit_bary


def _wavefront(state, numbers, hits, similar_fraction, outs):
    """The walks a bounce at a time: the live ones are rows of ``state``,
    kept dense (finished ones written into ``outs`` and dropped); each
    bounce is two row loops (``_direction_rows``, ``_advance_rows``) around
    one intersection call for all live walks.  ``numbers(bounce, which,
    rows)``: the (M, 4) sample values of the rows' walks; ``hits(o, d,
    tmax, rows)``: (hit, t, global prim, barycentrics) on their objects."""
    out_beta, out_o, out_d, exit_prim, exit_bary = outs
    rows = np.arange(len(state))
    for bounce in range(MAX_BOUNCES):
        m = len(rows)
        if m == 0:
            break
        scatter, similar = bounce > 0, bounce > SIMILARITY_LEVEL
        u = np.ascontiguousarray(numbers(bounce, 0, rows), np.float64)
        u2 = np.ascontiguousarray(numbers(bounce, 1, rows), np.float64) if scatter else u
        t, tmax, terms = np.empty(m), np.empty(m), np.empty((m, 6))
        _direction_rows(u, u2, state, scatter, similar, similar_fraction, t, tmax, terms)
        hit, t_hit, prim, bary = hits(state[:, O:O + 3], state[:, D:D + 3], tmax, rows)
        done = np.empty(m, bool)
        _advance_rows(hit, t_hit, t, state, terms, scatter, similar, done)
        if done.any():
            r = rows[hit]
            out_beta[r], out_o[r], out_d[r] = state[hit, B:B + 3], state[hit, O:O + 3], state[hit, D:D + 3]
            exit_prim[r], exit_bary[r] = prim[hit], bary[hit]
            keep = np.flatnonzero(~done)
            rows, state = rows[keep], state[keep]


def _sampler_numbers(sampler, pseed, sample, depth):
    """``numbers`` for ``_wavefront`` from a sampler."""
    return lambda bounce, which, rows: sampler.get(pseed[rows], sample[rows], subsurface_set(depth, bounce, which))


def _hashed_numbers(pseed, sample, hashes, random):
    """``numbers`` for ``_wavefront`` from the dimension sets' hashes (the
    sampler's own functions, as ``_numbers_one`` computes them per walk)."""
    def numbers(bounce, which, rows):
        out = np.empty((len(rows), 4))
        if random:
            out[:] = _random4_hashed(pseed[rows], sample[rows], hashes[bounce, which])
        else:
            _sobol4_into(pseed[rows], sample[rows], hashes[bounce, which], out, _HI, _LO, _DIM_SALT64, _BYTES)
        return out
    return numbers


def _random4_hashed(pseed, sample, set_hash):
    """sampler.random4 given its dimension set's hash."""
    base = hash32(pseed ^ hash32(np.asarray(sample, np.uint32) + np.uint32(set_hash)))
    return np.stack([hash32(base ^ np.uint32(salt)) for salt in _DIM_SALT64], axis=1) * _TO_UNIT


_HASHES = {}


def _set_hashes(depth):
    """(MAX_BOUNCES, 2) uint32: the hash of subsurface_set(depth, bounce, which)."""
    table = _HASHES.get(depth)
    if table is None:
        table = np.array([[_hash_scalar(subsurface_set(depth, b, w)) for w in (0, 1)] for b in range(MAX_BOUNCES)],
                         np.uint32)
        _HASHES[depth] = table
    return table


def _accel_hits(ctx, inst):
    """``hits`` for ``_wavefront`` through the objects' own Accels (``local_accel``)."""
    return lambda o, d, tmax, rows: _local_hits(ctx, o, d, tmax, inst[rows])


# ----------------------------------------------------------------------------
# the objects' own Embree scenes (Cycles' same-object rule), for ``_walk_paths``

_SCENES = weakref.WeakKeyDictionary()   # scene Accel -> {instance: embree_c.TriangleScene}
_BY_HANDLE = weakref.WeakValueDictionary()   # handle -> TriangleScene (``_walk_paths_numpy``)
_SCENES_LOCK = threading.Lock()


def _local_scenes(ctx, instances):
    """(handles (K,) uint64, each scene's first row in ``prims`` (K + 1,),
    the global triangle of each scene's triangles, instance -> index into
    handles (max instance + 1,)) for the objects ``instances`` (built once
    per render and object, shared by the threads); None without Embree's C
    API."""
    if not embree_c.available():
        return None
    with _SCENES_LOCK:
        per_scene = _SCENES.setdefault(ctx.accel, {})
        for inst in instances:
            if int(inst) not in per_scene:
                per_scene[int(inst)] = _object_scene(ctx.triangles, int(inst))
        built = [(inst, per_scene[int(inst)]) for inst in instances]
    index = np.full(int(instances.max()) + 1, -1, np.int64)
    index[instances] = np.arange(len(instances))
    handles = np.array([scene.handle for _, scene in built], np.uint64)
    counts = [len(scene.order) for _, scene in built]
    prim_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    prims = np.concatenate([scene.order for _, scene in built]).astype(np.int64)
    return handles, prim_start, prims, index


def _object_scene(triangles, instance):
    """An Embree scene of one object's triangles (a corner soup, as the Accel)."""
    prims = np.flatnonzero(triangles.shading.instance == instance)
    p0, e1, e2 = triangles.p0[prims], triangles.e1[prims], triangles.e2[prims]
    corners = np.stack([p0, p0 + e1, p0 + e2], axis=1).astype(np.float32).reshape(1, -1, 3)
    scene = embree_c.TriangleScene([(corners, np.arange(3 * len(prims)).reshape(-1, 3), prims)])
    _BY_HANDLE[scene.handle] = scene
    return scene


def _walk_state(o, d, beta, sigma_t, alpha, g, normal, entry, guided):
    """The (N, WIDTH) state rows of N walks at their start."""
    n = len(o)
    g = np.array(np.broadcast_to(np.asarray(g, np.float64), (n,)))
    sigma_t = np.asarray(sigma_t, np.float64)
    alpha = np.asarray(alpha, np.float64)
    sigma_s = sigma_t * alpha
    # Past the similarity level: isotropic with the reduced scattering coefficient.
    sigma_s_star = sigma_s * (1.0 - g)[:, None]
    state = np.zeros((n, WIDTH))
    state[:, O:O + 3], state[:, D:D + 3], state[:, B:B + 3] = o, d, beta
    state[:, ST:ST + 3], state[:, SS:SS + 3] = sigma_t, sigma_s
    state[:, ST_STAR:ST_STAR + 3], state[:, SS_STAR:SS_STAR + 3] = sigma_t - sigma_s + sigma_s_star, sigma_s_star
    state[:, A:A + 3], state[:, G] = alpha, g
    state[:, N:N + 3] = -np.asarray(d, np.float64) if normal is None else normal
    state[:, P0:P0 + 3] = o if entry is None else entry
    state[:, DL], state[:, PLOG], state[:, GF] = guide_terms(alpha, g, guided)
    return state


def guide_terms(alpha, g, guided):
    """Cycles' guiding constants per walk: the Dwivedi diffusion length of
    the largest single-scattering albedo (Eq. 67 of d'Eon and Krivanek
    2020), log((v + 1) / (v - 1)) for its phase, and the share of guided
    steps, 1 - max(0.5, |g|^(1/8)) (0 when not ``guided``)."""
    a = np.max(alpha, axis=1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        length = 1.0 / np.sqrt(1.0 - a ** (2.44294 - 0.0215813 * a + 0.578637 / a))
        phase_log = np.log((length + 1.0) / (length - 1.0))
    fraction = 1.0 - np.maximum(0.5, np.abs(g) ** 0.125) if guided else np.zeros(len(a))
    return length, phase_log, fraction


def _channel_pdf(b, a):
    """Cycles' volume_sample_channel_pdf: |throughput x albedo| normalized, else uniform."""
    w = np.abs(b * a)
    total = w.sum(axis=1)
    return np.where(total[:, None] > 0, w / np.where(total > 0, total, 1.0)[:, None], 1.0 / 3.0)


def _coefficients_now(state, similar, similar_fraction):
    """(sigma_t, sigma_s, g, guided share) of this bounce's walks."""
    if similar:
        m = len(state)
        return (state[:, ST_STAR:ST_STAR + 3], state[:, SS_STAR:SS_STAR + 3], np.zeros(m),
                np.full(m, similar_fraction))
    return state[:, ST:ST + 3], state[:, SS:SS + 3], state[:, G], state[:, GF]


def _hg_numpy(cos, g):
    """phase_henyey_greenstein (g already clamped)."""
    fac = 1.0 + g * (g - 2.0 * cos)
    return np.where(np.abs(g) < 1e-3, 0.25 / np.pi, (1.0 - g * g) / (4.0 * np.pi * fac * np.sqrt(np.maximum(fac, 0.0))))


def _around_numpy(axis, cos, u):
    """The unit direction at polar cosine ``cos`` about ``axis`` (N, 3), azimuth 2 pi u."""
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    phi = 2.0 * np.pi * u
    x, y = sin * np.cos(phi), sin * np.sin(phi)
    sign = 2.0 * (axis[:, 2] >= 0.0) - 1.0
    q = -1.0 / (sign + axis[:, 2])
    r = axis[:, 0] * axis[:, 1] * q
    s = np.stack([1.0 + sign * axis[:, 0] * axis[:, 0] * q, sign * r, -sign * axis[:, 0]], axis=1)
    t = np.stack([r, sign + axis[:, 1] * axis[:, 1] * q, -axis[:, 1]], axis=1)
    new = x[:, None] * s + y[:, None] * t + cos[:, None] * axis
    return new / np.sqrt(np.sum(new * new, axis=1))[:, None]


def _direction_numpy(u, u2, state, scatter, similar, similar_fraction, t, tmax, terms):
    """The next direction (in place, when ``scatter``): guided (Dwivedi's
    phase about the entry normal, towards the entry side or, near an
    opposite side, mirrored away from it) with the guided share's
    probability by u2[:, 0], else Henyey-Greenstein about d; the colour
    channel by u[:, 0] and a free-flight distance t of its extinction
    (stretched when guided) by u[:, 1]; tmax the distance to trace (the
    first step looks 10 mean free paths ahead for an opposite side).
    ``terms`` keeps what the pdf needs after the ray-cast: guided share,
    backward share, the guided forward and backward phase over
    Henyey-Greenstein's, the forward and backward stretchings."""
    m = len(t)
    st, _, g, gf = _coefficients_now(state, similar, similar_fraction)
    d, o, nrm, p0 = state[:, D:D + 3], state[:, O:O + 3], state[:, N:N + 3], state[:, P0:P0 + 3]
    have, opp, dl, plog = state[:, HAVE] > 0, state[:, OPP], state[:, DL], state[:, PLOG]
    cpdf = _channel_pdf(state[:, B:B + 3], state[:, A:A + 3])
    channel = (u[:, 0] >= cpdf[:, 0]).astype(np.int64) + (u[:, 0] >= cpdf[:, 0] + cpdf[:, 1])
    sample_st = st[np.arange(m), channel]
    if not scatter:
        terms[:] = (0.0, 0.0, 1.0, 1.0, 1.0, 1.0)
        t[:] = -np.log1p(-u[:, 1]) / sample_st
        tmax[:] = np.maximum(t, 10.0 / st.min(axis=1))
        return
    gc = np.clip(g, -G_LIMIT, G_LIMIT)
    guided = u2[:, 0] < gf
    x = np.minimum(np.maximum(np.sum((o - p0) * -nrm, axis=1), 0.0), opp)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        back_share = np.where(have, 1.0 / (1.0 + np.exp((opp - 2.0 * x) / dl)), 0.0)
    backward = have & (u2[:, 1] < back_share)
    # classic: Henyey-Greenstein about d
    iso = np.abs(gc) < 1e-3
    gs = np.where(iso, 0.5, gc)
    k = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u[:, 2])
    cos_hg = np.clip(np.where(iso, 1.0 - 2.0 * u[:, 2], (1.0 + gs * gs - k * k) / (2.0 * gs)), -1.0, 1.0)
    classic = _around_numpy(d, cos_hg, u[:, 3])
    # guided: Dwivedi's phase about the entry normal
    cos_g = dl - (dl + 1.0) * np.exp(-u[:, 2] * plog)
    cos_g = np.where(backward, -cos_g, cos_g)
    steered = _around_numpy(nrm, np.clip(cos_g, -1.0, 1.0), u[:, 3])
    hg = _hg_numpy(np.where(guided, np.sum(d * steered, axis=1), cos_hg), gc)
    new = np.where(guided[:, None], steered, classic)
    cos = np.where(guided, cos_g, np.sum(new * nrm, axis=1))
    state[:, D:D + 3] = new
    with np.errstate(divide="ignore", invalid="ignore"):
        forward = 1.0 / ((dl - cos) * plog) / (2.0 * np.pi * hg)
        mirrored = 1.0 / ((dl + cos) * plog) / (2.0 * np.pi * hg)
    stretch_f, stretch_b = 1.0 - cos / dl, 1.0 + cos / dl
    terms[:] = np.stack([gf, back_share, forward, mirrored, stretch_f, stretch_b], axis=1)
    sample_st = sample_st * np.where(guided, np.where(backward, stretch_b, stretch_f), 1.0)
    t[:] = -np.log1p(-u[:, 1]) / sample_st
    tmax[:] = t


@loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], boolean, boolean, float64, float64[::1], "
             "float64[::1], float64[:, ::1])", _direction_numpy)
def _direction_rows(u, u2, state, scatter, similar, similar_fraction, t, tmax, terms):
    for i in range(len(t)):
        t[i], tmax[i] = _direction_one(u[i], u2[i], state[i], scatter, similar, similar_fraction, terms[i])


@helper
def _direction_one(u, u2, s, scatter, similar, similar_fraction, terms):
    """``_direction_numpy`` of one walk (state row s, its terms row):
    returns (t, tmax)."""
    stc = ST_STAR if similar else ST
    w0, w1, w2 = abs(s[B] * s[A]), abs(s[B + 1] * s[A + 1]), abs(s[B + 2] * s[A + 2])
    total = w0 + w1 + w2
    p0c, p1c = (w0 / total, w1 / total) if total > 0 else (1.0 / 3.0, 1.0 / 3.0)
    c = (1 if u[0] >= p0c else 0) + (1 if u[0] >= p0c + p1c else 0)
    sample_st = s[stc + c]
    if not scatter:
        terms[0], terms[1], terms[2], terms[3], terms[4], terms[5] = 0.0, 0.0, 1.0, 1.0, 1.0, 1.0
        t = -np.log1p(-u[1]) / sample_st
        return t, max(t, 10.0 / min(s[stc], min(s[stc + 1], s[stc + 2])))
    gc = 0.0 if similar else min(max(s[G], -G_LIMIT), G_LIMIT)
    gf = similar_fraction if similar else s[GF]
    dl, plog = s[DL], s[PLOG]
    guided = u2[0] < gf
    back_share = 0.0
    backward = False
    if s[HAVE] > 0:
        x = -((s[O] - s[P0]) * s[N] + (s[O + 1] - s[P0 + 1]) * s[N + 1] + (s[O + 2] - s[P0 + 2]) * s[N + 2])
        x = min(max(x, 0.0), s[OPP])
        back_share = 1.0 / (1.0 + np.exp((s[OPP] - 2.0 * x) / dl))
        backward = u2[1] < back_share
    if guided:
        cos = dl - (dl + 1.0) * np.exp(-u[2] * plog)
        if backward:
            cos = -cos
        n0, n1, n2 = _around(s[N], s[N + 1], s[N + 2], min(max(cos, -1.0), 1.0), u[3])
        cos_d = s[D] * n0 + s[D + 1] * n1 + s[D + 2] * n2
    else:
        if abs(gc) < 1e-3:
            cos_d = 1.0 - 2.0 * u[2]
        else:
            k = (1.0 - gc * gc) / (1.0 - gc + 2.0 * gc * u[2])
            cos_d = (1.0 + gc * gc - k * k) / (2.0 * gc)
        cos_d = min(max(cos_d, -1.0), 1.0)
        n0, n1, n2 = _around(s[D], s[D + 1], s[D + 2], cos_d, u[3])
        cos = n0 * s[N] + n1 * s[N + 1] + n2 * s[N + 2]
    s[D], s[D + 1], s[D + 2] = n0, n1, n2
    hg = _hg(cos_d, gc)
    terms[0], terms[1] = gf, back_share
    terms[2] = 1.0 / ((dl - cos) * plog) / (2.0 * np.pi * hg)
    terms[3] = 1.0 / ((dl + cos) * plog) / (2.0 * np.pi * hg)
    terms[4], terms[5] = 1.0 - cos / dl, 1.0 + cos / dl
    if guided:
        sample_st *= terms[5] if backward else terms[4]
    t = -np.log1p(-u[1]) / sample_st
    return t, t


@helper
def _hg(cos, g):
    """phase_henyey_greenstein (g already clamped)."""
    if abs(g) < 1e-3:
        return 0.25 / np.pi
    fac = 1.0 + g * (g - 2.0 * cos)
    return (1.0 - g * g) / (4.0 * np.pi * fac * np.sqrt(max(fac, 0.0)))


@helper
def _around(a0, a1, a2, cos, u):
    """The unit direction at polar cosine ``cos`` about the unit axis a, azimuth 2 pi u."""
    sin = np.sqrt(max(1.0 - cos * cos, 0.0))
    phi = 2.0 * np.pi * u
    x, y = sin * np.cos(phi), sin * np.sin(phi)
    s0, s1, s2, t0, t1, t2 = frame_of(a0, a1, a2)
    n0 = x * s0 + y * t0 + cos * a0
    n1 = x * s1 + y * t1 + cos * a1
    n2 = x * s2 + y * t2 + cos * a2
    length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    return n0 / length, n1 / length, n2 / length


def _advance_numpy(hit, t_hit, t, state, terms, scatter, similar, done):
    """Cycles' update after the ray-cast: on the first step a hit within
    the look-ahead records the opposite side's distance along -normal and
    counts as an exit only within t; the distance (to the exit where the
    segment met the surface), the throughput by one-sample MIS over the
    channels and, after the first step, the classic, guided and backward
    guided samplings (transmittance, times sigma_s at a scattering), the
    point moved on (all in place); ``done``: exited or faded."""
    st, ss, _, _ = _coefficients_now(state, similar, 0.0)
    o, d, b = state[:, O:O + 3], state[:, D:D + 3], state[:, B:B + 3]
    if not scatter:
        far = o + d * np.where(hit, t_hit, 0.0)[:, None]
        state[:, OPP] = np.where(hit, np.sum((far - state[:, P0:P0 + 3]) * -state[:, N:N + 3], axis=1), state[:, OPP])
        state[:, HAVE] = np.where(hit, 1.0, state[:, HAVE])
        hit &= t_hit < t
    have = state[:, HAVE] > 0
    t[:] = np.where(hit, t_hit, t)
    cpdf = _channel_pdf(b, state[:, A:A + 3])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        tr = np.exp(-st * t[:, None])
        pdf = _distance_pdf(st, t, hit)
        if scatter:
            gf, back_share, forward, mirrored, stretch_f, stretch_b = (terms[:, k, None] for k in range(6))
            steered = _distance_pdf(stretch_f * st, t, hit) * forward
            away = _distance_pdf(stretch_b * st, t, hit) * mirrored
            steered = np.where(have[:, None], (1.0 - back_share) * steered + back_share * away, steered)
            pdf = (1.0 - gf) * pdf + gf * steered
        step = b * np.where(hit[:, None], tr, ss * tr) / np.sum(cpdf * pdf, axis=1)[:, None]
    b[:] = np.where(np.isfinite(step), step, 0.0)
    o += d * t[:, None]
    done[:] = hit | (np.max(b, axis=1) < THROUGHPUT_EPSILON)


def _distance_pdf(st, t, hit):
    """subsurface_random_walk_pdf: transmittance at an exit, sigma_t times it at a scattering."""
    tr = np.exp(-st * t[:, None])
    return np.where(hit[:, None], tr, st * tr)


@loop_kernel("void(boolean[::1], float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], boolean, boolean, "
             "boolean[::1])", _advance_numpy)
def _advance_rows(hit, t_hit, t, state, terms, scatter, similar, done):
    for i in range(len(t)):
        hit[i], t[i], done[i] = _advance_one(hit[i], t_hit[i], t[i], state[i], terms[i], scatter, similar)


@helper
def _advance_one(hit, t_hit, t, s, terms, scatter, similar):
    """``_advance_numpy`` of one walk (state row s, its terms row):
    returns (hit, t, done)."""
    stc = ST_STAR if similar else ST
    ssc = SS_STAR if similar else SS
    if not scatter and hit:
        s[OPP] = -((s[O] + s[D] * t_hit - s[P0]) * s[N] + (s[O + 1] + s[D + 1] * t_hit - s[P0 + 1]) * s[N + 1]
                   + (s[O + 2] + s[D + 2] * t_hit - s[P0 + 2]) * s[N + 2])
        s[HAVE] = 1.0
        hit = t_hit < t
    if hit:
        t = t_hit
    w0, w1, w2 = abs(s[B] * s[A]), abs(s[B + 1] * s[A + 1]), abs(s[B + 2] * s[A + 2])
    total = w0 + w1 + w2
    if total > 0:
        p0c, p1c, p2c = w0 / total, w1 / total, w2 / total
    else:
        p0c = p1c = p2c = 1.0 / 3.0
    denom = 0.0
    for c, pc in ((0, p0c), (1, p1c), (2, p2c)):
        sc = s[stc + c]
        pdf = _step_pdf(sc, t, hit)
        if scatter:
            steered = _step_pdf(terms[4] * sc, t, hit) * terms[2]
            if s[HAVE] > 0:
                away = _step_pdf(terms[5] * sc, t, hit) * terms[3]
                steered = (1.0 - terms[1]) * steered + terms[1] * away
            pdf = (1.0 - terms[0]) * pdf + terms[0] * steered
        denom += pc * pdf
    largest = 0.0
    for c in range(3):
        tr = np.exp(-s[stc + c] * t)
        f = tr if hit else s[ssc + c] * tr
        v = s[B + c] * f / denom if denom != 0 else np.nan
        v = v if np.isfinite(v) else 0.0
        s[B + c] = v
        largest = v if c == 0 else max(largest, v)
    s[O] += s[D] * t
    s[O + 1] += s[D + 1] * t
    s[O + 2] += s[D + 2] * t
    return hit, t, hit or largest < THROUGHPUT_EPSILON


@helper
def _step_pdf(st, t, hit):
    """subsurface_random_walk_pdf of one channel."""
    tr = np.exp(-st * t)
    if hit:
        return tr
    return st * tr


_15, _HASH_A, _HASH_B = np.uint64(15), np.uint64(0x7FEB352D), np.uint64(0x846CA68B)   # sampler.hash32


@helper
def _mix32(x):
    """sampler.hash32 of a uint64 holding 32 bits."""
    x ^= x >> _16
    x = (x * _HASH_A) & _M32
    x ^= x >> _15
    x = (x * _HASH_B) & _M32
    return x ^ (x >> _16)


@helper
def _numbers_one(ps, smp, set_hash, random, salts, byte_table, out):
    """The four sample values of one walk's dimension set (hash ``set_hash``)
    into ``out``: sampler.sobol4 (the loop of sampler._sobol4_into) or
    sampler.random4 for one path."""
    if random:
        base = _mix32(np.uint64(ps) ^ _mix32((np.uint64(smp) + np.uint64(set_hash)) & _M32))
        for d in range(4):
            out[d] = np.float64(np.int64(_mix32(base ^ salts[d]))) * _TO_UNIT
        return
    _sobol4_one(ps, smp, set_hash, salts, byte_table, out)


def _walk_paths_numpy(state, obj, pseed, sample, hashes, random, handles, prim_start, prims, fn, similar_fraction,
                      salts, byte_table, buf, out_beta, out_o, out_d, exit_prim, exit_bary):
    """``_walk_paths``' NumPy form: the wavefront, tracing by Embree packets."""
    scenes = [_BY_HANDLE[int(h)] for h in handles]

    def hits(o, d, tmax, rows):
        hit, t, prim, bary = np.zeros(len(rows), bool), np.full(len(rows), np.inf), np.full(len(rows), -1), \
            np.zeros((len(rows), 2))
        for k in np.unique(obj[rows]):
            part = np.flatnonzero(obj[rows] == k)
            tk, pk, uk, vk = scenes[k].intersect(o[part], d[part], tmax[part], 0.0, loops=())
            found = (pk >= 0) & (tk <= tmax[part])
            hit[part], t[part] = found, np.where(found, tk, np.inf)
            prim[part] = np.where(found, pk, -1)
            bary[part, 0], bary[part, 1] = uk, vk
        return hit, t, prim, bary

    _wavefront(state, _hashed_numbers(pseed, sample, hashes, random), hits, similar_fraction,
               (out_beta, out_o, out_d, exit_prim, exit_bary))


@embree_c.embree_loop_kernel(
    "void(float64[:, ::1], int64[::1], uint32[::1], uint32[::1], uint32[:, ::1], boolean, uint64[::1], int64[::1], "
    "int64[::1], uint64, float64, uint64[::1], uint32[:, :, ::1], float32[::1], float64[:, ::1], float64[:, ::1], "
    "float64[:, ::1], int64[::1], float64[:, ::1])", _walk_paths_numpy)
def _walk_paths(state, obj, pseed, sample, hashes, random, handles, prim_start, prims, fn, similar_fraction,
                salts, byte_table, buf, out_beta, out_o, out_d, exit_prim, exit_bary):
    """Each walk from start to exit or fade (``_direction_one``, a ray in
    its object's scene, ``_advance_one``), written into the outputs on an
    exit; ``buf`` one RTCRayHit."""
    w = buf.view(np.uint32)
    addr = np.uint64(buf.ctypes.data)
    u, u2, terms = np.empty(4), np.empty(4), np.empty(6)
    for i in range(len(state)):
        s = state[i]
        k = obj[i]
        handle = handles[k]
        for bounce in range(MAX_BOUNCES):
            scatter, similar = bounce > 0, bounce > SIMILARITY_LEVEL
            _numbers_one(pseed[i], sample[i], hashes[bounce, 0], random, salts, byte_table, u)
            if scatter:
                _numbers_one(pseed[i], sample[i], hashes[bounce, 1], random, salts, byte_table, u2)
            t, tmax = _direction_one(u, u2, s, scatter, similar, similar_fraction, terms)
            buf[0], buf[1], buf[2], buf[3] = s[O], s[O + 1], s[O + 2], 0.0
            buf[4], buf[5], buf[6], buf[7] = s[D], s[D + 1], s[D + 2], 0.0
            buf[8] = 1e37 if tmax > 1e37 else tmax   # NaN stays NaN (no hit), as np.minimum
            w[9], w[10], w[11] = 0xFFFFFFFF, 0, 0
            w[18], w[19] = 0xFFFFFFFF, 0xFFFFFFFF
            embree_c.rtc_call(fn, handle, addr, np.uint64(0))
            t_hit = np.float64(buf[8])
            hit = w[18] != 0xFFFFFFFF and t_hit <= tmax
            if not hit:
                t_hit = np.inf
            hit, t, done = _advance_one(hit, t_hit, t, s, terms, scatter, similar)
            if done:
                if hit:
                    for c in range(3):
                        out_beta[i, c], out_o[i, c], out_d[i, c] = s[B + c], s[O + c], s[D + c]
                    exit_prim[i] = prims[prim_start[k] + np.int64(w[17])]
                    exit_bary[i, 0], exit_bary[i, 1] = np.float64(buf[15]), np.float64(buf[16])
                break


def _local_hits(ctx, o, d, tmax, instance):
    """The first hit on each ray's own object within tmax: (hit (N,) bool,
    t, global prim, barycentrics (N, 2)); the rows come sorted by object."""
    n = len(o)
    if instance[0] == instance[-1]:   # one object (sorted rows): no gathering
        accel, prims = local_accel(ctx.accel, ctx.triangles, int(instance[0]))
        ti, pi, bu, bv = accel.intersect(o, d, tmax)
        hit = (pi >= 0) & (ti <= tmax)
        prim = np.full(n, -1, np.int64)
        prim[hit] = prims[pi[hit]]
        return hit, np.where(hit, ti, np.inf), prim, np.column_stack([bu, bv])
    hit, t, prim, bary = np.zeros(n, bool), np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 2))
    bounds = np.concatenate([[0], np.flatnonzero(instance[1:] != instance[:-1]) + 1, [n]])
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        accel, prims = local_accel(ctx.accel, ctx.triangles, int(instance[lo]))
        ti, pi, bu, bv = accel.intersect(o[lo:hi], d[lo:hi], tmax[lo:hi])
        found = (pi >= 0) & (ti <= tmax[lo:hi])
        hit[lo:hi], t[lo:hi] = found, np.where(found, ti, np.inf)
        prim[lo:hi][found] = prims[pi[found]]
        bary[lo:hi, 0], bary[lo:hi, 1] = bu, bv
    return hit, t, prim, bary


def arrive(paths, found):
    """The next bounce's hits of the paths on their way to a subsurface
    exit: the recorded triangle, no light on the way; marks them (-2) for
    ``exit_lobes``."""
    rows = np.flatnonzero(paths.exit_prim >= 0)
    if len(rows) == 0:
        return
    found.prim[rows] = paths.exit_prim[rows]
    found.bu[rows], found.bv[rows], found.t[rows] = paths.exit_hit[rows].T
    found.light[rows] = False
    paths.exit_prim[rows] = -2


def walking(paths):
    """Paths on their way to an exit point (after ``walk``, before the next
    bounce): their vertex counts no bounce kind and keeps the previous one's
    MIS record (the exit collects no emission)."""
    return paths.exit_prim >= 0


def at_exit(paths):
    """Paths shading a subsurface exit point this bounce."""
    return paths.exit_prim == -2


def exit_lobes(paths, lobes):
    """Cycles' subsurface_shader_data_setup: a white diffuse lobe of weight 1
    replaces the material's lobes at exit points (under the shading normal
    the material's normal map or bump gives); the mark is cleared.  After a
    diffuse bounce a Christensen-Burley lobe is a diffuse one (Cycles'
    bssrdf_setup with PATH_RAY_DIFFUSE_ANCESTOR)."""
    after = paths.diffuse_ancestor[:, None] & (lobes.kind == SUBSURFACE_BURLEY)
    if after.any():
        lobes.kind[after] = DIFFUSE
    rows = np.flatnonzero(at_exit(paths))
    if len(rows) == 0:
        return
    for param in EXTRA_PARAMS:
        getattr(lobes, param.field)[rows] = table_value(param, _WHITE)
    lobes.kind[rows] = NONE
    lobes.kind[rows, 0] = DIFFUSE
    lobes.color[rows] = 0.0
    lobes.color[rows, 0] = 1.0
    lobes.alpha[rows] = 1.0
    lobes.schlick[rows] = False
    paths.exit_prim[rows] = -1


def _params(lobes, rows, slot):
    albedo = np.clip(lobes.color[rows, slot], 0.0, 1.0)
    ior = np.clip(lobes.ior[rows, slot], *IOR_RANGE)
    g = np.clip(lobes.phase_g[rows, slot], *G_RANGE)
    skin = lobes.kind[rows, slot] == SUBSURFACE_SKIN
    radius = remapped_radius(np.maximum(lobes.radius[rows, slot], MIN_RADIUS), albedo, ior, skin)
    return albedo, radius, g
