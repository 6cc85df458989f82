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


def _undeformed_corners(obj, mesh):
    """Corner positions (T, 3, 3) of the original (undeformed) mesh, which
    Cycles' Generated coordinates use (Blender's orco), when modifiers or
    shape keys moved the vertices without changing their count; None when
    nothing moved or the count changed (then the evaluated positions stand
    in, and the texture space is the evaluated one)."""
    original = getattr(getattr(obj, 'original', None), 'data', None)
    if original is None or original is obj.data or len(original.vertices) != len(mesh.positions):
        return None
    positions = _get(original.vertices, 'co', len(original.vertices), 3, np.float32)
    if np.array_equal(positions, mesh.positions):
        return None
    return positions[mesh.triangles]


def mesh_from_object(obj, name, check=None):
    """Export an evaluated object's geometry (modifiers applied).

    ``to_mesh`` on an evaluated object returns the final geometry for meshes,
    curves, text and metaballs; the temporary mesh is freed right after copy.
    """
    if obj.type == 'MESH':
        # The evaluated mesh already has the modifiers applied: no copy needed.
        out = mesh_from_blender(obj.data, name, needs_tangents(obj), check, needs_derived(obj))
        if out is not None:
            out.orco = _undeformed_corners(obj, out)
        return out
    mesh = obj.to_mesh()
    try:
        if mesh is None:
            return None
        return mesh_from_blender(mesh, name, needs_tangents(obj), check, needs_derived(obj))
    finally:
        obj.to_mesh_clear()
