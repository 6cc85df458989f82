"""Texture and input nodes rendered by Ember and by Cycles agree (also
textures on float inputs: weights, IORs, Mix Shader factors).

Test images are made at test time (NumPy + OpenImageIO) in a tmp folder.
Each scene groups several materials on quads side by side, seen from above
by an orthographic camera, direct light only (max bounces 0) from a large
area light (its sampling noise gives every block a measurable variance).
Ember's render is compared with a converged Cycles reference
(tests/data/cycles_texture_<scene>.exr, tools/cycles_references.py) by the
image and quadrant totals and block by block, at the suite's family level
(ember_testlib.check_against_reference).
"""
import os

import bpy
import numpy as np
import pytest

from parity_scenes import ortho_grid_scene
from ember_testlib import check_against_reference, render_array, render_for_reference, require, setup_ember

EMBER_SPP = 256
SAMPLES = {'inputs': 384}   # 256 resolved 0.50 % of the image, at the 0.5 % asked (the channel sum's variance)
BLOCK = 12          # one quad per block
IMAGE_POWER, BLOCK_POWER = 0.005, 0.02   # issue 12's targets, asserted
TILE = 12           # pixels per quad side
GRID = 4            # quads per row


def oiio():
    try:
        import OpenImageIO
    except ImportError:
        OpenImageIO = None
    require(OpenImageIO is not None, "OpenImageIO is needed to write test images")
    return OpenImageIO


def write_image(path, pixels, uint8=False):
    """pixels (H, W, C) in [0, 1], row 0 at the top."""
    io = oiio()
    h, w, c = pixels.shape
    spec = io.ImageSpec(w, h, c, io.UINT8 if uint8 else io.FLOAT)
    out = io.ImageOutput.create(path)
    assert out.open(path, spec), io.geterror()
    data = np.round(pixels * 255).astype(np.uint8) if uint8 else pixels.astype(np.float32)
    assert out.write_image(data)
    out.close()
    return path


def checker(n=4, a=(0.85, 0.3, 0.1), b=(0.1, 0.4, 0.8)):
    img = np.empty((n, n, 3))
    odd = np.add.outer(np.arange(n), np.arange(n)) % 2 == 1
    img[odd], img[~odd] = b, a
    img[0, 0] = (0.9, 0.9, 0.2)  # marks the top-left corner (catches flips)
    return img


def gradient(n=8):
    u = (np.arange(n) + 0.5) / n
    img = np.zeros((n, n, 3))
    img[..., 0] = u[None, :]
    img[..., 1] = u[::-1, None]
    img[..., 2] = 0.3
    return img


# ----------------------------------------------------------------------------
# scene building

def empty_scene():
    return ortho_grid_scene(GRID, 2, TILE)


