"""Ember's render settings, stored on the scene as ``scene.ember``.

Defaults and ranges follow Cycles where the two renderers share an idea, so a
scene moved between them keeps its meaning.  Film transparency is Blender's
own ``scene.render.film_transparent`` and is not duplicated here.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

# Automatic is the default: the light tree, as Cycles (with one light it
# costs nothing, with many it lowers the noise several times), but every light
# at glossy vertices when there are a few (the tree does not see the BSDF's
# lobe).  Numbered: files store the number, and AUTO came last.
LIGHT_SELECTION_ITEMS = (
    ('AUTO', "Automatic", "The light tree; with 2 to 4 lights and no emissive mesh, every light at "
     "glossy surfaces (roughness up to 0.5)", 4),
    ('TREE', "Light Tree", "Pick one light per vertex by its estimated contribution there "
     "(power, distance and orientation): far less noise with many lights", 0),
    ('POWER', "Power", "Pick one light per vertex, proportional to its power", 1),
    ('UNIFORM', "Uniform", "Pick one light per vertex, every light equally likely", 2),
    ('ALL', "All Lights", "Sample every light at every vertex (slower, less noise with few lights)", 3),
    ('RIS', "Resampled", "Draw 4 lights by the light tree at each vertex and keep one by its unshadowed "
     "contribution with the BSDF (one shadow ray): less noise over glossy surfaces, more CPU per sample", 5),
    ('TREE_BSDF', "Light Tree with BSDF", "The light tree, weighing each branch by how much of it the glossy "
     "lobe reflects at glossy surfaces: less noise over glossy surfaces at about the tree's cost", 6),
)

STRATEGY_ITEMS = (
    ('MIS', "Multiple Importance", "Combine light and BSDF sampling (the robust default)"),
    ('LIGHT', "Light Only", "Next-event estimation only (debugging)"),
    ('BSDF', "BSDF Only", "BSDF sampling only (debugging)"),
)

PATTERN_ITEMS = (
    ('SOBOL', "Sobol-Burley", "Shuffled, Owen-scrambled Sobol sequence (Cycles' default): "
     "less noise for the same samples"),
    ('RANDOM', "Independent", "Independent random numbers per sample (for comparisons)"),
)

FILTER_ITEMS = (
    ('BLACKMAN_HARRIS', "Blackman-Harris", "Blackman-Harris filter, as Cycles"),
    ('GAUSSIAN', "Gaussian", "Gaussian filter"),
    ('BOX', "Box", "Box filter"),
)


class EmberRenderSettings(bpy.types.PropertyGroup):
    samples: IntProperty(
        name="Samples", description="Samples per pixel for final renders",
        default=64, min=1, max=1 << 24, soft_max=4096)
    preview_samples: IntProperty(
        name="Preview Samples", description="Samples per pixel for material previews",
        default=16, min=1, max=1 << 16, soft_max=256)
    viewport_samples: IntProperty(
        name="Viewport Samples", description="Samples per pixel in the Rendered viewport; "
        "sampling pauses when they are reached (as Cycles' viewport Max Samples)",
        default=128, min=1, max=1 << 24, soft_max=4096)
    preview_pause: BoolProperty(
        name="Pause Preview", description="Pause sampling in the Rendered viewport", default=False)
    use_denoising: BoolProperty(
        name="Denoise", description="Denoise final renders with Intel Open Image Denoise "
        "(albedo and normal guided); the result is Combined, the raw image the Noisy Image pass",
        default=False)
    use_preview_denoising: BoolProperty(
        name="Denoise Viewport", description="Denoise the Rendered viewport with Intel Open Image "
        "Denoise once its samples are done (and whenever it pauses)", default=False)
    use_adaptive_sampling: BoolProperty(
        name="Noise Threshold", description="Stop sampling pixels once their noise is below the "
        "threshold, as Cycles' adaptive sampling", default=True)
    adaptive_threshold: FloatProperty(
        name="Noise Threshold", description="Error a pixel may keep when adaptive sampling stops it "
        "(lower: less noise, longer renders); as Cycles'", default=0.01, min=0.0001, max=1.0,
        soft_min=0.001, precision=4)
    adaptive_min_samples: IntProperty(
        name="Min Samples", description="Samples every pixel gets before adaptive sampling may stop "
        "it (0 = automatic, from the threshold, as Cycles)", default=0, min=0, max=4096)
    sampling_pattern: EnumProperty(
        name="Pattern", description="Where the random numbers of each sample come from",
        items=PATTERN_ITEMS, default='SOBOL')
    time_limit: FloatProperty(
        name="Time Limit", description="Stop after this many seconds (0 = no limit); "
        "the pass that crosses the limit is finished", default=0.0, min=0.0, subtype='TIME_ABSOLUTE')
    seed: IntProperty(
        name="Seed", description="Seed of the random sequences; change it to get a different noise pattern",
        default=0, min=0)
    max_bounces: IntProperty(
        name="Max Bounces", description="Path vertices that sample lights; as Cycles' Max Bounces",
        default=12, min=0, max=1024)
    transparent_max_bounces: IntProperty(
        name="Transparent Max Bounces",
        description="Transparent surfaces (Transparent BSDF, Principled Alpha) a path or shadow ray "
                    "may pass through, counted apart from Max Bounces; as Cycles' (default 8)",
        default=8, min=0, max=1024)
    diffuse_bounces: IntProperty(
        name="Diffuse Bounces", description="Diffuse bounces a path may take (within Max Bounces); "
        "as Cycles' (default 4)", default=4, min=0, max=1024)
    glossy_bounces: IntProperty(
        name="Glossy Bounces", description="Glossy and mirror reflections a path may take (within Max "
        "Bounces); as Cycles' (default 4)", default=4, min=0, max=1024)
    transmission_bounces: IntProperty(
        name="Transmission Bounces", description="Refractions and other transmissions a path may take "
        "(within Max Bounces); as Cycles' (default 12)", default=12, min=0, max=1024)
    filter_glossy: FloatProperty(
        name="Filter Glossy", description="Blur glossy reflections after blurry bounces to cut caustic "
        "fireflies, at the cost of accuracy; as Cycles' (default 1.0, 0 = off)", default=1.0, min=0.0, soft_max=10.0)
    volume_bounces: IntProperty(
        name="Volume Bounces",
        description="Scattering events a path may have in volumes, counted apart from Max Bounces "
                    "(0 = single scattering); as Cycles' (default 0)",
        default=0, min=0, max=1024)
    light_selection: EnumProperty(
        name="Light Selection", description="How a light is chosen for next-event estimation",
        items=LIGHT_SELECTION_ITEMS, default='AUTO')
    mis_compensation: BoolProperty(
        name="World MIS Compensation",
        description="Sample an HDRI world by its radiance above the mean (Karlik et al. 2019): "
                    "lower noise when BSDF and light sampling are combined",
        default=True)
    strategy: EnumProperty(
        name="Sampling Strategy", description="Which estimators are combined",
        items=STRATEGY_ITEMS, default='MIS')
    clamp: FloatProperty(
        name="Clamp", description="Largest radiance a sample may add (0 = no clamping)",
        default=0.0, min=0.0)
    filter_type: EnumProperty(
        name="Pixel Filter", description="Reconstruction filter of the pixels",
        items=FILTER_ITEMS, default='BLACKMAN_HARRIS')
    filter_width: FloatProperty(
        name="Filter Width", description="Pixel filter width in pixels",
        default=1.5, min=0.01, max=10.0, subtype='PIXEL')
    threads: IntProperty(
        name="Threads", description="Render threads (0 = every core)", default=0, min=0, max=1024)
    use_jit: BoolProperty(
        name="Compiled Kernels",
        description="Run the renderer's per-ray maths as kernels compiled by numba (cached in the user "
                    "cache folder after the first render); off, or without numba, the same maths runs "
                    "in NumPy. The environment variable EMBER_JIT=0 also turns it off",
        default=True)


def _passes_changed(self, context):
    """Tell Blender the layer's passes changed (compositor sockets)."""
    view_layer = getattr(context, 'view_layer', None)
    if view_layer is not None:
        view_layer.update_render_passes()


