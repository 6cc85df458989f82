"""Converter and colour nodes as Cycles' SVM evaluates them."""
import numpy as np

from .color_math import hsl_to_rgb, hsv_to_rgb, rgb_to_hsl, rgb_to_hsv
from .registry import node

LUMA = np.array([0.2126, 0.7152, 0.0722])
RAMP_SIZE = 257   # Cycles bakes colour ramps at i / 256


def _safe_div(a, b):
    return np.where(b != 0, a / np.where(b != 0, b, 1.0), 0.0)


def ramp_lookup(table, f, interpolate, extrapolate=False):
    """Cycles' rgb_ramp_lookup on a (S, C) table for f (N,)."""
    size = len(table)
    f = np.nan_to_num(np.asarray(f, dtype=np.float64), nan=0.0)
    if extrapolate:
        lo = table[0] + (table[0] - table[1]) * (0.0 - f)[:, None] * (size - 1)
        hi = table[-1] + (table[-1] - table[-2]) * (f - 1.0)[:, None] * (size - 1)
    x = np.clip(f, 0.0, 1.0) * (size - 1)
    i = np.clip(x.astype(np.int64), 0, size - 1)
    t = x - i
    out = table[i]
    if interpolate:
        nxt = table[np.minimum(i + 1, size - 1)]
        out = np.where((t > 0)[:, None], (1.0 - t)[:, None] * out + t[:, None] * nxt, out)
    if extrapolate:
        out = np.where((f < 0)[:, None], lo, np.where((f > 1)[:, None], hi, out))
    return out


def bake_color_ramp(ramp):
    """(RAMP_SIZE, 4) RGBA table from a bpy ColorRamp (``evaluate``)."""
    table = np.array([tuple(ramp.evaluate(k / (RAMP_SIZE - 1))) for k in range(RAMP_SIZE)], dtype=np.float64)
    return {"table": table.tolist(), "constant": ramp.interpolation == "CONSTANT"}


@node("ShaderNodeValToRGB", inputs=(("Fac", "float"),), outputs=(("Color", "color"), ("Alpha", "float")),
      translate=lambda n: bake_color_ramp(n.color_ramp),
      bounds=lambda p: {"Color": (float(np.min(np.asarray(p["table"])[:, :3])),
                                  float(np.max(np.asarray(p["table"])[:, :3]))),
                        "Alpha": (float(np.min(np.asarray(p["table"])[:, 3])),
                                  float(np.max(np.asarray(p["table"])[:, 3])))},
      cases=[{"ramp": "EASE"}, {"ramp": "CONSTANT"}, {"ramp": "LINEAR"}, {"ramp": "B_SPLINE"}])
def color_ramp(ctx, i, p):
    rgba = ramp_lookup(np.asarray(p["table"], dtype=np.float64), i["Fac"], not p["constant"])
    return {"Color": rgba[:, :3], "Alpha": rgba[:, 3]}


def bake_curves(mapping, channels):
    """Per-channel tables over [min_x, max_x] of the curve points (Cycles'
    curvemapping_minmax): for RGB Curves the combined curve runs first."""
    mapping.initialize()
    curves = list(mapping.curves)
    xs = [pt.location[0] for c in curves for pt in c.points]
    lo, hi = min(xs), max(xs)
    grid = lo + (hi - lo) * np.arange(RAMP_SIZE) / (RAMP_SIZE - 1)
    table = np.zeros((RAMP_SIZE, 3))
    for k, x in enumerate(grid):
        if channels == 3:
            table[k] = [mapping.evaluate(curves[c], mapping.evaluate(curves[3], x)) for c in range(3)]
        else:
            table[k] = mapping.evaluate(curves[0], x)
    return {"table": table.tolist(), "min_x": lo, "max_x": hi}


@node("ShaderNodeRGBCurve", inputs=(("Fac", "float"), ("Color", "color")), outputs=(("Color", "color"),),
      translate=lambda n: bake_curves(n.mapping, 3), cases=[{"curve": "S"}])
def rgb_curves(ctx, i, p):
    table = np.asarray(p["table"])
    span = p["max_x"] - p["min_x"]
    c = (i["Color"] - p["min_x"]) / (span if span != 0 else 1.0)
    out = np.stack([ramp_lookup(table[:, k:k + 1], c[:, k], True, True)[:, 0] for k in range(3)], axis=1)
    fac = i["Fac"][:, None]
    return {"Color": (1.0 - fac) * i["Color"] + fac * out}


@node("ShaderNodeFloatCurve", inputs=(("Factor", "float"), ("Value", "float")), outputs=(("Value", "float"),),
      translate=lambda n: bake_curves(n.mapping, 1), cases=[{"curve": "S"}])
