"""The bounce's volume stages (engine/media/ has the maths): each live
path in a medium flies freely along its ray (attenuation, emission and
perhaps a scattering before the surface), and the paths that scatter make a
volume vertex there: next-event estimation with the phase function, then a
phase-function sample for the next ray, as a surface vertex with its BSDF.
Shadow rays, from surfaces and from volume vertices, are attenuated by every
medium they cross.  Scenes without a volume (Context.media None) never get
here.

Bounces as Cycles: a scattering is a bounce (it counts towards max_bounces
and, apart, towards volume_bounces); a path past either limit, or past its
last transparent pass, is still attenuated but does not scatter, and at
its next surface only collects emission (Cycles'
PATH_RAY_TERMINATE_AFTER_TRANSPARENT): volume_bounces 0 is single
scattering, lit by next-event estimation at the scattering point and by
the phase-sampled ray finding a light.
"""
import weakref
from types import SimpleNamespace

import numpy as np

from .. import media
from ..pass_events import NO_PASSES
from ..lights.point import PointLights
from ..media import direct as direct_points, equiangular, tracking
from ..motion import path_time
from ..accel import shadow_rays
from ..sampler import BSDF, LIGHT, MEDIUM, emitter_set, vertex_set
from ..sampling import power_heuristic
from ..vec import dot, row_any_positive
from . import stages, transparency, visibility, volume_guide
from .records import RowView
from .stages import finish, nee_rounds, points_path, spread_from
from ..geometry import VIS_VOLUME
from ..hits import hit_geometry
from .visibility import VIS_INDIRECT


def free_flights(ctx, paths, found, depth, tile=None):
    """The FreeFlight of the paths in a medium (None when none is): lights
    met on the way are scaled by what reaches them, and hidden where the
    path scattered first.  The throughput changes later (``after_flights``):
    the emitters stage weighs lights by the throughput at the ray's start.
    Segments in homogeneous media also choose where their direct light is
    estimated (``_direct_setup``); camera rays' segments scatter with the
    probability the film's volume guide gives (``_camera_guide``)."""
    inside = np.flatnonzero((paths.stack >= 0).any(axis=1))
    if len(inside) == 0:
        return None
    on = RowView(paths, inside, len(paths.pix))
    t_end = np.minimum(found.t[inside], on.tmax)
    may = ~transparency.last_vertices(ctx, on)   # past max_bounces or volume_bounces: no scattering
    u = ctx.sampler.get(on.pseed, on.sample, vertex_set(depth, MEDIUM))
    u_distance = u[:, 1].copy()
    mixed = ctx.media.stack_media(on.stack)   # the stacks' summed homogeneous coefficients, phase media
    direct = _direct_setup(ctx, on, mixed[1], t_end, may, u_distance, depth)
    lit = np.flatnonzero(found.light[inside])
    x_light = np.full(len(inside), np.inf)
    if len(lit):
        rows = inside[lit]
        x = found.light_t[rows]
        if ctx.transparent_shadows:   # light_t is measured from where the straight line started
            x = x - dot(paths.o[rows] - paths.mis_o[rows], paths.d[rows])
        x_light[lit] = x
    _tracked_points(ctx, on, direct, u)
    flight = media.free_flight(ctx.media, on.stack, on.beta, t_end, may, u[:, 0], u_distance,
                               on.o, on.d, tracking_rng(ctx, on.pseed, on.sample, depth, 1), x_light, mixed)
    flight.rows = inside
    _camera_guide(paths, on, inside, flight, mixed[1], u[:, 0], u_distance, getattr(tile, "guide", None))
    _direct_points(ctx, on, flight, direct, u, depth, mixed[1], mixed[3])
    if len(lit):
        rows = inside[lit]
        x = x_light[lit]
        found.Le[rows] *= volume_guide.light_factor(flight, lit, x, media.light_factor(flight, lit, x))
        found.light[rows] = flight.t[lit] > x
    return flight


