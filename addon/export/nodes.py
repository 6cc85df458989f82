"""Input and texture nodes -> constants or engine texture expressions.

``SocketReader.read(socket)`` follows a linked input through RGB, Value,
Image Texture (with UV Map / Texture Coordinate UV vectors), Environment
Texture (its Vector a direction), Mix (colour and float) / legacy MixRGB,
and Math nodes.  The result is a constant (float or RGB tuple) or an
``engine.scene`` texture expression.  A node it cannot translate gives None:
the caller uses the socket's own constant and names the input in its
warning.  ``scale``, ``add``, ``mix``, ``clamp01``, ``math``, ``multiply``
and ``one_minus`` combine constants and expressions alike, so closure
weighting works on both; ``may_exceed`` / ``may_be_below`` decide from an
expression's range whether a lobe can be present.
"""
import bpy

from .. import backend
from . import images

LUMA = (0.2126, 0.7152, 0.0722)
# Image Texture interpolations Ember renders as Linear (Cycles: bicubic).
CUBIC = ('Cubic', 'Smart')


def is_expr(value):
    return isinstance(value, backend.engine().TEXTURE_TYPES)


def luminance(color):
    return sum(float(c) * w for c, w in zip(color, LUMA))


# ----------------------------------------------------------------------------
# arithmetic on constants or expressions

def scale(color, weight):
    if is_expr(color) or is_expr(weight):
        return backend.engine().MixColor('MULTIPLY', 1.0, color, weight, clamp_factor=False)
    return tuple(float(c) * float(weight) for c in color)


def add(a, b):
    if is_expr(a) or is_expr(b):
        return backend.engine().MixColor('ADD', 1.0, a, b, clamp_factor=False)
    return tuple(float(x) + float(y) for x, y in zip(a, b))


def mix(a, b, t):
    if is_expr(a) or is_expr(b) or is_expr(t):
        return backend.engine().MixColor('MIX', t, a, b, clamp_factor=False)
    return tuple((1.0 - t) * float(x) + t * float(y) for x, y in zip(a, b))


def clamp01(value):
    if is_expr(value):
        return backend.engine().Math('ADD', value, 0.0, clamp=True)
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
        return backend.engine().Math(op, a, b)
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
    renderer = backend.engine()
    colour = isinstance(value, renderer.MixColor) or (
        isinstance(value, renderer.ImageTexture) and value.output == 'Color')
    return renderer.Math('ADD', value, 0.0) if colour else value


def value_range(value):
    """(lo, hi) a constant or expression can take (engine.textures)."""
    return backend.engine().value_range(value)


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
# following links: reroutes, muted links, node groups

class SocketList:
    """A node's inputs or outputs seen inside node groups (list and name access)."""

    def __init__(self, sockets, path):
        self._sockets = sockets
        self._path = path

    def __getitem__(self, key):
        return InGroup(self._sockets[key], self._path)

    def get(self, key, default=None):
        socket = self._sockets.get(key)
        return default if socket is None else InGroup(socket, self._path)

    def __contains__(self, key):
        return key in self._sockets

    def __iter__(self):
        return (InGroup(s, self._path) for s in self._sockets)

    def __reversed__(self):
        return (InGroup(s, self._path) for s in reversed(list(self._sockets)))

    def __len__(self):
        return len(self._sockets)


class InGroup:
    """A node or socket inside node groups: ``path`` holds the group nodes
    from the outermost in, so a Group Input leads back to the right instance."""

    def __init__(self, target, path):
        self.__dict__['_target'] = target
        self.__dict__['_path'] = path

    def __getattr__(self, name):
        if name in ('inputs', 'outputs'):
            return SocketList(getattr(self._target, name), self._path)
        return getattr(self._target, name)

    def __eq__(self, other):
        return isinstance(other, InGroup) and self._target == other._target and self._path == other._path

    def __hash__(self):
        return hash((self._target.as_pointer(), tuple(g.as_pointer() for g in self._path)))


class GroupDefault:
    """Stands for an unlinked input of a group node read from inside the
    group: its value is that input's own (readers use ``constant``)."""
    type = 'GROUP_DEFAULT'
    mute = False
    bl_idname = 'NodeGroupInput'

    def __init__(self, socket):
        self.socket = socket
        self.name = getattr(socket, 'name', 'Group Input')


