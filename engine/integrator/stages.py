"""The stages of a bounce (engine.integrator._bounce lists them in order).

Each stage is a function of the Context, the live ``Paths`` and the records
of engine/integrator/records.py it names; it updates the paths in place
(radiance, throughput, the next ray) or returns a new record.  Light added
to a path is reported to the pass observer (engine.pass_events) with the
record it came from.
"""
from dataclasses import replace

import numpy as np

from .. import bsdf, bump_correction, nee, throughput
from ..accel import shadow_rays, shadow_rays_f32
from ..hits import hit_geometry
from ..motion import path_time, triangles_at
from ..lobes import hair_huang
from ..lobes import registry as lobe_registry
from ..lobes.hair_huang import HAIR_HUANG
from ..points import curve_hits, curve_key_mix, curve_tangents, curve_rows, sphere_hits
from ..nodes import NodeRays, ShadingContext
from ..nodes.context import PATH_COLUMNS
from ..lights.shader import emission_path, path_rows
from ..sampler import BSDF, LIGHT, candidate_set, emitter_set, vertex_set
from ..sampling import power_heuristic
from ..vec import dot, frame, row_any_positive, row_max, to_local
from . import catcher, path_guide, portal, subsurface, transparency, visibility
from .linking import instance_of
from .records import Hit, LightSample, RayHits, ShadowBatch, Vertex, RowView, rows_of
from ..geometry import VIS_DIFFUSE, VIS_GLOSSY, VIS_TRANSMISSION
from .visibility import VIS_INDIRECT


# ----------------------------------------------------------------------------
# intersect

def intersect(ctx, paths):
    """The closest surface each ray may see and the analytic lights before it."""
    time = path_time(paths)
    if ctx.strands is None:
        t, prim, bu, bv = ctx.accel.intersect(paths.o, paths.d, paths.tmax, time=time)
    else:   # rays leaving a strand pass it (Cycles' self-intersection rule)
        t, prim, bu, bv = ctx.accel.intersect_skipping(paths.o, paths.d, paths.tmax, paths.self_prim, time=time)
    if ctx.triangles.visibility is not None:
        t, prim, bu, bv = visibility.skip_invisible(ctx, paths.o, paths.d, paths.tmax, paths.ray, t, prim, bu, bv,
                                                    time=time)
    if ctx.catcher is not None:
        t, prim, bu, bv = visibility.catchers_only(ctx, paths.o, paths.d, paths.tmax, paths.catcher == 2,
                                                   t, prim, bu, bv)
    light_t, emitter, Le, pdf = _lights_along(ctx, paths, np.minimum(t, paths.tmax))
    return RayHits(t, prim, bu, bv, light_t < np.inf, emitter, Le, pdf, light_t)


def _lights_along(ctx, paths, tmax):
    """Analytic lights on each ray before tmax, seen from where its straight
    line started (before any transparent pass, as Cycles keeps the ray's
    origin), so MIS weighs them with the pdf NEE had at that vertex.  Camera
    rays (bounce 0) see only camera-visible lights."""
    ray = paths.ray if ctx.track_rays else None
    o = paths.o
    tmin = None
    if ctx.transparent_shadows:
        # Only past the ray's current start (Cycles' ray tmin): a light the
        # line passed before a transparent surface or volume boundary was
        # collected then, and is not met again.
        o = paths.mis_o
        tmin = dot(paths.o - o, paths.d)
        tmax = tmax + tmin
        tmin = np.where(tmin > 0, tmin, 0.0)
    camera = paths.bounce == 0
    path = light_hit_path(ctx, paths)
    if camera.all() or not camera.any():
        return ctx.lights.intersect(o, paths.d, tmax, camera=bool(camera.all()), ray=ray, path=path, tmin=tmin)
    n = len(o)
    out = (np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3)), np.zeros(n))
    for rows in (np.nonzero(camera)[0], np.nonzero(~camera)[0]):
        res = ctx.lights.intersect(o[rows], paths.d[rows], tmax[rows], camera=bool(camera[rows[0]]),
                                   ray=None if ray is None else ray[rows], path=path_rows(path, rows),
                                   tmin=None if tmin is None else tmin[rows])
        for a, r in zip(out, res):
            a[rows] = r
    return out


def camera_aovs(ctx, paths, found, tile):
    """Alpha, and the first-hit AOVs the film keeps (none by default: the
    denoiser asks for normal and albedo)."""
    prim, t = found.prim, found.t
    hit_light = found.light
    hit_surf = (prim >= 0) & ~hit_light
    alpha = (hit_light | hit_surf).astype(np.float64)
    kept = getattr(tile, "aovs", None)
    depth = normal = albedo = None
    if kept is None or "depth" in kept:
        if getattr(ctx.camera, "pano", None) is not None:
            # A panorama's depth is the distance from the camera (Cycles' camera_z_depth).
            p = paths.o + paths.d * np.where(hit_surf, t, 0.0)[:, None]
            depth = np.where(hit_surf, ctx.camera.z_depth(p), 0.0)
        else:
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


# ----------------------------------------------------------------------------
# emitters: lights, the world and emissive surfaces met by the rays

def mis_hit(ctx, paths, i, emitter, pdf_light):
    """MIS weight for emitters found by BSDF sampling."""
    s = ctx.settings
    prev_delta = paths.prev_delta[i] | paths.mis_skip[i]   # a portal since the vertex: Cycles' MIS skip
    if s.strategy == "bsdf":
        return np.ones(len(i))
    if s.strategy == "light":
        return prev_delta.astype(np.float64)
    seg = paths.prev_seg[i]   # after a volume vertex lit by its segment's light selection
    if s.light_selection == "ris":
        p_sel = ctx.lights.selection_pdf(emitter, paths.prev_p[i], paths.prev_n[i], segment=seg)
        p_light = np.where(paths.prev_every[i], resampled_mis_pmf(p_sel), p_sel) * pdf_light
        return np.where(prev_delta, 1.0, power_heuristic(paths.prev_pdf[i], p_light))
    every = paths.prev_every[i] if ctx.lights.every_at_glossy else None
    lobe = paths.prev_lobe[i] if ctx.lights.lobe_term else None
    p_light = ctx.lights.selection_pdf(emitter, paths.prev_p[i], paths.prev_n[i], every, lobe, seg) * pdf_light
    return np.where(prev_delta, 1.0, power_heuristic(paths.prev_pdf[i], p_light))


