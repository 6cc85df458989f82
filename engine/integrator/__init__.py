"""Wavefront path tracer: next-event estimation and BSDF sampling combined by
multiple importance sampling (power heuristic), as pbrt-v4's PathIntegrator
and Mitsuba 3's path.cpp, but on arrays of paths.

Path state is a struct of arrays indexed by live path; dead paths are
removed by compaction after every bounce, so every NumPy operation works on
live lanes only.  ``trace_batch`` runs one batch of camera samples for a
contiguous range of pixels and returns a ``film.Tile``; ``_bounce`` is one
wavefront step, a list of named stages (engine/integrator/stages.py) over
the records of records.py, as pbrt-v4's wavefront loop.

Conventions (Cycles, measured against it): max_bounces = N means light
sampling at path vertices 0..N (vertex 0 = the first hit), and vertex N + 1
only collects emission, so N = 0 is direct lighting.  A constant world is not
light sampled (BSDF sampling only, as Cycles does); delta lights cannot be hit
by BSDF rays, so they are always light sampled, in every strategy.

Transparent surfaces (Cycles' transparent bounces and shadows): a pass
straight through a sampled transparent lobe is not a vertex; it keeps the
ray's start, MIS state and kind and counts towards ``transparent_max_bounces``
instead of max_bounces.  Shadow rays cross transparent surfaces, attenuated
by their transparency (transparency.py).  Ray visibility: visibility.py.
"""
import numpy as np

from .. import pass_events
from ..geometry import VIS_CAMERA
from ..media import start_stack
from ..nee import add_rows as _add_rows
from ..sampler import CAMERA, TIME
from ..vec import dot
from . import catcher, path_guide, stages, subsurface, transparency, volume, volume_guide
from .context import Context
from .records import Hit, LightSample, Paths, RayHits, ShadowBatch, Vertex, rows_of
from .stages import every_light as _every_light, interaction as _interaction
from .visibility import _diffuse_lobe

__all__ = ["Context", "Hit", "LightSample", "Paths", "RayHits", "ShadowBatch", "Vertex", "rows_of",
           "trace_batch", "_add_rows", "_diffuse_lobe", "_every_light", "_interaction"]


def trace_batch(ctx, pix, sample, tile):
    """Trace camera sample ``sample[i]`` of pixel ``pix[i]`` for every i and
    add them to ``tile``."""
    n = len(pix)
    pseed = ctx.sampler.pixel_seeds(pix)
    sample = np.asarray(sample, np.uint32)
    u = ctx.sampler.get(pseed, sample, CAMERA)
    first = None
    if ctx.bake is not None:   # texels of a light bake: their first hit is given
        time = np.zeros((n, 0))
        o, d, tmax, first = ctx.bake.generate(pix, u[:, 0], u[:, 1], sample)
    elif ctx.motion is None:
        time = np.zeros((n, 0))
        o, d, tmax = ctx.camera.generate(pix, u[:, 0], u[:, 1], u[:, 2], u[:, 3])
    else:   # motion blur: the sample's time, its own dimension set
        time = ctx.camera.shutter_times(pix, ctx.sampler.get(pseed, sample, TIME)[:, 0])[:, None]
        o, d, tmax = ctx.camera.generate(pix, u[:, 0], u[:, 1], u[:, 2], u[:, 3], time=time[:, 0])
    spread = (np.column_stack(ctx.camera.origin_spread(d)) if ctx.bake is None and hasattr(ctx.camera, "origin_spread")
              else np.full((n, 2), np.nan))
    paths = Paths(pix, o, d, tmax, np.ones((n, 3)), np.zeros((n, 3)),
                  np.ones(n), np.ones(n, bool), o, np.zeros((n, 4)), np.zeros(n, bool),
                  np.full(n, VIS_CAMERA, np.uint8),
                  o, np.zeros(n, np.int32), np.zeros(n, np.int32), pseed, sample,
                  np.zeros((n, pass_events.aux_width(ctx.settings)), np.float32),
                  np.zeros((n, 3 if ctx.count_kinds else 0), np.int16), np.full(n, np.inf),
                  start_stack(ctx.media, n), np.zeros(n, np.int16), np.full(n, -1, np.int64), np.zeros((n, 3)),
                  np.full(n, -1, np.int32), np.zeros(n, np.int8), time, np.zeros(n, bool),
                  np.full(n, -1, np.int64), np.zeros((n, 5)), np.zeros(n, np.int16), np.zeros(n, bool), spread,
                  np.zeros((n, volume_guide.COLUMNS if getattr(tile, "guide", None) is not None else 0)),
                  np.full(n, -1.0), path_guide.start_columns(n, tile))
    obs = pass_events.observer(ctx, tile)
    obs.start(paths)
    # Every step raises a live path's bounce or its transparent bounce
    # count, both bounded: max_bounces + 1 vertices scatter, one more only
    # collects emission, and transparent passes end at transparent_limit;
    # volume boundaries, which count no transparent bounce, get steps of their own.
    for depth in range(ctx.settings.max_bounces + 2 + ctx.transparent_limit + volume.boundary_steps(ctx)):
        if len(paths.pix) == 0:
            break
        paths = _bounce(ctx, paths, depth, tile, obs, first if depth == 0 else None)
    if len(paths.pix):
        stages.finish(ctx, paths, tile)


