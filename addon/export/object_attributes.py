"""Attribute nodes of type Object, Instancer and View Layer: the value each
instance reads, resolved as Blender resolves them for Cycles
(BKE_object_dupli_find_rgba_attribute, BKE_view_layer_find_rgba_attribute).

A name is looked up first as a custom property, then as an RNA path
('color', 'location', 'data.xxx'); a number becomes (v, v, v, 1), a float
array of up to 4 values fills RGBA over (0, 0, 0, 1); anything else, or
nothing found, is zero RGBA.  Object: the object, then its data (mesh).
Instancer: the instancing object first (for instances), then as Object.
View Layer: the view layer, the scene, then the scene's world.
"""
from .mesh import node_trees

TYPES = ('OBJECT', 'INSTANCER', 'VIEW_LAYER')
_NOT_FOUND = object()


def requested(obj, cache=None):
    """((type, name), ...) the materials of obj read through Attribute
    nodes of these types (node groups included)."""
    mats = tuple(slot.material for slot in getattr(obj, 'material_slots', ()) if slot.material)
    key = tuple(m.as_pointer() for m in mats)
    if cache is not None and key in cache:
        return cache[key]
    out, seen = [], set()
    for mat in mats:
        for tree in node_trees(getattr(mat, 'node_tree', None), seen):
            for node in tree.nodes:
                if node.type == 'ATTRIBUTE' and node.attribute_type in TYPES and not node.mute:
                    item = (node.attribute_type, node.attribute_name)
                    if item not in out:
                        out.append(item)
    out = tuple(out)
    if cache is not None:
        cache[key] = out
    return out


def _convert(value):
    """RGBA of a property value, or None where Blender finds none."""
    if isinstance(value, bool):
        value = float(value)
    if isinstance(value, (int, float)):
        return (float(value),) * 3 + (1.0,)
    try:
        items = list(value)
    except TypeError:
        return None
    if not 0 < len(items) <= 4 or not all(isinstance(v, float) for v in items):
        return None
    return tuple(float(v) for v in items) + (0.0, 0.0, 0.0, 1.0)[len(items):]


def _lookup(struct, name):
    """find_rna_property_rgba: a custom property, else an RNA path."""
    if struct is None:
        return None
    try:
        value = struct[name]
    except (KeyError, TypeError, AttributeError):
        value = _NOT_FOUND
    if value is _NOT_FOUND:
        try:
            value = struct.path_resolve(name)
        except (ValueError, TypeError, AttributeError):
            return None
    return _convert(value)


def _object_value(obj, name):
    value = _lookup(obj, name)
    if value is None:
        value = _lookup(getattr(obj, 'data', None), name)
    return value


def resolve(kind, name, inst, view_layer, scene):
    """The RGBA an instance reads (None: not found, Cycles' zero)."""
    if not name:
        return None
    if kind == 'VIEW_LAYER':
        for struct in (view_layer, scene, getattr(scene, 'world', None)):
            value = _lookup(struct, name)
            if value is not None:
                return value
        return None
    if kind == 'INSTANCER' and inst.is_instance:
        psys = getattr(inst, 'particle_system', None)
        if psys is not None:
            value = _lookup(psys.settings, name)
            if value is not None:
                return value
        value = _lookup(inst.parent, name)
        if value is not None:
            return value
    return _object_value(inst.object, name)


def instance_values(inst, view_layer, scene, cache=None, requests=None):
    """{key: RGBA} of every Object / Instancer / View Layer attribute the
    instance's materials read (``requests``: requested(inst.object) when
    the caller has it)."""
    from .. import backend
    key_of = backend.engine().instance_attribute_key
    out = {}
    for kind, name in requests if requests is not None else requested(inst.object, cache):
        value = resolve(kind, name, inst, view_layer, scene)
        if value is not None:
            out[key_of(kind, name)] = value
    return out