def _camera_guide(paths, on, inside, flight, sigma_s, u_channel, u_distance, view):
    """Camera rays' segments (bounce 0) in homogeneous media redo their
    scattering choice with the guide's probability (volume_guide.py) where
    the film has a guide ``view``."""
    if view is None or paths.guide.shape[1] == 0:
        return
    first = np.flatnonzero(on.bounce == 0)
    if len(first) == 0:
        return
    volume_guide.enter(paths.guide, inside[first], paths.L, flight.sigma_t[first], flight.t_end[first])
    homogeneous = flight.samples[first] if flight.tracked is None else flight.samples[first] & ~flight.tracked[first]
    k = first[homogeneous]
    if len(k) == 0:
        return
    with np.errstate(invalid="ignore", over="ignore"):
        att = -np.expm1(-flight.sigma_t[k] * flight.t_end[k, None])
    att = np.where(flight.sigma_t[k] > 0, att, 0.0)
    scattered, transmitted, depth = view
    pix = on.pix[k]
    q = volume_guide.scatter_probability(att, scattered[pix], transmitted[pix], depth[pix])
    volume_guide.guided_flight(flight, k, q, sigma_s[k], u_channel[k], u_distance[k])


# ----------------------------------------------------------------------------
# where a segment's direct light is estimated (Cycles' direct scatter)

def _direct_setup(ctx, on, ss, t_end, may, u_distance, depth):
    """Segments in scattering media that may scatter get a direct-light
    point of their own, as Cycles 5.0's: a light is picked for the whole
    segment (LightSet.select_segment, Cycles' light_tree_sample<true>: a
    spot whose cone misses the ray's start but crosses the segment keeps
    its probability) and a point of it sampled from the ray's start (its
    emitter is the one the direct-light point samples), and the stack's
    Volume > Sampling (equiangular.stack_method) says how the point is
    found: a distance, equiangular towards the sampled light point, or one
    of the two with probability 1/2 each (MIS).  Distant lights and worlds
    take distance sampling.  In heterogeneous media, the Distance setting
    keeps light sampling at the free flight's own scattering point, as
    before (those rows are left out); their equiangular and MIS points,
    and the distance points of distant lights, come from
    ``_tracked_points``.  Only with MIS strategy and one light picked per
    vertex (else the scattering point samples light, as before).  Returns
    (rows, equiangular (bool), mis (bool), light point P, t0, t1, emitter,
    its selection probability, heterogeneous (bool), the heterogeneous
    rows' points) or None."""
    s = ctx.settings
    if ctx.lights.count == 0 or s.strategy != "mis" or s.light_selection == "all":
        return None
    het = ctx.media.heterogeneous(on.stack)
    method = equiangular.stack_method(ctx.media.sampling, on.stack)
    cand = np.flatnonzero(may & np.where(het, method != equiangular.DISTANCE, np.any(ss > 0, axis=1)))
    if len(cand) == 0:
        return None
    method = method[cand]
    o = on.o[cand]
    ul = ctx.sampler.get(on.pseed[cand], on.sample[cand], vertex_set(depth, LIGHT))
    e, p_sel = ctx.lights.select_segment(ul[:, 0], o, on.d[cand], t_end[cand])
    path = points_path(ctx, on, on.o)
    ls = ctx.lights.sample(e, o, ul[:, 1], ul[:, 2], ul[:, 3], time=_time(on, cand),
                           path=None if path is None else (path[0][cand], path[1][cand]))
    ok = (ls.pdf > 0) & (p_sel > 0)
    cand, method, e, p_sel = cand[ok], method[ok], e[ok], p_sel[ok]
    finite = np.isfinite(ls.dist[ok])
    method = np.where(finite, method, equiangular.DISTANCE)
    P = o[ok] + ls.wi[ok] * np.where(finite, ls.dist[ok], 0.0)[:, None]
    t0, t1 = _lit_segment(ctx, on.o, on.d, cand, e, t_end[cand])
    mis = method == equiangular.MIS
    xi = u_distance[cand]
    equi = (method == equiangular.EQUIANGULAR) | (mis & (xi >= 0.5))
    u_distance[cand] = np.where(mis, np.where(xi < 0.5, 2.0 * xi, 2.0 * xi - 1.0), xi)   # Cycles' rscatter
    return [cand, equi, mis, P, t0, t1, e, p_sel, het[cand], None]


