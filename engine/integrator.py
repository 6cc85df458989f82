"""Wavefront path tracer: next-event estimation and BSDF sampling combined by
multiple importance sampling (power heuristic), as pbrt-v4's PathIntegrator
and Mitsuba 3's path.cpp, but on arrays of paths.

Path state is a struct of arrays indexed by live path; dead paths are
removed by compaction after every bounce, so every NumPy operation works on
live lanes only.  ``trace_batch`` runs one batch of camera samples for a
contiguous range of pixels and returns a ``film.Tile``.

Conventions (Cycles, measured against it): max_bounces = N means light
sampling at path vertices 0..N (vertex 0 = the first hit), and vertex N + 1
only collects emission, so N = 0 is direct lighting.  A constant world is not
light sampled (BSDF sampling only, as Cycles does); delta lights cannot be hit
by BSDF rays, so they are always light sampled, in every strategy.

Transparent surfaces (Cycles' transparent bounces and shadows): a pass
straight through a sampled transparent lobe is not a vertex; it keeps the
ray's start, MIS state and kind and counts towards ``transparent_max_bounces``
instead of max_bounces.  Shadow rays cross transparent surfaces, attenuated
by their transparency.
"""
from dataclasses import dataclass, fields, replace

import numpy as np

from . import bsdf, kernels, nee, pass_events, throughput
from .accel import shadow_rays, shadow_rays_f32
from .pass_events import lobe_rows as _lobe_rows
from .geometry import VIS_CAMERA, VIS_DIFFUSE, VIS_GLOSSY, VIS_SHADOW, VIS_TRANSMISSION
from .hits import hit_geometry
from .lobes import kinds_of_class
from .nodes import NodeRays, ShadingContext
from .sampler import BSDF, CAMERA, KIND, LIGHT, emitter_set, vertex_set
from .sampling import power_heuristic
from .vec import dot, frame, row_any_positive, row_max, to_local, to_world


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
        self.jit = kernels.configure(getattr(self.settings, "use_jit", True))
        # prepare() sets the scene's own (its Blender version); this default
        # serves contexts built directly.
        self.bump_model = bsdf.BUMP_GGX
        lt = self.lights
        self.delta_emitters = np.nonzero(lt.delta)[0]   # each light type says which it has
        self.all_emitters = np.arange(lt.count)
        _visibility_setup(self)
        _transparency_setup(self)


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
    # The previous path vertex and its geometric normal: the light tree's
    # selection probability at that vertex weighs emitters hit by MIS.
    prev_p: np.ndarray
    prev_n: np.ndarray
    # NEE sampled every light at the previous vertex (light selection
    # 'auto' at a glossy vertex): its selection probability is 1 there.
    prev_every: np.ndarray
    # VIS_* bit of the ray: camera, or the kind of the bounce that cast it
    # (tracked only when something in the scene is invisible to some rays).
    ray: np.ndarray
    # Where the ray's straight line started (the last vertex; transparent
    # passes move o, not this): lights hit are weighed by MIS from here.
    mis_o: np.ndarray
    bounce: np.ndarray    # vertices scattered so far (0 = camera ray)
    tbounce: np.ndarray   # transparent surfaces passed so far
    # The sample's address for the sampler: pixel scramble seed and sample
    # index (uint32), so every random number is fixed by (seed, pixel,
    # sample index, dimension), whatever the batching.
    pseed: np.ndarray
    sample: np.ndarray
    aux: np.ndarray       # (N, k) per-path state of the extra passes (k = 0 without)

    def take(self, keep):
        """The paths where ``keep`` (a mask or indices).  np.take with
        indices copies rows 4-5x faster than boolean indexing."""
        idx = rows_of(keep)
        return Paths(*(np.take(getattr(self, f), idx, axis=0) for f in self.__dataclass_fields__))

    def finish_rows(self, keep):
        """Pixel, radiance and sample index of the paths where ``keep``: all
        that ending a path needs."""
        idx = rows_of(keep)
        return np.take(self.pix, idx), np.take(self.L, idx, axis=0), np.take(self.sample, idx)

    def concat(self, other):
        return Paths(*(np.concatenate([getattr(self, f), getattr(other, f)])
                       for f in self.__dataclass_fields__))


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
    # For normal maps: interpolated world tangent (N, 3) and bitangent sign
    # (N,), or None; back: the ray hit the triangle's back face.
    tangent: object = None
    tangent_sign: object = None
    back: object = None
    # For shader nodes (engine.nodes.ShadingContext): barycentrics (N, 2),
    # bounces before this hit and the VIS_* bit of the ray that found it.
    bary: object = None
    depth: object = None
    ray: object = None


