"""Render passes under Cycles' names: which ones a view layer asks for, how
they are registered with Blender, and how the engine's passes are written.

The engine names passes as Blender 5.0 does (engine/passes.py); older
Blenders (3.4, 4.2) call the same Cycles passes by short names (IndexOB,
DiffDir, Emit ...), so the compositor's sockets match in every version.
Generic passes use the View Layer checkboxes Cycles uses
(``view_layer.use_pass_mist`` ...); Cycles-only ones (Denoising Data, Sample
Count) and Ember's own (strategy passes, Variance) are on ``view_layer.ember``.
"""
import json

import bpy

from . import backend

# engine name, legacy (< 5.0) name, channels, chan_id, type, enabled by
# (a view_layer property, or "ember.<property>" / "cycles.<property>" on its settings).
PASSES = (
    ("Depth", "Depth", 1, "Z", 'VALUE', "use_pass_z"),
    ("Mist", "Mist", 1, "Z", 'VALUE', "use_pass_mist"),
    ("Position", "Position", 3, "XYZ", 'VECTOR', "use_pass_position"),
    ("Normal", "Normal", 3, "XYZ", 'VECTOR', "use_pass_normal"),
    ("UV", "UV", 3, "UVA", 'VECTOR', "use_pass_uv"),
    ("Vector", "Vector", 4, "XYZW", 'VECTOR', "use_pass_vector"),
    ("Object Index", "IndexOB", 1, "X", 'VALUE', "use_pass_object_index"),
    ("Material Index", "IndexMA", 1, "X", 'VALUE', "use_pass_material_index"),
    ("Diffuse Direct", "DiffDir", 3, "RGB", 'COLOR', "use_pass_diffuse_direct"),
    ("Diffuse Indirect", "DiffInd", 3, "RGB", 'COLOR', "use_pass_diffuse_indirect"),
    ("Diffuse Color", "DiffCol", 3, "RGB", 'COLOR', "use_pass_diffuse_color"),
    ("Glossy Direct", "GlossDir", 3, "RGB", 'COLOR', "use_pass_glossy_direct"),
    ("Glossy Indirect", "GlossInd", 3, "RGB", 'COLOR', "use_pass_glossy_indirect"),
    ("Glossy Color", "GlossCol", 3, "RGB", 'COLOR', "use_pass_glossy_color"),
    ("Transmission Direct", "TransDir", 3, "RGB", 'COLOR', "use_pass_transmission_direct"),
    ("Transmission Indirect", "TransInd", 3, "RGB", 'COLOR', "use_pass_transmission_indirect"),
    ("Transmission Color", "TransCol", 3, "RGB", 'COLOR', "use_pass_transmission_color"),
    ("Volume Direct", "VolumeDir", 3, "RGB", 'COLOR', "cycles.use_pass_volume_direct"),
    ("Volume Indirect", "VolumeInd", 3, "RGB", 'COLOR', "cycles.use_pass_volume_indirect"),
    ("Emission", "Emit", 3, "RGB", 'COLOR', "use_pass_emit"),
    ("Environment", "Env", 3, "RGB", 'COLOR', "use_pass_environment"),
    ("Ambient Occlusion", "AO", 3, "RGB", 'COLOR', "use_pass_ambient_occlusion"),
    ("Denoising Normal", "Denoising Normal", 3, "XYZ", 'VECTOR', "ember.use_pass_denoising_data"),
    ("Denoising Albedo", "Denoising Albedo", 3, "RGB", 'COLOR', "ember.use_pass_denoising_data"),
    ("Sample Count", "Debug Sample Count", 1, "X", 'VALUE', "ember.use_pass_sample_count"),
    ("Strategy Light", "Strategy Light", 3, "RGB", 'COLOR', "ember.use_pass_strategies"),
    ("Strategy BSDF", "Strategy BSDF", 3, "RGB", 'COLOR', "ember.use_pass_strategies"),
    ("Strategy Light Unweighted", "Strategy Light Unweighted", 3, "RGB", 'COLOR', "ember.use_pass_strategies"),
    ("Strategy BSDF Unweighted", "Strategy BSDF Unweighted", 3, "RGB", 'COLOR', "ember.use_pass_strategies"),
    ("MIS Weight Light", "MIS Weight Light", 1, "X", 'VALUE', "ember.use_pass_strategies"),
    ("Variance", "Variance", 3, "RGB", 'COLOR', "ember.use_pass_variance"),
    ("Shadow Catcher", "Shadow Catcher", 3, "RGB", 'COLOR', "cycles.use_pass_shadow_catcher"),
)
CRYPTO = (("CryptoObject", "use_pass_cryptomatte_object"),
          ("CryptoMaterial", "use_pass_cryptomatte_material"),
          ("CryptoAsset", "use_pass_cryptomatte_asset"))
MIST_FALLOFF = {'QUADRATIC': 2.0, 'LINEAR': 1.0, 'INVERSE_QUADRATIC': 0.5}


def modern_names():
    """Blender 5.0 renamed Cycles' passes (IndexOB -> Object Index ...)."""
    return bpy.app.version >= (5, 0, 0)