def _tracked_points(ctx, on, direct, u):
    """The direct-light points of the heterogeneous segments of ``direct``
    (stored in its last slot for ``_direct_points``): equiangular, or under
    MIS either equiangular or a distance from a homogeneous stand-in, the
    media's mean majorant (MediumTable.mean_majorant) plus the homogeneous
    extinction, truncated to the lit part of the segment (also the point
    of a distant light); both pdfs are closed-form, so the power heuristic
    needs no null-collision probabilities."""
    if direct is None or not direct[8].any():
        return
    rows, equi, mis, P, t0, t1 = direct[:6]
    h = np.flatnonzero(direct[8])
    r = rows[h]
    o, d = on.o[r], on.d[r]
    xi = u[r, 2]
    sigma = ctx.media.mean_majorant(on.stack[r]) + ctx.media.extinction(on.stack[r]).max(axis=1)
    t = np.zeros(len(h))
    q = equi[h]
    e, k = np.flatnonzero(q), np.flatnonzero(~q)
    t[e], _ = equiangular.sample(o[e], d[e], P[h[e]], t0[h[e]], t1[h[e]], xi[e])
    t[k] = direct_points.truncated_exponential(sigma[k], t0[h[k]], t1[h[k]], xi[k])
    p_e = equiangular.pdf(o, d, P[h], t0[h], t1[h], t)
    p_d = direct_points.truncated_pdf(np.ones((len(h), 1)), sigma[:, None], t0[h], t1[h], t)
    direct[9] = (h, t, p_e, p_d)


def _lit_segment(ctx, o, d, rows, e, t_end):
    """(t0, t1) of the rays o[rows], d[rows] (up to t_end, per row) the
    emitters e can light: a spot's cone (Cycles'
    volume_valid_direct_ray_segment), else the whole segment; one compiled
    loop over the rows (equiangular.lit_segments)."""
    cones = _spot_cones(ctx.lights)
    if cones is None:
        return np.zeros(len(rows)), np.array(t_end, np.float64, copy=True)
    return equiangular.lit_segments(o, d, rows, e, *cones, t_end)


_CONES = weakref.WeakKeyDictionary()


def _spot_cones(lights):
    """Per emitter of ``lights``: (whether its lit part is a cone: spots of
    cone up to 180 degrees wide, apex, axis, cos of the half angle), or
    None without such spots; built once per light set (gathering them per
    segment from the light groups cost 5 % of a fog batch).  The spot's
    attenuation is taken towards the sampled point of its sphere or disk:
    the cone tangent to the sphere (apex moved back r / sin(half angle))
    holds every point it lights."""
    if lights in _CONES:
        return _CONES[lights]
    n = lights.count
    lit, apex, axis, cos_half = np.zeros(n, bool), np.zeros((n, 3)), np.zeros((n, 3)), np.ones(n)
    for g in lights.groups:
        table = g.table
        if not isinstance(table, PointLights) or not table.spot.any():
            continue
        rows = np.flatnonzero(lights.kind == g.definition.kind)
        j = lights.local[rows]
        spot = table.spot[j] & (table.cos_half[j] >= 0.0)
        rows, j = rows[spot], j[spot]
        sin_half = np.sqrt(np.maximum(1.0 - table.cos_half[j] ** 2, 1e-12))
        lit[rows] = True
        apex[rows] = table.pos[j] - table.dir[j] * (table.radius[j] / sin_half)[:, None]
        axis[rows], cos_half[rows] = table.dir[j], table.cos_half[j]
    _CONES[lights] = out = (lit, apex, axis, cos_half) if lit.any() else None
    return out


