"""Helpers shared by the add-on tests (imported after conftest has set up bpy)."""
import math
import os

import bpy
import numpy as np

from prerequisites import in_ci, require  # noqa: F401  (tests/prerequisites.py)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES_DIR = os.path.join(ROOT, 'blend_scenes')
SCENE_NAMES = ('cornell', 'veach_mis', 'instances_lights')


def engine_available():
    """True once the renderer exposes engine.render.render."""
    try:
        from addon import backend
        backend.require_ray_tracer()
    except ImportError as err:
        return False, str(err)
    return True, ""


def open_scene(name):
    """Open one of blend_scenes/*.blend (saved by Blender 3.4)."""
    path = os.path.join(SCENES_DIR, name + '.blend')
    require(os.path.isfile(path), f"{path} is missing: run blend_scenes/build_scenes.py")
    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    return scene


# ----------------------------------------------------------------------------
# rendering to NumPy

def load_exr(path):
    """An image file as (H, W, 4) float32, row 0 = top (loaded by Blender)."""
    import numpy as np
    image = bpy.data.images.load(path)
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1].copy()


def render_array(scene, folder, name="render"):
    """Render the scene with its engine; returns the linear RGBA result."""
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    bpy.ops.render.render()
    path = os.path.join(str(folder), name + ".exr")
    bpy.data.images['Render Result'].save_render(path)
    return load_exr(path)


def read_multilayer_exr(path):
    """{pass name: (H, W, C) float64} of a multilayer EXR, row 0 = top
    (Composite as 'Composite')."""
    import OpenImageIO as oiio
    image = oiio.ImageInput.open(path)
    assert image is not None, oiio.geterror()
    channels = {}
    index = 0
    while image.seek_subimage(index, 0):
        spec = image.spec()
        pixels = image.read_image('float')
        for k, name in enumerate(spec.channelnames):
            parts = name.split('.')
            key = 'Composite' if parts[0] == 'Composite' else parts[-2]
            channels.setdefault(key, []).append(pixels[..., k])
        index += 1
    image.close()
    return {k: np.stack(v, axis=-1).astype(np.float64) for k, v in channels.items()}


def multilayer_output(scene):
    """Render output: 32-bit multilayer EXR (every pass of the view layer)."""
    settings = scene.render.image_settings
    if hasattr(settings, 'media_type'):
        settings.media_type = 'MULTI_LAYER_IMAGE'
    else:
        settings.file_format = 'OPEN_EXR_MULTILAYER'
    settings.color_depth = '32'


def setup_cycles(scene, samples, seed, max_bounces, filter_type='BLACKMAN_HARRIS', filter_width=1.5):
    """Cycles configured as Ember renders: CPU, unbiased, nothing clamped or
    filtered away, the same bounce limit and pixel filter."""
    scene.render.engine = 'CYCLES'
    cycles = scene.cycles
    cycles.device = 'CPU'
    cycles.samples = samples
    cycles.seed = seed
    cycles.use_animated_seed = False
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = 0.0
    cycles.light_sampling_threshold = 0.0
    cycles.blur_glossy = 0.0
    cycles.caustics_reflective = True
    cycles.caustics_refractive = True
    cycles.max_bounces = max_bounces
    for name in ('diffuse_bounces', 'glossy_bounces', 'transmission_bounces', 'transparent_max_bounces'):
        setattr(cycles, name, max_bounces)
    # Volume bounces as Ember renders the scene (its default 0 is Cycles').
    cycles.volume_bounces = getattr(getattr(scene, 'ember', None), 'volume_bounces', 0)
    cycles.min_light_bounces = 0
    cycles.min_transparent_bounces = 0
    if hasattr(cycles, 'use_auto_tile'):
        cycles.use_auto_tile = False
    cycles.pixel_filter_type = filter_type
    cycles.filter_width = filter_width
    scene.render.threads_mode = 'AUTO'


def cycles_settings_key(filter_type='BLACKMAN_HARRIS', filter_width=1.5):
    """A hash of how setup_cycles configures Cycles (its code and the filter
    it is given): part of a reference's key, so a reference made with other
    Cycles settings (a clamp, the light threshold, caustics) is refused.
    Samples, seeds and bounces are keyed apart; Blender's own defaults by its
    version."""
    import inspect
    source = inspect.getsource(setup_cycles)
    body = source[source.index('"""', source.index('"""') + 3) + 3:]     # the code, not its docstring
    return hashlib_sha(repr((body, filter_type, float(filter_width))).encode())[:16]