def float_curve(ctx, i, p):
    table = np.asarray(p["table"])[:, :1]
    span = p["max_x"] - p["min_x"]
    c = (i["Value"] - p["min_x"]) / (span if span != 0 else 1.0)
    out = ramp_lookup(table, c, True, True)[:, 0]
    fac = i["Factor"]
    return {"Value": (1.0 - fac) * i["Value"] + fac * out}


# ----------------------------------------------------------------------------
# Map Range, Clamp

def _smoothstep(e0, e1, x):
    t = _safe_div(x - e0, e1 - e0)
    return np.where(x < e0, 0.0, np.where(x >= e1, 1.0, (3.0 - 2.0 * t) * t * t))


def _smootherstep(e0, e1, x):
    t = np.clip(_safe_div(x - e0, e1 - e0), 0.0, 1.0)
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _range_clamp(value, lo, hi):
    return np.where(lo > hi, np.clip(value, hi, lo), np.clip(value, lo, hi))


def map_range_values(kind, value, fmin, fmax, tmin, tmax, steps):
    same = fmax == fmin
    if kind == "LINEAR":
        f = _safe_div(value - fmin, fmax - fmin)
    elif kind == "STEPPED":
        f = _safe_div(value - fmin, fmax - fmin)
        f = np.where(steps > 0, np.floor(f * (steps + 1.0)) / np.where(steps > 0, steps, 1.0), 0.0)
    elif kind == "SMOOTHSTEP":
        f = np.where(fmin > fmax, 1.0 - _smoothstep(fmax, fmin, value), _smoothstep(fmin, fmax, value))
    else:
        f = np.where(fmin > fmax, 1.0 - _smootherstep(fmax, fmin, value), _smootherstep(fmin, fmax, value))
    f = np.where(same, 0.0, f)
    return tmin + f * (tmax - tmin)


@node("ShaderNodeMapRange",
      inputs=(("Value", "float"), ("From Min", "float"), ("From Max", "float"), ("To Min", "float"),
              ("To Max", "float"), ("Steps", "float"), ("Vector", "vector"), ("From_Min_FLOAT3", "vector"),
              ("From_Max_FLOAT3", "vector"), ("To_Min_FLOAT3", "vector"), ("To_Max_FLOAT3", "vector"),
              ("Steps_FLOAT3", "vector")),
      outputs=(("Result", "float"), ("Vector", "vector")),
      props=(("data_type", "FLOAT"), ("interpolation_type", "LINEAR"), ("clamp", True)),
      cases=[{"Value": None, "From Min": 0.2, "From Max": 0.8, "To Min": -0.5, "To Max": 2.0},
             {"interpolation_type": "STEPPED", "Steps": 4.0, "clamp": False, "From Max": 0.7},
             {"interpolation_type": "SMOOTHSTEP", "From Min": 0.9, "From Max": 0.1},
             {"interpolation_type": "SMOOTHERSTEP", "From Min": 0.1, "From Max": 0.6},
             {"data_type": "FLOAT_VECTOR", "From_Max_FLOAT3": (0.5, 1.0, 2.0)}])
def map_range(ctx, i, p):
    kind, clamp = p["interpolation_type"], bool(p["clamp"]) and p["interpolation_type"] in ("LINEAR", "STEPPED")
    if p["data_type"] == "FLOAT_VECTOR":
        args = [i[k] for k in ("Vector", "From_Min_FLOAT3", "From_Max_FLOAT3", "To_Min_FLOAT3", "To_Max_FLOAT3",
                               "Steps_FLOAT3")]
        out = map_range_values(kind, *args)
        if clamp:
            out = _range_clamp(out, args[3], args[4])
        return {"Vector": out, "Result": out.mean(axis=1)}
    args = [i[k] for k in ("Value", "From Min", "From Max", "To Min", "To Max", "Steps")]
    out = map_range_values(kind, *args)
    if clamp:
        out = _range_clamp(out, args[3], args[4])
    return {"Result": out, "Vector": np.repeat(out[:, None], 3, axis=1)}


@node("ShaderNodeClamp", inputs=(("Value", "float"), ("Min", "float"), ("Max", "float")),
      outputs=(("Result", "float"),), props=(("clamp_type", "MINMAX"),),
      cases=[{"Min": 0.2, "Max": 0.7}, {"clamp_type": "RANGE", "Min": 0.8, "Max": 0.3}])
def clamp(ctx, i, p):
    v, lo, hi = i["Value"], i["Min"], i["Max"]
    if p["clamp_type"] == "RANGE":
        return {"Result": _range_clamp(v, lo, hi)}
    return {"Result": np.minimum(np.maximum(v, lo), hi)}


# ----------------------------------------------------------------------------
# Vector Math

