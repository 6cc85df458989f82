"""Every registered shader node evaluates as in Cycles, per pixel.

One scene holds a quad per (node, property case, output) of
engine.nodes.REGISTRY: an Emission shader whose colour is the node's output
mapped by x * 0.25 + 0.5 (so signed values stay visible), seen from above by
an orthographic camera.  Cycles renders it with one sample, which sits at
each pixel centre (its first sample is never jittered); Ember evaluates the
same exported scene at the pixel centres (engine.nodes.probe).  Both are
deterministic, so every pixel must agree to float32 precision.

Quads are objects placed, scaled and coloured differently, with a corner
colour attribute, so object, generated and attribute inputs vary.  Nodes
without a Vector input read the Generated coordinates through their first
input (a vector into a float socket also exercises Cycles' implicit
conversion).  The parametrized test runs one check per registry entry on
the one shared render.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import render_array, require, small_resolution

TILE = 6            # pixels per quad side
COLUMNS = 24
# Cycles computes shading in float32; outputs pass x * 0.25 + 0.5.
ATOL = 4e-6
RTOL = 2e-5
SHIFT_Y_SIGN = 1.0


def _registry():
    from engine.nodes import REGISTRY
    return REGISTRY


def quad_cases():
    """[(idname, case index, props/inputs dict, output)] for every output
    the registry evaluates (Vector Math: the output its operation writes)."""
    cases = []
    scratch = bpy.data.materials.new("scratch")
    scratch.use_nodes = True
    for idname, entry in _registry().items():
        if not hasattr(bpy.types, idname):
            continue   # a node this Blender lacks (Gabor before 4.3)
        for k, case in enumerate(entry.cases or [{}]):
            node = scratch.node_tree.nodes.new(idname)
            _configure(node, idname, case)
            enabled = {s.identifier for s in node.outputs if getattr(s, 'enabled', True)}
            enabled |= {s.name for s in node.outputs if getattr(s, 'enabled', True)}
            for output, _ in entry.outputs:
                if output in entry.unsupported_outputs or output not in enabled:
                    continue
                if idname == 'ShaderNodeVectorMath':
                    value_op = case['operation'] in ('DOT_PRODUCT', 'DISTANCE', 'LENGTH')
                    if (output == 'Value') != value_op:
                        continue
                cases.append((idname, k, case, output))
    bpy.data.materials.remove(scratch)
    return cases


# ----------------------------------------------------------------------------
# scene

def _socket(sockets, identifier):
    for s in sockets:
        if s.identifier == identifier and getattr(s, 'enabled', True):
            return s
    for s in sockets:
        if s.name == identifier and getattr(s, 'enabled', True):
            return s
    return None


def _configure(node, idname, case):
    entry = _registry()[idname]
    for key, value in case.items():
        if key in ('ramp', 'curve') or value is None:
            continue
        if hasattr(node, key) and key not in dict(entry.inputs):
            setattr(node, key, value)
    for key, value in case.items():
        socket = _socket(node.inputs, key) if key in dict(entry.inputs) else None
        if socket is not None and value is not None:
            socket.default_value = value if isinstance(value, (int, float)) else tuple(value)[:len(socket.default_value)]
    if 'ramp' in case:
        ramp = node.color_ramp
        ramp.interpolation = case['ramp']
        ramp.elements[0].position, ramp.elements[0].color = 0.2, (0.9, 0.1, 0.2, 0.3)
        ramp.elements[1].position, ramp.elements[1].color = 0.8, (0.1, 0.3, 1.0, 1.0)
        mid = ramp.elements.new(0.55)
        mid.color = (0.2, 0.9, 0.4, 0.6)
    if 'curve' in case:
        mapping = node.mapping
        for curve in mapping.curves:
            curve.points.new(0.3, 0.15)
            curve.points.new(0.7, 0.9)
        mapping.update()


def _first_input(node, idname, case):
    """The input that receives the Generated coordinates (None: none)."""
    entry = _registry()[idname]
    if entry.coords is not None or not entry.inputs:
        return None
    if idname == 'ShaderNodeMix':
        return _socket(node.inputs, 'A_Vector')
    if idname == 'ShaderNodeMapRange' and case.get('data_type') == 'FLOAT_VECTOR':
        return _socket(node.inputs, 'Vector')
    for identifier, _ in entry.inputs:
        if identifier in case and case[identifier] is not None:
            continue
        socket = _socket(node.inputs, identifier)
        if socket is not None and identifier != 'Normal':
            return socket
    return None


def emission_material(name):
    """An empty material whose surface is an Emission shader: (material,
    tree, emission node)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    for n in list(tree.nodes):
        tree.nodes.remove(n)
    out = tree.nodes.new('ShaderNodeOutputMaterial')
    emission = tree.nodes.new('ShaderNodeEmission')
    tree.links.new(emission.outputs[0], out.inputs['Surface'])
    return mat, tree, emission