def setup_ember(scene, samples, seed, max_bounces, filter_type='BLACKMAN_HARRIS', filter_width=1.5):
    scene.render.engine = 'EMBER'
    ember = scene.ember
    ember.samples = samples
    ember.use_adaptive_sampling = False   # as setup_cycles
    ember.seed = seed
    ember.max_bounces = max_bounces
    ember.transparent_max_bounces = max_bounces   # as setup_cycles
    for name in ('diffuse_bounces', 'glossy_bounces', 'transmission_bounces'):
        setattr(ember, name, max_bounces)         # as setup_cycles
    ember.filter_glossy = 0.0                     # as setup_cycles' blur_glossy
    ember.clamp = 0.0
    ember.time_limit = 0.0
    ember.filter_type = filter_type
    ember.filter_width = filter_width


def small_resolution(scene, width, height):
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.render.use_border = False


# ----------------------------------------------------------------------------
# Ember's progressive passes

class PassTap:
    """Wraps the engine's progress object to keep every displayed pass."""

    def __init__(self, progress):
        self.progress = progress
        self.images = []

    def on_pass(self, image, samples_done, stats_):
        self.images.append((samples_done, np.array(image, dtype=np.float64)))
        self.progress.on_pass(image, samples_done, stats_)

    def should_stop(self):
        return self.progress.should_stop()


def per_pass_estimates(images):
    """Independent per-pass images from running means: n_k M_k - n_{k-1} M_{k-1}."""
    batches, previous_n, previous_sum = [], 0, 0.0
    for n, mean in images:
        total = mean * n
        batches.append((total - previous_sum) / (n - previous_n))
        previous_n, previous_sum = n, total
    return np.array(batches)


# ----------------------------------------------------------------------------
# Ember against live Cycles renders (where no converged reference can be: the
# Blender 3.4 binary's Cycles; the sky parity test)

def render_ember_and_cycles(scene, tmp_path, name, taps, ember_spp, ember_seed, cycles_seeds, cycles_spp,
                            bounces):
    """Ember's final image and per-pass estimates (RGB), and Cycles' RGB
    images for seeds 0..cycles_seeds-1, with the same bounces and filter."""
    setup_ember(scene, ember_spp, seed=ember_seed, max_bounces=bounces)
    image = render_array(scene, tmp_path, "ember_" + name)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert np.isfinite(image).all()
    ember_batches = per_pass_estimates(taps[-1].images)[..., :3]
    cycles = []
    for seed in range(cycles_seeds):
        setup_cycles(scene, cycles_spp, seed, bounces)
        cycles.append(render_array(scene, tmp_path, f"cycles_{name}_{seed}")[..., :3])
    return image, ember_batches, np.array(cycles, dtype=np.float64)


def compare_with_cycles(name, ember_batches, cycles, block):
    """Ember's passes against Cycles' seeds (tests/ember_stats.py): Welch's t
    per block and channel, and the total of the whole image and of its four
    quadrants (a bias spread over many blocks hides in each of them).  Prints
    both results with their power.  Returns failures (blocks), details (with
    the failing mean tests) and both block-mean arrays."""
    import ember_stats as stats
    ember_blocks = stats.block_means(ember_batches, block)
    cycles_blocks = stats.block_means(cycles, block)
    failures, details = stats.failing_blocks(ember_blocks, cycles_blocks, name=f"{name} blocks")
    tests, level = stats.region_mean_tests(ember_batches, cycles, name=f"{name} region means")
    details['mean_failures'] = stats.report_mean_tests(f"{name}: Ember against Cycles", tests, level)
    details['relative_mean_error'] = tests[0].relative
    block_se = _typical_relative_block_se(ember_blocks, cycles_blocks)
    print(f"{name}: mean |block error| {details['relative_abs_error']:.4f}, max |t| {details['max_abs_t']:.2f} "
          f"over {details['blocks']} block-channels (reject below p={details['level']:.2e}); a bias in one "
          f"block is detected with probability 1/2 from "
          f"{stats.detectable(block_se, details['level'], min(len(ember_batches), len(cycles)) - 1):.1%} "
          f"(median block)")
    return failures, details, ember_blocks, cycles_blocks


