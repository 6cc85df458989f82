"""What the integrator tells the extra passes, and what each pass adds.

The integrator reports to one observer per batch (``observer(ctx, tile)``
at the end of this file): the bounce's stages hand it their records (a
Vertex, a traced ShadowBatch, the rows that met an emitter) where they add
light or leave a surface.  Without extra passes the observer is NO_PASSES,
whose hooks do nothing, so the physics stays in engine/integrator/ and the
passes stay here.

Vertices: vertex 0 is the first surface a camera path scatters at
(``paths.bounce`` counts scattering vertices; transparent passes are not
vertices).  Light found by next-event estimation (NEE) at vertex k, or by the
BSDF sample of vertex k hitting an emitter (``paths.bounce`` = k + 1), is
*direct* light of vertex k; Cycles' Direct passes hold vertex 0's, its
Indirect passes every later vertex's.

Strategy passes (issue 13): ``Strategy Light`` and ``Strategy BSDF`` hold the
MIS-weighted contributions of light sampling and of BSDF sampling, at every
vertex (or vertex 0 only with ``PassConfig.strategy_first_vertex``), so
Strategy Light + Strategy BSDF + Emission + Environment = Combined (before
clamping).  The Unweighted passes hold each strategy's own estimate of the
same light, from the same samples, without the MIS weight: only light that
both strategies can reach counts there (no delta lights, no light after a
mirror bounce, no constant-colour world, which Ember samples by BSDF only).
``MIS Weight Light`` averages the weight MIS gives light sampling over the
directions both strategies sampled at vertex 0, each counted by what it
brings: it converges to the share of the direct light MIS takes from light
sampling (see _add_light_weight).
"""
import threading
from dataclasses import replace

import numpy as np

from . import bsdf, instance_batch, instance_columns
from .lights import scene_lights_in_order
from .lobes import kinds_of_class
from .passes import (AOV_COLOR, CRYPTO, LIGHT_CLASSES, STRATEGY, VOLUME_PASSES, PassConfig, crypto_manifest,
                     is_aov, light_groups)
from .rows import take_arrays
from .sampling import cosine_hemisphere
from .vec import dot, luminance, to_local, to_world

# Per-path state (Paths.aux columns), only when passes are requested:
# the share of each light class (diffuse, glossy, transmission; RGB each) in
# the BSDF sample that left vertex 0; whether the denoising features are
# still to be written, and their throughput (Cycles'); whether the path's
# first scattering vertex was in a volume (Cycles' PATH_RAY_VOLUME_PASS).
SHARES, PENDING, FEATURE_TP, VOLUME = slice(0, 9), 9, slice(10, 13), 13
AUX_WIDTH = 14
SPECULAR_ALPHA = 0.075  # Cycles: roughness^2 below this is specular for denoising features
DIFFUSE_KINDS = kinds_of_class("diffuse")


def configure(scene, settings):
    """The PassConfig of a render, with the scene's names for Cryptomatte."""
    cfg = settings.pass_config if settings.pass_config is not None else PassConfig()
    if not settings.passes:
        return cfg
    from .scene import DEFAULT_MATERIAL
    mats = list(scene.materials) + [DEFAULT_MATERIAL]
    return replace(
        cfg,
        group_parts=_group_parts(scene, mats, cfg, settings.passes),
        aov_tables=_aov_tables(mats, settings.passes),
        object_names=tuple(instance_batch.field_of_each(scene.instances, "name")),
        material_names=tuple(m.name for m in mats),
        asset_names=tuple(a or n for a, n in zip(instance_batch.field_of_each(scene.instances, "asset"),
                                                  instance_batch.field_of_each(scene.instances, "name"))),
        object_pass_index=tuple(instance_columns.columns(scene.instances).pass_index.astype(int).tolist()),
        material_pass_index=tuple(int(getattr(m, "pass_index", 0)) for m in mats))