def _bounce(ctx, paths, depth, tile, obs=pass_events.NO_PASSES, first=None):
    """One wavefront step of the live paths; returns the paths that go on.
    Each line is a stage (stages.py) or bookkeeping (below).  ``first``:
    the RayHits of a bake's texels, given instead of traced at depth 0."""
    found = stages.intersect(ctx, paths) if first is None else first   # RayHits
    if ctx.bake is not None and not ctx.bake.filter.direct:
        found.light[paths.bounce == 1] = False                   # a bake without Direct: no lamps there
    if ctx.subsurface:
        subsurface.arrive(paths, found)                          # walks' exit points: no tracing
    if depth == 0:
        stages.camera_aovs(ctx, paths, found, tile)
    if ctx.media is not None and first is None:
        volume.enter_media(ctx, paths, found, obs)                # boundaries met outside media: crossed
    # A bake's given first hit has no segment to fly through: Cycles' init_from_bake goes straight
    # to shading the texel (no intersect or volume kernel for the P + N -> P stand-in ray).
    flight = None if ctx.media is None or first is not None else volume.free_flights(ctx, paths, found, depth, tile)
    ended = stages.emitters(ctx, paths, found, obs)              # lights on the ray
    scattered = held = None
    if flight is not None:                                       # volume vertices: NEE, phase sample
        ended, scattered, held = volume.after_flights(ctx, paths, ended, flight, depth, tile, obs)
    stages.escaped(ctx, paths, np.flatnonzero((found.prim < 0) & ~ended), tile, obs)
    go_on = (found.prim >= 0) & ~ended
    crossed = None
    if ctx.media is not None and first is None:                 # volume boundaries: crossed, no vertex
        crossed, at = volume.split_boundaries(ctx, paths, found, go_on, obs)
        if crossed is not None:
            go_on, held = go_on & ~at, at if held is None else held | at
    paths, surface = _compact(ctx, paths, found.surface, go_on, tile, held)
    if len(paths.pix) == 0:
        return _join(paths, scattered, crossed)
    hit = stages.interaction(ctx, paths, *surface)               # Hit
    if ctx.holdout is not None:                                  # camera rays at holdouts
        paths, hit = _holdouts(ctx, paths, hit, tile)
        if len(paths.pix) == 0:
            return _join(paths, scattered, crossed)
    if ctx.catcher is not None:                                  # shadow catchers: split paths
        paths, hit = catcher.split(ctx, paths, hit, tile)
    stages.surface_emission(ctx, paths, hit, depth, obs)
    passed = None
    if ctx.media is not None and first is None:                 # the other boundaries, after their emission
        paths, hit, passed = volume.pass_boundaries(ctx, paths, hit, obs)
        if paths is None:
            return _join(passed, scattered, crossed)
    paths, hit, carried = _past_last_vertex(ctx, paths, hit, tile)
    if carried is not None and ctx.subsurface:
        carried.exit_prim[:] = -1
    if len(paths.pix) == 0:
        return _join(paths, carried, scattered, passed, crossed)
    v = stages.shade(ctx, paths, hit, depth)                     # Vertex
    v.guide = stages.guide_at(ctx, v, tile)                      # path guiding there, if any
    obs.vertex(paths, v, depth)
    every = stages.sampling_every_light(ctx, v)
    trace = stages.trace_shadows if ctx.media is None else volume.trace_surface_shadows
    no_nee = depth == 0 and ctx.bake is not None and not ctx.bake.filter.direct
    for batch in () if no_nee else stages.light_samples(ctx, paths, v, depth, every):   # nee: ShadowBatch
        trace(ctx, paths, batch)
        obs.light_sample(paths, batch)
    ray = paths.ray
    alive, through = stages.scatter(ctx, paths, v, depth)       # BSDF sample, throughput, roulette
    if v.guide is not None:                                      # guided vertices: training records
        path_guide.record_slots(paths, v, np.flatnonzero(v.guide.eligible & alive), tile)
    if ctx.subsurface:                                           # BSSRDF: the random walk to the exit
        alive = subsurface.walk(ctx, paths, v, alive, depth)
    if ctx.media is not None:                                    # refracted or passed through: the volume stack
        volume.cross_surfaces(ctx, paths, hit, alive & (dot(paths.d, hit.ng) < 0) & ~subsurface.walking(paths),
                              through)
    obs.after_scatter(paths, v, through)
    held = through | subsurface.walking(paths) if ctx.subsurface else through
    stages.remember_vertex(ctx, paths, v, held, every, ray, depth)
    paths = _end(ctx, paths, alive, tile)
    return _join(paths, carried, scattered, passed, crossed)


