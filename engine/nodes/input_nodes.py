"""Input nodes: coordinates, geometry, object info, attributes, light path,
Fresnel / Layer Weight, and Mapping (kernel/svm/tex_coord.h, geometry.h,
fresnel.h, attribute.h, light_path.h, mapping_util.h)."""
import numpy as np

from .context import (CURVE_INTERCEPT, CURVE_LENGTH, CURVE_RANDOM, CURVE_THICKNESS, IS_RIBBON, IS_STRAND, PATH_COLUMNS,
                      POINTINESS, RANDOM_PER_ISLAND)
from .registry import node, one_of, wanted

VIS_CAMERA, VIS_DIFFUSE, VIS_GLOSSY, VIS_TRANSMISSION, VIS_SHADOW = 1, 2, 4, 8, 16
VIS_VOLUME = 32   # engine.geometry.VIS_VOLUME: the ray left a volume scatter event


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _normalize(v):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), 0.0)


def _object_matrix_inverse(n):
    """TexCoord 'object' property: the inverse matrix of another object."""
    obj = getattr(n, "object", None)
    if obj is None:
        return {"object_inverse": None}
    return {"object_inverse": np.linalg.inv(np.array(obj.matrix_world)).tolist()}


def _camera_coords(ctx):
    """World to camera space as Cycles' worldtocamera: the camera's matrix
    without scale, its z axis flipped (Cycles' camera looks down +z)."""
    camera = ctx.camera
    if camera is None:
        return ctx.p
    m = np.asarray(camera.matrix, dtype=np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    local = (ctx.p - m[:3, 3]) @ rot
    local[:, 2] = -local[:, 2]
    return local


def _window_coords(ctx):
    """Cycles' NODE_TEXCO_WINDOW: the point projected into the camera's
    full frame, (0, 0) at its bottom-left corner and (1, 1) at the top
    right (camera_world_to_ndc), z = 0."""
    camera = ctx.camera
    out = np.zeros((len(ctx), 3))
    if camera is None:
        return out
    from ..camera import view_plane
    m = np.asarray(camera.matrix, dtype=np.float64)
    rot = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0, keepdims=True)
    local = (ctx.p - m[:3, 3]) @ rot
    if camera.kind == "PANO":   # the direction's panorama (u, v), unshifted
        from ..panorama import Panorama
        pano = Panorama(camera)
        out[:, 0], out[:, 1] = pano.from_direction(pano.from_local(local))
        return np.where(np.isfinite(out), out, 0.0)
    if camera.kind == "ORTHO":
        sx, sy = local[:, 0], local[:, 1]
    else:
        depth = -local[:, 2]
        depth = np.where(depth != 0, depth, 1e-30)
        sx, sy = local[:, 0] / depth, local[:, 1] / depth
    xmin, ymin, pw, ph = view_plane(camera)
    out[:, 0] = (sx - xmin) / (pw * float(camera.resolution[0]))
    out[:, 1] = (sy - ymin) / (ph * float(camera.resolution[1]))
    return out


@node("ShaderNodeTexCoord", outputs=(("Generated", "vector"), ("Normal", "vector"), ("UV", "vector"),
                                     ("Object", "vector"), ("Camera", "vector"), ("Reflection", "vector"),
                                     ("Window", "vector")),
      translate=_object_matrix_inverse, cases=[{}])
def tex_coord(ctx, i, p):
    # Only the outputs something reads: Camera and Window project every
    # point, Normal transforms it (a third of a procedural material's cost).
    makers = {"Generated": lambda: ctx.generated, "Normal": lambda: ctx.to_object(ctx.ns),
              "UV": lambda: _uv3(ctx), "Object": lambda: _object_coords(ctx, p),
              "Camera": lambda: _camera_coords(ctx),
              "Reflection": lambda: 2.0 * _dot(ctx.ns, ctx.wo)[:, None] * ctx.ns - ctx.wo,
              "Window": lambda: _window_coords(ctx)}
    return {name: make() for name, make in makers.items() if wanted(p, name)}


def _uv3(ctx):
    uv = np.zeros((len(ctx), 3))
    uv[:, :2] = ctx.uv
    return uv