def build_material(idname, case, output):
    mat, tree, emission = emission_material(f"{idname}-{output}")
    node = tree.nodes.new(idname)
    _configure(node, idname, case)
    target = _first_input(node, idname, case)
    if target is not None:
        coords = tree.nodes.new('ShaderNodeTexCoord')
        tree.links.new(coords.outputs['Generated'], target)
    socket = _socket(node.outputs, output)
    assert socket is not None, (idname, output)
    kind = dict(_registry()[idname].outputs)[output]
    if kind == 'float':
        scale = tree.nodes.new('ShaderNodeMath')
        scale.operation = 'MULTIPLY_ADD'
        scale.inputs[1].default_value, scale.inputs[2].default_value = 0.25, 0.5
        tree.links.new(socket, scale.inputs[0])
    else:
        scale = tree.nodes.new('ShaderNodeVectorMath')
        scale.operation = 'MULTIPLY_ADD'
        scale.inputs[1].default_value, scale.inputs[2].default_value = (0.25,) * 3, (0.5,) * 3
        tree.links.new(socket, scale.inputs[0])
    tree.links.new(scale.outputs[0], emission.inputs['Color'])
    return mat


def add_quad(index, material, rows):
    x, y = index % COLUMNS, rows - 1 - index // COLUMNS
    mesh = bpy.data.meshes.new(f"quad{index}")
    # Starting the face at the second corner puts the triangles' shared edge
    # on x + y = 0, which no (shifted) pixel centre lies on: the triangle hit
    # is never ambiguous (Geometry Parametric jumps across that edge).
    mesh.from_pydata([(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0)], [], [(1, 2, 3, 0)])
    layer = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.polygons[0].loop_indices:
        co = mesh.vertices[mesh.loops[loop].vertex_index].co
        layer.data[loop].uv = (co.x + 0.5, co.y + 0.5)
    colors = mesh.color_attributes.new("Col", 'BYTE_COLOR', 'CORNER')
    for k, c in enumerate([(0.9, 0.2, 0.1, 1.0), (0.1, 0.8, 0.3, 0.5), (0.2, 0.3, 0.9, 1.0), (1.0, 1.0, 0.2, 0.2)]):
        colors.data[k].color = c
    mesh.materials.append(material)
    obj = bpy.data.objects.new(f"quad{index}", mesh)
    # A slight scale and a location per quad: Object coordinates and Object
    # Info differ from the world position; the image still tiles exactly.
    obj.location = (x + 0.5, y + 0.5, 0.1 * (index % 3))
    obj.pass_index = index
    obj.color = (0.3 + 0.05 * (index % 7), 0.6, 0.9 - 0.04 * (index % 11), 1.0)
    bpy.context.scene.collection.objects.link(obj)
    return obj


# ----------------------------------------------------------------------------
# structure cases: node groups, muted nodes, Mapping in materials

def _group(name, build):
    """A shader node group whose interface build(tree, group_in, group_out) fills."""
    group = bpy.data.node_groups.new(name, 'ShaderNodeTree')
    group_in = group.nodes.new('NodeGroupInput')
    group_out = group.nodes.new('NodeGroupOutput')
    build(group, group_in, group_out)
    return group


