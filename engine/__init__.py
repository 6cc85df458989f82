"""Ember's renderer: plain NumPy scene data in, pixels out (no Blender).

This file declares the engine's public surface, ``__all__``: what the add-on
uses (through ``addon.backend.engine()``, vendored or not) and what the
command line and the farm may rely on.  Everything else is internal, read by
the engine's own modules and its tests.  tests/engine/test_imports.py checks
that the add-on uses only these names and that no import forms a cycle
(docs/design.md, Imports).  Importing the package loads NumPy and the
engine's modules, not numba (compiled on the first render) nor embreex
(loaded on the first scene built).  ``engine.render`` is the render function;
the module of that name is ``importlib.import_module("engine.render")``.
"""
from . import bake
from .coplanar import coincident_pairs
from .environment import bake as bake_environment
from .environment import lookup as environment_lookup
from .kernels import cache_complete as kernel_cache_complete
from .kernels import configure as configure_kernels
from .kernels import stop as stop_kernels
from .kernels import wait as wait_for_kernels
from .kernels import warm_cache as warm_kernel_cache
from .lobes.hair import sigma_from_color as hair_sigma_from_color
from .lobes.hair import sigma_from_melanin as hair_sigma_from_melanin
from .nodes import REGISTRY as NODE_REGISTRY
from .nodes import ShadingContext
from .nodes.hashing import hash_uint
from . import mesh_attributes
from .instance_batch import InstanceBatch, distinct as distinct_instances, join as join_instances
from .instance_batch import meshes_of as instance_meshes
from .nodes.input_nodes import instance_attribute_key
from .nodes.sky import sun_guide as sky_sun_guide
from .passes import PassConfig, murmur3_32
from .render import RenderResult, prepare, render
from .scene import (FALLOFFS, MATH_OPERATIONS, MIX_BLENDS, TEXTURE_TYPES, AreaLight, Bump, Camera, Cancelled,
                    Displacement, EnvironmentTexture, HairCurves, ImageTexture, Instance, LinkSet, Lobe,
                    Material, Math, Mesh, MixColor, NodeCall, NodeOutput, NormalMap, PointCloud, PointLight,
                    RenderSettings, Scene, SceneError, SpotLight, SunGuide, SunLight, TextureImage, Volume, World)
from .textures import Compiler as TextureCompiler
from .textures import value_range
from .validate import validate_camera, validate_scene, validate_settings

__all__ = [
    # scene data the exporter builds (engine.scene)
    "Scene", "Mesh", "Instance", "InstanceBatch", "distinct_instances", "join_instances", "instance_meshes",
    "LinkSet", "Material", "Lobe", "Volume", "Camera", "World", "EnvironmentTexture",
    "SunGuide",
    "PointLight", "SpotLight", "SunLight", "AreaLight", "PointCloud", "HairCurves",
    "TextureImage", "ImageTexture", "MixColor", "Math", "NormalMap", "Bump", "NodeCall", "NodeOutput",
    "Displacement",
    "TEXTURE_TYPES", "MIX_BLENDS", "MATH_OPERATIONS", "FALLOFFS",
    "RenderSettings", "SceneError", "Cancelled",
    # validation (engine.validate); faces of objects that coincide (engine.coplanar)
    "validate_scene", "validate_settings", "validate_camera", "coincident_pairs",
    # rendering (engine.render, engine.passes)
    "render", "prepare", "RenderResult", "PassConfig", "murmur3_32",
    # texture baking (engine.bake)
    "bake",
    # the numba kernels (engine.kernels): compile once, wait, stop
    "configure_kernels", "wait_for_kernels", "stop_kernels", "kernel_cache_complete", "warm_kernel_cache",
    # shader nodes and textures the exporter evaluates (engine.nodes, engine.textures)
    "NODE_REGISTRY", "ShadingContext", "TextureCompiler", "value_range", "hash_uint",
    # Geometry node attributes derived from a mesh's topology (engine.mesh_attributes)
    "mesh_attributes",
    # Attribute nodes of Object / Instancer / View Layer type: Instance.object_attributes keys
    "instance_attribute_key",
    # the Principled Hair BSDF's absorption from melanin or colour (engine.lobes.hair)
    "hair_sigma_from_melanin", "hair_sigma_from_color",
    # worlds (engine.environment, engine.nodes.sky)
    "bake_environment", "environment_lookup", "sky_sun_guide",
]
