"""RenderEngine.bake (issue 26): bpy.ops.object.bake with Ember against
Cycles' bake of the same object, per texel.

Scene: a smooth UV sphere, rotated, scaled and moved (the object transform
matters for Position and Normal), baked into a 32 x 32 float image.  The
exact types (Position, Normal in world, object and tangent space with a
swizzle, UV) must match Cycles within float tolerance in the texels both
fill (Cycles at 1 sample: the texel centre, as Ember).  Blender applies the
margin after the engine returns, so it is off here (margin 0) to compare
the engine's texels only; one run with Blender's margin checks it is still
applied around Ember's texels.  Hostile input: a type Ember does not bake
yet, an object without UV map, a non-mesh object: a clear error, no crash.
Shaded types (Emit, Roughness) of textured closures: the render's node
evaluation at each texel against Cycles' bake, per texel.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import empty_factory_scene

SIZE = 32
SCALE = (1.0, 1.5, 0.8)   # non-uniform: normals through the inverse transpose, per corner as Cycles


def bake_target_material():
    """A material whose active node is an Image Texture on a new SIZE x SIZE
    float image: where bpy.ops.object.bake writes."""
    image = bpy.data.images.new("bake_target", SIZE, SIZE, float_buffer=True, alpha=True)
    mat = bpy.data.materials.new("bake_mat")
    mat.use_nodes = True
    node = mat.node_tree.nodes.new('ShaderNodeTexImage')
    node.image = image
    mat.node_tree.nodes.active = node
    return mat, image


def _scene():
    scene = empty_factory_scene()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=1.0, location=(0.3, -0.2, 0.5),
                                         rotation=(0.4, 0.2, 0.7))
    obj = bpy.context.active_object
    obj.scale = SCALE
    bpy.ops.object.shade_smooth()
    mat, image = bake_target_material()
    obj.data.materials.append(mat)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    return scene, obj, image


def _bake(scene, image, engine, kind, margin=0, **settings):
    scene.render.engine = engine
    if engine == 'CYCLES':
        scene.cycles.samples = 1
        scene.cycles.device = 'CPU'
    else:
        scene.ember.samples = 1
    scene.render.bake.margin = margin
    for key, value in settings.items():
        setattr(scene.render.bake, key, value)
    image.pixels.foreach_set(np.zeros(SIZE * SIZE * 4, np.float32))
    bpy.ops.object.bake(type=kind, margin=margin, **{k: v for k, v in settings.items()})
    out = np.empty(SIZE * SIZE * 4, np.float32)
    image.pixels.foreach_get(out)
    return out.reshape(SIZE, SIZE, 4)


CASES = [
    ('POSITION', {}),
    ('NORMAL', {'normal_space': 'OBJECT'}),
    ('NORMAL', {'normal_space': 'TANGENT'}),
    ('NORMAL', {'normal_space': 'OBJECT', 'normal_r': 'NEG_Y', 'normal_g': 'POS_Z', 'normal_b': 'NEG_X'}),
]


@pytest.mark.parametrize("kind,settings", CASES, ids=[c[0] + "-" + "-".join(map(str, c[1].values())) for c in CASES])
def test_exact_bakes_match_cycles(kind, settings):
    scene, obj, image = _scene()
    cycles = _bake(scene, image, 'CYCLES', kind, **settings)
    ember = _bake(scene, image, 'EMBER', kind, **settings)
    filled = (np.abs(cycles[..., :3]).sum(axis=2) > 0) & (np.abs(ember[..., :3]).sum(axis=2) > 0)
    both = int(filled.sum())
    diff = np.abs(ember[..., :3] - cycles[..., :3])[filled]
    print(kind, "centre texel: Cycles", cycles[16, 10], "Ember", ember[16, 10])
    diff = np.append(diff.ravel(), np.inf if both == 0 else 0.0)
    print(f"{kind} {settings}: {both} texels filled by both (Cycles {int((np.abs(cycles[..., :3]).sum(2) > 0).sum())},"
          f" Ember {int((np.abs(ember[..., :3]).sum(2) > 0).sum())}), max |diff| {diff.max():.2e}")
    assert both > 0.5 * SIZE * SIZE, "too few texels baked to compare"
    # Both fill the same texels (Blender decides which), the values agree within float rounding.
    assert ((np.abs(cycles[..., :3]).sum(axis=2) > 0) == (np.abs(ember[..., :3]).sum(axis=2) > 0)).mean() > 0.99
    assert diff.max() < 2e-4


def test_uv_bake_is_the_texel_uv():
    """A UV bake writes, in each texel, the UV that maps to that texel: its
    centre ((x + 0.5) / 32, (y + 0.5) / 32) within float rounding (Blender
    samples texel centres).  Not against Cycles: bpy 5.0.1's Cycles bakes UV
    as 0 in every texel of this sphere (measured; its UV pass needs the UV
    attribute requested by a shader, which a bake does not do)."""
    scene, obj, image = _scene()
    ember = _bake(scene, image, 'EMBER', 'UV')
    filled = ember[..., 3] > 0
    ys, xs = np.nonzero(filled)
    expected = np.stack([(xs + 0.5) / SIZE, (ys + 0.5) / SIZE], axis=1)
    diff = np.abs(ember[ys, xs, :2] - expected)
    print(f"UV: {len(xs)} texels, max |uv - texel centre| {diff.max():.2e}")
    assert len(xs) > 0.5 * SIZE * SIZE
    assert diff.max() < 1e-4
    assert np.all(ember[ys, xs, 2] == 0)


def test_margin_applied_by_blender():
    scene, obj, image = _scene()
    bare = _bake(scene, image, 'EMBER', 'POSITION', margin=0)
    padded = _bake(scene, image, 'EMBER', 'POSITION', margin=4)
    empty = np.abs(bare[..., :3]).sum(axis=2) == 0
    grown = np.abs(padded[..., :3]).sum(axis=2) > 0
    assert (empty & grown).sum() > 0, "Blender's margin filled no texel around Ember's bake"
    inside = ~empty
    assert np.abs(padded[inside] - bare[inside]).max() < 1e-6


@pytest.mark.parametrize("case", ["unsupported_type", "no_uv", "non_mesh"])
def test_hostile_bakes_report_clearly(case, monkeypatch):
    scene, obj, image = _scene()
    scene.render.engine = 'EMBER'
    kind = 'POSITION'
    if case == "unsupported_type":
        # Ember bakes every type Blender offers: a type it does not know is played by SHADOW
        from addon import backend
        bake = backend.engine().bake
        monkeypatch.setattr(bake, 'SUPPORTED', tuple(k for k in bake.SUPPORTED if k != 'SHADOW'))
        kind = 'SHADOW'
    elif case == "no_uv":
        obj.data.uv_layers.remove(obj.data.uv_layers[0])
    else:
        bpy.ops.object.empty_add(location=(3, 0, 0))
        empty = bpy.context.active_object
        bpy.context.view_layer.objects.active = empty
        obj.select_set(False)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.object.bake(type=kind, margin=0)
    message = str(err.value)
    print(case, "->", message.strip())
    if case == "unsupported_type":
        assert "Ember" in message and "SHADOW" in message
    else:
        assert message.strip()   # Blender's own check, before Ember is called
    pixels = np.empty(SIZE * SIZE * 4, np.float32)
    image.pixels.foreach_get(pixels)
    assert np.isfinite(pixels).all()


@pytest.mark.parametrize("kind", ["POSITION", "NORMAL"])
def test_selected_to_active_matches_cycles(kind):
    """Selected to active with extrusion: Blender casts the rays from the
    active object onto the selected one and hands the engine the selected
    object's texels; Ember bakes them as Cycles."""
    scene, obj, image = _scene()
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=1.05, location=obj.location)
    high = bpy.context.active_object
    high.scale = SCALE
    high.rotation_euler = (0.1, 0.5, 0.2)
    high.select_set(True)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    settings = {'use_selected_to_active': True, 'cage_extrusion': 0.2}
    if kind == 'NORMAL':
        settings['normal_space'] = 'OBJECT'
    cycles = _bake(scene, image, 'CYCLES', kind, **settings)
    ember = _bake(scene, image, 'EMBER', kind, **settings)
    filled = ember[..., 3] > 0
    diff = np.abs(ember[..., :3] - cycles[..., :3])[filled]
    print(f"selected to active {kind}: {int(filled.sum())} texels, max |diff| {diff.max():.2e}")
    assert filled.sum() > 0.5 * SIZE * SIZE
    assert diff.max() < 2e-4
    high.select_set(False)   # the active object's own bake differs: the test sees which object was baked
    own = _bake(scene, image, 'EMBER', kind, **dict(settings, use_selected_to_active=False))
    assert np.abs(own[..., :3] - ember[..., :3])[filled].max() > 1e-2