def _interface(group, name, in_out, socket_type, default=None):
    if hasattr(group, 'interface'):
        item = group.interface.new_socket(name, in_out=in_out, socket_type=socket_type)
    else:   # Blender before 4.0
        sockets = group.inputs if in_out == 'INPUT' else group.outputs
        item = sockets.new(socket_type, name)
    if default is not None:
        item.default_value = default
    return item


def _inner_group():
    """Value * Factor (Factor defaults to 2.5), a group used inside another."""
    def build(tree, gin, gout):
        _interface(tree, 'Value', 'INPUT', 'NodeSocketFloat', 0.0)
        _interface(tree, 'Factor', 'INPUT', 'NodeSocketFloat', 2.5)
        _interface(tree, 'Result', 'OUTPUT', 'NodeSocketFloat')
        math = tree.nodes.new('ShaderNodeMath')
        math.operation = 'MULTIPLY'
        tree.links.new(gin.outputs['Value'], math.inputs[0])
        tree.links.new(gin.outputs['Factor'], math.inputs[1])
        tree.links.new(math.outputs[0], gout.inputs['Result'])
    return _group("inner", build)


def _outer_group(inner):
    """Noise(scale from the group input) -> inner group -> Color Ramp."""
    def build(tree, gin, gout):
        _interface(tree, 'Scale', 'INPUT', 'NodeSocketFloat', 3.0)
        _interface(tree, 'Color', 'OUTPUT', 'NodeSocketColor')
        noise = tree.nodes.new('ShaderNodeTexNoise')
        tree.links.new(gin.outputs['Scale'], noise.inputs['Scale'])
        nested = tree.nodes.new('ShaderNodeGroup')
        nested.node_tree = inner
        tree.links.new(noise.outputs['Fac'], nested.inputs['Value'])
        ramp = tree.nodes.new('ShaderNodeValToRGB')
        ramp.color_ramp.elements[0].color = (0.1, 0.2, 0.6, 1.0)
        tree.links.new(nested.outputs['Result'], ramp.inputs['Fac'])
        reroute = tree.nodes.new('NodeReroute')
        tree.links.new(ramp.outputs['Color'], reroute.inputs[0])
        tree.links.new(reroute.outputs[0], gout.inputs['Color'])
    return _group("outer", build)


def _structure_group_default(tree):
    group = tree.nodes.new('ShaderNodeGroup')
    group.node_tree = bpy.data.node_groups.get('outer') or _outer_group(_inner_group())
    return group.outputs['Color']


def _structure_group_linked(tree):
    group = tree.nodes.new('ShaderNodeGroup')
    group.node_tree = bpy.data.node_groups.get('outer') or _outer_group(_inner_group())
    value = tree.nodes.new('ShaderNodeValue')
    value.outputs[0].default_value = 7.0
    tree.links.new(value.outputs[0], group.inputs['Scale'])
    return group.outputs['Color']


def _structure_muted(tree):
    """A muted Invert passes its Color through; a muted Math its first value."""
    coords = tree.nodes.new('ShaderNodeTexCoord')
    invert = tree.nodes.new('ShaderNodeInvert')
    tree.links.new(coords.outputs['Generated'], invert.inputs['Color'])
    invert.mute = True
    math = tree.nodes.new('ShaderNodeMath')
    math.operation = 'POWER'
    tree.links.new(invert.outputs['Color'], math.inputs[0])
    math.mute = True
    mix = tree.nodes.new('ShaderNodeMix')
    mix.data_type = 'RGBA'
    sockets = {s.identifier: s for s in mix.inputs}
    tree.links.new(math.outputs[0], sockets['Factor_Float'])
    tree.links.new(invert.outputs['Color'], sockets['A_Color'])
    sockets['B_Color'].default_value = (0.9, 0.1, 0.3, 1.0)
    return mix.outputs[2]


