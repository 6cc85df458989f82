"""Evaluated Blender geometry -> engine.scene.Mesh.

Everything is read with ``foreach_get`` into preallocated NumPy arrays: a
Python loop over vertices would cost seconds on a million triangles.
"""
import bpy
import numpy as np

from .. import backend

# Object types whose evaluated geometry ``to_mesh`` can triangulate.
MESHABLE_TYPES = {'MESH', 'CURVE', 'SURFACE', 'FONT', 'META'}


def _get(collection, attribute, count, width, dtype):
    """``collection.foreach_get`` into a new (count, width) array."""
    flat = np.empty(count * width, dtype=dtype)
    if count:
        collection.foreach_get(attribute, flat)
    return flat.reshape(count, width) if width > 1 else flat


def _has_smooth_faces(mesh):
    """True if any face is shaded smooth (then per-corner normals matter)."""
    count = len(mesh.polygons)
    if count == 0:
        return False
    smooth = np.empty(count, dtype=bool)
    mesh.polygons.foreach_get('use_smooth', smooth)
    return bool(smooth.any())


def _has_custom_normals(mesh):
    return bool(getattr(mesh, 'has_custom_normals', False))


def _corner_normals(mesh, tri_count):
    """Per-corner shading normals, (T, 3, 3), or None when every face is flat.

    Split normals cover flat, smooth, auto-smooth and custom normals at once.
    Before 4.1 they must be computed explicitly; 4.1 computes them on demand.
    """
    if not (_has_smooth_faces(mesh) or _has_custom_normals(mesh)):
        return None
    if hasattr(mesh, 'calc_normals_split'):
        mesh.calc_normals_split()
    normals = _get(mesh.loop_triangles, 'split_normals', tri_count, 9, np.float32)
    return normals.reshape(tri_count, 3, 3)


def _corner_uvs(mesh, loops):
    """Per-corner UVs of the active UV map, (T, 3, 2), or None."""
    layer = mesh.uv_layers.active
    if layer is None:
        return None
    uv = _get(layer.data, 'uv', len(mesh.loops), 2, np.float32)
    return uv[loops]


def _corner_tangents(mesh, loops):
    """MikkTSpace tangents of the active UV map and bitangent signs per
    corner, ((T, 3, 3), (T, 3)), as Cycles uses for normal maps; (None, None)
    without UVs or where Blender cannot compute them (n-gons before 4.x):
    the renderer then uses per-triangle UV tangents."""
    layer = mesh.uv_layers.active
    if layer is None:
        return None, None
    try:
        mesh.calc_tangents(uvmap=layer.name)
    except RuntimeError:
        return None, None
    try:
        count = len(mesh.loops)
        tangents = _get(mesh.loops, 'tangent', count, 3, np.float32)
        signs = _get(mesh.loops, 'bitangent_sign', count, 1, np.float32)
    finally:
        mesh.free_tangents()
    return tangents[loops], signs[loops]


def needs_tangents(obj):
    """True if a material of the object uses a tangent-space Normal Map node
    or a UV-map Tangent node (anisotropic lobes)."""
    for slot in getattr(obj, 'material_slots', ()):
        tree = getattr(slot.material, 'node_tree', None) if slot.material else None
        if tree is not None and any((n.type == 'NORMAL_MAP' and n.space == 'TANGENT')
                                    or (n.type == 'TANGENT' and n.direction_type == 'UV_MAP') for n in tree.nodes):
            return True
    return False


GEOMETRY_DERIVED = ('Pointiness', 'Random Per Island')


def node_trees(tree, seen):
    """A node tree and the groups inside it, each once."""
    if tree is None or tree.as_pointer() in seen:
        return
    seen.add(tree.as_pointer())
    yield tree
    for n in tree.nodes:
        if n.type == 'GROUP':
            yield from node_trees(getattr(n, 'node_tree', None), seen)


def needs_derived(obj):
    """The Geometry node outputs Cycles computes from the mesh's topology
    (Pointiness, Random Per Island) that a material of the object reads."""
    out, seen = set(), set()
    for slot in getattr(obj, 'material_slots', ()):
        tree = getattr(slot.material, 'node_tree', None) if slot.material else None
        for t in node_trees(tree, seen):
            for n in t.nodes:
                if n.type == 'NEW_GEOMETRY':
                    out |= {s.name for s in n.outputs if s.name in GEOMETRY_DERIVED and s.is_linked}
    return out