def _collect(paths, i, unweighted, w):
    paths.L[i] += unweighted * w[:, None]


def emitters(ctx, paths, found, obs):
    """Analytic lights met before the surface: their MIS-weighted radiance;
    the paths go on through them (a transparent bounce).  Returns which
    paths end at a light."""
    ended = np.zeros(len(found.prim), bool)
    hit_light = found.light
    if hit_light.any():
        i = np.nonzero(hit_light)[0]
        w = linking_hits(ctx, paths, i, found.emitter[i], mis_hit(ctx, paths, i, found.emitter[i], found.pdf[i]))
        unweighted = paths.beta[i] * found.Le[i]
        _collect(paths, i, unweighted, w)
        obs.emitter(paths, i, unweighted, w, emitters=found.emitter[i])
        ended[i] = transparency.pass_light(ctx, paths, i)
    return ended


def escaped(ctx, paths, i, tile, obs):
    """Paths ``i`` left the scene: the world (an HDRI by MIS, a constant one
    unweighted) and the suns in their direction."""
    if ctx.bake is not None and not ctx.bake.filter.direct:
        i = i[paths.bounce[i] != 1]   # a bake without Direct: vertex 0's rays see no world (Cycles)
    if len(i) == 0:
        return
    catcher.camera_background(ctx, paths, i, tile)
    sky = i
    if ctx.settings.transparent:
        # With a transparent film camera rays (also through transparent
        # surfaces, which keep the ray's kind) see no world.
        camera = paths.bounce[i] == 0
        transparency.film_alpha_through(paths, i[camera & (paths.tbounce[i] > 0)], tile)
        sky = i[~camera]
    env = ctx.lights.environment_hits(paths.d[sky]) if len(sky) else None
    if env is not None:
        # An HDRI world is an emitter NEE samples: weigh it by MIS.
        emitter, Le, pdf = env
        w = mis_hit(ctx, paths, sky, np.full(len(sky), emitter), pdf)
        unweighted = paths.beta[sky] * Le
        _collect(paths, sky, unweighted, w)
        obs.emitter(paths, sky, unweighted, w, world=True, emitters=np.full(len(sky), emitter))
    else:
        if np.any(ctx.world != 0):   # a black world adds nothing: skip the row gathers
            paths.L[sky] += paths.beta[sky] * ctx.world
        if obs.active:
            obs.emitter(paths, sky, paths.beta[sky] * ctx.world, np.ones(len(sky)), world=True, bsdf_only=True)
    path = path_rows(light_hit_path(ctx, paths), i)
    for mask, emitter, Le, pdf in ctx.lights.sun_hits(paths.d[i], paths.ray[i] if ctx.track_rays else None, path):
        j = i[mask]
        if len(j):
            w = linking_hits(ctx, paths, j, emitter, mis_hit(ctx, paths, j, np.full(len(j), emitter),
                                                             np.full(len(j), pdf)))
            unweighted = paths.beta[j] * Le
            _collect(paths, j, unweighted, w)
            obs.emitter(paths, j, unweighted, w, emitters=np.full(len(j), emitter))


def surface_emission(ctx, paths, hit, depth, obs):
    """Emissive surfaces hit: their radiance, MIS-weighted against the
    light sample the previous vertex could have taken of them."""
    if ctx.bake is not None and not ctx.bake.filter.emits(depth):
        return   # a bake's filter: bake_paths.BakeFilter
    emission = ctx.materials.emission[hit.mat]
    if ctx.materials.textures.emission:
        emission = ctx.materials.textures.emission_at(hit.mat, shading(ctx, hit, paths, depth), emission)
    em = np.flatnonzero(row_any_positive(emission))
    if ctx.subsurface:
        em = em[~subsurface.at_exit(paths)[em]]   # Cycles collects no emission at an exit point
    if len(em) == 0:
        return
    if ctx.materials.emission_layers:
        # Sheen and coat dim the emission below them (Principled BSDF).
        sub = hit.take(em)
        emission = np.array(emission, copy=True)
        emission[em] = ctx.materials.dim_emission(sub.mat, ShadingContext.of_hit(ctx.triangles, sub),
                                                  dot(sub.wo, sub.ns), emission[em])
    if ctx.settings.strategy == "mis":
        emitter = ctx.lights.emitter_of_triangle(hit.mat[em])
        if ctx.unlit is not None:   # no light samples points or curves: BSDF rays find them
            emitter = np.where(ctx.unlit[hit.prim[em]], -1, emitter)
        w = np.ones(len(em))
        # A surface that is no light (its emission's estimate is 0) is found
        # by BSDF rays alone: weight 1.
        lit = np.flatnonzero(emitter >= 0)
        if len(lit):
            rows = em[lit]
            time = path_time(paths)
            pdf = ctx.lights.triangle_pdf(hit.prim[rows], paths.mis_o[rows], hit.p[rows], hit.ng[rows],
                                          time=None if time is None else time[rows])
            w[lit] = mis_hit(ctx, paths, rows, emitter[lit], pdf)
    else:
        w = mis_hit(ctx, paths, em, None, None)
    unweighted = paths.beta[em] * emission[em]
    _collect(paths, em, unweighted, w)
    obs.emitter(paths, em, unweighted, w, emitters=ctx.lights.emitter_of_triangle(hit.mat[em]))


# ----------------------------------------------------------------------------
# the surface: hit geometry, then the vertex (lobes, frame, weights)

