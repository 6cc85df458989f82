"""Converter and colour nodes as Cycles' SVM evaluates them."""
import numpy as np

from .. import kernels
from .color_math import hsl_to_rgb, hsv_to_rgb, rgb_to_hsl, rgb_to_hsv
from .registry import node

LUMA = np.array([0.2126, 0.7152, 0.0722])
RAMP_SIZE = 257   # Cycles bakes colour ramps at i / 256


def f32(a):
    return np.asarray(a, dtype=np.float32)


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
    rgba = ramp_rows(np.ascontiguousarray(p["table"], dtype=np.float64), i["Fac"], not p["constant"])
    return {"Color": rgba[:, :3], "Alpha": rgba[:, 3]}


def ramp_rows(table, f, interpolate):
    """ramp_lookup without extrapolation as one compiled pass over the
    points (a Color Ramp: eight array passes before)."""
    f = np.ascontiguousarray(f, dtype=np.float64)
    out = np.empty((len(f), table.shape[1]))
    _ramp_loop(table, f, int(bool(interpolate)), out)
    return out


def _ramp_numpy(table, f, interpolate, out):
    """The NumPy reference of _ramp_loop: ramp_lookup."""
    out[:] = ramp_lookup(table, f, bool(interpolate))


@kernels.loop_kernel("void(float64[:, ::1], float64[::1], int64, float64[:, ::1])", _ramp_numpy)
def _ramp_loop(table, f, interpolate, out):
    size = table.shape[0]
    for n in range(f.shape[0]):
        v = f[n]
        if v != v:
            v = 0.0                        # nan_to_num: NaN reads as 0 (infinities clip below)
        x = min(max(v, 0.0), 1.0) * (size - 1)
        i = min(max(int(x), 0), size - 1)
        t = x - i
        j = min(i + 1, size - 1)
        for c in range(table.shape[1]):
            value = table[i, c]
            if interpolate and t > 0:
                value = (1.0 - t) * value + t * table[j, c]
            out[n, c] = value


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


# ----------------------------------------------------------------------------
# Blackbody and Wavelength (kernel/svm/math_util.h, kernel/tables.h)

BLACKBODY_R = np.array([
    [1.61919106e+03, -2.05010916e-03, 5.02995757e+00], [2.48845471e+03, -1.11330907e-03, 3.22621544e+00],
    [3.34143193e+03, -4.86551192e-04, 1.76486769e+00], [4.09461742e+03, -1.27446582e-04, 7.25731635e-01],
    [4.67028036e+03, 2.91258199e-05, 1.26703442e-01], [4.59509185e+03, 2.87495649e-05, 1.50345020e-01],
    [3.78717450e+03, 9.35907826e-06, 3.99075871e-01]], np.float32)
BLACKBODY_G = np.array([
    [-4.88999748e+02, 6.04330754e-04, -7.55807526e-02], [-7.55994277e+02, 3.16730098e-04, 4.78306139e-01],
    [-1.02363977e+03, 1.20223470e-04, 9.36662319e-01], [-1.26571316e+03, 4.87340896e-06, 1.27054498e+00],
    [-1.42529332e+03, -4.01150431e-05, 1.43972784e+00], [-1.17554822e+03, -2.16378048e-05, 1.30408023e+00],
    [-5.00799571e+02, -4.59832026e-06, 1.09098763e+00]], np.float32)
BLACKBODY_B = np.array([
    [5.96945309e-11, -4.85742887e-08, -9.70622247e-05, -4.07936148e-03],
    [2.40430366e-11, 5.55021075e-08, -1.98503712e-04, 2.89312858e-02],
    [-1.40949732e-11, 1.89878968e-07, -3.56632824e-04, 9.10767778e-02],
    [-3.61460868e-11, 2.84822009e-07, -4.93211319e-04, 1.56723440e-01],
    [-1.97075738e-11, 1.75359352e-07, -2.50542825e-04, -2.22783266e-02],
    [-1.61997957e-13, -1.64216008e-08, 3.86216271e-04, -7.38077418e-01],
    [6.72650283e-13, -2.73078809e-08, 4.24098264e-04, -7.52335691e-01]], np.float32)
BLACKBODY_HOT = np.array([0.8262954810464208, 0.9945080501520986, 1.566307710274283], np.float32)
BLACKBODY_COLD = np.array([5.413294490189271, -0.20319390035873933, -0.0822535242887164], np.float32)


