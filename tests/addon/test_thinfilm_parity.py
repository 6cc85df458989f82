"""Cycles parity of thin-film iridescence (engine/thinfilm.py wired into
the lobes): one scene, rendered by Ember and compared with a converged
Cycles reference (tools/cycles_references.py thinfilm_films,
tests/data/cycles_thinfilm_films.exr) by the totals of the image and its
quadrants and block by block (ember_testlib.check_against_reference), power
printed.

Objects, under an area light and a dim grey world, over a grey floor:
* a soap bubble: a smooth Principled sphere, Transmission 1, IOR 1.33, a
  500 nm film of IOR 1.45 (the film over the glass lobe, read from inside
  with the film IOR divided by 1.33 as Cycles);
* oil on metal: a Principled Metallic sphere under a 420 nm film of IOR 1.5
  (the F82 metal's Gulbrandsen n, k under the film);
* a Metallic BSDF (F82 Tint) sphere under a 320 nm film of IOR 1.5;
* a Principled dielectric over a red diffuse base with a 600 nm film of IOR
  1.4 on its specular layer (the layer's albedo at the view angle dims the
  base, as Cycles' bsdf_albedo).

Hostile inputs (thickness NaN, negative, 1e30; film IOR 0 and NaN) render
finite pixels, NaN named in the material's warning.
"""
import bpy
import numpy as np

from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution
from test_lobe_parity import _material, _sphere, lit_stage
from parity_scenes import plane

EMBER_SPP = 256
BLOCK = 16
WIDTH, HEIGHT = 64, 48
BOUNCES = 8


def films(scene):
    plane("Floor", _material("Floor", 'ShaderNodeBsdfDiffuse', Color=(0.5, 0.5, 0.5)), half=6.0)
    bubble = _material("Bubble", 'ShaderNodeBsdfPrincipled', **{
        'Base Color': (1.0, 1.0, 1.0), 'Transmission Weight': 1.0, 'IOR': 1.33, 'Roughness': 0.0,
        'Thin Film Thickness': 500.0, 'Thin Film IOR': 1.45, 'distribution': 'MULTI_GGX'})
    _sphere(bubble, (-1.1, 0.45, 0.5), radius=0.5)
    oil = _material("OilOnMetal", 'ShaderNodeBsdfPrincipled', **{
        'Base Color': (0.8, 0.78, 0.75), 'Metallic': 1.0, 'Roughness': 0.25,
        'Thin Film Thickness': 420.0, 'Thin Film IOR': 1.5, 'distribution': 'MULTI_GGX'})
    _sphere(oil, (1.1, 0.45, 0.5), radius=0.5)
    metal = _material("FilmedF82", 'ShaderNodeBsdfMetallic', **{
        'Base Color': (0.95, 0.64, 0.54), 'Edge Tint': (0.9, 0.9, 0.6), 'Roughness': 0.3,
        'Thin Film Thickness': 320.0, 'Thin Film IOR': 1.5, 'fresnel_type': 'F82', 'distribution': 'MULTI_GGX'})
    _sphere(metal, (0.6, -0.75, 0.42))
    coated = _material("FilmedSpecular", 'ShaderNodeBsdfPrincipled', **{
        'Base Color': (0.6, 0.1, 0.08), 'Roughness': 0.2, 'IOR': 1.5,
        'Thin Film Thickness': 600.0, 'Thin Film IOR': 1.4, 'distribution': 'MULTI_GGX'})
    _sphere(coated, (-0.6, -0.75, 0.42))
    lit_stage(scene, 120.0, (0.4, 1.4, 3.2), 0.25, (0.0, -4.2, 2.6), (0.0, 3.9, -2.3), 42)
    small_resolution(scene, WIDTH, HEIGHT)
    return BOUNCES


def conductors(scene):
    """Physical Conductors (the Metallic BSDF's exact complex-IOR Fresnel):
    gold's n, k bare, a k = 0 conductor (n 1.5: where the F82 fit misses
    the exact curve by up to 26 %), and copper's n, k under a 350 nm film."""
    plane("Floor", _material("Floor", 'ShaderNodeBsdfDiffuse', Color=(0.5, 0.5, 0.5)), half=6.0)
    gold = _material("Gold", 'ShaderNodeBsdfMetallic', **{
        'IOR': (0.18, 0.42, 1.37), 'Extinction': (3.42, 2.35, 1.77), 'Roughness': 0.3,
        'fresnel_type': 'PHYSICAL_CONDUCTOR', 'distribution': 'MULTI_GGX'})
    _sphere(gold, (-1.1, 0.45, 0.5), radius=0.5)
    clear = _material("KZero", 'ShaderNodeBsdfMetallic', **{
        'IOR': (1.5, 1.5, 1.5), 'Extinction': (0.0, 0.0, 0.0), 'Roughness': 0.2,
        'fresnel_type': 'PHYSICAL_CONDUCTOR', 'distribution': 'GGX'})
    _sphere(clear, (1.1, 0.45, 0.5), radius=0.5)
    copper = _material("FilmedCopper", 'ShaderNodeBsdfMetallic', **{
        'IOR': (0.27, 0.68, 1.32), 'Extinction': (3.61, 2.62, 2.29), 'Roughness': 0.25,
        'Thin Film Thickness': 350.0, 'Thin Film IOR': 1.45, 'fresnel_type': 'PHYSICAL_CONDUCTOR',
        'distribution': 'MULTI_GGX'})
    _sphere(copper, (0.0, -0.75, 0.42))
    lit_stage(scene, 120.0, (0.4, 1.4, 3.2), 0.35, (0.0, -4.2, 2.6), (0.0, 3.9, -2.3), 42)
    small_resolution(scene, WIDTH, HEIGHT)
    return BOUNCES