def _direct_points(ctx, on, flight, direct, u, depth, sigma_s, g):
    """Sets flight.nee_scale (the factor on the light sampled at a free
    flight's scattering point: 1, or 0 for the segments ``_direct_setup``
    chose a direct-light point for) and flight.direct: (rows, t, throughput
    factor, emitter, its selection probability, Henyey-Greenstein g) of
    those points,
    sigma_s T(t) / pdf, inside the part of the segment the light can reach
    (a spot's cone): equiangular, or under MIS either equiangular or a
    distance (in homogeneous media the free flight's channel mixture of
    exponentials truncated to that part, as Cycles 5.0's homogeneous direct
    scatter), weighted 2 w by the power heuristic (Cycles'
    volume_direct_scatter_mis).  In heterogeneous media T(t) is the
    homogeneous media's transmittance in closed form times a ratio-tracking
    estimate of the textured ones' (tracking.field_transmittance), and
    sigma_s and g are evaluated there (``sigma_s``, ``g``: the stacks'
    homogeneous media's, MediumTable.stack_media)."""
    n = len(flight.t_end)
    flight.nee_scale = np.ones(n)
    flight.direct = None
    if direct is None or len(direct[0]) == 0:
        return
    rows, equi, mis, P, t0, t1, emitter, p_sel, het, tracked = direct
    flight.nee_scale[rows] = 0.0
    o, d = on.o[rows], on.d[rows]
    pc, st = flight.channel_pdf[rows], flight.sigma_t[rows]
    xi, uc = u[rows, 2], u[rows, 3]
    t, p_e, p_d = direct_points.sample_points(o, d, P, t0, t1, xi, uc, pc, st, equi, het)
    if tracked is not None:   # heterogeneous rows: sampled before their flight
        h = tracked[0]
        t[h], p_e[h], p_d[h] = tracked[1], tracked[2], tracked[3]
    ss = sigma_s[rows]
    # One compiled loop for the homogeneous weights (direct_points.point_weights).
    good, factor = direct_points.point_weights(t, p_e, p_d, equi, mis, t0, t1, st, ss)
    keep = np.flatnonzero(good)
    if len(keep) == 0:
        return
    factor = factor[keep]
    gk = g[rows[keep]]
    hk = np.flatnonzero(het[keep])
    if len(hk):   # the textured media's scattering and g at the point, the tracker's transmittance to it
        kh = keep[hk]
        r = rows[kh]
        x = on.o[r] + on.d[r] * t[kh, None]
        _, s_at, _, gw_at = ctx.media.local(on.stack[r], x, on.d[r])
        gk[hk] = _mean_g(ss[kh], gk[hk], s_at, gw_at)
        p = np.where(equi[kh], p_e[kh], p_d[kh])
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(mis[kh], 2.0 * power_heuristic(p, np.where(equi[kh], p_d[kh], p_e[kh])), 1.0)
        rng = tracking_rng(ctx, on.pseed[r], on.sample[r], depth, 4)
        T = tracking.field_transmittance(ctx.media, on.stack[r], on.o[r], on.d[r], t[kh], rng)
        factor[hk] = (ss[kh] + s_at) * T * (w / p)[:, None]
    flight.direct = (rows[keep], t[keep], factor, emitter[keep], p_sel[keep], gk)


def _mean_g(ss, g, s_at, gw_at):
    """The scattering-weighted mean g at points where homogeneous media
    (sigma_s ``ss``, mean g ``g``) and textured ones (sigma_s ``s_at``,
    summed mean(sigma_s) x g ``gw_at``, MediumTable.local) overlap: the
    point's own, not the free flight's (which is 0 where it did not
    scatter)."""
    w = ss.mean(axis=1) + s_at.mean(axis=1)
    gw = ss.mean(axis=1) * g + gw_at
    return np.where(w > 0, gw / np.where(w > 0, w, 1.0), 0.0)


def tracking_rng(ctx, pseed, sample, depth, salt):
    """The random numbers of null-scattering tracking (a ray's collisions
    are unbounded in number, so they come from a generator seeded by the
    batch's first path, the step and the purpose: deterministic for a seed)."""
    n = len(pseed)
    first = (int(pseed[0]), int(sample[0])) if n else (0, 0)
    return np.random.default_rng([int(ctx.settings.seed) & 0xFFFFFFFF, first[0], first[1], depth, salt, n])