def blackbody_rec709(t):
    """Cycles' piecewise fit of the blackbody colour (Rec.709, may be negative)."""
    t = np.asarray(t, np.float32)
    i = np.searchsorted(np.array([965.0, 1167.0, 1449.0, 1902.0, 3315.0, 6365.0], np.float32), t, side="right")
    r, g, b = BLACKBODY_R[i], BLACKBODY_G[i], BLACKBODY_B[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_inv = np.float32(1.0) / t
        rgb = np.stack([r[:, 0] * t_inv + r[:, 1] * t + r[:, 2], g[:, 0] * t_inv + g[:, 1] * t + g[:, 2],
                        ((b[:, 0] * t + b[:, 1]) * t + b[:, 2]) * t + b[:, 3]], axis=1)
    rgb = np.where((t >= 12000.0)[:, None], BLACKBODY_HOT, rgb)
    return np.where((t < 800.0)[:, None], BLACKBODY_COLD, rgb)


@node("ShaderNodeBlackbody", inputs=(("Temperature", "float"),), outputs=(("Color", "color"),),
      cases=[{"Temperature": t} for t in (650.0, 1000.0, 1500.0, 2700.0, 4500.0, 6500.0, 9000.0, 15000.0)])
def blackbody(ctx, i, p):
    """Rec.709 is Blender's default working space, so rec709_to_rgb is the identity.
    ``_unclamped`` (the exporter's Principled Volume blackbody): the fit as
    it is, negative below about 1500 K in blue, as svm_node_principled_volume
    takes it (the Blackbody node clamps it at 0)."""
    rgb = blackbody_rec709(i["Temperature"])
    return {"Color": rgb if p.get("_unclamped") else np.maximum(rgb, 0.0)}


CIE_COLOR_MATCH = np.array([
    0.0014, 0.0000, 0.0065, 0.0022, 0.0001, 0.0105, 0.0042, 0.0001, 0.0201, 0.0076, 0.0002, 0.0362,
    0.0143, 0.0004, 0.0679, 0.0232, 0.0006, 0.1102, 0.0435, 0.0012, 0.2074, 0.0776, 0.0022, 0.3713,
    0.1344, 0.0040, 0.6456, 0.2148, 0.0073, 1.0391, 0.2839, 0.0116, 1.3856, 0.3285, 0.0168, 1.6230,
    0.3483, 0.0230, 1.7471, 0.3481, 0.0298, 1.7826, 0.3362, 0.0380, 1.7721, 0.3187, 0.0480, 1.7441,
    0.2908, 0.0600, 1.6692, 0.2511, 0.0739, 1.5281, 0.1954, 0.0910, 1.2876, 0.1421, 0.1126, 1.0419,
    0.0956, 0.1390, 0.8130, 0.0580, 0.1693, 0.6162, 0.0320, 0.2080, 0.4652, 0.0147, 0.2586, 0.3533,
    0.0049, 0.3230, 0.2720, 0.0024, 0.4073, 0.2123, 0.0093, 0.5030, 0.1582, 0.0291, 0.6082, 0.1117,
    0.0633, 0.7100, 0.0782, 0.1096, 0.7932, 0.0573, 0.1655, 0.8620, 0.0422, 0.2257, 0.9149, 0.0298,
    0.2904, 0.9540, 0.0203, 0.3597, 0.9803, 0.0134, 0.4334, 0.9950, 0.0087, 0.5121, 1.0000, 0.0057,
    0.5945, 0.9950, 0.0039, 0.6784, 0.9786, 0.0027, 0.7621, 0.9520, 0.0021, 0.8425, 0.9154, 0.0018,
    0.9163, 0.8700, 0.0017, 0.9786, 0.8163, 0.0014, 1.0263, 0.7570, 0.0011, 1.0567, 0.6949, 0.0010,
    1.0622, 0.6310, 0.0008, 1.0456, 0.5668, 0.0006, 1.0026, 0.5030, 0.0003, 0.9384, 0.4412, 0.0002,
    0.8544, 0.3810, 0.0002, 0.7514, 0.3210, 0.0001, 0.6424, 0.2650, 0.0000, 0.5419, 0.2170, 0.0000,
    0.4479, 0.1750, 0.0000, 0.3608, 0.1382, 0.0000, 0.2835, 0.1070, 0.0000, 0.2187, 0.0816, 0.0000,
    0.1649, 0.0610, 0.0000, 0.1212, 0.0446, 0.0000, 0.0874, 0.0320, 0.0000, 0.0636, 0.0232, 0.0000,
    0.0468, 0.0170, 0.0000, 0.0329, 0.0119, 0.0000, 0.0227, 0.0082, 0.0000, 0.0158, 0.0057, 0.0000,
    0.0114, 0.0041, 0.0000, 0.0081, 0.0029, 0.0000, 0.0058, 0.0021, 0.0000, 0.0041, 0.0015, 0.0000,
    0.0029, 0.0010, 0.0000, 0.0020, 0.0007, 0.0000, 0.0014, 0.0005, 0.0000, 0.0010, 0.0004, 0.0000,
    0.0007, 0.0002, 0.0000, 0.0005, 0.0002, 0.0000, 0.0003, 0.0001, 0.0000, 0.0002, 0.0001, 0.0000,
    0.0002, 0.0001, 0.0000, 0.0001, 0.0000, 0.0000, 0.0001, 0.0000, 0.0000, 0.0001, 0.0000, 0.0000,
    0.0000, 0.0000, 0.0000], np.float32).reshape(-1, 3)
# CIE XYZ (D65) -> linear Rec.709 (Blender's default scene linear space), the
# matrix from the primaries' chromaticities (measured: matches Cycles exactly).
XYZ_TO_REC709 = np.array([[3.2409699, -1.5373832, -0.4986108], [-0.9692436, 1.8759675, 0.0415551],
                          [0.0556301, -0.2039770, 1.0569715]], np.float32)


@node("ShaderNodeWavelength", inputs=(("Wavelength", "float"),), outputs=(("Color", "color"),),
      cases=[{"Wavelength": w} for w in (400.0, 455.5, 510.0, 580.0, 650.0, 720.0, 900.0)])
def wavelength(ctx, i, p):
    """CIE matching functions in 5 nm steps from 380 nm, interpolated,
    to RGB, scaled by 1 / 2.52 and clamped at 0 (Cycles' wavelength.h)."""
    ii = (f32(i["Wavelength"]) - np.float32(380.0)) * np.float32(0.2)
    k = ii.astype(np.int64)
    ok = (ii >= 0) & (k < 80)
    k = np.clip(k, 0, 79)
    t = (ii - k)[:, None]
    xyz = np.where(ok[:, None], (1 - t) * CIE_COLOR_MATCH[k] + t * CIE_COLOR_MATCH[k + 1], 0.0)
    return {"Color": np.maximum(xyz @ XYZ_TO_REC709.T / 2.52, 0.0)}