def _typical_relative_block_se(a, b):
    """Median relative standard error of a block difference."""
    se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b))
    mean = np.abs(b.mean(axis=0))
    keep = mean > 0
    return float(np.median(se[keep] / mean[keep])) if keep.any() else 0.0


def seed_block_test(block_family, mean_family, name, ember, cycles, keep=None, storage=1e-5):
    """Ember seeds (N, H, W, C) against Cycles seeds: Welch t per 4x4
    block-channel over the seeds (Sidak, family ``block_family``) and
    Welch's t of the whole-image mean (``mean_family``), both asserted, with
    the power of each printed.  ``storage``: a deterministic floor as a
    relative standard error (the float32 EXR's rounding, 1e-5, below any
    noise here; or the precision of a table both renderers read).
    ``keep``: (H, W) pixels to compare; blocks with any other are left out."""
    import ember_stats as stats
    a, b = stats.block_means(ember, 4), stats.block_means(cycles, 4)
    _, dof, ma, mb = stats.welch(a, b)
    va, vb = a.var(axis=0, ddof=1) / len(a), b.var(axis=0, ddof=1) / len(b)
    # Rounding relative to each block's value, and to the pass's largest
    # value for blocks near 0 (a unit normal's 0 component stored as 1e-9).
    scale = np.maximum(np.abs(ma), np.abs(mb)) + 1e-3 * np.abs(mb).max()
    se = np.sqrt(va + vb + (storage * scale) ** 2 + 1e-30)
    t = (ma - mb) / se
    noisy = (va + vb > 0) & (mb != 0)            # the power of blocks that carry noise
    rel_se = np.where(noisy, se / np.where(mb != 0, np.abs(mb), 1.0), np.nan)
    if keep is not None:
        blocks = stats.block_means(keep[None, :, :, None].astype(float), 4)[0, ..., 0] == 1.0
        t, dof, rel_se, ma, mb = t[blocks], dof[blocks], rel_se[blocks], ma[blocks], mb[blocks]
    level = stats.family_level(block_family, t.size)
    p = stats.t_p_values(t, dof)
    ember_means, cycles_means = (x.mean(axis=tuple(range(1, x.ndim))) for x in (ember, cycles))
    mean = stats.MeanTest("image", ember_means.mean(), ember_means.var(ddof=1) / len(ember_means),
                          len(ember_means) - 1, cycles_means.mean(), cycles_means.var(ddof=1) / len(cycles_means),
                          len(cycles_means) - 1)
    mean_level = stats.family_level(mean_family)
    block_power = (f"the median noisy block detects "
                   f"{stats.detectable(float(np.nanmedian(rel_se)), level, float(np.median(dof))):.1%}"
                   if np.isfinite(rel_se).any() else "no block carries noise")
    print(f"\n{name}: Ember {ember_means.mean():.5g}, Cycles {cycles_means.mean():.5g}: {mean}; detects "
          f"{stats.detectable(mean.relative_se, mean_level, mean.dof):.2%} with probability 1/2; max block |t| "
          f"{np.abs(t).max():.2f} over {t.size} block-channels (dof {np.median(dof):.0f}), {block_power}")
    bad = p < level
    assert not bad.any(), (f"{name}: {int(bad.sum())} blocks differ from Cycles (index, Ember, Cycles, t): "
                           f"{[(tuple(i), ma[tuple(i)], mb[tuple(i)], t[tuple(i)]) for i in np.argwhere(bad)[:6]]}")
    assert mean.p >= mean_level, f"{name}: whole-image mean off: {mean}"


def assert_no_failing_blocks(failures, details):
    assert len(failures) == 0, (
        f"{len(failures)} blocks differ from Cycles (block, y, x, channel): {failures[:10].tolist()}; {details}")
    assert not details['mean_failures'], (
        f"the image or region means differ from Cycles: {details['mean_failures']}")


# ----------------------------------------------------------------------------
# Converged Cycles references (tools/cycles_references.py, tests/data)

def empty_factory_scene():
    """Blender's factory scene without its cube and light (camera kept)."""
    bpy.ops.wm.read_factory_settings()
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    return bpy.context.scene


