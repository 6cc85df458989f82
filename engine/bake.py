"""Texture baking: what Blender's bake hands a render engine, turned into
surface samples (Cycles' kernel/integrator/init_from_bake.h).

Blender fills the bake render result with, per texel, the barycentrics
(u, v) and the primitive id (a corner triangle of the evaluated mesh, -1
where the texel is empty or belongs to another object) and their screen
differentials; cage, extrusion, max ray distance, selected-to-active, the
margin and the normal space/swizzle are Blender's (object_bake_api.cc):
the engine returns world-space values.

Barycentrics: Blender's (u, v) weigh the corners as P = u v0 + v v1 +
(1 - u - v) v2; Cycles converts them to Embree's (1 - u - v) v0 + u v1 + v v2.
"""
import numpy as np

# Bake types with a closed form from the mesh alone (no shading, no tracing).
GEOMETRIC = ("POSITION", "NORMAL", "UV")


def unpack_primitives(primitive):
    """(N, 3) or (N, 4) BakePrimitive rows -> (prim, u, v) in Blender's
    convention.  Blender 4.x+ writes (u, v, prim-as-int-bits); 2.92-3.x
    wrote (seed, prim, u, v), both ids stored as int bits in floats."""
    primitive = np.ascontiguousarray(primitive, np.float32)
    if primitive.shape[1] == 3:
        prim = primitive[:, 2].copy().view(np.int32)
        u, v = primitive[:, 0], primitive[:, 1]
    else:
        prim = primitive[:, 1].copy().view(np.int32)
        u, v = primitive[:, 2], primitive[:, 3]
    return prim.astype(np.int64), u.astype(np.float64), v.astype(np.float64)


def corner_weights(u, v):
    """(N, 3) weights of the triangle's corners for Blender's (u, v)."""
    return np.stack([u, v, 1.0 - u - v], axis=1)


def bake_geometric(mesh, matrix, kind, prim, u, v):
    """(N, 4) RGBA of the texels for a GEOMETRIC bake type; alpha 1 where a
    texel has a primitive, 0 (and colour 0) elsewhere.  ``mesh`` is the
    object's engine.scene.Mesh (object space), ``matrix`` its 4x4
    object-to-world matrix."""
    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    tri_count = len(mesh.triangles)
    ok = (prim >= 0) & (prim < tri_count)
    rows = np.flatnonzero(ok)
    if len(rows) == 0:
        return out
    p = prim[rows]
    w = corner_weights(u[rows], v[rows])
    m = np.asarray(matrix, np.float64)
    if kind == "POSITION":
        corners = np.asarray(mesh.positions, np.float64)[np.asarray(mesh.triangles)[p]]   # (R, 3, 3)
        local = np.einsum("rc,rcj->rj", w, corners)
        value = local @ m[:3, :3].T + m[:3, 3]
    elif kind == "NORMAL":
        value = _world_normals(mesh, m, p, w)
    elif kind == "UV":
        value = np.zeros((len(rows), 3))
        if mesh.uvs is not None:
            value[:, :2] = np.einsum("rc,rcj->rj", w, np.asarray(mesh.uvs, np.float64)[p])
    else:
        raise ValueError(f"{kind} is not a geometric bake type")
    out[rows, :3] = value
    out[rows, 3] = 1.0
    return out


def _world_normals(mesh, m, p, w):
    """Shading normals in world space, as Cycles' fast path for Normal
    bakes of materials without bump: Cycles applies the object transform to
    the mesh (its corner normals through the inverse transpose, each
    normalized) and then interpolates and normalizes; under a non-uniform
    scale that differs from transforming the interpolated normal (by up to
    0.02 on a 16-segment sphere scaled (1, 1.5, 0.8)).  Flat faces: the
    world-space face normal."""
    try:
        normal_matrix = np.linalg.inv(m[:3, :3]).T
    except np.linalg.LinAlgError:
        normal_matrix = np.eye(3)
    corners = np.asarray(mesh.positions, np.float64)[np.asarray(mesh.triangles)[p]] @ m[:3, :3].T
    ng = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    if mesh.normals is not None:
        cn = np.asarray(mesh.normals, np.float64)[p] @ normal_matrix.T               # (R, 3, 3)
        cn = cn / np.maximum(np.linalg.norm(cn, axis=2, keepdims=True), 1e-30)
        n = np.einsum("rc,rcj->rj", w, cn)
        bad = ~(np.linalg.norm(n, axis=1) > 1e-12)
        n[bad] = ng[bad]
    else:
        n = ng
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 1e-30, n / np.maximum(length, 1e-30), 0.0)


