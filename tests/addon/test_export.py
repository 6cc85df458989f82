"""Export: Blender data -> engine.scene, checked against Blender's own numbers."""
import math

import bpy
import numpy as np
import pytest
from mathutils import Vector

from addon.export import camera as camera_export
from addon.export import material as material_export
from addon.export import scene as scene_export

from ember_testlib import SCENES_DIR, open_scene, require


def export():
    return scene_export.export_scene(bpy.context.evaluated_depsgraph_get())


def instances_of(exported, mesh_name):
    scene = exported.scene
    return [inst for inst in scene.instances if scene.meshes[inst.mesh].name == mesh_name]


def evaluated_triangles(obj):
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    mesh.calc_loop_triangles()
    return len(mesh.loop_triangles), len(mesh.vertices)


# ----------------------------------------------------------------------------
# registration and settings

def test_engine_is_registered_with_blender_flags(factory_scene):
    from addon.engine import EmberRenderEngine
    assert EmberRenderEngine in bpy.types.RenderEngine.__subclasses__()
    assert factory_scene.render.engine == 'EMBER'
    assert EmberRenderEngine.bl_label == "Ember"
    assert EmberRenderEngine.bl_use_preview and EmberRenderEngine.bl_use_postprocess
    assert not EmberRenderEngine.bl_use_shading_nodes_custom


def test_blender_panels_show_for_ember(factory_scene):
    panels = {p.__name__: p for p in bpy.types.Panel.__subclasses__()}
    for name in ('RENDER_PT_format', 'RENDER_PT_output', 'RENDER_PT_color_management',
                 'DATA_PT_lens', 'DATA_PT_camera_dof', 'EEVEE_MATERIAL_PT_surface',
                 'EEVEE_WORLD_PT_surface', 'RENDER_PT_ember_sampling', 'RENDER_PT_ember_film'):
        assert 'EMBER' in panels[name].COMPAT_ENGINES, name


def test_render_settings_follow_scene(factory_scene):
    ember = factory_scene.ember
    assert scene_export.render_settings(factory_scene).light_selection == 'auto'   # the default
    ember.samples, ember.seed, ember.max_bounces, ember.clamp = 7, 3, 4, 2.5
    ember.light_selection, ember.strategy, ember.filter_type = 'ALL', 'BSDF', 'BOX'
    ember.filter_width, ember.time_limit = 0.5, 12.0
    factory_scene.render.film_transparent = True
    settings = scene_export.render_settings(factory_scene)
    assert (settings.samples, settings.seed, settings.max_bounces, settings.clamp) == (7, 3, 4, 2.5)
    assert (settings.light_selection, settings.strategy, settings.filter_type) == ('all', 'bsdf', 'BOX')
    # Cycles ignores the box filter's width (always one pixel); so does the export.
    assert settings.filter_width == 1.0 and settings.time_limit == 12.0
    ember.light_selection = 'TREE_BSDF'   # the light tree with the glossy lobe's term
    assert scene_export.render_settings(factory_scene).light_selection == 'tree_bsdf'
    ember.filter_type = 'GAUSSIAN'
    assert scene_export.render_settings(factory_scene).filter_width == pytest.approx(0.5)
    assert settings.mis_compensation is True
    assert settings.transparent
    assert scene_export.render_settings(factory_scene, is_preview=True).samples == ember.preview_samples


def test_path_guiding_follows_cycles_settings(factory_scene):
    """Cycles' own Path Guiding settings: Guiding and Surface Guiding turn
    it on (not in previews), Training Samples carries over (0: all)."""
    cycles = factory_scene.cycles
    assert scene_export.render_settings(factory_scene).path_guiding is False   # Cycles' default: off
    cycles.use_guiding, cycles.use_surface_guiding, cycles.guiding_training_samples = True, True, 32
    settings = scene_export.render_settings(factory_scene)
    assert settings.path_guiding is True and settings.path_guiding_training_samples == 32
    assert scene_export.render_settings(factory_scene, is_preview=True).path_guiding is False
    cycles.use_surface_guiding = False
    assert scene_export.render_settings(factory_scene).path_guiding is False


# ----------------------------------------------------------------------------
# meshes

