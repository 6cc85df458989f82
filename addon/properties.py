"""Ember's render settings, stored on the scene as ``scene.ember``.

Defaults and ranges follow Cycles where the two renderers share an idea, so a
scene moved between them keeps its meaning.  Film transparency is Blender's
own ``scene.render.film_transparent`` and is not duplicated here.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

LIGHT_SELECTION_ITEMS = (
    ('POWER', "Power", "Pick one light per vertex, proportional to its power"),
    ('UNIFORM', "Uniform", "Pick one light per vertex, every light equally likely"),
    ('ALL', "All Lights", "Sample every light at every vertex (slower, less noise with few lights)"),
    ('TREE', "Light Tree", "Pick one light per vertex by its estimated contribution there "
     "(power, distance and orientation): far less noise with many lights"),
)

STRATEGY_ITEMS = (
    ('MIS', "Multiple Importance", "Combine light and BSDF sampling (the robust default)"),
    ('LIGHT', "Light Only", "Next-event estimation only (debugging)"),
    ('BSDF', "BSDF Only", "BSDF sampling only (debugging)"),
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
    light_selection: EnumProperty(
        name="Light Selection", description="How a light is chosen for next-event estimation",
        items=LIGHT_SELECTION_ITEMS, default='POWER')
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


classes = (EmberRenderSettings,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    # Added after registration, not in a register() classmethod: the bpy 4.2
    # module crashes at exit when the pointer is created inside register_class.
    bpy.types.Scene.ember = PointerProperty(
        type=EmberRenderSettings, name="Ember", description="Ember render settings")


def unregister():
    del bpy.types.Scene.ember
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