def _join(paths, *others):
    """The paths and the others that go on (None or empty: none), in one
    concatenation."""
    parts = [p for p in (paths,) + others if p is not None and len(p.pix)]
    if len(parts) < 2:
        return parts[0] if parts else paths
    return parts[0].concat(*parts[1:])


def _compact(ctx, paths, arrays, go_on, tile, held=None):
    """End the paths not ``go_on`` (nor ``held``: moved on elsewhere, the
    volume vertices) and keep the others, and those rows of ``arrays``:
    dense arrays for every stage after, no index indirection."""
    if go_on.all():
        return paths, arrays
    stages.finish(ctx, paths, tile, ~go_on if held is None else ~go_on & ~held)
    rows = np.flatnonzero(go_on)
    return paths.take(rows), tuple(a.take(rows) for a in arrays)


def _end(ctx, paths, alive, tile):
    """End the paths absorbed or stopped by Russian roulette."""
    if alive.all():
        return paths
    stages.finish(ctx, paths, tile, ~alive)
    return paths.take(alive)


def _holdouts(ctx, paths, hit, tile):
    """Camera paths (before any scattering, through transparent passes too)
    at holdout surfaces uncover the film by the holdout weight times their
    throughput; those at a full holdout end there (Cycles'
    integrate_surface_holdout).  Returns the paths and hits that go on."""
    weight = np.where(paths.bounce == 0, ctx.holdout[hit.prim], 0.0)
    rows = np.flatnonzero(weight > 0)
    if len(rows) == 0:
        return paths, hit
    tile.add_holdout(paths.pix[rows], weight[rows] * paths.beta[rows].mean(axis=1))
    go_on = weight < 1.0
    if go_on.all():
        return paths, hit
    stages.finish(ctx, paths, tile, ~go_on)
    return paths.take(go_on), hit.take(go_on)


def _past_last_vertex(ctx, paths, hit, tile):
    """Split off the paths at a vertex that only collects emission: those
    crossing a transparent surface go on (``carried``, joined to the paths
    after this bounce; None when none), the others end.  Returns (paths,
    hit, carried)."""
    last = transparency.last_vertices(ctx, paths)
    if not last.any():
        return paths, hit, None
    # Only paths at a material with a transparent lobe may cross: the
    # others end here, without a copy of their rows.
    may = last & ctx.transparent_mat[hit.mat] if ctx.transparent_shadows else np.zeros(len(last), bool)
    ends = last & ~may
    if ends.any():
        stages.finish(ctx, paths, tile, ends)
    if not may.any():
        rest = np.flatnonzero(~last)
        return paths.take(rest), hit.take(rest), None
    carried, at = paths.take(may), hit.take(may)
    go = transparency.pass_last(ctx, carried, at, lambda h: stages.shading(ctx, h))
    if not go.all():
        stages.finish(ctx, carried, tile, ~go)
        carried, at = carried.take(go), at.take(go)
    transparency.step_through(ctx, carried, at)
    if ctx.media is not None:
        volume.cross_surfaces(ctx, carried, at, np.ones(len(carried.pix), bool), np.ones(len(carried.pix), bool))
    return paths.take(~last), hit.take(~last), carried