def interaction(ctx, paths, t, prim, bu, bv):
    """The Hit of rays (paths.o, paths.d) on triangles ``prim``."""
    tr = ctx.triangles
    d = paths.d
    ray_time = path_time(paths) if ctx.motion is not None else None   # (points and curves move too)
    time = ray_time if ctx.motion is not None and ctx.motion.moving else None
    if time is None:
        p, ng, ns, back = hit_geometry(tr, paths.o, d, t, prim, bu, bv)
    else:   # the triangles where they are at each ray's time
        p, ng, ns, back = hit_geometry(triangles_at(ctx.motion, tr, prim, time), paths.o, d, t,
                                       np.arange(len(prim)), bu, bv)
    if ctx.spheres is not None:   # points: the sphere's point and normal
        on = np.flatnonzero(ctx.spheres.is_point[prim])
        if len(on):
            p[on], ng[on], back[on] = sphere_hits(ctx.spheres, paths.o[on], d[on], t[on], prim[on],
                                                    _rows(ray_time, on))
            ns[on] = ng[on]
    curve_eps = fibre = None
    if ctx.strands is not None:   # curves: the point on the round curve, its normal and tangent
        on = np.flatnonzero(ctx.strands.is_curve[prim])
        if len(on):
            p[on], ng[on], back[on], radius = curve_hits(ctx.strands, paths.o[on], d[on], t[on], prim[on], bu[on],
                                                            _rows(ray_time, on), bv[on])
            ns[on] = ng[on]
            curve_eps = (on, radius)
            fibre = np.zeros_like(p)
            fibre[on] = curve_tangents(ctx.strands, prim[on], bu[on], _rows(ray_time, on))
    uv = _hit_uv(tr, prim, bu, bv)
    hit = Hit(p, ng, ns, -d, np.take(tr.material, prim), prim, ctx.accel.offset_scale(p), uv, back=back,
              bary=np.stack([bu, bv], axis=1), depth=getattr(paths, "bounce", None),
              ray=getattr(paths, "ray", None), fibre=fibre)
    if curve_eps is not None:
        # Embree's curve distances are coarser than its triangles': leave a strand
        # by a thousandth of its radius at least.
        on, radius = curve_eps
        hit.eps[on] = np.maximum(hit.eps[on], 1e-3 * radius)
    if ctx.light_path:
        hit.path = path_columns(paths, p)
    hit.dp = footprint(paths, p)
    if getattr(tr, "tangent", None) is not None:
        w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
        # Unnormalised, as Cycles interpolates its tangent attribute.
        hit.tangent = np.einsum("nk,nkj->nj", w, tr.tangent[prim])
        hit.tangent_sign = np.where(np.einsum("nk,nk->n", w, tr.tangent_sign[prim]) < 0, -1.0, 1.0)
    return hit


def footprint(paths, p):
    """The ray footprint's radius at points p of the paths' rays, Cycles'
    compact sd->dP = ray dP + t dD (t from the ray's last vertex: a
    transparent pass moves only tmin there), or None without differentials."""
    spread = getattr(paths, "spread", None)
    if spread is None or not len(spread) or np.isnan(spread[:, 0]).any():
        return None
    return spread[:, 0] + np.linalg.norm(p - paths.mis_o, axis=1) * spread[:, 1]


def spread_from(paths, p, at=None):
    """The paths' spread for rays leaving points p (a new vertex): Cycles'
    bounce sets ray->dP to the point's sd->dP and keeps ray->dD.  ``at``:
    the footprint there when known (the Hit's dp)."""
    at = footprint(paths, p) if at is None else at
    if at is None:
        return paths.spread
    return np.column_stack([at, paths.spread[:, 1]])


def _rows(values, rows):
    """values[rows], or None without values (a still scene's ray times)."""
    return None if values is None else values[rows]


def path_columns(paths, p):
    """The Light Path node's PATH_COLUMNS at hits p: bounces by kind,
    transparent passes, the ray's length from its last vertex (Cycles
    passes transparent surfaces by moving tmin) and whether the last bounce
    was singular (a camera ray is not)."""
    n = len(p)
    zeros = np.zeros(n)
    kinds = getattr(paths, "kinds", None)
    if kinds is None or kinds.shape[1] == 0:
        kinds = np.zeros((n, 3))   # camera rays of a probe (engine/nodes/probe.py): no bounces yet
    length = np.linalg.norm(p - getattr(paths, "mis_o", paths.o), axis=1)
    singular = getattr(paths, "prev_delta", np.zeros(n, bool)) & (getattr(paths, "bounce", zeros) > 0)
    return np.column_stack([kinds, getattr(paths, "tbounce", zeros), length, singular,
                            getattr(paths, "portal", zeros)]).astype(np.float64)


def light_sample_path(ctx, paths, hit):
    """What a Light Path node in a light sample's emission reads (None when
    no material or light has one): as Cycles' light_path.h for
    PATH_RAY_EMISSION, the depth one bounce further than the vertex, its
    bounces by kind and transparent passes, not singular; the ray length is
    the sample's."""
    return points_path(ctx, paths, hit.p)


def points_path(ctx, paths, p):
    """``light_sample_path`` of light samples taken at points p (a hit's,
    or scattering points in a volume: Cycles' volume direct light reads the
    path's bounce there + 1 too)."""
    if not ctx.light_path:
        return None
    columns = path_columns(paths, p)
    columns[:, PATH_COLUMNS.index("Is Singular Ray")] = 0.0
    return emission_path(paths.bounce, columns)


def light_hit_path(ctx, paths):
    """What a Light Path node in the tree of a light that the rays hit
    reads (None when no light has one): Cycles' shade_light evaluates it as
    a light sample's, from the path's state after the bounce that cast the
    ray, so Ray Depth is the rays' bounce + 1 (a BSDF ray from vertex b:
    b + 2; a camera ray: 1) and the per-kind depths count that bounce."""
    if not (ctx.light_path and getattr(ctx.lights, "light_path", False)):
        return None
    return emission_path(paths.bounce, path_columns(paths, paths.o))


def _hit_uv(tr, prim, bu, bv):
    """Interpolated texture coordinates (0 without a UV map)."""
    if tr.uv is None:
        return np.zeros((len(prim), 2))
    c = np.take(tr.uv, prim, axis=0)
    return (1.0 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]


def shading(ctx, hit, paths=None, step=None):
    """The hit's shading context for texture and shader-node evaluation;
    given the paths, nodes may cast rays from it (AO, Bevel)."""
    sc = ShadingContext.of_hit(ctx.triangles, hit)
    if paths is not None and sc.rays is None:
        sc.rays = NodeRays.of_paths(ctx, paths, step)
    return sc