def node_material(name, kind, inputs):
    """A material whose surface is one shader node of type ``kind``, its
    inputs (or, for other keys, node properties such as distribution) set."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    for node in list(tree.nodes):
        if node != out:
            tree.nodes.remove(node)
    node = tree.nodes.new(kind)
    for key, value in inputs.items():
        if key in node.inputs:
            node.inputs[key].default_value = value
        else:
            setattr(node, key, value)
    tree.links.new(node.outputs[0], out.inputs['Surface'])
    return mat


def rough_material(name, color):
    """A Principled BSDF material of ``color`` at roughness 1; returns (material, its BSDF node)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED')
    bsdf.inputs['Base Color'].default_value = tuple(color) + (1.0,)
    bsdf.inputs['Roughness'].default_value = 1.0
    return mat, bsdf


def add_object(op, name, mat, **kwargs):
    """``op(**kwargs)`` (a bpy.ops.mesh primitive), named, with ``mat``."""
    op(**kwargs)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def render_seeds(scene, folder, name, seeds, spp, first_seed, bounces, read=None):
    """{'EMBER' | 'CYCLES': (seeds, H, W, C)} renders of the scene with
    seeds first_seed.. (render_array's RGBA, or ``read(path)`` of the written
    file), the Ember renders checked for errors."""
    out = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        images = []
        for seed in range(seeds):
            setup(scene, spp, first_seed + seed, bounces)
            if read is None:
                images.append(render_array(scene, folder, f"{name}_{engine}_{seed}").astype(np.float64))
            else:
                scene.render.filepath = os.path.join(str(folder), f"{name}_{engine}_{seed}.exr")
                bpy.ops.render.render(write_still=True)
                images.append(read(scene.render.filepath))
        out[engine] = np.array(images)
    from addon import engine as ember_engine
    assert all(entry['error'] is None for entry in ember_engine.RENDER_LOG[-seeds:])
    return out


def references_tool():
    """tools/cycles_references.py as a module."""
    import importlib.util
    spec = importlib.util.spec_from_file_location('cycles_references',
                                                  os.path.join(ROOT, 'tools', 'cycles_references.py'))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# What a reference depends on, read from the Blender scene (not from Ember's
# export): objects, meshes, materials and world node trees, lights, camera,
# resolution.  Names, file paths and editor layout are left out.
_SKIP = {'rna_type', 'name', 'name_full', 'session_uid', 'is_evaluated', 'original', 'users', 'use_fake_user',
         'use_extra_user', 'is_embedded_data', 'is_library_indirect', 'is_missing', 'is_runtime_data', 'tag',
         'id_type', 'library', 'library_weak_reference', 'asset_data', 'override_library', 'preview',
         'location', 'width', 'height', 'dimensions', 'select', 'show_options', 'show_preview', 'show_texture',
         'hide', 'label', 'width_hidden', 'use_custom_color', 'bl_width_default', 'bl_width_min',
         'bl_width_max', 'bl_height_default', 'bl_height_min', 'bl_height_max', 'bl_icon', 'bl_label',
         'bl_description', 'bl_static_type', 'type', 'color_tag', 'warning_propagation', 'is_active_output',
         'is_editor_icon_update', 'filepath', 'filepath_raw', 'node_tree', 'image', 'object', 'parent'}


def _rounded(value):
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    try:
        return tuple(_rounded(v) for v in value)
    except TypeError:
        return repr(type(value).__name__)


# A node's 'color' is its editor colour; a light's, a world's or an
# object's colour is rendered (it was skipped everywhere once, so a light's
# colour or a node-less world's colour could change unseen: issue 27).
_NODE_SKIP = _SKIP | {'color'}


def _rna(struct, skip=_SKIP):
    items = []
    for prop in struct.bl_rna.properties:
        key = prop.identifier
        if key in skip or prop.type in ('POINTER', 'COLLECTION'):
            continue
        try:
            items.append((key, _rounded(getattr(struct, key))))
        except (AttributeError, RuntimeError, TypeError):
            continue
    return items


def _image_print(image):
    if image is None:
        return None
    pixels = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    return (tuple(image.size), image.source, image.alpha_mode, image.colorspace_settings.name,
            image.packed_file is not None, hashlib_sha(pixels.tobytes()))


def hashlib_sha(data):
    import hashlib
    return hashlib.sha256(data).hexdigest()