def _aov_tables(materials, names):
    """{pass name: (materials, C) values}: each material's constant AOV
    output, RGB + 1 for colour AOVs (0 where the material has none)."""
    tables = {}
    for name in names:
        if not is_aov(name):
            continue
        aov = name.split(":", 1)[1]
        colour = name.startswith(AOV_COLOR)
        table = np.zeros((len(materials), 4 if colour else 1))
        for i, mat in enumerate(materials):
            entry = (getattr(mat, "aovs", None) or {}).get(aov)
            if entry is not None:
                table[i] = (*entry[0], 1.0) if colour else entry[1]
        tables[name] = table
    return tables


def _group_parts(scene, materials, cfg, names):
    """Light-group ids (-1 = none) of the emitters' sources: the scene's
    lights in LightSet's order (registry.scene_lights_in_order), the world
    (HDRI, or the constant world BSDF sampling finds), emissive materials
    (the group of the first grouped object using the material: Ember's
    emissive meshes are one emitter per material)."""
    groups = {g: i for i, g in enumerate(light_groups(names))}
    if not groups:
        return None
    of = cfg.lightgroup_of
    material = np.full(len(materials), -1, np.int64)
    for inst in instance_batch.distinct(scene.instances):   # (in order of first use)
        g = groups.get(of.get(inst.name, ""), -1)
        for m in inst.materials:
            if g >= 0 and 0 <= m < len(material) and material[m] < 0:
                material[m] = g
    return {"lights": [groups.get(of.get(l.name, ""), -1) for l in scene_lights_in_order(scene.lights)],
            "world": groups.get(cfg.world_lightgroup, -1), "material": material, "count": len(groups),
            "names": tuple(groups)}


def emitter_groups(config, lights):
    """(emitters,) light-group id per LightSet emitter (None without light
    groups): built once per render, into the Context."""
    parts = config.group_parts
    if parts is None:
        return None
    emitters = lights.per_emitter(parts["lights"], parts["world"], parts["material"])
    return np.array(list(emitters) + [-1], np.int64)


class CentreRecord:
    """Which pixels' centre rays (the FIRST passes) are traced already: the
    first batch to reach a pixel claims it.  Shared by the render's batches,
    behind a lock."""

    def __init__(self, pixels):
        self._pixels = pixels
        self._done = None   # allocated by the first claim (renders without FIRST passes never claim)
        self._lock = threading.Lock()

    def claim(self, pix):
        """The pixels of ``pix`` (unique) not claimed before; claims them."""
        with self._lock:
            if self._done is None:
                self._done = np.zeros(self._pixels, bool)
            pix = pix[~self._done[pix]]
            self._done[pix] = True
            return pix


def _add_light_groups(ctx, pix, contrib, emitters, tile, world=False):
    """Combined_<group>: light from the group's emitters, MIS-weighted as
    in Combined (all bounces), so the groups and the ungrouped light add
    up to Combined."""
    parts = ctx.pass_config.group_parts
    if parts is None or len(pix) == 0:
        return
    if emitters is None:
        gid = np.full(len(pix), parts["world"] if world else -1)
    else:
        gid = ctx.emitter_groups[np.asarray(emitters, np.int64)]
    for g, name in enumerate(parts["names"]):
        sel = gid == g
        if sel.any():
            tile.add_pass("Combined_" + name, pix[sel], contrib[sel])


def metadata(config, names):
    return {kind: crypto_manifest(config, kind) for kind in CRYPTO if kind in names}


def aux_width(settings):
    return AUX_WIDTH if settings.passes else 0


def _start(ctx, paths, tile):
    """New camera paths: reset their pass state; the first batch to reach a
    pixel also traces its centre ray for the FIRST passes."""
    if paths.aux.shape[1]:
        paths.aux[:, PENDING] = 1.0
        paths.aux[:, FEATURE_TP] = 1.0
    centre_passes(ctx, paths.pix, tile)


