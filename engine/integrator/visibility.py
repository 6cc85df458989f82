"""Ray visibility (Blender's Object > Visibility > Ray Visibility, as
Cycles): rays pass triangles invisible to their kind, lights skip the lobes
of bounce kinds they are hidden from, and each bounce's ray kind is drawn as
Cycles' closure kind.  Bookkeeping only: scenes where everything is visible
to everything never call it (Context.track_rays, shadow_skips, ...)."""
from dataclasses import fields, replace

import numpy as np

from .. import bsdf
from ..lobes import OWN_WEIGHT, REGISTRY, kinds_of_class
from ..geometry import VIS_DIFFUSE, VIS_GLOSSY, VIS_SHADOW, VIS_TRANSMISSION
from ..sampler import KIND, vertex_set
from ..vec import dot, to_local

MAX_SKIPS = 16   # invisible surfaces a ray may pass before it counts as a miss
VIS_INDIRECT = VIS_DIFFUSE | VIS_GLOSSY | VIS_TRANSMISSION


def skip_invisible(ctx, o, d, tmax, ray, t, prim, bu, bv, time=None):
    """Closest hit among triangles visible to each ray's kind: embreex has no
    ray masks, so rays that hit an invisible triangle continue past it."""
    vis = ctx.triangles.visibility
    t, prim, bu, bv = t.copy(), prim.copy(), bu.copy(), bv.copy()
    for _ in range(MAX_SKIPS):
        again = np.nonzero((prim >= 0) & ((vis[np.maximum(prim, 0)] & ray) == 0))[0]
        if len(again) == 0:
            return t, prim, bu, bv
        tn, pn, un, vn = _continue_past(ctx, o[again], d[again], tmax[again], t[again], prim[again],
                                        None if time is None else time[again])
        t[again], prim[again], bu[again], bv[again] = tn, pn, un, vn
    miss = (prim >= 0) & ((vis[np.maximum(prim, 0)] & ray) == 0)
    t[miss], prim[miss] = np.inf, -1
    return t, prim, bu, bv


def _continue_past(ctx, o, d, tmax, t, prim, time=None):
    """Intersect again from just behind the hit triangle; t stays measured
    from the original origin o."""
    p = o + d * t[:, None]
    start = ctx.accel.offset_origin(p, ctx.triangles.ng[prim], d)
    t0 = dot(start - o, d)
    tn, pn, un, vn = ctx.accel.intersect(start, d, np.maximum(tmax - t0, 0.0), time=time)
    return np.where(pn >= 0, tn + t0, np.inf), pn, un, vn


def occluded(ctx, origin, wi, tmax, emitter, time=None, skip=None):
    """Shadow test: lights with visible_shadow off (Cycles' Cast Shadow) are
    never blocked; objects with visible_shadow off never block.  ``skip``
    (N,): the curve row each ray leaves, which it passes (None: none)."""
    if ctx.links is not None and ctx.links.any_blockers:
        return _occluded_linked(ctx, origin, wi, tmax, emitter, skip)
    if not ctx.light_no_shadow and not ctx.shadow_skips:
        return _occluded(ctx, origin, wi, tmax, time, skip)
    blocked = np.zeros(len(origin), bool)
    test = np.ones(len(origin), bool)
    if ctx.light_no_shadow:
        test = (ctx.lights.visibility[emitter] & VIS_SHADOW) != 0
    idx = np.nonzero(test)[0]
    ti = None if time is None else time[idx]
    own = None if skip is None else skip[idx]
    if not ctx.shadow_skips:
        blocked[idx] = _occluded(ctx, origin[idx], wi[idx], tmax[idx], ti, own)
        return blocked
    t, prim, _, _ = _intersect(ctx, origin[idx], wi[idx], tmax[idx], ti, own)
    ray = np.full(len(idx), VIS_SHADOW, np.uint8)
    t, prim, _, _ = skip_invisible(ctx, origin[idx], wi[idx], tmax[idx], ray, t, prim, t, t, time=ti)
    blocked[idx] = prim >= 0
    return blocked


def _occluded(ctx, origin, wi, tmax, time, skip):
    if skip is None:
        return ctx.accel.occluded(origin, wi, tmax, time=time)
    return ctx.accel.occluded_skipping(origin, wi, tmax, skip, time=time)