# Texture nodes whose unlinked Vector is not Generated (UV, direction, object space).
_NOT_GENERATED_BY_DEFAULT = frozenset({'TEX_IMAGE', 'TEX_ENVIRONMENT', 'TEX_SKY', 'TEX_IES', 'TEX_POINTDENSITY'})


def needs_generated(obj):
    """True if a material of the object may read Generated coordinates (a
    Texture Coordinate node's Generated, a procedural texture with its
    Vector unlinked, a radial Tangent), erring towards True."""
    seen = set()
    for slot in getattr(obj, 'material_slots', ()):
        tree = getattr(slot.material, 'node_tree', None) if slot.material else None
        for t in node_trees(tree, seen):
            for n in t.nodes:
                if n.type == 'TEX_COORD' and n.outputs['Generated'].is_linked:
                    return True
                if n.type == 'TANGENT' and n.direction_type == 'RADIAL':
                    return True
                if n.type.startswith('TEX_') and n.type not in _NOT_GENERATED_BY_DEFAULT:
                    vector = n.inputs.get('Vector')
                    if vector is not None and not vector.is_linked:
                        return True
    return False


def _derived_attributes(mesh, triangles, wanted):
    """{reserved name: (T, 3) corners} of Pointiness and Random Per Island
    (engine.mesh_attributes), computed as Cycles does at sync."""
    if not wanted:
        return {}
    attrs = backend.engine().mesh_attributes
    count = len(mesh.vertices)
    edges = _get(mesh.edges, 'vertices', len(mesh.edges), 2, np.int32)
    out = {}
    if 'Pointiness' in wanted:
        positions = _get(mesh.vertices, 'co', count, 3, np.float32)
        normals = _vertex_normals(mesh, count)
        out[attrs.POINTINESS] = attrs.pointiness(positions, normals, edges)[triangles]
    if 'Random Per Island' in wanted:
        value = attrs.random_per_island(count, edges, triangles)
        out[attrs.RANDOM_PER_ISLAND] = np.repeat(value[:, None], 3, axis=1)
    return out


def _vertex_normals(mesh, count):
    """Blender's vertex normals (4.1+: ``vertex_normals``; before: ``normal``)."""
    if hasattr(mesh, 'vertex_normals'):
        return _get(mesh.vertex_normals, 'vector', count, 3, np.float32)
    return _get(mesh.vertices, 'normal', count, 3, np.float32)


def mesh_from_blender(mesh, name, tangents=False, check=None, derived=()):
    """Copy a triangulated Blender mesh into an engine Mesh.

    Returns None for geometry without triangles (empty meshes, edges, points),
    which the renderer cannot hit anyway.  ``check()`` runs between the
    arrays (it raises to cancel): one array of 2M triangles takes ~2 s in
    Blender 3.4.
    """
    check = check or (lambda: None)
    mesh.calc_loop_triangles()
    tri_count = len(mesh.loop_triangles)
    if tri_count == 0:
        return None
    renderer = backend.engine()
    check()
    positions = _get(mesh.vertices, 'co', len(mesh.vertices), 3, np.float32)
    triangles = _get(mesh.loop_triangles, 'vertices', tri_count, 3, np.int32)
    check()
    loops = _get(mesh.loop_triangles, 'loops', tri_count, 3, np.int32)
    check()
    slots = _get(mesh.loop_triangles, 'material_index', tri_count, 1, np.int32)
    check()
    corner_tangents, signs = _corner_tangents(mesh, loops) if tangents else (None, None)
    normals = _corner_normals(mesh, tri_count)
    check()
    out = renderer.Mesh(
        positions=positions,
        triangles=triangles,
        normals=normals,
        uvs=_corner_uvs(mesh, loops),
        material_slots=slots if slots.any() else None,
        name=name,
        tangents=corner_tangents,
        tangent_signs=signs,
        uv_maps=_named_uv_maps(mesh, loops),
        attributes=_with_derived(_color_attributes(mesh, triangles, loops),
                                 _derived_attributes(mesh, triangles, derived)),
        texspace=texspace_of(mesh),
    )
    if normals is not None and hasattr(out, 'smooth'):
        # Which faces are smooth: true displacement recomputes only their vertex normals.
        smooth = _get(mesh.loop_triangles, 'use_smooth', tri_count, 1, bool)
        out.smooth = None if smooth.all() else smooth
    return out