# Bake types evaluated from the material at the texel (no light transport).
SHADED = ("EMIT", "ROUGHNESS")
# Bake types that trace rays through the whole scene.
TRACED = ("AO",)
# Bake types of the light arriving at the texel: paths of the integrator
# start there (integrator/bake_paths.py), under Blender's pass filter.
LIGHT = ("DIFFUSE", "GLOSSY", "TRANSMISSION", "COMBINED")
# SHADOW: the render's Shadow Catcher pass with the baked object as a
# catcher (bake_shadow); ENVIRONMENT: the world seen along each texel's
# world position (bake_environment).
SUPPORTED = GEOMETRIC + SHADED + TRACED + LIGHT + ("SHADOW", "ENVIRONMENT")


def bake_shaded(scene, kind, prim, u, v):
    """(N, 4) RGBA of the texels for a SHADED bake type of the one-instance
    ``scene`` (an engine.scene.Scene holding the baked object and its
    materials; prim indexes its mesh's triangles).  Each texel is shaded as
    Cycles' bake does (init_from_bake.h): a hit at the texel's point seen
    along its shading normal.  EMIT: the emission (textures evaluated);
    ROUGHNESS: Cycles' surface_shader_average_roughness, the lobes'
    roughness sqrt(alpha) averaged with their colour weights (1 for
    diffuse lobes)."""
    from types import SimpleNamespace
    from . import bsdf
    from .integrator import _interaction
    from .nodes.context import ShadingContext
    from .render import prepare
    from .scene import RenderSettings

    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    mesh = scene.meshes[scene.instances[0].mesh]
    ok = (prim >= 0) & (prim < len(mesh.triangles))
    ctx = prepare(scene, RenderSettings(samples=1, max_bounces=0))
    tr = ctx.triangles
    # flatten drops degenerate triangles: the mesh triangle -> its row in tr.
    row_of = np.arange(len(mesh.triangles))
    if tr.kept is not None:
        row_of = np.where(tr.kept, np.cumsum(tr.kept) - 1, -1)
    rows = np.flatnonzero(ok)
    rows = rows[row_of[prim[rows]] >= 0]
    if len(rows) == 0:
        return out
    k = row_of[prim[rows]]
    bu, bv = v[rows], 1.0 - u[rows] - v[rows]     # Blender's (u, v) -> Embree's
    w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
    p = tr.p0[k] + bu[:, None] * tr.e1[k] + bv[:, None] * tr.e2[k]
    if tr.ns is not None:
        ns = np.einsum("nc,ncj->nj", w, tr.ns[k])
    else:
        ns = np.array(tr.ng[k], np.float64)
    ns = ns / np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-30)
    paths = SimpleNamespace(o=p + ns, d=-ns)
    h = _interaction(ctx, paths, np.ones(len(rows)), k, bu, bv)
    shading = ShadingContext.of_hit(tr, h)
    mats = ctx.materials
    if kind == "EMIT":
        value = mats.emission[h.mat]
        if mats.textures.emission:
            value = mats.textures.emission_at(h.mat, shading, value)
    elif kind == "ROUGHNESS":
        lobes = mats.gather(h.mat, shading)
        # Seen along the shading normal: the closures' weights at wo = N, as Cycles holds them.
        wo_l = np.tile([0.0, 0.0, 1.0], (len(rows), 1))
        value = np.repeat(average_roughness(lobes, bsdf.closure_weights(lobes, wo_l))[:, None], 3, axis=1)
    else:
        raise ValueError(f"{kind} is not a shaded bake type")
    value = np.where(np.isfinite(value), value, 0.0)
    out[rows, :3] = value
    out[rows, 3] = 1.0
    return out


