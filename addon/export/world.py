"""Blender world -> engine.scene.World: a constant background or an HDRI.

Radiance = Background colour * strength of the node linked to the World
Output, as Cycles; without nodes, ``world.color``; no world renders black, as
in Cycles.

The Background's Color may come from an Environment Texture (equirectangular or mirror ball)
whose Vector is unlinked or comes from a Texture Coordinate node (Generated,
or Object: the ray direction, through the chosen object's inverse rotation)
through any number of Mapping nodes.  Mapping rotation and scale become the
texture's world -> texture matrix (Cycles' svm_mapping and
euler_to_transform); a location cannot move a direction and is ignored with a
warning.  As Cycles: a Mapping with nothing linked to its Vector looks up the
texture at the zero vector (one constant colour), a missing image renders
magenta.  Other trees of registered nodes (procedural textures, the Sky
Texture) are baked into an equirectangular map for sampling; worlds with a
sky are shaded per direction and its sun disc sampled by its cone (Cycles'
sun guiding).  Anything else is read as the Background's constant colour and
reported.  The World Output's Volume becomes a medium filling space (its
inputs constants or textures evaluated per point).
"""
import numpy as np

from .. import backend
from . import compat, images, material, nodes

BLACK = (0.0, 0.0, 0.0)
MAGENTA = (1.0, 0.0, 1.0)
CUBIC = ('Cubic', 'Smart')


def _output_node(tree):
    return nodes.output_node(tree, 'OUTPUT_WORLD')


def _linked(socket):
    """(node, output socket) feeding an input, skipping reroutes; (None, None)
    when unlinked or the link is muted (Cycles then uses the socket's value)."""
    while socket.is_linked:
        link = socket.links[0]
        if getattr(link, 'is_muted', False):
            return None, None
        node = link.from_node
        if node.type != 'REROUTE':
            return node, link.from_socket
        socket = node.inputs[0]
    return None, None


def _constant(node, name):
    socket = node.inputs[name]
    value = socket.default_value
    return value if isinstance(value, float) else tuple(value)[:3]


class _Notes:
    """Warnings about one world, reported as one sentence."""

    def __init__(self, world):
        self.world = world
        self.items = []

    def add(self, text):
        if text not in self.items:
            self.items.append(text)

    def message(self):
        if not self.items:
            return None
        return f"World '{self.world.name}': " + "; ".join(self.items)


def world_from_blender(world):
    """Returns (engine World, warning or None)."""
    renderer = backend.engine()
    if world is None:
        return renderer.World(color=BLACK), None
    notes = _Notes(world)
    color, texture = _translate(world, notes)
    return renderer.World(color=color, texture=texture, volume=_volume(world, notes)), notes.message()


def _volume(world, notes):
    """The World Output's Volume: a medium everywhere (the material
    exporter's volume translation; textured inputs are evaluated per point,
    engine/media/field.py WorldField, at Object = Generated = the point, as
    Cycles' background volume)."""
    tree = world.node_tree if compat.uses_nodes(world) else None
    output = None if tree is None else _output_node(tree)
    socket = None if output is None else output.inputs.get('Volume')
    if socket is None or not socket.is_linked:
        return None
    translator = material.NodeTranslator(world.name)
    v = translator.volume(socket)
    warning = translator.warning()
    if warning:
        notes.add(warning.split(": ", 1)[1])
    volume = material.volume_of(v)
    volume.sampling = material.volume_sampling(world, 'EQUIANGULAR')
    return volume


