"""Ember's panels in Render Properties, and Blender's own panels shown for Ember.

Ember's options sit where Cycles keeps its own: Sampling (samples, time limit,
seed, lights, strategy), Light Paths (bounces, clamping) and Film (pixel
filter, transparency).  Blender's generic panels (output, colour management,
camera, light, world, material...) are opted in through ``COMPAT_ENGINES``.
"""
import bpy

ENGINE_ID = 'EMBER'

# Panels that Blender marks 'BLENDER_RENDER' are generic; these EEVEE ones are
# what makes materials, worlds and lights editable without Cycles' own panels.
# Names differ between versions, so missing ones are skipped.
EXTRA_PANELS = (
    'EEVEE_MATERIAL_PT_context_material',
    'EEVEE_MATERIAL_PT_surface',
    'EEVEE_WORLD_PT_surface',
    'DATA_PT_EEVEE_light',
    'DATA_PT_EEVEE_light_distance',
    'DATA_PT_camera_dof',
    'DATA_PT_camera_dof_aperture',
    'MATERIAL_PT_preview',
)

# Generic panels that show settings Ember ignores; hiding them avoids promising
# features that are not there.
EXCLUDED_PANELS = (
    'VIEWLAYER_PT_layer_passes',
    'RENDER_PT_freestyle',
)


class EmberPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = 'render'
    COMPAT_ENGINES = {ENGINE_ID}

    # (property of scene.ember, label or None) drawn by the default draw().
    PROPS = ()

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def split_layout(self):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        return layout

    def draw(self, context):
        layout = self.split_layout()
        for name, label in self.PROPS:
            if label is None:
                layout.prop(context.scene.ember, name)
            else:
                layout.prop(context.scene.ember, name, text=label)


