"""Transparency (Transparent BSDF, Principled Alpha: the 'transparent'
lobe), as Cycles' transparent bounces and shadows: a pass straight through
a sampled transparent lobe is not a vertex; paths past max_bounces still
cross transparent surfaces; shadow rays cross them, attenuated.  Scenes
without a transparent lobe (Context.transparent_shadows False) never get
here."""
import numpy as np

from .. import bsdf
from ..geometry import VIS_SHADOW
from ..lobes.ray_portal import portal_rows
from ..media import transmittance_factor
from ..nodes import ShadingContext
from ..points import curve_rows
from ..vec import dot, row_any_positive
from .visibility import skip_invisible


def pass_light(ctx, paths, i):
    """Paths ``i`` met a light: as Cycles (integrator_shade_light) they go on
    past it to the surface or world behind, counting a transparent bounce,
    and end once that count reaches transparent_max_bounces (so with 0 or 1
    a light still ends the path).  Returns which of ``i`` end."""
    paths.tbounce[i] += 1
    return paths.tbounce[i] >= ctx.settings.transparent_max_bounces


def film_alpha_through(paths, i, tile):
    """Camera rays that leave through transparent surfaces uncover the
    transparent film by their throughput (Cycles: alpha = 1 - the average
    throughput of such rays); their first hit counted them opaque."""
    if len(i):
        np.subtract.at(tile.alpha, paths.pix[i] - tile.lo, paths.beta[i].mean(axis=1))


def last_vertices(ctx, paths):
    """Which paths are at a vertex that only collects emission: past
    max_bounces or volume_bounces, or (Cycles' TERMINATE_ON_NEXT_SURFACE)
    past the last transparent pass."""
    last = paths.bounce > ctx.settings.max_bounces
    if ctx.count_kinds:
        last |= np.any(paths.kinds > ctx.kind_limits, axis=1)
    if ctx.media is not None:
        # Past its volume bounces a path ends the same way (Cycles sets
        # PATH_RAY_TERMINATE_AFTER_TRANSPARENT for both).
        last |= paths.vbounce > ctx.settings.volume_bounces
    if ctx.transparent_shadows:
        last |= paths.tbounce >= ctx.transparent_limit
    return last


def pass_last(ctx, paths, hit, shading):
    """Paths at a vertex that only collects emission (past max_bounces)
    still cross transparent surfaces, weighted by their transparency, as
    Cycles (TERMINATE_AFTER_TRANSPARENT keeps the transparent closure).
    Moves those on in place; returns which go on (the others end here)."""
    go = paths.tbounce < ctx.transparent_limit
    if ctx.media is not None:
        go |= ctx.media.boundary[hit.mat]     # volume boundaries count no transparent bounce
    go &= ctx.transparent_mat[hit.mat]
    rows = np.nonzero(go)[0]
    if len(rows):
        T = bsdf.transparency(ctx.materials.gather(hit.mat[rows], shading(hit).take(rows)))
        paths.beta[rows] *= T
        go[rows] = row_any_positive(T)
    return go


def step_through(ctx, paths, hit):
    """Move paths on past the transparent surfaces ``hit``, same direction."""
    o = ctx.accel.offset_origin(hit.p, hit.ng, paths.d, hit.eps)
    paths.tmax = paths.tmax - dot(o - paths.o, paths.d)
    paths.o = o
    paths.tbounce = paths.tbounce + 1
    if ctx.strands is not None:   # a transparent strand is passed whole
        paths.self_prim = curve_rows(ctx.strands, hit.prim)


def sampled_transparent(ctx, hit, delta, wi_l, wo_l):
    """Which samples chose a transparent lobe: bsdf.sample returns exactly
    -wo for them (a delta sample; refraction through glass of IOR 1 is not
    bit-exact, and materials without a transparent lobe are excluded)."""
    if not ctx.transparent_shadows:
        return np.zeros(len(delta), bool)
    return delta & ctx.transparent_mat[hit.mat] & np.all(wi_l == -wo_l, axis=1)