def _shaded_material(obj, kind):
    """The sphere's material with a textured closure: a Checker on the UV map
    (and a Noise on the position for the Principled case) into the
    emission colour / the roughness; the bake target stays the active,
    unlinked image node."""
    mat = obj.data.materials[0]
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    out = next(n for n in nodes if n.type == 'OUTPUT_MATERIAL')
    coords = nodes.new('ShaderNodeTexCoord')
    checker = nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 3.0
    checker.inputs['Color1'].default_value = (0.9, 0.3, 0.1, 1.0)
    checker.inputs['Color2'].default_value = (0.1, 0.4, 0.8, 1.0)
    links.new(coords.outputs['UV'], checker.inputs['Vector'])
    if kind == 'emission':
        shader = nodes.new('ShaderNodeEmission')
        shader.inputs['Strength'].default_value = 2.5
        links.new(checker.outputs['Color'], shader.inputs['Color'])
    elif kind == 'principled':
        shader = nodes.get('Principled BSDF') or nodes.new('ShaderNodeBsdfPrincipled')
        noise = nodes.new('ShaderNodeTexNoise')
        noise.inputs['Scale'].default_value = 2.0
        links.new(coords.outputs['Object'], noise.inputs['Vector'])
        links.new(checker.outputs['Color'], shader.inputs['Emission Color'])
        links.new(noise.outputs['Fac'], shader.inputs['Emission Strength'])
    else:   # roughness: a Glossy BSDF whose roughness is the checker's factor, remapped
        shader = nodes.new('ShaderNodeBsdfGlossy')
        ramp = nodes.new('ShaderNodeMapRange')
        ramp.inputs['To Min'].default_value = 0.2
        ramp.inputs['To Max'].default_value = 0.7
        links.new(checker.outputs['Fac'], ramp.inputs['Value'])
        links.new(ramp.outputs['Result'], shader.inputs['Roughness'])
        if kind == 'mix':   # with a Diffuse (roughness 1) by a 0.3 mix: Cycles' weighted average
            mix = nodes.new('ShaderNodeMixShader')
            mix.inputs['Fac'].default_value = 0.3
            links.new(shader.outputs[0], mix.inputs[1])
            links.new(nodes.new('ShaderNodeBsdfDiffuse').outputs[0], mix.inputs[2])
            shader = mix
        elif kind == 'two_glossy':   # with a second, rougher and tinted Glossy by a 0.4 mix: Cycles
            # weighs each by its closure weight, the multiscatter GGX energy compensation included
            mix = nodes.new('ShaderNodeMixShader')
            mix.inputs['Fac'].default_value = 0.4
            other = nodes.new('ShaderNodeBsdfGlossy')
            other.inputs['Roughness'].default_value = 0.8
            other.inputs['Color'].default_value = (0.3, 0.5, 0.9, 1.0)
            links.new(shader.outputs[0], mix.inputs[1])
            links.new(other.outputs[0], mix.inputs[2])
            shader = mix
        elif kind == 'oren_nayar':   # a Diffuse BSDF with that roughness: Oren-Nayar's sigma
            shader = nodes.new('ShaderNodeBsdfDiffuse')
            links.new(ramp.outputs['Result'], shader.inputs['Roughness'])
        elif kind == 'principled_roughness':
            shader = nodes.get('Principled BSDF') or nodes.new('ShaderNodeBsdfPrincipled')
            links.new(ramp.outputs['Result'], shader.inputs['Roughness'])
    links.new(shader.outputs[0], out.inputs['Surface'])