def centre_passes(ctx, pix, tile):
    """The FIRST passes of the pixels ``pix`` that have none yet; the
    render calls it before it drops the samples beyond a fisheye's rim,
    as Cycles' sample 0 sits at the pixel centre wherever the others fall."""
    if listening(tile) and tile.extra.first:
        pix = ctx.centres.claim(np.unique(pix))
        if len(pix):
            _centre_rays(ctx, pix, tile)


def _centre_rays(ctx, pix, tile):
    """Depth, Position, Object and Material Index from one ray through each
    pixel's centre (and the lens centre), as Cycles writes them from its
    sample 0: never averaged.  Background: depth 1e10, the rest 0."""
    cfg = ctx.pass_config
    half = np.full(len(pix), 0.5)
    o, d, tmax = ctx.camera.generate(pix, half, half, half, half)
    t, prim, _, _ = ctx.accel.intersect(o, d, tmax)
    # Beyond a fisheye's rim Cycles traces nothing: the pixel keeps the background's values.
    hit = (prim >= 0) & (t < tmax) & ~ctx.camera.outside(pix, half, half)
    p = o + d * np.where(hit, t, 0.0)[:, None]
    safe = np.where(hit, prim, 0)
    rank = np.full(len(pix), -1.0)
    depth = np.where(hit, ctx.camera.z_depth(p), 1e10)
    tile.add_pass("Depth", pix, depth, rank)
    tile.add_pass("Position", pix, np.where(hit[:, None], p, 0.0), rank)
    if tile.wants("Object Index"):
        inst = ctx.triangles.instance[safe] if ctx.triangles.instance is not None else np.zeros(len(pix), int)
        index = np.asarray(cfg.object_pass_index + (0,), float)[inst]
        tile.add_pass("Object Index", pix, np.where(hit, index, 0.0), rank)
    if tile.wants("Material Index"):
        index = np.asarray(cfg.material_pass_index + (0,), float)[ctx.triangles.material[safe]]
        tile.add_pass("Material Index", pix, np.where(hit, index, 0.0), rank)


def listening(tile):
    return getattr(tile, "extra", None) is not None


# ----------------------------------------------------------------------------
# Vertex 0: data passes (Cycles' data_passes.h), colours, Cryptomatte, AO

def _vertex(ctx, paths, hit, lobes, w, tt, bb, depth, tile):
    """Paths at a surface that scatters: the first one's data passes, and
    the denoising features of paths still looking for a non-specular one."""
    features = tile.wants("Denoising Albedo") or tile.wants("Denoising Normal")
    colours = any(tile.wants(c + " Color") for c in LIGHT_CLASSES)
    if features or colours:
        w = _closure_albedos(lobes, hit, tt, bb)
    if depth == 0:
        first_hit(ctx, paths, hit, lobes, w, tt, bb, tile)
    if colours:
        # Cycles writes the colours at every surface a camera ray meets
        # (PATH_RAY_CAMERA: before the first scattering vertex, through
        # transparent ones and volume boundaries), times the throughput.
        rows = np.flatnonzero(paths.bounce == 0)
        if len(rows) == len(paths.pix):
            _colours(lobes, (w[0] * paths.beta[:, None], w[1] * paths.beta[:, None]), paths.pix, tile)
        elif len(rows):
            sub = lobe_rows(lobes, rows)
            tp = paths.beta[rows][:, None]
            _colours(sub, (w[0][rows] * tp, w[1][rows] * tp), paths.pix[rows], tile)
    if features:
        _denoising_features(ctx, paths, hit, lobes, w[0] + w[1], tile)


def _closure_albedos(lobes, hit, tt, bb):
    """Each lobe's (reflection, transmission) albedo as Cycles' bsdf_albedo
    (bsdf.closure_albedos): what its colour and denoising passes hold."""
    return bsdf.closure_albedos(lobes, to_local(hit.wo, tt, bb, hit.ns))


