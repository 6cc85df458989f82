"""Blender lights -> engine lights in Cycles units.

power (point, spot, area) = colour * energy [W]; sun strength = colour *
strength [W/m^2]; Blender 4.0+ light exposure multiplies both by 2^exposure.
Light node trees (Cycles-only) are read through the shader-node registry
(nodes.SocketReader): an Emission node's Color x Strength that is the same
at every point (e.g. a Blackbody of a fixed temperature) scales the light
(the fast path); one that varies over the light (textures on the light's
Texture Coordinate or Geometry outputs) becomes the engine light's
``shader``, evaluated per light sample and per BSDF-ray hit as Cycles does
(engine/lights/shader.py; suns per direction, engine/lights/sun.py).  A Light
Falloff node on the Strength (Quadratic, Linear or Constant output, Smooth)
becomes the engine light's ``falloff`` / ``falloff_smooth``.

Blender 3.x lights follow older conventions, converted here the way Blender
4.0 converts a 3.x file when it opens it (measured: the same Cornell box
renders within 0.1% in 3.4's and 5.0's Cycles):
* an area light of P watts in 3.x emits like a 4.x area light of P * pi/4;
* 3.x point and spot lights are disks facing the shading point, which is what
  4.x calls soft falloff (4.0 sets ``use_soft_falloff`` on old files).
"""
import dataclasses
import math

import bpy
import numpy as np

from .. import backend
from . import compat, nodes

LEGACY_LIGHT_UNITS = bpy.app.version < (4, 0, 0)
LEGACY_AREA_SCALE = math.pi / 4.0


def _intensity(light, amount):
    scale = float(amount) * 2.0 ** float(getattr(light, 'exposure', 0.0))
    return tuple(float(c) * scale for c in light.color)


def _direction(matrix):
    """Where the light shines: the object's -Z axis, normalised."""
    axis = -matrix[:3, 2]
    length = float(np.linalg.norm(axis))
    if length == 0.0:
        raise ValueError("has a zero scale, so it has no direction")
    return tuple(float(v) for v in axis / length)


def _point_fields(light, matrix):
    return dict(
        position=tuple(float(v) for v in matrix[:3, 3]),
        power=_intensity(light, light.energy),
        radius=float(light.shadow_soft_size),
        # 3.x has no such switch: its point lights behave as soft falloff.
        soft_falloff=bool(getattr(light, 'use_soft_falloff', True)),
    )


def light_from_blender(light, matrix, name, visible_camera=False, visibility=None):
    """Translate one light data block placed at ``matrix`` (4x4 NumPy).

    visible_camera is the object's camera ray visibility (off by default for
    Blender lights); visibility: the object's other ray visibility flags
    (visible_diffuse, visible_glossy, visible_transmission).  The engine's
    visible_shadow is the light's Cast Shadow: Cycles ignores the light
    object's Shadow ray visibility (measured in bpy 5.0).  Each is passed
    on when the engine's light types have the field.
    """
    data = light
    light = _translate(data, matrix, name)
    flags = dict(visibility or {}, visible_camera=visible_camera, visible_shadow=_casts_shadow(data))
    names = {f.name for f in dataclasses.fields(light)}
    for key, value in flags.items():
        if key in names:
            setattr(light, key, bool(value))
    return light


def _casts_shadow(light):
    """Cycles' Cast Shadow: light.cycles.cast_shadow in 3.x, use_shadow in 4.x+."""
    cycles = getattr(light, 'cycles', None)
    if LEGACY_LIGHT_UNITS and cycles is not None and hasattr(cycles, 'cast_shadow'):
        return bool(cycles.cast_shadow)
    return bool(getattr(light, 'use_shadow', True))


def _translate(light, matrix, name):
    scene = _scene()
    if light.type == 'POINT':
        return scene.PointLight(name=name, **_point_fields(light, matrix))
    if light.type == 'SPOT':
        return scene.SpotLight(
            name=name, direction=_direction(matrix), spot_size=float(light.spot_size),
            spot_blend=float(light.spot_blend), **_point_fields(light, matrix))
    if light.type == 'SUN':
        return scene.SunLight(
            name=name, direction=_direction(matrix), strength=_intensity(light, light.energy),
            angle=min(float(light.angle), math.pi))  # 180 degrees in float32 is above pi
    if light.type == 'AREA':
        square = light.shape in ('SQUARE', 'DISK')
        energy = light.energy * (LEGACY_AREA_SCALE if LEGACY_LIGHT_UNITS else 1.0)
        return scene.AreaLight(
            name=name, matrix=np.array(matrix, dtype=np.float64),
            power=_intensity(light, energy), shape=light.shape,
            size_x=float(light.size), size_y=float(light.size if square else light.size_y),
            normalize=bool(getattr(light, 'normalize', True)))
    raise ValueError(f"has an unknown light type {light.type}")