def test_modifiers_are_applied(factory_scene):
    cube = bpy.data.objects['Cube']
    subsurf = cube.modifiers.new("Subsurf", 'SUBSURF')
    subsurf.levels = subsurf.render_levels = 2
    array = cube.modifiers.new("Array", 'ARRAY')
    array.count = 3
    tris, verts = evaluated_triangles(cube)
    assert tris == 3 * 6 * 16 * 2
    mesh = export().scene.meshes[instances_of(export(), 'Cube')[0].mesh]
    assert mesh.triangles.shape == (tris, 3) and mesh.positions.shape == (verts, 3)
    assert mesh.triangles.dtype == np.int32 and mesh.positions.dtype == np.float32
    assert mesh.triangles.max() == verts - 1


def test_positions_and_triangles_match_blender(factory_scene):
    cube = bpy.data.objects['Cube']
    exported = export()
    mesh = exported.scene.meshes[instances_of(exported, 'Cube')[0].mesh]
    blender = np.array([v.co[:] for v in cube.data.vertices], dtype=np.float32)
    np.testing.assert_array_equal(mesh.positions, blender)
    cube.data.calc_loop_triangles()
    np.testing.assert_array_equal(mesh.triangles, [t.vertices[:] for t in cube.data.loop_triangles])


def test_flat_mesh_has_no_shading_normals(factory_scene):
    exported = export()
    assert exported.scene.meshes[instances_of(exported, 'Cube')[0].mesh].normals is None


def test_smooth_normals_are_vertex_normals(empty_scene):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8)
    sphere = bpy.context.object
    sphere.data.name = 'SmoothSphere'
    bpy.ops.object.shade_smooth()
    exported = export()
    mesh = exported.scene.meshes[instances_of(exported, 'SmoothSphere')[0].mesh]
    assert mesh.normals.shape == (len(mesh.triangles), 3, 3)
    expected = np.array([v.normal[:] for v in sphere.data.vertices])[mesh.triangles]
    np.testing.assert_allclose(mesh.normals, expected, atol=1e-5)
    # Smooth normals on a sphere point away from the centre.
    np.testing.assert_allclose(np.einsum('tci,tci->tc', mesh.normals, mesh.positions[mesh.triangles])
                               / np.linalg.norm(mesh.positions[mesh.triangles], axis=2), 1.0, atol=0.02)


def test_custom_normals_are_exported(empty_scene):
    bpy.ops.mesh.primitive_plane_add()
    plane = bpy.context.object
    plane.data.name = 'NormalPlane'
    if hasattr(plane.data, 'use_auto_smooth'):
        plane.data.use_auto_smooth = True  # before 4.1 custom normals need it
    tilted = Vector((0.3, 0.0, 1.0)).normalized()
    plane.data.normals_split_custom_set([tilted[:]] * len(plane.data.loops))
    exported = export()
    mesh = exported.scene.meshes[instances_of(exported, 'NormalPlane')[0].mesh]
    np.testing.assert_allclose(mesh.normals.reshape(-1, 3), [tilted[:]] * 6, atol=1e-3)


def test_uvs_per_corner(factory_scene):
    cube = bpy.data.objects['Cube']
    exported = export()
    mesh = exported.scene.meshes[instances_of(exported, 'Cube')[0].mesh]
    cube.data.calc_loop_triangles()
    uv = cube.data.uv_layers.active.data
    expected = [[uv[i].uv[:] for i in t.loops] for t in cube.data.loop_triangles]
    np.testing.assert_allclose(mesh.uvs, expected)


def test_material_slots(factory_scene):
    cube = bpy.data.objects['Cube']
    red = material_export_helper("Red", (1.0, 0.0, 0.0))
    cube.data.materials.append(red)
    for polygon in cube.data.polygons[:2]:
        polygon.material_index = 1
    exported = export()
    inst = instances_of(exported, 'Cube')[0]
    mesh = exported.scene.meshes[inst.mesh]
    cube.data.calc_loop_triangles()
    expected = [t.material_index for t in cube.data.loop_triangles]
    np.testing.assert_array_equal(mesh.material_slots, expected)
    assert sorted(set(expected)) == [0, 1]
    names = [exported.scene.materials[i].name for i in inst.materials]
    assert names == ['Material', 'Red']
    assert exported.scene.materials[inst.materials[1]].lobes[0].color == pytest.approx((1, 0, 0))