@pytest.mark.parametrize("kind,material", [('EMIT', 'emission'), ('EMIT', 'principled'),
                                           ('ROUGHNESS', 'roughness'), ('ROUGHNESS', 'mix'),
                                           ('ROUGHNESS', 'oren_nayar'), ('ROUGHNESS', 'principled_roughness'),
                                           ('ROUGHNESS', 'two_glossy')])
def test_shaded_bakes_match_cycles(kind, material):
    """Emit and Roughness bakes of textured closures: Ember's node evaluation
    at the texel against Cycles' per texel (1 sample: the texel centre),
    within float tolerance except at the checker's edges (a texel whose
    point lies within rounding of an edge may take either colour)."""
    scene, obj, image = _scene()
    _shaded_material(obj, material)
    cycles = _bake(scene, image, 'CYCLES', kind)
    ember = _bake(scene, image, 'EMBER', kind)
    filled = ember[..., 3] > 0
    diff = np.abs(ember[..., :3] - cycles[..., :3]).max(axis=2)[filled]
    close = diff < 2e-4
    spread = np.ptp(cycles[..., :3][filled], axis=0).max()
    print("centre texel: Cycles", cycles[16, 10, :3], "Ember", ember[16, 10, :3])
    print(f"{kind}/{material}: {int(filled.sum())} texels, {int((~close).sum())} differ by > 2e-4, "
          f"max |diff| {diff.max():.2e}, median {np.median(diff):.2e}, Cycles' range {spread:.3f}")
    assert filled.sum() > 0.5 * SIZE * SIZE
    assert spread > 0.1, "the texture did not vary: the test would not see a wrong lookup"
    assert close.mean() > 0.99


