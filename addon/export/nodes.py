"""Input and texture nodes -> constants or engine texture expressions.

``SocketReader.read(socket)`` follows a linked input through RGB, Value,
Image Texture (with UV Map / Texture Coordinate UV vectors), Mix (colour and
float) / legacy MixRGB, and Math nodes.  The result is a constant (float or
RGB tuple) or an ``engine.scene`` texture expression.  A node it cannot
translate gives None: the caller uses the socket's own constant and names the
input in its warning.  ``scale``, ``add``, ``mix``, ``clamp01``, ``math``,
``multiply`` and ``one_minus`` combine constants and expressions alike, so
closure weighting works on both; ``may_exceed`` / ``may_be_below`` decide
from an expression's range whether a lobe can be present.
"""
from . import images

LUMA = (0.2126, 0.7152, 0.0722)
# Image Texture interpolations Ember renders as Linear (Cycles: bicubic).
CUBIC = ('Cubic', 'Smart')


def _scene():
    from .. import backend
    return backend.scene_module()


def is_expr(value):
    return isinstance(value, _scene().TEXTURE_TYPES)


def luminance(color):
    return sum(float(c) * w for c, w in zip(color, LUMA))


# ----------------------------------------------------------------------------
# arithmetic on constants or expressions

def scale(color, weight):
    if is_expr(color) or is_expr(weight):
        return _scene().MixColor('MULTIPLY', 1.0, color, weight, clamp_factor=False)
    return tuple(float(c) * float(weight) for c in color)


def add(a, b):
    if is_expr(a) or is_expr(b):
        return _scene().MixColor('ADD', 1.0, a, b, clamp_factor=False)
    return tuple(float(x) + float(y) for x, y in zip(a, b))


def mix(a, b, t):
    if is_expr(a) or is_expr(b) or is_expr(t):
        return _scene().MixColor('MIX', t, a, b, clamp_factor=False)
    return tuple((1.0 - t) * float(x) + t * float(y) for x, y in zip(a, b))


def clamp01(value):
    if is_expr(value):
        return _scene().Math('ADD', value, 0.0, clamp=True)
    return min(max(float(value), 0.0), 1.0)


# Float operations on constants (exactly as Python computes them, so a
# constant input keeps today's numbers) or, with an expression among the
# operands, as a Math expression evaluated per ray.
_FLOAT_OPS = {
    'ADD': lambda a, b: a + b, 'SUBTRACT': lambda a, b: a - b, 'MULTIPLY': lambda a, b: a * b,
    'DIVIDE': lambda a, b: a / b if b != 0 else 0.0, 'MINIMUM': min, 'MAXIMUM': max,
    'LESS_THAN': lambda a, b: float(a < b), 'SQRT': lambda a, b: a ** 0.5 if a > 0 else 0.0,
}


def math(op, a, b=0.0):
    if is_expr(a) or is_expr(b):
        return _scene().Math(op, a, b)
    return _FLOAT_OPS[op](float(a), float(b))


def multiply(a, b):
    """a * b for float weights; a factor 1 leaves the other operand as is."""
    if not is_expr(a) and float(a) == 1.0:
        return b if is_expr(b) else float(b)
    if not is_expr(b) and float(b) == 1.0:
        return a if is_expr(a) else float(a)
    return math('MULTIPLY', a, b)


def one_minus(value):
    return math('SUBTRACT', 1.0, value)


def at_least(value, low):
    return math('MAXIMUM', value, low)


def as_value(value):
    """A colour expression used as a float input: its luminance (Cycles'
    colour-to-float conversion), made explicit so that a float lobe field
    (e.g. a coat weight stored as a grey colour) does not keep the hue."""
    scene = _scene()
    colour = isinstance(value, scene.MixColor) or (
        isinstance(value, scene.ImageTexture) and value.output == 'Color')
    return scene.Math('ADD', value, 0.0) if colour else value


def value_range(value):
    """(lo, hi) a constant or expression can take (engine.textures)."""
    from .. import backend
    return backend.load('textures').value_range(value)


def may_exceed(value, level):
    """Whether value > level somewhere: ``value > level`` for a constant."""
    if not is_expr(value):
        return float(value) > level
    return value_range(value)[1] > level