def trace_batch(ctx, pix, sample, tile):
    """Trace camera sample ``sample[i]`` of pixel ``pix[i]`` for every i and
    add them to ``tile``."""
    n = len(pix)
    pseed = ctx.sampler.pixel_seeds(pix)
    sample = np.asarray(sample, np.uint32)
    u = ctx.sampler.get(pseed, sample, CAMERA)
    o, d, tmax = ctx.camera.generate(pix, u[:, 0], u[:, 1], u[:, 2], u[:, 3])
    paths = Paths(pix, o, d, tmax, np.ones((n, 3)), np.zeros((n, 3)),
                  np.ones(n), np.ones(n, bool), o, np.zeros((n, 3)), np.zeros(n, bool),
                  np.full(n, VIS_CAMERA, np.uint8),
                  o, np.zeros(n, np.int32), np.zeros(n, np.int32), pseed, sample,
                  np.zeros((n, pass_events.aux_width(ctx.settings)), np.float32))
    pass_events.start(ctx, paths, tile)
    # Every step raises a live path's bounce or its transparent bounce
    # count, both bounded: max_bounces + 1 vertices scatter, one more only
    # collects emission, and transparent passes end at transparent_limit.
    for depth in range(ctx.settings.max_bounces + 2 + ctx.transparent_limit):
        if len(paths.pix) == 0:
            break
        paths = _bounce(ctx, paths, depth, tile)
    if len(paths.pix):
        _finish(ctx, paths, tile)


def rows_of(keep):
    """Indices of a boolean mask (indices pass through)."""
    keep = np.asarray(keep)
    return np.flatnonzero(keep) if keep.dtype == bool else keep


def _finish(ctx, paths, tile, keep=None):
    """Add the radiance of the paths (those where ``keep``, if given) to the tile."""
    if keep is None:
        pix, L, sample = paths.pix, paths.L, paths.sample
    else:
        pix, L, sample = paths.finish_rows(keep)
    _add_radiance(ctx, pix, L, sample, tile)


def _add_radiance(ctx, pix, L, sample, tile):
    L = np.where(np.isfinite(L), L, 0.0)
    clamp = ctx.settings.clamp
    if clamp > 0:
        m = row_max(L)
        L = L * np.where(m > clamp, clamp / np.maximum(m, 1e-30), 1.0)[:, None]
    tile.add_radiance(pix, L, sample)


def _bounce(ctx, paths, depth, tile):
    s = ctx.settings
    t, prim, bu, bv = ctx.accel.intersect(paths.o, paths.d, paths.tmax)
    if ctx.triangles.visibility is not None:
        t, prim, bu, bv = _skip_invisible(ctx, paths.o, paths.d, paths.tmax, paths.ray, t, prim, bu, bv)
    lt, emitter, lLe, lpdf = _lights_along(ctx, paths, np.minimum(t, paths.tmax))
    hit_light = lt < np.inf
    if depth == 0:
        _camera_aovs(ctx, paths, t, prim, hit_light, (prim >= 0) & ~hit_light, tile)

    # Emitters and the world seen along the ray.
    stop = np.zeros(len(prim), bool)
    if hit_light.any():
        i = np.nonzero(hit_light)[0]
        w = _mis_hit(ctx, paths, i, emitter[i], lpdf[i])
        paths.L[i] += paths.beta[i] * lLe[i] * w[:, None]
        pass_events.emitter(ctx, paths, i, paths.beta[i] * lLe[i], w, tile, emitters=emitter[i])
        stop[i] = _pass_light(ctx, paths, i)
    hit_surf = (prim >= 0) & ~stop
    miss = (prim < 0) & ~stop
    if miss.any():
        _escaped(ctx, paths, np.nonzero(miss)[0], tile)

    # Compact to the paths that hit a surface: everything below works on
    # dense arrays, with no index indirection.
    if not hit_surf.all():
        _finish(ctx, paths, tile, ~hit_surf)
        rows = np.flatnonzero(hit_surf)
        paths = paths.take(rows)
        t, prim, bu, bv = t.take(rows), prim.take(rows), bu.take(rows), bv.take(rows)
    if len(paths.pix) == 0:
        return paths
    hit = _interaction(ctx, paths, t, prim, bu, bv)
    emission = ctx.materials.emission[hit.mat]
    if ctx.materials.textures.emission:
        emission = ctx.materials.textures.emission_at(hit.mat, _shading(ctx, hit, paths, depth), emission)
    em = np.flatnonzero(row_any_positive(emission))
    if len(em):
        _emission_hit(ctx, paths, em, hit, emission[em], tile)

    last = paths.bounce > s.max_bounces
    if ctx.transparent_shadows:
        # Cycles' TERMINATE_ON_NEXT_SURFACE after the last transparent pass.
        last |= paths.tbounce >= ctx.transparent_limit
    carried = None
    if last.all() and not ctx.transparent_shadows:
        _finish(ctx, paths, tile)
        return paths.take(np.zeros(len(paths.pix), bool))
    if last.any():
        carried = _pass_last(ctx, paths.take(last), _take_hit(hit, last), tile)
        paths, hit = paths.take(~last), _take_hit(hit, ~last)
        if len(paths.pix) == 0:
            return carried

    lobes = ctx.materials.gather(hit.mat, _shading(ctx, hit, paths, depth))
    _orient(hit, lobes)
    # Texture hook: normal maps and bump replace the shading normal.
    smooth = None
    if ctx.materials.textures.normals:
        smooth = hit.ns
        hit.ns = ctx.materials.textures.perturb(hit, ctx.triangles)
    tt, bb = frame(hit.ns)
    wo_l = to_local(hit.wo, tt, bb, hit.ns)
    if smooth is not None:
        _bump_shadowing_setup(ctx, lobes, smooth, hit.ns, tt, bb)
    # Lobe weights and selection depend on wo only: once per vertex, shared
    # by light sampling (every emitter) and BSDF sampling.
    w = bsdf.weights(lobes, wo_l)
    lobes_wo = (bsdf.selection(lobes, wo_l, w), w)
    pass_events.vertex(ctx, paths, hit, lobes, w, tt, bb, depth, tile)
    every = _next_event(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth, tile)
    ray = paths.ray
    alive, through = _scatter(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth)
    pass_events.after_scatter(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, through, tile)
    # For the light tree's MIS pdf; a transparent pass keeps the vertex.
    paths.prev_p = _unless(through, paths.prev_p, hit.p)
    paths.prev_n = _unless(through, paths.prev_n, hit.ng)
    if every is not None:
        paths.prev_every = _unless(through, paths.prev_every, every)
    if ctx.track_rays:
        paths.ray = _unless(through, ray, _ray_kind(ctx, hit, lobes, wo_l, tt, bb, paths, depth))
    elif ctx.triangles.visibility is not None:
        # Only camera (or shadow) visibility differs: any indirect kind sees
        # the same triangles, but no longer as a camera ray.
        paths.ray = _unless(through, ray, np.full(len(ray), VIS_INDIRECT, np.uint8))
    if not alive.all():
        _finish(ctx, paths, tile, ~alive)
        paths = paths.take(alive)
    return paths if carried is None or len(carried.pix) == 0 else paths.concat(carried)