def shade(ctx, paths, hit, depth):
    """The Vertex of each hit: its material's lobes gathered at the point,
    the shading normal after normal maps and bump, the shading frame, and
    the lobe weights and selection (wo only: once per vertex)."""
    sc = shading(ctx, hit, paths, depth)
    lobes = ctx.materials.gather(hit.mat, sc)
    if ctx.subsurface:
        subsurface.exit_lobes(paths, lobes)
    if ctx.settings.filter_glossy > 0:
        filter_glossy(ctx, paths, lobes)
    if hit.back is not None:
        # Refraction inverts the relative IOR on back faces (leaving the medium).
        lobes.back = hit.back
    smooth = bent = None
    if ctx.materials.textures.normals:
        smooth = hit.ns
        bent = ctx.materials.textures.perturb(hit, ctx.triangles)
        # The shading frame is the glossy lobes' normal, Cycles' Bump Map
        # Correction of the bent one (the diffuse lobes keep that: below).
        hit.ns = bump_correction.corrected(hit.ng, hit.wo, bent, smooth)
    tt, bb = frame(hit.ns)
    # Anisotropic lobes' tangents (evaluated on the unbent normal, as Cycles'
    # Tangent node reads sd->N; projected onto the bent one).
    ctx.materials.textures.tangent_frames(hit.mat, sc, hit.ns, tt, bb)
    if hit.fibre is not None:
        fibre_frames(hit.fibre, hit.ns, tt, bb)
        hair_inputs(ctx, paths, hit, lobes, tt, bb, depth)
    wo_l = to_local(hit.wo, tt, bb, hit.ns)
    if smooth is not None:
        own = ctx.materials.textures.normal_is_smooth(hit.mat)
        if own is not None and own.any():
            smooth = np.where(own[:, None], bent, smooth)   # no bump shadowing against it
    if smooth is not None and not (np.array_equal(smooth, hit.ns) and np.array_equal(bent, hit.ns)):
        # Cycles' bump shadowing term (bsdf.bump_shadowing) needs the smooth
        # normal in the shading frame, in the scene's Blender version's form.
        lobes.smooth_n = to_local(smooth, tt, bb, hit.ns)
        lobes.bump_model = np.full(len(hit.ns), ctx.bump_model, np.int8)
        rot, split = bump_correction.rotations(tt, bb, hit.ns, bent)
        if rot is not None:
            lobes.diffuse_rot, lobes.diffuse_split = rot, split
            lobes.diffuse_smooth = bump_correction.apply(rot, lobes.smooth_n)
    w = bsdf.weights(lobes, wo_l)
    if depth == 0 and ctx.bake is not None:
        w = ctx.bake.filter_weights(lobes, w)   # the bake's pass filter: lobes kept at the texel
    return Vertex(hit, tt, bb, wo_l, lobes, w, bsdf.selection(lobes, wo_l, w))


def fibre_frames(fibre, ns, tt, bb):
    """On strands the shading frame's x is the curve's tangent (made
    perpendicular to the normal; the hair lobes read the fibre's axis and
    the offset across it from that frame, engine/lobes/hair.py).  In place,
    where ``fibre`` is not zero."""
    y = np.cross(ns, fibre)
    length = np.linalg.norm(y, axis=1)
    ok = length > 1e-12 * np.maximum(np.linalg.norm(fibre, axis=1), 1e-300)
    if not ok.any():
        return
    y = y / np.where(ok, length, 1.0)[:, None]
    tt[ok] = np.cross(y, ns)[ok]
    bb[ok] = y[ok]


def hair_inputs(ctx, paths, hit, lobes, tt, bb, depth):
    """The Huang hair lobes' per-ray inputs on strands (engine/lobes/
    hair_huang.py): the ellipse's major axis from the curve's normal, and on
    camera rays half the pixel's footprint over the fibre's radius (Cycles'
    pixel_coverage, which switches its near-field model on)."""
    huang = lobes.kind == HAIR_HUANG
    if not huang.any():
        return
    rows = np.flatnonzero(huang.any(axis=1) & ctx.strands.is_curve[hit.prim])
    if not len(rows):
        return
    slots = np.flatnonzero(huang[rows].any(axis=0))
    prim, u = hit.prim[rows], hit.bary[rows, 0]
    normal = curve_key_mix(ctx.strands, prim, u, ctx.strands.normals)
    axes = hair_huang.ellipse_axes(hit.fibre[rows], normal, tt[rows], bb[rows], hit.ns[rows])
    for k in slots:
        lobes.fibre_axis[rows, k] = axes
    if depth == 0 and hasattr(ctx.camera, "spread"):
        radius = curve_key_mix(ctx.strands, prim, u, ctx.strands.cvs[:, 3:4])[:, 0]
        dp, dd = ctx.camera.spread(-hit.wo[rows])
        footprint = dp + np.linalg.norm(hit.p[rows] - paths.o[rows], axis=1) * dd
        with np.errstate(divide="ignore", invalid="ignore"):
            coverage = 0.5 * footprint / radius
        coverage = np.where(np.isfinite(coverage) & (radius > 0), coverage, 1.0)
        for k in slots:
            lobes.pixel_coverage[rows, k] = coverage


def filter_glossy(ctx, paths, lobes):
    """Cycles' Filter Glossy: after a bounce as unlikely as pdf p (the
    path's smallest), microfacet lobes are blurred to a roughness of
    sqrt(1 - p / filter) / 2 where p < filter (Cycles' blur_pdf < 1): fewer
    caustic fireflies, a bias Cycles accepts by default (filter 1)."""
    blur_pdf = paths.min_pdf / ctx.settings.filter_glossy
    rows = np.flatnonzero(blur_pdf < 1.0)
    if len(rows):
        bsdf.blur(lobes, rows, np.sqrt(1.0 - blur_pdf[rows]) * 0.5)


# ----------------------------------------------------------------------------
# nee: one light sample per vertex (per emitter in the 'list' modes)