def _structure_mapping_object(tree):
    """Mapping (rotated, scaled) on Object coordinates into a Checker, the
    texture's own hidden texture_mapping scaled too."""
    coords = tree.nodes.new('ShaderNodeTexCoord')
    mapping = tree.nodes.new('ShaderNodeMapping')
    mapping.inputs['Rotation'].default_value = (0.0, 0.0, 0.4)
    mapping.inputs['Scale'].default_value = (1.5, 0.7, 1.0)
    tree.links.new(coords.outputs['Object'], mapping.inputs['Vector'])
    checker = tree.nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 3.0
    tree.links.new(mapping.outputs['Vector'], checker.inputs['Vector'])
    return checker.outputs['Color']


def _structure_texture_mapping(tree):
    wave = tree.nodes.new('ShaderNodeTexWave')
    wave.texture_mapping.scale = (2.0, 1.0, 1.0)
    wave.texture_mapping.rotation = (0.0, 0.0, 0.3)
    wave.texture_mapping.translation = (0.1, 0.2, 0.0)
    return wave.outputs['Fac']


def _affine(tree, socket, scale, offset):
    node = tree.nodes.new('ShaderNodeMath')
    node.operation = 'MULTIPLY_ADD'
    node.inputs[1].default_value, node.inputs[2].default_value = scale, offset
    tree.links.new(socket, node.inputs[0])
    return node.outputs[0]


def _structure_math(operation):
    """Math (an engine expression, not a registry node) on a = 4x - 2,
    b = 3y - 1, c = 0.3 over the quad, shown as 0.02 r + 0.5 (kept positive:
    Ember clips negative emission, Cycles does not)."""
    def build(tree):
        coords = tree.nodes.new('ShaderNodeTexCoord')
        xyz = tree.nodes.new('ShaderNodeSeparateXYZ')
        tree.links.new(coords.outputs['Generated'], xyz.inputs[0])
        math = tree.nodes.new('ShaderNodeMath')
        math.operation = operation
        tree.links.new(_affine(tree, xyz.outputs['X'], 4.0, -2.0), math.inputs[0])
        tree.links.new(_affine(tree, xyz.outputs['Y'], 3.0, -1.0), math.inputs[1])
        math.inputs[2].default_value = 0.3
        return _affine(tree, math.outputs[0], 0.002 if operation == 'DEGREES' else 0.02, 0.5)
    return build


def _structure_blend(blend):
    """Mix Color blends of the Generated colour with a constant, factor x."""
    def build(tree):
        coords = tree.nodes.new('ShaderNodeTexCoord')
        xyz = tree.nodes.new('ShaderNodeSeparateXYZ')
        tree.links.new(coords.outputs['Generated'], xyz.inputs[0])
        mix = tree.nodes.new('ShaderNodeMix')
        mix.data_type = 'RGBA'
        mix.blend_type = blend
        sockets = {s.identifier: s for s in mix.inputs}
        tree.links.new(xyz.outputs['X'], sockets['Factor_Float'])
        tree.links.new(coords.outputs['Generated'], sockets['A_Color'])
        sockets['B_Color'].default_value = (0.8, 0.3, 0.5, 1.0)
        shown = tree.nodes.new('ShaderNodeVectorMath')   # 0.5 c + 0.5: Subtract and Linear Light go negative
        shown.operation = 'MULTIPLY_ADD'
        shown.inputs[1].default_value, shown.inputs[2].default_value = (0.5,) * 3, (0.5,) * 3
        tree.links.new(mix.outputs[2], shown.inputs[0])
        return shown.outputs[0]
    return build