def first_hit(ctx, paths, hit, lobes, w, tt, bb, tile):
    """Paths at their first surface (camera rays, before any bounce)."""
    cfg = ctx.pass_config
    pix = paths.pix
    add = tile.add_pass
    add("Normal", pix, hit.ns)
    if tile.wants("UV"):
        has = _has_uv(ctx.triangles, hit.prim)
        add("UV", pix, np.where(has[:, None], np.column_stack([hit.uv, np.ones(len(pix))]), 0.0))
    if tile.wants("Mist"):
        add("Mist", pix, 1.0 - _mist(ctx, cfg, hit.p))
    if cfg.vector is not None and tile.wants("Vector"):
        u = hit.bary[:, 0] if hit.bary is not None else None   # a curve hit's u (Cycles' sd->u)
        add("Vector", pix, cfg.vector.vectors(hit.p, hit.prim, u))
        add("Vector:n", pix, np.ones(len(pix)))
    inst = ctx.triangles.instance[hit.prim] if ctx.triangles.instance is not None else np.zeros(len(pix), int)
    for name, table in (cfg.aov_tables or {}).items():
        add(name, pix, table[hit.mat])
    if tile.extra.crypto:
        _cryptomatte(cfg, inst, hit.mat, pix, tile)
    if tile.wants("Ambient Occlusion"):
        _ambient_occlusion(ctx, cfg, hit, tt, bb, pix, tile)


def _has_uv(triangles, prim):
    """Whether the triangles ``prim`` belong to meshes with a UV map."""
    shading = getattr(triangles, "shading", None)
    if shading is None:
        return np.full(len(prim), triangles.uv is not None)
    return shading.has_uv()[prim]


def _denoising_features(ctx, paths, hit, lobes, w, tile):
    """Cycles' denoising features (film/denoising_passes.h): at the first
    surface whose non-specular lobes hold over a quarter of the sample
    weight, write throughput x their albedo and the averaged normal (in
    camera space); before it, the throughput takes the specular albedo."""
    rows = np.nonzero(paths.aux[:, PENDING] > 0)[0]
    if len(rows) == 0:
        return
    kind = lobes.kind[rows]
    solid = (kind != bsdf.NONE) & (kind != bsdf.TRANSPARENT)
    albedo = w[rows] * solid[:, :, None]
    weight = albedo.mean(axis=2)
    specular = (lobes.alpha[rows] <= SPECULAR_ALPHA) | (kind == bsdf.MIRROR)
    total = weight.sum(axis=1)
    rough = (weight * ~specular).sum(axis=1)
    done = (total == 0) | (4.0 * rough > total)
    tp = paths.aux[rows][:, FEATURE_TP]
    d = np.nonzero(done)[0]
    if len(d):
        pix = paths.pix[rows[d]]
        diffuse = (albedo[d] * ~specular[d][:, :, None]).sum(axis=1)
        tile.add_pass("Denoising Albedo", pix, tp[d] * diffuse)
        normal = np.where(total[d, None] > 0, hit.ns[rows[d]], 0.0)
        tile.add_pass("Denoising Normal", pix, _to_camera(ctx, normal))
        paths.aux[rows[d], PENDING] = 0.0
    g = np.nonzero(~done)[0]
    if len(g):
        paths.aux[rows[g], FEATURE_TP] = tp[g] * (albedo[g] * specular[g][:, :, None]).sum(axis=1)


def _to_camera(ctx, v):
    """World directions in Cycles' camera space (x right, y up, z forward)."""
    rot = ctx.camera.rot
    out = v @ rot
    out[:, 2] = -out[:, 2]
    return out


def _features_at_emitter(paths, rows, unweighted, world, tile):
    """A path still looking for its denoising features meets light: Cycles
    adds throughput x radiance to the albedo; the world ends the path."""
    if not (tile.wants("Denoising Albedo") or tile.wants("Denoising Normal")):
        return
    pending = paths.aux[rows, PENDING] > 0
    if not pending.any():
        return
    r = rows[pending]
    beta = paths.beta[r]
    with np.errstate(divide="ignore", invalid="ignore"):
        Le = np.where(beta > 0, unweighted[pending] / np.where(beta > 0, beta, 1.0), 0.0)
    tile.add_pass("Denoising Albedo", paths.pix[r], paths.aux[r][:, FEATURE_TP] * Le)
    if world:
        paths.aux[r, PENDING] = 0.0