def after_flights(ctx, paths, ended, flight, depth, tile, obs=NO_PASSES):
    """Apply the flights: emission, the throughput; the paths that scattered
    (and did not end at a light first) make a volume vertex and leave this
    bounce.  Returns ``ended`` with the scattered rows set too, the
    scattered paths moved on (None when none) and the mask of their rows,
    which the bounce's compaction drops without finishing them (one take
    per bounce, not one here and one there).  ``obs``: the pass observer,
    told of the light added here (engine.pass_events)."""
    r = flight.rows
    if flight.direct is not None:   # equiangular direct-light points, lit with the throughput at the start
        k, t, w, e, p_sel, g = flight.direct
        rows = r[k]
        at = RowView(paths, rows, len(paths.pix))   # the few fields light sampling reads
        at.beta = at.beta * w
        before = at.L.copy()
        phase = ctx.media.vertex_phase(g, flight.phase_medium[k])
        p = at.o + at.d * t[:, None]
        # The emitter picked for the segment (the point was sampled for it),
        # divided by the probability it had; its MIS weight against phase
        # sampling takes that same probability, as an emitter met by the
        # phase-sampled ray of the segment's scattering vertex does
        # (volume_vertex's ``segment``; Cycles' light_tree_pdf after
        # PATH_RAY_VOLUME_SCATTER).
        u = ctx.sampler.get(at.pseed, at.sample, vertex_set(depth, LIGHT))
        _light_sample(ctx, at, p, phase, e, p_sel, u[:, 1:], obs)
        paths.L[rows] += at.L - before
        if paths.guide.shape[1]:   # direct light at camera rays' volume points: the guide's L_s
            cam = paths.bounce[rows] == 0
            paths.guide[rows[cam], volume_guide.LS] += (at.L - before)[cam]
    if flight.emitted.any():   # most media emit nothing: no row gathers then
        emitted = paths.beta[r] * flight.emitted
        paths.L[r] += emitted
        if obs.active:
            obs.volume_emission(paths, r, emitted)
    paths.beta[r] *= flight.weight
    sc = flight.scatter & ~ended[r]
    if not sc.any():
        return ended, None, None
    rows = r[sc]
    if paths.guide.shape[1]:   # scattered in the camera ray's media: the rest is the guide's L_s
        paths.guide[rows[paths.bounce[rows] == 0], volume_guide.SCAT] = 1.0
    held = np.zeros(len(paths.pix), bool)
    held[rows] = True
    moved = paths.take(rows)
    p = moved.o + moved.d * flight.t[sc, None]
    segment = (moved.o, moved.d, flight.t_end[sc])   # the segment whose light selection lit nee_scale 0 rows
    volume_vertex(ctx, moved, p, ctx.media.vertex_phase(flight.g[sc], flight.phase_medium[sc]), depth,
                  flight.nee_scale[sc], obs, segment)
    alive = row_any_positive(moved.beta)
    if not alive.all():   # no throughput left: their light so far goes to the film
        finish(ctx, moved, tile, ~alive)
        moved = moved.take(alive)
    return ended | held, moved, held


# ----------------------------------------------------------------------------
# the volume vertex

class _Points:
    """What stages.nee_rounds asks of a set of vertices."""
    path_rows = None

    def __init__(self, n):
        self.n = n

    def __len__(self):
        return self.n


def volume_vertex(ctx, paths, p, phase, depth, nee_scale=None, obs=NO_PASSES, segment=None):
    """Light sampling at scattering points p (phase functions ``phase``,
    MediumTable.vertex_phase; its contributions times ``nee_scale``, None:
    1) and the phase-function sample of the next ray; moves the paths in
    place.  ``segment``: (start, direction, length) of the rays' segments,
    whose light selection (``_direct_setup``) lit the rows of nee_scale 0:
    the next ray's MIS takes that selection's probability there."""
    n = len(paths.pix)
    obs.volume_vertex(paths)
    if nee_scale is None:
        direct_light(ctx, paths, p, phase, depth, obs)
    else:
        lit = np.flatnonzero(nee_scale > 0)
        if len(lit):
            at = RowView(paths, lit, n)
            at.beta = at.beta * nee_scale[lit, None]
            before = at.L.copy()
            direct_light(ctx, at, p[lit], phase_rows(phase, lit), depth, obs)
            paths.L[lit] += at.L - before
    u = ctx.sampler.get(paths.pseed, paths.sample, vertex_set(depth, BSDF))
    wi, pdf = media.phase_sample(paths.d, phase, u[:, 0], u[:, 1])
    paths.spread = spread_from(paths, p)   # Cycles' volume bounce: ray->dP = sd->dP
    paths.o, paths.d, paths.mis_o, paths.prev_p = p, wi, p, p
    paths.self_prim = np.full(n, -1, np.int64)
    paths.tmax = np.full(n, np.inf)
    paths.prev_n = np.zeros((n, 4))   # no normal (the tree's n, stages.tree_normals)
    paths.prev_seg = np.full(n, -1.0)
    if segment is not None and nee_scale is not None:
        _remember_segments(paths, np.flatnonzero(nee_scale == 0), *segment)
    paths.prev_pdf = pdf
    paths.prev_delta = np.zeros(n, bool)
    paths.mis_skip = np.zeros(n, bool)
    paths.prev_every = np.zeros(n, bool)
    paths.prev_lobe = np.zeros((n, 5))
    paths.min_pdf = np.minimum(paths.min_pdf, pdf)   # Cycles' min_ray_pdf takes the phase pdf too
    paths.bounce = paths.bounce + 1
    paths.vbounce = paths.vbounce + 1
    if ctx.track_rays or ctx.triangles.visibility is not None:
        # Blender's Volume Scatter ray visibility is not exported: volume
        # rays see what indirect rays see; VIS_VOLUME tells the Light Path
        # node they left a volume scatter event.
        paths.ray = np.full(n, VIS_INDIRECT | VIS_VOLUME, np.uint8)