def _translate(world, notes):
    """(constant rgb, EnvironmentTexture or None)."""
    tree = world.node_tree if compat.uses_nodes(world) else None
    if tree is None:
        return tuple(float(c) for c in world.color), None
    output = _output_node(tree)
    if output is None:
        return BLACK, None
    node, _ = _linked(output.inputs['Surface'])
    if node is None:
        return BLACK, None
    if node.type != 'BACKGROUND':
        notes.add(f"'{node.name}' ({node.bl_idname}) is not supported, world is black")
        return BLACK, None
    if node.inputs['Strength'].is_linked:
        notes.add("a linked Background Strength is read as its constant value")
    strength = float(_constant(node, 'Strength'))
    color = tuple(float(c) * strength for c in _constant(node, 'Color'))
    source, out = _linked(node.inputs['Color'])
    if source is None:
        return color, None
    if source.type == 'TEX_ENVIRONMENT' and out.name == 'Color' and not source.mute:
        return _environment(source, strength, color, notes)
    baked = _bake_node_tree(node.inputs['Color'], strength, notes)
    if baked is not None:
        return baked
    notes.add(f"'{source.name}' ({source.bl_idname}) is not supported: the Background's "
              "constant colour is used")
    return color, None


# Resolution of a baked procedural world (equirectangular, importance-sampled
# like an HDRI); 512 x 256 texels are 0.7 degrees each.
BAKE_SIZE = (512, 256)


def _bake_node_tree(socket, strength, notes):
    """Any node tree of the shader-node registry above the Background Color,
    evaluated per direction as Cycles shades the world (P = Generated =
    Object = the ray direction, N = incoming = -direction, camera rays) and
    baked into an equirectangular EnvironmentTexture.  None if a node in it
    is not evaluated (the caller falls back to the constant colour)."""
    reader = nodes.SocketReader()
    expr = reader.read(socket)
    if expr is None or reader.unsupported:
        for warning in reader.warnings:
            notes.add(warning)
        return None
    for warning in reader.warnings:
        notes.add(warning)
    if not nodes.is_expr(expr):
        value = expr if isinstance(expr, tuple) else (float(expr),) * 3
        return tuple(float(c) * strength for c in value), None
    renderer = backend.engine()
    skies = _sky_calls(expr)
    sun = _sun_guide(skies)
    # With sun guiding the disc stays out of the table (its cone is sampled instead).
    pixels = renderer.bake_environment(expr, *BAKE_SIZE, importance_bake=sun is not None)
    # A sky's sun disc is smaller than a texel: such worlds are shaded per
    # direction (the bake only builds the sampling table).
    texture = renderer.EnvironmentTexture(pixels, strength, np.eye(3), 'Linear', name='baked world nodes',
                                       shader=expr if skies else None, sun=sun, expression=expr)
    mean = tuple(float(c) * strength for c in pixels.reshape(-1, 3).mean(axis=0))
    return mean, texture


def _sky_calls(expr):
    """The Sky Texture node calls inside a world expression."""
    found, seen, stack = [], set(), [expr]
    while stack:
        item = stack.pop()
        if id(item) in seen or item is None or isinstance(item, (str, int, float, bool)):
            continue
        seen.add(id(item))
        if isinstance(item, (tuple, list)):
            stack.extend(item)
        elif isinstance(item, dict):
            stack.extend(item.values())
        elif hasattr(item, '__dataclass_fields__'):
            if type(item).__name__ == 'NodeCall' and item.idname == 'ShaderNodeTexSky':
                found.append(item)
            stack.extend(getattr(item, name) for name in item.__dataclass_fields__)
    return found


def _sun_guide(skies):
    """Cycles' sun guiding (scene/light.cpp): one sky with its disc on whose
    Vector is the ray direction or a linear map of it (Generated through
    Mapping nodes without location, the hidden texture mapping included:
    the guide is the disc's direction mapped back; Cycles instead falls back
    to a 4096 x 2048 table there).  Otherwise None: the disc stays in the
    baked table, found by BSDF sampling."""
    # Preetham and Hosek-Wilkie have no disc (Cycles 5.0 would still aim at
    # the Nishita sun of the hidden properties: a variance, not a bias).
    with_disc = [c for c in skies if c.props.get('sun_disc', True)
                 and c.props.get('sky_type') not in ('PREETHAM', 'HOSEK_WILKIE')]
    if len(with_disc) != 1:
        return None
    call = with_disc[0]
    matrix = _direction_matrix(call.inputs.get('Vector'))
    if matrix is None or abs(np.linalg.det(matrix)) < 1e-12:
        return None
    return backend.engine().sky_sun_guide(call.props, matrix)


