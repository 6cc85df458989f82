"""Blender shader node trees -> engine.scene.Material (a weighted set of lobes).

Covered so far: Diffuse BSDF, Glossy BSDF, Emission, Principled BSDF (base
colour, metallic, roughness, specular, emission), Mix Shader and Add Shader.
A node Ember cannot translate becomes a grey diffuse (or a diffuse of the
node's Color input) and is named in one warning per material.  Texture inputs
are read as their unlinked default value, also with a warning.
"""
from dataclasses import dataclass, field

GREY = (0.8, 0.8, 0.8)
# Principled BSDF inputs (3.x and 4.x names) whose layers are not rendered yet.
PRINCIPLED_UNSUPPORTED = (
    'Subsurface', 'Subsurface Weight', 'Transmission', 'Transmission Weight',
    'Clearcoat', 'Coat Weight', 'Sheen', 'Sheen Weight',
)
BLACK = (0.0, 0.0, 0.0)


@dataclass
class Closure:
    """What a shader socket evaluates to: lobes and emission, before weighting."""
    lobes: list = field(default_factory=list)
    emission: tuple = BLACK

    def scaled(self, weight):
        scene = _scene()
        lobes = [scene.Lobe(lobe.kind, _scale(lobe.color, weight), lobe.roughness, lobe.fresnel)
                 for lobe in self.lobes]
        return Closure(lobes, _scale(self.emission, weight))

    def plus(self, other):
        return Closure(self.lobes + other.lobes, _add(self.emission, other.emission))


def _scale(color, weight):
    return tuple(float(c) * weight for c in color)


def _add(a, b):
    return tuple(float(x) + float(y) for x, y in zip(a, b))


def _mix(a, b, t):
    return tuple((1.0 - t) * float(x) + t * float(y) for x, y in zip(a, b))


def _clamp01(value):
    return min(max(float(value), 0.0), 1.0)


class NodeTranslator:
    """Translates one material's node tree, remembering what it could not."""

    def __init__(self, material_name):
        self.material_name = material_name
        self.unsupported = []   # node labels, in order of discovery
        self.textured = []      # "node.input" names read as constants
        self.approximated = []  # Principled BSDF features not rendered yet

    # -- socket values --------------------------------------------------------

    def _linked_node(self, socket):
        """The node feeding a socket, skipping reroutes and muted links."""
        if not socket.is_linked:
            return None, None
        link = socket.links[0]
        if getattr(link, 'is_muted', False) or not getattr(link, 'is_valid', True):
            return None, None
        node, out = link.from_node, link.from_socket
        while node.type == 'REROUTE':
            if not node.inputs[0].is_linked:
                return None, None
            link = node.inputs[0].links[0]
            node, out = link.from_node, link.from_socket
        return node, out

    def color(self, node, name, default=GREY):
        socket = node.inputs.get(name)
        if socket is None:
            return default
        source, _ = self._linked_node(socket)
        if source is not None:
            if source.type == 'RGB':
                return tuple(source.outputs[0].default_value)[:3]
            self._note_texture(node, name)
        value = socket.default_value
        if isinstance(value, float):
            return (value, value, value)
        return tuple(value)[:3]

    def value(self, node, name, default=0.0):
        socket = node.inputs.get(name)
        if socket is None:
            return default
        source, _ = self._linked_node(socket)
        if source is not None:
            if source.type == 'VALUE':
                return float(source.outputs[0].default_value)
            self._note_texture(node, name)
        value = socket.default_value
        if not isinstance(value, float):
            value = sum(tuple(value)[:3]) / 3.0
        return float(value)

    def _note_texture(self, node, name):
        label = f"{node.name}.{name}"
        if label not in self.textured:
            self.textured.append(label)

    # -- closures -------------------------------------------------------------

    def surface(self, socket):
        node, _ = self._linked_node(socket)
        if node is None:
            return Closure()  # an unlinked surface renders black, as in Cycles
        if node.mute:
            return self._fallback(node)
        handler = getattr(self, '_node_' + node.type.lower(), None)
        if handler is None:
            return self._fallback(node)
        return handler(node)

    def _fallback(self, node):
        """Grey diffuse, or a diffuse of the node's Color input if it has one."""
        label = f"'{node.name}' ({node.bl_idname})"
        if label not in self.unsupported:
            self.unsupported.append(label)
        socket = node.inputs.get('Color')
        color = GREY
        if socket is not None and not isinstance(socket.default_value, float):
            color = tuple(socket.default_value)[:3]
        return Closure([_scene().Lobe('diffuse', color)])

    def _node_bsdf_diffuse(self, node):
        return Closure([_scene().Lobe('diffuse', self.color(node, 'Color'))])

    def _node_bsdf_glossy(self, node):
        roughness = _clamp01(self.value(node, 'Roughness', 0.5))
        return Closure([_scene().Lobe('glossy', self.color(node, 'Color'), roughness, 'none')])

    # Blender 5.0 registers the Glossy BSDF under the anisotropic type.
    _node_bsdf_anisotropic = _node_bsdf_glossy

    def _node_emission(self, node):
        strength = self.value(node, 'Strength', 1.0)
        return Closure([], _scale(self.color(node, 'Color', (1.0, 1.0, 1.0)), strength))

    def _node_bsdf_principled(self, node):
        scene = _scene()
        base = self.color(node, 'Base Color')
        metallic = _clamp01(self.value(node, 'Metallic', 0.0))
        roughness = _clamp01(self.value(node, 'Roughness', 0.5))
        f0 = _dielectric_f0(self, node)
        specular = _mix((f0, f0, f0), base, metallic)
        diffuse = _scale(base, 1.0 - metallic)
        lobes = [scene.Lobe('glossy', specular, roughness, 'schlick')]
        if metallic < 1.0:
            lobes.insert(0, scene.Lobe('diffuse', diffuse))
        self._note_principled_features(node)
        return Closure(lobes, _principled_emission(self, node))

    def _note_principled_features(self, node):
        """Name the Principled layers in use that Ember does not render yet."""
        used = [name.split()[0] for name in PRINCIPLED_UNSUPPORTED
                if name in node.inputs and self.value(node, name, 0.0) > 0.0]
        if 'Alpha' in node.inputs and self.value(node, 'Alpha', 1.0) < 1.0:
            used.append('Alpha')
        if used:
            self.approximated.append(f"'{node.name}' ({', '.join(used)})")

    def _node_mix_shader(self, node):
        fac = _clamp01(self.value(node, 'Fac', 0.5))
        first = self.surface(node.inputs[1]).scaled(1.0 - fac)
        second = self.surface(node.inputs[2]).scaled(fac)
        return first.plus(second)

    def _node_add_shader(self, node):
        return self.surface(node.inputs[0]).plus(self.surface(node.inputs[1]))

    # -- report ----------------------------------------------------------------

    def warning(self):
        """One sentence naming everything approximated, or None."""
        parts = []
        if self.unsupported:
            parts.append("unsupported node " + ", ".join(self.unsupported) + " rendered as diffuse")
        if self.approximated:
            parts.append("Principled BSDF " + ", ".join(self.approximated) + " not rendered yet")
        if self.textured:
            parts.append("linked input " + ", ".join(self.textured) + " read as its constant value")
        if not parts:
            return None
        return f"Material '{self.material_name}': " + "; ".join(parts)