def uses_adaptive_subdivision(obj):
    """Whether Cycles would subdivide the object adaptively (5.0: the last
    modifier is a Subdivision Surface with Adaptive Subdivision on; before:
    the object's Cycles setting under the Experimental feature set) and one
    of its materials displaces the surface (Ember does not dice: it
    displaces the evaluated mesh)."""
    original = getattr(obj, 'original', obj)
    mods = list(getattr(original, 'modifiers', ()) or ())
    last = mods[-1] if mods else None
    adaptive = bool(last is not None and last.type == 'SUBSURF' and getattr(last, 'use_adaptive_subdivision', False)
                    and last.show_render)
    if not adaptive:
        cycles = getattr(original, 'cycles', None)
        scene_cycles = getattr(getattr(bpy.context, 'scene', None), 'cycles', None)
        adaptive = (bool(getattr(cycles, 'use_adaptive_subdivision', False))
                    and getattr(scene_cycles, 'feature_set', '') == 'EXPERIMENTAL')
    if not adaptive:
        return False
    for slot in getattr(original, 'material_slots', ()):
        material = slot.material
        method = getattr(material, 'displacement_method', None) if material is not None else None
        if method is None and material is not None:
            method = getattr(getattr(material, 'cycles', None), 'displacement_method', 'BUMP')
        if method in ('DISPLACEMENT', 'BOTH'):
            return True
    return False


def drop_nonfinite_triangles(mesh):
    """Remove the triangles that use a NaN or infinite vertex (Cycles skips
    them too) and zero those vertices; returns how many were dropped."""
    finite = np.isfinite(mesh.positions).all(axis=1)
    if finite.all():
        return 0
    keep = finite[mesh.triangles].all(axis=1)
    mesh.positions = np.where(finite[:, None], mesh.positions, np.float32(0.0))
    for name in ('triangles', 'normals', 'uvs', 'material_slots', 'tangents', 'tangent_signs', 'orco', 'smooth'):
        value = getattr(mesh, name)
        if value is not None:
            setattr(mesh, name, value[keep])
    for name in ('uv_maps', 'attributes'):  # per-triangle arrays by name
        value = getattr(mesh, name, None)
        if value:
            setattr(mesh, name, {key: array[keep] for key, array in value.items()})
    return int(len(keep) - np.count_nonzero(keep))


def _named_uv_maps(mesh, loops):
    """Every UV map by name, (T, 3, 2) each, when there is more than one
    (the active one is ``uvs``), for UV Map nodes and image nodes naming one."""
    layers = list(mesh.uv_layers)
    if len(layers) < 2:
        return None
    return {layer.name: _get(layer.data, 'uv', len(mesh.loops), 2, np.float32)[loops] for layer in layers}


def _color_attributes(mesh, triangles, loops):
    """Colour attributes as linear RGBA per corner, (T, 3, 4) by name; ''
    names the default (render) one.  Blender's ``color`` is scene linear for
    byte colours too (stored sRGB, decoded as Cycles does at sync)."""
    attrs = getattr(mesh, 'color_attributes', None)
    if attrs is None or len(attrs) == 0:
        return None
    out = {}
    for attr in attrs:
        if attr.domain not in ('POINT', 'CORNER'):
            continue
        count = len(attr.data)
        rgba = _get(attr.data, 'color', count, 4, np.float32)
        out[attr.name] = rgba[triangles] if attr.domain == 'POINT' else rgba[loops]
    index = getattr(attrs, 'render_color_index', -1)
    if 0 <= index < len(attrs) and attrs[index].name in out:
        out[''] = out[attrs[index].name]
    elif out:
        out[''] = next(iter(out.values()))
    return out or None


def _with_derived(attributes, derived):
    if not derived:
        return attributes
    return dict(attributes or {}, **derived)


def texspace_of(mesh):
    """(location, size) of the mesh's texture space (Generated coordinates)."""
    loc = getattr(mesh, 'texspace_location', None)
    size = getattr(mesh, 'texspace_size', None)
    if loc is None or size is None:
        return None
    return (tuple(float(v) for v in loc), tuple(float(v) for v in size))