def average_roughness(lobes, w=None):
    """Cycles' ROUGHNESS bake (surface_shader_average_roughness,
    bsdf_get_roughness_pass_squared): per point, the lobes' roughness
    averaged with weights |mean of the closure weight|: ``w`` (N, K, 3), the
    lobes' weights as Cycles' closures hold them (bsdf.closure_weights:
    colour x mix weight x the multiscatter Fresnel darkening and the
    layering; None: colour x mix weight).  A microfacet lobe's
    roughness is sqrt(alpha) (sqrt(sqrt(alpha_x alpha_y)) when anisotropic),
    an Oren-Nayar lobe's its sigma, a transparent lobe's 0 (singular), a hair
    lobe's 1; the diffuse class (Lambert, sheen, translucent) and subsurface
    do not enter the average, and a point without such lobes bakes 1
    (measured on bpy 5.0.1)."""
    from .lobe_ids import GLASS, GLOSSY, GLOSSY_ANISOTROPIC, MIRROR, OREN_NAYAR, REFRACTION, TRANSPARENT
    from .lobes import kinds_of_class
    kind = np.asarray(lobes.kind)
    if w is None:
        weight = np.abs(np.asarray(lobes.color).mean(axis=2))
        if lobes.weight is not None:
            weight = weight * np.asarray(lobes.weight)
    else:
        weight = np.abs(np.asarray(w).mean(axis=2))
    microfacet = np.isin(kind, (GLOSSY, GLOSSY_ANISOTROPIC, MIRROR, GLASS, REFRACTION))
    rough = np.where(microfacet, np.sqrt(np.clip(np.asarray(lobes.alpha), 0.0, None)), 1.0)
    rough = np.where(kind == TRANSPARENT, 0.0, rough)
    if lobes.diffuse_roughness is not None:
        rough = np.where(kind == OREN_NAYAR, np.clip(lobes.diffuse_roughness, 0.0, 1.0), rough)
    left_out = np.isin(kind, kinds_of_class("diffuse")) & (kind != OREN_NAYAR)
    weight = weight * ~left_out * (kind >= 0)
    total = weight.sum(axis=1)
    return np.where(total > 0, (weight * rough).sum(axis=1) / np.maximum(total, 1e-30), 1.0)


def bake_ao(scene, instance, prim, u, v, samples, distance, seed=0):
    """(N, 4) RGBA of an AO bake: per texel the fraction of ``samples``
    cosine-weighted rays about the shading normal that meet nothing within
    ``distance`` (Cycles' AO pass at a bake point, world AO distance; a
    direction below the geometric normal counts as occluded).  ``scene``
    holds every object (they occlude), ``instance`` is the baked one's
    index in scene.instances; prim indexes its mesh's triangles."""
    from .nodes.rays import make_orthonormals
    from .render import prepare
    from .sampling import cosine_hemisphere
    from .scene import RenderSettings

    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    mesh = scene.meshes[scene.instances[instance].mesh]
    ctx = prepare(scene, RenderSettings(samples=1, max_bounces=0))
    tr = ctx.triangles
    first = sum(len(scene.meshes[i.mesh].triangles) for i in scene.instances[:instance])
    total = sum(len(scene.meshes[i.mesh].triangles) for i in scene.instances)
    row_of = np.arange(total)
    if tr.kept is not None:
        row_of = np.where(tr.kept, np.cumsum(tr.kept) - 1, -1)
    ok = (prim >= 0) & (prim < len(mesh.triangles))
    rows = np.flatnonzero(ok)
    rows = rows[row_of[first + prim[rows]] >= 0]
    if len(rows) == 0:
        return out
    k = row_of[first + prim[rows]]
    bu, bv = v[rows], 1.0 - u[rows] - v[rows]
    w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
    p = tr.p0[k] + bu[:, None] * tr.e1[k] + bv[:, None] * tr.e2[k]
    ng = np.asarray(tr.ng[k], np.float64)
    ng = ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-30)
    ns = np.einsum("nc,ncj->nj", w, tr.ns[k]) if tr.ns is not None else ng.copy()
    ns = ns / np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-30)
    ng = np.where((np.einsum("ij,ij->i", ng, ns) < 0)[:, None], -ng, ng)   # the side the normal faces
    a, b = make_orthonormals(ns)
    rng = np.random.default_rng(seed)
    unoccluded = np.zeros(len(rows))
    eps = ctx.accel.offset_scale(p)
    for _ in range(int(samples)):
        local, _pdf = cosine_hemisphere(rng.random(len(rows)), rng.random(len(rows)))
        d = local[:, :1] * a + local[:, 1:2] * b + local[:, 2:3] * ns
        up = np.einsum("ij,ij->i", d, ng) > 0
        o = p + ng * eps[:, None]
        blocked = ctx.accel.occluded(o, d, np.full(len(rows), float(distance)))
        unoccluded += up & ~blocked
    out[rows, :3] = (unoccluded / max(int(samples), 1))[:, None]
    out[rows, 3] = 1.0
    return out