SCENES = {'films': films, 'conductors': conductors}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_thin_film_parity_with_cycles(tmp_path, tapped_engine):
    """Films over glass, F82 metals and the Principled specular layer
    render as Cycles, and no warning calls them approximated any more."""
    from addon import engine as ember_engine
    scene, bounces = reference_scene('films')
    image, var = render_for_reference(scene, tmp_path, 'films', tapped_engine, EMBER_SPP, 13, bounces)
    warnings = " ".join(ember_engine.RENDER_LOG[-1]['warnings'])
    assert "Thin Film" not in warnings, warnings
    check = check_against_reference('thinfilm_films', scene, bounces, image, var, EMBER_SPP, BLOCK)
    check.assert_agrees(0.006, 0.03)


def test_physical_conductor_parity_with_cycles(tmp_path, tapped_engine):
    """Physical Conductors render with their exact Fresnel as Cycles' CONDUCTOR
    mode (bare, k = 0, under a film), no approximation named."""
    from addon import engine as ember_engine
    scene, bounces = reference_scene('conductors')
    image, var = render_for_reference(scene, tmp_path, 'conductors', tapped_engine, EMBER_SPP, 17, bounces)
    warnings = " ".join(ember_engine.RENDER_LOG[-1]['warnings'])
    assert "Conductor" not in warnings and "F82" not in warnings, warnings
    check = check_against_reference('thinfilm_conductors', scene, bounces, image, var, EMBER_SPP, BLOCK)
    check.assert_agrees(0.006, 0.03)


def hostile(scene):
    nan = float('nan')
    _sphere(_material("NaNFilm", 'ShaderNodeBsdfPrincipled', **{
        'Metallic': 1.0, 'Thin Film Thickness': nan, 'Thin Film IOR': 1.5}), (-1.0, 0.0, 0.42))
    _sphere(_material("HugeFilm", 'ShaderNodeBsdfPrincipled', **{
        'Transmission Weight': 1.0, 'Roughness': 0.1, 'Thin Film Thickness': 1e30, 'Thin Film IOR': 0.0}),
        (0.0, 0.0, 0.42))
    _sphere(_material("NegativeFilm", 'ShaderNodeBsdfMetallic', **{
        'Thin Film Thickness': -300.0, 'Thin Film IOR': 1.5}), (1.0, 0.0, 0.42))
    _sphere(_material("NaNFilmIOR", 'ShaderNodeBsdfGlass', **{
        'Roughness': 0.0, 'Thin Film Thickness': 400.0, 'Thin Film IOR': nan}), (0.0, 1.0, 0.42))
    _sphere(_material("ZeroFilmIOR", 'ShaderNodeBsdfMetallic', **{
        'Thin Film Thickness': 400.0, 'Thin Film IOR': 0.0}), (0.0, -1.0, 0.42))
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.5, 0.5, 0.5, 1.0)
    scene.world = world
    scene.camera.location = (0.0, -4.0, 3.0)
    from mathutils import Vector
    scene.camera.rotation_euler = Vector((0.0, 4.0, -2.6)).to_track_quat('-Z', 'Y').to_euler()
    small_resolution(scene, 24, 18)
    return 4


def test_hostile_thin_film_inputs_render_finite(tmp_path, tapped_engine):
    """Thickness NaN, negative or 1e30, film IOR 0 or NaN: finite pixels, the
    NaN inputs named in the material's warning, the finite ones clamped
    unnamed as Cycles clamps them."""
    from addon import engine as ember_engine
    scene = empty_factory_scene()
    bounces = hostile(scene)
    image, _ = render_for_reference(scene, tmp_path, 'hostile_film', tapped_engine, 8, 1, bounces)
    assert np.isfinite(image).all() and image[..., :3].max() > 0.0
    warnings = " ".join(ember_engine.RENDER_LOG[-1]['warnings'])
    print(warnings)
    for name in ("NaNFilm", "NaNFilmIOR"):
        assert f"'{name}'" in warnings and "nan read as" in warnings, name
    for name in ("HugeFilm", "NegativeFilm", "ZeroFilmIOR"):
        assert f"'{name}'" not in warnings, name