def _tree_print(tree):
    if tree is None:
        return None
    nodes = list(tree.nodes)
    index = {node.name: i for i, node in enumerate(nodes)}
    out = []
    for node in nodes:
        inputs = [(s.identifier, _rounded(getattr(s, 'default_value', None))) for s in node.inputs]
        ramp = getattr(node, 'color_ramp', None)
        out.append((node.bl_idname, _rna(node, _NODE_SKIP), inputs,
                    [(e.position, tuple(e.color)) for e in ramp.elements] if ramp else None,
                    _image_print(getattr(node, 'image', None)),
                    _tree_print(getattr(node, 'node_tree', None)),
                    [(o.identifier, _rounded(getattr(o, 'default_value', None))) for o in node.outputs]))
    links = sorted((index[link.from_node.name], link.from_socket.identifier, index[link.to_node.name],
                    link.to_socket.identifier) for link in tree.links)
    return _rounded(out), links


def _mesh_print(mesh):
    """Order-independent (Blender 5's primitives number their vertices and
    faces differently from one call to the next): each face as the sorted
    set of its corners (position, UVs, colours), the faces sorted."""
    co = np.empty(len(mesh.vertices) * 3, np.float64)
    mesh.vertices.foreach_get('co', co)
    co = np.round(co.reshape(-1, 3), 5).tolist()
    uvs = [[tuple(np.round(d.uv, 5)) for d in layer.data] for layer in mesh.uv_layers]
    colours = [(a.domain == 'POINT', [tuple(np.round(d.color, 5)) for d in a.data]) for a in mesh.color_attributes]
    faces = []
    for poly in mesh.polygons:
        corners = sorted((tuple(co[v]), tuple(uv[loop] for uv in uvs),
                          tuple(data[v if by_point else loop] for by_point, data in colours))
                         for v, loop in zip(poly.vertices, poly.loop_indices))
        faces.append((tuple(corners), poly.use_smooth, poly.material_index))
    return hashlib_sha(repr(sorted(faces)).encode()), [_material_print(m) for m in mesh.materials]


def _light_tree_renders(light):
    """Whether a light's node tree holds more than its Emission and Light
    Output (references of lights with the default tree keep their
    fingerprints; a Light Falloff or a texture on the light counts)."""
    tree = getattr(light, 'node_tree', None)
    return tree is not None and any(n.type not in ('OUTPUT_LIGHT', 'EMISSION') for n in tree.nodes)


def _material_print(material):
    if material is None:
        return None
    return _rna(material), _tree_print(material.node_tree if material.use_nodes else None)


def scene_fingerprint(scene):
    """A hash of what the scene renders: a reference is only valid for the
    scene it was rendered from.  Objects (transform, visibility, modifiers,
    data, materials), lights and worlds with their colours, node trees,
    camera and resolution."""
    bpy.context.view_layer.update()     # matrix_world as rendered
    objects = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        data = obj.data
        if obj.type == 'MESH':
            data_print = _mesh_print(data)
        elif obj.type == 'LIGHT' and _light_tree_renders(data):
            data_print = (_rna(data), _tree_print(data.node_tree))
        elif data is not None:
            data_print = _rna(data)
        else:
            data_print = None
        matrix = _rounded([tuple(row) for row in obj.matrix_world])
        flags = [(k, getattr(obj, k)) for k in ('hide_render', 'visible_camera', 'visible_diffuse',
                                                'visible_glossy', 'visible_transmission', 'visible_shadow')]
        modifiers = [(m.type, _rna(m)) for m in obj.modifiers]   # a Subdivision changes the mesh rendered
        objects.append((obj.type, matrix, flags, data_print, modifiers,
                        [_material_print(slot.material) for slot in obj.material_slots if slot.link == 'OBJECT']))
    world = scene.world
    render = scene.render
    description = (objects, _rna(world) if world else None, _tree_print(world.node_tree) if world else None,
                   scene.camera.name if scene.camera else None,
                   (render.resolution_x, render.resolution_y, render.resolution_percentage, render.film_transparent))
    if os.environ.get('EMBER_FINGERPRINT_DUMP'):   # debugging a refused reference: what differs
        with open(os.environ['EMBER_FINGERPRINT_DUMP'], 'a') as dump:
            dump.write(repr(description).replace('), (', '),\n(') + '\n=====\n')
    return hashlib_sha(repr(description).encode())[:16]