def _remember_segments(paths, rows, o, d, t):
    """The rows' previous vertex, for MIS, is their segment (o, d, t):
    Paths.prev_seg."""
    paths.prev_p = paths.prev_p.copy()
    paths.prev_p[rows] = o[rows]
    paths.prev_n[rows, :3] = d[rows]
    paths.prev_seg[rows] = t[rows]


def phase_rows(phase, rows):
    return tuple(a[rows] for a in phase)


def direct_light(ctx, paths, p, phase, depth, obs=NO_PASSES):
    """Next-event estimation at points p in media (phase functions
    ``phase``): paths.L gains the light reaching them times paths.beta."""
    n = len(paths.pix)
    zeros = np.zeros((n, 3))
    for _, mode, emitters in nee_rounds(ctx, _Points(n), None):
        if mode in ("select", "resample"):   # resampling weighs by a BSDF: the tree's pick at points in media
            u = ctx.sampler.get(paths.pseed, paths.sample, vertex_set(depth, LIGHT))
            e, p_sel = ctx.lights.select(u[:, 0], p, zeros)
            _light_sample(ctx, paths, p, phase, e, p_sel, u[:, 1:], obs=obs)
        else:
            for e in emitters:
                u = ctx.sampler.get(paths.pseed, paths.sample, emitter_set(depth, e))
                _light_sample(ctx, paths, p, phase, np.full(n, e), np.ones(n), u[:, :3], obs=obs)


def _time(paths, rows):
    time = path_time(paths)
    return None if time is None else time[rows]