def _pass_light(ctx, paths, i):
    """Paths ``i`` met a light: as Cycles (integrator_shade_light) they go on
    past it to the surface or world behind, counting a transparent bounce,
    and end once that count reaches transparent_max_bounces (so with 0 or 1
    a light still ends the path).  Returns which of ``i`` end."""
    paths.tbounce[i] += 1
    return paths.tbounce[i] >= ctx.settings.transparent_max_bounces


def _unless(mask, old, new):
    """new, but old where mask (per ray); new itself when mask is empty."""
    if not mask.any():
        return new
    return np.where(mask.reshape((-1,) + (1,) * (new.ndim - 1)), old, new)


def _take_hit(hit, keep):
    idx = rows_of(keep)
    return replace(hit, **{f.name: np.take(getattr(hit, f.name), idx, axis=0) for f in fields(hit)
                           if isinstance(getattr(hit, f.name), np.ndarray)})


def _lights_along(ctx, paths, tmax):
    """Analytic lights on each ray before tmax, seen from where its straight
    line started (before any transparent pass, as Cycles keeps the ray's
    origin), so MIS weighs them with the pdf NEE had at that vertex.  Camera
    rays (bounce 0) see only camera-visible lights."""
    ray = paths.ray if ctx.track_rays else None
    o = paths.o
    if ctx.transparent_shadows:
        o = paths.mis_o
        tmax = tmax + dot(paths.o - o, paths.d)
    camera = paths.bounce == 0
    if camera.all() or not camera.any():
        return ctx.lights.intersect(o, paths.d, tmax, camera=bool(camera.all()), ray=ray)
    n = len(o)
    out = (np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3)), np.zeros(n))
    for rows in (np.nonzero(camera)[0], np.nonzero(~camera)[0]):
        res = ctx.lights.intersect(o[rows], paths.d[rows], tmax[rows], camera=bool(camera[rows[0]]),
                                   ray=None if ray is None else ray[rows])
        for a, r in zip(out, res):
            a[rows] = r
    return out


def _camera_aovs(ctx, paths, t, prim, hit_light, hit_surf, tile):
    """Alpha, and the first-hit AOVs the film keeps (none by default: the
    denoiser asks for normal and albedo)."""
    visible = hit_light | hit_surf
    alpha = visible.astype(np.float64)
    kept = getattr(tile, "aovs", None)
    depth = normal = albedo = None
    if kept is None or "depth" in kept:
        # Z depth along the view axis, counted from the camera (rays start at clip start).
        cos = np.maximum(dot(paths.d, np.broadcast_to(ctx.camera.forward, paths.d.shape)), 0.0)
        depth = np.where(hit_surf, t * cos + ctx.camera.cam.clip_start, 0.0)
    hs = np.nonzero(hit_surf)[0]
    if kept is None or "normal" in kept:
        normal = np.zeros((len(paths.pix), 3))
        normal[hs] = ctx.triangles.ng[prim[hs]]
    if kept is None or "albedo" in kept:
        albedo = np.zeros((len(paths.pix), 3))
        m = ctx.triangles.material[prim[hs]]
        col = ctx.materials.color[m] * ctx.materials.weight[m][..., None]
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
    every = paths.prev_every[i] if ctx.lights.every_at_glossy else None
    p_light = ctx.lights.selection_pdf(emitter, paths.prev_p[i], paths.prev_n[i], every) * pdf_light
    return np.where(prev_delta, 1.0, power_heuristic(paths.prev_pdf[i], p_light))


