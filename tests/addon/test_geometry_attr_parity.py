"""Geometry node Pointiness and Random Per Island as Cycles computes them
(blender/mesh.cpp attr_create_pointiness, attr_create_random_per_island),
per pixel against a one-sample Cycles render, as test_node_parity.py.

The scene, seen from above by an orthographic camera: a bumpy welded grid
(pointiness varies over it), a cube whose faces carry their own vertices
(Cycles welds coincident vertices for Pointiness; each face is an island of
its own for Random Per Island) and one mesh of several separate bumpy
pieces (islands).  Each shows Pointiness or Random Per Island through an
Emission shader.  Pixels next to a silhouette are left out (which surface a
ray grazing an outline hits is float rounding, not shading).
"""
import bpy
import numpy as np

from test_node_parity import ATOL, RTOL, SHIFT_Y_SIGN, cycles_first_sample_offset, emission_material, render_cycles
from ember_testlib import small_resolution

WIDTH, HEIGHT = 64, 48


def _material(output):
    mat, tree, emission = emission_material(f"geometry {output}")
    geometry = tree.nodes.new('ShaderNodeNewGeometry')
    tree.links.new(geometry.outputs[output], emission.inputs['Color'])
    return mat


def _bumpy_grid(name, n, size, seed, offset):
    rng = np.random.default_rng(seed)
    xs = np.linspace(-size / 2, size / 2, n + 1)
    verts = [(x + offset[0], y + offset[1], float(rng.uniform(-0.15, 0.15)) * size / 2)
             for y in xs for x in xs]
    faces = [(j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
             for j in range(n) for i in range(n)]
    return verts, faces


def _link(name, verts, faces, material, location, rotation=(0.0, 0.0, 0.0), scale=1.0):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location, obj.rotation_euler, obj.scale = location, rotation, (scale,) * 3
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _split_cube():
    corners = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    verts, faces = [], []
    for quad in quads:   # every face its own four vertices
        faces.append(tuple(range(len(verts), len(verts) + 4)))
        verts += [corners[k] for k in quad]
    return verts, faces


def _pieces(seed):
    verts, faces = [], []
    rng = np.random.default_rng(seed)
    for k in range(6):
        y = 2.2 * (k // 3) - 1.1 + float(rng.uniform(-0.1, 0.1))
        v, f = _bumpy_grid("piece", 3, 1.9, seed + k, (2.3 * (k % 3 - 1) + 0.07 * k, y))
        base = len(verts)
        verts += v
        faces += [tuple(base + i for i in face) for face in f]
    return verts, faces


def build_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = 'ORTHO'
    cam_data.ortho_scale = 16.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (0.013, 0.021, 10.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    world = bpy.data.worlds.new("world")
    world.use_nodes = False
    world.color = (0.0, 0.0, 0.0)
    scene.world = world
    small_resolution(scene, WIDTH, HEIGHT)
    pointiness, island = _material('Pointiness'), _material('Random Per Island')
    v, f = _bumpy_grid("grid", 10, 5.0, 3, (0.0, 0.0))
    _link("grid", v, f, pointiness, (-4.4, 2.3, 0.0), (0.0, 0.0, 0.21))
    v, f = _split_cube()
    _link("cube pointiness", v, f, pointiness, (1.2, 3.0, 0.0), (0.6, 0.4, 0.3), 2.2)
    _link("cube islands", v, f, island, (4.9, 2.9, 0.0), (0.6, 0.4, 0.3), 2.2)
    v, f = _pieces(11)
    _link("pieces islands", v, f, island, (3.0, -3.0, 0.0), (0.0, 0.0, 0.13))
    _link("pieces pointiness", v, f, pointiness, (-4.4, -3.1, 0.0), (0.0, 0.0, -0.11))
    return scene


def _interior(material):
    """Pixels whose 3x3 neighbourhood hits one material."""
    m = np.pad(material, 1, mode='edge')
    same = np.ones(material.shape, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            same &= m[dy:dy + material.shape[0], dx:dx + material.shape[1]] == material
    return same & (material >= 0)


def emission_against_cycles(scene, tmp_path):
    """(exported scene, Ember's emission at Cycles' first-sample positions,
    the material per pixel, Cycles' one-sample render) of ``scene``, which
    must export without warnings."""
    from addon.export.scene import export_scene
    from engine.nodes import probe
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    assert not exported.warnings, exported.warnings
    shift = cycles_first_sample_offset()
    ember, material = probe.emission_at_pixel_centres(exported.scene, offset=(shift, SHIFT_Y_SIGN * shift))
    return exported, ember, material, render_cycles(scene, tmp_path)


def test_pointiness_and_random_per_island_match_cycles(registered_addon, tmp_path):
    scene = build_scene()
    exported, ember, material, cycles = emission_against_cycles(scene, tmp_path)
    assert cycles.shape == ember.shape
    keep = _interior(material)
    names = [m.name for m in exported.scene.materials]
    for name in ('geometry Pointiness', 'geometry Random Per Island'):
        rows = keep & (material == names.index(name))
        got, want = ember[rows], cycles[rows]
        assert rows.sum() > 200 and np.ptp(want[:, 0]) > 0.1, (name, int(rows.sum()), np.ptp(want[:, 0]))
        bad = ~np.isclose(got, want, atol=ATOL, rtol=RTOL)
        assert not bad.any(), (f"{name}: {int(bad.any(axis=1).sum())} of {int(rows.sum())} pixels off, "
                               f"max |error| {np.abs(got - want).max():.3g}")
    # Random Per Island: one value per island (three faces of the cube in view, six pieces).
    islands = np.unique(np.round(cycles[keep & (material == names.index('geometry Random Per Island'))][:, 0], 5))
    assert len(islands) >= 8, islands


def test_window_coordinates_match_cycles_in_perspective(registered_addon, tmp_path):
    """Texture Coordinate Window through a shifted perspective camera over
    a tilted plane: the frame position of each point (the orthographic
    case is in test_node_parity.py's Texture Coordinate quads)."""
    from addon.export.scene import export_scene
    from engine.nodes import probe
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.lens, cam_data.shift_x, cam_data.shift_y = 35.0, 0.12, -0.05
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location, cam.rotation_euler = (0.3, -6.0, 3.0), (1.1, 0.0, 0.08)
    scene.collection.objects.link(cam)
    scene.camera = cam
    small_resolution(scene, 48, 36)
    mat, tree, emission = emission_material("window")
    coords = tree.nodes.new('ShaderNodeTexCoord')
    tree.links.new(coords.outputs['Window'], emission.inputs['Color'])
    v, f = _bumpy_grid("plane", 4, 12.0, 5, (0.0, 0.0))
    _link("plane", v, f, mat, (0.0, 0.0, 0.0), (0.2, 0.1, 0.0))
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    assert not exported.warnings, exported.warnings
    # A perspective camera's rays fan out: no one shift moves them all; the
    # first sample sits within 5e-4 pixel of the centre (about 1e-5 in
    # Window units at 48 pixels), far inside the tolerance below.
    ember, material = probe.emission_at_pixel_centres(exported.scene)
    cycles = render_cycles(scene, tmp_path)
    keep = _interior(material)
    assert keep.sum() > 600, int(keep.sum())
    got, want = ember[keep], cycles[keep]
    assert np.ptp(want[:, 0]) > 0.5 and np.ptp(want[:, 1]) > 0.5
    np.testing.assert_allclose(got, want, atol=3e-5)


def _top_ortho_scene():
    """An empty scene seen from above by an orthographic camera 16 units
    wide (off the pixel grid by a fraction of a pixel)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type, cam_data.ortho_scale = 'ORTHO', 16.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (0.013, 0.021, 10.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene


def test_generated_coordinates_of_deformed_meshes_match_cycles(registered_addon, tmp_path):
    """Generated coordinates come from the undeformed mesh (Blender's orco),
    as Cycles reads them: a grid bent by a Simple Deform modifier, one
    moved by a shape key, one whose texture space is set by hand, and one
    twisted with a Texture Mesh (whose vertices are then the orco)."""
    scene = _top_ortho_scene()
    small_resolution(scene, WIDTH, HEIGHT)
    mat, tree, emission = emission_material("generated")
    coords = tree.nodes.new('ShaderNodeTexCoord')
    tree.links.new(coords.outputs['Generated'], emission.inputs['Color'])
    v, f = _bumpy_grid("grid", 8, 4.0, 7, (0.0, 0.0))
    bent = _link("bent", v, f, mat, (-4.5, 1.5, 0.0), (0.0, 0.0, 0.1))
    deform = bent.modifiers.new("bend", 'SIMPLE_DEFORM')
    deform.deform_method, deform.angle, deform.deform_axis = 'TWIST', 1.2, 'X'
    keyed = _link("keyed", v, f, mat, (1.0, 1.5, 0.0), (0.0, 0.0, -0.2))
    keyed.shape_key_add(name="Basis")
    key = keyed.shape_key_add(name="moved")
    for k, point in enumerate(key.data):
        point.co = (point.co.x * 1.3 + 0.2, point.co.y * 0.8 + 0.1 * np.sin(k), point.co.z)
    key.value = 1.0
    spaced = _link("spaced", v, f, mat, (4.5, -3.0, 0.0), (0.0, 0.0, 0.3))
    spaced.data.use_auto_texspace = False
    spaced.data.texspace_location, spaced.data.texspace_size = (0.3, -0.2, 0.1), (2.8, 2.5, 0.6)   # Generated stays in [0, 1]: Ember clips negative emission
    wave = spaced.modifiers.new("wave", 'WAVE')
    wave.height = 0.3
    # A Texture Mesh under a deform-only stack: Blender's orco is its vertices (BKE_mesh_orco_verts_get).
    textured = _link("texture mesh", v, f, mat, (-4.5, -3.0, 0.0), (0.0, 0.0, -0.1))
    textured.data.texco_mesh = bpy.data.meshes.new("texture space")
    textured.data.texco_mesh.from_pydata([(x * 0.85 + 0.1 * y, y * 0.9, z) for x, y, z in v], [], f)
    twist = textured.modifiers.new("twist", 'SIMPLE_DEFORM')
    twist.deform_method, twist.angle, twist.deform_axis = 'TWIST', 0.9, 'Y'
    exported, ember, material, cycles = emission_against_cycles(scene, tmp_path)
    keep = _interior(material)
    assert keep.sum() > 400, int(keep.sum())
    bad = ~np.isclose(ember, cycles, atol=ATOL, rtol=RTOL) & keep[..., None]
    ys, xs = np.nonzero(bad.any(axis=2))
    assert not bad.any(), f"{int(bad.any(axis=2).sum())} pixels off at x {sorted(set(xs.tolist()))} y {sorted(set(ys.tolist()))}, max {np.abs(ember - cycles)[bad].max():.3g}"


def _subdivide_nodes():
    """A geometry-nodes group that subdivides its mesh once."""
    group = bpy.data.node_groups.new("subdivide", 'GeometryNodeTree')
    group.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    group.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    given, result = group.nodes.new('NodeGroupInput'), group.nodes.new('NodeGroupOutput')
    subdivide = group.nodes.new('GeometryNodeSubdivideMesh')
    subdivide.inputs['Level'].default_value = 1
    group.links.new(given.outputs[0], subdivide.inputs['Mesh'])
    group.links.new(subdivide.outputs[0], result.inputs[0])
    return group


def _moving_nodes():
    """A geometry-nodes group that moves every vertex (count kept)."""
    group = bpy.data.node_groups.new("move", 'GeometryNodeTree')
    group.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    group.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    given, result = group.nodes.new('NodeGroupInput'), group.nodes.new('NodeGroupOutput')
    move = group.nodes.new('GeometryNodeSetPosition')
    move.inputs['Offset'].default_value = (0.25, -0.15, 0.3)
    group.links.new(given.outputs[0], move.inputs['Geometry'])
    group.links.new(move.outputs[0], result.inputs[0])
    return group


def _generated_material(name):
    """Emission of Generated * 0.25 + 0.5 (orco outside the texture space,
    as array and mirror copies make, stays positive: Ember clips negative
    emission)."""
    mat, tree, emission = emission_material(name)
    coords = tree.nodes.new('ShaderNodeTexCoord')
    scale = tree.nodes.new('ShaderNodeVectorMath')
    scale.operation = 'MULTIPLY_ADD'
    scale.inputs[1].default_value, scale.inputs[2].default_value = (0.25,) * 3, (0.5,) * 3
    tree.links.new(coords.outputs['Generated'], scale.inputs[0])
    tree.links.new(scale.outputs[0], emission.inputs['Color'])
    return mat


def _subsurf(obj, levels=2):
    sub = obj.modifiers.new("subsurf", 'SUBSURF')
    sub.levels = sub.render_levels = levels   # Ember exports the viewport depsgraph, Cycles renders
    return sub


def _displace(obj):
    texture = bpy.data.textures.get("clouds") or bpy.data.textures.new("clouds", 'CLOUDS')
    texture.noise_scale = 0.6
    displace = obj.modifiers.new("displace", 'DISPLACE')
    displace.texture, displace.strength, displace.direction = texture, 0.8, 'X'
    return displace


def _shape_key(obj, move):
    obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name="moved")
    for k, point in enumerate(key.data):
        point.co = move(k, point.co)
    key.value = 1.0


def _armature(obj, location):
    """An Armature modifier bending ``obj`` (its +x half weighted to a
    second, rotated bone) followed by a Subdivision Surface."""
    arm = bpy.data.objects.new(f"{obj.name} rig", bpy.data.armatures.new("rig"))
    arm.location = location
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode='EDIT')
    root = arm.data.edit_bones.new("root")
    root.head, root.tail = (-1.5, 0.0, 0.0), (0.0, 0.0, 0.0)
    tip = arm.data.edit_bones.new("tip")
    tip.head, tip.tail, tip.parent = (0.0, 0.0, 0.0), (1.5, 0.0, 0.0), root
    bpy.ops.object.mode_set(mode='OBJECT')
    arm.pose.bones["tip"].rotation_mode = 'XYZ'
    arm.pose.bones["tip"].rotation_euler = (0.3, 0.0, 0.5)
    groups = {name: obj.vertex_groups.new(name=name) for name in ("root", "tip")}
    for vertex in obj.data.vertices:
        weight = min(max(vertex.co.x / 1.5 + 0.5, 0.0), 1.0)
        groups["tip"].add([vertex.index], weight, 'REPLACE')
        groups["root"].add([vertex.index], 1.0 - weight, 'REPLACE')
    obj.modifiers.new("armature", 'ARMATURE').object = arm
    _subsurf(obj)


def build_constructive_scene():
    """Objects whose stack both deforms and changes the vertex count, each
    with its own material (one row of ``_link`` per case, 3.4 units apart)."""
    scene = _top_ortho_scene()
    small_resolution(scene, 96, 72)   # 1.5 times the suite's 64 x 48: the array and mirror cases are thin
    v, f = _bumpy_grid("grid", 4, 3.0, 7, (0.0, 0.0))
    objects = {}

    def add(name, location, verts=v, faces=f, rotation=0.1):
        objects[name] = _link(name, verts, faces, _generated_material(name), location, (0.0, 0.0, rotation))
        return objects[name]

    _subsurf(_displace(add("displace, subsurf", (-5.8, 3.6, 0.0))).id_data)
    _displace(_subsurf(add("subsurf, displace", (-1.9, 3.6, 0.0))).id_data)
    arrayed = add("array, simple deform", (1.4, 3.6, 0.0), *_bumpy_grid("half", 3, 1.5, 8, (0.0, 0.0)))
    arrayed.modifiers.new("array", 'ARRAY').count = 2
    bend = arrayed.modifiers.new("bend", 'SIMPLE_DEFORM')
    bend.deform_method, bend.angle, bend.deform_axis = 'TWIST', 0.9, 'X'
    half = _bumpy_grid("side", 3, 1.5, 9, (1.05, 0.0))
    mirrored = add("mirror, shape key", (-5.6, -0.2, 0.0), *half)
    mirrored.modifiers.new("mirror", 'MIRROR')
    _shape_key(mirrored, lambda k, co: (co.x * 1.2 + 0.1, co.y + 0.1 * np.sin(k), co.z + 0.2))
    # The shape key lifts the half off the mirror plane: the final mesh keeps
    # the seam vertices the undeformed one merges (Blender's orco is then the
    # final positions).
    seam = add("mirror merge, shape key", (-1.8, -0.2, 0.0), *_bumpy_grid("edge", 3, 1.5, 10, (0.75, 0.0)))
    seam.modifiers.new("mirror", 'MIRROR')
    _shape_key(seam, lambda k, co: (co.x + 0.3, co.y * 0.9, co.z))
    nodes = add("simple deform, geometry nodes", (2.0, -0.2, 0.0))
    twist = nodes.modifiers.new("twist", 'SIMPLE_DEFORM')
    twist.deform_method, twist.angle, twist.deform_axis = 'TWIST', 1.0, 'Y'
    nodes.modifiers.new("subdivide", 'NODES').node_group = _subdivide_nodes()
    moved = add("geometry nodes moving", (5.8, -0.2, 0.0))
    moved.modifiers.new("move", 'NODES').node_group = _moving_nodes()
    _armature(add("armature, subsurf", (2.0, -4.0, 0.0)), (2.0, -4.0, 0.0))
    wave = add("wave, subsurf, geometry nodes", (-3.9, -4.0, 0.0))
    wave.modifiers.new("wave", 'WAVE').height = 0.4
    _subsurf(wave, 1)
    wave.modifiers.new("subdivide", 'NODES').node_group = _subdivide_nodes()
    return scene, objects


def pixels_off(exported, ember, material, cycles):
    """{material name: (pixels off, pixels compared, max |error|)}."""
    keep = _interior(material)
    out = {}
    for index, mat in enumerate(exported.scene.materials):
        rows = keep & (material == index)
        bad = ~np.isclose(ember[rows], cycles[rows], atol=ATOL, rtol=RTOL)
        error = float(np.abs(ember[rows] - cycles[rows]).max()) if rows.any() else 0.0
        out[mat.name] = (int(bad.any(axis=1).sum()), int(rows.sum()), error)
    return out


def test_generated_coordinates_through_constructive_modifiers_match_cycles(registered_addon, tmp_path):
    """Generated coordinates of meshes whose stack deforms and changes the
    vertex count (either order), per pixel against Cycles: Blender's orco
    runs the constructive modifiers (subdivision, array, mirror, geometry
    nodes) on the undeformed vertices, which the exporter reaches by
    evaluating the stack again without its deform-only modifiers and shape
    keys; where the counts then differ (the mirror merge) Blender keeps the
    final positions, and so does the exporter."""
    scene, objects = build_constructive_scene()
    exported, ember, material, cycles = emission_against_cycles(scene, tmp_path)
    counts = pixels_off(exported, ember, material, cycles)
    print("pixels off (off, compared, max error):", counts)
    for name in objects:
        off, compared, error = counts[name]
        assert compared > 40, (name, compared)
        assert off == 0, f"{name}: {off} of {compared} pixels off, max |error| {error:.3g}"
    for obj in objects.values():   # the user's objects are left as they were
        assert all(m.show_viewport and m.show_render for m in obj.modifiers)
        assert not obj.show_only_shape_key


def test_orco_evaluation_leaves_the_depsgraph_and_objects_alone(registered_addon):
    """The second evaluation switches modifiers and shape keys off on the
    evaluated copies only: after the export nothing is tagged for an update
    (a viewport render would otherwise export again and again), the user's
    flags read as before, and every case got its undeformed coordinates."""
    from addon.export.scene import export_scene
    _, objects = build_constructive_scene()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    updated = []

    def note(scene, graph):
        updated.extend(u.id.name for u in graph.updates)

    bpy.app.handlers.depsgraph_update_post.append(note)
    try:
        exported = export_scene(depsgraph)
        depsgraph.update()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(note)
    assert not exported.warnings, exported.warnings
    assert updated == [], updated
    for obj in objects.values():
        assert all(m.show_viewport and m.show_render for m in obj.modifiers)
        assert not obj.show_only_shape_key
        if obj.data.shape_keys is not None:
            assert obj.data.shape_keys.key_blocks[-1].value == 1.0
    # all but the mirror merge and the geometry-nodes move (orco = final positions there)
    with_orco = [m.name for m in exported.scene.meshes if m.orco is not None]
    assert len(with_orco) == len(objects) - 2, with_orco


def test_unreachable_generated_coordinates_are_named(registered_addon):
    """Where the second evaluation cannot give Blender's orco, a warning
    names the object and the reason: absolute shape keys (zeroing values
    does not take them out) and a Texture Mesh under a constructive modifier
    (Cycles reads its vertices there, through the modifier)."""
    from addon.export.scene import export_scene
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    v, f = _bumpy_grid("grid", 3, 2.0, 5, (0.0, 0.0))
    absolute = _link("absolute", v, f, _generated_material("absolute"), (0.0, 0.0, 0.0))
    _shape_key(absolute, lambda k, co: (co.x + 0.2, co.y, co.z))
    absolute.data.shape_keys.use_relative = False
    _subsurf(absolute, 1)
    textured = _link("texture mesh", v, f, _generated_material("texture mesh"), (3.0, 0.0, 0.0))
    textured.data.texco_mesh = bpy.data.meshes.new("texture space")
    textured.data.texco_mesh.from_pydata([(x * 1.1, y, z) for x, y, z in v], [], f)
    _subsurf(_displace(textured).id_data, 1)
    warnings = export_scene(bpy.context.evaluated_depsgraph_get()).warnings
    assert any("'absolute'" in w and "absolute" in w.split(":", 2)[2] for w in warnings), warnings
    assert any("'texture mesh'" in w and "Texture Mesh" in w for w in warnings), warnings


def test_final_render_reaches_the_same_undeformed_coordinates(registered_addon, tmp_path, monkeypatch):
    """A final render's depsgraph (render mode: the modifiers' Render
    switches) gives the same orco as the viewport depsgraph the parity test
    exports (the scene's subdivision levels agree), and leaves the user's
    flags as they were."""
    from addon.export import mesh as mesh_export
    from addon.export.scene import export_scene
    from ember_testlib import render_array, setup_ember
    scene, objects = build_constructive_scene()
    reach = mesh_export._undeformed_corners
    seen = {'VIEWPORT': {}, 'RENDER': {}}

    def recorded(obj, mesh, depsgraph=None, warn=None):
        orco = reach(obj, mesh, depsgraph, warn)
        seen[depsgraph.mode][obj.name] = orco
        return orco

    monkeypatch.setattr(mesh_export, '_undeformed_corners', recorded)
    export_scene(bpy.context.evaluated_depsgraph_get())
    setup_ember(scene, samples=1, seed=1, max_bounces=0)
    render_array(scene, tmp_path, "orco_render")
    viewport, render = seen['VIEWPORT'], seen['RENDER']
    assert set(render) == set(viewport) == set(objects), (sorted(render), sorted(viewport))
    for name, orco in render.items():
        if viewport[name] is None:
            assert orco is None, name
        else:
            np.testing.assert_array_equal(orco, viewport[name], err_msg=name)
    # all but the mirror merge and the geometry-nodes move (orco = final positions there)
    assert sum(orco is not None for orco in render.values()) == len(objects) - 2, render.keys()
    for obj in objects.values():
        assert all(m.show_viewport and m.show_render for m in obj.modifiers)


def test_second_evaluation_only_where_generated_is_read(registered_addon, monkeypatch):
    """The stack is evaluated again only for an object whose material may
    read Generated (here a Noise texture's unlinked Vector), never for one
    that cannot (a plain Emission)."""
    from addon.export import mesh as mesh_export
    from addon.export.scene import export_scene
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    v, f = _bumpy_grid("grid", 3, 2.0, 5, (0.0, 0.0))
    plain, _, _ = emission_material("plain")
    noisy, tree, emission = emission_material("noisy")
    noise = tree.nodes.new('ShaderNodeTexNoise')
    tree.links.new(noise.outputs['Color'], emission.inputs['Color'])
    for name, material in (("plain", plain), ("noisy", noisy)):
        obj = _link(name, v, f, material, (0.0, 0.0, 0.0))
        _subsurf(_displace(obj).id_data, 1)
    runs = []
    run = mesh_export._constructive_positions
    monkeypatch.setattr(mesh_export, '_constructive_positions',
                        lambda obj, *args: runs.append(obj.name) or run(obj, *args))
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    assert runs == ["noisy"], runs
    assert sum(m.orco is not None for m in exported.scene.meshes) == 1


def test_an_unexpected_struct_layout_is_named_not_written(registered_addon, monkeypatch):
    """Were a Blender's modifier struct laid out otherwise (here: the offset
    of its type field instead of its mode), the field does not read as RNA
    says, nothing is written and a warning names the object."""
    from addon.export import mesh as mesh_export
    from addon.export.scene import export_scene
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    v, f = _bumpy_grid("grid", 3, 2.0, 5, (0.0, 0.0))
    obj = _link("displaced", v, f, _generated_material("displaced"), (0.0, 0.0, 0.0))
    _subsurf(_displace(obj).id_data, 1)
    monkeypatch.setattr(mesh_export, 'MODIFIER_MODE_OFFSET', 16)
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    assert any("'displaced'" in w and "could not switch" in w for w in exported.warnings), exported.warnings
    assert [m.type for m in obj.modifiers] == ['DISPLACE', 'SUBSURF']
    assert all(m.show_viewport and m.show_render for m in obj.modifiers)