def _normalize(v):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length != 0, v / np.where(length != 0, length, 1.0), 0.0)


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _vector_op(op, a, b, c, s):
    vec = {
        "ADD": lambda: a + b, "SUBTRACT": lambda: a - b, "MULTIPLY": lambda: a * b,
        "DIVIDE": lambda: _safe_div(a, b), "MULTIPLY_ADD": lambda: a * b + c,
        "CROSS_PRODUCT": lambda: np.cross(a, b),
        "PROJECT": lambda: _safe_div(_dot(a, b), _dot(b, b))[:, None] * b,
        "REFLECT": lambda: a - 2.0 * _dot(_normalize(b), a)[:, None] * _normalize(b),
        "REFRACT": lambda: _refract(a, _normalize(b), s),
        "FACEFORWARD": lambda: np.where((_dot(c, b) < 0)[:, None], a, -a),
        "SCALE": lambda: a * s[:, None], "NORMALIZE": lambda: _normalize(a),
        "SNAP": lambda: np.floor(_safe_div(a, b)) * b, "FLOOR": lambda: np.floor(a), "CEIL": lambda: np.ceil(a),
        "MODULO": lambda: np.where(b != 0, np.fmod(a, np.where(b != 0, b, 1.0)), 0.0),
        "WRAP": lambda: np.where(b - c != 0, a - (b - c) * np.floor(_safe_div(a - c, b - c)), c),
        "FRACTION": lambda: a - np.floor(a), "ABSOLUTE": lambda: np.abs(a),
        "POWER": lambda: _safe_pow(a, b), "SIGN": lambda: np.sign(a),
        "MINIMUM": lambda: np.minimum(a, b), "MAXIMUM": lambda: np.maximum(a, b),
        "SINE": lambda: np.sin(a), "COSINE": lambda: np.cos(a), "TANGENT": lambda: np.tan(a),
    }
    val = {"DOT_PRODUCT": lambda: _dot(a, b), "DISTANCE": lambda: np.linalg.norm(a - b, axis=1),
           "LENGTH": lambda: np.linalg.norm(a, axis=1)}
    if op in vec:
        return vec[op](), None
    return None, val[op]()


def _safe_pow(a, b):
    ok = (a >= 0) | (b == np.floor(b))
    return np.where(ok, np.power(np.where(ok, a, 1.0), b), 0.0)


def _refract(i, n, eta):
    d = _dot(n, i)
    k = 1.0 - eta * eta * (1.0 - d * d)
    out = eta[:, None] * i - (eta * d + np.sqrt(np.maximum(k, 0.0)))[:, None] * n
    return np.where((k < 0)[:, None], 0.0, out)


VECTOR_OPS = ("ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "CROSS_PRODUCT", "PROJECT", "REFLECT",
              "REFRACT", "FACEFORWARD", "DOT_PRODUCT", "DISTANCE", "LENGTH", "SCALE", "NORMALIZE", "SNAP",
              "FLOOR", "CEIL", "MODULO", "WRAP", "FRACTION", "ABSOLUTE", "POWER", "SIGN", "MINIMUM", "MAXIMUM",
              "SINE", "COSINE", "TANGENT")


@node("ShaderNodeVectorMath",
      inputs=(("Vector", "vector"), ("Vector_001", "vector"), ("Vector_002", "vector"), ("Scale", "float")),
      outputs=(("Vector", "vector"), ("Value", "float")), props=(("operation", "ADD"),),
      cases=[{"operation": op, "Vector_001": (0.3, -0.6, 0.9), "Vector_002": (0.2, 0.5, -0.4), "Scale": 0.7}
             for op in VECTOR_OPS])
def vector_math(ctx, i, p):
    with np.errstate(all="ignore"):
        v, f = _vector_op(p["operation"], i["Vector"], i["Vector_001"], i["Vector_002"], i["Scale"])
    n = len(i["Scale"])
    v = np.zeros((n, 3)) if v is None else np.where(np.isfinite(v), v, 0.0)
    f = np.zeros(n) if f is None else np.where(np.isfinite(f), f, 0.0)
    return {"Vector": v, "Value": f}


# ----------------------------------------------------------------------------
# Mix in vector mode (colour and float modes are engine.scene.MixColor)

@node("ShaderNodeMix",
      inputs=(("Factor_Float", "float"), ("Factor_Vector", "vector"), ("A_Vector", "vector"), ("B_Vector", "vector")),
      outputs=(("Result_Vector", "vector"),), props=(("factor_mode", "UNIFORM"), ("clamp_factor", True)),
      cases=[{"data_type": "VECTOR", "B_Vector": (1.0, 0.2, -0.5)},
             {"data_type": "VECTOR", "factor_mode": "NON_UNIFORM", "Factor_Vector": (0.2, 0.9, 0.5)}])