def _escaped(ctx, paths, i, tile):
    sky = i
    if ctx.settings.transparent:
        # With a transparent film camera rays (also through transparent
        # surfaces, which keep the ray's kind) see no world.
        camera = paths.bounce[i] == 0
        _film_alpha_through(paths, i[camera & (paths.tbounce[i] > 0)], tile)
        sky = i[~camera]
    env = ctx.lights.environment_hits(paths.d[sky]) if len(sky) else None
    if env is not None:
        # An HDRI world is an emitter NEE samples: weigh it by MIS.
        emitter, Le, pdf = env
        w = _mis_hit(ctx, paths, sky, np.full(len(sky), emitter), pdf)
        paths.L[sky] += paths.beta[sky] * Le * w[:, None]
        pass_events.emitter(ctx, paths, sky, paths.beta[sky] * Le, w, tile, world=True,
                            emitters=np.full(len(sky), emitter))
    else:
        if np.any(ctx.world != 0):   # a black world adds nothing: skip the row gathers
            paths.L[sky] += paths.beta[sky] * ctx.world
        if pass_events.listening(tile):
            pass_events.emitter(ctx, paths, sky, paths.beta[sky] * ctx.world, np.ones(len(sky)), tile,
                                world=True, bsdf_only=True)
    for mask, emitter, Le, pdf in ctx.lights.sun_hits(paths.d[i], paths.ray[i] if ctx.track_rays else None):
        j = i[mask]
        if len(j):
            w = _mis_hit(ctx, paths, j, np.full(len(j), emitter), np.full(len(j), pdf))
            paths.L[j] += paths.beta[j] * Le * w[:, None]
            pass_events.emitter(ctx, paths, j, paths.beta[j] * Le, w, tile, emitters=np.full(len(j), emitter))


def _film_alpha_through(paths, i, tile):
    """Camera rays that leave through transparent surfaces uncover the
    transparent film by their throughput (Cycles: alpha = 1 - the average
    throughput of such rays); their first hit counted them opaque."""
    if len(i):
        np.subtract.at(tile.alpha, paths.pix[i] - tile.lo, paths.beta[i].mean(axis=1))


def _interaction(ctx, paths, t, prim, bu, bv):
    tr = ctx.triangles
    d = paths.d
    p, ng, ns, back = hit_geometry(tr, paths.o, d, t, prim, bu, bv)
    uv = _hit_uv(tr, prim, bu, bv)
    hit = Hit(p, ng, ns, -d, np.take(tr.material, prim), prim, ctx.accel.offset_scale(p), uv, back=back,
              bary=np.stack([bu, bv], axis=1), depth=getattr(paths, "bounce", None),
              ray=getattr(paths, "ray", None))
    if getattr(tr, "tangent", None) is not None:
        w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
        # Unnormalised, as Cycles interpolates its tangent attribute.
        hit.tangent = np.einsum("nk,nkj->nj", w, tr.tangent[prim])
        hit.tangent_sign = np.where(np.einsum("nk,nk->n", w, tr.tangent_sign[prim]) < 0, -1.0, 1.0)
    return hit


def _shading(ctx, hit, paths=None, step=None):
    """The hit's shading context for texture and shader-node evaluation;
    given the paths, nodes may cast rays from it (AO, Bevel)."""
    shading = ShadingContext.of_hit(ctx.triangles, hit)
    if paths is not None and shading.rays is None:
        shading.rays = NodeRays.of_paths(ctx, paths, step)
    return shading


def _hit_uv(tr, prim, bu, bv):
    """Interpolated texture coordinates (0 without a UV map)."""
    if tr.uv is None:
        return np.zeros((len(prim), 2))
    c = np.take(tr.uv, prim, axis=0)
    return (1.0 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]


def _emission_hit(ctx, paths, em, hit, Le, tile=None):
    s = ctx.settings
    if s.strategy == "mis":
        emitter = ctx.lights.emitter_of_triangle(hit.mat[em])
        pdf = ctx.lights.triangle_pdf(hit.prim[em], paths.mis_o[em], hit.p[em], hit.ng[em])
        w = _mis_hit(ctx, paths, em, emitter, pdf)
    else:
        w = _mis_hit(ctx, paths, em, None, None)
    paths.L[em] += paths.beta[em] * Le * w[:, None]
    pass_events.emitter(ctx, paths, em, paths.beta[em] * Le, w, tile,
                        emitters=ctx.lights.emitter_of_triangle(hit.mat[em]))


