"""Shader nodes that cast rays: Ambient Occlusion and Bevel (Cycles'
kernel/svm/ao.h and bevel.h, set up by scene/shader_nodes.cpp).

Both read ``ctx.rays`` (engine.nodes.rays.NodeRays); without it they return
what Cycles returns where it does not ray-trace in shaders: AO 1 (Color
unchanged) and the shading normal.
"""
import sys

import numpy as np

from .rays import AO, BEVEL, concentric_disk, make_orthonormals
from .registry import node

# Cycles' default world AO distance without a world (blender/sync.cpp).
DEFAULT_WORLD_AO_DISTANCE = 10.0


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _normalize(v):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), 0.0)


# ----------------------------------------------------------------------------
# Ambient Occlusion

def _global_distance(bpy_node):
    """Cycles' NODE_AO_GLOBAL_RADIUS: an unlinked Distance of 0 reads the
    world's AO distance (World > Light Settings > Distance; 10 without a
    world).  The exporting scene is Blender's current one."""
    socket = bpy_node.inputs.get("Distance")
    if socket is None or socket.is_linked or float(socket.default_value) != 0.0:
        return {"global_distance": None}
    bpy = sys.modules.get("bpy")
    world = getattr(getattr(getattr(bpy, "context", None), "scene", None), "world", None)
    distance = DEFAULT_WORLD_AO_DISTANCE if world is None else float(world.light_settings.distance)
    return {"global_distance": distance}


@node("ShaderNodeAmbientOcclusion",
      inputs=(("Color", "color"), ("Distance", "float"), ("Normal", "vector")),
      outputs=(("Color", "color"), ("AO", "float")),
      props=(("samples", 16), ("inside", False), ("only_local", False)),
      translate=_global_distance, bounds=lambda p: {"AO": (0.0, 1.0)},
      input_defaults={"Color": (1.0, 1.0, 1.0), "Distance": 1.0},
      # A flat quad never occludes itself: with Only Local both renders are
      # exact, so the per-pixel parity scene can hold them.  The stochastic
      # cases are compared in tests/addon/test_ray_node_parity.py.
      cases=[{"only_local": True, "Distance": 0.5}, {"only_local": True, "inside": True, "samples": 4}])
def ambient_occlusion(ctx, i, p):
    ao = _in_chunks(ctx, int(p.get("samples", 16)), lambda sub, rows: occlusion(
        sub, {k: v[rows] for k, v in i.items()}, p))
    return {"Color": i["Color"] * ao[:, None], "AO": ao}


# Rays cast at once by one node: memory stays bounded (a 128-sample AO on
# 2^16 paths would otherwise hold 8 M rays).
MAX_RAYS = 1 << 18