AO_SAMPLES = 256
AO_BLOCK = 4


def _ao_points():
    """40 spheres (radius 0.05-0.12) hovering 0.15-0.4 over the plane: a point cloud made by geometry nodes."""
    from test_points_parity import point_object
    rng = np.random.default_rng(7)
    positions = np.c_[rng.uniform(-0.8, 0.8, (40, 2)), rng.uniform(0.15, 0.4, 40)]   # none cuts the plane
    point_object("ao_points", positions, rng.uniform(0.05, 0.12, 40), np.ones((40, 4)),
                 bpy.data.materials.new("points"))


def _ao_curves(scene):
    """60 round (3D) strands of 5 points, 0.15-0.55 over the plane, radius 0.03 to 0.01."""
    rng = np.random.default_rng(8)
    count, points = 60, 5
    base = np.c_[rng.uniform(-0.8, 0.8, (count, 2)), np.full(count, 0.15)]
    k = np.arange(points)[None, :, None]
    lean = np.c_[rng.uniform(-0.1, 0.1, (count, 2)), np.full(count, 0.1)][:, None, :]
    positions = base[:, None, :] + k * lean
    data = bpy.data.hair_curves.new("ao_strands")
    data.add_curves([points] * count)
    data.attributes['position'].data.foreach_set('vector', positions.reshape(-1).astype(np.float32))
    radius = data.attributes.new('radius', 'FLOAT', 'POINT')
    radius.data.foreach_set('value', np.tile(np.linspace(0.03, 0.01, points), count).astype(np.float32))
    scene.collection.objects.link(bpy.data.objects.new("ao_strands", data))
    scene.cycles_curves.shape = 'THICK'