def _nee_emitters(ctx):
    s = ctx.settings
    if s.strategy == "bsdf":
        return "list", ctx.delta_emitters
    if s.light_selection == "all":
        return "list", ctx.all_emitters
    if s.light_selection == "auto":
        return "auto", ctx.all_emitters
    return "select", None


def _uniforms(ctx, paths, dim_set):
    """(N, 4) sample values of one dimension set for the live paths."""
    return ctx.sampler.get(paths.pseed, paths.sample, dim_set)


def _next_event(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth, tile=None):
    """Light sampling at every path's vertex.  Returns, for light selection
    'auto', which vertices sampled every light (else None)."""
    lt = ctx.lights
    n = len(paths.pix)
    if lt.count == 0 or n == 0:
        return None
    mode, emitters = _nee_emitters(ctx)
    args = (ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth, tile)
    if mode == "select":
        _nee_select(*args)
        return None
    if mode == "list":
        _nee_each(*args, emitters)
        return None
    every = _every_light(lobes, lobes_wo[0])
    if every.all():
        _nee_each(*args, emitters)
    elif not every.any():
        _nee_select(*args)
    else:
        for rows in (np.flatnonzero(~every), np.flatnonzero(every)):
            sub = _RowView(paths, rows, n)
            sub_args = (ctx, sub, _RowView(hit, rows, n), _lobe_rows(lobes, rows),
                        (lobes_wo[0][rows], lobes_wo[1][rows]), tt[rows], bb[rows], wo_l[rows], depth, tile)
            if every[rows[0]]:
                _nee_each(*sub_args, emitters)
            else:
                _nee_select(*sub_args)
            paths.L[rows] = sub.L
    return every


class _RowView:
    """The rows ``rows`` of an object's per-row arrays, each taken when
    first read (light sampling reads a few of the path's and hit's dozen)."""

    def __init__(self, obj, rows, n):
        self._obj, self._rows, self._n = obj, rows, n   # n: the object's row count

    def __getattr__(self, name):
        value = getattr(self._obj, name)
        if isinstance(value, np.ndarray) and value.ndim and len(value) == self._n:
            value = np.take(value, self._rows, axis=0)
        setattr(self, name, value)
        return value


# Light selection 'auto' samples every light at vertices where lobes this
# narrow (GGX alpha, roughness 0.5) take most of the BSDF's sampling weight.
EVERY_LIGHT_ALPHA = 0.25


def _every_light(lobes, selection):
    """Vertices whose BSDF is mostly narrow glossy reflection, where one
    light picked without regard to the lobe is often outside it."""
    narrow = (lobes.kind == bsdf.GLOSSY) & (lobes.alpha <= EVERY_LIGHT_ALPHA)
    return np.where(narrow, selection, 0.0).sum(axis=1) > 0.5


def _nee_select(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth, tile):
    u = _uniforms(ctx, paths, vertex_set(depth, LIGHT))
    e, p_sel = ctx.lights.select(u[:, 0], hit.p, hit.ng)
    _shade_light(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, e, p_sel, u[:, 1:], tile)


def _nee_each(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth, tile, emitters):
    n = len(paths.pix)
    for e in emitters:
        u = _uniforms(ctx, paths, emitter_set(depth, e))[:, :3]
        _shade_light(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, np.full(n, e), np.ones(n), u, tile)


def _shade_light(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, e, p_sel, u, tile=None):
    s = ctx.settings
    ls = ctx.lights.sample(e, hit.p, u[:, 0], u[:, 1], u[:, 2])
    wi_l = to_local(ls.wi, tt, bb, hit.ns)
    f, pdf_b = bsdf.eval_pdf(lobes, wo_l, wi_l, *lobes_wo)
    if ctx.light_excludes:
        f = _visible_lobes_f(ctx, lobes, wo_l, wi_l, ls.wi, hit.ng, e, f)
    contrib, w, live = nee.contribution(wi_l, ls.wi, hit.ng, ls.pdf, p_sel, pdf_b, ls.delta,
                                        s.strategy == "mis", paths.beta, f, ls.Le)
    live = np.flatnonzero(live)
    if len(live) == 0:
        return
    if ctx.transparent_shadows:
        origin, wi, tmax = shadow_rays(hit.p, hit.ng, ls.wi, ls.dist, ls.on_surface, hit.eps, live)
        added = contrib[live] * _transmittance(ctx, origin, wi, tmax, e[live], paths.tbounce[live])
        paths.L[live] += added
        free = live
    else:
        o, d, tfar = shadow_rays_f32(hit.p, hit.ng, ls.wi, ls.dist, ls.on_surface, hit.eps, live)
        free = live[~_occluded(ctx, o, d, tfar, e[live])]
        _add_rows(paths.L, free, contrib)
        added = None
    if pass_events.listening(tile):
        if added is None:
            added = np.take(contrib, free, axis=0)
        pass_events.nee(ctx, paths, free, added, w[free], np.broadcast_to(ls.delta, w.shape)[free],
                        lobes, lobes_wo, wo_l, wi_l[free], f[free], tile, emitters=e[free])