def _mist(ctx, cfg, p):
    """Cycles' mist: distance from the camera (its view depth for an
    orthographic one) mapped to 0..1 by start, depth and falloff."""
    cam = ctx.camera
    if cam.cam.kind == "ORTHO":
        dist = (p - cam.pos) @ cam.forward
    else:
        dist = np.linalg.norm(p - cam.pos, axis=1)
    m = np.clip((dist - cfg.mist_start) / max(cfg.mist_depth, 1e-30), 0.0, 1.0)
    return m if cfg.mist_falloff == 1.0 else m ** cfg.mist_falloff


def _class_of(lobes):
    """(N, K) light class of each lobe: 0 diffuse, 1 glossy, 2 transmission
    (a glass lobe counts as glossy here; its refraction is told by direction),
    -1 none or transparent."""
    kind = lobes.kind
    cls = np.where(bsdf.kind_in(kind, DIFFUSE_KINDS), 0, 1)
    cls = np.where(kind == bsdf.REFRACTION, 2, cls)
    return np.where((kind == bsdf.NONE) | (kind == bsdf.TRANSPARENT), -1, cls)


def _colours(lobes, w, pix, tile):
    """Diffuse / Glossy / Transmission Color: the summed closure albedos of
    each class at vertex 0 (Cycles' surface_shader_diffuse / glossy /
    transmission): a glass lobe's reflection estimate is glossy, its
    refracted part transmission.  ``w``: (reflection, transmission)."""
    if not any(tile.wants(c + " Color") for c in LIGHT_CLASSES):
        return
    refl, trans = w
    cls = _class_of(lobes)
    glass = lobes.kind == bsdf.GLASS
    for index, name in enumerate(LIGHT_CLASSES):
        if index == 2:
            value = (trans * (glass | (cls == 2))[:, :, None]).sum(axis=1)
        else:
            value = (refl * (cls == index)[:, :, None]).sum(axis=1)
        tile.add_pass(name + " Color", pix, value)


def _cryptomatte(cfg, inst, mat, pix, tile):
    names = cfg.asset_names
    asset_ids = {n: i for i, n in enumerate(names)}
    asset = np.array([asset_ids[n] for n in names] or [0], np.int64)
    ones = np.ones(len(pix))
    tile.extra.add_crypto("CryptoObject", pix, inst, ones)
    tile.extra.add_crypto("CryptoMaterial", pix, mat, ones)
    tile.extra.add_crypto("CryptoAsset", pix, asset[inst], ones)


def _ambient_occlusion(ctx, cfg, hit, tt, bb, pix, tile):
    """Cycles' AO pass: 1 where a cosine-distributed ray about the shading
    normal leaves above the geometric surface and meets nothing within the
    world's AO distance."""
    # Own random numbers: asking for AO must not change the other passes.
    u = np.random.default_rng([int(ctx.settings.seed), 0xA0, int(pix[0]), len(pix)]).random((len(pix), 2))
    d_l, _ = cosine_hemisphere(u[:, 0], u[:, 1])
    d = to_world(d_l, tt, bb, hit.ns)
    up = dot(d, hit.ng) > 0
    value = np.zeros(len(pix))
    rows = np.nonzero(up)[0]
    if len(rows):
        o = ctx.accel.offset_origin(hit.p[rows], hit.ng[rows], d[rows], hit.eps[rows])
        blocked = ctx.accel.occluded(o, d[rows], np.full(len(rows), cfg.ao_distance))
        value[rows] = ~blocked
    tile.add_pass("Ambient Occlusion", pix, np.repeat(value[:, None], 3, axis=1))