def mix_vector(ctx, i, p):
    t = i["Factor_Vector"] if p["factor_mode"] == "NON_UNIFORM" else i["Factor_Float"][:, None]
    if p["clamp_factor"]:
        t = np.clip(t, 0.0, 1.0)
    return {"Result_Vector": (1.0 - t) * i["A_Vector"] + t * i["B_Vector"]}


# ----------------------------------------------------------------------------
# Separate / Combine

@node("ShaderNodeSeparateXYZ", inputs=(("Vector", "vector"),),
      outputs=(("X", "float"), ("Y", "float"), ("Z", "float")), cases=[{}])
def separate_xyz(ctx, i, p):
    v = i["Vector"]
    return {"X": v[:, 0], "Y": v[:, 1], "Z": v[:, 2]}


@node("ShaderNodeCombineXYZ", inputs=(("X", "float"), ("Y", "float"), ("Z", "float")),
      outputs=(("Vector", "vector"),), cases=[{"Z": 0.4}])
def combine_xyz(ctx, i, p):
    return {"Vector": np.stack([i["X"], i["Y"], i["Z"]], axis=1)}


_TO_MODE = {"RGB": lambda c: c, "HSV": rgb_to_hsv, "HSL": rgb_to_hsl}
_FROM_MODE = {"RGB": lambda c: c, "HSV": hsv_to_rgb, "HSL": hsl_to_rgb}


@node("ShaderNodeSeparateColor", inputs=(("Color", "color"),),
      outputs=(("Red", "float"), ("Green", "float"), ("Blue", "float")), props=(("mode", "RGB"),),
      cases=[{"mode": m} for m in ("RGB", "HSV", "HSL")])
def separate_color(ctx, i, p):
    c = _TO_MODE[p["mode"]](i["Color"])
    return {"Red": c[:, 0], "Green": c[:, 1], "Blue": c[:, 2]}


@node("ShaderNodeCombineColor", inputs=(("Red", "float"), ("Green", "float"), ("Blue", "float")),
      outputs=(("Color", "color"),), props=(("mode", "RGB"),),
      cases=[{"mode": m, "Blue": 0.6} for m in ("RGB", "HSV", "HSL")])
def combine_color(ctx, i, p):
    return {"Color": _FROM_MODE[p["mode"]](np.stack([i["Red"], i["Green"], i["Blue"]], axis=1))}


# ----------------------------------------------------------------------------
# Colour adjustments

@node("ShaderNodeHueSaturation",
      inputs=(("Hue", "float"), ("Saturation", "float"), ("Value", "float"), ("Fac", "float"), ("Color", "color")),
      outputs=(("Color", "color"),), cases=[{"Hue": 0.3, "Saturation": 1.4, "Value": 0.8, "Fac": 0.9}])
def hue_saturation(ctx, i, p):
    c = i["Color"]
    hsv = rgb_to_hsv(c)
    h = hsv[:, 0] + i["Hue"] + 0.5
    hsv[:, 0] = h - np.floor(h)
    hsv[:, 1] = np.clip(hsv[:, 1] * i["Saturation"], 0.0, 1.0)
    hsv[:, 2] = hsv[:, 2] * i["Value"]
    out = hsv_to_rgb(hsv)
    fac = i["Fac"][:, None]
    return {"Color": np.maximum(fac * out + (1.0 - fac) * c, 0.0)}


@node("ShaderNodeInvert", inputs=(("Fac", "float"), ("Color", "color")), outputs=(("Color", "color"),),
      cases=[{"Fac": 0.8}])
def invert(ctx, i, p):
    fac = i["Fac"][:, None]
    return {"Color": (1.0 - fac) * i["Color"] + fac * (1.0 - i["Color"])}


@node("ShaderNodeGamma", inputs=(("Color", "color"), ("Gamma", "float")), outputs=(("Color", "color"),),
      cases=[{"Gamma": 2.2}])
def gamma(ctx, i, p):
    c = i["Color"]
    g = i["Gamma"][:, None]
    out = np.where(c > 0, np.power(np.maximum(c, 1e-30), g), c)
    return {"Color": np.where(g == 0, 1.0, out)}


@node("ShaderNodeBrightContrast", inputs=(("Color", "color"), ("Bright", "float"), ("Contrast", "float")),
      outputs=(("Color", "color"),), cases=[{"Bright": 0.1, "Contrast": 0.4}])
def bright_contrast(ctx, i, p):
    a = 1.0 + i["Contrast"]
    b = i["Bright"] - i["Contrast"] * 0.5
    return {"Color": np.maximum(a[:, None] * i["Color"] + b[:, None], 0.0)}


@node("ShaderNodeRGBToBW", inputs=(("Color", "color"),), outputs=(("Val", "float"),), cases=[{}])
def rgb_to_bw(ctx, i, p):
    return {"Val": i["Color"] @ LUMA}