def _add_rows(L, rows, values):
    """L[rows] += values[rows] (rows unique), in one compiled loop."""
    if L.flags.c_contiguous and values.flags.c_contiguous and values.dtype == L.dtype == np.float64:
        _add_rows_loop(L, np.ascontiguousarray(rows, np.int64), values)
    else:
        _add_rows_numpy(L, rows, values)


def _add_rows_numpy(L, rows, values):
    """A dense masked add when rows are most of L: row-wise fancy indexing
    of (N, 3) arrays costs several times a pass over the whole array."""
    if len(rows) * 4 < len(L):
        L[rows] += np.take(values, rows, axis=0)
        return
    use = np.zeros(len(L), bool)
    use[rows] = True
    L += np.where(use[:, None], values, 0.0)


@kernels.loop_kernel("void(float64[:, ::1], int64[::1], float64[:, ::1])", _add_rows_numpy)
def _add_rows_loop(L, rows, values):
    for r in rows:
        for k in range(3):
            L[r, k] += values[r, k]


def _bump_shadowing_setup(ctx, lobes, smooth, ns, tt, bb):
    """Where a normal map, bump or Bevel moved the shading normal, give the
    lobes the smooth normal (in the shading frame) for Cycles' bump
    shadowing term (bsdf.bump_shadowing), in the form of the Blender
    version the scene comes from."""
    if np.array_equal(smooth, ns):
        return
    lobes.smooth_n = to_local(smooth, tt, bb, ns)
    lobes.bump_model = np.full(len(ns), ctx.bump_model, np.int8)


def _orient(hit, lobes):
    """Tell the lobes which rays arrived on a back face: refraction inverts
    the relative IOR there (leaving the medium)."""
    back = getattr(hit, "back", None)
    if back is not None:
        lobes.back = back


def _scatter(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, depth):
    """Sample the BSDF and update the path state in place; returns which
    paths live on and which passed straight through a transparent lobe."""
    s = ctx.settings
    u = _uniforms(ctx, paths, vertex_set(depth, BSDF))
    wi_l, weight, pdf, delta = bsdf.sample(lobes, wo_l, u[:, 0], u[:, 1], u[:, 2], *lobes_wo)
    wi = to_world(wi_l, tt, bb, hit.ns)
    ok, paths.beta = throughput.update(wi, hit.ng, wi_l, weight, paths.beta, paths.bounce, s.rr_depth, u[:, 3])
    through = _sampled_transparent(ctx, hit, delta, wi_l, wo_l)
    if through.any():
        # A transparent pass is not a vertex: the path keeps its direction,
        # MIS pdf and segment start (Cycles moves only the ray's tmin).
        wi[through] = paths.d[through]
        pdf = np.where(through, paths.prev_pdf, pdf)
        delta = np.where(through, paths.prev_delta, delta)
    o = ctx.accel.offset_origin(hit.p, hit.ng, wi, hit.eps)
    paths.tmax = _unless(through, paths.tmax - dot(o - paths.o, wi), np.full(len(wi), np.inf))
    paths.mis_o = _unless(through, paths.mis_o, o)
    paths.o = o
    paths.d = wi
    paths.prev_pdf = pdf
    paths.prev_delta = delta
    paths.bounce = paths.bounce + ~through
    paths.tbounce = paths.tbounce + through
    return ok, through


def _sampled_transparent(ctx, hit, delta, wi_l, wo_l):
    """Which samples chose a transparent lobe: bsdf.sample returns exactly
    -wo for them (a delta sample; refraction through glass of IOR 1 is not
    bit-exact, and materials without a transparent lobe are excluded)."""
    if not ctx.transparent_shadows:
        return np.zeros(len(delta), bool)
    return delta & ctx.transparent_mat[hit.mat] & np.all(wi_l == -wo_l, axis=1)


# ----------------------------------------------------------------------------
# Ray visibility (Blender's Object > Visibility > Ray Visibility, as Cycles)

MAX_SKIPS = 16   # invisible surfaces a ray may pass before it counts as a miss
VIS_INDIRECT = VIS_DIFFUSE | VIS_GLOSSY | VIS_TRANSMISSION


def _visibility_setup(ctx):
    """Whether paths must track their ray kind, and whether some light is
    excluded from some bounce kind: both False in the common scene, which
    then pays nothing for visibility."""
    vis = ctx.lights.visibility
    indirect = VIS_INDIRECT
    ctx.light_excludes = bool(np.any((vis & indirect) != indirect))
    ctx.light_no_shadow = bool(np.any((vis & VIS_SHADOW) == 0))
    tv = ctx.triangles.visibility
    ctx.track_rays = ctx.light_excludes or (tv is not None and bool(np.any((tv & indirect) != indirect)))
    ctx.shadow_skips = tv is not None and bool(np.any((tv & VIS_SHADOW) == 0))