# Extra tolerance: Wave multiplies coordinates by Scale * 20 = 100, so the
# float32 rounding of Cycles' mapping matrix (Ember maps in float64) shows.
STRUCTURE_TOLERANCE = {'hidden texture mapping': 2e-4}
STRUCTURES = {
    'group with defaults': _structure_group_default,
    'group with a linked input': _structure_group_linked,
    'muted nodes': _structure_muted,
    'mapping on object coordinates': _structure_mapping_object,
    'hidden texture mapping': _structure_texture_mapping,
}
STRUCTURES.update({f'math {op}': _structure_math(op) for op in (
    'ADD', 'SUBTRACT', 'MULTIPLY', 'DIVIDE', 'MULTIPLY_ADD', 'POWER', 'LOGARITHM', 'SQRT', 'INVERSE_SQRT',
    'ABSOLUTE', 'EXPONENT', 'MINIMUM', 'MAXIMUM', 'LESS_THAN', 'GREATER_THAN', 'SIGN', 'COMPARE',
    'SMOOTH_MIN', 'SMOOTH_MAX', 'ROUND', 'FLOOR', 'CEIL', 'TRUNC', 'FRACT', 'MODULO', 'FLOORED_MODULO',
    'WRAP', 'SNAP', 'PINGPONG', 'SINE', 'COSINE', 'TANGENT', 'ARCSINE', 'ARCCOSINE', 'ARCTANGENT',
    'ARCTAN2', 'SINH', 'COSH', 'TANH', 'RADIANS', 'DEGREES')})
STRUCTURES.update({f'mix {blend}': _structure_blend(blend) for blend in (
    'MIX', 'DARKEN', 'MULTIPLY', 'BURN', 'LIGHTEN', 'SCREEN', 'DODGE', 'ADD', 'OVERLAY', 'SOFT_LIGHT',
    'LINEAR_LIGHT', 'DIFFERENCE', 'EXCLUSION', 'SUBTRACT', 'DIVIDE', 'HUE', 'SATURATION', 'COLOR', 'VALUE')})


def build_structure_material(name):
    mat, tree, emission = emission_material(name)
    tree.links.new(STRUCTURES[name](tree), emission.inputs['Color'])
    return mat