def _light_sample(ctx, paths, p, phase, e, p_sel, u, obs=NO_PASSES):
    """One light sample per scattering point, MIS-weighted against phase
    sampling (power heuristic, with the selection probability p_sel), its
    shadow ray attenuated by the media."""
    ls = ctx.lights.sample(e, p, u[:, 0], u[:, 1], u[:, 2], time=path_time(paths), path=points_path(ctx, paths, p))
    f = media.phase_eval(dot(paths.d, ls.wi), phase)
    p_light = p_sel * ls.pdf
    if ctx.settings.strategy == "mis":
        w = np.where(ls.delta, 1.0, power_heuristic(p_sel * ls.pdf, f))
    else:
        w = np.ones(len(f))
    ok = (ls.pdf > 0) & (p_sel > 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        scale = np.where(ok, f * w / np.where(ok, p_light, 1.0), 0.0)
    contrib = paths.beta * ls.Le * scale[:, None]
    live = np.flatnonzero(row_any_positive(contrib))
    if len(live) == 0:
        return
    eps = ctx.accel.offset_scale(p)
    origin, direction, tmax = shadow_rays(p, np.zeros_like(p), ls.wi, ls.dist, ls.on_surface, eps, live)
    rng = tracking_rng(ctx, paths.pseed[live], paths.sample[live], int(paths.bounce[live[0]]), 2)
    T = shadow_transmittance(ctx, origin, direction, tmax, e[live], paths.tbounce[live], paths.stack[live], rng)
    added = contrib[live] * T
    paths.L[live] += added
    if obs.active:
        obs.volume_light(paths, live, added)


# ----------------------------------------------------------------------------
# shadow rays through media

def shadow_transmittance(ctx, origin, direction, tmax, emitter, tbounce, stack, rng):
    """(N, 3) light reaching the shadow rays' ends: blocked by opaque
    surfaces, times the transparency of transparent ones (volume boundaries
    among them) and the transmittance of every medium between, starting in
    the media of ``stack`` (N, K); heterogeneous media by ratio tracking
    with ``rng``."""
    if ctx.transparent_shadows:
        return transparency.transmittance(ctx, origin, direction, tmax, emitter, tbounce, stack=stack, rng=rng)
    T = media.transmittance_factor(ctx.media, stack, tmax, origin, direction, rng)
    T[visibility.occluded(ctx, origin, direction, tmax, emitter)] = 0.0
    return T


def trace_surface_shadows(ctx, paths, batch):
    """stages.trace_shadows in a scene with media: the shadow ray starts in
    its path's media, entering or leaving the vertex's own medium when it
    leaves through the surface."""
    rows = batch.rows if batch.at.path_rows is None else batch.at.path_rows[batch.rows]
    hit = batch.at.hit
    stack = paths.stack[rows].copy()
    mat = ctx.media.medium_of(hit.prim[batch.rows], hit.mat[batch.rows])
    back, ng = hit.back[batch.rows], hit.ng[batch.rows]
    below = np.flatnonzero(dot(batch.direction, ng) < 0)
    ctx.media.cross(stack, below, mat[below], back[below])
    e = batch.sample.emitter[batch.rows]
    rng = tracking_rng(ctx, paths.pseed[rows], paths.sample[rows], int(paths.bounce[rows[0]]) if len(rows) else 0, 3)
    T = shadow_transmittance(ctx, batch.origin, batch.direction, batch.tmax, e, paths.tbounce[rows], stack, rng)
    added = batch.sample.contrib[batch.rows] * T
    batch.free, batch.added = batch.rows, added
    paths.L[rows] += added


def cross_surfaces(ctx, paths, hit, crossing, passed):
    """Paths whose new ray passes through their hit surface (refraction, a
    transparent pass) enter or leave its medium; a transparent pass
    (``passed``) through a volume boundary takes back its transparent bounce
    (Cycles counts those apart, volume_bounds_bounce)."""
    rows = np.flatnonzero(crossing)
    if len(rows):
        ctx.media.cross(paths.stack, rows, ctx.media.medium_of(hit.prim[rows], hit.mat[rows]),
                        np.asarray(hit.back)[rows])
    free = passed & ctx.media.boundary[hit.mat]
    if free.any():
        paths.tbounce = paths.tbounce - free


def pass_boundaries(ctx, paths, hit, obs=NO_PASSES):
    """Paths at a volume boundary (the pass-through surface of a
    volume-only material, MediumTable.boundary) cross it as Cycles'
    integrate_surface_volume_only_bounds: into or out of its medium, on
    along the same ray, with no vertex, shading, light sample or Russian
    roulette, and no transparent bounce counted.  The full bounce did the
    same through the transparent lobe (a white one of weight 1: weight 1),
    at the cost of shading and sampling it.  Returns (the other paths and
    their hits, or None, None when every path crossed; the paths that
    crossed, or None).  With extra passes (``obs`` active) boundaries are
    left to the full bounce, which reports them."""
    at = ctx.media.boundary[hit.mat]
    if obs.active or not at.any():
        return paths, hit, None
    if at.all():
        _cross_boundary(ctx, paths, hit)
        return None, None, paths
    rows, rest = np.flatnonzero(at), np.flatnonzero(~at)
    moved = paths.take(rows)
    _cross_boundary(ctx, moved, hit.take(rows))
    return paths.take(rest), hit.take(rest), moved


def enter_media(ctx, paths, found, obs=NO_PASSES):
    """Rays outside every medium whose closest hit is a volume boundary
    cross it here and are traced on at once, up to BOUNDARY_STEPS times:
    no free flight is owed for a segment in no medium, so the crossing
    (as ``pass_boundaries``) needs no wavefront step of its own (camera
    rays entering a fog box, rays from a floor below it).  Moves the paths
    and ``found`` on in place.  Left to the full step where a boundary may
    do more than pass (extra passes, holdouts, shadow catchers, subsurface
    walks, bakes) or a light comes before it."""
    quiet = _quiet_boundaries(ctx, obs)
    if quiet is None:
        return
    for _ in range(BOUNDARY_STEPS):
        hit_prim = found.prim >= 0
        mat = np.take(ctx.triangles.material, np.where(hit_prim, found.prim, 0))
        rows = np.flatnonzero(hit_prim & ~found.light & quiet[mat] & (paths.stack < 0).all(axis=1))
        if len(rows) == 0:
            return
        at = RowView(paths, rows, len(paths.pix))
        _cross_boundary(ctx, at, _boundary_hit(ctx, at, found.take(rows)))
        again = stages.intersect(ctx, at)
        for name in ("o", "tmax", "tbounce", "stack") + (("self_prim",) if ctx.strands is not None else ()):
            a = getattr(paths, name).copy()   # a copy: a camera ray's o is also its mis_o
            a[rows] = getattr(at, name)
            setattr(paths, name, a)
        for name in found.__dataclass_fields__:   # intersect's own arrays: written in place
            getattr(found, name)[rows] = getattr(again, name)


def split_boundaries(ctx, paths, found, go_on, obs=NO_PASSES):
    """The paths going on (``go_on``) that are at a volume boundary, taken
    and crossed before the bounce's compaction (which then leaves them
    out), so the other paths are copied once, not once there and again by
    ``pass_boundaries``.  Returns (those paths crossed, their mask) or
    (None, None) when none or where the full step decides
    (``_quiet_boundaries``)."""
    quiet = _quiet_boundaries(ctx, obs)
    if quiet is None:
        return None, None
    at = go_on & quiet[np.take(ctx.triangles.material, np.where(go_on, found.prim, 0))]
    if not at.any():
        return None, None
    rows = np.flatnonzero(at)
    moved = paths.take(rows)
    _cross_boundary(ctx, moved, _boundary_hit(ctx, moved, found.take(rows)))
    return moved, at


def _quiet_boundaries(ctx, obs):
    """Per material, the volume boundaries a path may cross with no
    shading at all (no emission there: surface_emission's), or None where
    the full step is kept for every boundary: extra passes, holdouts,
    shadow catchers, subsurface walks, bakes."""
    if (obs.active or ctx.holdout is not None or ctx.catcher is not None or ctx.subsurface
            or ctx.bake is not None or not ctx.media.boundary.any()):
        return None
    quiet = ctx.media.boundary[:len(ctx.materials.emission)] & ~row_any_positive(ctx.materials.emission)
    quiet[list(ctx.materials.textures.emission)] = False
    return quiet


def _boundary_hit(ctx, paths, found):
    """What crossing a boundary reads of its Hit (point, normal, offset,
    material, side): without motion, points or curves the triangles'
    geometry alone, not the whole ``stages.interaction``."""
    if ctx.motion is not None or ctx.spheres is not None or ctx.strands is not None:
        return stages.interaction(ctx, paths, *found.surface)
    p, ng, _, back = hit_geometry(ctx.triangles, paths.o, paths.d, found.t, found.prim, found.bu, found.bv)
    return SimpleNamespace(p=p, ng=ng, eps=ctx.accel.offset_scale(p), prim=found.prim,
                           mat=np.take(ctx.triangles.material, found.prim), back=back)


def _cross_boundary(ctx, paths, hit):
    """Move paths on past the volume boundaries ``hit``, in place."""
    transparency.step_through(ctx, paths, hit)
    every = np.ones(len(paths.pix), bool)
    cross_surfaces(ctx, paths, hit, every, every)   # takes back step_through's transparent bounce
    if ctx.subsurface:
        paths.exit_prim[:] = -1


# Wavefront steps per bounce for volume-boundary crossings, which count no
# transparent bounce (Cycles allows VOLUME_BOUNDS_MAX = 1024 per bounce;
# paths still going after the last step are finished with what they have).
BOUNDARY_STEPS = 8


def boundary_steps(ctx):
    if ctx.media is None or not ctx.media.boundary.any():
        return 0
    return BOUNDARY_STEPS * (ctx.settings.max_bounces + 2)