def _intersect(ctx, origin, wi, tmax, time, skip):
    if skip is None:
        return ctx.accel.intersect(origin, wi, tmax, time=time)
    return ctx.accel.intersect_skipping(origin, wi, tmax, skip, time=time)


def _occluded_linked(ctx, origin, wi, tmax, emitter, skip=None):
    """Shadow linking: the shadow rays of a light with a blocker set pass
    every object outside it (the others as ``occluded`` without links)."""
    emitter = np.broadcast_to(np.asarray(emitter, np.int64), (len(origin),))
    linked = ctx.links.shadow_linked(emitter)
    blocked = np.zeros(len(origin), bool)
    plain = np.flatnonzero(~linked)
    if len(plain):
        blocked[plain] = occluded(replace(ctx, links=None), origin[plain], wi[plain], tmax[plain], emitter[plain],
                                  skip=None if skip is None else skip[plain])
    idx = np.flatnonzero(linked)
    if len(idx):
        o, d, tm, e = origin[idx], wi[idx], tmax[idx], emitter[idx]
        t, prim, _, _ = _intersect(ctx, o, d, tm, None, None if skip is None else skip[idx])
        if ctx.light_no_shadow:
            prim = np.where((ctx.lights.visibility[e] & VIS_SHADOW) != 0, prim, -1)
        vis = ctx.triangles.visibility
        for _ in range(MAX_SKIPS):
            passes = (prim >= 0) & ~ctx.links.blocking(e, prim)
            if vis is not None:
                passes |= (prim >= 0) & ((vis[np.maximum(prim, 0)] & VIS_SHADOW) == 0)
            again = np.flatnonzero(passes)
            if len(again) == 0:
                break
            tn, pn, _, _ = _continue_past(ctx, o[again], d[again], tm[again], t[again], prim[again])
            t[again], prim[again] = tn, pn
        blocked[idx] = (prim >= 0) & ctx.links.blocking(e, prim)
    return blocked


def catchers_only(ctx, o, d, tmax, only, t, prim, bu, bv):
    """Rays of shadow catcher paths (``only``) see catcher triangles alone
    (Cycles shifts their visibility onto the catchers' bits)."""
    rows = np.flatnonzero(only)
    if len(rows) == 0:
        return t, prim, bu, bv
    t, prim, bu, bv = t.copy(), prim.copy(), bu.copy(), bv.copy()
    for _ in range(MAX_SKIPS):
        again = rows[(prim[rows] >= 0) & ~ctx.catcher[np.maximum(prim[rows], 0)]]
        if len(again) == 0:
            return t, prim, bu, bv
        tn, pn, un, vn = _continue_past(ctx, o[again], d[again], tmax[again], t[again], prim[again])
        t[again], prim[again], bu[again], bv[again] = tn, pn, un, vn
    miss = rows[(prim[rows] >= 0) & ~ctx.catcher[np.maximum(prim[rows], 0)]]
    t[miss], prim[miss] = np.inf, -1
    return t, prim, bu, bv


def occluded_by_catchers(ctx, o, d, tmax):
    """Shadow rays of shadow catcher paths: blocked by catchers only."""
    t, prim, bu, bv = ctx.accel.intersect(o, d, tmax)
    t, prim, _, _ = catchers_only(ctx, o, d, tmax, np.ones(len(o), bool), t, prim, bu, bv)
    return (prim >= 0) & (t < tmax)