def _in_chunks(ctx, samples, fn):
    """fn(sub-context, rows) over runs of points casting at most MAX_RAYS rays."""
    n = len(ctx)
    step = max(MAX_RAYS // max(samples, 1), 1)
    if n <= step:
        return fn(ctx, slice(None))
    parts = []
    for lo in range(0, n, step):
        rows = np.arange(lo, min(lo + step, n))
        parts.append(fn(ctx.take(rows), rows))
    return np.concatenate(parts)


def occlusion(ctx, i, p):
    """Cycles' svm_ao: the fraction of ``samples`` cosine-distributed rays
    about the normal (the Normal input as given, else the shading normal;
    flipped with Inside) that meet nothing within Distance (of the same
    object only with Only Local)."""
    n = len(ctx)
    rays = ctx.rays
    samples = int(p.get("samples", 16))
    distance = i["Distance"] if p.get("global_distance") is None else np.full(n, float(p["global_distance"]))
    can = rays is not None and samples >= 1 and ctx.prim is not None
    live = np.nonzero(distance > 0)[0] if can else np.zeros(0, np.int64)
    ao = np.ones(n)
    if len(live) == 0:
        return ao
    sub = ctx.take(live)
    normal = i.get("Normal")
    normal = sub.ns if normal is None else normal[live]
    bad = ~np.isfinite(normal).all(axis=1) | (np.abs(normal).max(axis=1) == 0)
    normal = np.where(bad[:, None], sub.ns, normal)
    if p.get("inside", False):
        normal = -normal
    t, b = make_orthonormals(normal)
    u = sub.rays.uniforms(AO, samples).reshape(-1, 2)
    dx, dy = concentric_disk(u[:, 0], u[:, 1])
    dz = np.sqrt(np.maximum(1.0 - dx * dx - dy * dy, 0.0))
    rep = lambda a: np.repeat(a, samples, axis=0)
    d = dx[:, None] * rep(t) + dy[:, None] * rep(b) + dz[:, None] * rep(normal)
    p_rep, ng_rep = rep(sub.p), rep(sub.ng)
    o = sub.rays.accel.offset_origin(p_rep, ng_rep, d)
    instance = None
    if p.get("only_local", False):
        instance = rep(sub.rays.instance_of(sub.prim))
    blocked = sub.rays.blocked(o, d, rep(distance[live]), instance)
    ao[live] = (~blocked).reshape(-1, samples).sum(axis=1) / samples
    return ao


# ----------------------------------------------------------------------------
# Bevel

@node("ShaderNodeBevel", inputs=(("Radius", "float"), ("Normal", "vector")), outputs=(("Normal", "vector"),),
      props=(("samples", 4),), bounds=lambda p: {"Normal": (-1.0, 1.0)},
      input_defaults={"Radius": 0.05},
      # On a flat quad every hit has the quad's normal: exact in both renders.
      cases=[{}, {"Radius": 0.0, "samples": 8}])
def bevel(ctx, i, p):
    if ctx.rays is None:
        return {"Normal": ctx.ns}   # Cycles without the raytrace feature
    samples = int(p.get("samples", 4))
    out = _in_chunks(ctx, samples, lambda sub, rows: bevel_normal(sub, i["Radius"][rows], samples))
    ref = i.get("Normal")
    if ref is not None:
        # Cycles: "preserve input normal".
        out = _normalize(ref + (out - ctx.ns))
    return {"Normal": out}


def bevel_normal(ctx, radius, samples):
    """Cycles' svm_bevel: normals of the same object's surface near each
    point, found by rays through disk points (cubic falloff of the radius)
    on planes across its geometric normal and two tangents, picked 1/2,
    1/4, 1/4 and weighed by the power heuristic over the three axes."""
    n = len(ctx)
    rays = ctx.rays
    out = ctx.ns.copy()
    live = np.nonzero((radius > 0) & np.isfinite(radius) & rays.sharp)[0] if samples >= 1 else np.zeros(0, np.int64)
    if len(live) == 0 or ctx.prim is None:
        return out
    sub = ctx.take(live)
    m = len(live)
    rep = lambda a: np.repeat(a, samples, axis=0)
    R = rep(radius[live])
    u = sub.rays.uniforms(BEVEL, samples).reshape(-1, 2)
    axes, pick, ux = _pick_axis(rep(sub.ng), u[:, 0])
    disk_n, disk_t, disk_b = axes
    phi = 2.0 * np.pi * ux
    disk_r = cubic_root(u[:, 1]) * R
    height = np.sqrt(np.maximum(R * R - disk_r * disk_r, 0.0))
    origin = (rep(sub.p) + disk_n * height[:, None]
              + disk_r[:, None] * (np.cos(phi)[:, None] * disk_t + np.sin(phi)[:, None] * disk_b))
    own = rep(sub.rays.instance_of(sub.prim))
    rows, prim, _, bu, bv = sub.rays.local_hits(origin, -disk_n, 2.0 * height, own)
    if len(rows):
        weight, normal = _hit_weights(sub.rays.triangles, sub.rays, rows, prim, bu, bv, axes, pick,
                                      rep(sub.p), R, disk_r)
        total = np.zeros((m * samples, 3))
        np.add.at(total, rows, weight[:, None] * normal)
        total = total.reshape(m, samples, 3).sum(axis=1)
        nrm = _normalize(total)
        found = np.abs(nrm).max(axis=1) > 0
        nrm = np.where(sub.back[:, None], -nrm, nrm)
        out[live] = np.where(found[:, None], nrm, sub.ns)
    return out


def _pick_axis(ng, u):
    """Cycles' axis choice: the geometric normal with probability 1/2, each
    tangent with 1/4; the random number is rescaled for the disk angle."""
    t, b = make_orthonormals(ng)
    first = u < 0.5
    second = ~first & (u < 0.75)
    third = ~first & ~second
    c = lambda mask: mask[:, None]
    disk_n = np.where(c(first), ng, np.where(c(second), t, b))
    disk_t = np.where(c(second), ng, t)
    disk_b = np.where(c(third), ng, b)
    pick = np.where(c(first), [0.5, 0.25, 0.25], np.where(c(second), [0.25, 0.5, 0.25], [0.25, 0.25, 0.5]))
    ux = np.where(first, u * 2.0, np.where(second, (u - 0.5) * 4.0, (u - 0.75) * 4.0))
    return (disk_n, disk_t, disk_b), pick, ux


def _hit_weights(tris, rays, rows, prim, bu, bv, axes, pick, p, radius, disk_r):
    """Weight and (smooth) normal of each hit (Cycles' loop over local hits)."""
    disk_n, disk_t, disk_b = (a[rows] for a in axes)
    hit_ng = rays.outward_normal(prim)
    normal = hit_ng
    if tris.ns is not None:
        c = tris.ns[prim]
        smooth = (1 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
        smooth = _normalize(smooth)
        use = tris.smooth[prim] & (np.abs(smooth).max(axis=1) > 0)
        normal = np.where(use[:, None], smooth, hit_ng)
    pk = pick[rows]
    pdf_n = pk[:, 0] * np.abs(_dot(disk_n, hit_ng))
    pdf_t = pk[:, 1] * np.abs(_dot(disk_t, hit_ng))
    pdf_b = pk[:, 2] * np.abs(_dot(disk_b, hit_ng))
    denom = pdf_n * pdf_n + pdf_t * pdf_t + pdf_b * pdf_b
    w = np.where(denom > 0, pdf_n / np.where(denom > 0, denom, 1.0), 0.0)
    hit_p = tris.p0[prim] + bu[:, None] * tris.e1[prim] + bv[:, None] * tris.e2[prim]
    r = np.linalg.norm(hit_p - p[rows], axis=1)
    R = radius[rows]
    disk_pdf = cubic_pdf(R, disk_r[rows])
    w = np.where(disk_pdf > 0, w * cubic_pdf(R, r) / np.where(disk_pdf > 0, disk_pdf, 1.0), 0.0)
    return w, normal


def cubic_pdf(radius, r):
    """Cycles' planar cubic falloff 10 (R - r)^3 / (pi R^5), 0 beyond R."""
    f = np.maximum(radius - r, 0.0)
    r5 = np.where(radius > 0, radius ** 5, 1.0)
    return np.where(r < radius, 10.0 * f * f * f / (r5 * np.pi), 0.0)


def cubic_root(xi):
    """Cycles' Newton solve of 10x^2 - 20x^3 + 15x^4 - 4x^5 = xi (the
    falloff's CDF in r / R), from x = 0.25, at most 10 steps, clamped to
    [0, 1], each lane stopping where |f| < 1e-6 or f' = 0."""
    x = np.full(len(xi), 0.25)
    going = np.ones(len(xi), bool)
    for _ in range(10):
        x2 = x * x
        x3 = x2 * x
        nx = 1.0 - x
        f = 10.0 * x2 - 20.0 * x3 + 15.0 * x2 * x2 - 4.0 * x2 * x3 - xi
        df = 20.0 * (x * nx) * (nx * nx)
        going &= ~((np.abs(f) < 1e-6) | (df == 0.0))
        if not going.any():
            break
        step = np.where(going, f / np.where(df != 0, df, 1.0), 0.0)
        x = np.clip(x - step, 0.0, 1.0)
    return x