def _direction_matrix(vector):
    """M with lookup vector = M (world direction) for a sky's Vector
    expression, or None when it is not such a linear map."""
    if vector is None:
        return np.eye(3)
    if type(vector).__name__ != 'NodeOutput':
        return None
    call = vector.call
    if call.idname == 'ShaderNodeTexCoord':
        direct = vector.output == 'Generated' or (vector.output == 'Object' and not call.props.get('object'))
        return np.eye(3) if direct else None
    if call.idname != 'ShaderNodeMapping' or vector.output != 'Vector':
        return None
    values = [call.inputs.get(name, default) for name, default in
              (('Location', (0.0, 0.0, 0.0)), ('Rotation', (0.0, 0.0, 0.0)), ('Scale', (1.0, 1.0, 1.0)))]
    if not all(isinstance(v, tuple) for v in values):
        return None      # a linked Location / Rotation / Scale
    location, rotation, scale = (np.array(v, float) for v in values)
    kind = call.props.get('vector_type', 'POINT')
    if kind in ('POINT', 'TEXTURE') and np.any(location != 0):
        return None
    inner = _direction_matrix(call.inputs.get('Vector'))
    if inner is None or (kind in ('TEXTURE', 'NORMAL') and np.any(scale == 0)):
        return None
    rot = euler_matrix(rotation)
    if kind == 'TEXTURE':
        outer = np.diag(1.0 / scale) @ rot.T
    elif kind == 'NORMAL':
        outer = rot @ np.diag(1.0 / scale)
    else:
        outer = rot @ np.diag(scale)
    return outer @ inner


def _environment(node, strength, fallback, notes):
    """The Environment Texture as (constant rgb, EnvironmentTexture or None)."""
    renderer = backend.engine()
    if node.projection not in ('EQUIRECTANGULAR', 'MIRROR_BALL'):
        notes.add(f"'{node.name}' {node.projection} projection is not supported: the "
                  "Background's constant colour is used")
        return fallback, None
    pixels, missing = _pixels(node, notes)
    if missing:
        return tuple(c * strength for c in MAGENTA), None
    interpolation = node.interpolation
    if interpolation in CUBIC:
        notes.add(f"'{node.name}' {interpolation} interpolation rendered as Linear")
        interpolation = 'Linear'
    matrix = _vector_matrix(node, notes)
    mean = tuple(float(c) * strength for c in pixels.reshape(-1, 3).mean(axis=0))
    if matrix is None:
        # Cycles looks up the zero vector: (u, v) = (0, 0), one colour.
        # (a mirror ball's zero vector reads its centre: Cycles' direction_to_mirrorball)
        at = np.full(1, 0.5 if node.projection == 'MIRROR_BALL' else 0.0)
        value = renderer.environment_lookup(pixels[::-1], at, at, interpolation == 'Closest')[0]
        return tuple(float(c) * strength for c in value), None
    texture = renderer.EnvironmentTexture(pixels, strength, matrix, interpolation, name=node.image.name,
                                          projection=node.projection)
    return mean, texture


def _pixels(node, notes):
    """(H, W, 3) float32 linear pixels, row 0 = top; (None, True) if missing."""
    if node.image is None:
        notes.add(f"'{node.name}' has no image: rendered magenta")
        return None, True
    pixels, warnings = images.load_image(node.image)
    for warning in warnings:
        notes.add(warning)
    if images.is_missing(pixels, warnings):
        return None, True
    pixels = np.asarray(pixels, np.float32)
    channels = pixels.shape[2]
    rgb = pixels[..., :3] if channels >= 3 else np.repeat(pixels[..., :1], 3, axis=2)
    bad = ~np.isfinite(rgb)
    if bad.any():
        notes.add(f"image '{node.image.name}' has {int(bad.sum())} NaN or infinite values, read as 0")
        rgb = np.where(bad, 0.0, rgb)
    return np.ascontiguousarray(rgb, dtype=np.float32), False