def ray_kind(ctx, v, paths, depth):
    """VIS_* bit of the bounce just sampled at vertices ``v``, distributed as
    Cycles' (the kind of the closure it sampled): below the surface =
    transmission; after a delta (mirror) sample = glossy; else diffuse with
    the probability that the diffuse lobes produced this direction,
    sel_d pdf_d / pdf."""
    lobes, hit = v.lobes, v.hit
    n = len(paths.pix)
    kind = np.full(n, VIS_GLOSSY, np.uint8)
    diffuse = _diffuse_lobe(lobes.kind)
    other = ~diffuse & (lobes.kind != bsdf.NONE)
    kind[diffuse.any(axis=1) & ~other.any(axis=1)] = VIS_DIFFUSE
    mixed = np.nonzero(diffuse.any(axis=1) & other.any(axis=1) & ~paths.prev_delta)[0]
    if len(mixed):
        wi_l = to_local(paths.d[mixed], v.tt[mixed], v.bb[mixed], hit.ns[mixed])
        only_d = lobes_where(lobes, ~diffuse, mixed)
        sel = bsdf.selection(lobes_where(lobes, np.zeros_like(diffuse), mixed), v.wo_l[mixed])
        _, pdf_d = bsdf.eval_pdf(only_d, v.wo_l[mixed], wi_l, sel)
        # The BSDF's own pdf of the direction (a guided vertex's MIS pdf is the
        # guide mixture's): Cycles' guided samples pick their closure by it.
        pdf = paths.prev_pdf[mixed] if v.bsdf_pdf is None else v.bsdf_pdf[mixed]
        with np.errstate(divide="ignore", invalid="ignore"):
            p_d = np.where(pdf > 0, pdf_d / pdf, 0.0)
        u = ctx.sampler.get(paths.pseed[mixed], paths.sample[mixed], vertex_set(depth, KIND))[:, 0]
        kind[mixed] = np.where(u < p_d, VIS_DIFFUSE, VIS_GLOSSY)
    kind[dot(paths.d, hit.ng) < 0] = VIS_TRANSMISSION
    return _labelled(kind, v.sampled_labels)


_LABELS = {"diffuse": VIS_DIFFUSE, "glossy": VIS_GLOSSY, "transmission": VIS_TRANSMISSION}


def _labelled(kind, labels):
    """Samples an OWN_WEIGHT lobe drew take its light class wherever they
    went (Cycles' Hair BSDF labels a Reflection sample a reflection even
    below N, a Transmission sample a transmission even above)."""
    if labels is None:
        return kind
    for d in REGISTRY.values():
        if d.has(OWN_WEIGHT) and d.pass_class in _LABELS:
            kind[labels == d.id] = _LABELS[d.pass_class]
    return kind


def _diffuse_lobe(kind):
    """Lobes Cycles counts as diffuse closures (the registry's 'diffuse'
    class); the others reflect as glossy (transmission is told by direction)."""
    return bsdf.kind_in(kind, kinds_of_class("diffuse"))


def lobes_where(lobes, drop, rows):
    """The lobes of ``rows`` with the ``drop`` (N, K) entries switched off."""
    per_ray = {f.name: getattr(lobes, f.name) for f in fields(lobes)}
    sub = replace(lobes, **{k: v[rows] for k, v in per_ray.items()
                            if isinstance(v, np.ndarray) and len(v) == len(lobes)})
    return replace(sub, kind=np.where(drop[rows], bsdf.NONE, sub.kind).astype(lobes.kind.dtype))


def visible_lobes_f(ctx, v, wi_l, wi, emitter, f):
    """BSDF value for NEE at vertices ``v`` with lights that are invisible
    to some bounce kinds: as Cycles, the excluded lobes' f is dropped (the
    pdf, for MIS, keeps every lobe)."""
    lobes, wo_l = v.lobes, v.wo_l
    vis = ctx.lights.visibility[emitter]
    no_d = (vis & VIS_DIFFUSE) == 0
    no_g = (vis & VIS_GLOSSY) == 0
    rows = np.nonzero(no_d | no_g)[0]
    if len(rows) == 0:
        return f
    kind = lobes.kind[rows]
    drop = np.zeros(lobes.kind.shape, bool)
    diffuse = _diffuse_lobe(kind)
    drop[rows] = (diffuse & no_d[rows, None]) | (~diffuse & (kind != bsdf.NONE) & no_g[rows, None])
    sel = bsdf.selection(lobes_where(lobes, np.zeros_like(drop), rows), wo_l[rows])
    f = f.copy()
    f[rows] = bsdf.eval_pdf(lobes_where(lobes, drop, rows), wo_l[rows], wi_l[rows], sel)[0]
    no_t = np.nonzero((vis & VIS_TRANSMISSION) == 0)[0]
    f[no_t[dot(wi[no_t], v.hit.ng[no_t]) < 0]] = 0.0
    return f