# Blender's pass filter (BakeSettings.pass_filter): the light components a
# DIFFUSE / GLOSSY / TRANSMISSION bake keeps (Direct, Indirect, Color) and a
# COMBINED bake's contributions (Emit, Diffuse, Glossy, Transmission).
FILTER_NAMES = ("EMIT", "DIRECT", "INDIRECT", "COLOR", "DIFFUSE", "GLOSSY", "TRANSMISSION")


class LightBake:
    """A light bake's texels: ``rgba`` (N, 4), ``variance`` (N, 3) the
    variance of each texel's value (None where the value is a colour pass),
    and the render behind it (``result``: samples, stats, warnings)."""

    def __init__(self, rgba, variance, result):
        self.rgba, self.variance, self.result = rgba, variance, result


def light_filter(kind, pass_filter):
    """(BakeFilter, indirect, value) of a light bake as Cycles sets it up
    (blender/session.cpp bake_setup_pass): ``value`` is 'combined' (the
    light through the kept lobes, colour included), 'light' (that / the
    class's colour) or 'color' (the class's Color pass)."""
    from .integrator.bake_paths import BakeFilter
    names = {str(n).upper() for n in pass_filter}
    unknown = names - set(FILTER_NAMES)
    if unknown:
        raise ValueError(f"unknown bake pass filter {sorted(unknown)} (known: {', '.join(FILTER_NAMES)})")
    direct, indirect = "DIRECT" in names, "INDIRECT" in names
    if kind == "COMBINED":
        classes = tuple(c for c in ("diffuse", "glossy", "transmission") if c.upper() in names)
        emit = "EMIT" in names
        return BakeFilter(classes, emit, direct, True, texel_emission=emit), indirect, "combined"
    if kind not in ("DIFFUSE", "GLOSSY", "TRANSMISSION"):
        raise ValueError(f"{kind} is not a light bake type")
    cls = kind.lower()
    value = "color" if not (direct or indirect) else ("combined" if "COLOR" in names else "light")
    side = {"glossy": 1, "transmission": -1}.get(cls, 0)
    return BakeFilter((cls,), True, direct, cls == "diffuse", texel_emission=False, glass_side=side), indirect, value


def bake_light(scene, instance, prim, u, v, kind, pass_filter, settings, diff=None, progress=None):
    """A light bake (``LIGHT``) of the texels (prim, u, v) of
    ``scene.instances[instance]``: every path starts at a texel's point,
    seen along its shading normal (Cycles' init_from_bake), and is traced
    by the render integrator with ``settings`` (samples, bounces, seed;
    engine.scene.RenderSettings) under the pass filter's closure filter.
    ``diff``: Blender's (N, 4) BakeDifferential, to spread the samples over
    each texel; ``progress`` as engine.render.render's (on_pass,
    should_stop).  Returns a LightBake; texels without a primitive (or on a
    degenerate triangle) are 0 with alpha 0."""
    import dataclasses
    from .render import render
    from .validate import validate_settings

    validate_settings(settings)
    bake_filter, indirect, value = light_filter(kind, pass_filter)
    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    ok, target = _texel_target(scene, instance, prim, u, v, diff, bake_filter)
    if target is None:
        return LightBake(out, np.zeros((n, 3)), None)
    colour = kind.capitalize() + " Color"
    passes = (colour,) if value != "combined" else ()
    settings = dataclasses.replace(settings, passes=tuple(passes), aovs=(), transparent=False,
                                   max_bounces=settings.max_bounces if indirect else 0)
    result = render(scene, settings, progress, bake=target)
    combined = result.image[0, :, :3].astype(np.float64)
    var = result.variance[0].astype(np.float64)
    if value == "color":
        texel, texel_var = result.passes[colour][0, :, :3].astype(np.float64), None
    elif value == "light":
        c = result.passes[colour][0, :, :3].astype(np.float64)
        safe = np.where(c > 0, c, 1.0)
        texel = np.where(c > 0, combined / safe, 0.0)
        texel_var = np.where(c > 0, var / safe ** 2, 0.0)
    else:
        texel, texel_var = combined, var
    good = target.valid
    rows = ok[good]
    out[rows, :3] = np.where(np.isfinite(texel[good]), texel[good], 0.0)
    out[rows, 3] = 1.0
    variance = None
    if texel_var is not None:
        variance = np.zeros((n, 3))
        variance[rows] = texel_var[good]
    return LightBake(out, variance, result)


