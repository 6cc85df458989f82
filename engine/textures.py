"""Texture expressions evaluated per ray, and normal perturbation.

A Lobe parameter, a Material's emission or its normal may be an expression
(``scene.ImageTexture``, ``MixColor``, ``Math``, ``NormalMap``, ``Bump``)
instead of a constant.  ``compile_expr`` turns one into a function of the
hit's UVs (N, 2) returning (N,) floats or (N, 3) colours.  ``MaterialTextures``
collects a scene's expressions; ``bsdf.MaterialTable.gather`` lets it overwrite
the textured lobe parameters, and the integrator asks it to perturb shading
normals.

Image lookups follow Cycles' CPU kernel (``kernel/device/cpu/image.h``): image
row 0 is the bottom (UV v = 0), Closest reads texel floor(u W), Linear blends
the texels around u W - 0.5; REPEAT wraps, EXTEND clamps, CLIP reads zero
outside, MIRROR reflects.  8-bit sRGB images are filtered in sRGB encoding and
decoded after, straight alpha is associated before filtering and divided out
again only when the node's Alpha output is used, as Cycles does.
"""
import dataclasses

import numpy as np

from .kernels import helper, kernel, where
from .nodes import REGISTRY, ShadingContext, as_context
from .nodes.color_math import EXTRA_BLENDS
from .nodes.context import _bary_of_offsets
from .nodes.rays import orthonormal_a
from .projection import to_uv
from .scene import (TEXTURE_TYPES, Bump, ImageTexture, Math, MixColor, NodeOutput, NormalMap)

LUMA = np.array([0.2126, 0.7152, 0.0722])
# Far-away UVs lose all precision anyway; keep them within int64 range.
UV_LIMIT = 1e9


def is_texture(value):
    return isinstance(value, TEXTURE_TYPES)


# ----------------------------------------------------------------------------
# colour spaces

def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float64)
    low = np.maximum(c, 0.0) / 12.92
    high = np.power(np.maximum(c + 0.055, 0.0) / 1.055, 2.4)
    return np.where(c < 0.04045, low, high)


def linear_to_srgb(c):
    c = np.asarray(c, dtype=np.float64)
    low = np.maximum(c, 0.0) * 12.92
    high = 1.055 * np.power(np.maximum(c, 0.0), 1.0 / 2.4) - 0.055
    return np.where(c < 0.0031308, low, high)


# ----------------------------------------------------------------------------
# images

TEXEL_BAND = 512  # rows converted at a time: float64 temporaries stay small


def prepare_texels(image):
    """(H, W, 4) float32 RGBA, row 0 at the BOTTOM, in the space Cycles
    filters in: sRGB-encoded for srgb_filter images, alpha associated for
    straight-alpha colour images.  One float32 copy of the image and no
    full-size temporaries (a 16k x 16k texture is 4 GiB as float32 RGBA).
    Kept on the image (read-only) so that every user - the shader compiler,
    value ranges, later renders of the same scene - shares one copy."""
    cached = getattr(image, "_texels", None)
    if cached is not None and cached[0] is image.pixels:
        return cached[1]
    rgba = _convert_texels(image)
    rgba.flags.writeable = False
    try:
        image._texels = (image.pixels, rgba)
    except AttributeError:  # an image type without a __dict__: no sharing
        pass
    return rgba