def _raw(item):
    return item._target if isinstance(item, InGroup) else item


def _wrap(item, path):
    return InGroup(item, path) if path else item


def group_output_node(tree):
    outputs = [n for n in tree.nodes if n.type == 'GROUP_OUTPUT']
    return next((n for n in outputs if getattr(n, 'is_active_output', False)), outputs[0] if outputs else None)


def _by_identifier(sockets, identifier):
    for socket in sockets:
        if socket.identifier == identifier:
            return socket
    return None


def linked_node(socket):
    """(node, output socket) feeding ``socket``: reroutes and muted or
    invalid links skipped, node groups entered (nested, each instance with
    its own inputs) and left again at their Group Input.  (None, None) when
    nothing is linked; (GroupDefault, socket) for an unlinked group input."""
    path = getattr(socket, '_path', ())
    raw = _raw(socket)
    for _ in range(10000):   # bounded: a malformed tree cannot loop forever
        if not raw.is_linked:
            return None, None
        link = raw.links[0]
        if getattr(link, 'is_muted', False) or not getattr(link, 'is_valid', True):
            return None, None
        node, out = link.from_node, link.from_socket
        if node.type == 'REROUTE':
            raw = node.inputs[0]
            continue
        if node.type == 'GROUP' and not node.mute:
            tree = node.node_tree
            inner_out = group_output_node(tree) if tree is not None else None
            inner = _by_identifier(inner_out.inputs, out.identifier) if inner_out is not None else None
            if inner is None:
                return None, None
            path, raw = path + (node,), inner
            continue
        if node.type == 'GROUP_INPUT':
            if not path:
                return None, None
            group, path = path[-1], path[:-1]
            outer = _by_identifier(group.inputs, out.identifier)
            if outer is None:
                return None, None
            if not outer.is_linked:
                return GroupDefault(_wrap(outer, path)), _wrap(outer, path)
            raw = outer
            continue
        return _wrap(node, path), _wrap(out, path)
    return None, None


def muted_source(node, out):
    """The input a muted node passes to ``out`` (Blender's internal links,
    as Cycles), or None."""
    path = getattr(node, '_path', ())
    raw_out = _raw(out)
    for link in getattr(_raw(node), 'internal_links', ()):
        if link.to_socket.identifier == raw_out.identifier:
            return _wrap(link.from_socket, path)
    return None


# ----------------------------------------------------------------------------
# reading sockets