def may_be_below(value, level):
    """Whether value < level somewhere: ``value < level`` for a constant."""
    if not is_expr(value):
        return float(value) < level
    return value_range(value)[0] < level


# ----------------------------------------------------------------------------
# reading sockets

class SocketReader:
    """Translates the node tree behind input sockets of one material.

    linked_node(socket) -> (node, output socket) skips reroutes and muted
    links (NodeTranslator._linked_node).  Notes go to ``unsupported`` (node
    labels) and ``warnings`` (sentences, e.g. a missing image)."""

    def __init__(self, linked_node, image_cache=None):
        self.linked_node = linked_node
        self.images = {} if image_cache is None else image_cache
        self.unsupported = []
        self.warnings = []

    def read(self, socket):
        """Constant or expression for an input socket (its own default when
        unlinked); None if something linked cannot be translated."""
        node, out = self.linked_node(socket)
        if node is None:
            return constant(socket)
        if node.mute:
            return self._unsupported(node)
        handler = getattr(self, '_node_' + node.type.lower(), None)
        if handler is None:
            return self._unsupported(node)
        return handler(node, out)

    def input(self, node, name_or_index):
        """Reads a node's input; an untranslatable source counts as its default."""
        socket = _input(node, name_or_index)
        value = self.read(socket)
        return constant(socket) if value is None else value

    def _unsupported(self, node):
        label = f"'{node.name}' ({node.bl_idname})"
        if label not in self.unsupported:
            self.unsupported.append(label)
        return None

    # -- input nodes -----------------------------------------------------------

    def _node_rgb(self, node, out):
        return tuple(float(c) for c in out.default_value[:3])

    def _node_value(self, node, out):
        return float(out.default_value)

    def _node_tex_image(self, node, out):
        scene = _scene()
        if getattr(node, 'projection', 'FLAT') != 'FLAT':
            return self._unsupported(node)
        image = self._image(node)
        if image is None:
            return (1.0, 1.0, 1.0) if out.name == 'Alpha' else (1.0, 0.0, 1.0)
        interpolation = node.interpolation
        if interpolation in CUBIC:
            self._note(f"'{node.name}' {interpolation} interpolation rendered as Linear")
            interpolation = 'Linear'
        alpha_out = node.outputs.get('Alpha')
        unassociate = bool(alpha_out is not None and alpha_out.is_linked and not image.data
                           and image.alpha_mode not in ('CHANNEL_PACKED', 'NONE'))
        return scene.ImageTexture(image, interpolation, node.extension,
                                  'Alpha' if out.name == 'Alpha' else 'Color', unassociate,
                                  self._vector(node))

    def _vector(self, node):
        """None (the active UV map) for UV inputs Ember knows."""
        source, out = self.linked_node(node.inputs['Vector'])
        if source is None:
            return None
        if source.type == 'TEX_COORD' and out.name == 'UV':
            return None
        if source.type == 'UVMAP':
            if source.uv_map:
                self._note(f"'{source.name}' UV map '{source.uv_map}' read as the active UV map")
            return None
        self._unsupported(source)
        return None

    def _image(self, node):
        """engine TextureImage for the node's image (loaded once per image),
        or None for none or a missing file (magenta, as Cycles)."""
        scene = _scene()
        bpy_image = node.image
        if bpy_image is None:
            self._note(f"'{node.name}' has no image: rendered magenta")
            return None
        key = bpy_image.as_pointer()
        if key not in self.images:
            pixels, warnings = images.load_image(bpy_image)
            if images.is_missing(pixels, warnings):
                self.images[key] = (None, warnings)
            else:
                self.images[key] = (scene.TextureImage(
                    pixels, bpy_image.name, images.srgb_filtered(bpy_image),
                    _alpha_mode(bpy_image), images.is_data(bpy_image)), warnings)
        image, warnings = self.images[key]
        for warning in warnings:
            self._note(warning)
        return image

    def _note(self, text):
        if text not in self.warnings:
            self.warnings.append(text)

    # -- colour and math -------------------------------------------------------

    def _node_mix(self, node, out):
        """The Mix node (3.4+): colour and float modes."""
        data_type = getattr(node, 'data_type', 'RGBA')
        if data_type == 'RGBA':
            a, b = self.input(node, 'A_Color'), self.input(node, 'B_Color')
        elif data_type == 'FLOAT':
            a, b = self.input(node, 'A_Float'), self.input(node, 'B_Float')
        else:
            return self._unsupported(node)
        blend = node.blend_type if data_type == 'RGBA' else 'MIX'
        if blend not in _scene().MIX_BLENDS:
            return self._unsupported(node)
        return self._mix_color(blend, self.input(node, 'Factor_Float'), a, b,
                               node.clamp_factor, data_type == 'RGBA' and node.clamp_result)

    def _node_mix_rgb(self, node, out):
        """The legacy MixRGB node: the factor is always clamped."""
        if node.blend_type not in _scene().MIX_BLENDS:
            return self._unsupported(node)
        return self._mix_color(node.blend_type, self.input(node, 'Fac'), self.input(node, 'Color1'),
                               self.input(node, 'Color2'), True, node.use_clamp)

    def _mix_color(self, blend, fac, a, b, clamp_factor, clamp_result):
        return _scene().MixColor(blend, fac, _as_color(a), _as_color(b), clamp_factor, clamp_result)

    def _node_math(self, node, out):
        if node.operation not in _scene().MATH_OPERATIONS:
            return self._unsupported(node)
        a, b, c = (self.input(node, i) for i in range(3))
        return _scene().Math(node.operation, _as_value(a), _as_value(b), _as_value(c), node.use_clamp)

    # -- normals ---------------------------------------------------------------

    def normal(self, socket):
        """NormalMap / Bump expression behind a BSDF's Normal input, or None."""
        node, _ = self.linked_node(socket)
        if node is None:
            return None
        scene = _scene()
        if node.type == 'NORMAL_MAP' and not node.mute:
            if node.space != 'TANGENT':
                self._note(f"'{node.name}' {node.space.lower()}-space normal map is not rendered yet")
                return None
            if node.uv_map:
                self._note(f"'{node.name}' UV map '{node.uv_map}' read as the active UV map")
            return scene.NormalMap(self.input(node, 'Color'), _as_value(self.input(node, 'Strength')))
        if node.type == 'BUMP' and not node.mute:
            inner = self.normal(node.inputs['Normal']) if node.inputs['Normal'].is_linked else None
            return scene.Bump(_as_value(self.input(node, 'Height')),
                              _as_value(self.input(node, 'Strength')),
                              _as_value(self.input(node, 'Distance')), bool(node.invert), inner)
        self._unsupported(node)
        return None