# Passes whose Blender name is the same in every version but not the engine's.
ALWAYS_LEGACY = {"Sample Count"}


def blender_name(engine_name, legacy):
    return engine_name if modern_names() and engine_name not in ALWAYS_LEGACY else legacy


def _enabled(view_layer, prop):
    """A view layer property, or one of its ``ember.`` / ``cycles.`` settings
    (Cycles' Shadow Catcher pass is ``view_layer.cycles.use_pass_shadow_catcher``)."""
    owner, _, name = prop.rpartition(".")
    settings = getattr(view_layer, owner, None) if owner else view_layer
    return bool(getattr(settings, name, False)) if settings is not None else False


def crypto_layers(view_layer):
    """RGBA layers per Cryptomatte pass: two ranked ids each."""
    depth = int(getattr(view_layer, "pass_cryptomatte_depth", 6))
    return max(1, (depth + 1) // 2)


def requested(view_layer):
    """[(engine name, blender name, channels, chan_id, type)] this layer asks for."""
    out = []
    for name, legacy, channels, chan_id, kind, prop in PASSES:
        if _enabled(view_layer, prop):
            out.append((name, blender_name(name, legacy), channels, chan_id, kind))
    for name, prop in CRYPTO:
        if _enabled(view_layer, prop):
            for i in range(crypto_layers(view_layer)):
                out.append((name, f"{name}{i:02d}", 4, "RGBA", 'COLOR'))
    for group in getattr(view_layer, "lightgroups", ()):
        name = "Combined_" + group.name
        out.append((name, name, 3, "RGB", 'COLOR'))
    for aov in getattr(view_layer, "aovs", ()):
        if aov.type == 'COLOR':
            out.append(("AOV Color:" + aov.name, aov.name, 4, "RGBA", 'COLOR'))
        else:
            out.append(("AOV Value:" + aov.name, aov.name, 1, "X", 'VALUE'))
    return out


def register_passes(engine, scene, view_layer):
    for _, blender, channels, chan_id, kind in requested(view_layer):
        engine.register_pass(scene, view_layer, blender, channels, chan_id, kind)


def add_result_passes(engine, view_layer):
    """Blender creates a render result with Combined only: add the layer's
    other passes before begin_result."""
    for _, blender, channels, chan_id, _ in requested(view_layer):
        engine.add_pass(blender, channels, chan_id, layer=view_layer.name)


def engine_passes(view_layer):
    """The engine pass names to request for this view layer."""
    names = []
    for name, *_ in requested(view_layer):
        if name not in names:
            names.append(name)
    return tuple(names)


def pass_config(scene, view_layer, config_class):
    """engine.passes.PassConfig from the world's Mist and AO settings."""
    world = scene.world
    kwargs = {}
    if world is not None:
        mist = world.mist_settings
        kwargs.update(mist_start=float(mist.start), mist_depth=float(mist.depth),
                      mist_falloff=MIST_FALLOFF.get(mist.falloff, 2.0),
                      ao_distance=float(world.light_settings.distance))
        kwargs.update(world_lightgroup=str(getattr(world, "lightgroup", "") or ""))
    ember = getattr(view_layer, "ember", None)
    first = ember is not None and ember.strategy_passes_vertex == 'FIRST'
    # Light groups by object name (lights and meshes; instances of an object
    # share its name and group, as in Cycles).
    groups = {obj.name: obj.lightgroup for obj in scene.objects if getattr(obj, "lightgroup", "")}
    return config_class(strategy_first_vertex=first, lightgroup_of=groups,
                        crypto_levels=2 * crypto_layers(view_layer), **kwargs)


def blender_images(view_layer, engine_images, samples=1):
    """{blender pass name: (H, W, C) array} from the engine's pass images.
    Sample Count is Cycles' Debug Sample Count: a fraction of the samples."""
    out = {}
    for name, blender, channels, _, _ in requested(view_layer):
        image = engine_images.get(name)
        if image is None:
            continue
        if name.startswith("Crypto"):
            layer = int(blender[-2:])
            image = image[..., 4 * layer:4 * layer + 4]
            if image.shape[-1] < 4:
                continue
        if name == "Sample Count":
            image = image / max(samples, 1)
        out[blender] = image
    return out


def crypto_metadata(view_layer, manifests):
    """Render-result metadata the Cryptomatte node reads, as Cycles writes it:
    cryptomatte/<7 hex of the layer name's hash>/{name, hash, conversion, manifest}."""
    renderer = backend.engine()
    fields = {}
    for kind, manifest in manifests.items():
        layer = f"{view_layer.name}.{kind}"
        key = f"cryptomatte/{renderer.murmur3_32(layer):08x}"[:len("cryptomatte/") + 7]
        fields[key + "/name"] = layer
        fields[key + "/hash"] = "MurmurHash3_32"
        fields[key + "/conversion"] = "uint32_to_float32"
        fields[key + "/manifest"] = json.dumps(manifest, separators=(",", ":"))
    return fields