def build_scene(cases):
    bpy.ops.wm.read_factory_settings()
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scene = bpy.context.scene
    rows = (len(cases) + COLUMNS - 1) // COLUMNS
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = 'ORTHO'
    cam_data.ortho_scale = COLUMNS
    cam_data.sensor_fit = 'HORIZONTAL'   # the scale spans the columns even when rows outnumber them
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (COLUMNS / 2, rows / 2, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.world.use_nodes = False
    scene.world.color = (0.0, 0.0, 0.0)
    small_resolution(scene, COLUMNS * TILE, rows * TILE)
    for index, (idname, _, case, output) in enumerate(cases):
        material = (build_structure_material(idname) if idname in STRUCTURES
                    else build_material(idname, case, output))
        add_quad(index, material, rows)
    return scene


def render_cycles(scene, folder):
    scene.render.engine = 'CYCLES'
    cycles = scene.cycles
    cycles.device = 'CPU'
    cycles.samples = 1
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.pixel_filter_type = 'BOX'
    cycles.max_bounces = 0
    scene.view_settings.view_transform = 'Standard'
    return render_array(scene, folder, "node_parity")[..., :3]


@pytest.fixture(scope='module')
def parity(registered_addon, tmp_path_factory):
    """(cases, Cycles image, Ember image, warnings) of the one shared scene."""
    from addon import backend
    from addon.export.scene import export_scene
    from engine.nodes import probe   # the repository's engine, which the add-on loads here
    bpy.ops.wm.read_factory_settings()
    cases = quad_cases() + [(name, 0, {}, 'Color') for name in STRUCTURES]
    scene = build_scene(cases)
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    shift = cycles_first_sample_offset()
    ember, _ = probe.emission_at_pixel_centres(exported.scene, offset=(shift, SHIFT_Y_SIGN * shift))
    cycles = render_cycles(scene, tmp_path_factory.mktemp("nodes"))
    return cases, cycles, ember, exported.warnings


def cycles_first_sample_offset(resolution=1024):
    """Where Cycles' first sample (filter table read at u = 0.5) sits from
    the pixel centre, in pixels, for its box filter: the table is the
    inverted CDF built symmetric from its middle entry (film.cpp /
    util_cdf_inverted), and reading between entries 511 and 512 lands half
    an entry off the centre (about 5e-4 pixel)."""
    cdf = np.arange(resolution + 1) / resolution          # box filter: a linear CDF
    half = (resolution - 1) // 2
    x = 1.0 / half
    index = int(np.searchsorted(cdf, x, side='right'))
    t = (x - cdf[index]) / (cdf[index + 1] - cdf[index])
    y = ((index + t) / (resolution - 1)) * (2.0 * 0.5)
    entry_512 = 0.5 * (1.0 + y)
    return 0.5 * (0.5 + entry_512) - 0.5


def _blocks(image, index, rows):
    x, y = index % COLUMNS, index // COLUMNS
    return image[y * TILE:(y + 1) * TILE, x * TILE:(x + 1) * TILE]


@pytest.mark.parametrize('idname', sorted(i for i in _registry() if not i.startswith('Ember')))  # Blender's nodes
def test_node_matches_cycles_per_pixel(parity, idname):
    cases, cycles, ember, warnings = parity
    # A shape mismatch is a failure of the test set-up, not a missing prerequisite.
    assert cycles.shape == ember.shape, f"images differ in shape {cycles.shape} vs {ember.shape}"
    rows = (len(cases) + COLUMNS - 1) // COLUMNS
    failures = []
    for index, (name, k, case, output) in enumerate(cases):
        if name != idname:
            continue
        want = _blocks(cycles, index, rows)
        got = _blocks(ember, index, rows)
        atol = ATOL + _registry()[idname].tolerance
        bad = ~np.isclose(got, want, atol=atol, rtol=RTOL)
        if bad.any():
            err = np.abs(got - want).max()
            failures.append(f"case {k} {case} output {output}: {int(bad.sum())} values off, max |error| {err:.3g}")
    assert not [w for w in warnings if idname in w], warnings
    assert not failures, "\n".join(failures)


def test_every_registered_node_is_in_the_scene(parity):
    cases = parity[0]
    # Ember's own entries (EmberPrincipledHairRandom: no Blender node) are not in it.
    blender_nodes = {idname for idname in _registry() if not idname.startswith('Ember')}
    assert {c[0] for c in cases} == blender_nodes | set(STRUCTURES)


@pytest.mark.parametrize('name', sorted(STRUCTURES))
def test_node_structures_match_cycles_per_pixel(parity, name):
    """Node groups (nested, defaults and linked inputs), muted nodes,
    reroutes, Mapping and hidden texture mappings: inlined as Cycles does."""
    cases, cycles, ember, warnings = parity
    rows = (len(cases) + COLUMNS - 1) // COLUMNS
    index = next(i for i, c in enumerate(cases) if c[0] == name)
    want, got = _blocks(cycles, index, rows), _blocks(ember, index, rows)
    assert want.std() > 1e-4, "the case must vary over its quad"
    assert not [w for w in warnings if name in w], warnings
    np.testing.assert_allclose(got, want, atol=ATOL + STRUCTURE_TOLERANCE.get(name, 0.0), rtol=RTOL)


def test_unevaluated_node_variants_fall_back_with_one_warning(registered_addon):
    """An Object Info Material Index feeds an input: it falls back to the
    socket's constant, named in the warning; a Light Path Portal Depth,
    rendered now, is not.  (It was a Geometry Tangent, which is rendered
    now too.)"""
    from addon.export import material as material_export
    bpy.ops.wm.read_factory_settings()
    mat = bpy.data.materials.new("Unrendered")
    mat.use_nodes = True
    tree = mat.node_tree
    principled = tree.nodes['Principled BSDF']
    coords = tree.nodes.new('ShaderNodeLightPath')
    geometry = tree.nodes.new('ShaderNodeObjectInfo')
    tree.links.new(coords.outputs['Portal Depth'], principled.inputs['Roughness'])
    tree.links.new(geometry.outputs['Material Index'], principled.inputs['Metallic'])
    translated, warning = material_export.translate(mat)
    assert warning is not None and warning.count("'Unrendered'") == 1, warning
    assert geometry.name in warning and "'Material Index'" in warning
    assert "'Portal Depth'" not in warning and coords.name not in warning, warning
    from addon import backend
    textures = backend.engine().TEXTURE_TYPES
    assert translated.lobes
    assert [lobe for lobe in translated.lobes if isinstance(lobe.roughness, textures)]
    assert not [lobe for lobe in translated.lobes if isinstance(lobe.weight, textures)]


def test_displacement_output_becomes_bump_only(registered_addon):
    """Material Output Displacement (via a Displacement node) renders as
    Cycles' default "Bump Only": a bump of (Height - Midlevel) * Scale
    over the BSDF's own normal map."""
    from addon.export import material as material_export
    from addon import backend
    scene = backend.engine()
    bpy.ops.wm.read_factory_settings()
    mat = bpy.data.materials.new("Displaced")
    mat.use_nodes = True
    tree = mat.node_tree
    noise = tree.nodes.new('ShaderNodeTexNoise')
    displacement = tree.nodes.new('ShaderNodeDisplacement')
    displacement.inputs['Midlevel'].default_value = 0.4
    displacement.inputs['Scale'].default_value = 0.2
    tree.links.new(noise.outputs['Fac'], displacement.inputs['Height'])
    tree.links.new(displacement.outputs[0], tree.nodes['Material Output'].inputs['Displacement'])
    normal_map = tree.nodes.new('ShaderNodeNormalMap')
    normal_map.space = 'OBJECT'
    normal_map.inputs['Color'].default_value = (0.6, 0.5, 1.0, 1.0)
    tree.links.new(normal_map.outputs[0], tree.nodes['Principled BSDF'].inputs['Normal'])
    translated, warning = material_export.translate(mat)
    assert warning is None, warning
    bump = translated.normal
    assert isinstance(bump, scene.Bump) and bump.strength == 1.0 and bump.distance == 1.0
    assert isinstance(bump.normal, scene.NormalMap) and bump.normal.space == 'OBJECT'
    # The height: (noise - 0.4) * 0.2, evaluated through the engine.
    from engine.nodes import ShadingContext
    from engine.textures import Compiler
    ctx = ShadingContext(3, p=np.array([[0.1, 0.2, 0.3], [1.0, 0.5, 0.2], [0.3, 0.9, 0.7]]))
    height = Compiler().value(bump.height)(ctx)
    fac = Compiler().value(scene.NodeOutput(bump.height.a.a.call, 'Fac'))(ctx)
    np.testing.assert_allclose(height, (fac - 0.4) * 0.2, rtol=1e-6)
    assert translated.displacement is None
    # "Displacement and Bump": the same bump, on the undisplaced surface, plus true displacement.
    mat.displacement_method = 'BOTH'
    both, warning = material_export.translate(mat)
    assert warning is None, warning
    assert isinstance(both.normal, scene.Bump) and both.normal.undisplaced
    assert both.displacement.method == 'BOTH' and both.displacement.space == 'OBJECT'
    np.testing.assert_allclose(Compiler().value(both.displacement.height)(ctx), height, rtol=1e-6)
    mat.displacement_method = 'DISPLACEMENT'
    only, _ = material_export.translate(mat)
    assert isinstance(only.normal, scene.NormalMap) and only.displacement.method == 'DISPLACEMENT'


def test_bump_filter_width_is_exported(registered_addon):
    """The Bump node's Filter Width (Blender 4.3+) reaches the engine's Bump
    (Cycles moves the height's copies by it); a linked width is its
    socket's value, named in the warning."""
    from addon.export import material as material_export
    bpy.ops.wm.read_factory_settings()
    mat = bpy.data.materials.new("Bumped")
    mat.use_nodes = True
    tree = mat.node_tree
    noise = tree.nodes.new('ShaderNodeTexNoise')
    bump = tree.nodes.new('ShaderNodeBump')
    tree.links.new(noise.outputs['Fac'], bump.inputs['Height'])
    tree.links.new(bump.outputs['Normal'], tree.nodes['Principled BSDF'].inputs['Normal'])
    bump.inputs['Filter Width'].default_value = 0.35
    translated, warning = material_export.translate(mat)
    assert warning is None, warning
    assert translated.normal.filter_width == pytest.approx(0.35, rel=1e-6)
    tree.links.new(noise.outputs['Fac'], bump.inputs['Filter Width'])
    translated, warning = material_export.translate(mat)
    assert translated.normal.filter_width == pytest.approx(0.35, rel=1e-6)
    assert warning is not None and "Filter Width" in warning, warning


def test_light_node_tree_scales_the_light(registered_addon):
    """A light whose Emission colour is a Blackbody (and strength 2) emits
    colour x energy x Blackbody x 2; a tree varying over the light becomes
    the light's shader."""
    from addon.export.light import collect_lights
    from engine.nodes.converter_nodes import blackbody_rec709
    bpy.ops.wm.read_factory_settings()
    light = bpy.data.objects['Light']
    data = light.data
    data.energy = 100.0
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    emission.inputs['Strength'].default_value = 2.0
    black = tree.nodes.new('ShaderNodeBlackbody')
    black.inputs['Temperature'].default_value = 3200.0
    tree.links.new(black.outputs[0], emission.inputs['Color'])
    lights, warnings = collect_lights(bpy.context.evaluated_depsgraph_get())
    assert not warnings, warnings
    want = 100.0 * 2.0 * np.maximum(blackbody_rec709(np.array([3200.0])), 0.0)[0] * np.array(data.color)
    np.testing.assert_allclose(lights[0].power, want, rtol=1e-6)
    noise = tree.nodes.new('ShaderNodeTexNoise')
    tree.links.new(noise.outputs['Color'], emission.inputs['Color'])
    lights, warnings = collect_lights(bpy.context.evaluated_depsgraph_get())
    # Varying over the light: evaluated per light point (engine/lights/shader.py), the power left alone.
    assert not warnings, warnings
    assert lights[0].shader is not None
    np.testing.assert_allclose(lights[0].power, 100.0 * np.array(data.color), rtol=1e-6)


def test_light_tree_path_outputs_and_unsupported_nodes(registered_addon):
    """In a light's tree, as Cycles evaluates it (PATH_RAY_EMISSION): a
    Light Path ray kind reads 0 (an 'Is Camera Ray' x 9 + 1 Strength is a
    plain light), a depth makes the tree the light's per-point shader; a
    node Ember cannot translate (Wireframe) gives its input's default and is
    named once, as in materials, while the rest of the tree still applies."""
    from addon.export.light import collect_lights
    bpy.ops.wm.read_factory_settings()
    data = bpy.data.objects['Light'].data
    data.energy = 100.0
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    path = tree.nodes.new('ShaderNodeLightPath')
    gain = tree.nodes.new('ShaderNodeMath')
    gain.operation = 'MULTIPLY_ADD'
    gain.inputs[1].default_value = 9.0
    gain.inputs[2].default_value = 1.0
    tree.links.new(path.outputs['Is Camera Ray'], gain.inputs[0])
    tree.links.new(gain.outputs[0], emission.inputs['Strength'])
    lights, warnings = collect_lights(bpy.context.evaluated_depsgraph_get())
    assert not warnings, warnings
    assert lights[0].shader is None
    np.testing.assert_allclose(lights[0].power, 100.0 * np.array(data.color), rtol=1e-6)
    tree.links.new(path.outputs['Ray Depth'], gain.inputs[0])
    lights, warnings = collect_lights(bpy.context.evaluated_depsgraph_get())
    assert not warnings, warnings
    assert lights[0].shader is not None
    wire = tree.nodes.new('ShaderNodeWireframe')
    mix = tree.nodes.new('ShaderNodeMix')
    mix.data_type = 'RGBA'
    mix.inputs['A'].default_value = (1.0, 0.0, 0.0, 1.0)
    mix.inputs['B'].default_value = (0.0, 0.0, 1.0, 1.0)
    tree.links.new(wire.outputs['Fac'], mix.inputs['Factor'])
    tree.links.new(mix.outputs['Result'], emission.inputs['Color'])
    lights, warnings = collect_lights(bpy.context.evaluated_depsgraph_get())
    assert len(warnings) == 1 and wire.name in warnings[0] and 'not translated' in warnings[0], warnings
    assert lights[0].shader is not None   # the Ray Depth Strength still applies