def sampling_every_light(ctx, v):
    """For light selection 'auto': which vertices sample every light
    (mostly narrow glossy ones); for 'ris' every vertex (MIS then weighs
    BSDF rays from there by ``resampled_mis_pmf``); None in the other
    modes."""
    s = ctx.settings
    if ctx.lights.count == 0 or s.strategy == "bsdf" or s.light_selection not in ("auto", "ris"):
        return None
    if s.light_selection == "ris":   # every surface vertex resamples its lights
        return np.ones(len(v), bool)
    return every_light(v.lobes, v.selection)


def nee_rounds(ctx, v, every):
    """The light-sampling rounds at vertices ``v``: (vertices, mode,
    emitters) with mode 'select' (one light picked per vertex), 'resample'
    (light selection 'ris': one kept of several candidates; points in
    media pick as 'select') or 'each' (one round per emitter).  Light selection 'auto' samples every light at
    the vertices ``every`` and picks one at the others: a 'mixed' round
    (its third item the mask ``every``: a picked light elsewhere, the first
    emitter there), then 'each' rounds of the other emitters at those."""
    s = ctx.settings
    if ctx.lights.count == 0 or len(v) == 0:
        return []
    if s.strategy == "bsdf":
        return [(v, "each", ctx.delta_emitters)]
    if s.light_selection == "all":
        return [(v, "each", ctx.all_emitters)]
    if s.light_selection == "ris":
        return [(v, "resample", None)]
    if every is None or not every.any():
        return [(v, "select", None)]
    if every.all():
        return [(v, "each", ctx.all_emitters)]
    # The first round over every vertex ('mixed': a picked light at the
    # others, the first emitter at those that sample every light), the
    # other emitters at the latter alone: one subset of the vertices, not
    # two (each row's numbers and order of adding light are as in a
    # 'select' round and 'each' rounds).
    tree_normals(v)   # made once, before the subset takes its rows
    rest = ctx.all_emitters[1:]
    return [(v, "mixed", every)] + ([(v.take(np.flatnonzero(every)), "each", rest)] if len(rest) else [])


# Light selection 'auto' samples every light at vertices where lobes this
# narrow (GGX alpha, roughness 0.5) take most of the BSDF's sampling weight.
EVERY_LIGHT_ALPHA = 0.25


def every_light(lobes, selection):
    """Vertices whose BSDF is mostly narrow glossy reflection, where one
    light picked without regard to the lobe is often outside it."""
    narrow = (lobes.kind == bsdf.GLOSSY) & (lobes.alpha <= EVERY_LIGHT_ALPHA)
    return np.where(narrow, selection, 0.0).sum(axis=1) > 0.5


# Light selection 'tree_bsdf': the glossy lobes' share of a vertex's sampling
# weight that the light tree's lobe factor weighs (lighttree LOBE_COLUMNS),
# at most 1 - LOBE_FLOOR so every light keeps a nonzero probability; lobes
# rougher than LOBE_MAX_ALPHA are too wide for the factor to tell lights apart.
LOBE_FLOOR = 0.03
LOBE_MAX_ALPHA = 0.5


def lobe_terms(ctx, v):
    """(N, LOBE_COLUMNS) per vertex: the mirror direction of wo about the
    shading normal (world), the glossy lobes' angular width (2 alpha, their
    selection-weighted mean, radians) and the mix; None unless
    'tree_bsdf' or where no vertex has a glossy lobe."""
    if not ctx.lights.lobe_term:
        return None
    lobes, sel = v.lobes, v.selection
    glossy = np.where((lobes.kind == bsdf.GLOSSY) & (lobes.alpha <= LOBE_MAX_ALPHA), sel, 0.0)
    share = glossy.sum(axis=1)
    if not share.any():   # no glossy vertex: the plain tree, without the factor's work
        return None
    alpha = (glossy * lobes.alpha).sum(axis=1) / np.maximum(share, 1e-12)
    wo = v.wo_l
    mirror = v.world(np.stack([-wo[:, 0], -wo[:, 1], wo[:, 2]], axis=1))
    out = np.empty((len(share), 5))
    out[:, :3] = mirror
    out[:, 3] = 2.0 * alpha + 0.02
    out[:, 4] = np.clip(share, 0.0, 1.0) * (1.0 - LOBE_FLOOR)
    return out


def tree_normals(v):
    """(N, 4) per vertex, the normal the light tree reads: the shading
    normal (Cycles' sd->N) and 1 where none of the vertex's lobes has
    transmission (Cycles' SD_BSDF_HAS_TRANSMISSION unset, registry
    ``has_transmission``): there the tree gives lights wholly behind the
    normal probability 0, in light sampling and in the MIS of BSDF rays
    that meet them (engine/lighttree.py)."""
    if v.tree_n is None:
        v.tree_n = nee.tree_normals(v.hit.ns, v.lobes.kind, v.weights, lobe_registry.transmitting())
    return v.tree_n


def light_samples(ctx, paths, v, depth, every):
    """Every light sample of the vertices ``v`` that brings light, as
    ShadowBatches (one per round, made when the previous one is traced)."""
    for at, mode, emitters in nee_rounds(ctx, v, every):
        rows = at.path_rows
        on = paths if rows is None else RowView(paths, rows, len(paths.pix))
        n = len(at)
        if mode == "resample":
            batches = [resampled_light_sample(ctx, on, at, depth)]
        elif mode in ("select", "mixed"):
            u = uniforms(ctx, on, vertex_set(depth, LIGHT))
            e, p_sel = ctx.lights.select(u[:, 0], at.hit.p, tree_normals(at), lobe_terms(ctx, at))
            u = u[:, 1:]
            if mode == "mixed":   # emitters: the vertices that sample every light
                e, p_sel, u = _first_emitter(ctx, on, depth, emitters, e, p_sel, u)
            batches = [light_sample(ctx, on, at, e, p_sel, u)]
        else:
            batches = (light_sample(ctx, on, at, np.full(n, e), np.ones(n),
                                    uniforms(ctx, on, emitter_set(depth, e))[:, :3]) for e in emitters)
        for batch in batches:
            if batch is not None:
                yield batch