class LightCollector:
    """Engine lights of the light instances given to ``add`` one by one,
    while a depsgraph walk is at them (an instance's object is the walk's
    temporary copy: read at once, never kept).  ``lights``, ``warnings``;
    with a dict ``links``, light index -> (receivers, blockers) of Blender
    4.0+'s Light Linking and Shadow Linking collections."""

    def __init__(self, links=None):
        self.lights, self.warnings, self.links = [], [], links

    def add(self, obj, matrix, inst=None):
        """One light instance (``inst``: the depsgraph's, read at once for
        its Object Info random number; None: not an instance's)."""
        light = self._light(obj, matrix, inst)
        if light is None:
            return
        self.lights.append(light)
        if self.links is not None:
            linked = light_links(obj, self.warnings)
            if linked != (None, None):
                self.links[len(self.lights) - 1] = linked

    def _light(self, obj, matrix, inst=None):
        """The engine light, or None (black, or skipped with a warning)."""
        warnings = self.warnings
        try:
            visibility = {key: getattr(obj, key, True)
                          for key in ('visible_diffuse', 'visible_glossy', 'visible_transmission')}
            light = light_from_blender(obj.data, matrix, obj.name,
                                       getattr(obj, 'visible_camera', False), visibility)
        except ValueError as err:
            warnings.append(f"Light '{obj.name}' skipped: it {err}")
            return None
        bad = _nonfinite_field(light)
        if bad:
            warnings.append(f"Light '{obj.name}' skipped: its {bad} is NaN or infinite")
            return None
        if _is_black(light):
            return None
        if compat.uses_nodes(obj.data) and _has_light_nodes(obj.data):
            light, note = _with_node_tree(light, obj.data, matrix, object_info_of(obj, inst))
            if note:
                warnings.append(f"Light '{obj.name}': {note}")
            if _nonfinite_field(light):
                warnings.append(f"Light '{obj.name}' skipped: its node tree gives a NaN or infinite strength")
                return None
            if _is_black(light):
                return None
        return light


def collect_lights(depsgraph, check=None, links=None):
    """Every visible light, including instanced ones; returns (lights,
    warnings).  ``check()`` (which raises to cancel) runs every 256
    instances; ``links``: see LightCollector.  (A render's export gives its
    instance walk a LightCollector instead: one walk, not two.)"""
    collector = LightCollector(links)
    for count, inst in enumerate(depsgraph.object_instances):
        if check is not None and count % 256 == 255:
            check()
        obj = inst.object  # for instances: the instanced (possibly temporary) object
        if obj.type == 'LIGHT':
            collector.add(obj, np.array(inst.matrix_world, dtype=np.float64), inst)
    return collector.lights, collector.warnings


def light_links(obj, warnings):
    """(receivers, blockers) of a light object as engine LinkSets (None:
    every object), from Blender 4.0+'s Object > Shading > Light Linking and
    Shadow Linking collections; Blender 3.x has none (None, None)."""
    linking = getattr(obj, 'light_linking', None)
    if linking is None:
        return None, None
    out = []
    for kind, attr in (("receiver", 'receiver_collection'), ("blocker", 'blocker_collection')):
        collection = getattr(linking, attr, None)
        out.append(None if collection is None else _link_set(obj, kind, collection, warnings))
    return tuple(out)


def _link_set(obj, kind, collection, warnings):
    """A linking collection's objects by their Include / Exclude state (a
    child collection's objects take its state); an empty collection links
    every object, as in Blender, with a warning."""
    include, exclude = set(), set()

    def state(entry):
        link = getattr(entry, 'light_linking', None)
        return getattr(link, 'link_state', 'INCLUDE')
    # collection_objects[i] holds the state of objects[i] (children alike).
    for entry, member in zip(getattr(collection, 'collection_objects', ()), collection.objects):
        (include if state(entry) == 'INCLUDE' else exclude).add(member.name)
    for entry, child in zip(getattr(collection, 'collection_children', ()), collection.children):
        (include if state(entry) == 'INCLUDE' else exclude).update(o.name for o in child.all_objects)
    if not include and not exclude:
        warnings.append(f"Light '{obj.name}': its {kind} collection '{collection.name}' is empty: "
                        "every object takes part, as in Blender")
        return None
    return _scene().LinkSet(frozenset(include - exclude), frozenset(exclude))