def _skip_invisible(ctx, o, d, tmax, ray, t, prim, bu, bv):
    """Closest hit among triangles visible to each ray's kind: embreex has no
    ray masks, so rays that hit an invisible triangle continue past it."""
    vis = ctx.triangles.visibility
    t, prim, bu, bv = t.copy(), prim.copy(), bu.copy(), bv.copy()
    for _ in range(MAX_SKIPS):
        again = np.nonzero((prim >= 0) & ((vis[np.maximum(prim, 0)] & ray) == 0))[0]
        if len(again) == 0:
            return t, prim, bu, bv
        tn, pn, un, vn = _continue_past(ctx, o[again], d[again], tmax[again], t[again], prim[again])
        t[again], prim[again], bu[again], bv[again] = tn, pn, un, vn
    miss = (prim >= 0) & ((vis[np.maximum(prim, 0)] & ray) == 0)
    t[miss], prim[miss] = np.inf, -1
    return t, prim, bu, bv


def _continue_past(ctx, o, d, tmax, t, prim):
    """Intersect again from just behind the hit triangle; t stays measured
    from the original origin o."""
    p = o + d * t[:, None]
    start = ctx.accel.offset_origin(p, ctx.triangles.ng[prim], d)
    t0 = dot(start - o, d)
    tn, pn, un, vn = ctx.accel.intersect(start, d, np.maximum(tmax - t0, 0.0))
    return np.where(pn >= 0, tn + t0, np.inf), pn, un, vn


def _occluded(ctx, origin, wi, tmax, emitter):
    """Shadow test: lights with visible_shadow off (Cycles' Cast Shadow) are
    never blocked; objects with visible_shadow off never block."""
    if not ctx.light_no_shadow and not ctx.shadow_skips:
        return ctx.accel.occluded(origin, wi, tmax)
    blocked = np.zeros(len(origin), bool)
    test = np.ones(len(origin), bool)
    if ctx.light_no_shadow:
        test = (ctx.lights.visibility[emitter] & VIS_SHADOW) != 0
    idx = np.nonzero(test)[0]
    if not ctx.shadow_skips:
        blocked[idx] = ctx.accel.occluded(origin[idx], wi[idx], tmax[idx])
        return blocked
    t, prim, _, _ = ctx.accel.intersect(origin[idx], wi[idx], tmax[idx])
    ray = np.full(len(idx), VIS_SHADOW, np.uint8)
    t, prim, _, _ = _skip_invisible(ctx, origin[idx], wi[idx], tmax[idx], ray, t, prim, t, t)
    blocked[idx] = prim >= 0
    return blocked


def _ray_kind(ctx, hit, lobes, wo_l, tt, bb, paths, depth):
    """VIS_* bit of the bounce just sampled, distributed as Cycles' (the kind
    of the closure it sampled): below the surface = transmission; after a
    delta (mirror) sample = glossy; else diffuse with the probability that
    the diffuse lobes produced this direction, sel_d pdf_d / pdf."""
    n = len(paths.pix)
    kind = np.full(n, VIS_GLOSSY, np.uint8)
    diffuse = _diffuse_lobe(lobes.kind)
    other = ~diffuse & (lobes.kind != bsdf.NONE)
    kind[diffuse.any(axis=1) & ~other.any(axis=1)] = VIS_DIFFUSE
    mixed = np.nonzero(diffuse.any(axis=1) & other.any(axis=1) & ~paths.prev_delta)[0]
    if len(mixed):
        wi_l = to_local(paths.d[mixed], tt[mixed], bb[mixed], hit.ns[mixed])
        only_d = _lobes_where(lobes, ~diffuse, mixed)
        sel = bsdf.selection(_lobes_where(lobes, np.zeros_like(diffuse), mixed), wo_l[mixed])
        _, pdf_d = bsdf.eval_pdf(only_d, wo_l[mixed], wi_l, sel)
        with np.errstate(divide="ignore", invalid="ignore"):
            p_d = np.where(paths.prev_pdf[mixed] > 0, pdf_d / paths.prev_pdf[mixed], 0.0)
        u = ctx.sampler.get(paths.pseed[mixed], paths.sample[mixed], vertex_set(depth, KIND))[:, 0]
        kind[mixed] = np.where(u < p_d, VIS_DIFFUSE, VIS_GLOSSY)
    kind[dot(paths.d, hit.ng) < 0] = VIS_TRANSMISSION
    return kind


def _diffuse_lobe(kind):
    """Lobes Cycles counts as diffuse closures (the registry's 'diffuse'
    class); the others reflect as glossy (transmission is told by direction)."""
    return bsdf.kind_in(kind, kinds_of_class("diffuse"))