# ----------------------------------------------------------------------------
# Light arriving: NEE, emitters hit, the world

def _class_split(ctx, lobes, lobes_wo, wo_l, wi_l, f, delta=None):
    """(N, 3, 3) share of f in each light class for direction wi_l."""
    cls = _class_of(lobes)
    diffuse_only = replace(lobes, kind=np.where(cls == 0, lobes.kind, bsdf.NONE).astype(lobes.kind.dtype))
    f_d = bsdf.eval_pdf(diffuse_only, wo_l, wi_l, *lobes_wo)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        share_d = np.where(f > 0, np.clip(f_d / np.where(f > 0, f, 1.0), 0.0, 1.0), 0.0)
    rest = 1.0 - share_d
    below = (wi_l[:, 2] < 0)[:, None]
    if delta is not None:
        share_d = np.where(delta[:, None], 0.0, share_d)
        rest = np.where(delta[:, None], 1.0, rest)
    out = np.zeros((len(f), 3, 3))
    out[:, 0] = share_d
    out[:, 1] = np.where(below, 0.0, rest)
    out[:, 2] = np.where(below, rest, 0.0)
    return out


def _after_scatter(ctx, paths, hit, lobes, lobes_wo, tt, bb, wo_l, through, tile):
    """Remember, for paths that just left vertex 0, which light class their
    BSDF sample belongs to (Cycles' pass_diffuse_weight / glossy_weight)."""
    if not _light_passes(tile):
        return
    rows = np.nonzero((paths.bounce == 1) & ~through)[0]
    if len(rows) == 0:
        return
    sub = lobe_rows(lobes, rows)
    wi_l = to_local(paths.d[rows], tt[rows], bb[rows], hit.ns[rows])
    sel, w = lobes_wo[0][rows], lobes_wo[1][rows]
    f = bsdf.eval_pdf(sub, wo_l[rows], wi_l, sel, w)[0]
    paths.aux[rows, SHARES] = _class_split(ctx, sub, (sel, w), wo_l[rows], wi_l, f,
                                           paths.prev_delta[rows]).reshape(len(rows), 9)


def lobe_rows(lobes, rows):
    """The lobes of ``rows`` (every per-ray array taken)."""
    return take_arrays(lobes, rows, len(lobes.kind))


def _light_passes(tile):
    return (any(tile.wants(f"{c} {p}") for c in LIGHT_CLASSES for p in ("Direct", "Indirect"))
            or any(tile.wants(n) for n in VOLUME_PASSES))


def _add_light_classes(paths, rows, contrib, direct, tile, shares=None):
    """Split light by class into the Direct / Indirect passes; the light of
    paths whose first vertex was a volume scatter goes to Volume Direct /
    Indirect instead (Cycles' film_write_combined_pass: VOLUME_PASS paths)."""
    if len(rows) == 0:
        return
    vol = paths.aux[rows, VOLUME] > 0
    if vol.any():
        pix = paths.pix[rows[vol]]
        tile.add_pass("Volume Direct", pix[direct[vol]], contrib[vol][direct[vol]])
        tile.add_pass("Volume Indirect", pix[~direct[vol]], contrib[vol][~direct[vol]])
        if vol.all():
            return
        keep = ~vol
        rows, contrib, direct = rows[keep], contrib[keep], direct[keep]
        shares = None if shares is None else shares[keep]
    if shares is None:
        shares = paths.aux[rows][:, SHARES].reshape(len(rows), 3, 3)
    for index, name in enumerate(LIGHT_CLASSES):
        part = contrib * shares[:, index]
        for sel, suffix in ((direct, " Direct"), (~direct, " Indirect")):
            if sel.any():
                tile.add_pass(name + suffix, paths.pix[rows[sel]], part[sel])