def _object_coords(ctx, p):
    inv = p.get("object_inverse")
    if inv is None:
        return ctx.object_coords
    inv = np.asarray(inv)
    return ctx.p @ inv[:3, :3].T + inv[:3, 3]


@node("ShaderNodeUVMap", outputs=(("UV", "vector"),), props=(("uv_map", ""),), cases=[{}])
def uv_map(ctx, i, p):
    uv = np.zeros((len(ctx), 3))
    uv[:, :2] = ctx.uv_map(p["uv_map"])
    return {"UV": uv}


@node("ShaderNodeNewGeometry", outputs=(("Position", "vector"), ("Normal", "vector"), ("True Normal", "vector"),
                                        ("Incoming", "vector"), ("Parametric", "vector"), ("Backfacing", "float"),
                                        ("Pointiness", "float"), ("Random Per Island", "float"),
                                        ("Tangent", "vector")),
      cases=[{}],
      bounds=lambda p: {"Pointiness": (0.0, 1.0), "Random Per Island": (0.0, 1.0)})
def geometry(ctx, i, p):
    """Cycles' geometry.h; Pointiness and Random Per Island are the mesh
    attributes engine.mesh_attributes computes at export (0 on geometry
    without them, as Cycles' missing attribute); Tangent is primitive_tangent.
    On ribbons the True Normal is the view direction (Cycles' sd->Ng = sd->wi)."""
    ribbon = _derived(ctx, IS_RIBBON)[:, None] > 0.5
    out = {"Position": ctx.p, "Normal": ctx.ns, "True Normal": np.where(ribbon, ctx.wo, ctx.ng), "Incoming": ctx.wo,
           "Parametric": _parametric(ctx), "Backfacing": ctx.back.astype(np.float64),
           "Pointiness": _derived(ctx, POINTINESS), "Random Per Island": _derived(ctx, RANDOM_PER_ISLAND)}
    if wanted(p, "Tangent"):
        out["Tangent"] = primitive_tangent(ctx)
    return out


def _on_fibre(ctx):
    """(N,) bool: the points on a strand (a non-zero dC/du)."""
    if ctx.fibre is None:
        return np.zeros(len(ctx), bool)
    return np.any(ctx.fibre != 0.0, axis=1)


def primitive_tangent(ctx):
    """Cycles' primitive_tangent: on curves normalize(dPdu); on triangles
    the radial tangent about Z of the Generated coordinates, in world space
    as a normal, made perpendicular to the shading normal."""
    out = _radial_tangent(ctx, "Z")
    fibre = _on_fibre(ctx)
    if fibre.any():
        out[fibre] = _normalize(ctx.fibre[fibre])
    return out


@node("ShaderNodeHairInfo", outputs=(("Is Strand", "float"), ("Intercept", "float"), ("Length", "float"),
                                     ("Thickness", "float"), ("Tangent Normal", "vector"), ("Random", "float")),
      bounds=lambda p: {"Is Strand": (0.0, 1.0), "Intercept": (0.0, 1.0), "Random": (0.0, 1.0)}, cases=[{}])
def curves_info(ctx, i, p):
    """Cycles' svm_node_hair_info (the Curves Info node; Hair Info before
    Blender 3.5): Intercept, Length and Random are the curve attributes
    Cycles' export writes (engine.curve_attributes), Thickness
    curve_thickness (twice the radius mixed between the segment's keys),
    Tangent Normal curve_tangent_normal (the view direction made
    perpendicular to dPdu); all 0 off strands."""
    out = {"Is Strand": _derived(ctx, IS_STRAND), "Intercept": _derived(ctx, CURVE_INTERCEPT),
           "Length": _derived(ctx, CURVE_LENGTH), "Thickness": _derived(ctx, CURVE_THICKNESS),
           "Random": _derived(ctx, CURVE_RANDOM)}
    if wanted(p, "Tangent Normal"):
        out["Tangent Normal"] = _tangent_normal(ctx)
    return out