# Surfaces a shadow ray crosses at most (volume boundaries count no
# transparent bounce; Cycles' VOLUME_BOUNDS_MAX): past them it is blocked.
VOLUME_BOUNDS_MAX = 1024


def transmittance(ctx, origin, wi, tmax, emitter, tbounce, stack=None, rng=None, time=None, skip=None):
    """(N, 3) light reaching the shadow rays' ends through transparent
    surfaces (Cycles' transparent shadows).  embreex has no any-hit filter,
    so each ray is traced again from past its transparent hit, times that
    surface's transparency; an opaque hit blocks it, and so does a
    transparent hit beyond the transparent bounces its path has left.
    ``stack`` (N, K): the media each ray starts in (engine/media), whose
    transmittance multiplies each segment; crossing a surface enters or
    leaves its material's medium.  ``skip`` (N,): the curve row each ray
    leaves, passed on its first segment (None: none)."""
    n = len(origin)
    out = np.ones((n, 3))
    cast = np.ones(n, bool)
    if ctx.light_no_shadow:
        cast = (ctx.lights.visibility[emitter] & VIS_SHADOW) != 0
    idx = np.nonzero(cast)[0]
    o, d, tm = origin[idx], wi[idx], tmax[idx]
    tt = None if time is None else time[idx]
    own = None if skip is None else skip[idx]
    left = np.maximum(ctx.settings.transparent_max_bounces - tbounce[idx], 0)
    if stack is not None:
        stack = stack[idx].copy()
    crossings = 0
    while len(idx):
        crossings += 1
        if crossings > VOLUME_BOUNDS_MAX:
            out[idx] = 0.0     # more surfaces on the ray than Cycles crosses: blocked
            break
        if own is None:
            t, prim, bu, bv = ctx.accel.intersect(o, d, tm, time=tt)
        else:   # the first segment passes the strand the ray leaves
            t, prim, bu, bv = ctx.accel.intersect_skipping(o, d, tm, own, time=tt)
            own = None
        if ctx.shadow_skips:
            ray = np.full(len(idx), VIS_SHADOW, np.uint8)
            t, prim, bu, bv = skip_invisible(ctx, o, d, tm, ray, t, prim, bu, bv, time=tt)
        hit = prim >= 0
        if stack is not None:
            out[idx] *= transmittance_factor(ctx.media, stack, np.where(hit, np.minimum(t, tm), tm), o, d, rng)
        mat = ctx.triangles.material[np.maximum(prim, 0)]
        boundary = ctx.media.boundary[mat] if ctx.media is not None else False
        crosses = hit & ctx.transparent_mat[mat] & ((left > 0) | boundary)
        out[idx[hit & ~crosses]] = 0.0
        c = np.nonzero(crosses)[0]
        if len(c) == 0:
            break
        lobes = ctx.materials.gather(mat[c], ShadingContext.at(
            ctx.triangles, prim[c], bu[c], bv[c], wo=-d[c], ray=np.full(len(c), VIS_SHADOW, np.uint8)))
        T = bsdf.transparency(lobes)
        if ctx.portal_mat is not None:   # Cycles: no transparent shadow through a ray portal
            T[portal_rows(lobes)] = 0.0
        out[idx[c]] *= T
        c = c[row_any_positive(T)]
        # Go on from just past the surface, towards the same end point.
        ng = ctx.triangles.ng[prim[c]]
        if stack is not None:
            stack = stack[c]
            ctx.media.cross(stack, np.arange(len(c)), ctx.media.medium_of(prim[c], mat[c]), dot(ng, d[c]) > 0)
        start = ctx.accel.offset_origin(o[c] + d[c] * t[c, None], ng, d[c])
        tm = tm[c] - dot(start - o[c], d[c])
        counted = 1 if ctx.media is None else ~ctx.media.boundary[mat[c]]
        idx, o, d, left = idx[c], start, d[c], left[c] - counted
        if tt is not None:
            tt = tt[c]
    return out