def load_reference(name, scene=None, bounces=None):
    """Mean, variance of the mean and header of tests/data/cycles_<name>.exr,
    checked against the tool's settings and (given the scene the test built
    and its bounces) the scene's resolution, bounces and fingerprint.  The
    variance has the channel sum's last (ember_stats.sum_variance) where the
    file holds it (var.sum, references written since it was added)."""
    import OpenImageIO as oiio
    refs = references_tool()
    path = refs.reference_path(name)
    require(os.path.isfile(path), f"{path} is missing: run tools/cycles_references.py {name}")
    buf = oiio.ImageBuf(path)
    spec = buf.spec()
    pixels = buf.get_pixels(oiio.FLOAT).astype(np.float64)
    header = {key: spec.getattribute('ember:' + key) for key in refs.HEADER}
    expected = refs.expected_header(name)
    if scene is not None:
        expected.update(width=str(scene.render.resolution_x), height=str(scene.render.resolution_y),
                        fingerprint=scene_fingerprint(scene))
    if bounces is not None:
        expected['max_bounces'] = str(bounces)
    stale = {k: (header.get(k), v) for k, v in expected.items() if header.get(k) != v}
    assert not stale, (f"{path} was rendered from another scene or with other settings (file, now): {stale}; "
                       f"re-run tools/cycles_references.py {name}")
    height, width = int(header['height']), int(header['width'])
    assert pixels.shape in ((height, width, 6), (height, width, 7)), pixels.shape
    return pixels[..., :3], pixels[..., 3:], header


def render_for_reference(scene, tmp_path, name, taps, spp, seed, bounces, configure=None):
    """Ember's render through Blender (one pass) and the variance of each
    pixel's mean, its channel sum's last (tapped_engine keeps the engine's
    result and asks for it); ``configure`` (scene.ember -> None) changes
    settings after setup_ember."""
    setup_ember(scene, spp, seed=seed, max_bounces=bounces)
    if configure is not None:
        configure(scene.ember)
    taps.samples_per_pass = spp
    image = render_array(scene, tmp_path, "ember_" + name)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert np.isfinite(image).all()
    var = taps[-1].result.variance_with_sum.astype(np.float64)
    return image, var


def live_cycles_reference(scene, tmp_path, name, seeds, spp, bounces, configure=None):
    """A Cycles reference rendered now (for settings no stored reference has):
    the mean of ``seeds`` renders, the variance of that mean per pixel from
    their scatter (the channel sum's last: ember_stats.sum_variance), and
    the header ReferenceCheck reads; ``configure``
    (scene.cycles -> None) changes settings after setup_cycles."""
    images = []
    for seed in range(seeds):
        setup_cycles(scene, spp, seed, bounces)
        if configure is not None:
            configure(scene.cycles)
        images.append(render_array(scene, tmp_path, f"cycles_{name}_{seed}")[..., :3])
    images = np.array(images, np.float64)
    return images.mean(axis=0), seed_variance(images), {'seeds': seeds, 'samples': spp}


def seed_variance(images):
    """(H, W, C + 1) variance of the mean of independent (N, H, W, C) renders
    per pixel and channel, and last of their channel sum (from the scatter:
    the channels' covariance included)."""
    with_sum = np.concatenate([images, images.sum(axis=3, keepdims=True)], axis=3)
    return with_sum.var(axis=0, ddof=1) / len(images)