def _tangent_normal(ctx):
    out = np.zeros((len(ctx), 3))
    on = _on_fibre(ctx)
    if on.any():
        d, wi = ctx.fibre[on], ctx.wo[on]
        tg = wi - d * (_dot(d, wi) / _dot(d, d))[:, None]
        out[on] = _normalize(tg)
    return out


def _derived(ctx, name):
    value = ctx.attribute(name)
    return np.zeros(len(ctx)) if value is None else value[:, 0]


def _parametric(ctx):
    """Cycles' (1 - u - v, u, 0) in its barycentrics: measured against
    Cycles, 1 - u - v weighs Ember's first corner and u its second."""
    out = np.zeros((len(ctx), 3))
    if ctx.bary is not None:
        bu, bv = ctx.bary[:, 0], ctx.bary[:, 1]
        out[:, 0] = 1.0 - bu - bv
        out[:, 1] = bu
    return out


@node("ShaderNodeObjectInfo", outputs=(("Location", "vector"), ("Color", "color"), ("Alpha", "float"),
                                       ("Object Index", "float"), ("Random", "float")),
      unsupported_outputs=("Material Index",), bounds=lambda p: {"Random": (0.0, 1.0)}, cases=[{}])
def object_info(ctx, i, p):
    """Cycles' object_location / color / alpha / pass_id / random_number of
    the shading point's object.  On lights the exporter gives the light
    object's values as the private prop ``_object`` (constant per light)."""
    light = p.get("_object")
    if light is not None:
        return {name: _constant(ctx, light[name]) for name in ("Location", "Color", "Alpha", "Object Index",
                                                                "Random")}
    return {"Location": ctx.object_info("location"), "Color": ctx.object_info("color"),
            "Alpha": np.ones(len(ctx)), "Object Index": ctx.object_info("pass_index"),
            "Random": ctx.object_info("random")}


def _constant(ctx, value):
    value = np.asarray(value, np.float64)
    return np.broadcast_to(value, (len(ctx),) + value.shape).copy()


INSTANCE_ATTRIBUTE_TYPES = ("GEOMETRY", "OBJECT", "INSTANCER", "VIEW_LAYER")


def instance_attribute_key(kind, name):
    """The key of Instance.object_attributes for an Attribute node's type and name."""
    return f"{kind}:{name}"


def _attribute_rgba(ctx, name, missing=0.0):
    rgba = ctx.attribute(name)
    if rgba is None:
        rgba = np.full((len(ctx), 4), float(missing))
    return rgba


@node("ShaderNodeAttribute", outputs=(("Color", "color"), ("Vector", "vector"), ("Fac", "float"),
                                      ("Alpha", "float")),
      props=(("attribute_name", ""), ("attribute_type", "GEOMETRY")), cases=[{"attribute_name": "Col"}],
      accepts=one_of(attribute_type=INSTANCE_ATTRIBUTE_TYPES))
def attribute(ctx, i, p):
    """Cycles' svm_node_attr: a geometry attribute interpolated over the
    surface, or an Object / Instancer / View Layer one, constant per
    instance (the exporter resolves it as Blender's
    BKE_object_dupli_find_rgba_attribute / BKE_view_layer_find_rgba_attribute).
    The exporter's private prop ``_missing`` is the value of an absent
    attribute (0 as Cycles' node; Principled Volume's attribute inputs: 1)."""
    kind = p.get("attribute_type", "GEOMETRY")
    if kind == "GEOMETRY":
        rgba = _attribute_rgba(ctx, p["attribute_name"], p.get("_missing", 0.0))
    else:
        rgba = ctx.instance_attribute(instance_attribute_key(kind, p["attribute_name"]))
    return {"Color": rgba[:, :3], "Vector": rgba[:, :3], "Fac": rgba[:, :3].mean(axis=1), "Alpha": rgba[:, 3]}


@node("ShaderNodeVertexColor", outputs=(("Color", "color"), ("Alpha", "float")), props=(("layer_name", ""),),
      cases=[{}])
def color_attribute(ctx, i, p):
    rgba = _attribute_rgba(ctx, p["layer_name"])
    return {"Color": rgba[:, :3], "Alpha": rgba[:, 3]}