def _pass_toggle_update():
    """The update callback of the pass checkboxes, or None without a UI:
    the render pipeline registers passes itself when it renders, and the
    bpy 4.2 module segfaults at exit when a ViewLayer property group has
    any update callback (measured: even a no-op one)."""
    return None if bpy.app.background else _passes_changed


STRATEGY_VERTEX_ITEMS = (
    ('ALL', "Every Vertex", "Direct light of every path vertex: with Emission and Environment "
     "the strategy passes add up to Combined"),
    ('FIRST', "First Vertex", "Direct light of the first surface only: add up to a render with "
     "Max Bounces 0"),
)


class EmberViewLayerSettings(bpy.types.PropertyGroup):
    """Ember's passes of a view layer (``view_layer.ember``); the passes that
    Cycles also has use Blender's own View Layer checkboxes."""
    use_pass_strategies: BoolProperty(
        name="Strategies", description="Strategy Light, Strategy BSDF (their MIS-weighted direct light), "
        "the same unweighted, and MIS Weight Light", default=False, update=_pass_toggle_update())
    strategy_passes_vertex: EnumProperty(
        name="Strategy Vertices", description="Which path vertices the strategy passes show",
        items=STRATEGY_VERTEX_ITEMS, default='ALL')
    use_pass_variance: BoolProperty(
        name="Variance", description="Per-pixel variance of the Combined mean (what adaptive sampling reads)",
        default=False, update=_pass_toggle_update())
    use_pass_denoising_data: BoolProperty(
        name="Denoising Data", description="Denoising Albedo and Denoising Normal, as Cycles",
        default=False, update=_pass_toggle_update())
    use_pass_sample_count: BoolProperty(
        name="Sample Count", description="Samples per pixel (Cycles' Debug Sample Count)",
        default=False, update=_pass_toggle_update())


classes = (EmberRenderSettings, EmberViewLayerSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    # Added after registration, not in a register() classmethod: the bpy 4.2
    # module crashes at exit when the pointer is created inside register_class.
    bpy.types.Scene.ember = PointerProperty(
        type=EmberRenderSettings, name="Ember", description="Ember render settings")
    bpy.types.ViewLayer.ember = PointerProperty(
        type=EmberViewLayerSettings, name="Ember", description="Ember's passes of this view layer")


def unregister():
    del bpy.types.ViewLayer.ember
    del bpy.types.Scene.ember
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