# Modifier types Blender evaluates as deform-only (ModifierTypeType::OnlyDeform
# in their MOD_*.cc): the stack's orco (undeformed coordinates, which Cycles'
# Generated reads) skips them, as it skips the shape keys.
DEFORM_ONLY = frozenset({
    'ARMATURE', 'CAST', 'CLOTH', 'COLLISION', 'CORRECTIVE_SMOOTH', 'CURVE', 'DISPLACE', 'HOOK',
    'LAPLACIANDEFORM', 'LAPLACIANSMOOTH', 'LATTICE', 'MESH_CACHE', 'MESH_DEFORM', 'PARTICLE_SYSTEM',
    'SHRINKWRAP', 'SIMPLE_DEFORM', 'SMOOTH', 'SOFT_BODY', 'SURFACE', 'SURFACE_DEFORM', 'WARP', 'WAVE',
})
# Constructive modifiers that leave the orco mesh as it is (Fluid returns its
# input under MOD_APPLY_ORCO): off in the orco evaluation too.
ORCO_SKIPS = frozenset({'FLUID'})


def _enabled_modifiers(obj, render):
    flag = 'show_render' if render else 'show_viewport'
    return [m for m in getattr(obj, 'modifiers', ()) if getattr(m, flag, False)]


def _undeformed_corners(obj, mesh, depsgraph=None, warn=None):
    """Corner positions (T, 3, 3) of Blender's orco, the undeformed mesh
    Cycles' Generated coordinates use (blenkernel mesh_calc_modifiers): the
    original vertices when only deform-only modifiers and shape keys act;
    the constructive modifiers applied to the original vertices (a second
    evaluation without the deform-only ones, ``depsgraph`` needed) when both
    kinds act and the vertex count stays that of the final mesh.  None when
    the orco is the final positions (no deformation, or the counts differ,
    where Blender falls back to the final positions too), or when it cannot
    be reached (then ``warn(text)`` says why)."""
    original = getattr(getattr(obj, 'original', None), 'data', None)
    if original is None or original is obj.data:
        return None
    render = getattr(depsgraph, 'mode', 'VIEWPORT') == 'RENDER'
    modifiers = _enabled_modifiers(obj, render)
    key = getattr(original, 'shape_keys', None)
    deformed = key is not None or any(m.type in DEFORM_ONLY | ORCO_SKIPS for m in modifiers)
    texture_mesh = getattr(original, 'texco_mesh', None) if deformed else None
    if all(m.type in DEFORM_ONLY for m in modifiers):
        if len(original.vertices) != len(mesh.positions):
            return None
        positions = (_get(original.vertices, 'co', len(original.vertices), 3, np.float32) if texture_mesh is None
                     else _texture_mesh_positions(texture_mesh, len(original.vertices)))
    elif texture_mesh is not None:
        _tell(warn, obj, "its Texture Mesh under constructive modifiers is not read (Cycles takes the undeformed "
                         "vertices from it)")
        return None
    else:
        if not deformed or depsgraph is None or not getattr(obj, 'is_evaluated', False) or not needs_generated(obj):
            return None   # (without Generated in a material, the second evaluation is not worth it)
        reason = _unreachable(original, key)
        positions = _constructive_positions(obj, depsgraph, render) if reason is None else None
        if positions is None:
            _tell(warn, obj, reason or "the undeformed evaluation could not switch its deform-only modifiers off")
            return None
        if len(positions) != len(mesh.positions):
            return None
    if np.array_equal(positions, mesh.positions):
        return None
    return positions[mesh.triangles]


def _texture_mesh_positions(texture_mesh, count):
    """Blender's orco from a Texture Mesh (BKE_mesh_orco_verts_get): its
    first ``count`` vertices, zeros for any it lacks."""
    have = min(len(texture_mesh.vertices), count)
    positions = np.zeros((count, 3), np.float32)
    if have:
        positions[:have] = _get(texture_mesh.vertices, 'co', len(texture_mesh.vertices), 3, np.float32)[:have]
    return positions


def _tell(warn, obj, reason):
    if warn is not None:
        warn(f"Object '{obj.name}': Generated coordinates follow the deformed mesh: {reason}")


def _unreachable(original, key):
    """Why the second evaluation would not give Blender's orco, or None:
    it leaves shape keys out by zeroing the relative keys' values, so the
    reference key must hold the mesh's own vertices (Blender's orco)."""
    if key is None:
        return None
    if not key.use_relative:
        return "its shape keys are absolute (Cycles reads the vertices without them)"
    count = len(original.vertices)
    reference = key.reference_key
    if reference is None or len(reference.data) != count:
        return "its shape keys do not match its vertices"
    if not np.array_equal(_get(reference.data, 'co', count, 3, np.float32),
                          _get(original.vertices, 'co', count, 3, np.float32)):
        return "its reference shape key differs from its vertices (Cycles reads the vertices)"
    return None