def _texel_target(scene, instance, prim, u, v, diff, bake_filter=None):
    """(rows of the texels with a primitive, their BakeTarget) of
    ``scene.instances[instance]``; (rows, None) when no texel has one."""
    from .integrator.bake_paths import BakeFilter, BakeTarget
    mesh = scene.meshes[scene.instances[instance].mesh]
    ok = np.flatnonzero((prim >= 0) & (prim < len(mesh.triangles)))
    if len(ok) == 0:
        return ok, None
    first = sum(len(scene.meshes[i.mesh].triangles) for i in scene.instances[:instance])
    # Cycles 3.5 changed how samples are jittered across a texel.
    rejection = tuple(getattr(scene, "cycles_version", (5, 0, 0)))[:2] >= (3, 5)
    return ok, BakeTarget(first + prim[ok], u[ok], v[ok], None if diff is None else np.asarray(diff)[ok],
                          bake_filter or BakeFilter(), rejection=rejection)


def bake_shadow(scene, instance, prim, u, v, settings, diff=None, progress=None):
    """Cycles' SHADOW bake (blender/session.cpp bake_setup_pass): the baked
    object is made a shadow catcher for the bake and the value is the
    render's Shadow Catcher pass at its texels (every light class, direct
    and indirect, a transparent film), 1 where nothing shadows.  Returns a
    LightBake without variance (the pass is a ratio of estimates)."""
    import dataclasses
    from .render import render
    from .validate import validate_settings

    validate_settings(settings)
    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    instances = list(scene.instances)
    instances[instance] = dataclasses.replace(instances[instance], shadow_catcher=True, holdout=False)
    scene = dataclasses.replace(scene, instances=instances)
    ok, target = _texel_target(scene, instance, prim, u, v, diff)
    if target is None:
        return LightBake(out, None, None)
    settings = dataclasses.replace(settings, passes=("Shadow Catcher",), aovs=(), transparent=True)
    result = render(scene, settings, progress, bake=target)
    shadow = result.passes["Shadow Catcher"][0, :, :3].astype(np.float64)
    rows = ok[target.valid]
    out[rows, :3] = np.where(np.isfinite(shadow[target.valid]), shadow[target.valid], 0.0)
    out[rows, 3] = 1.0
    return LightBake(out, None, result)


def bake_background(scene, instance, prim, u, v, settings, diff=None):
    """Cycles' ENVIRONMENT bake (init_from_bake.h): per sample, the world
    the camera would see along normalize(P), P the texel's world-space
    point (jittered across the texel after sample 0 as the light bakes);
    nothing is traced.  Returns a LightBake with the variance of each
    texel's mean."""
    from .render import prepare
    from .validate import validate_settings

    validate_settings(settings)
    n = len(prim)
    out = np.zeros((n, 4), np.float32)
    variance = np.zeros((n, 3))
    ok, target = _texel_target(scene, instance, prim, u, v, diff)
    if target is None:
        return LightBake(out, variance, None)
    ctx = prepare(scene, settings, bake=target)
    rows = np.flatnonzero(target.valid)
    rng = np.random.default_rng([int(settings.seed), 0xE7])
    total = np.zeros((len(rows), 3))
    squares = np.zeros((len(rows), 3))
    samples = int(settings.samples)
    for sample in range(samples):
        o, d, _tmax, _first = target.generate(rows, rng.random(len(rows)), rng.random(len(rows)),
                                              np.full(len(rows), sample))
        p = o + d
        length = np.linalg.norm(p, axis=1, keepdims=True)
        # A texel at the origin has no direction: Cycles' normalize gives 0, the world's +z here.
        direction = np.where(length > 1e-30, p / np.maximum(length, 1e-30), np.array([0.0, 0.0, 1.0]))
        value = np.asarray(world_along(ctx, scene.world, direction), np.float64)
        value = np.where(np.isfinite(value), value, 0.0)
        total += value
        squares += value * value
    mean = total / samples
    out[ok[rows], :3] = mean
    out[ok[rows], 3] = 1.0
    if samples > 1:
        variance[ok[rows]] = np.maximum(squares - total * mean, 0.0) / (samples * (samples - 1))
    return LightBake(out, variance, None)


def world_along(ctx, world, d):
    """(N, 3) the world the camera sees along directions d: a procedural
    world's expression shaded per direction as Cycles' background (renders
    read its baked map), else what the render's camera rays see."""
    from .environment import compile_world
    from .integrator.catcher import background
    texture = world.texture
    if texture is not None and texture.shader is None and texture.expression is not None:
        return compile_world(texture.expression)(d) * float(texture.strength)
    return background(ctx, d)