@node("ShaderNodeLightPath",
      outputs=(("Is Camera Ray", "float"), ("Is Shadow Ray", "float"), ("Is Diffuse Ray", "float"),
               ("Is Glossy Ray", "float"), ("Is Reflection Ray", "float"), ("Is Transmission Ray", "float"),
               ("Is Volume Scatter Ray", "float"), ("Ray Depth", "float"))
      + tuple((name, "float") for name in PATH_COLUMNS),
      cases=[{}])
def light_path(ctx, i, p):
    """Cycles' light_path.h.  The path columns come from the integrator
    (ShadingContext.path); where it evaluates no path (a light sample's
    emission, a world, a bake) they read 0, as Cycles' PATH_RAY_EMISSION
    evaluation reads no ray kind.  A ray a volume scattered (VIS_VOLUME)
    is no diffuse, glossy, reflection or transmission ray: Cycles'
    path_state_next clears those flags and sets PATH_RAY_VOLUME_SCATTER."""
    ray = ctx.ray.astype(np.int64)
    flag = lambda bits: ((ray & bits) != 0).astype(np.float64)
    surface = 1.0 - flag(VIS_VOLUME)
    out = {"Is Camera Ray": flag(VIS_CAMERA), "Is Shadow Ray": flag(VIS_SHADOW),
           "Is Diffuse Ray": flag(VIS_DIFFUSE) * surface, "Is Glossy Ray": flag(VIS_GLOSSY) * surface,
           "Is Reflection Ray": flag(VIS_DIFFUSE | VIS_GLOSSY) * surface,
           "Is Transmission Ray": flag(VIS_TRANSMISSION) * surface, "Is Volume Scatter Ray": flag(VIS_VOLUME),
           "Ray Depth": ctx.depth.astype(np.float64)}
    path = ctx.path if ctx.path is not None else np.zeros((ctx.n, len(PATH_COLUMNS)))
    for column, name in enumerate(PATH_COLUMNS):
        out[name] = path[:, column].astype(np.float64)
    return out


# ----------------------------------------------------------------------------
# Fresnel and Layer Weight

def fresnel_dielectric_cos(cosi, eta):
    c = np.abs(cosi)
    g = eta * eta - 1.0 + c * c
    ok = g > 0
    g = np.sqrt(np.where(ok, g, 1.0))
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return np.where(ok, 0.5 * a * a * (1.0 + b * b), 1.0)


def _normal_in(ctx, i):
    """An unlinked Normal input is the shading normal (the exporter leaves
    it out); a linked one is used as given."""
    n = i.get("Normal")
    return ctx.ns if n is None else n


@node("ShaderNodeFresnel", inputs=(("IOR", "float"), ("Normal", "vector")), outputs=(("Fac", "float"),),
      bounds=lambda p: {"Fac": (0.0, 1.0)}, cases=[{"IOR": 1.45}, {"IOR": 2.5}])
def fresnel(ctx, i, p):
    eta = np.maximum(i["IOR"], 1e-5)
    eta = np.where(ctx.back, 1.0 / eta, eta)
    return {"Fac": fresnel_dielectric_cos(_dot(ctx.wo, _normal_in(ctx, i)), eta)}


@node("ShaderNodeLayerWeight", inputs=(("Blend", "float"), ("Normal", "vector")),
      outputs=(("Fresnel", "float"), ("Facing", "float")),
      bounds=lambda p: {"Fresnel": (0.0, 1.0), "Facing": (0.0, 1.0)},
      cases=[{"Blend": 0.3}, {"Blend": 0.8}])
def layer_weight(ctx, i, p):
    blend = i["Blend"]
    cos = _dot(ctx.wo, _normal_in(ctx, i))
    eta = np.maximum(1.0 - blend, 1e-5)
    eta = np.where(ctx.back, eta, 1.0 / eta)
    fres = fresnel_dielectric_cos(cos, eta)
    b = np.clip(blend, 0.0, 1.0 - 1e-5)
    expo = np.where(b < 0.5, 2.0 * b, 0.5 / (1.0 - b))
    facing = np.abs(cos)
    facing = np.where(blend != 0.5, np.power(facing, expo), facing)
    return {"Fresnel": fres, "Facing": 1.0 - facing}