def test_empty_slot_uses_default_material(factory_scene):
    cube = bpy.data.objects['Cube']
    cube.data.materials.clear()
    cube.data.materials.append(None)
    inst = instances_of(export(), 'Cube')[0]
    assert list(inst.materials) == [-1]


def material_export_helper(name, color):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    principled = material.node_tree.nodes['Principled BSDF']
    output = material.node_tree.nodes['Material Output']
    diffuse = material.node_tree.nodes.new('ShaderNodeBsdfDiffuse')
    diffuse.inputs['Color'].default_value = (*color, 1.0)
    material.node_tree.nodes.remove(principled)
    material.node_tree.links.new(diffuse.outputs[0], output.inputs['Surface'])
    return material


# ----------------------------------------------------------------------------
# instances

def test_shared_mesh_is_exported_once(factory_scene):
    cube = bpy.data.objects['Cube']
    for i in range(4):
        copy = cube.copy()  # linked duplicate: same mesh data
        copy.location = (3.0 * (i + 1), 0.0, 0.0)
        factory_scene.collection.objects.link(copy)
    modified = cube.copy()
    modified.modifiers.new("Bevel", 'BEVEL')
    factory_scene.collection.objects.link(modified)
    exported = export()
    assert len(exported.scene.instances) == 6
    assert len(exported.scene.meshes) == 2  # the shared cube and the bevelled one
    assert sorted(len(m.triangles) for m in exported.scene.meshes)[0] == 12


def test_collection_instances_have_blender_transforms(empty_scene):
    bpy.ops.mesh.primitive_cube_add()
    source = bpy.context.object
    source.data.name = 'SrcCube'
    collection = bpy.data.collections.new("Src")
    for owner in list(source.users_collection):
        owner.objects.unlink(source)
    collection.objects.link(source)
    matrices = []
    for i in range(5):
        empty = bpy.data.objects.new(f"Inst{i}", None)
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = collection
        empty.location = (i, 2.0 * i, -i)
        empty.rotation_euler = (0.1 * i, 0.2, 0.3 * i)
        empty.scale = (1.0 + i, 1.0, 0.5)
        empty_scene.collection.objects.link(empty)
        matrices.append(empty)
    bpy.context.view_layer.update()
    exported = export()
    cubes = instances_of(exported, 'SrcCube')
    assert len(cubes) == 5 and len(exported.scene.meshes) == 1
    got = sorted((inst.matrix for inst in cubes), key=lambda m: m[0, 3])
    for empty, matrix in zip(matrices, got):
        np.testing.assert_allclose(matrix, np.array(empty.matrix_world), atol=1e-6)


def test_geometry_nodes_instances(empty_scene):
    import importlib.util
    import os
    spec = importlib.util.spec_from_file_location('build_scenes', os.path.join(SCENES_DIR, 'build_scenes.py'))
    build_scenes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_scenes)
    bpy.ops.mesh.primitive_ico_sphere_add(location=(0, 0, -50))
    ball = bpy.context.object
    ball.data.name = 'Icosphere'
    grid = build_scenes._geometry_nodes_instancer(empty_scene, ball)
    bpy.context.view_layer.update()
    exported = export()
    balls = instances_of(exported, 'Icosphere')
    assert len(balls) == 1 + 9  # the source object itself plus nine copies
    # The source object and the nine copies: geometry nodes hand the copies
    # their own evaluated mesh, shared by all nine.
    assert len(exported.scene.meshes) == 2
    copies = [inst for inst in balls if inst.matrix[2, 3] > -40]
    assert len({inst.mesh for inst in copies}) == 1
    positions = sorted(tuple(np.round(inst.matrix[:3, 3], 5)) for inst in balls if inst.matrix[2, 3] > -40)
    # Object Info's default 'Original' space: copies sit at the grid points.
    expected = sorted(tuple(np.round(np.array(grid.matrix_world @ v.co)[:3], 5))
                      for v in grid.data.vertices)
    np.testing.assert_allclose(positions, expected, atol=1e-5)