@pytest.mark.parametrize("occluder", ['cube', 'points', 'curves'])
def test_ao_bake_matches_cycles(occluder):
    """AO bake of a plane under a tilted cube (the cube occludes; the world's
    AO distance 0.8 cuts the far rays), or under a point cloud, against
    Cycles' AO bake, both at 256 samples: the means of 4 x 4 texel blocks,
    z-tested with binomial variances p (1 - p) / S per texel (an upper bound
    for Cycles' stratified samples), Sidak over the blocks; one statistical
    family each."""
    from ember_stats import detectable, family_level, z_scores, z_threshold
    scene = empty_factory_scene()
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    if occluder == 'cube':
        bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.2, -0.1, 0.45), rotation=(0.3, 0.2, 0.4))
    elif occluder == 'points':
        _ao_points()
    else:
        _ao_curves(scene)
    mat, image = bake_target_material()
    plane.data.materials.append(mat)
    for o in scene.objects:
        o.select_set(False)
    plane.select_set(True)
    bpy.context.view_layer.objects.active = plane
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.light_settings.distance = 0.8
    scene.cycles.samples = AO_SAMPLES
    scene.cycles.device = 'CPU'
    scene.render.engine = 'CYCLES'
    scene.render.bake.margin = 0
    image.pixels.foreach_set(np.zeros(SIZE * SIZE * 4, np.float32))
    bpy.ops.object.bake(type='AO', margin=0)
    cycles = np.empty(SIZE * SIZE * 4, np.float32)
    image.pixels.foreach_get(cycles)
    scene.render.engine = 'EMBER'
    scene.ember.samples = AO_SAMPLES
    image.pixels.foreach_set(np.zeros(SIZE * SIZE * 4, np.float32))
    bpy.ops.object.bake(type='AO', margin=0)
    ember = np.empty(SIZE * SIZE * 4, np.float32)
    image.pixels.foreach_get(ember)
    cycles, ember = cycles.reshape(SIZE, SIZE, 4)[..., 0], ember.reshape(SIZE, SIZE, 4)[..., 0]

    def blocks(img):
        return img.reshape(SIZE // AO_BLOCK, AO_BLOCK, SIZE // AO_BLOCK, AO_BLOCK).mean(axis=(1, 3))

    def block_var(img):
        return blocks(np.clip(img * (1 - img), 1.0 / AO_SAMPLES, None) / AO_SAMPLES) / AO_BLOCK ** 2
    a, b, va, vb = blocks(ember), blocks(cycles), block_var(ember), block_var(cycles)
    count = a.size
    level = family_level("bake AO blocks" if occluder == 'cube' else f"bake AO {occluder}", count)
    z = z_scores(a, va, b, vb)
    se = float(np.sqrt(np.median(va + vb)))
    print(f"AO under the {occluder}: Cycles mean {cycles.mean():.4f} (min {cycles.min():.3f}), Ember mean {ember.mean():.4f} "
          f"(min {ember.min():.3f}); {count} blocks, max |z| {np.abs(z).max():.2f} (threshold "
          f"{z_threshold(level):.2f}); detectable block difference {detectable(se, level):.4f}")
    assert cycles.min() < 0.6, f"the {occluder} did not occlude: the test would not see a wrong AO"
    assert np.abs(z).max() < z_threshold(level)


# Hostile bake input (issue 26), fuzz-style: each hazard with every kind of bake Ember does
# (a closed form, a shaded, a traced and a light bake); each must give finite pixels or stop
# with one clear message (Blender's own refusal or Ember's report), never a crash, a hang, a
# leaked exception type or a NaN.
HOSTILE_KINDS = ('POSITION', 'NORMAL', 'EMIT', 'AO', 'DIFFUSE', 'COMBINED')
HOSTILE_FLOATS = {'nan': float('nan'), 'inf': float('inf'), 'negative': -0.5}


def _hostile_scene(hazard):
    """The sphere scene broken in one way; returns (scene, image, bake keyword arguments)."""
    scene, obj, image = _scene()
    settings = {}
    if hazard == 'zero_area_uv':   # every UV of the first 40 loops collapsed to one point
        uv = obj.data.uv_layers.active.data
        for loop in range(min(40, len(uv))):
            uv[loop].uv = (0.25, 0.25)
    elif hazard == 'one_pixel':
        image.scale(1, 1)
    elif hazard == 'odd_size':    # a second slot baking into an image of another, non-square size
        mat, other = bake_target_material()
        other.scale(7, 3)
        obj.data.materials.append(mat)
        for i, poly in enumerate(obj.data.polygons):
            poly.material_index = i % 2
    elif hazard == 'no_uv':
        obj.data.uv_layers.remove(obj.data.uv_layers[0])
    else:                         # (nan | inf | negative)_(extrusion | cage): selected to active
        value, which = hazard.split('_', 1)
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=1.05, location=obj.location)
        high = bpy.context.active_object
        high.select_set(True)
        obj.select_set(True)
        bpy.context.view_layer.objects.active = obj
        settings = {'use_selected_to_active': True}
        if which == 'cage':
            settings.update(use_cage=True, cage_extrusion=HOSTILE_FLOATS[value])
        else:
            settings['cage_extrusion'] = HOSTILE_FLOATS[value]
            settings['max_ray_distance'] = HOSTILE_FLOATS[value]
    return scene, image, settings