class SocketReader:
    """Translates the node tree behind input sockets of one material.

    linked_node(socket) -> (node, output socket) skips reroutes and muted
    links (NodeTranslator._linked_node).  Notes go to ``unsupported`` (node
    labels) and ``warnings`` (sentences, e.g. a missing image)."""

    def __init__(self, linked_node=None, image_cache=None):
        self.linked_node = linked_node or globals()['linked_node']
        self.images = {} if image_cache is None else image_cache
        self.unsupported = []
        self.warnings = []
        self.calls = {}   # (node, group path) -> NodeCall: outputs of one node share it

    def read(self, socket):
        """Constant or expression for an input socket (its own default when
        unlinked); None if something linked cannot be translated."""
        node, out = self.linked_node(socket)
        if node is None:
            return constant(socket)
        if node.type == 'GROUP_DEFAULT':
            return constant(out)
        if node.mute:
            source = muted_source(node, out)
            return _zero(out) if source is None else self.input_value(source)
        handler = getattr(self, '_node_' + node.type.lower(), None)
        if handler is not None:
            return handler(node, out)
        entry = _registry().get(node.bl_idname)
        if entry is not None:
            return self._registered(node, out, entry)
        return self._unsupported(node)

    def input_value(self, socket):
        value = self.read(socket)
        return constant(socket) if value is None else value

    # -- registered nodes (engine.nodes.REGISTRY) ------------------------------

    def _registered(self, node, out, entry):
        output = _match_output(entry, out)
        if output is None:
            self._note(f"'{node.name}' output '{out.name}' is not rendered yet")
            return self._unsupported(node)
        key = (_raw(node).as_pointer(), tuple(g.as_pointer() for g in getattr(node, '_path', ())))
        call = self.calls.get(key)
        if call is None:
            call = self._call(node, entry)
            self.calls[key] = call
        reason = entry.accepts(call.props) if entry.accepts is not None else None
        if reason:
            self._note(f"'{node.name}' {reason}")
            return self._unsupported(node)
        used = call.props.setdefault('_outputs', [])
        if output not in used:
            used.append(output)
        return backend.engine().NodeOutput(call, output)

    def _call(self, node, entry):
        inputs = {}
        for identifier, kind in entry.inputs:
            socket = _find_input(node, identifier)
            if socket is None:
                continue
            if not socket.is_linked and identifier in ('Vector', 'Normal') and (
                    entry.coords is not None or identifier == 'Normal'):
                continue   # the engine's default (texture coordinates, the shading normal)
            inputs[identifier] = _as_kind(self.input_value(socket), kind, self._source_is_vector(socket))
        props = {name: _prop(getattr(node, name, default)) for name, default in entry.props}
        # Some kernels changed between Blender versions (Voronoi's cell hash).
        props['_blender_version'] = _blender_version()
        if entry.translate is not None:
            props.update(entry.translate(_raw(node)))
        mapping = _texture_mapping(node, entry, inputs.get('Vector'))
        if mapping is not None:
            inputs['Vector'] = mapping
        return backend.engine().NodeCall(node.bl_idname, inputs, props)

    def _source_is_vector(self, socket):
        source, out = self.linked_node(socket)
        return out is not None and getattr(out, 'type', '') == 'VECTOR'

    def input(self, node, name_or_index):
        """Reads a node's input; an untranslatable source counts as its default."""
        socket = _input(node, name_or_index)
        value = self.read(socket)
        return constant(socket) if value is None else value

    def value_input(self, node, name_or_index):
        """A node's float input as a float or float expression: a colour
        constant (an RGB node, a missing image's magenta, a muted colour
        node's zero) becomes its luminance and a vector one its average, as
        Cycles converts a link into a float socket."""
        socket = _input(node, name_or_index)
        value = _as_kind(self.input(node, name_or_index), 'float', self._source_is_vector(socket))
        return as_value(value)

    def _filter_width(self, node):
        """The Bump node's Filter Width (Blender 4.3+) as a constant: Cycles
        moves the height's copies by the socket's value (a link is not
        followed there), clamped at 0 here (a negative width would flip the
        bent normal)."""
        socket = node.inputs['Filter Width']
        if socket.is_linked:
            self._note(f"'{node.name}' Filter Width: its link is not read (the socket's value {socket.default_value:g})")
        width = float(socket.default_value)
        return max(width, 0.0) if width == width else 0.1

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
        renderer = backend.engine()
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
        return renderer.ImageTexture(image, interpolation, node.extension,
                                  'Alpha' if out.name == 'Alpha' else 'Color', unassociate,
                                  self._vector(node))

    def _node_tex_environment(self, node, out):
        """The Environment Texture on a surface: its Vector (unlinked: the
        world position, Cycles' LINK_POSITION) as a direction, projected
        equirectangular or mirror ball; REPEAT, and the Color stays
        associated even with Alpha linked (svm_node_tex_environment has no
        unassociate flag)."""
        renderer = backend.engine()
        image = self._image(node)
        if image is None:
            return (1.0, 1.0, 1.0) if out.name == 'Alpha' else (1.0, 0.0, 1.0)
        if image.tiles:
            self._note(f"'{node.name}' tiled image read as its first tile")
            image = renderer.TextureImage(image.pixels, image.name, image.srgb_filter, image.alpha_mode, image.data)
        interpolation = node.interpolation
        if interpolation in CUBIC:
            self._note(f"'{node.name}' {interpolation} interpolation rendered as Linear")
            interpolation = 'Linear'
        return renderer.ImageTexture(image, interpolation, 'REPEAT', 'Alpha' if out.name == 'Alpha' else 'Color',
                                     False, self._environment_vector(node), projection=node.projection)

    def _environment_vector(self, node):
        """None (the world position) when unlinked, else the vector read;
        the hidden texture mapping applied to either."""
        socket = node.inputs['Vector']
        source, _ = self.linked_node(socket)
        if source is None:
            return _texture_mapping(node, _POSITION, None)
        vector = self.read(socket)
        if vector is None:
            return None
        return _texture_mapping(node, None, vector) or vector

    def _vector(self, node):
        """None (the active UV map) when unlinked or fed by the UV output of
        a Texture Coordinate node; else the vector expression (UV Map by
        name, Mapping, procedural coordinates, ...)."""
        socket = node.inputs['Vector']
        source, out = self.linked_node(socket)
        if source is None:
            return _texture_mapping(node, None, None)
        if source.type == 'TEX_COORD' and out.name == 'UV' and getattr(source, 'object', None) is None:
            vector = None
        else:
            vector = self.read(socket)
            if vector is None:
                return None
        return _texture_mapping(node, None, vector) or vector

    def _image(self, node):
        """engine TextureImage for the node's image (loaded once per image),
        or None for none or a missing file (magenta, as Cycles)."""
        renderer = backend.engine()
        bpy_image = node.image
        if bpy_image is None:
            self._note(f"'{node.name}' has no image: rendered magenta")
            return None
        key = bpy_image.as_pointer()
        if key not in self.images:
            self.images[key] = _tiled_image(bpy_image) if images.is_tiled(bpy_image) else _image(bpy_image)
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
            return self._registered(node, out, _registry()['ShaderNodeMix'])
        blend = node.blend_type if data_type == 'RGBA' else 'MIX'
        if blend not in backend.engine().MIX_BLENDS:
            return self._unsupported(node)
        return self._mix_color(blend, self.input(node, 'Factor_Float'), a, b,
                               node.clamp_factor, data_type == 'RGBA' and node.clamp_result)

    def _node_mix_rgb(self, node, out):
        """The legacy MixRGB node: the factor is always clamped."""
        if node.blend_type not in backend.engine().MIX_BLENDS:
            return self._unsupported(node)
        return self._mix_color(node.blend_type, self.input(node, 'Fac'), self.input(node, 'Color1'),
                               self.input(node, 'Color2'), True, node.use_clamp)

    def _mix_color(self, blend, fac, a, b, clamp_factor, clamp_result):
        return backend.engine().MixColor(blend, fac, _as_color(a), _as_color(b), clamp_factor, clamp_result)

    def _node_math(self, node, out):
        if node.operation not in backend.engine().MATH_OPERATIONS:
            return self._unsupported(node)
        a, b, c = (self.input(node, i) for i in range(3))
        return backend.engine().Math(node.operation, _as_value(a), _as_value(b), _as_value(c), node.use_clamp)

    # -- normals ---------------------------------------------------------------

    def normal(self, socket):
        """NormalMap / Bump expression behind a BSDF's Normal input, or None."""
        node, _ = self.linked_node(socket)
        if node is None:
            return None
        renderer = backend.engine()
        if node.type == 'NORMAL_MAP' and not node.mute:
            if node.space == 'TANGENT' and node.uv_map:
                self._note(f"'{node.name}' UV map '{node.uv_map}' read as the active UV map")
            return renderer.NormalMap(self.input(node, 'Color'), self.value_input(node, 'Strength'), node.space)
        if node.type == 'BUMP' and not node.mute:
            inner = self.normal(node.inputs['Normal']) if node.inputs['Normal'].is_linked else None
            bump = renderer.Bump(self.value_input(node, 'Height'), self.value_input(node, 'Strength'),
                                 self.value_input(node, 'Distance'), bool(node.invert), inner)
            if 'Filter Width' in node.inputs and hasattr(bump, 'filter_width'):
                bump.filter_width = self._filter_width(node)
            return bump
        value = self.read(socket)
        if isinstance(value, renderer.NodeOutput) and _registry()[value.call.idname].output_kind(value.output) == 'vector':
            return value   # a vector node (e.g. Bevel): the normal itself, normalized by the engine
        self._unsupported(node)
        return None