def test_instance_random_is_cycles_float32_of_random_id(empty_scene):
    """Object Info Random of geometry-nodes copies: random_id as uint32 in
    float32 times 2^-32, as Cycles (the export computes it without NumPy
    scalars: checked here against them, and on rounding edge cases)."""
    from addon.export.instances import uint32_unit_float32
    import importlib.util
    import os
    edges = [0, 1, 2 ** 24 - 1, 2 ** 24 + 1, 2 ** 24 + 3, 2 ** 25 + 2, 2 ** 31 + 192, 2 ** 32 - 129, 2 ** 32 - 1]
    for rid in edges + list(np.random.default_rng(2).integers(0, 2 ** 32, 5000)):
        assert uint32_unit_float32(int(rid)) == float(np.float32(int(rid)) * np.float32(2.0 ** -32)), rid
    spec = importlib.util.spec_from_file_location('build_scenes', os.path.join(SCENES_DIR, 'build_scenes.py'))
    build_scenes = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_scenes)
    bpy.ops.mesh.primitive_ico_sphere_add(location=(0, 0, -50))
    ball = bpy.context.object
    build_scenes._geometry_nodes_instancer(empty_scene, ball)
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ids = sorted(float(np.float32(inst.random_id & 0xFFFFFFFF) * np.float32(2.0 ** -32))
                 for inst in depsgraph.object_instances if inst.is_instance)
    exported = export()
    got = sorted(inst.random for inst in exported.scene.instances if inst.matrix[2, 3] > -40)
    assert len(ids) == 9 and got == ids


def test_particle_instances(empty_scene):
    bpy.ops.mesh.primitive_cube_add(size=0.1, location=(0, 0, -50))
    bpy.context.object.data.name = 'PCube'
    bpy.ops.mesh.primitive_plane_add(size=2)
    emitter = bpy.context.object
    emitter.data.name = 'Emitter'
    emitter.modifiers.new("P", 'PARTICLE_SYSTEM')
    settings = emitter.particle_systems[0].settings
    settings.type = 'HAIR'
    settings.count = 25
    settings.render_type = 'OBJECT'
    settings.instance_object = bpy.data.objects['Cube']
    bpy.context.view_layer.update()
    exported = export()
    assert len(instances_of(exported, 'PCube')) == 1 + 25
    assert len(instances_of(exported, 'Emitter')) == 1  # emitter shown by default
    emitter.show_instancer_for_render = False
    emitter.show_instancer_for_viewport = False
    bpy.context.view_layer.update()
    assert len(instances_of(export(), 'Emitter')) == 0


def test_blend_scene_instances(registered_addon):
    open_scene('instances_lights')
    exported = export()
    counts = {}
    for inst in exported.scene.instances:
        counts[exported.scene.meshes[inst.mesh].name] = counts.get(exported.scene.meshes[inst.mesh].name, 0) + 1
    assert counts['Pillar'] == 3 and counts['Ball'] == 9 and counts['Chip'] == 12
    assert len({m.name for m in exported.scene.meshes}) == len(exported.scene.meshes)
    assert exported.triangles == sum(len(exported.scene.meshes[i.mesh].triangles) for i in exported.scene.instances)


def test_hidden_objects_are_not_exported(factory_scene):
    cube = bpy.data.objects['Cube']
    cube.hide_viewport = True
    bpy.context.view_layer.update()
    assert instances_of(export(), 'Cube') == []


# ----------------------------------------------------------------------------
# lights and world

def add_light(scene, kind, **settings):
    data = bpy.data.lights.new(kind, kind)
    for key, value in settings.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(kind, data)
    scene.collection.objects.link(obj)
    return obj