HAZARDS = ('zero_area_uv', 'one_pixel', 'odd_size', 'no_uv') + tuple(
    f"{value}_{which}" for value in HOSTILE_FLOATS for which in ('extrusion', 'cage'))


def _classify(message, pixels):
    """'baked' (finite pixels), 'refused' (one clear message) or 'FAILED: why'."""
    if not np.isfinite(pixels).all():
        return f"FAILED: {int((~np.isfinite(pixels)).sum())} non-finite values"
    if message is None:
        return 'baked'
    text = message.strip()
    leaked = any(f"{name}:" in text for name in ('TypeError', 'ValueError', 'IndexError', 'KeyError',
                                                  'AttributeError', 'ZeroDivisionError', 'FloatingPointError'))
    if not text or leaked or 'bake failed' in text:
        return f"FAILED: {text!r}"
    return 'refused'


@pytest.mark.parametrize("hazard", HAZARDS)
def test_hostile_bake_input(hazard):
    import time
    outcomes = {}
    for kind in HOSTILE_KINDS:
        scene, image, settings = _hostile_scene(hazard)
        scene.render.engine = 'EMBER'
        scene.ember.samples = 2
        scene.render.bake.margin = 0
        message = None
        start = time.perf_counter()
        try:
            bpy.ops.object.bake(type=kind, margin=0, **settings)
        except RuntimeError as err:
            message = str(err)
        seconds = time.perf_counter() - start
        pixels = np.empty(len(image.pixels), np.float32)
        image.pixels.foreach_get(pixels)
        outcomes[kind] = _classify(message, pixels)
        print(f"{hazard} {kind}: {outcomes[kind]} in {seconds:.1f} s"
              + (f" ({message.strip()[:120]})" if message else f", pixel range {pixels.min():.3g}..{pixels.max():.3g}"))
    failed = {k: v for k, v in outcomes.items() if v.startswith('FAILED')}
    assert not failed, failed
    if hazard in ('zero_area_uv', 'one_pixel', 'odd_size'):
        assert set(outcomes.values()) == {'baked'}, "a valid (if odd) bake was refused"


def test_bake_result_of_another_size_is_refused_clearly():
    """A bake result that does not hold width x height texels (Blender
    asking for one size and handing another) ends in one report naming the
    object and the size, not a leaked exception; width or height 0 too."""
    from addon import bake as addon_bake
    scene, obj, image = _scene()

    class Rect:
        def __init__(self, count):
            self.values = np.zeros(count, np.float32)

        def foreach_get(self, out):
            if len(out) != len(self.values):
                raise RuntimeError("internal error setting the array")
            out[:] = self.values

        foreach_set = foreach_get

    class Pass:
        def __init__(self, name, channels, count):
            self.name, self.channels, self.rect = name, channels, Rect(count * channels)

    class Engine:
        def __init__(self, texels):
            self.reports, self.texels = [], texels

        def report(self, kind, message):
            self.reports.append(message)

        def begin_result(self, *args, **kwargs):
            passes = [Pass("BakePrimitive", 3, self.texels), Pass("Combined", 4, self.texels)]
            return type("Result", (), {"layers": [type("Layer", (), {"passes": passes})()]})()

        def end_result(self, result):
            pass

    depsgraph = bpy.context.evaluated_depsgraph_get()
    for texels, width, height in ((10, 4, 4), (16, 0, 4)):
        engine = Engine(texels)
        addon_bake.bake(engine, depsgraph, obj, 'POSITION', set(), width, height)
        print(f"{texels} texels for {width} x {height} ->", engine.reports)
        assert len(engine.reports) == 1
        assert obj.name in engine.reports[0] and "bake failed" not in engine.reports[0]
        assert f"{width} x {height}" in engine.reports[0]