def _first_emitter(ctx, paths, depth, every, e, p_sel, u):
    """The light sample's emitter, selection probability and numbers where
    ``every``: the first emitter, probability 1, that emitter's numbers (as
    an 'each' round draws them)."""
    rows = np.flatnonzero(every)
    first = ctx.all_emitters[0]
    e, p_sel, u = e.copy(), p_sel.copy(), np.array(u)
    e[rows], p_sel[rows] = first, 1.0
    u[rows] = uniforms(ctx, RowView(paths, rows, len(paths.pix)), emitter_set(depth, first))[:, :3]
    return e, p_sel, u


def linking_nee(ctx, e, prim, contrib, w, live):
    """Light linking at light samples: nothing from lights that do not
    light the vertex's object; shadow-linked lights weigh 1 (light sampling
    alone finds them, engine/integrator/linking.py)."""
    links = ctx.links
    e = np.broadcast_to(e, live.shape)
    lit = links.lit(e, instance_of(ctx, prim))
    contrib = contrib * lit[:, None]
    live = live & lit
    alone = links.shadow_linked(e) & (w > 0)
    if alone.any():
        contrib = np.where(alone[:, None], contrib / np.where(alone, w, 1.0)[:, None], contrib)
        w = np.where(alone, 1.0, w)
    return contrib, w, live


def linking_hits(ctx, paths, i, emitter, w):
    """Light linking for BSDF rays ``i`` that met ``emitter``: the weight 0
    where the light does not light the previous vertex's object, or where
    it is shadow-linked (found by light sampling alone) after a bounce."""
    if ctx.links is None:
        return w
    emitter = np.broadcast_to(emitter, (len(i),))
    keep = ctx.links.lit(emitter, paths.prev_inst[i])
    keep &= ~(ctx.links.shadow_linked(emitter) & (paths.bounce[i] > 0))
    return w * keep


def uniforms(ctx, paths, dim_set):
    """(N, 4) sample values of one dimension set for the paths."""
    return ctx.sampler.get(paths.pseed, paths.sample, dim_set)


def light_sample(ctx, paths, v, e, p_sel, u):
    """A sample of emitter e[i] (picked with probability p_sel[i]) at each
    vertex: its MIS-weighted contribution and the shadow rays of the
    vertices it brings light to (None when none)."""
    return shadow_batch(ctx, v, unshadowed(ctx, paths, v, e, p_sel, u))


# Light candidates per vertex under resampled light selection (nee.resample).
RIS_CANDIDATES = 4
_U_BELOW_1 = np.nextafter(1.0, 0.0)


def resampled_light_sample(ctx, paths, v, depth, m=None):
    """Resampled light selection (light selection 'ris'): ``m`` candidates
    per vertex, each picked by the light tree and sampled as usual, weighed
    by MIS against the BSDF with the selection probability
    ``resampled_mis_pmf`` (which mis_hit gives a BSDF ray that meets the
    light too), one kept by its unshadowed contribution with the BSDF
    (nee.resample); one shadow ray per vertex."""
    m = RIS_CANDIDATES if m is None else m
    hit = v.hit
    u = [uniforms(ctx, paths, candidate_set(depth, k)) for k in range(m)]
    # The selections are stratified: candidate k picks by a number of
    # [k/m, (k+1)/m), so the candidates spread over the lights.  Each
    # candidate alone is then no unbiased estimate, but their mean is, and
    # that is all nee.resample needs.
    strata = np.minimum((u[0][:, :1] + np.arange(m)) / m, _U_BELOW_1)
    e, p_sel = ctx.lights.select_many(strata, hit.p, tree_normals(v))
    n = len(v)
    # Every candidate's light point in one pass over m n rows (candidate k
    # of vertex i in row k n + i): the light types' loops run once.
    rows = np.tile(np.arange(n), m)
    path = light_sample_path(ctx, paths, hit)
    time = path_time(paths)
    ls = ctx.lights.sample(e.T.ravel(), hit.p[rows], *np.concatenate([uk[:, 1:] for uk in u]).T,
                           path=None if path is None else (path[0][rows], path[1][rows]),
                           time=None if time is None else time[rows])
    candidates = [unshadowed(ctx, paths, v, e[:, k], p_sel[:, k], None, resampled_mis_pmf(p_sel[:, k], m),
                             ls=_rows_of_sample(ls, k * n, (k + 1) * n)) for k in range(m)]
    # Candidate 1's spare number makes the choice.
    choice = u[1][:, 0] if m > 1 else np.zeros(n)
    kept, factor = nee.resample(np.stack([c.contrib.sum(axis=1) for c in candidates]), choice)
    chosen = _Unshadowed.pick(candidates, kept)
    chosen.contrib = chosen.contrib * factor[:, None]
    chosen.live = chosen.live & (factor > 0)
    return shadow_batch(ctx, v, chosen)


class _Unshadowed:
    """A light sample at each vertex before its shadow ray: emitter e,
    direction (world and shading frame), distance, whether it ends on a
    triangle, delta, BSDF value f, MIS weight w, contribution, live."""
    FIELDS = ("e", "wi", "wi_l", "dist", "on_surface", "delta", "f", "w", "contrib", "live")

    def __init__(self, *values):
        for name, value in zip(self.FIELDS, values):
            setattr(self, name, value)

    @classmethod
    def pick(cls, candidates, kept):
        """Row i of candidate kept[i], for every field (np.choose: one pass)."""
        out = []
        for name in cls.FIELDS:
            values = [getattr(c, name) for c in candidates]
            index = kept if np.ndim(values[0]) < 2 else kept[:, None]
            out.append(np.choose(index, values))
        return cls(*out)


def resampled_mis_pmf(p_sel, m=None):
    """The selection probability MIS weighs a light by at a vertex that
    resampled its light candidates: about the chance that the light is
    among the m stratified candidates, min(1, m p_sel); resampling keeps a
    candidate the BSDF reflects, so where one light dominates this is close
    to the probability of its sample.  Any function of the light and the
    vertex would keep MIS unbiased (NEE and BSDF rays use the same)."""
    m = RIS_CANDIDATES if m is None else m
    return np.minimum(1.0, m * p_sel)