# ----------------------------------------------------------------------------
# Vector input: Texture Coordinate and Mapping nodes -> a 3x3 matrix

def _vector_matrix(env_node, notes):
    """World direction -> lookup vector; None when a Mapping node's Vector
    is unlinked (Cycles then looks up the zero vector)."""
    matrix = np.eye(3)
    node, out = _linked(env_node.inputs['Vector'])
    while node is not None and node.type == 'MAPPING' and not node.mute:
        mapping = node
        matrix = matrix @ _mapping_matrix(mapping, notes)
        node, out = _linked(mapping.inputs['Vector'])
        if node is None:
            notes.add(f"Mapping '{mapping.name}' Vector is unlinked: one constant colour, as in Cycles")
            return None
    if node is None:
        return matrix
    if node.type == 'TEX_COORD' and out.name in ('Generated', 'Object') and not node.mute:
        if out.name == 'Object' and node.object is not None:
            matrix = matrix @ _object_rotation(node.object, notes)
        return matrix
    notes.add(f"'{node.name}' ({node.bl_idname}) output '{out.name}' as the environment "
              "vector is not supported: the ray direction is used")
    return matrix


def euler_matrix(rotation):
    """Cycles' euler_to_transform: R = Rz Ry Rx."""
    cx, cy, cz = np.cos(rotation)
    sx, sy, sz = np.sin(rotation)
    return np.array([[cy * cz, sy * sx * cz - cx * sz, sy * cx * cz + sx * sz],
                     [cy * sz, sy * sx * sz + cx * cz, sy * cx * sz - sx * cz],
                     [-sy, cy * sx, cy * cx]])


def _mapping_matrix(node, notes):
    """The linear part of Cycles' svm_mapping for one Mapping node."""
    values = {}
    for name in ('Location', 'Rotation', 'Scale'):
        socket = node.inputs.get(name)
        if socket is None:
            continue
        if socket.is_linked:
            notes.add(f"Mapping '{node.name}' linked {name} is read as its constant value")
        values[name] = np.array(socket.default_value[:3], float)
    rot = euler_matrix(values.get('Rotation', np.zeros(3)))
    scale = values.get('Scale', np.ones(3))
    kind = node.vector_type
    location = values.get('Location', np.zeros(3))
    if kind in ('POINT', 'TEXTURE') and np.any(location != 0):
        notes.add(f"Mapping '{node.name}' location cannot move a direction and is ignored")
    if kind in ('TEXTURE', 'NORMAL') and np.any(scale == 0):
        notes.add(f"Mapping '{node.name}' has a zero scale: ignored")
        scale = np.ones(3)
    if kind == 'TEXTURE':
        return np.diag(1.0 / scale) @ rot.T
    if kind == 'NORMAL':
        return rot @ np.diag(1.0 / scale)
    if np.any(scale == 0):
        notes.add(f"Mapping '{node.name}' has a zero scale: ignored")
        scale = np.ones(3)
    return rot @ np.diag(scale)


def _object_rotation(obj, notes):
    """Object coordinates of a direction: the object's inverse 3x3 (its
    translation would shift a direction, Ember ignores it)."""
    m = np.array(obj.matrix_world, float)
    if abs(np.linalg.det(m[:3, :3])) < 1e-12:
        notes.add(f"Texture Coordinate object '{obj.name}' has a zero scale: ignored")
        return np.eye(3)
    inverse = np.linalg.inv(m)
    if np.any(np.abs(inverse[:3, 3]) > 1e-9):
        notes.add(f"Texture Coordinate object '{obj.name}' location is ignored")
    return inverse[:3, :3]