def _lobes_where(lobes, drop, rows):
    """The lobes of ``rows`` with the ``drop`` (N, K) entries switched off."""
    per_ray = {f.name: getattr(lobes, f.name) for f in fields(lobes)}
    sub = replace(lobes, **{k: v[rows] for k, v in per_ray.items()
                            if isinstance(v, np.ndarray) and len(v) == len(lobes)})
    return replace(sub, kind=np.where(drop[rows], bsdf.NONE, sub.kind).astype(lobes.kind.dtype))


def _visible_lobes_f(ctx, lobes, wo_l, wi_l, wi, ng, emitter, f):
    """BSDF value for NEE with lights that are invisible to some bounce
    kinds: as Cycles, the excluded lobes' f is dropped (the pdf, for MIS,
    keeps every lobe)."""
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
    sel = bsdf.selection(_lobes_where(lobes, np.zeros_like(drop), rows), wo_l[rows])
    f = f.copy()
    f[rows] = bsdf.eval_pdf(_lobes_where(lobes, drop, rows), wo_l[rows], wi_l[rows], sel)[0]
    no_t = np.nonzero((vis & VIS_TRANSMISSION) == 0)[0]
    f[no_t[dot(wi[no_t], ng[no_t]) < 0]] = 0.0
    return f


# ----------------------------------------------------------------------------
# Transparency (Transparent BSDF, Principled Alpha: the 'transparent' lobe)

def _transparency_setup(ctx):
    """Which materials have a transparent lobe; scenes without one pay
    nothing (shadow rays stay plain occlusion tests).  transparent_limit:
    transparent passes after which the next surface ends the path; Cycles
    lets a path cross one even when transparent_max_bounces is 0."""
    ctx.transparent_mat = np.any(ctx.materials.kind == bsdf.TRANSPARENT, axis=1)
    ctx.transparent_shadows = bool(ctx.transparent_mat.any())
    ctx.transparent_limit = max(int(ctx.settings.transparent_max_bounces), 1)


def _pass_last(ctx, paths, hit, tile):
    """Paths at a vertex that only collects emission (past max_bounces)
    still cross transparent surfaces, weighted by their transparency, as
    Cycles (TERMINATE_AFTER_TRANSPARENT keeps the transparent closure);
    the others end here.  Returns the paths that go on."""
    go = ctx.transparent_mat[hit.mat] & (paths.tbounce < ctx.transparent_limit)
    rows = np.nonzero(go)[0]
    if len(rows):
        T = bsdf.transparency(ctx.materials.gather(hit.mat[rows], _shading(ctx, hit).take(rows)))
        paths.beta[rows] *= T
        go[rows] = row_any_positive(T)
    if not go.all():
        _finish(ctx, paths, tile, ~go)
        paths, hit = paths.take(go), _take_hit(hit, go)
    o = ctx.accel.offset_origin(hit.p, hit.ng, paths.d, hit.eps)
    paths.tmax = paths.tmax - dot(o - paths.o, paths.d)
    paths.o = o
    paths.tbounce = paths.tbounce + 1
    return paths


def _transmittance(ctx, origin, wi, tmax, emitter, tbounce):
    """(N, 3) light reaching the shadow rays' ends through transparent
    surfaces (Cycles' transparent shadows).  embreex has no any-hit filter,
    so each ray is traced again from past its transparent hit, times that
    surface's transparency; an opaque hit blocks it, and so does a
    transparent hit beyond the transparent bounces its path has left."""
    n = len(origin)
    out = np.ones((n, 3))
    cast = np.ones(n, bool)
    if ctx.light_no_shadow:
        cast = (ctx.lights.visibility[emitter] & VIS_SHADOW) != 0
    idx = np.nonzero(cast)[0]
    o, d, tm = origin[idx], wi[idx], tmax[idx]
    left = np.maximum(ctx.settings.transparent_max_bounces - tbounce[idx], 0)
    while len(idx):
        t, prim, bu, bv = ctx.accel.intersect(o, d, tm)
        if ctx.shadow_skips:
            ray = np.full(len(idx), VIS_SHADOW, np.uint8)
            t, prim, bu, bv = _skip_invisible(ctx, o, d, tm, ray, t, prim, bu, bv)
        hit = prim >= 0
        mat = ctx.triangles.material[np.maximum(prim, 0)]
        crosses = hit & ctx.transparent_mat[mat] & (left > 0)
        out[idx[hit & ~crosses]] = 0.0
        c = np.nonzero(crosses)[0]
        if len(c) == 0:
            break
        T = bsdf.transparency(ctx.materials.gather(mat[c], ShadingContext.at(
            ctx.triangles, prim[c], bu[c], bv[c], wo=-d[c], ray=np.full(len(c), VIS_SHADOW, np.uint8))))
        out[idx[c]] *= T
        c = c[row_any_positive(T)]
        # Go on from just past the surface, towards the same end point.
        start = ctx.accel.offset_origin(o[c] + d[c] * t[c, None], ctx.triangles.ng[prim[c]], d[c])
        tm = tm[c] - dot(start - o[c], d[c])
        idx, o, d, left = idx[c], start, d[c], left[c] - 1
    return out