def _nonfinite_field(light):
    """The first number field of an engine light that is NaN or infinite
    (strength, colour, size, angle, ...), or None."""
    for f in dataclasses.fields(light):
        value = getattr(light, f.name)
        if isinstance(value, (bool, str)) or value is None:
            continue
        try:
            numbers = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if not np.isfinite(numbers).all():
            return f.name.replace('_', ' ')
    return None


def _with_node_tree(light, data, matrix=None, info=None):
    """The light scaled by its node tree's emission (Color x Strength of the
    Emission node feeding the Light Output), and a note or None; where the
    emission varies over the light and the light type can evaluate it per
    point, the light with that expression as its ``shader`` (and point
    lights with their object ``matrix``, which Object and Normal
    coordinates read).  A Light Falloff node on the Strength gives the light
    its falloff (the node's Strength scales the light, its output and
    Smooth go to the engine).  info: the light object's Object Info values
    (``object_info_of``), which its Object Info nodes read."""
    output = nodes.output_node(data.node_tree, 'OUTPUT_LIGHT')
    if output is None:
        return light, None
    reader = nodes.SocketReader()
    source, _ = reader.linked_node(output.inputs['Surface'])
    if source is None or source.type != 'EMISSION' or source.mute:
        name = 'nothing' if source is None else f"'{source.name}'"
        return light, f"light nodes ({name} at the output) are ignored"
    color = reader.input(source, 'Color')
    strength, falloff, notes = _strength_and_falloff(reader, source, light)
    # As in materials: a node Ember cannot translate gives its input's
    # default value, named once; the rest of the tree still applies.
    if reader.unsupported:
        notes.append("texture node " + ", ".join(reader.unsupported) + " not translated")
    notes += reader.warnings
    expr = nodes.scale(nodes._as_color(color), strength)
    _give_object_info(expr, info)
    factor, varies = _constant_rgb(nodes._as_color(color), strength)
    varies = varies or any(key in _PER_LIGHT_POINT for key in _expr_nodes(expr))
    light = dataclasses.replace(light, **falloff)
    names = {f.name for f in dataclasses.fields(light)}
    if varies and 'shader' in names:
        notes += _unsupported_on_lights(expr)
        extra = {}
        if 'matrix' in names and getattr(light, 'matrix', None) is None and matrix is not None:
            extra['matrix'] = np.array(matrix, dtype=np.float64)
        return dataclasses.replace(light, shader=expr, **extra), "; ".join(notes) or None
    if varies:
        notes.append("the light's node tree varies over the light: its mean is used")
    note = "; ".join(notes) or None
    for name in ('power', 'strength'):
        value = getattr(light, name, None)
        if value is not None:
            return dataclasses.replace(light, **{name: tuple(v * f for v, f in zip(value, factor))}), note
    return light, note


# Nodes whose light-shader values Ember does not give as Cycles does
# (rendered with the value named).  Outputs not listed read the light point
# as Cycles' lamp shader: Camera and Window of the point, the light object's
# Object Info, Light Path's ray kinds (0: PATH_RAY_EMISSION), Ray Length and
# depths (the path reaching the light: engine/lights/shader.emission_path).
# Nodes the engine has no kernel for (Wireframe) are the reader's
# unsupported nodes, named as in materials.
_OFF_ON_LIGHTS = {
    'ShaderNodeParticleInfo': "the Particle Info node reads no particle on lights",
}

# Outputs the export's probe points cannot vary (no camera, no distance, no
# path): a tree reading one is evaluated per light point.
_PER_LIGHT_POINT = {('ShaderNodeTexCoord', 'Camera'), ('ShaderNodeTexCoord', 'Window'),
                    ('ShaderNodeLightPath', 'Ray Length')} | {
    ('ShaderNodeLightPath', name) for name in ('Ray Depth', 'Diffuse Depth', 'Glossy Depth',
                                               'Transmission Depth', 'Transparent Depth', 'Portal Depth')}


def object_info_of(obj, inst=None):
    """The Object Info node's outputs on a light object (Cycles reads the
    light's object: location, colour, alpha, pass index, random number)."""
    from . import instances
    random = 0.0
    if inst is not None:
        random = instances.object_info(inst)['random']
    color = tuple(float(c) for c in tuple(getattr(obj, 'color', (1.0, 1.0, 1.0, 1.0))))
    matrix = np.array(getattr(inst, 'matrix_world', obj.matrix_world), dtype=np.float64)
    return {'Location': tuple(float(v) for v in matrix[:3, 3]), 'Color': color[:3],
            'Alpha': float(color[3]) if len(color) > 3 else 1.0,
            'Object Index': float(getattr(obj, 'pass_index', 0)), 'Random': random}