def add_quad(index, material, uv_min=(0.0, 0.0), uv_max=(1.0, 1.0), rotate_uv=False):
    """A 1 m quad at grid cell ``index`` (row 0 at the top of the image)."""
    x, y = index % GRID, 1 - index // GRID
    mesh = bpy.data.meshes.new(f"quad{index}")
    mesh.from_pydata([(x, y, 0), (x + 1, y, 0), (x + 1, y + 1, 0), (x, y + 1, 0)], [], [(0, 1, 2, 3)])
    layer = mesh.uv_layers.new(name="UVMap")
    (u0, v0), (u1, v1) = uv_min, uv_max
    corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    if rotate_uv:
        corners = corners[1:] + corners[:1]
    for loop, uv in zip(mesh.polygons[0].loop_indices, corners):
        layer.data[loop].uv = uv
    mesh.materials.append(material)
    obj = bpy.data.objects.new(f"quad{index}", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def diffuse_material(name):
    """A material whose Diffuse BSDF Color the caller links."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes['Principled BSDF'])
    diffuse = tree.nodes.new('ShaderNodeBsdfDiffuse')
    tree.links.new(diffuse.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    return mat, tree, diffuse


def image_node(tree, path, colorspace='sRGB', interpolation='Linear', extension='REPEAT', pack=False):
    image = bpy.data.images.load(path)
    image.colorspace_settings.name = colorspace
    if pack:
        image.pack()
    node = tree.nodes.new('ShaderNodeTexImage')
    node.image = image
    node.interpolation = interpolation
    node.extension = extension
    return node


def mix_node(tree, blend, fac):
    """Mix node in colour mode (3.4+): inputs Factor, A, B by identifier."""
    node = tree.nodes.new('ShaderNodeMix')
    node.data_type = 'RGBA'
    node.blend_type = blend
    sockets = {s.identifier: s for s in node.inputs}
    sockets['Factor_Float'].default_value = fac
    return node, sockets['A_Color'], sockets['B_Color'], node.outputs[2]


def linear_colorspace():
    names = [item.identifier for item in
             bpy.types.ColorManagedInputColorspaceSettings.bl_rna.properties['name'].enum_items]
    for name in ('Linear Rec.709', 'Linear'):
        if name in names:
            return name
    pytest.fail(f"no linear colour space among {names}")


# ----------------------------------------------------------------------------
# the scenes

def build_images(folder):
    """Image Texture: interpolations, extensions, colour spaces, packed, alpha."""
    scene = empty_scene()
    exr = write_image(os.path.join(folder, "checker.exr"), checker())
    png = write_image(os.path.join(folder, "gradient.png"), gradient(), uint8=True)
    rgba = np.concatenate([gradient(), np.tile(np.linspace(0.0, 1.0, 8)[:, None, None], (1, 8, 1))], axis=2)
    alpha_png = write_image(os.path.join(folder, "alpha.png"), rgba, uint8=True)
    linear = linear_colorspace()
    cases = [
        (dict(path=exr, colorspace=linear, interpolation='Closest'), dict(uv_max=(2.0, 2.0))),
        (dict(path=exr, colorspace=linear, extension='EXTEND'), dict(uv_min=(-0.3, -0.3), uv_max=(1.3, 1.3))),
        (dict(path=exr, colorspace=linear, extension='CLIP'), dict(uv_min=(-0.3, -0.3), uv_max=(1.3, 1.3))),
        (dict(path=png), dict(rotate_uv=True)),
        (dict(path=png, colorspace='Non-Color', interpolation='Closest'), {}),
        (dict(path=png, pack=True, extension='EXTEND'), dict(uv_min=(-0.2, 0.0), uv_max=(1.2, 1.0))),
    ]
    for index, (image_args, quad_args) in enumerate(cases):
        mat, tree, diffuse = diffuse_material(f"image{index}")
        node = image_node(tree, **image_args)
        tree.links.new(node.outputs['Color'], diffuse.inputs['Color'])
        add_quad(index, mat, **quad_args)
    # Alpha output as the factor between red and the (unassociated) colour.
    mat, tree, diffuse = diffuse_material("alpha")
    node = image_node(tree, alpha_png)
    mix, a, b, out = mix_node(tree, 'MIX', 0.5)
    a.default_value = (0.8, 0.1, 0.1, 1.0)
    tree.links.new(node.outputs['Alpha'], mix.inputs[0])
    tree.links.new(node.outputs['Color'], b)
    tree.links.new(out, diffuse.inputs['Color'])
    add_quad(6, mat)
    # Straight alpha, Alpha output unused: Cycles outputs the associated colour.
    mat, tree, diffuse = diffuse_material("premultiplied")
    node = image_node(tree, alpha_png, interpolation='Closest')
    tree.links.new(node.outputs['Color'], diffuse.inputs['Color'])
    add_quad(7, mat)
    return scene


def build_nodes(folder):
    """RGB, Value, Mix Color blends, legacy MixRGB, Math on constants and on
    texture values, roughness from a texture."""
    scene = empty_scene()
    exr = write_image(os.path.join(folder, "gradient.exr"), gradient())
    linear = linear_colorspace()
    index = 0
    for blend in ('MULTIPLY', 'SCREEN', 'OVERLAY', 'SUBTRACT'):
        mat, tree, diffuse = diffuse_material(f"mix_{blend}")
        node = image_node(tree, exr, linear)
        mix, a, b, out = mix_node(tree, blend, 0.7)
        rgb = tree.nodes.new('ShaderNodeRGB')
        rgb.outputs[0].default_value = (0.3, 0.6, 0.9, 1.0)
        tree.links.new(node.outputs['Color'], a)
        tree.links.new(rgb.outputs[0], b)
        tree.links.new(out, diffuse.inputs['Color'])
        add_quad(index, mat)
        index += 1
    # Legacy MixRGB (ADD, clamped) with a Value node as factor.
    mat, tree, diffuse = diffuse_material("mixrgb")
    node = image_node(tree, exr, linear)
    legacy = tree.nodes.new('ShaderNodeMixRGB')
    legacy.blend_type = 'ADD'
    legacy.use_clamp = True
    legacy.inputs['Color2'].default_value = (0.4, 0.2, 0.1, 1.0)
    value = tree.nodes.new('ShaderNodeValue')
    value.outputs[0].default_value = 0.8
    tree.links.new(value.outputs[0], legacy.inputs['Fac'])
    tree.links.new(node.outputs['Color'], legacy.inputs['Color1'])
    tree.links.new(legacy.outputs[0], diffuse.inputs['Color'])
    add_quad(index, mat)
    index += 1
    # Math on a texture value (colour -> float is luminance), into a colour.
    mat, tree, diffuse = diffuse_material("math_texture")
    node = image_node(tree, exr, linear)
    power = tree.nodes.new('ShaderNodeMath')
    power.operation = 'POWER'
    power.inputs[1].default_value = 0.5
    tree.links.new(node.outputs['Color'], power.inputs[0])
    tree.links.new(power.outputs[0], diffuse.inputs['Color'])
    add_quad(index, mat)
    index += 1
    # Math on constants only.
    mat, tree, diffuse = diffuse_material("math_constants")
    madd = tree.nodes.new('ShaderNodeMath')
    madd.operation = 'MULTIPLY_ADD'
    madd.inputs[0].default_value, madd.inputs[1].default_value, madd.inputs[2].default_value = 0.3, 0.5, 0.2
    tree.links.new(madd.outputs[0], diffuse.inputs['Color'])
    add_quad(index, mat)
    index += 1
    # Glossy roughness from a texture through a Math node.
    mat, tree, diffuse = diffuse_material("rough")
    tree.nodes.remove(diffuse)
    glossy = tree.nodes.new('ShaderNodeBsdfGlossy')
    if hasattr(glossy, 'distribution'):
        glossy.distribution = 'GGX'
    node = image_node(tree, exr, linear)
    scale = tree.nodes.new('ShaderNodeMath')
    scale.operation = 'MULTIPLY_ADD'
    scale.inputs[1].default_value, scale.inputs[2].default_value = 0.6, 0.3
    tree.links.new(node.outputs['Color'], scale.inputs[0])
    tree.links.new(scale.outputs[0], glossy.inputs['Roughness'])
    tree.links.new(glossy.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    add_quad(index, mat)
    return scene


def build_normals(folder):
    """Normal Map (tangent space, strengths, rotated UVs) and Bump nodes."""
    scene = empty_scene()
    n = 16
    u = (np.arange(n) + 0.5) / n
    wave = np.zeros((n, n, 3))
    wave[..., 0] = 0.5 + 0.3 * np.sin(2 * np.pi * u)[None, :]
    wave[..., 1] = 0.5 + 0.25 * np.cos(2 * np.pi * u)[:, None]
    wave[..., 2] = 0.9
    normal_png = write_image(os.path.join(folder, "normals.png"), wave, uint8=True)
    height = np.tile((0.5 + 0.5 * np.sin(2 * np.pi * u))[None, :, None], (n, 1, 3))
    height_exr = write_image(os.path.join(folder, "height.exr"), height)
    linear = linear_colorspace()
    index = 0
    for strength, rotate in ((1.0, False), (0.5, False), (1.0, True)):
        mat, tree, diffuse = diffuse_material(f"normal_map_{index}")
        diffuse.inputs['Color'].default_value = (0.8, 0.8, 0.8, 1.0)
        node = image_node(tree, normal_png, 'Non-Color')
        nmap = tree.nodes.new('ShaderNodeNormalMap')
        nmap.inputs['Strength'].default_value = strength
        tree.links.new(node.outputs['Color'], nmap.inputs['Color'])
        tree.links.new(nmap.outputs['Normal'], diffuse.inputs['Normal'])
        add_quad(index, mat, rotate_uv=rotate)
        index += 1
    for strength, distance, invert in ((1.0, 0.1, False), (0.7, 0.2, True), (1.0, 0.15, False)):
        mat, tree, diffuse = diffuse_material(f"bump_{index}")
        diffuse.inputs['Color'].default_value = (0.8, 0.8, 0.8, 1.0)
        node = image_node(tree, height_exr, linear)
        bump = tree.nodes.new('ShaderNodeBump')
        bump.inputs['Strength'].default_value = strength
        bump.inputs['Distance'].default_value = distance
        bump.invert = invert
        tree.links.new(node.outputs['Color'], bump.inputs['Height'])
        tree.links.new(bump.outputs['Normal'], diffuse.inputs['Normal'])
        add_quad(index, mat)
        index += 1
    # Principled BSDF with a normal map (tangent frames from Blender's MikkTSpace).
    mat = bpy.data.materials.new("principled_normal")
    mat.use_nodes = True
    tree = mat.node_tree
    node = image_node(tree, normal_png, 'Non-Color')
    nmap = tree.nodes.new('ShaderNodeNormalMap')
    tree.links.new(node.outputs['Color'], nmap.inputs['Color'])
    tree.links.new(nmap.outputs['Normal'], tree.nodes['Principled BSDF'].inputs['Normal'])
    tree.nodes['Principled BSDF'].inputs['Roughness'].default_value = 0.6
    add_quad(index, mat, rotate_uv=True)
    index += 1
    mat, tree, diffuse = diffuse_material("plain")
    add_quad(index, mat)
    return scene


def principled_material(name, **inputs):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    bsdf = tree.nodes['Principled BSDF']
    for socket, value in inputs.items():
        bsdf.inputs[socket].default_value = value
    return mat, tree, bsdf


def build_inputs(folder):
    """Float inputs driven by textures (weights, IORs, factors): Principled
    Metallic, Alpha, Transmission, Coat, Sheen, IOR and Specular IOR Level,
    Mix Shader Fac and Glass IOR, from grey checkers and gradients."""
    scene = empty_scene()
    grey = checker(a=(0.9,) * 3, b=(0.15,) * 3)
    grey[0, 0] = 0.5
    mask = write_image(os.path.join(folder, "mask.exr"), grey)
    ramp = write_image(os.path.join(folder, "ramp.exr"), np.repeat(gradient()[..., :1], 3, axis=2))
    ior_checker = checker(a=(2.3,) * 3, b=(1.4,) * 3)
    ior_checker[0, 0] = 1.8
    iors = write_image(os.path.join(folder, "iors.exr"), ior_checker)
    orange = (0.8, 0.35, 0.1, 1.0)
    cases = [
        ('metallic', dict(Roughness=0.35), 'Metallic', mask, 'Closest'),
        ('alpha', dict(), 'Alpha', mask, 'Closest'),
        ('transmission', dict(Roughness=0.3), 'Transmission Weight', ramp, 'Linear'),
        ('coat', dict(Roughness=0.6), 'Coat Weight', ramp, 'Linear'),
        ('sheen', dict(Roughness=0.7), 'Sheen Weight', mask, 'Closest'),
        ('ior', dict(Roughness=0.2), 'IOR', iors, 'Closest'),
        ('specular', dict(Roughness=0.25), 'Specular IOR Level', ramp, 'Linear'),
    ]
    for index, (name, inputs, socket, path, interpolation) in enumerate(cases):
        mat, tree, bsdf = principled_material(name, **{'Base Color': orange, **inputs})
        node = image_node(tree, path, 'Non-Color', interpolation)
        tree.links.new(node.outputs['Color'], bsdf.inputs[socket])
        add_quad(index, mat)
    # Mix Shader: Fac from a texture between a red diffuse and a Glass BSDF
    # whose IOR is textured too.
    mat, tree, diffuse = diffuse_material("mix_fac")
    diffuse.inputs['Color'].default_value = (0.7, 0.1, 0.1, 1.0)
    glass = tree.nodes.new('ShaderNodeBsdfGlass')
    glass.inputs['Roughness'].default_value = 0.25
    mix = tree.nodes.new('ShaderNodeMixShader')
    tree.links.new(image_node(tree, ramp, 'Non-Color').outputs['Color'], mix.inputs['Fac'])
    tree.links.new(image_node(tree, iors, 'Non-Color', 'Closest').outputs['Color'], glass.inputs['IOR'])
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glass.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    add_quad(7, mat)
    return scene


SCENES = {'images': build_images, 'nodes': build_nodes, 'normals': build_normals, 'inputs': build_inputs}


def reference_scene(name, folder):
    """The scene ``name`` (its images written into ``folder``) and its bounces."""
    return SCENES[name](str(folder)), 0


# The converged reference found the quads with a tangent-space Normal Map at
# strength 1 0.6-0.9 % brighter than Cycles (t 7-10; image +0.29 % +- 0.03 %):
# Cycles' bump shadowing term, which main added since (2b2ce97), removed it.
@pytest.mark.parametrize("name", sorted(SCENES))
def test_textures_agree_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name, tmp_path)
    spp = SAMPLES.get(name, EMBER_SPP)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 1, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
    assert not any("magenta" in w or "not translated" in w or "constant value" in w for w in warnings), warnings
    check = check_against_reference('texture_' + name, scene, bounces, image, var, spp, BLOCK)
    check.assert_agrees(IMAGE_POWER, BLOCK_POWER)


def test_missing_image_renders_magenta_with_one_warning(tmp_path, tapped_engine):
    scene = empty_scene()
    path = write_image(os.path.join(str(tmp_path), "gone.exr"), checker())
    mat, tree, diffuse = diffuse_material("lost")
    node = image_node(tree, path, linear_colorspace())
    tree.links.new(node.outputs['Color'], diffuse.inputs['Color'])
    add_quad(0, mat)
    node.image.reload()
    os.remove(path)
    node.image.reload()
    setup_ember(scene, 4, seed=0, max_bounces=0)
    image = render_array(scene, tmp_path, "missing")
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None
    lost = [w for w in log['warnings'] if "'lost'" in w]
    assert len(lost) == 1 and "magenta" in lost[0] and "gone.exr" in lost[0], log['warnings']
    quad = image[2:TILE - 2, 2:TILE - 2, :3].mean(axis=(0, 1))
    assert quad[1] == 0.0 and quad[0] > 0.05 and quad[0] == pytest.approx(quad[2], rel=1e-6), quad


def test_textured_float_inputs_become_expressions_without_warnings(tmp_path):
    """Metallic, Alpha, IOR, Coat, Specular IOR Level and Mix Fac textures are
    rendered (no "read as its constant value" warning); a texture on an input
    of an input Ember reads as a constant (Subsurface Radius; 3.x Subsurface) still is, and a lobe
    whose weight texture is zero everywhere is left out."""
    from addon.export import material as material_export
    from engine.scene import TEXTURE_TYPES
    empty_scene()
    mask = write_image(os.path.join(str(tmp_path), "mask.exr"), checker(a=(1.0,) * 3, b=(0.0,) * 3))
    black = write_image(os.path.join(str(tmp_path), "black.exr"), np.zeros((2, 2, 3)))
    mat, tree, bsdf = principled_material("inputs")
    for socket in ('Metallic', 'Alpha', 'IOR', 'Specular IOR Level'):
        tree.links.new(image_node(tree, mask, 'Non-Color').outputs['Color'], bsdf.inputs[socket])
    tree.links.new(image_node(tree, black, 'Non-Color').outputs['Color'], bsdf.inputs['Coat Weight'])
    translated, warning = material_export.translate(mat)
    assert warning is None, warning
    kinds = [lobe.kind for lobe in translated.lobes]
    assert kinds == ['transparent', 'glossy', 'glossy', 'diffuse'], kinds   # no coat: its weight is 0
    assert all(isinstance(lobe.weight, TEXTURE_TYPES) for lobe in translated.lobes)
    assert isinstance(translated.lobes[2].ior, TEXTURE_TYPES)            # specular layer IOR
    # A texture on a subsurface input read as a constant (4.x: the Radius; 3.x: Subsurface itself).
    subsurface = 'Subsurface Radius' if 'Subsurface Weight' in bsdf.inputs else 'Subsurface'
    if 'Subsurface Weight' in bsdf.inputs:
        bsdf.inputs['Subsurface Weight'].default_value = 0.5
    tree.links.new(image_node(tree, mask, 'Non-Color').outputs['Color'], bsdf.inputs[subsurface])
    _, warning = material_export.translate(mat)
    assert warning is not None and f"{bsdf.name}.{subsurface}" in warning and "constant value" in warning
    assert "Metallic" not in warning and "Alpha" not in warning