class ReferenceCheck:
    """Ember (image, per-pixel variance of the mean, spp samples) against a
    converged Cycles reference: the image and region totals
    (``region_mean_tests_var``) and blocks per channel
    (``failing_blocks_var``), each one family of the suite budget, with their
    power printed."""

    def __init__(self, name, image, var, spp, ref, ref_var, header, block, splits=2):
        import ember_stats as stats
        seeds, samples = int(header['seeds']), int(header['samples'])
        self.name = name
        self.tests, self.level = stats.region_mean_tests_var(
            image, var, spp - 1, ref, ref_var, seeds - 1, name=f"{name} against Cycles", splits=splits,
            float32_sums_b=samples)
        self.mean_failures = stats.report_mean_tests(
            f"{name}: Ember ({spp} spp) against converged Cycles ({seeds} x {samples} spp)", self.tests, self.level)
        image_test = self.tests[0]
        self.image_detects = stats.detectable(image_test.relative_se, self.level, image_test.dof)
        self.blocks, self.details = stats.failing_blocks_var(
            image, var, spp - 1, ref, ref_var, seeds - 1, block, name=f"{name} blocks against Cycles",
            float32_sums_b=samples)
        self.block_detects = self.details['median_block_detects']
        self.cycles_detects = self._power_at_cycles_noise(ref, ref_var, seeds * samples / spp, block, image_test.dof)
        print(f"{name}: image mean detects {self.image_detects:.2%}; {self.details['blocks']} block-channels of "
              f"{block}x{block} pixels, max |t| {self.details['max_abs_t']:.2f}, a bias in one block detected "
              f"from {self.block_detects:.1%} (median block), with probability 1/2")

    def _power_at_cycles_noise(self, ref, ref_var, ratio, block, dof):
        """(image, median block) power these tests would have if Ember's
        pixels were as noisy per sample as Cycles' (the reference's variance
        times its samples over Ember's): the power a render at Ember's sample
        count is owed, derived from the reference instead of set by hand."""
        import ember_stats as stats
        image_se = math.sqrt((1.0 + ratio) * float(stats.sum_variance(ref, ref_var).sum())) / abs(float(ref.sum()))
        means, var = stats.block_means_var(ref, stats.channel_variances(ref, ref_var), block)
        return (stats.detectable(image_se, self.level, dof),
                stats.median_block_detects(stats.t_threshold(self.details['level'], dof), means, (1.0 + ratio) * var))

    def assert_agrees(self, image_power=None, block_power=None):
        """No region or block differs; where given, the power is asserted too
        (a test that could not see the target bias must not pass as if it did).
        ``'cycles'``: the power owed at Cycles' noise per sample (above)."""
        asked = (image_power, block_power)
        image_power = self.cycles_detects[0] if image_power == 'cycles' else image_power
        block_power = self.cycles_detects[1] if block_power == 'cycles' else block_power
        if 'cycles' in asked:
            print(f"{self.name}: at Cycles' noise per sample the image mean would detect "
                  f"{self.cycles_detects[0]:.2%}, the median block {self.cycles_detects[1]:.1%}; held to "
                  f"{image_power:.2%} (image), {block_power:.1%} (median block)")
        if image_power is not None:
            assert self.image_detects <= image_power, (
                f"{self.name}: the image-mean test only resolves {self.image_detects:.2%}, not {image_power:.1%}")
        if block_power is not None:
            assert self.block_detects <= block_power, (
                f"{self.name}: the median block only resolves {self.block_detects:.1%}, not {block_power:.1%}")
        assert not self.mean_failures, f"{self.name}: the image or region means differ from Cycles: " \
                                       f"{self.mean_failures}"
        assert len(self.blocks) == 0, (f"{self.name}: blocks (y, x, channel) differ from Cycles: "
                                       f"{self.blocks[:10].tolist()}; {self.details}")


def check_against_reference(name, scene, bounces, image, var, spp, block, splits=2):
    """Ember's image and variances against reference ``name`` of the scene
    the test built (checked to be the one the reference was rendered from)."""
    ref, ref_var, header = load_reference(name, scene, bounces)
    return ReferenceCheck(name, image[..., :3].astype(np.float64), var, spp, ref, ref_var, header, block, splits)


def built_reference_scene(build, width, height):
    """(scene, bounces) of a parity module's scene: ``build(scene)`` on an
    empty factory scene returns its bounces; the resolution is set after."""
    scene = empty_factory_scene()
    bounces = build(scene)
    small_resolution(scene, width, height)
    return scene, bounces


def render_against_reference(name, scene, bounces, tmp_path, taps, spp, block, seed=1):
    """Ember's render of a reference scene (no material warning allowed)
    checked against the stored reference ``name`` (a ReferenceCheck)."""
    image, var = render_for_reference(scene, tmp_path, name, taps, spp, seed, bounces)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert not [w for w in log.get('warnings', ()) if 'Material' in w], log.get('warnings')
    return check_against_reference(name, scene, bounces, image, var, spp, block)


def record_engine_scenes(monkeypatch):
    """A list that receives the engine Scene of every render from now on
    (the renderer's entry point wrapped for the test's duration)."""
    from addon import backend
    real, seen = backend.engine().render, []

    def spy(scene, settings, progress=None):
        seen.append(scene)
        return real(scene, settings, progress)
    monkeypatch.setattr(backend.engine(), 'render', spy)
    return seen
