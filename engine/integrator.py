"""Wavefront path tracer: next-event estimation and BSDF sampling combined by
multiple importance sampling (power heuristic), as pbrt-v4's PathIntegrator
and Mitsuba 3's path.cpp, but on arrays of paths.

Path state is a struct of arrays indexed by live path; dead paths are
removed by compaction after every bounce, so every NumPy operation works on
live lanes only.  ``trace_batch`` runs one batch of camera samples for a
contiguous range of pixels and returns a ``film.Tile``.

Conventions (Cycles, measured against it): max_bounces = N means light
sampling at path vertices 0..N (vertex 0 = the first hit), and vertex N + 1
only collects emission, so N = 0 is direct lighting.  A constant world is not light
sampled (BSDF sampling only, as Cycles does); delta lights cannot be hit by
BSDF rays, so they are always light sampled, in every strategy.
"""
from dataclasses import dataclass

import numpy as np

from . import bsdf
from .film import Tile
from .lights import POINT, SUN
from .sampling import power_heuristic
from .vec import dot, frame, luminance, to_local, to_world


@dataclass
class Context:
    """Everything a batch needs, shared read-only between threads."""
    accel: object
    triangles: object
    materials: object
    lights: object
    camera: object
    world: np.ndarray
    settings: object

    def __post_init__(self):
        lt = self.lights
        delta = np.zeros(lt.count, bool)
        if lt.count:
            pts = lt.kind == POINT
            delta[pts] = lt.points.radius[lt.local[pts]] <= 0
            suns = lt.kind == SUN
            delta[suns] = lt.suns.delta[lt.local[suns]]
        self.delta_emitters = np.nonzero(delta)[0]
        self.all_emitters = np.arange(lt.count)