# ----------------------------------------------------------------------------
# Mapping

def euler_matrix(rot):
    """(N, 3, 3) rotation Rz Ry Rx from Euler XYZ angles (N, 3)."""
    cx, cy, cz = np.cos(rot[:, 0]), np.cos(rot[:, 1]), np.cos(rot[:, 2])
    sx, sy, sz = np.sin(rot[:, 0]), np.sin(rot[:, 1]), np.sin(rot[:, 2])
    return np.stack([
        np.stack([cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz], axis=1),
        np.stack([cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz], axis=1),
        np.stack([-sy, cy * sx, cy * cx], axis=1)], axis=1)


def _safe_div(a, b):
    return np.where(b != 0, a / np.where(b != 0, b, 1.0), 0.0)


def mapping_values(kind, v, loc, rot, scale):
    r = euler_matrix(rot)
    if kind == "POINT":
        return np.einsum("nij,nj->ni", r, v * scale) + loc
    if kind == "TEXTURE":
        return _safe_div(np.einsum("nji,nj->ni", r, v - loc), scale)
    if kind == "VECTOR":
        return np.einsum("nij,nj->ni", r, v * scale)
    return _normalize(np.einsum("nij,nj->ni", r, _safe_div(v, scale)))


@node("ShaderNodeMapping",
      inputs=(("Vector", "vector"), ("Location", "vector"), ("Rotation", "vector"), ("Scale", "vector")),
      outputs=(("Vector", "vector"),), props=(("vector_type", "POINT"),),
      cases=[{"vector_type": t, "Location": (0.2, -0.1, 0.3), "Rotation": (0.3, 0.5, 0.9), "Scale": (2.0, 1.5, 0.5)}
             for t in ("POINT", "TEXTURE", "VECTOR", "NORMAL")])
def mapping(ctx, i, p):
    return {"Vector": mapping_values(p["vector_type"], i["Vector"], i["Location"], i["Rotation"], i["Scale"])}


def _cross(a, b):
    return np.cross(a, b)


@node("ShaderNodeTangent", outputs=(("Tangent", "vector"),), props=(("direction_type", "RADIAL"), ("axis", "Z"),
                                                                     ("uv_map", "")),
      # Radial about Z and the UV map: the parity scene's quads face +Z, where
      # the X and Y radial tangents are along the normal (Generated z = 0.5)
      # and Cycles' result is the sign of a float32 rounding of that 0.5.
      cases=[{}, {"direction_type": "UV_MAP"}])
def tangent(ctx, i, p):
    """Cycles' svm_node_tangent: radial, a tangent about the object's axis
    from Generated coordinates (object-space P without them), or the UV
    map's MikkTSpace tangent (the active map's: the one the exporter
    computes; zero without one, as Cycles without the attribute); carried to
    world space as a normal (object_normal_transform) and made perpendicular
    to the shading normal."""
    if p.get("direction_type", "RADIAL") == "UV_MAP":
        t = ctx.uv_tangent
        if t is None:
            return {"Tangent": np.zeros((len(ctx), 3))}
        t = ctx.to_world_normal(t)
        n = ctx.ns
        return {"Tangent": _cross(n, _normalize(_cross(t, n)))}
    return {"Tangent": _radial_tangent(ctx, p.get("axis", "Z"))}


def _radial_tangent(ctx, axis):
    """A tangent about the object's axis from Generated coordinates, in
    world space as a normal, perpendicular to the shading normal."""
    zero = np.zeros(len(ctx))
    g = ctx.generated - 0.5
    if axis == "X":
        t = np.stack([zero, -g[:, 2], g[:, 1]], axis=1)
    elif axis == "Y":
        t = np.stack([-g[:, 2], zero, g[:, 0]], axis=1)
    else:
        t = np.stack([-g[:, 1], g[:, 0], zero], axis=1)
    t = ctx.to_world_normal(t)
    n = ctx.ns
    return _cross(n, _normalize(_cross(t, n)))