def _input(node, name_or_index):
    if isinstance(name_or_index, int):
        return node.inputs[name_or_index]
    for socket in node.inputs:
        if socket.identifier == name_or_index:
            return socket
    return node.inputs[name_or_index]


def constant(socket):
    """An unlinked socket's value: float, or RGB for colour and vector sockets."""
    value = getattr(socket, 'default_value', 0.0)
    if isinstance(value, (float, int)):
        return float(value)
    return tuple(float(c) for c in tuple(value)[:3])


def _as_color(value):
    return (float(value),) * 3 if isinstance(value, (float, int)) else value


def _as_value(value):
    return luminance(value) if isinstance(value, tuple) else value


def _alpha_mode(bpy_image):
    mode = getattr(bpy_image, 'alpha_mode', 'STRAIGHT')
    return mode if mode in ('STRAIGHT', 'PREMUL', 'CHANNEL_PACKED', 'NONE') else 'STRAIGHT'


def output_node(tree, output_type):
    """The output node Cycles would use ('OUTPUT_MATERIAL' or 'OUTPUT_WORLD'):
    Blender's choice for Cycles, else the active (or first) node of the type."""
    try:
        node = tree.get_output_node('CYCLES')
    except (AttributeError, TypeError):
        node = None
    if node is None:
        outputs = [n for n in tree.nodes if n.type == output_type]
        node = next((n for n in outputs if getattr(n, 'is_active_output', False)),
                    outputs[0] if outputs else None)
    return node