def _convert_texels(image):
    px = np.asarray(image.pixels)
    if px.ndim == 2:
        px = px[..., None]
    h, w, c = px.shape
    source = px[::-1]
    rgba = np.empty((h, w, 4), np.float32)
    rgba[..., :3] = source[..., :1] if c <= 2 else source[..., :3]
    if c in (2, 4) and image.alpha_mode != "NONE":
        rgba[..., 3] = source[..., -1]
    else:
        rgba[..., 3] = 1.0
    np.nan_to_num(rgba, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    for lo in range(0, h, TEXEL_BAND):
        band = rgba[lo:lo + TEXEL_BAND]
        if image.srgb_filter:
            band[..., :3] = linear_to_srgb(band[..., :3])
        if image.alpha_mode == "STRAIGHT" and not image.data:
            band[..., :3] *= band[..., 3:]
    return rgba


def _wrap(i, size, extension):
    if extension == "REPEAT":
        return np.mod(i, size)
    if extension == "MIRROR":
        m = np.mod(np.abs(i + (i < 0)), 2 * size)
        return np.where(m >= size, 2 * size - m - 1, m)
    return np.clip(i, 0, size - 1)  # EXTEND; CLIP masks separately


def _read(texels, ix, iy, extension):
    h, w = texels.shape[:2]
    out = texels[_wrap(iy, h, extension), _wrap(ix, w, extension)]
    if extension == "CLIP":
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        out = out * inside[:, None]
    return out


def sample_texels(texels, uv, interpolation="Linear", extension="REPEAT"):
    """(N, 4) filtered texels at uv (N, 2); texels row 0 = bottom (v = 0)."""
    h, w = texels.shape[:2]
    uv = np.clip(np.nan_to_num(np.asarray(uv, dtype=np.float64)), -UV_LIMIT, UV_LIMIT)
    x, y = uv[:, 0] * w, uv[:, 1] * h
    if interpolation == "Closest":
        return _read(texels, np.floor(x).astype(np.int64), np.floor(y).astype(np.int64), extension)
    x, y = x - 0.5, y - 0.5
    fx, fy = np.floor(x), np.floor(y)
    tx, ty = (x - fx)[:, None], (y - fy)[:, None]
    ix, iy = fx.astype(np.int64), fy.astype(np.int64)
    return ((1 - ty) * ((1 - tx) * _read(texels, ix, iy, extension) + tx * _read(texels, ix + 1, iy, extension))
            + ty * ((1 - tx) * _read(texels, ix, iy + 1, extension)
                    + tx * _read(texels, ix + 1, iy + 1, extension)))


def _last_call(fn):
    """fn remembering its last argument and result: one image feeds several
    lobe fields of a material (Principled metallic weighs the metal and,
    as 1 - metallic, the layers beside it), looked up once per ray batch.
    The argument is held, so its identity cannot be reused; results are
    read-only to callers."""
    last = [None]

    def cached(arg):
        # One (argument, result) pair swapped in whole: render threads share it.
        entry = last[0]
        if entry is None or entry[0] is not arg:
            entry = (arg, fn(arg))
            last[0] = entry
        return entry[1]
    return cached


# Cycles' TEX_IMAGE_MISSING_*: a UV outside every tile of a UDIM image.
MISSING_TILE = np.array([1.0, 0.0, 1.0, 1.0])


def _tiled_lookup(node, tiles):
    """RGBA of a UDIM image as Cycles' kernel_image_udim_map: the tile of
    (tx, ty) = the UV's integer parts truncated toward zero (as C's (int)),
    number 1001 + tx + 10 ty for 0 <= tx < 10 and ty >= 0, read at the UV
    minus (tx, ty) with the node's extension; no such tile gives magenta.
    tiles: [(number, TextureImage, texels)]."""
    lookups = {int(number): _image_lookup(node, image, texels) for number, image, texels in tiles}

    def lookup(uv):
        uv = np.clip(np.nan_to_num(np.asarray(uv, dtype=np.float64)), -UV_LIMIT, UV_LIMIT)
        t = np.trunc(uv)
        inside = (t[:, 0] >= 0) & (t[:, 1] >= 0) & (t[:, 0] < 10)
        number = np.where(inside, 1001 + t[:, 0] + 10 * t[:, 1], -1)
        out = np.tile(MISSING_TILE, (len(uv), 1))
        for n, fn in lookups.items():
            rows = np.nonzero(number == n)[0]
            if len(rows):
                out[rows] = fn(uv[rows] - t[rows])
        return out
    return lookup


def _extension(node):
    """The node's extension; the Environment Texture's is always REPEAT
    (Cycles' EnvironmentTextureNode::image_params)."""
    return node.extension if node.projection == "FLAT" else "REPEAT"


def _image_lookup(node, image, texels):
    """RGBA at uv as the Image Texture node outputs it (colour linear)."""
    extension = _extension(node)

    def lookup(uv):
        rgba = sample_texels(texels, uv, node.interpolation, extension)
        if node.unassociate:
            a = rgba[:, 3:]
            scale = np.where((a != 0) & (a != 1), 1.0 / np.where(a != 0, a, 1.0), 1.0)
            rgba[:, :3] *= scale
        if image.srgb_filter:
            rgba[:, :3] = srgb_to_linear(rgba[:, :3])
        return rgba
    return lookup


# ----------------------------------------------------------------------------
# expressions

class Compiler:
    """Compiles expressions to functions of a shading context
    (engine.nodes.ShadingContext; (N, 2) UVs are accepted too);
    images are prepared once, every node call is evaluated once per context."""

    def __init__(self):
        self.texels = {}
        self.compiled = {}  # id(expr) -> (expr, compiled): shared sub-expressions compile once
        self.calls = {}     # id(NodeCall) -> (call, fn(ctx) -> outputs)

    def texels_of(self, image):
        key = id(image)
        if key not in self.texels:
            self.texels[key] = (image, prepare_texels(image))
        return self.texels[key][1]

    def compile(self, expr):
        """-> (fn(ctx) -> (N,) or (N, 3), is_colour)."""
        fn, kind = self.compile_kind(expr)
        return fn, kind != "float"

    def compile_kind(self, expr):
        """-> (fn(ctx), kind) with kind 'float', 'color' or 'vector'."""
        if not is_texture(expr):
            fn, kind = self._compile(expr)
        else:
            key = id(expr)
            if key not in self.compiled:
                self.compiled[key] = (expr, self._compile(expr))
            fn, kind = self.compiled[key][1]
        return (lambda ctx: fn(as_context(ctx))), kind

    def _compile(self, expr):
        if isinstance(expr, ImageTexture):
            return self._image(expr)
        if isinstance(expr, MixColor):
            return self._mix(expr), "color"
        if isinstance(expr, Math):
            return self._math(expr), "float"
        if isinstance(expr, NodeOutput):
            return self._node_output(expr)
        if isinstance(expr, (NormalMap, Bump)):
            raise TypeError(f"{type(expr).__name__} is a normal, not a colour or value")
        value = np.asarray(expr, dtype=np.float64)
        if value.ndim == 0:
            v = float(value)
            return (lambda ctx: np.full(len(ctx), v)), "float"
        rgb = value.reshape(-1)[:3]
        return (lambda ctx: np.broadcast_to(rgb, (len(ctx), 3)).copy()), "color"

    def color(self, expr):
        fn, is_color = self.compile(expr)
        return fn if is_color else (lambda ctx: np.repeat(fn(ctx)[:, None], 3, axis=1))

    def value(self, expr):
        fn, kind = self.compile_kind(expr)
        if kind == "vector":
            return lambda ctx: fn(ctx).mean(axis=1)       # Cycles: vector to float = average
        return (lambda ctx: fn(ctx) @ LUMA) if kind == "color" else fn

    def as_kind(self, expr, kind):
        """expr converted to a socket kind as Cycles' implicit conversions."""
        return self.value(expr) if kind == "float" else self.color(expr)

    def _image(self, node):
        image = node.image
        if image.tiles and node.projection == "FLAT":
            sampler = _tiled_lookup(node, [(n, tile, self.texels_of(tile)) for n, tile in image.tiles])
        else:
            sampler = _image_lookup(node, image, self.texels_of(image))
        lookup = _last_call(sampler)
        if node.projection != "FLAT":
            coords = self._environment_uv(node)
        else:
            coords = (lambda ctx: ctx.uv) if node.uv is None else self._uv(node.uv)
        if node.output == "Alpha":
            return (lambda ctx: lookup(coords(ctx))[:, 3]), "float"
        return (lambda ctx: lookup(coords(ctx))[:, :3]), "color"

    def _environment_uv(self, node):
        """The Environment Texture's image UV: its Vector (the world
        position when unlinked) as a direction, equirectangular or mirror
        ball (svm_node_tex_environment)."""
        vector = (lambda ctx: ctx.p) if node.uv is None else self.color(node.uv)

        def coords(ctx):
            e = np.asarray(vector(ctx), dtype=np.float64)
            uv = np.stack(to_uv(e, node.projection), axis=1)
            if node.projection == "EQUIRECTANGULAR":
                # direction_to_equirectangular_range: a zero vector is (0, 0).
                uv[~np.any(e != 0.0, axis=1)] = 0.0
            return uv
        return coords

    def _uv(self, expr):
        """A vector input: its first two components are the UV."""
        fn = self.color(expr)
        return lambda ctx: fn(ctx)[:, :2]

    def _mix(self, node):
        fac, a, b = self.value(node.fac), self.color(node.a), self.color(node.b)

        def mix(ctx):
            t = fac(ctx)
            if node.clamp_factor:
                t = np.clip(t, 0.0, 1.0)
            out = mix_colors(node.blend, t[:, None], a(ctx), b(ctx))
            return np.clip(out, 0.0, 1.0) if node.clamp_result else out
        return mix

    def _math(self, node):
        a, b, c = self.value(node.a), self.value(node.b), self.value(node.c)

        def math(ctx):
            out = math_op(node.operation, a(ctx), b(ctx), c(ctx))
            return np.clip(out, 0.0, 1.0) if node.clamp else out
        return math

    def _node_output(self, expr):
        entry = REGISTRY[expr.call.idname]
        run = self._call(expr.call)
        name = expr.output
        return (lambda ctx: run(ctx)[name]), entry.output_kind(name)

    def _call(self, call):
        key = id(call)
        if key not in self.calls:
            self.calls[key] = (call, _last_call(self._call_fn(call)))
        return self.calls[key][1]

    def _call_fn(self, call):
        entry = REGISTRY[call.idname]
        inputs = {name: self.as_kind(call.inputs[name], kind)
                  for name, kind in entry.inputs if name in call.inputs}
        defaults = [(name, kind) for name, kind in entry.inputs if name not in call.inputs]
        props = dict(call.props)

        def run(ctx):
            values = {name: fn(ctx) for name, fn in inputs.items()}
            for name, kind in defaults:
                default = _default_input(ctx, entry, name, kind)
                if default is not None:
                    values[name] = default
            with np.errstate(all="ignore"):
                out = entry.evaluate(ctx, values, props)
            return {k: _finite(v) for k, v in out.items()}
        return run


def _default_input(ctx, entry, name, kind):
    """An input the expression leaves out: the coordinates a texture reads
    by default, the shading normal for Normal (None), else zero."""
    if name == "Vector" and entry.coords is not None:
        if entry.coords == "generated":
            return ctx.generated
        if entry.coords == "position":
            return ctx.p
        if entry.coords == "incoming":
            return ctx.to_object(ctx.wo)   # Cycles' LINK_TEXTURE_INCOMING (IES)
        uv = np.zeros((len(ctx), 3))
        uv[:, :2] = ctx.uv
        return uv
    if name == "Normal":
        return None
    value = entry.input_defaults.get(name, 0.0)
    return np.full(len(ctx), float(value)) if kind == "float" else np.broadcast_to(
        np.asarray(value, dtype=np.float64), (len(ctx), 3)).copy()


def _finite(value):
    value = np.asarray(value, dtype=np.float64)
    return np.where(np.isfinite(value), value, 0.0)


def mix_colors(blend, t, a, b):
    """Cycles' svm_mix_* (kernel/svm/color_util.h); t is (N, 1)."""
    tm = 1.0 - t
    if blend == "MIX":
        return tm * a + t * b
    if blend == "ADD":
        return a + t * b
    if blend == "MULTIPLY":
        return a * (tm + t * b)
    if blend == "SUBTRACT":
        return a - t * b
    if blend == "SCREEN":
        return 1.0 - (tm + t * (1.0 - b)) * (1.0 - a)
    if blend == "OVERLAY":
        return np.where(a < 0.5, a * (tm + 2.0 * t * b), 1.0 - (tm + 2.0 * t * (1.0 - b)) * (1.0 - a))
    if blend == "DIVIDE":
        safe = np.where(b != 0, b, 1.0)
        return np.where(b != 0, tm * a + t * a / safe, a)
    if blend == "DIFFERENCE":
        return tm * a + t * np.abs(a - b)
    if blend == "DARKEN":
        return tm * a + t * np.minimum(a, b)
    if blend == "LIGHTEN":
        return tm * a + t * np.maximum(a, b)
    if blend in EXTRA_BLENDS:
        t = np.broadcast_to(t, np.broadcast_shapes(np.shape(t), np.shape(a), np.shape(b))[:-1] + (1,))
        a, b = (np.broadcast_to(x, t.shape[:-1] + (3,)).astype(np.float64) for x in (a, b))
        if t.ndim == 1:
            return EXTRA_BLENDS[blend](t[None], a[None], b[None])[0]
        return EXTRA_BLENDS[blend](t, a, b)
    raise ValueError(f"unknown mix blend {blend!r}")


def _safe_div(a, b):
    return np.where(b != 0, a / np.where(b != 0, b, 1.0), 0.0)


def math_op(op, a, b, c):
    """Cycles' svm_math (kernel/svm/math_util.h) with its safe variants."""
    with np.errstate(all="ignore"):
        out = _math_raw(op, a, b, c)
    return np.where(np.isfinite(out), out, 0.0)


def _fract(x):
    return x - np.floor(x)


def _smooth_min(a, b, c):
    """Cycles' smoothminf: a polynomial blend of width c."""
    safe_c = np.where(c != 0, c, 1.0)
    h = np.maximum(c - np.abs(a - b), 0.0) / safe_c
    return np.where(c != 0, np.minimum(a, b) - h * h * h * c * (1.0 / 6.0), np.minimum(a, b))


def _math_raw(op, a, b, c):
    simple = {
        "ADD": lambda: a + b, "SUBTRACT": lambda: a - b, "MULTIPLY": lambda: a * b,
        "DIVIDE": lambda: _safe_div(a, b), "MULTIPLY_ADD": lambda: a * b + c,
        "MINIMUM": lambda: np.minimum(a, b), "MAXIMUM": lambda: np.maximum(a, b),
        "LESS_THAN": lambda: (a < b).astype(float), "GREATER_THAN": lambda: (a > b).astype(float),
        "ABSOLUTE": lambda: np.abs(a), "EXPONENT": lambda: np.exp(a), "SIGN": lambda: np.sign(a),
        "ROUND": lambda: np.floor(a + 0.5), "FLOOR": lambda: np.floor(a), "CEIL": lambda: np.ceil(a),
        "TRUNC": lambda: np.trunc(a), "FRACT": lambda: a - np.floor(a),
        "SINE": lambda: np.sin(a), "COSINE": lambda: np.cos(a), "TANGENT": lambda: np.tan(a),
        "SQRT": lambda: np.where(a > 0, np.sqrt(np.maximum(a, 0.0)), 0.0),
        "INVERSE_SQRT": lambda: np.where(a > 0, 1.0 / np.sqrt(np.where(a > 0, a, 1.0)), 0.0),
        "MODULO": lambda: np.where(b != 0, np.fmod(a, np.where(b != 0, b, 1.0)), 0.0),
        "SNAP": lambda: np.where(b != 0, np.floor(_safe_div(a, b)) * b, 0.0),
        "COMPARE": lambda: (np.abs(a - b) <= np.maximum(c, 1e-5)).astype(float),
        "SMOOTH_MIN": lambda: _smooth_min(a, b, c), "SMOOTH_MAX": lambda: -_smooth_min(-a, -b, c),
        "WRAP": lambda: np.where(b - c != 0, a - (b - c) * np.floor(_safe_div(a - c, b - c)), c),
        "PINGPONG": lambda: np.where(b != 0, np.abs(_fract(_safe_div(a - b, b * 2.0)) * b * 2.0 - b), 0.0),
        "ARCSINE": lambda: np.arcsin(np.clip(a, -1.0, 1.0)), "ARCCOSINE": lambda: np.arccos(np.clip(a, -1.0, 1.0)),
        "ARCTANGENT": lambda: np.arctan(a), "ARCTAN2": lambda: np.arctan2(a, b),
        "SINH": lambda: np.sinh(a), "COSH": lambda: np.cosh(a), "TANH": lambda: np.tanh(a),
        "RADIANS": lambda: a * (np.pi / 180.0), "DEGREES": lambda: a * (180.0 / np.pi),
        "FLOORED_MODULO": lambda: np.where(b != 0, a - np.floor(_safe_div(a, b)) * b, 0.0),
    }
    if op in simple:
        return simple[op]()
    if op == "POWER":
        # safe_powf: a negative base needs an integer exponent.
        ok = (a >= 0) | (b == np.floor(b))
        return np.where(ok, np.power(np.where(ok, a, 1.0), b), 0.0)
    if op == "LOGARITHM":
        ok = (a > 0) & (b > 0)
        return np.where(ok, np.log(np.where(ok, a, 1.0)) / np.log(np.where(ok, b, 2.0)), 0.0)
    raise ValueError(f"unknown math operation {op!r}")


def possible_emission(expr):
    """The constant standing for an emission whose mean over UVs is 0 but
    which may emit elsewhere (a Light Path output, a texture dark where the
    grid samples it): as Cycles' emission estimate, which takes 1 for what it
    cannot fold, it keeps the mesh a light; its upper bound where finite."""
    lo, hi = value_range(expr)
    if not hi > 0:
        return (0.0, 0.0, 0.0)
    v = float(hi) if np.isfinite(hi) else 1.0
    return (v, v, v)


def constant_of(fn, is_color):
    """A representative constant of an expression: its mean over a UV grid
    (used where one number per material is needed, e.g. the albedo AOV)."""
    g = (np.arange(16) + 0.5) / 16
    uv = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    mean = fn(uv).mean(axis=0)
    return tuple(float(x) for x in mean) if is_color else float(mean)


# ----------------------------------------------------------------------------
# value ranges (interval arithmetic), for deciding at export which lobes exist

UNBOUNDED = (-np.inf, np.inf)
# Math operations monotone in each operand (for fixed others) on any box:
# their extremes over a box of operand intervals lie at its corners.
MONOTONE_MATH = ("ADD", "SUBTRACT", "MULTIPLY", "MULTIPLY_ADD", "MINIMUM", "MAXIMUM", "LESS_THAN",
                 "GREATER_THAN", "SIGN", "ROUND", "FLOOR", "CEIL", "TRUNC", "EXPONENT", "SQRT")
# Mix blends multilinear in (factor, a, b): extremes at the corners too.
MULTILINEAR_BLENDS = ("MIX", "ADD", "MULTIPLY", "SUBTRACT", "SCREEN")


def value_range(expr):
    """(lo, hi) bounding every value of every channel a constant or texture
    expression can take (a colour used as a float, its luminance, lies in
    it too).  Conservative: an operation it cannot bound gives (-inf, inf),
    which only costs the exporter a lobe it might have left out."""
    if isinstance(expr, ImageTexture):
        return _image_range(expr)
    if isinstance(expr, MixColor):
        return _mix_range(expr)
    if isinstance(expr, Math):
        lo, hi = _math_range(expr)
        return (max(lo, 0.0), min(hi, 1.0)) if expr.clamp else (lo, hi)
    if isinstance(expr, NodeOutput):
        entry = REGISTRY.get(expr.call.idname)
        bounds = entry.bounds(expr.call.props) if entry is not None and entry.bounds is not None else {}
        return tuple(bounds.get(expr.output, UNBOUNDED))
    if is_texture(expr):
        return UNBOUNDED
    value = np.asarray(expr, dtype=np.float64).reshape(-1)
    return float(value.min()), float(value.max())


def _hull(values, *extra):
    values = np.concatenate([np.asarray(values, dtype=np.float64).reshape(-1), np.asarray(extra, float)])
    if not np.isfinite(values).all():
        return UNBOUNDED
    return float(values.min()), float(values.max())


def _image_range(node):
    """Filtering blends the prepared texels (sRGB-encoded, alpha associated)
    with weights in [0, 1] summing to 1, so it stays within their hull (CLIP
    adds 0); decoding sRGB after is monotone.  Dividing by filtered alpha
    (unassociate) is not bounded here.  A UDIM image: the hull of its
    tiles' and of the missing-tile magenta."""
    if not node.image.tiles or node.projection != "FLAT":
        return _single_image_range(node, node.image)
    ranges = [_single_image_range(node, tile) for _, tile in node.image.tiles] + [(0.0, 1.0)]
    return min(r[0] for r in ranges), max(r[1] for r in ranges)


def _single_image_range(node, image):
    texels = prepare_texels(image)
    zero = (0.0,) if _extension(node) == "CLIP" else ()
    if node.output == "Alpha":
        return _hull(texels[..., 3], *zero)
    if node.unassociate and (texels[..., 3] != 1).any():
        return UNBOUNDED
    lo, hi = _hull(texels[..., :3], *zero)
    if image.srgb_filter:
        lo, hi = (float(x) for x in srgb_to_linear([lo, hi]))
    return lo, hi


def _corners(fn, ranges):
    """fn evaluated at every corner of the box of operand ranges (a corner
    that overflows leaves the range unbounded)."""
    if not all(np.isfinite(r).all() for r in ranges):
        return UNBOUNDED
    grid = np.array(np.meshgrid(*ranges, indexing="ij")).reshape(len(ranges), -1)
    with np.errstate(all="ignore"):
        return _hull(fn(*grid))


def _math_range(node):
    op = node.operation
    a, b, c = value_range(node.a), value_range(node.b), value_range(node.c)
    if op in MONOTONE_MATH:
        return _corners(lambda x, y, z: _math_raw(op, x, y, z), (a, b, c))
    if op == "DIVIDE" and (b[0] > 0 or b[1] < 0):
        return _corners(lambda x, y: _math_raw(op, x, y, 0.0), (a, b))
    if op == "POWER" and a[0] > 0:
        return _corners(lambda x, y: _math_raw(op, x, y, 0.0), (a, b))
    if op == "INVERSE_SQRT" and a[0] > 0:
        return _corners(lambda x: _math_raw(op, x, 0.0, 0.0), (a,))
    if op == "ABSOLUTE":
        top = max(abs(a[0]), abs(a[1]))
        return (0.0 if a[0] <= 0 <= a[1] else min(abs(a[0]), abs(a[1])), top)
    if op in ("SINE", "COSINE"):
        return (-1.0, 1.0)
    if op == "FRACT":
        return (0.0, 1.0)
    return UNBOUNDED


def _mix_range(node):
    t, a, b = value_range(node.fac), value_range(node.a), value_range(node.b)
    if node.clamp_factor:
        t = (min(max(t[0], 0.0), 1.0), min(max(t[1], 0.0), 1.0))
    blend = node.blend
    if blend in MULTILINEAR_BLENDS:
        lo, hi = _corners(lambda s, x, y: mix_colors(blend, s, x, y), (t, a, b))
    elif blend == "OVERLAY":
        # Either branch may apply: the union of both (each multilinear).
        pieces = [_corners(lambda s, x, y, f=f: f(s, x, y), (t, a, b)) for f in _OVERLAY_BRANCHES]
        lo, hi = min(p[0] for p in pieces), max(p[1] for p in pieces)
    elif blend in ("DIFFERENCE", "DARKEN", "LIGHTEN"):
        # (1 - t) a + t g with g = |a - b|, min or max, bounded apart.
        g = _blend_operand_range(blend, a, b)
        lo, hi = _corners(lambda s, x, y: (1.0 - s) * x + s * y, (t, a, g))
    else:
        lo, hi = UNBOUNDED
    return (max(lo, 0.0), min(hi, 1.0)) if node.clamp_result else (lo, hi)


_OVERLAY_BRANCHES = (lambda t, a, b: a * (1.0 - t + 2.0 * t * b),
                     lambda t, a, b: 1.0 - (1.0 - t + 2.0 * t * (1.0 - b)) * (1.0 - a))


def _blend_operand_range(blend, a, b):
    if blend == "DARKEN":
        return min(a[0], b[0]), min(a[1], b[1])
    if blend == "LIGHTEN":
        return max(a[0], b[0]), max(a[1], b[1])
    top = max(abs(a[1] - b[0]), abs(b[1] - a[0]))
    return 0.0, top


# ----------------------------------------------------------------------------
# the scene's textures

# Lobe fields whose table array has another name or needs a conversion;
# every other textured field is stored as is into the Lobes array of its name.
ROUGHNESS_FLOOR = 0.1  # a textured glossy lobe must stay glossy in the table



class MaterialTextures:
    """Every texture expression of a scene's materials, compiled.

    ``constants`` is the material list with each expression replaced by a
    constant (so the constant tables build as before); ``apply`` overwrites
    the textured parameters per ray; ``perturb`` replaces shading normals.
    """

    def __init__(self, materials):
        self.compiler = Compiler()
        self.lobe_fields = []    # (material, lobe, field, fn)
        self.emission = {}       # material -> fn
        self.normals = {}        # material -> NormalMap | Bump
        self.sets_normal = set()  # materials whose bump is the smooth normal (a displacement's)
        self.tangents = {}       # material -> fn (its anisotropic lobes' tangent)
        self.constants = [self._constant_material(i, m) for i, m in enumerate(materials)]
        self.any = bool(self.lobe_fields or self.emission)
        self.names = [m.name for m in materials]
        # A Light Path node reads the ray's kind and the path's depths: the
        # integrator then tracks them (Context.light_path).
        self.light_path = any(call.idname == "ShaderNodeLightPath" for call, _ in self.compiler.calls.values())

    def _constant_material(self, i, mat):
        lobes = [self._constant_lobe(i, j, lobe) for j, lobe in enumerate(mat.lobes)]
        emission = mat.emission
        if is_texture(emission):
            fn = self.compiler.color(emission)
            self.emission[i] = fn
            emission = constant_of(fn, True)
            if max(emission) <= 0:
                emission = possible_emission(mat.emission)
        normal = getattr(mat, "normal", None)
        if normal is not None:
            self.normals[i] = self._compile_normal(normal)
            if isinstance(normal, Bump) and getattr(normal, "sets_normal", False) and normal.normal is None:
                self.sets_normal.add(i)
        tangent = getattr(mat, "tangent", None)
        if tangent is not None:
            self.tangents[i] = self.compiler.color(tangent)
        return dataclasses.replace(mat, lobes=tuple(lobes), emission=emission, normal=None, tangent=None)

    def _constant_lobe(self, i, j, lobe):
        lobe = _with_derived_f0(lobe)
        changes = {}
        for f in dataclasses.fields(lobe):
            value = getattr(lobe, f.name)
            if not is_texture(value):
                continue
            fn, is_color = self.compiler.compile(value)
            const = constant_of(fn, is_color)
            if is_color and isinstance(f.default, float):
                const = float(np.dot(const, LUMA))   # a colour in a scalar field: its luminance
            if f.name == "roughness":
                const = max(const, ROUGHNESS_FLOOR)
            self.lobe_fields.append((i, j, f.name, fn, is_color))
            changes[f.name] = const
        return dataclasses.replace(lobe, **changes) if changes else lobe

    def _compile_normal(self, expr):
        if isinstance(expr, NormalMap):
            return ("normal_map", self.compiler.color(expr.color), self.compiler.value(expr.strength),
                    getattr(expr, "space", "TANGENT"))
        if isinstance(expr, Bump):
            inner = None if expr.normal is None else self._compile_normal(expr.normal)
            return ("bump", self.compiler.value(expr.height), self.compiler.value(expr.strength),
                    self.compiler.value(expr.distance), expr.invert, inner, _bump_step(expr),
                    bool(getattr(expr, "undisplaced", False)), getattr(expr, "displacement_space", None),
                    self.compiler.value(getattr(expr, "filter_width", BUMP_FILTER_WIDTH)))
        if isinstance(expr, NodeOutput):
            # A vector node's output (e.g. Bevel): Cycles normalizes it.
            return ("vector", self.compiler.color(expr))
        raise TypeError(f"a material normal must be a NormalMap, Bump or node output, not {type(expr).__name__}")

    # -- per ray -------------------------------------------------------------

    def apply(self, mat, shading, lobes, min_alpha):
        """Overwrite the textured lobe parameters of the rays' materials
        (any Lobe field: colours, roughness, weight, ior, f0, ...) at their
        shading points (a ShadingContext, or (N, 2) UVs)."""
        ctx = as_context(np.zeros((len(mat), 2)) if shading is None else shading)
        at = {}  # material -> (rows, their context): one sub-context per material
        for i, j, name, fn, is_color in self.lobe_fields:
            if i not in at:
                rows = np.nonzero(mat == i)[0]
                at[i] = rows, ctx.take(rows)
            rows, sub = at[i]
            if len(rows):
                _store(lobes, name, rows, j, fn(sub), is_color, min_alpha)

    def emission_at(self, mat, shading, emission):
        """Per-ray emission: the constant table's rows, textured ones evaluated."""
        ctx = as_context(shading)
        for i, fn in self.emission.items():
            rows = np.nonzero(mat == i)[0]
            if len(rows):
                emission = np.array(emission, copy=True)
                emission[rows] = np.clip(_renderable(fn(ctx.take(rows))), 0.0, None)
        return emission

    def tangent_frames(self, mat, shading, ns, tt, bb):
        """The shading frames (tt, bb) of the rays whose material has a
        tangent: tt its tangent made perpendicular to the shading normal ns
        and bb = ns x tt, as Cycles' make_orthonormals_tangent; where the
        tangent is zero, not finite or along ns, the frame is kept.  In place."""
        if not self.tangents:
            return
        ctx = as_context(shading)
        for i, fn in self.tangents.items():
            rows = np.nonzero(mat == i)[0]
            if not len(rows):
                continue
            n = ns[rows]
            t = np.nan_to_num(np.asarray(fn(ctx.take(rows)), dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
            y = np.cross(n, t)
            length = np.linalg.norm(y, axis=1)
            ok = length > 1e-12 * np.maximum(np.linalg.norm(t, axis=1), 1e-300)
            y = y / np.where(ok, length, 1.0)[:, None]
            x = np.cross(y, n)
            tt[rows] = np.where(ok[:, None], x, tt[rows])
            bb[rows] = np.where(ok[:, None], y, bb[rows])

    def normal_is_smooth(self, mat):
        """(N,) rows whose bent normal is also the smooth one (Cycles'
        displacement bump sets sd->N), or None."""
        if not self.sets_normal:
            return None
        return np.isin(mat, list(self.sets_normal))

    def perturb(self, hit, triangles):
        """Shading normals with each material's normal map / bump applied."""
        ctx = ShadingContext.of_hit(triangles, hit)
        ns = hit.ns
        for i, normal in self.normals.items():
            rows = np.nonzero(hit.mat == i)[0]
            if len(rows):
                ns = np.array(ns, copy=True)
                ns[rows] = _perturbed(normal, hit, rows, triangles, ctx.take(rows))
        return ns


# Per-ray values are held to what validation lets constants be (the largest
# radiance Ember renders): a chain of multiplying nodes can reach 1e60 in
# float64, which overflows the float32 film to infinity (and inf - inf to NaN).
MAX_TEXTURE_VALUE = 1e30


def _renderable(value):
    # The clip sends +-inf to +-MAX_TEXTURE_VALUE (as nan_to_num would), so
    # only NaN needs a pass of its own: a third of nan_to_num's cost.
    value = np.clip(value, -MAX_TEXTURE_VALUE, MAX_TEXTURE_VALUE)
    return np.where(np.isnan(value), 0.0, value)


# Lower bounds of textured fields, as the constant tables clamp them.
FIELD_FLOORS = {"color": 0.0, "weight": 0.0, "f0": 0.0, "transmission_tint": 0.0, "ior": 1e-5,
                "thin_film_thickness": 0.0, "thin_film_ior": 1e-5}


# Lobe fields where NaN means "not given" (the Ray Portal's hit point and
# incoming direction, engine/lobes/ray_portal.py): kept NaN, not made 0.
NAN_DEFAULT_FIELDS = ("portal_position", "portal_direction")


def _store(lobes, name, rows, j, value, is_color, min_alpha):
    if name in NAN_DEFAULT_FIELDS:
        value = np.asarray(value, np.float64)
        value = np.where(np.isfinite(value) & (np.abs(value) < MAX_TEXTURE_VALUE), value, np.nan)
        if value.ndim == 1:
            value = np.repeat(value[:, None], 3, axis=1)
        bad = np.isnan(value).any(axis=1)
        value[bad] = np.nan   # one bad component: the whole vector is not given
        getattr(lobes, name)[rows, j] = value
        return
    value = _renderable(value)
    if name == "roughness":
        r = np.clip(value @ LUMA if is_color else value, 0.0, 1.0)
        lobes.alpha[rows, j] = np.maximum(r * r, min_alpha)
        return
    target = getattr(lobes, name)
    if target.ndim == 3 and not is_color:
        value = np.repeat(value[:, None], 3, axis=1)
    elif target.ndim == 2 and is_color:
        value = value @ LUMA
    if name in FIELD_FLOORS:
        value = np.maximum(value, FIELD_FLOORS[name])
    target[rows, j] = value


def _with_derived_f0(lobe):
    """A lobe whose f0 is left to its default (the dielectric F0 of the IOR,
    or the colour) gets that default as an expression when the IOR or colour
    it follows is textured, so f0 follows it per ray."""
    if getattr(lobe, "f0", None) is not None:
        return lobe
    dielectric = getattr(lobe, "fresnel", "none") == "dielectric" or lobe.kind in ("glass", "refraction")
    if dielectric and is_texture(lobe.ior):
        return dataclasses.replace(lobe, f0=f0_of_ior(lobe.ior))
    if not dielectric and is_texture(lobe.color):
        return dataclasses.replace(lobe, f0=lobe.color)
    return lobe


def f0_of_ior(ior):
    """((ior - 1) / (ior + 1))^2 as a texture expression."""
    ratio = Math("DIVIDE", Math("SUBTRACT", ior, 1.0), Math("ADD", ior, 1.0))
    return Math("MULTIPLY", ratio, ratio)


# Cycles' default Filter Width of the Bump node (Blender 4.3+; before, and
# for a displacement's bump, the same constant).
BUMP_FILTER_WIDTH = 0.1


def _bump_step(expr):
    """UV step of the limit bump's central differences (points without a
    ray footprint: surface_gradient): a tenth of a texel of the finest
    image in the height expression, or 1e-4 without images."""
    sizes = [max(np.shape(tile.pixels)[:2]) for img in _images_in(expr.height)
             for tile in (img, *(t for _, t in img.tiles))]
    return 0.1 / max(sizes) if sizes else 1e-4


def _images_in(expr):
    if isinstance(expr, ImageTexture):
        yield expr.image
    if isinstance(expr, NodeOutput):
        for value in expr.call.inputs.values():
            yield from _images_in(value)
    elif is_texture(expr):
        for f in dataclasses.fields(expr):
            value = getattr(expr, f.name)
            if is_texture(value):
                yield from _images_in(value)


# ----------------------------------------------------------------------------
# normal perturbation

def _unit(v, fallback):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    ok = np.isfinite(length) & (length > 1e-12)
    return np.where(ok, v / np.where(ok, length, 1.0), fallback)


def _perturbed(normal, hit, rows, triangles, ctx):
    """New unit shading normals for hit rows, facing the same side as hit.ns;
    also those the viewer sees from behind (the diffuse lobes keep them, the
    others take Cycles' Bump Map Correction: engine/bump_correction.py)."""
    ns = hit.ns[rows]
    return _unit(_evaluate_normal(normal, hit, rows, triangles, ns, ctx), ns)


def _evaluate_normal(normal, hit, rows, triangles, ns, ctx):
    if normal[0] == "vector":
        return normal[1](ctx)
    if normal[0] == "normal_map":
        if normal[3] != "TANGENT":
            return space_normal_map(hit, rows, ns, normal[1], normal[2], normal[3], ctx)
        return normal_map(hit, rows, ns, normal[1], normal[2], ctx)
    _, height, strength, distance, invert, inner, step, undisplaced, space, width = normal
    base = ns if inner is None else _unit(_evaluate_normal(inner, hit, rows, triangles, ns, ctx), ns)
    if undisplaced and inner is None and ctx.prim is not None:
        base = _flat_undisplaced(base, triangles, ctx)
    object_space = space is not None and ctx.prim is not None and ctx.instance[0] is not None
    if _has_footprint(ctx):
        return footprint_bump(height, ctx, base, triangles, (strength(ctx), distance(ctx), invert, width(ctx)),
                              undisplaced, space if object_space else None)
    grad = surface_gradient(height, ctx, step, triangles)
    ng = triangles.ng[ctx.prim] if ctx.prim is not None else None
    if undisplaced and ctx.prim is not None:
        grad, ng = _on_undisplaced(grad, ng, triangles, ctx)
    if object_space and ng is not None:
        return _object_space_bump(base, grad, ng, space, strength(ctx), distance(ctx), invert, ctx)
    return bump(base, grad, strength(ctx), distance(ctx), invert, ng)


def _flat_undisplaced(ns, triangles, ctx):
    """ns, but on flat faces of a "Both" mesh the undisplaced face normal
    (turned to ns' side): Cycles' bump starts from the undisplaced normal
    (svm_node_enter_bump_eval sets sd->N from ATTR_STD_NORMAL_UNDISPLACED),
    and on a flat face ns is the displaced triangle's normal, which the
    relief would then bend a second time (a 2 M-triangle heightmap terrain
    rendered 11 % dark).  Smooth faces keep their undisplaced normals
    already (engine/displacement.py)."""
    shading = getattr(triangles, "shading", None)
    smooth = getattr(triangles, "smooth", None)
    edges = shading.undisplaced_edges(ctx.prim) if shading is not None and smooth is not None else None
    if edges is None:
        return ns
    flat = ~np.asarray(smooth)[ctx.prim]
    if not flat.any():
        return ns
    n0 = _unit(np.cross(edges[0], edges[1]), ns)
    n0 = np.where((np.einsum("ij,ij->i", n0, ns) < 0.0)[:, None], -n0, n0)
    return np.where(flat[:, None], n0, ns)


def _has_footprint(ctx):
    """Points on triangles with a ray footprint (camera paths): Cycles'
    scheme; others (bakes, probes) keep the limit bump."""
    dp = getattr(ctx, "dp", None)
    return dp is not None and ctx.prim is not None and len(dp) > 0 and bool(np.all(np.isfinite(dp) & (dp > 0)))


def footprint_bump(height, ctx, base, triangles, params, undisplaced=False, space=None):
    """Cycles 5.0's bump: the height at P, P + w dPdx and P + w dPdy (w
    the Filter Width, dPdx and dPdy the compact ray differential made
    full, differential_from_compact: dP times make_orthonormals(Ng)), one
    pass through the height's nodes on the three copies of each point;
    then svm_node_set_bump.  ``undisplaced`` ("Both"): the differentials
    are the undisplaced surface's (NODE_ENTER_BUMP_EVAL); ``space`` (a
    "Both" bump, 'OBJECT' or 'WORLD'): the bump is taken in object space
    (use_object_space) on the height dot(D, N)."""
    strength, distance, invert, width = params
    width = np.broadcast_to(np.asarray(width, np.float64), (len(ctx),))
    dx, dy, offsets, moves = _footprint_steps(ctx, width)
    values = height(ctx.shifted_copies([None, *offsets], moves=moves))
    heights = np.asarray(values, np.float64).reshape(-1, 3)
    if undisplaced:
        dx, dy = _undisplaced_differentials(dx, dy, triangles, ctx)
    if space is None:
        return set_bump(base, dx, dy, heights, strength, distance, invert, width)
    shading, inst = ctx.instance
    mt = np.swapaxes(shading.matrix[inst][:, :3, :3], 1, 2)
    inv = shading.inverse[inst][:, :3, :3]
    base_o = np.einsum("nij,nj->ni", mt, base)          # object_inverse_normal_transform
    if space == "OBJECT":
        # dot(D, N) with D = M (h unit(M^T N)): h |M^T N|, the same factor on the three copies.
        heights = heights * np.linalg.norm(base_o, axis=1, keepdims=True)
    dx_o, dy_o = (np.einsum("nij,nj->ni", inv, d) for d in (dx, dy))   # object_inverse_dir_transform
    out_o = set_bump(_unit(base_o, base), dx_o, dy_o, heights, strength, distance, invert, width)
    return ctx.to_world_normal(out_o)


def _footprint_steps(ctx, width):
    """(dx, dy, [w dx, w dy], barycentric moves of the three copies or None)
    from one elementwise kernel (the frame, the steps and their moves
    within each triangle in one pass: a dozen NumPy passes before)."""
    tris = ctx.tris
    on_triangles = ctx.bary is not None and tris is not None
    ng = ctx.ng
    if on_triangles:
        e1, e2 = tris.e1[ctx.prim], tris.e2[ctx.prim]
    else:
        e1 = e2 = np.zeros((len(ctx), 3))
    out = bump_steps(ng[:, 0], ng[:, 1], ng[:, 2], ctx.dp, width, *e1.T, *e2.T)
    dx, dy, ox, oy = (np.stack(out[k:k + 3], axis=1) for k in (0, 3, 6, 9))
    moves = None
    if on_triangles:
        moves = [np.zeros((len(ctx), 2)), np.stack(out[12:14], axis=1), np.stack(out[14:16], axis=1)]
    return dx, dy, [ox, oy], moves


@kernel(11, 16)
def bump_steps(nx, ny, nz, dp, w, ax1, ay1, az1, ax2, ay2, az2):
    """The footprint bump's steps at a point with geometric normal n, ray
    footprint dp, filter width w on a triangle of edges e1, e2: dx = dp a,
    dy = dp b (a, b = make_orthonormals(n): engine.nodes.rays.orthonormal_a), the copies'
    offsets w dx, w dy, and their barycentric moves (context._bary_of_offsets:
    the offset projected on the triangle's plane, zero on a degenerate one)."""
    tx, ty, tz = orthonormal_a(nx, ny, nz)
    bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
    dxx, dxy, dxz, dyx, dyy, dyz = tx * dp, ty * dp, tz * dp, bx * dp, by * dp, bz * dp
    oxx, oxy, oxz, oyx, oyy, oyz = dxx * w, dxy * w, dxz * w, dyx * w, dyy * w, dyz * w
    d00 = ax1 * ax1 + ay1 * ay1 + az1 * az1
    d01 = ax1 * ax2 + ay1 * ay2 + az1 * az2
    d11 = ax2 * ax2 + ay2 * ay2 + az2 * az2
    det = d00 * d11 - d01 * d01
    inv = where(np.abs(det) > 1e-300, 1.0 / where(det != 0, det, 1.0), 0.0)
    ux, vx = _bary_move(oxx, oxy, oxz, ax1, ay1, az1, ax2, ay2, az2, d00, d01, d11, inv)
    uy, vy = _bary_move(oyx, oyy, oyz, ax1, ay1, az1, ax2, ay2, az2, d00, d01, d11, inv)
    return dxx, dxy, dxz, dyx, dyy, dyz, oxx, oxy, oxz, oyx, oyy, oyz, ux, vx, uy, vy


@helper
def _bary_move(ox, oy, oz, ax1, ay1, az1, ax2, ay2, az2, d00, d01, d11, inv):
    d20 = ox * ax1 + oy * ay1 + oz * az1
    d21 = ox * ax2 + oy * ay2 + oz * az2
    return (d11 * d20 - d01 * d21) * inv, (d00 * d21 - d01 * d20) * inv


def set_bump(normal, dx, dy, heights, strength, distance, invert, width):
    """Cycles' svm_node_set_bump (5.0) on rows: heights (N, 3) at the
    centre, the x and the y copy (the elementwise kernel set_bump_rows)."""
    d = -np.asarray(distance, np.float64) if invert else distance
    out = set_bump_rows(*normal.T, *dx.T, *dy.T, *np.asarray(heights, np.float64).T, strength, d, width)
    return np.stack(out, axis=1)


@kernel(15, 3)
def set_bump_rows(nx, ny, nz, dxx, dxy, dxz, dyx, dyy, dyz, hc, hx, hy, strength, distance, width):
    """normalize(w |det| n - d sign(det) g) with g = (h_x - h_c) (dy x n)
    + (h_y - h_c) (n x dx), det = dx . (dy x n), then mixed with n by the
    strength and made unit (textures._unit).  |det| goes as dP^2: normalized
    at any scale (Cycles' safe_normalize); a zero result (no footprint, a
    zero width) keeps n."""
    rxx, rxy, rxz = dyy * nz - dyz * ny, dyz * nx - dyx * nz, dyx * ny - dyy * nx
    ryx, ryy, ryz = ny * dxz - nz * dxy, nz * dxx - nx * dxz, nx * dxy - ny * dxx
    det = dxx * rxx + dxy * rxy + dxz * rxz
    gx, gy = hx - hc, hy - hc
    along, across = width * np.abs(det), distance * np.sign(det)
    ox = along * nx - across * (gx * rxx + gy * ryx)
    oy = along * ny - across * (gx * rxy + gy * ryy)
    oz = along * nz - across * (gx * rxz + gy * ryz)
    ox, oy, oz = _unit_or(ox, oy, oz, nx, ny, nz, 0.0)
    s = np.maximum(strength, 0.0)
    return _unit_or(s * ox + (1.0 - s) * nx, s * oy + (1.0 - s) * ny, s * oz + (1.0 - s) * nz,
                    nx, ny, nz, 1e-12)


@helper
def _unit_or(x, y, z, fx, fy, fz, floor):
    """(x, y, z) made unit, or (fx, fy, fz) where its length is not finite
    or not above floor."""
    length = np.sqrt(x * x + y * y + z * z)
    ok = np.isfinite(length) & (length > floor)
    scale = where(ok, length, 1.0)
    return where(ok, x / scale, fx), where(ok, y / scale, fy), where(ok, z / scale, fz)


def _undisplaced_differentials(dx, dy, triangles, ctx):
    """dPdx, dPdy of the points on the triangles as they were before true
    displacement ("Both": Cycles' NODE_ENTER_BUMP_EVAL differentiates the
    undisplaced position attribute with the displaced hit's du, dv): the
    same barycentric moves along the undisplaced edges."""
    shading = getattr(triangles, "shading", None)
    edges = shading.undisplaced_edges(ctx.prim) if shading is not None else None
    if edges is None:
        return dx, dy
    a, b = edges
    moves = _bary_of_offsets(triangles, ctx.prim, (dx, dy))
    return tuple(m[:, :1] * a + m[:, 1:] * b for m in moves)


def _object_space_bump(base, grad, ng, space, strength, distance, invert, ctx):
    """The displacement bump of "Both" as Cycles' bump_from_displacement
    builds it: svm_node_set_bump with use_object_space (the normal and the
    differentials taken to object space, the result brought back with the
    inverse transpose), on the height dot(D, N) of the world-space
    displacement vector D: for an Object-space Displacement node D = M (h n)
    with n = unit(M^T N), so the height is h |M^T N|; for World space it is
    h.  On an unscaled object both reduce to the world-space bump of h."""
    shading, inst = ctx.instance
    m = shading.matrix[inst][:, :3, :3]
    mt = np.swapaxes(m, 1, 2)
    base_o = np.einsum("nij,nj->ni", mt, base)        # M^T N (object_inverse_normal_transform)
    if space == "OBJECT":
        grad = grad * np.linalg.norm(base_o, axis=1, keepdims=True)
    ng_o = _unit(np.einsum("nij,nj->ni", mt, ng), ng)
    # The height's derivatives along the surface are the same in both spaces
    # (dh = grad_w . M dp_o): grad_o is M^T grad_w, kept in the object plane.
    grad_o = np.einsum("nij,nj->ni", mt, grad)
    grad_o = grad_o - np.einsum("ij,ij->i", grad_o, ng_o)[:, None] * ng_o
    out_o = bump(_unit(base_o, ng_o), grad_o, strength, distance, invert, ng_o)
    return ctx.to_world_normal(out_o)


def _on_undisplaced(grad, ng, triangles, ctx):
    """The height's gradient and the face normal on the triangles as they
    were before true displacement ("Both": Cycles bumps with the undisplaced
    surface's derivatives): the derivatives along the edges (grad . e) are
    the same on both, so grad is rebuilt from the undisplaced edges."""
    shading = getattr(triangles, "shading", None)
    edges = shading.undisplaced_edges(ctx.prim) if shading is not None else None
    if edges is None:
        return grad, ng
    a, b = edges
    du = np.einsum("ij,ij->i", grad, triangles.e1[ctx.prim])
    dv = np.einsum("ij,ij->i", grad, triangles.e2[ctx.prim])
    c = np.cross(a, b)
    cc = np.einsum("ij,ij->i", c, c)
    ok = np.isfinite(cc) & (cc > 1e-30)
    inv = np.where(ok, 1.0 / np.where(ok, cc, 1.0), 0.0)[:, None]
    grad0 = (du[:, None] * np.cross(b, c) + dv[:, None] * np.cross(c, a)) * inv
    ng0 = c * np.sqrt(inv)
    return np.where(ok[:, None], grad0, grad), np.where(ok[:, None], ng0, ng)


def normal_map(hit, rows, ns, color_fn, strength_fn, ctx):
    """Cycles' tangent-space svm_node_normal_map (5.0): the strength scales
    the tangential part, the frame is (tangent, sign * n x tangent, n) with n
    the front-facing normal; back-facing hits flip the result."""
    c = 2.0 * (color_fn(ctx) - 0.5)
    s = strength_fn(ctx)
    c[:, 0] *= s
    c[:, 1] *= s
    c[:, 2] = 1.0 + (c[:, 2] - 1.0) * np.clip(s, 0.0, 1.0)
    tangent = getattr(hit, "tangent", None)
    if tangent is None:
        return ns  # no UVs: Cycles leaves the normal as is
    back = hit.back[rows] if getattr(hit, "back", None) is not None else np.zeros(len(rows), bool)
    flip = np.where(back, -1.0, 1.0)[:, None]
    n = ns * flip
    t = tangent[rows]
    b = hit.tangent_sign[rows][:, None] * np.cross(n, t)
    out = c[:, :1] * t + c[:, 1:2] * b + c[:, 2:3] * n
    return out * flip


def space_normal_map(hit, rows, ns, color_fn, strength_fn, space, ctx):
    """Cycles' object- and world-space svm_node_normal_map: the colour is
    the normal (Blender's variants negate y and z), object space goes
    through the object's normal matrix, back faces flip it, and a strength
    other than 1 blends linearly from the shading normal."""
    c = 2.0 * (color_fn(ctx) - 0.5)
    if space.startswith("BLENDER_"):
        c[:, 1:] = -c[:, 1:]
    n = ctx.to_world_normal(c) if space.endswith("OBJECT") else _unit(c, ns)
    back = hit.back[rows] if getattr(hit, "back", None) is not None else np.zeros(len(rows), bool)
    n = np.where(back[:, None], -n, n)
    s = np.maximum(strength_fn(ctx), 0.0)[:, None]
    mixed = _unit(ns + (n - ns) * s, ns)
    return np.where(s == 1.0, n, mixed)


def surface_gradient(height_fn, ctx, uv_step, triangles):
    """World-space surface gradient of the height at the context's points:
    finite differences along two unit directions in each triangle's plane,
    the point moved in position (so procedural heights of P, Generated or
    Object coordinates and image heights of UV alike follow it).  The step
    is uv_step in UV (a tenth of the finest texel) where UVs vary, else
    1e-3 of the triangle's size; central differences keep float32 node
    arithmetic (about 1e-7) from dominating the slope."""
    prim = ctx.prim
    if prim is None:
        grad_u, grad_v = np.tile([1.0, 0.0, 0.0], (len(ctx), 1)), np.tile([0.0, 1.0, 0.0], (len(ctx), 1))
        t1, t2, h = grad_u, grad_v, np.full(len(ctx), uv_step)
    else:
        ng = triangles.ng[prim]
        t1 = _unit(triangles.e1[prim], ng)
        t2 = np.cross(ng, t1)
        grad_u, grad_v = uv_gradients(triangles, prim)
        uv_rate = np.maximum(np.linalg.norm(grad_u, axis=1), np.linalg.norm(grad_v, axis=1))
        size = np.sqrt(triangles.area[prim])
        h = np.where(uv_rate > 0, uv_step / np.where(uv_rate > 0, uv_rate, 1.0), 1e-3 * size)
        h = np.clip(h, 1e-7 * (1.0 + np.abs(ctx.p).max(axis=1)), np.maximum(size, 1e-12))
    # The four moved copies in one evaluation of the height: one pass
    # through its nodes instead of four (per-node overhead, small batches).
    s1, s2 = t1 * h[:, None], t2 * h[:, None]
    n = len(ctx)
    values = height_fn(ctx.shifted_pairs((s1, s2))) if n else np.zeros(0)
    up1, down1, up2, down2 = (values[k::4] for k in range(4))   # a point's four copies are consecutive
    d1, d2 = (up1 - down1) / (2.0 * h), (up2 - down2) / (2.0 * h)
    return d1[:, None] * t1 + d2[:, None] * t2


def uv_gradients(triangles, prim):
    """World-space gradients of u and v over triangles (0 without UVs or on
    triangles whose UVs are degenerate)."""
    n = len(prim)
    if triangles.uv is None:
        return np.zeros((n, 3)), np.zeros((n, 3))
    e1, e2 = triangles.e1[prim], triangles.e2[prim]
    c = triangles.uv[prim]
    d1, d2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    # Gram matrix of the edges; gradient of f = [e1 e2] M^-1 [df1, df2].
    m11, m12, m22 = (np.einsum("ij,ij->i", e1, e1), np.einsum("ij,ij->i", e1, e2),
                     np.einsum("ij,ij->i", e2, e2))
    det = m11 * m22 - m12 * m12
    ok = np.abs(det) > 1e-30
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)

    def grad(f1, f2):
        a = (m22 * f1 - m12 * f2) * inv
        b = (m11 * f2 - m12 * f1) * inv
        return a[:, None] * e1 + b[:, None] * e2
    return grad(d1[:, 0], d2[:, 0]), grad(d1[:, 1], d2[:, 1])


def bump(normal, grad, strength, distance, invert, ng=None):
    """Cycles' svm_node_set_bump in the limit of small differentials:
    n' = normalize(n - distance * g), then mixed with n by strength.  g has
    the height's derivatives along the surface, and is perpendicular to the
    incoming normal n, as Cycles' surface gradient (dPdy x n, n x dPdx) /
    det is: grad (in the triangle's plane, perpendicular to ng) moved along
    ng when n is tilted (a smooth normal, a displacement's or an inner
    bump's)."""
    d = -distance if invert else distance
    if ng is not None:
        cos = np.einsum("ij,ij->i", ng, normal)
        ok = np.abs(cos) > 1e-6
        shift = np.where(ok, np.einsum("ij,ij->i", grad, normal) / np.where(ok, cos, 1.0), 0.0)
        grad = grad - shift[:, None] * ng
    bumped = _unit(normal - d[:, None] * grad, normal)
    s = np.maximum(strength, 0.0)[:, None]
    return s * bumped + (1.0 - s) * normal