def _dielectric_f0(translator, node):
    """Reflectance at normal incidence of the Principled BSDF's specular layer.

    4.x: from the IOR, scaled by 2 * Specular IOR Level (0.5 keeps it as is).
    3.x: 0.08 * Specular (0.5 -> 0.04, i.e. IOR 1.5).
    """
    if 'Specular IOR Level' in node.inputs:
        ior = max(translator.value(node, 'IOR', 1.5), 1.0)
        level = max(translator.value(node, 'Specular IOR Level', 0.5), 0.0)
        return ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * level
    return 0.08 * max(translator.value(node, 'Specular', 0.5), 0.0)


def _principled_emission(translator, node):
    strength = translator.value(node, 'Emission Strength', 1.0)
    name = 'Emission Color' if 'Emission Color' in node.inputs else 'Emission'
    return _scale(translator.color(node, name, BLACK), strength)


def _output_node(tree):
    """The Material Output node Cycles would use."""
    try:
        node = tree.get_output_node('CYCLES')
    except (AttributeError, TypeError):
        node = None
    if node is None:
        outputs = [n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL']
        node = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    return node


def translate(material):
    """Returns (engine Material, warning or None) for a bpy material."""
    scene = _scene()
    name = material.name
    tree = material.node_tree if _uses_nodes(material) else None
    if tree is None:
        color = tuple(material.diffuse_color)[:3]
        return scene.Material(name, (scene.Lobe('diffuse', color),)), None
    translator = NodeTranslator(name)
    output = _output_node(tree)
    if output is None:
        return scene.Material(name, ()), f"Material '{name}': no Material Output node, rendered black"
    closure = translator.surface(output.inputs['Surface'])
    return scene.Material(name, tuple(closure.lobes), closure.emission), translator.warning()


class MaterialTable:
    """Scene materials, each Blender material translated once."""

    def __init__(self, override=None):
        self.materials = []
        self.warnings = []
        self.index_of = {}
        self.override = override
        self.slots_cache = {}

    def index(self, material):
        if material is None:
            return -1
        key = material.as_pointer()
        if key not in self.index_of:
            translated, warning = translate(material)
            self.index_of[key] = len(self.materials)
            self.materials.append(translated)
            if warning:
                self.warnings.append(warning)
        return self.index_of[key]

    def slots(self, obj):
        """Scene material index per material slot of an evaluated object."""
        if self.override is not None:
            count = max(len(obj.material_slots), 1)
            return [self.index(self.override)] * count
        key = (obj.original.as_pointer(), obj.data.as_pointer() if obj.data else 0)
        if key not in self.slots_cache:
            slots = [slot.material for slot in obj.material_slots]
            if not slots and obj.data is not None and hasattr(obj.data, 'materials'):
                slots = list(obj.data.materials)
            self.slots_cache[key] = [self.index(m) for m in slots]
        return self.slots_cache[key]


def _scene():
    from .. import backend
    return backend.scene_module()


def _uses_nodes(datablock):
    """Blender 5.0 always uses nodes and deprecates the ``use_nodes`` switch."""
    import bpy
    if bpy.app.version >= (5, 0, 0):
        return True
    return bool(getattr(datablock, 'use_nodes', False))