def test_every_light_type(empty_scene):
    point = add_light(empty_scene, 'POINT', energy=100.0, color=(1.0, 0.5, 0.25), shadow_soft_size=0.3)
    point.location = (1, 2, 3)
    spot = add_light(empty_scene, 'SPOT', energy=50.0, spot_size=0.7, spot_blend=0.4)
    spot.rotation_euler = (math.pi / 2, 0, 0)  # -Z rotated to +Y
    sun = add_light(empty_scene, 'SUN', energy=3.0, angle=0.1)
    sun.rotation_euler = (0, math.pi / 2, 0)   # -Z rotated to -X
    area = add_light(empty_scene, 'AREA', energy=20.0, shape='ELLIPSE', size=2.0, size_y=0.5)
    area.scale = (2.0, 1.0, 1.0)
    bpy.context.view_layer.update()
    lights = {light.name: light for light in export().scene.lights}
    p = lights['POINT']
    assert p.position == pytest.approx((1, 2, 3)) and p.power == pytest.approx((100, 50, 25))
    assert p.radius == pytest.approx(0.3)
    # 3.x point lights are what 4.x calls soft falloff.
    assert p.soft_falloff == getattr(point.data, 'use_soft_falloff', True)
    s = lights['SPOT']
    assert s.direction == pytest.approx((0, 1, 0), abs=1e-6)
    assert (s.spot_size, s.spot_blend) == pytest.approx((0.7, 0.4))
    u = lights['SUN']
    assert u.direction == pytest.approx((-1, 0, 0), abs=1e-6) and u.strength == pytest.approx((3, 3, 3))
    assert u.angle == pytest.approx(0.1)
    a = lights['AREA']
    assert a.shape == 'ELLIPSE' and (a.size_x, a.size_y) == pytest.approx((2.0, 0.5))
    np.testing.assert_allclose(a.matrix, np.array(area.matrix_world))
    # Blender 4.0 scales 3.x area light energy by pi/4 when opening old files.
    legacy = math.pi / 4 if bpy.app.version < (4, 0, 0) else 1.0
    assert a.power == pytest.approx((20 * legacy,) * 3)


def test_light_exposure(empty_scene):
    light = add_light(empty_scene, 'POINT', energy=10.0)
    if not hasattr(light.data, 'exposure'):
        pytest.skip("light exposure exists from Blender 4.0 on")
    light.data.exposure = 2.0
    assert export().scene.lights[0].power == pytest.approx((40, 40, 40))


def test_black_light_is_dropped(empty_scene):
    add_light(empty_scene, 'POINT', energy=0.0)
    assert export().scene.lights == []


def test_world_background_color_times_strength(factory_scene):
    background = factory_scene.world.node_tree.nodes['Background']
    background.inputs['Color'].default_value = (0.2, 0.4, 0.6, 1.0)
    background.inputs['Strength'].default_value = 2.5
    assert export().scene.world.color == pytest.approx((0.5, 1.0, 1.5))


def test_world_without_nodes_and_without_world(factory_scene):
    world = factory_scene.world
    world.use_nodes = False
    world.color = (0.1, 0.2, 0.3)
    if world.use_nodes:  # 5.0 always uses nodes
        world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.1, 0.2, 0.3, 1)
    assert export().scene.world.color == pytest.approx((0.1, 0.2, 0.3))
    factory_scene.world = None
    assert export().scene.world.color == (0.0, 0.0, 0.0)


def test_world_texture_falls_back_with_warning(factory_scene):
    tree = factory_scene.world.node_tree
    sky = tree.nodes.new('ShaderNodeTexSky')
    sky.sky_type = 'HOSEK_WILKIE'
    sky.turbidity = float('nan')       # Cycles' sky is undefined: Ember does not evaluate it
    tree.links.new(sky.outputs[0], tree.nodes['Background'].inputs['Color'])
    exported = export()
    assert any("World" in w and "Hosek-Wilkie turbidity" in w for w in exported.warnings), exported.warnings
    assert np.isfinite(exported.scene.world.color).all()


def test_world_sky_of_this_blender_is_exported(factory_scene):
    """The default sky of each Blender (3.4 / 4.2: Nishita, 5.0: Multiple
    Scattering) becomes a world shaded per direction with its sun guided."""
    tree = factory_scene.world.node_tree
    sky = tree.nodes.new('ShaderNodeTexSky')
    tree.links.new(sky.outputs[0], tree.nodes['Background'].inputs['Color'])
    exported = export()
    assert not [w for w in exported.warnings if "World" in w], exported.warnings
    texture = exported.scene.world.texture
    assert texture is not None and texture.shader is not None and texture.sun is not None
    assert np.isfinite(texture.pixels).all() and texture.pixels.max() > 0
    props = texture.shader.call.props
    assert props['sky_type'] == sky.sky_type and props['_blender_version'] == tuple(bpy.app.version)