@dataclass
class Paths:
    pix: np.ndarray
    o: np.ndarray
    d: np.ndarray
    tmax: np.ndarray
    beta: np.ndarray
    L: np.ndarray
    prev_pdf: np.ndarray
    prev_delta: np.ndarray

    def take(self, keep):
        return Paths(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


@dataclass
class Hit:
    """Surface interaction at the closest hit, in world space."""
    p: np.ndarray
    ng: np.ndarray   # geometric normal facing the incoming ray
    ns: np.ndarray   # shading normal on the same side
    wo: np.ndarray
    mat: np.ndarray
    prim: np.ndarray
    eps: np.ndarray  # ray-origin offset for this point
    uv: np.ndarray   # (N, 2) interpolated texture coordinates (0 without UVs)


def trace_batch(ctx, pix, rng, tile):
    """Trace one camera sample per entry of ``pix`` and add them to ``tile``."""
    n = len(pix)
    u = rng.random((n, 4))
    o, d, tmax = ctx.camera.generate(pix, u[:, 0], u[:, 1], u[:, 2], u[:, 3])
    paths = Paths(pix, o, d, tmax, np.ones((n, 3)), np.zeros((n, 3)),
                  np.ones(n), np.ones(n, bool))
    s = ctx.settings
    for depth in range(s.max_bounces + 2):
        if len(paths.pix) == 0:
            break
        paths = _bounce(ctx, paths, depth, rng, tile)


def _finish(ctx, paths, tile):
    L = paths.L
    L = np.where(np.isfinite(L), L, 0.0)
    clamp = ctx.settings.clamp
    if clamp > 0:
        m = L.max(axis=1)
        L = L * np.where(m > clamp, clamp / np.maximum(m, 1e-30), 1.0)[:, None]
    tile.add_radiance(paths.pix, L)


def _bounce(ctx, paths, depth, rng, tile):
    s = ctx.settings
    t, prim, bu, bv = ctx.accel.intersect(paths.o, paths.d, paths.tmax)
    lt, emitter, lLe, lpdf = ctx.lights.intersect(paths.o, paths.d, np.minimum(t, paths.tmax),
                                                  camera=depth == 0)
    hit_light = lt < np.inf
    hit_surf = (prim >= 0) & ~hit_light
    if depth == 0:
        _camera_aovs(ctx, paths, t, prim, hit_light, hit_surf, tile)

    # Emitters and the world seen along the ray.
    if hit_light.any():
        i = np.nonzero(hit_light)[0]
        w = _mis_hit(ctx, paths, i, emitter[i], lpdf[i])
        paths.L[i] += paths.beta[i] * lLe[i] * w[:, None]
    miss = (prim < 0) & ~hit_light
    if miss.any():
        _escaped(ctx, paths, np.nonzero(miss)[0], depth)

    # Compact to the paths that hit a surface: everything below works on
    # dense arrays, with no index indirection.
    if not hit_surf.all():
        _finish(ctx, paths.take(~hit_surf), tile)
        paths = paths.take(hit_surf)
        t, prim, bu, bv = t[hit_surf], prim[hit_surf], bu[hit_surf], bv[hit_surf]
    if len(paths.pix) == 0:
        return paths
    hit = _interaction(ctx, paths, t, prim, bu, bv)
    emission = ctx.materials.emission[hit.mat]
    em = np.nonzero(np.any(emission > 0, axis=1))[0]
    if len(em):
        _emission_hit(ctx, paths, em, hit, emission[em])

    if depth == s.max_bounces + 1:
        _finish(ctx, paths, tile)
        return paths.take(np.zeros(len(paths.pix), bool))

    lobes = ctx.materials.gather(hit.mat, hit.uv)
    tt, bb = frame(hit.ns)
    wo_l = to_local(hit.wo, tt, bb, hit.ns)
    _next_event(ctx, paths, hit, lobes, tt, bb, wo_l, rng)
    alive = _scatter(ctx, paths, hit, lobes, tt, bb, wo_l, depth, rng)
    if alive.all():
        return paths
    _finish(ctx, paths.take(~alive), tile)
    return paths.take(alive)


def _camera_aovs(ctx, paths, t, prim, hit_light, hit_surf, tile):
    n = len(paths.pix)
    visible = hit_light | hit_surf
    alpha = visible.astype(np.float64)
    # Z depth along the view axis, counted from the camera (rays start at clip start).
    cos = np.maximum(paths.d @ ctx.camera.forward, 0.0)
    depth = np.where(hit_surf, t * cos + ctx.camera.cam.clip_start, 0.0)
    normal = np.zeros((n, 3))
    albedo = np.zeros((n, 3))
    hs = np.nonzero(hit_surf)[0]
    if len(hs):
        tr = ctx.triangles
        normal[hs] = tr.ng[prim[hs]]
        col = ctx.materials.color[tr.material[prim[hs]]]
        albedo[hs] = np.clip(col.sum(axis=1), 0.0, 1.0)
    tile.add_camera(paths.pix, alpha, depth, normal, albedo)


def _mis_hit(ctx, paths, i, emitter, pdf_light):
    """MIS weight for emitters found by BSDF sampling."""
    s = ctx.settings
    prev_delta = paths.prev_delta[i]
    if s.strategy == "bsdf":
        return np.ones(len(i))
    if s.strategy == "light":
        return prev_delta.astype(np.float64)
    p_light = ctx.lights.selection_pdf(emitter) * pdf_light
    return np.where(prev_delta, 1.0, power_heuristic(paths.prev_pdf[i], p_light))


def _escaped(ctx, paths, i, depth):
    transparent = ctx.settings.transparent and depth == 0
    if not transparent:
        paths.L[i] += paths.beta[i] * ctx.world
    for mask, emitter, Le, pdf in ctx.lights.sun_hits(paths.d[i]):
        j = i[mask]
        if len(j):
            w = _mis_hit(ctx, paths, j, np.full(len(j), emitter), np.full(len(j), pdf))
            paths.L[j] += paths.beta[j] * Le * w[:, None]


def _interaction(ctx, paths, t, prim, bu, bv):
    tr = ctx.triangles
    d = paths.d
    o = paths.o
    ng = tr.ng[prim]
    # Embree's t and barycentrics are float32; re-intersect the triangle's
    # plane in float64 so hit points (and shadow rays) sit on the surface
    # even on large triangles.
    cos = dot(d, ng)
    with np.errstate(divide="ignore", invalid="ignore"):
        t64 = dot(tr.p0[prim] - o, ng) / cos
    t = np.where(np.isfinite(t64) & (np.abs(cos) > 1e-6), t64, t)
    p = o + d * t[:, None]
    back = dot(ng, d) > 0
    ng = np.where(back[:, None], -ng, ng)
    if tr.ns is not None:
        c = tr.ns[prim]
        ns = (1.0 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
        ns /= np.maximum(np.linalg.norm(ns, axis=1), 1e-30)[:, None]
        ns = np.where((dot(ns, ng) < 0)[:, None], -ns, ns)
        # A shading normal that faces away from the viewer would make the
        # BSDF see wo below its horizon: fall back to the geometric normal.
        ns = np.where((dot(ns, -d) <= 1e-6)[:, None], ng, ns)
    else:
        ns = ng
    if tr.uv is not None:
        c = tr.uv[prim]
        uv = (1.0 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
    else:
        uv = np.zeros((len(p), 2))
    return Hit(p, ng, ns, -d, tr.material[prim], prim, ctx.accel.offset_scale(p), uv)


def _emission_hit(ctx, paths, em, hit, Le):
    s = ctx.settings
    if s.strategy == "mis":
        emitter = ctx.lights.emitter_of_triangle(hit.mat[em])
        pdf = ctx.lights.triangle_pdf(hit.prim[em], paths.o[em], hit.p[em], hit.ng[em])
        w = _mis_hit(ctx, paths, em, emitter, pdf)
    else:
        w = _mis_hit(ctx, paths, em, None, None)
    paths.L[em] += paths.beta[em] * Le * w[:, None]


def _nee_emitters(ctx):
    s = ctx.settings
    if s.strategy == "bsdf":
        return "list", ctx.delta_emitters
    if s.light_selection == "all":
        return "list", ctx.all_emitters
    return "select", None


def _next_event(ctx, paths, hit, lobes, tt, bb, wo_l, rng):
    lt = ctx.lights
    n = len(paths.pix)
    if lt.count == 0 or n == 0:
        return
    mode, emitters = _nee_emitters(ctx)
    if mode == "select":
        u = rng.random((n, 4))
        e, p_sel = lt.select(u[:, 0])
        _shade_light(ctx, paths, hit, lobes, tt, bb, wo_l, e, p_sel, u[:, 1:])
        return
    for e in emitters:
        u = rng.random((n, 3))
        _shade_light(ctx, paths, hit, lobes, tt, bb, wo_l, np.full(n, e), np.ones(n), u)


def _shade_light(ctx, paths, hit, lobes, tt, bb, wo_l, e, p_sel, u):
    s = ctx.settings
    ls = ctx.lights.sample(e, hit.p, u[:, 0], u[:, 1], u[:, 2])
    wi_l = to_local(ls.wi, tt, bb, hit.ns)
    f, pdf_b = bsdf.eval_pdf(lobes, wo_l, wi_l)
    cos = wi_l[:, 2]
    p_light = p_sel * ls.pdf
    ok = (ls.pdf > 0) & (cos > 0) & (dot(ls.wi, hit.ng) > 0)
    if s.strategy == "mis":
        w = np.where(ls.delta, 1.0, power_heuristic(p_light, pdf_b))
    else:
        w = np.ones(len(p_light))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        scale = np.where(ok, cos * w / np.where(ok, p_light, 1.0), 0.0)
    contrib = paths.beta * f * ls.Le * scale[:, None]
    live = np.nonzero(np.any(contrib > 0, axis=1))[0]
    if len(live) == 0:
        return
    eps = hit.eps[live]
    origin = ctx.accel.offset_origin(hit.p[live], hit.ng[live], ls.wi[live], eps)
    dist = ls.dist[live]
    # Points on triangles would block their own shadow ray: stop short.
    shorten = np.where(ls.on_surface[live], 10.0 * eps, 0.0)
    tmax = np.where(np.isfinite(dist), dist * (1.0 - 1e-6) - shorten, 1e37)
    blocked = ctx.accel.occluded(origin, ls.wi[live], tmax)
    free = live[~blocked]
    paths.L[free] += contrib[free]


def _scatter(ctx, paths, hit, lobes, tt, bb, wo_l, depth, rng):
    """Sample the BSDF and update the path state in place; returns which paths live on."""
    s = ctx.settings
    u = rng.random((len(paths.pix), 4))
    wi_l, weight, pdf, delta = bsdf.sample(lobes, wo_l, u[:, 0], u[:, 1], u[:, 2])
    wi = to_world(wi_l, tt, bb, hit.ns)
    # Reflection only: a direction below the geometric surface would leak.
    ok = (dot(wi, hit.ng) > 0) & np.all(np.isfinite(weight), axis=1) & np.any(weight > 0, axis=1)
    beta = paths.beta * weight
    if depth >= s.rr_depth:
        q = np.minimum(beta.max(axis=1), 0.95)
        survive = u[:, 3] < q
        beta = beta / np.where(survive, np.maximum(q, 1e-30), 1.0)[:, None]
        ok &= survive
    paths.beta = beta
    paths.o = ctx.accel.offset_origin(hit.p, hit.ng, wi, hit.eps)
    paths.d = wi
    paths.tmax = np.full(len(wi), np.inf)
    paths.prev_pdf = pdf
    paths.prev_delta = delta
    return ok