def _give_object_info(expr, info):
    """Hand the light object's values to every Object Info node of the
    light's expression (the node's private prop ``_object``)."""
    for call in _calls(expr, set()):
        if call.idname == 'ShaderNodeObjectInfo':
            call.props = dict(call.props, _object=dict(info or _NO_OBJECT))


_NO_OBJECT = {'Location': (0.0, 0.0, 0.0), 'Color': (1.0, 1.0, 1.0), 'Alpha': 1.0, 'Object Index': 0.0,
              'Random': 0.0}


def _calls(expr, seen):
    """Every NodeCall of an engine expression, once each."""
    if id(expr) in seen or not nodes.is_expr(expr):
        return
    seen.add(id(expr))
    call = getattr(expr, 'call', None)
    if call is not None:
        if id(call) not in seen:
            seen.add(id(call))
            yield call
            for value in call.inputs.values():
                yield from _calls(value, seen)
        return
    for f in dataclasses.fields(expr):
        yield from _calls(getattr(expr, f.name), seen)


def _unsupported_on_lights(expr):
    """Notes naming each node of a light's expression that Ember evaluates
    differently from Cycles on a light point."""
    notes = []
    for idname, output in _expr_nodes(expr):
        note = _OFF_ON_LIGHTS.get(idname)
        if note and note not in notes:
            notes.append(note)
    return notes


def _expr_nodes(expr, seen=None):
    """(idname, output) of every node call in an engine expression."""
    seen = set() if seen is None else seen
    if id(expr) in seen or not nodes.is_expr(expr):
        return
    seen.add(id(expr))
    call = getattr(expr, 'call', None)
    if call is not None:
        yield call.idname, expr.output
        for value in call.inputs.values():
            yield from _expr_nodes(value, seen)
        return
    for f in dataclasses.fields(expr):
        yield from _expr_nodes(getattr(expr, f.name), seen)


def _strength_and_falloff(reader, emission, light):
    """The Emission's Strength and the engine light's falloff fields: a
    Light Falloff node feeding Strength contributes its own Strength, and
    its output (Quadratic, Linear, Constant) and Smooth become the light's
    falloff (Cycles' svm_node_light_falloff, evaluated per light sample at
    its distance).  Suns have none: Cycles ignores the node on distant
    lights.  Returns (strength, fields, notes)."""
    node, out = reader.linked_node(emission.inputs['Strength'])
    if node is None or node.type != 'LIGHT_FALLOFF' or node.mute:
        return reader.value_input(emission, 'Strength'), {}, []
    strength = reader.value_input(node, 'Strength')
    names = {f.name for f in dataclasses.fields(light)}
    if 'falloff' not in names:
        return strength, {}, []
    smooth, varies = _constant_rgb((1.0, 1.0, 1.0), reader.value_input(node, 'Smooth'))
    notes = ["the Light Falloff's Smooth varies over the light: its mean is used"] if varies else []
    kind = out.name.upper()
    if kind not in _scene().FALLOFFS:
        return strength, {}, [f"Light Falloff output '{out.name}' is not rendered"]
    return strength, {'falloff': kind, 'falloff_smooth': max(0.0, smooth[0])}, notes


def _constant_rgb(color, strength):
    """(rgb, varies): the expression color * strength evaluated at random
    shading points; varies when they disagree (then the mean)."""
    expr = nodes.scale(color, strength)
    if not nodes.is_expr(expr):
        return tuple(float(c) for c in expr), False
    renderer = backend.engine()
    rng = np.random.default_rng(0)
    n = 64
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # No ray kind: Cycles evaluates lights with PATH_RAY_EMISSION, where Is
    # Camera Ray and the other kinds read 0 (as engine/lights/shader.py).
    ctx = renderer.ShadingContext(n, p=rng.uniform(-1.0, 1.0, (n, 3)), ng=d, ns=d, wo=d, uv=rng.random((n, 2)),
                                  ray=np.zeros(n, np.uint8))
    values = renderer.TextureCompiler().color(expr)(ctx)
    mean = values.mean(axis=0)
    varies = bool(np.abs(values - mean).max() > 1e-6 * max(1.0, float(np.abs(mean).max())))
    return tuple(float(c) for c in np.maximum(mean, 0.0)), varies


def _is_black(light):
    values = getattr(light, 'power', None) or getattr(light, 'strength', None)
    return not any(v > 0.0 for v in values)


def _has_light_nodes(light):
    tree = light.node_tree
    return tree is not None and any(n.type not in ('OUTPUT_LIGHT', 'EMISSION') for n in tree.nodes)


def _scene():
    return backend.engine()