# ----------------------------------------------------------------------------
# materials

def new_material(name):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    return material, material.node_tree


def test_principled_translation(factory_scene):
    material, tree = new_material("Gold")
    p = tree.nodes['Principled BSDF']
    p.inputs['Base Color'].default_value = (1.0, 0.8, 0.2, 1.0)
    p.inputs['Metallic'].default_value = 0.25
    p.inputs['Roughness'].default_value = 0.3
    emission = 'Emission Color' if 'Emission Color' in p.inputs else 'Emission'
    p.inputs[emission].default_value = (1.0, 0.5, 0.0, 1.0)
    p.inputs['Emission Strength'].default_value = 2.0
    translated, warning = material_export.translate(material)
    assert warning is None
    # Cycles' Principled BSDF: metal (F82, F0 = base colour) mixed by
    # Metallic with a specular layer (IOR 1.5 default: F0 0.04) over diffuse.
    metal, specular, diffuse = translated.lobes
    assert metal.kind == 'glossy' and metal.fresnel == 'f82' and metal.weight == pytest.approx(0.25)
    assert metal.f0 == pytest.approx((1.0, 0.8, 0.2)) and metal.roughness == pytest.approx(0.3)
    assert specular.kind == 'glossy' and specular.fresnel == 'dielectric' and specular.covers == 1
    assert specular.weight == pytest.approx(0.75) and specular.roughness == pytest.approx(0.3)
    ior = p.inputs['IOR'].default_value
    f0 = ((ior - 1) / (ior + 1)) ** 2 if 'Specular IOR Level' in p.inputs else 0.08 * 0.5  # 3.x: Specular
    assert specular.f0 == pytest.approx((f0,) * 3, rel=1e-4)
    assert diffuse.kind == 'diffuse' and diffuse.color == pytest.approx((1.0, 0.8, 0.2))
    assert diffuse.weight == pytest.approx(0.75)
    assert translated.emission == pytest.approx((2.0, 1.0, 0.0))