class RENDER_PT_ember_sampling(EmberPanel, bpy.types.Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = self.split_layout()
        ember = context.scene.ember
        row = layout.row(heading="Noise Threshold")
        row.prop(ember, "use_adaptive_sampling", text="")
        sub = row.row()
        sub.active = ember.use_adaptive_sampling
        sub.prop(ember, "adaptive_threshold", text="")
        layout.prop(ember, "samples", text="Max Samples" if ember.use_adaptive_sampling else "Samples")
        sub = layout.column()
        sub.active = ember.use_adaptive_sampling
        sub.prop(ember, "adaptive_min_samples", text="Min Samples")
        layout.prop(ember, "preview_samples", text="Preview")
        layout.prop(ember, "time_limit")
        layout.prop(ember, "seed")


class RENDER_PT_ember_sampling_viewport(EmberPanel, bpy.types.Panel):
    bl_label = "Viewport"
    bl_parent_id = 'RENDER_PT_ember_sampling'
    PROPS = (("viewport_samples", "Max Samples"), ("preview_pause", None),
             ("use_preview_denoising", "Denoise"))


class RENDER_PT_ember_sampling_denoise(EmberPanel, bpy.types.Panel):
    bl_label = "Denoise"
    bl_parent_id = 'RENDER_PT_ember_sampling'
    PROPS = (("use_denoising", "Denoise Render"),)


class RENDER_PT_ember_sampling_lights(EmberPanel, bpy.types.Panel):
    bl_label = "Lights"
    bl_parent_id = 'RENDER_PT_ember_sampling'
    bl_options = {'DEFAULT_CLOSED'}
    PROPS = (("light_selection", None), ("mis_compensation", None))


class RENDER_PT_ember_sampling_advanced(EmberPanel, bpy.types.Panel):
    bl_label = "Advanced"
    bl_parent_id = 'RENDER_PT_ember_sampling'
    bl_options = {'DEFAULT_CLOSED'}
    PROPS = (("sampling_pattern", None), ("strategy", None), ("threads", None), ("use_jit", None))


class RENDER_PT_ember_performance(EmberPanel, bpy.types.Panel):
    """Render > Performance > Final Render, where Cycles keeps Persistent
    Data (scene.render.use_persistent_data: Blender's own property)."""
    bl_label = "Performance"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.split_layout()
        layout.prop(context.scene.render, "use_persistent_data", text="Persistent Data")


class RENDER_PT_ember_light_paths(EmberPanel, bpy.types.Panel):
    bl_label = "Light Paths"
    bl_options = {'DEFAULT_CLOSED'}
    PROPS = (("max_bounces", "Total"), ("diffuse_bounces", "Diffuse"), ("glossy_bounces", "Glossy"),
             ("transmission_bounces", "Transmission"), ("transparent_max_bounces", "Transparent"),
             ("volume_bounces", "Volume"))


class RENDER_PT_ember_light_paths_caustics(EmberPanel, bpy.types.Panel):
    bl_label = "Caustics"
    bl_parent_id = 'RENDER_PT_ember_light_paths'
    PROPS = (("filter_glossy", None),)


class RENDER_PT_ember_light_paths_clamping(EmberPanel, bpy.types.Panel):
    bl_label = "Clamping"
    bl_parent_id = 'RENDER_PT_ember_light_paths'
    PROPS = (("clamp", "Samples"),)


class RENDER_PT_ember_film(EmberPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.split_layout()
        layout.prop(context.scene.ember, "filter_type")
        if context.scene.ember.filter_type != 'BOX':  # Cycles' box is always 1 pixel wide
            layout.prop(context.scene.ember, "filter_width")
        layout.prop(context.scene.render, "film_transparent", text="Transparent")


class EmberPassesPanel(EmberPanel):
    bl_context = 'view_layer'
    # (owner, property, label): owner 'layer' = view_layer, 'ember' = view_layer.ember,
    # 'cycles' = view_layer.cycles (Cycles' own pass settings, as Volume Direct);
    # properties a Blender version lacks are left out.
    PROPS = ()

    def draw(self, context):
        layout = self.split_layout()
        layer = context.view_layer
        for owner, name, label in self.PROPS:
            target = getattr(layer, owner, None) if owner in ('ember', 'cycles') else layer
            if target is not None and hasattr(target, name):
                layout.prop(target, name, text=label)


class VIEWLAYER_PT_ember_passes(EmberPassesPanel, bpy.types.Panel):
    """Ember's own passes on top; Cycles' passes in the sub-panels."""
    bl_label = "Passes"
    PROPS = (('ember', 'use_pass_strategies', "Strategies"),
             ('ember', 'strategy_passes_vertex', "Vertices"),
             ('ember', 'use_pass_variance', "Variance"))


class VIEWLAYER_PT_ember_passes_data(EmberPassesPanel, bpy.types.Panel):
    bl_label = "Data"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    PROPS = (('layer', 'use_pass_combined', "Combined"), ('layer', 'use_pass_z', "Z"),
                   ('layer', 'use_pass_mist', "Mist"), ('layer', 'use_pass_position', "Position"),
                   ('layer', 'use_pass_normal', "Normal"), ('layer', 'use_pass_vector', "Vector"),
                   ('layer', 'use_pass_uv', "UV"), ('ember', 'use_pass_denoising_data', "Denoising Data"),
                   ('layer', 'use_pass_object_index', "Object Index"),
                   ('layer', 'use_pass_material_index', "Material Index"),
                   ('ember', 'use_pass_sample_count', "Sample Count"))


class VIEWLAYER_PT_ember_passes_light(EmberPassesPanel, bpy.types.Panel):
    bl_label = "Light"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    PROPS = tuple(('layer', f'use_pass_{kind}_{part}', f"{kind.title()} {part.title()}")
                        for kind in ('diffuse', 'glossy', 'transmission')
                        for part in ('direct', 'indirect', 'color')) + (
        ('cycles', 'use_pass_volume_direct', "Volume Direct"),
        ('cycles', 'use_pass_volume_indirect', "Volume Indirect"),
        ('layer', 'use_pass_emit', "Emission"), ('layer', 'use_pass_environment', "Environment"),
        ('layer', 'use_pass_ambient_occlusion', "Ambient Occlusion"))


class VIEWLAYER_PT_ember_passes_lightgroups(EmberPassesPanel, bpy.types.Panel):
    """Cycles' Light Groups list (its panel is Cycles-only): one
    Combined_<group> pass each; objects and lights join a group in Object
    Properties > Light Group, the world here."""
    bl_label = "Light Groups"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.split_layout()
        layer = context.view_layer
        if not hasattr(layer, "lightgroups"):
            return
        if hasattr(layout, "template_list"):
            row = layout.row()
            row.template_list("UI_UL_list", "ember_lightgroups", layer, "lightgroups",
                              layer, "active_lightgroup_index", rows=3)
            col = row.column(align=True)
            col.operator("scene.view_layer_add_lightgroup", icon='ADD', text="")
            col.operator("scene.view_layer_remove_lightgroup", icon='REMOVE', text="")
        world = context.scene.world
        if world is not None and hasattr(world, "lightgroup"):
            layout.prop(world, "lightgroup", text="World")


class VIEWLAYER_PT_ember_passes_aovs(EmberPassesPanel, bpy.types.Panel):
    """Cycles' Shader AOV list (its panel is Cycles-only): one pass per AOV,
    written by the materials' AOV Output nodes."""
    bl_label = "Shader AOV"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    bl_options = {'DEFAULT_CLOSED'}
    PROPS = (('layer', 'use_pass_combined', "Combined"),)

    def draw(self, context):
        layout = self.split_layout()
        layer = context.view_layer
        if not hasattr(layer, "aovs") or not hasattr(layout, "template_list"):
            EmberPassesPanel.draw(self, context)
            return
        row = layout.row()
        row.template_list("UI_UL_list", "ember_aovs", layer, "aovs", layer, "active_aov_index", rows=3)
        col = row.column(align=True)
        col.operator("scene.view_layer_add_aov", icon='ADD', text="")
        col.operator("scene.view_layer_remove_aov", icon='REMOVE', text="")
        aov = layer.active_aov
        if aov is not None:
            layout.prop(aov, "type")


class OBJECT_PT_ember_lightgroup(bpy.types.Panel):
    bl_label = "Light Group"
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    bl_context = 'object'
    bl_options = {'DEFAULT_CLOSED'}
    COMPAT_ENGINES = {ENGINE_ID}
    PROPS = ()

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and context.object is not None

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if hasattr(obj, "lightgroup"):
            layout.prop(obj, "lightgroup", text="Light Group")


class VIEWLAYER_PT_ember_passes_crypto(EmberPassesPanel, bpy.types.Panel):
    bl_label = "Cryptomatte"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    PROPS = (('layer', 'use_pass_cryptomatte_object', "Object"),
                   ('layer', 'use_pass_cryptomatte_material', "Material"),
                   ('layer', 'use_pass_cryptomatte_asset', "Asset"),
                   ('layer', 'pass_cryptomatte_depth', "Levels"))


class VIEWLAYER_PT_ember_passes_strategies(EmberPassesPanel, bpy.types.Panel):
    bl_label = "Ember"
    bl_parent_id = 'VIEWLAYER_PT_ember_passes'
    PROPS = (('ember', 'use_pass_strategies', "Strategies"),
                   ('ember', 'strategy_passes_vertex', "Vertices"),
                   ('ember', 'use_pass_variance', "Variance"))


classes = (
    RENDER_PT_ember_sampling,
    RENDER_PT_ember_sampling_viewport,
    RENDER_PT_ember_sampling_denoise,
    RENDER_PT_ember_sampling_lights,
    RENDER_PT_ember_sampling_advanced,
    RENDER_PT_ember_light_paths,
    RENDER_PT_ember_light_paths_clamping,
    RENDER_PT_ember_light_paths_caustics,
    RENDER_PT_ember_film,
    RENDER_PT_ember_performance,
    VIEWLAYER_PT_ember_passes,
    VIEWLAYER_PT_ember_passes_data,
    VIEWLAYER_PT_ember_passes_light,
    VIEWLAYER_PT_ember_passes_crypto,
    VIEWLAYER_PT_ember_passes_lightgroups,
    VIEWLAYER_PT_ember_passes_aovs,
    OBJECT_PT_ember_lightgroup,
)


def compatible_panels():
    """Blender's panels that should also show when Ember is the engine."""
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, 'COMPAT_ENGINES', None)
        if not isinstance(engines, set) or panel.__name__ in EXCLUDED_PANELS:
            continue
        if 'BLENDER_RENDER' in engines or panel.__name__ in EXTRA_PANELS:
            panels.append(panel)
    return panels


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in compatible_panels():
        panel.COMPAT_ENGINES.add(ENGINE_ID)


def unregister():
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, 'COMPAT_ENGINES', None)
        if isinstance(engines, set) and panel not in classes:
            engines.discard(ENGINE_ID)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