def _image(bpy_image):
    """(engine TextureImage or None for a missing file, warnings)."""
    pixels, mode, warnings = images.load_texture(bpy_image)
    if images.is_missing(pixels, warnings):
        return None, warnings
    return backend.engine().TextureImage(pixels, bpy_image.name, images.srgb_filtered(bpy_image), mode,
                                         images.is_data(bpy_image)), warnings


def _tiled_image(bpy_image):
    """A UDIM image: every tile its own TextureImage (a tile that cannot be
    read is magenta, Cycles' missing-texture colour, there only)."""
    renderer = backend.engine()
    tiles, warnings = [], []
    for number, pixels, srgb_filter, mode, notes in images.load_tiles(bpy_image):
        tiles.append((number, renderer.TextureImage(pixels, f'{bpy_image.name} tile {number}', srgb_filter,
                                                    mode, images.is_data(bpy_image))))
        warnings += notes
    if not tiles:
        return None, [f"Image '{bpy_image.name}' is tiled but has no tiles: rendered magenta"]
    first = tiles[0][1]
    return renderer.TextureImage(first.pixels, bpy_image.name, first.srgb_filter, first.alpha_mode, first.data,
                                 tuple(tiles)), warnings


class _POSITION:
    """Stands for a registry entry whose default coordinates are the world
    position (for _texture_mapping)."""
    coords = 'position'