def test_diffuse_glossy_emission_and_mix(factory_scene):
    material, tree = new_material("Mix")
    tree.nodes.remove(tree.nodes['Principled BSDF'])
    diffuse = tree.nodes.new('ShaderNodeBsdfDiffuse')
    diffuse.inputs['Color'].default_value = (0.5, 0.5, 0.5, 1)
    glossy = tree.nodes.new('ShaderNodeBsdfGlossy')
    glossy.inputs['Color'].default_value = (1, 1, 1, 1)
    glossy.inputs['Roughness'].default_value = 0.2
    emission = tree.nodes.new('ShaderNodeEmission')
    emission.inputs['Strength'].default_value = 3.0
    mix = tree.nodes.new('ShaderNodeMixShader')
    mix.inputs['Fac'].default_value = 0.25
    add = tree.nodes.new('ShaderNodeAddShader')
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glossy.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], add.inputs[0])
    tree.links.new(emission.outputs[0], add.inputs[1])
    tree.links.new(add.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    translated, warning = material_export.translate(material)
    assert warning is None
    kinds = [(lobe.kind, lobe.color, lobe.roughness, lobe.weight) for lobe in translated.lobes]
    # The Mix factor is the lobe's weight (colours stay the nodes' colours).
    assert kinds[0][0] == 'diffuse' and kinds[0][1] == pytest.approx((0.5,) * 3)
    assert kinds[0][3] == pytest.approx(0.75)
    assert kinds[1][0] == 'glossy' and kinds[1][1] == pytest.approx((1.0,) * 3)
    assert kinds[1][2] == pytest.approx(0.2) and kinds[1][3] == pytest.approx(0.25)
    assert translated.emission == pytest.approx((3.0, 3.0, 3.0))


def test_unsupported_nodes_fall_back_with_one_warning(factory_scene):
    material, tree = new_material("Weird")
    glass = tree.nodes.new('ShaderNodeBsdfToon')
    glass.inputs['Color'].default_value = (0.2, 0.9, 0.3, 1.0)
    wire = tree.nodes.new('ShaderNodeWireframe')   # a node Ember does not evaluate
    mix = tree.nodes.new('ShaderNodeMixShader')
    tree.links.new(wire.outputs['Fac'], mix.inputs['Fac'])
    tree.links.new(glass.outputs[0], mix.inputs[1])
    tree.links.new(tree.nodes['Principled BSDF'].outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    bpy.data.objects['Cube'].data.materials[0] = material
    exported = export()
    warnings = [w for w in exported.warnings if "'Weird'" in w]
    assert len(warnings) == 1
    assert glass.name in warnings[0] and 'Fac' in warnings[0]
    lobes = exported.scene.materials[0].lobes
    assert lobes[0].kind == 'diffuse' and lobes[0].color == pytest.approx((0.2, 0.9, 0.3))
    assert lobes[0].weight == pytest.approx(0.5)


def test_principled_layers_not_rendered_are_named(factory_scene):
    material, tree = new_material("Glassy")
    principled = tree.nodes['Principled BSDF']
    if 'Subsurface Weight' in principled.inputs:   # 4.x: subsurface is rendered (the random walk), no warning
        principled.inputs['Subsurface Weight'].default_value = 1.0
        translated, warning = material_export.translate(material)
        assert warning is None, warning
        assert [lobe.kind for lobe in translated.lobes] == ['glossy', 'subsurface']   # weight 1: no diffuse left
        return
    principled.inputs['Subsurface'].default_value = 1.0
    translated, warning = material_export.translate(material)
    assert warning is not None and 'Subsurface' in warning and principled.name in warning
    assert [lobe.kind for lobe in translated.lobes] == ['glossy', 'diffuse']


def test_principled_transmission_coat_sheen_alpha(factory_scene):
    """Every Principled layer Ember renders becomes its lobe, no warning."""
    material, tree = new_material("Layers")
    p = tree.nodes['Principled BSDF']
    four = 'Coat Weight' in p.inputs
    p.inputs['Transmission Weight' if four else 'Transmission'].default_value = 0.6
    p.inputs['Coat Weight' if four else 'Clearcoat'].default_value = 0.5
    p.inputs['Sheen Weight' if four else 'Sheen'].default_value = 0.4
    p.inputs['Alpha'].default_value = 0.8
    translated, warning = material_export.translate(material)
    assert warning is None
    kinds = [lobe.kind for lobe in translated.lobes]
    assert kinds == ['transparent', 'sheen', 'glossy', 'glass', 'glossy', 'diffuse']
    transparent, sheen, coat, glass, specular, diffuse = translated.lobes
    assert transparent.weight == pytest.approx(0.2)
    assert sheen.covers == 4 and coat.covers == 3 and specular.covers == 1
    assert coat.fresnel == 'dielectric' and coat.color == pytest.approx((0.5,) * 3)
    assert glass.weight == pytest.approx(0.8 * 0.6) and diffuse.weight == pytest.approx(0.8 * 0.4)


def test_no_surface_is_black(factory_scene):
    material, tree = new_material("Empty")
    tree.links.clear()
    translated, warning = material_export.translate(material)
    assert translated.lobes == () and translated.emission == (0.0, 0.0, 0.0) and warning is None


# ----------------------------------------------------------------------------
# camera

def test_camera_fields(factory_scene):
    cam = factory_scene.camera
    cam.scale = (2.0, 3.0, 0.5)  # ignored by Blender's camera
    data = cam.data
    data.lens, data.sensor_width, data.sensor_height, data.sensor_fit = 35.0, 30.0, 20.0, 'VERTICAL'
    data.shift_x, data.shift_y, data.clip_start, data.clip_end = 0.1, -0.2, 0.5, 80.0
    data.dof.use_dof, data.dof.aperture_fstop = True, 2.0
    target = bpy.data.objects['Cube']
    data.dof.focus_object = target
    render = factory_scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 640, 480, 50
    render.pixel_aspect_x, render.pixel_aspect_y = 2.0, 1.0
    bpy.context.view_layer.update()
    camera = export().scene.camera
    assert camera.resolution == (320, 240) and camera.pixel_aspect == (2.0, 1.0)
    assert (camera.lens, camera.sensor_width, camera.sensor_height, camera.sensor_fit) == (35.0, 30.0, 20.0, 'VERTICAL')
    assert (camera.shift_x, camera.shift_y) == pytest.approx((0.1, -0.2))
    assert (camera.clip_start, camera.clip_end) == pytest.approx((0.5, 80.0))
    rotation = np.array(cam.matrix_world.to_quaternion().to_matrix())
    np.testing.assert_allclose(camera.matrix[:3, :3], rotation, atol=1e-6)
    np.testing.assert_allclose(camera.matrix[:3, 3], cam.matrix_world.translation, atol=1e-6)
    view = -rotation[:, 2]
    expected = abs(np.dot(view, np.array(target.location) - np.array(cam.location)))
    assert camera.focus_distance == pytest.approx(expected, rel=1e-6)
    assert camera.fstop == 2.0 and camera.aperture_radius == pytest.approx(0.035 / 4.0)


@pytest.mark.parametrize("size,border", [
    ((100, 80), (0.1, 0.55, 0.25, 0.9)),
    ((333, 217), (0.123, 0.777, 0.301, 0.699)),
    ((64, 64), (0.0, 1.0, 0.0, 1.0)),
])
def test_border_window_matches_blender(factory_scene, size, border):
    render = factory_scene.render
    render.resolution_x, render.resolution_y = size
    render.resolution_percentage = 100
    render.use_border = True
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = border
    x, y, w, h = camera_export.border_window(render)
    # Blender truncates in single precision (render_init_from_main).
    f32 = np.float32
    assert x == int(f32(render.border_min_x) * f32(size[0]))
    assert w == int(f32(render.border_max_x) * f32(size[0])) - x
    assert y == int(f32(render.border_min_y) * f32(size[1]))
    assert h == int(f32(render.border_max_y) * f32(size[1])) - y
    camera = export().scene.camera
    if (w, h) == size:
        assert camera.border is None
    else:
        xmin, xmax, ymin, ymax = camera.border
        assert (round(xmin * size[0]), round(xmax * size[0])) == (x, x + w)
        assert (round(ymin * size[1]), round(ymax * size[1])) == (y, y + h)


def test_no_camera_is_a_clear_error(factory_scene):
    factory_scene.camera = None
    with pytest.raises(scene_export.ExportError, match="no active camera"):
        export()


def test_exported_blend_scenes_validate(registered_addon):
    from addon import backend
    try:
        validate_scene = backend.engine().validate_scene
    except ImportError as err:
        require(False, f"the engine is missing: {err}")
    for name in ('cornell', 'veach_mis', 'instances_lights'):
        open_scene(name)
        exported = export()
        validate_scene(exported.scene)
        assert exported.warnings == [], exported.warnings


def test_every_ember_panel_draws(factory_scene):
    """Run each Ember panel's draw() against a recording layout: every
    property it shows exists (a typo would only show up in a real UI)."""
    import types
    from addon import ui

    class Layout:
        use_property_split = False
        use_property_decorate = True

        def __init__(self):
            self.shown = []

        def prop(self, data, name, text=None):
            assert hasattr(data, name), name
            self.shown.append(name)

        def column(self):
            return self

        def row(self, heading=None):
            return self

    for cls in ui.classes:
        panel = types.SimpleNamespace(layout=Layout(), PROPS=cls.PROPS)
        panel.split_layout = lambda p=panel: ui.EmberPanel.split_layout(p)
        cls.draw(panel, bpy.context)
        assert panel.layout.shown, cls.__name__
    film = types.SimpleNamespace(layout=Layout(), PROPS=())
    film.split_layout = lambda: ui.EmberPanel.split_layout(film)
    factory_scene.ember.filter_type = 'BOX'
    ui.RENDER_PT_ember_film.draw(film, bpy.context)
    assert 'filter_width' not in film.layout.shown  # Cycles' box filter has no width


def test_volume_object_is_named_in_a_warning(factory_scene):
    """A Volume object Ember cannot render (here: no file, no grids; in
    bpy 4.2: no openvdb module) is named in a warning
    (tests/addon/test_volume_object_parity.py renders real ones)."""
    obj = bpy.data.objects.new("CloudVDB", bpy.data.volumes.new("CloudVDB"))
    factory_scene.collection.objects.link(obj)
    exported = export()
    assert any("CloudVDB" in w and "not rendered" in w for w in exported.warnings), exported.warnings