def _volume_light(paths, rows, added, direct, tile, vertex=True):
    """Light added at (``vertex``: by light sampling at a volume scattering
    point whose index is the path's bounce) or along (volume emission) a
    path's segment: a volume vertex 0 makes its own light Volume Direct;
    later, the path's first vertex decides (_add_light_classes)."""
    if len(rows) == 0 or not _light_passes(tile):
        return
    if vertex:
        first = direct
        tile.add_pass("Volume Direct", paths.pix[rows[first]], added[first])
        rest = np.nonzero(~first)[0]
        rows, added, direct = rows[rest], added[rest], direct[rest]
    _add_light_classes(paths, rows, added, direct, tile)


def _nee(ctx, paths, prows, rows, contrib, w, delta, lobes, lobes_wo, wo_l, wi_l, f, tile, emitters=None):
    """Light sampling added ``contrib`` (MIS-weighted, after the shadow test)
    to paths ``prows``, the vertices ``rows`` of lobes, lobes_wo and wo_l;
    w is its MIS weight, delta marks delta lights, emitters the lights
    sampled."""
    if len(rows) == 0:
        return
    cfg = ctx.pass_config
    vertex = paths.bounce[prows]
    pix = paths.pix[prows]
    _add_light_groups(ctx, pix, contrib, emitters, tile)
    if _wants_strategy(tile):
        on = vertex == 0 if cfg.strategy_first_vertex else np.ones(len(rows), bool)
        tile.add_pass("Strategy Light", pix[on], contrib[on])
        both = on & ~delta & (w > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            tile.add_pass("Strategy Light Unweighted", pix[both], contrib[both] / w[both, None])
    if tile.wants("MIS Weight Light"):
        first = np.nonzero((vertex == 0) & ~delta & (w > 0))[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            _add_light_weight(tile, pix[first], w[first], luminance(contrib[first]) / w[first])
    if _light_passes(tile):
        direct = vertex == 0
        shares = paths.aux[prows][:, SHARES].reshape(len(rows), 3, 3).copy()
        d = np.nonzero(direct)[0]
        if len(d):
            sub = lobe_rows(lobes, rows[d])
            shares[d] = _class_split(ctx, sub, (lobes_wo[0][rows[d]], lobes_wo[1][rows[d]]),
                                     wo_l[rows[d]], wi_l[d], f[d])
        _add_light_classes(paths, prows, contrib, direct, tile, shares)


def _add_light_weight(tile, pix, w_light, brings):
    """MIS Weight Light: light sampling's MIS weight at the directions both
    strategies sampled at vertex 0, each counted by what the sample brings
    (its unweighted luminance), so the pass converges to the share of the
    direct light that MIS takes from light sampling, SL / (SL + SB)."""
    tile.add_pass("MIS Weight Light", pix, w_light * brings)
    tile.add_pass("MIS Weight Light:n", pix, brings)


def _wants_strategy(tile):
    return any(tile.wants(n) for n in STRATEGY)


def _emitter(ctx, paths, rows, unweighted, w, tile, world=False, bsdf_only=False, emitters=None):
    """An emitter (or the world) seen along the paths ``rows``: added
    unweighted * w.  bsdf_only: light that NEE never samples (a constant
    world); emitters: LightSet indices (None: the constant world or a
    light the passes do not group)."""
    if len(rows) == 0:
        return
    contrib = unweighted * w[:, None]
    bounce = paths.bounce[rows]
    pix = paths.pix[rows]
    _add_light_groups(ctx, pix, contrib, emitters, tile, world)
    camera = bounce == 0
    tile.add_pass("Environment" if world else "Emission", pix[camera], contrib[camera])
    if _wants_strategy(tile):
        cfg = ctx.pass_config
        on = bounce == 1 if cfg.strategy_first_vertex else ~camera
        tile.add_pass("Strategy BSDF", pix[on], contrib[on])
        if not bsdf_only:
            both = on & ~paths.prev_delta[rows]
            tile.add_pass("Strategy BSDF Unweighted", pix[both], unweighted[both])
    if tile.wants("MIS Weight Light") and not bsdf_only:
        first = (bounce == 1) & ~paths.prev_delta[rows]
        _add_light_weight(tile, pix[first], 1.0 - w[first], luminance(unweighted[first]))
    if _light_passes(tile) and not camera.all():
        lit = np.nonzero(~camera)[0]
        _add_light_classes(paths, rows[lit], contrib[lit], bounce[lit] == 1, tile)
    _features_at_emitter(paths, rows, unweighted, world, tile)


# ----------------------------------------------------------------------------
# The integrator's observer: one per batch, receiving the bounce's records

class NoPasses:
    """The observer of a batch without extra passes: every hook does
    nothing (``active`` False: the integrator skips what only the passes
    would read)."""
    active = False

    def start(self, paths):
        """New camera paths."""

    def vertex(self, paths, v, depth):
        """Paths at the vertices ``v`` (an integrator Vertex), before they scatter."""

    def emitter(self, paths, rows, unweighted, w, world=False, bsdf_only=False, emitters=None):
        """Paths ``rows`` met an emitter (or the world): added unweighted * w."""

    def light_sample(self, paths, batch):
        """A traced ShadowBatch added its light to the paths it reached."""

    def after_scatter(self, paths, v, through):
        """The paths left the vertices ``v`` (``through``: by a transparent pass)."""

    def volume_vertex(self, paths):
        """The paths scatter in a volume (before their bounce count rises)."""

    def volume_light(self, paths, rows, added):
        """Light sampling at volume scattering points added ``added`` to ``rows``
        (whose bounce is the vertex's index)."""

    def volume_emission(self, paths, rows, added):
        """Volume emission along the paths' last segment added ``added``."""


NO_PASSES = NoPasses()


def observer(ctx, tile):
    """The observer of a batch writing ``tile``: NO_PASSES unless the
    render asks for extra passes."""
    return PassObserver(ctx, tile) if listening(tile) else NO_PASSES


class PassObserver(NoPasses):
    """Writes the extra passes of one batch's tile from what the bounce's
    stages report."""
    active = True

    def __init__(self, ctx, tile):
        self.ctx, self.tile = ctx, tile

    def start(self, paths):
        _start(self.ctx, paths, self.tile)

    def vertex(self, paths, v, depth):
        _vertex(self.ctx, paths, v.hit, v.lobes, v.weights, v.tt, v.bb, depth, self.tile)

    def emitter(self, paths, rows, unweighted, w, world=False, bsdf_only=False, emitters=None):
        _emitter(self.ctx, paths, rows, unweighted, w, self.tile, world, bsdf_only, emitters)

    def light_sample(self, paths, batch):
        free, s, at = batch.free, batch.sample, batch.at
        if len(free) == 0:
            return
        added = np.take(s.contrib, free, axis=0) if batch.added is None else batch.added
        prows = free if at.path_rows is None else at.path_rows[free]
        _nee(self.ctx, paths, prows, free, added, s.w[free], np.broadcast_to(s.delta, s.w.shape)[free],
             at.lobes, at.lobes_wo, at.wo_l, s.wi_l[free], s.f[free], self.tile, emitters=s.emitter[free])

    def after_scatter(self, paths, v, through):
        _after_scatter(self.ctx, paths, v.hit, v.lobes, v.lobes_wo, v.tt, v.bb, v.wo_l, through, self.tile)

    def volume_vertex(self, paths):
        if paths.aux.shape[1]:
            paths.aux[paths.bounce == 0, VOLUME] = 1.0

    def volume_light(self, paths, rows, added):
        _volume_light(paths, rows, added, paths.bounce[rows] == 0, self.tile)

    def volume_emission(self, paths, rows, added):
        bounce = paths.bounce[rows]
        camera = bounce == 0
        self.tile.add_pass("Emission", paths.pix[rows[camera]], added[camera])
        lit = np.nonzero(~camera)[0]
        if len(lit) and _light_passes(self.tile):
            _volume_light(paths, rows[lit], added[lit], bounce[lit] == 1, self.tile, vertex=False)