def _rows_of_sample(ls, start, stop):
    """Rows start:stop of a lights.LightSample (views)."""
    return replace(ls, **{f: getattr(ls, f)[start:stop] for f in ("wi", "dist", "Le", "pdf", "delta", "on_surface")})


def unshadowed(ctx, paths, v, e, p_sel, u, p_mis=None, ls=None):
    """A sample of emitter e[i] (picked with probability p_sel[i]) at each
    vertex, with its MIS-weighted contribution if unoccluded (MIS with the
    selection probability p_mis, None: p_sel); ``ls``: the light sample, if
    drawn already (else drawn by u)."""
    hit = v.hit
    if ls is None:
        ls = ctx.lights.sample(e, hit.p, u[:, 0], u[:, 1], u[:, 2], path=light_sample_path(ctx, paths, hit),
                               time=path_time(paths))
    wi_l = v.local(ls.wi)
    f, pdf_b = bsdf.eval_pdf(v.lobes, v.wo_l, wi_l, *v.lobes_wo)
    if v.guide is not None:   # guided vertices: MIS against the guide-BSDF mixture
        pdf_b = path_guide.nee_pdf(v, ls.wi, pdf_b)
    if ctx.bake is not None:   # a Glossy / Transmission bake counts one side of glass lobes
        f = ctx.bake.glass_f(v, wi_l, f, paths.bounce == 0)
    if ctx.light_excludes:
        f = visibility.visible_lobes_f(ctx, v, wi_l, ls.wi, e, f)
    side_l = bump_correction.sided(v.lobes, wi_l, ls.wi, hit.ng)
    contrib, w, live = nee.contribution(side_l, ls.wi, hit.ng, ls.pdf, p_sel, pdf_b, ls.delta,
                                        ctx.settings.strategy == "mis", paths.beta, f, ls.Le, p_mis)
    if ctx.links is not None:
        contrib, w, live = linking_nee(ctx, e, hit.prim, contrib, w, live)
    return _Unshadowed(e, ls.wi, wi_l, ls.dist, ls.on_surface, ls.delta, f, w, contrib, live)


def shadow_batch(ctx, v, s):
    """The ShadowBatch of an unshadowed sample ``s``: shadow rays of the
    vertices it brings light to (None when none)."""
    hit = v.hit
    live = np.flatnonzero(s.live)
    if len(live) == 0:
        return None
    rays = shadow_rays if ctx.transparent_shadows else shadow_rays_f32
    origin, direction, tmax = rays(hit.p, hit.ng, s.wi, s.dist, s.on_surface, hit.eps, live)
    sample = LightSample(s.e, s.wi, s.wi_l, s.f, s.w, s.delta, s.contrib)
    # shadow rays from a strand pass it (light through the fibre: its TT lobes)
    skip = None if ctx.strands is None else curve_rows(ctx.strands, hit.prim[live])
    return ShadowBatch(v, sample, live, origin, direction, tmax, skip=skip)


# ----------------------------------------------------------------------------
# trace shadows

def trace_shadows(ctx, paths, batch):
    """Trace a batch's shadow rays and add the light that arrives; sets
    ``batch.free`` (the rows it reached) and, with transparent shadows,
    ``batch.added`` (what it brought through them)."""
    e = batch.sample.emitter[batch.rows]
    contrib = batch.sample.contrib
    path_rows = batch.at.path_rows
    rows = batch.rows if path_rows is None else path_rows[batch.rows]
    time = path_time(paths)
    time = None if time is None else time[rows]
    if ctx.transparent_shadows:
        added = contrib[batch.rows] * transparency.transmittance(ctx, batch.origin, batch.direction, batch.tmax,
                                                                 e, paths.tbounce[rows], time=time,
                                                                 skip=batch.skip)
        batch.free, batch.added = batch.rows, added
        paths.L[rows] += added
        return
    blocked = visibility.occluded(ctx, batch.origin, batch.direction, batch.tmax, e, time=time, skip=batch.skip)
    if ctx.catcher is not None:
        only = np.flatnonzero(paths.catcher[rows] == 2)
        if len(only):
            blocked[only] = visibility.occluded_by_catchers(ctx, batch.origin[only], batch.direction[only],
                                                            batch.tmax[only])
    batch.free = batch.rows[~blocked]
    if path_rows is None:
        nee.add_rows(paths.L, batch.free, contrib)
    else:
        paths.L[path_rows[batch.free]] += np.take(contrib, batch.free, axis=0)


# ----------------------------------------------------------------------------
# scatter: the BSDF sample, the throughput (Russian roulette included: one
# compiled pass, engine/throughput.py) and the next ray