class _Field:
    """One int or float of a Blender struct, written in place through its
    address.  The orco evaluation switches modifiers and shape keys off on
    the evaluated copy this way: the RNA setters would tag the original for
    an update (a viewport render would export again, endlessly).  The write
    is made only where the field reads as RNA does, checked against what
    RNA reads back, and undone when it disagrees."""

    def __init__(self, struct, offset, kind):
        import ctypes
        self.cell = (ctypes.c_int if kind == 'int' else ctypes.c_float).from_address(struct.as_pointer() + offset)
        self.saved = self.cell.value

    def restore(self):
        self.cell.value = self.saved


# DNA offsets (makesdna): ModifierData {next, prev, int type, int mode};
# KeyBlock {next, prev, float pos, float curval}.
MODIFIER_MODE_OFFSET, KEYBLOCK_CURVAL_OFFSET = 20, 20
MODE_BITS = {'show_viewport': 1, 'show_render': 2}   # eModifierMode_Realtime, _Render


def _switch_off(obj, depsgraph, render):
    """Fields written to leave the deform-only modifiers and the shape keys
    out of the evaluated object's stack; None when a write does not read
    back as meant (everything undone then)."""
    flag = 'show_render' if render else 'show_viewport'
    fields = []
    try:
        for m in _enabled_modifiers(obj, render):
            if m.type in DEFORM_ONLY | ORCO_SKIPS:
                field = _Field(m, MODIFIER_MODE_OFFSET, 'int')
                if any(bool(field.saved & bit) != getattr(m, name) for name, bit in MODE_BITS.items()):
                    raise ValueError(m.name)   # not the layout assumed: nothing written
                fields.append(field)
                field.cell.value = field.saved & ~MODE_BITS[flag]
                if getattr(m, flag):
                    raise ValueError(m.name)
        key = _evaluated_key(obj, depsgraph)
        for block in key.key_blocks if key is not None else ():
            if block != key.reference_key and block.value != 0.0:
                field = _Field(block, KEYBLOCK_CURVAL_OFFSET, 'float')
                if field.saved != np.float32(block.value):
                    raise ValueError(block.name)
                fields.append(field)
                field.cell.value = 0.0
                if block.value != 0.0:
                    raise ValueError(block.name)
    except (ValueError, TypeError, AttributeError):
        for field in reversed(fields):
            field.restore()
        return None
    return fields


def _evaluated_key(obj, depsgraph):
    key = getattr(getattr(obj, 'original', obj).data, 'shape_keys', None)
    return key.evaluated_get(depsgraph) if key is not None else None


def _constructive_positions(obj, depsgraph, render):
    """Vertex positions of the evaluated object's stack run again without its
    deform-only modifiers and shape keys: Blender's parallel orco mesh.  None
    when the switches cannot be made.  Only the evaluated copy changes, for
    the length of one ``to_mesh``; the original object and file are left
    alone."""
    fields = _switch_off(obj, depsgraph, render)
    if fields is None:
        return None
    try:
        result = obj.to_mesh(preserve_all_data_layers=True, depsgraph=depsgraph)
        if result is None:
            return None
        return _get(result.vertices, 'co', len(result.vertices), 3, np.float32)
    finally:
        obj.to_mesh_clear()
        for field in reversed(fields):
            field.restore()


def mesh_from_object(obj, name, check=None, depsgraph=None, warn=None):
    """Export an evaluated object's geometry (modifiers applied).

    ``to_mesh`` on an evaluated object returns the final geometry for meshes,
    curves, text and metaballs; the temporary mesh is freed right after copy.
    ``depsgraph`` (the one ``obj`` comes from) lets a mesh's Generated
    coordinates follow constructive modifiers as Cycles' do; ``warn(text)``
    hears where they cannot.
    """
    if obj.type == 'MESH':
        # The evaluated mesh already has the modifiers applied: no copy needed.
        out = mesh_from_blender(obj.data, name, needs_tangents(obj), check, needs_derived(obj))
        if out is not None:
            out.orco = _undeformed_corners(obj, out, depsgraph, warn)
        return out
    mesh = obj.to_mesh()
    try:
        if mesh is None:
            return None
        return mesh_from_blender(mesh, name, needs_tangents(obj), check, needs_derived(obj))
    finally:
        obj.to_mesh_clear()