def _blender_version():
    return tuple(bpy.app.version)


def _registry():
    return backend.engine().NODE_REGISTRY


def _zero(socket):
    """What a muted node without a pass-through outputs: zero."""
    return 0.0 if getattr(socket, 'type', 'VALUE') in ('VALUE', 'INT', 'BOOLEAN') else (0.0, 0.0, 0.0)


def _match_output(entry, out):
    names = dict(entry.outputs)
    for key in (out.identifier, out.name):
        if key in names and key not in entry.unsupported_outputs:
            return key
    return None


def _find_input(node, identifier):
    """An enabled input by identifier (else by name)."""
    sockets = list(node.inputs)
    for socket in sockets:
        if socket.identifier == identifier and getattr(socket, 'enabled', True):
            return socket
    for socket in sockets:
        if socket.name == identifier and getattr(socket, 'enabled', True):
            return socket
    return None


def _as_kind(value, kind, from_vector=False):
    """A constant converted to a socket kind as Cycles' implicit conversions
    (colour to float = luminance, vector to float = average, float to
    colour = grey); expressions are converted by the engine."""
    if is_expr(value):
        return value
    if kind == 'float':
        if isinstance(value, tuple):
            return sum(value[:3]) / 3.0 if from_vector else luminance(value)
        return float(value)
    if isinstance(value, (float, int)):
        return (float(value),) * 3
    return tuple(float(c) for c in value[:3])


def _prop(value):
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    try:
        return [float(v) for v in value]
    except TypeError:
        return str(value)


def _texture_mapping(node, entry, vector):
    """The hidden texture_mapping of a texture node as a Mapping node call
    (None when it is the identity, as almost always).  vector None: the
    node's default coordinates."""
    tm = getattr(_raw(node), 'texture_mapping', None)
    if tm is None:
        return None
    identity = (tuple(tm.translation) == (0.0, 0.0, 0.0) and tuple(tm.rotation) == (0.0, 0.0, 0.0)
                and tuple(tm.scale) == (1.0, 1.0, 1.0) and not tm.use_min and not tm.use_max
                and (tm.mapping_x, tm.mapping_y, tm.mapping_z) == ('X', 'Y', 'Z'))
    if identity:
        return None
    renderer = backend.engine()
    if vector is None:
        coords = getattr(entry, 'coords', None) or 'uv'
        if coords == 'position':
            vector = renderer.NodeOutput(renderer.NodeCall('ShaderNodeNewGeometry', {}), 'Position')
        elif coords == 'incoming':
            vector = renderer.NodeOutput(renderer.NodeCall('ShaderNodeNewGeometry', {}), 'Incoming')
        else:
            vector = renderer.NodeOutput(renderer.NodeCall('ShaderNodeTexCoord', {}),
                                      'Generated' if coords == 'generated' else 'UV')
    return renderer.NodeOutput(renderer.NodeCall('ShaderNodeMapping', {
        'Vector': vector, 'Location': tuple(tm.translation), 'Rotation': tuple(tm.rotation),
        'Scale': tuple(tm.scale)}, {'vector_type': tm.vector_type}), 'Vector')


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