def scatter(ctx, paths, v, depth):
    """Sample the BSDF at the vertices and move the paths on in place;
    returns (which paths live on, which passed straight through a
    transparent lobe)."""
    s = ctx.settings
    hit = v.hit
    u = uniforms(ctx, paths, vertex_set(depth, BSDF))
    if ctx.subsurface:
        wi_l, weight, pdf, delta = subsurface.sample(v, u)
        bent = v.sampled_bent
    else:
        bent = np.zeros(len(u), bool)
        v.sampled_labels = np.empty(len(u), np.int8)   # the Hair BSDF's samples' kinds (visibility.ray_kind)
        guided = v.guide is not None and v.guide.view is not None
        chosen, u_lobe = path_guide.split_choice(v.guide, u[:, 0]) if guided else (None, u[:, 0])
        wi_l, weight, pdf, delta = bsdf.sample(v.lobes, v.wo_l, u_lobe, u[:, 1], u[:, 2], *v.lobes_wo, bent=bent,
                                               labels=v.sampled_labels)
        if guided:   # one-sample MIS of the guide and the BSDF (path_guide.py)
            v.bsdf_pdf = path_guide.mix(v, chosen, u[:, 1], u[:, 2], wi_l, weight, pdf, delta, bsdf.eval_pdf)
    if depth == 0 and ctx.bake is not None:
        weight = ctx.bake.glass_weight(v, wi_l, weight, delta, np.ones(len(wi_l), bool))
    wi = v.world(wi_l)
    # Rows with a second normal (Bump Map Correction) judge a sample's side by its lobe's.
    side_l = bump_correction.sided(v.lobes, wi_l, reflected=bent)
    ok, paths.beta = throughput.update(wi, hit.ng, side_l, weight, paths.beta, paths.bounce, s.rr_depth, u[:, 3])
    through = transparency.sampled_transparent(ctx, hit, delta, wi_l, v.wo_l)
    gone = portal.chosen(v, u[:, 0], through) if ctx.portal_mat is not None else None
    if through.any():
        # A transparent pass is not a vertex: the path keeps its direction,
        # MIS pdf and segment start (Cycles moves only the ray's tmin).
        wi[through] = paths.d[through]
        pdf = np.where(through, paths.prev_pdf, pdf)
        delta = np.where(through, paths.prev_delta, delta)
    o = ctx.accel.offset_origin(hit.p, hit.ng, wi, hit.eps)
    if ctx.strands is not None:   # the next ray passes the strand it leaves (into it: through it)
        paths.self_prim = curve_rows(ctx.strands, hit.prim)
    if through.any():   # what is left of the ray past the transparent surface
        paths.tmax = np.where(through, paths.tmax - dot(o - paths.o, wi), np.inf)
    else:
        paths.tmax = np.full(len(wi), np.inf)
    paths.spread = unless(through, paths.spread, spread_from(paths, hit.p, getattr(hit, "dp", None)))
    paths.mis_o = unless(through, paths.mis_o, o)
    paths.o = o
    paths.d = wi
    paths.prev_pdf = pdf
    paths.prev_delta = delta
    paths.min_pdf = np.where(delta, paths.min_pdf, np.minimum(paths.min_pdf, pdf))
    paths.bounce = paths.bounce + ~through
    paths.tbounce = paths.tbounce + through
    if gone is not None:   # Ray Portal samples: the ray moves to the portal's exit
        portal.move(ctx, paths, v, *gone, through)
    return ok, through


def guide_at(ctx, v, tile):
    """Path guiding at vertices ``v`` (path_guide.GuideAt), or None: not
    with subsurface scattering in the scene, nor in a bake."""
    view = getattr(tile, "path_guide", None)
    recording = getattr(tile, "path_records", None) is not None
    if (view is None and not recording) or ctx.subsurface or ctx.bake is not None:
        return None
    return path_guide.at_vertices(view, recording, v, bsdf.kind_in, bsdf.NONE)


def remember_vertex(ctx, paths, v, through, every, ray, depth):
    """What the next bounce's MIS and visibility need of this vertex (a
    transparent pass keeps the previous one): its point and normal for the
    light tree's selection pdf, whether it sampled every light, and the kind
    of the ray it cast (``ray``: the kind before this bounce)."""
    hit = v.hit
    paths.prev_p = unless(through, paths.prev_p, hit.p)
    paths.prev_n = unless(through, paths.prev_n, tree_normals(v))
    paths.prev_seg = unless(through, paths.prev_seg, np.full(len(through), -1.0))
    if ctx.links is not None:
        paths.prev_inst = unless(through, paths.prev_inst, instance_of(ctx, hit.prim).astype(np.int32))
    if every is not None:
        paths.prev_every = unless(through, paths.prev_every, every)
    if ctx.lights.lobe_term:
        lobe = lobe_terms(ctx, v)
        paths.prev_lobe = unless(through, paths.prev_lobe, np.zeros((len(v), 5)) if lobe is None else lobe)
    if ctx.track_rays or ctx.count_kinds:
        kind = visibility.ray_kind(ctx, v, paths, depth)
        if ctx.count_kinds:
            count_kind(paths, kind, through)
    if ctx.track_rays:
        paths.ray = unless(through, ray, kind)
    elif ctx.triangles.visibility is not None:
        # Only camera (or shadow) visibility differs: any indirect kind sees
        # the same triangles, but no longer as a camera ray.
        paths.ray = unless(through, ray, np.full(len(ray), VIS_INDIRECT, np.uint8))


KIND_COLUMNS = (VIS_DIFFUSE, VIS_GLOSSY, VIS_TRANSMISSION)   # Paths.kinds columns


def count_kind(paths, kind, through):
    """One more bounce of its ``kind`` (VIS_* bit, Cycles' closure kind) for
    each path that scattered (a transparent pass is not a bounce)."""
    scattered = ~through
    for column, bit in enumerate(KIND_COLUMNS):
        paths.kinds[:, column] += (kind == bit) & scattered


def unless(mask, old, new):
    """new, but old where mask (per ray); new itself when mask is empty."""
    if not mask.any():
        return new
    return np.where(mask.reshape((-1,) + (1,) * (new.ndim - 1)), old, new)


# ----------------------------------------------------------------------------
# ending paths

def finish(ctx, paths, tile, keep=None):
    """Add the radiance of the paths (those where ``keep``, if given) to the tile."""
    if keep is None:
        pix, L, sample = paths.pix, paths.L, paths.sample
    else:
        pix, L, sample = paths.finish_rows(keep)
    L = np.where(np.isfinite(L), L, 0.0)
    clamp = ctx.settings.clamp
    if clamp > 0:
        m = row_max(L)
        L = L * np.where(m > clamp, clamp / np.maximum(m, 1e-30), 1.0)[:, None]
    if paths.guide_path.shape[1]:   # the path guide's records (path_guide.py)
        pg = paths.guide_path if keep is None else np.take(paths.guide_path, rows_of(keep), axis=0)
        path_guide.finish_slots(getattr(tile, "path_records", None), pg, L)
    if paths.guide.shape[1]:   # the volume guide's sums (volume_guide.py)
        tile.add_guide(pix, paths.guide if keep is None else np.take(paths.guide, rows_of(keep), axis=0), L)
    if ctx.catcher is not None:
        flag = paths.catcher if keep is None else np.take(paths.catcher, rows_of(keep))
        tile.add_catcher(pix, L, flag)
        combined = flag != 2
        pix, L, sample = pix[combined], L[combined], sample[combined]
    tile.add_radiance(pix, L, sample)
