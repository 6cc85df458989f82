"""Textures: image sampling exact on hand-made images, per-hit UVs, normal map
and bump checked analytically, textured renders, no NaN from degenerate UVs,
clear errors for bad textures."""
import numpy as np
import pytest

from engine import textures
from engine.integrator import _interaction
from engine.render import prepare, render
from engine.scene import (Bump, Camera, ImageTexture, Instance, Lobe, Material, Math, Mesh, MixColor,
                          NormalMap, RenderSettings, Scene, SceneError, TextureImage, World)
from engine.testscenes import look_at
from engine.validate import validate_scene

# A 2 x 2 image, row 0 at the TOP: (top-left, top-right; bottom-left, bottom-right).
TL, TR, BL, BR = (0.1, 0.2, 0.3), (0.4, 0.5, 0.6), (0.7, 0.8, 0.9), (1.0, 0.0, 0.5)
IMAGE = TextureImage(np.array([[TL, TR], [BL, BR]], np.float32), name="tiny")


def lookup(node, uv):
    fn, _ = textures.Compiler().compile(node)
    return fn(np.atleast_2d(np.asarray(uv, float)))


def test_closest_reads_the_texel_under_the_uv():
    node = ImageTexture(IMAGE, interpolation="Closest")
    # v = 0 is the image's bottom row (Blender/Cycles convention).
    got = lookup(node, [[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])
    np.testing.assert_allclose(got, [BL, BR, TL, TR], rtol=1e-6)


def test_linear_blends_the_four_texels_around_the_uv():
    node = ImageTexture(IMAGE, interpolation="Linear", extension="EXTEND")
    got = lookup(node, [[0.5, 0.5], [0.25, 0.25], [0.5, 0.25], [0.375, 0.625]])
    centre = np.mean([TL, TR, BL, BR], axis=0)
    bottom_mid = 0.5 * (np.array(BL) + BR)
    # (0.375, 0.625): x = 0.25 texel past the left centres, y = 0.75 texel above the bottom ones.
    quarter = 0.25 * (0.75 * np.array(BL) + 0.25 * np.array(BR)) + 0.75 * (0.75 * np.array(TL) + 0.25 * np.array(TR))
    np.testing.assert_allclose(got, [centre, BL, bottom_mid, quarter], rtol=1e-6)


@pytest.mark.parametrize("extension, expected", [
    # u = -0.25 lies half a texel left of the image, v = 0.25 on the bottom row.
    ("REPEAT", BR), ("EXTEND", BL), ("CLIP", (0.0, 0.0, 0.0)), ("MIRROR", BL)])
def test_extension_modes_closest(extension, expected):
    node = ImageTexture(IMAGE, interpolation="Closest", extension=extension)
    np.testing.assert_allclose(lookup(node, [[-0.25, 0.25]])[0], expected, rtol=1e-6)


@pytest.mark.parametrize("extension", ["REPEAT", "EXTEND", "CLIP", "MIRROR"])
def test_extension_modes_linear_at_the_left_edge(extension):
    """u = 0 is half-way between texel -1 (outside) and texel 0 (BL)."""
    node = ImageTexture(IMAGE, interpolation="Linear", extension=extension)
    outside = {"REPEAT": BR, "EXTEND": BL, "CLIP": (0.0, 0.0, 0.0), "MIRROR": BL}[extension]
    expected = 0.5 * (np.array(outside) + BL)
    np.testing.assert_allclose(lookup(node, [[0.0, 0.25]])[0], expected, rtol=1e-6)


def test_repeat_is_periodic_far_from_the_origin():
    node = ImageTexture(IMAGE, interpolation="Linear")
    uv = np.random.default_rng(1).random((50, 2))
    np.testing.assert_allclose(lookup(node, uv + [7.0, -3.0]), lookup(node, uv), atol=1e-9)


def test_srgb_images_filter_encoded_and_decode_after():
    """8-bit sRGB images are filtered in sRGB encoding (as Cycles)."""
    lin = np.array([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]], np.float32)
    node = ImageTexture(TextureImage(lin, srgb_filter=True), extension="EXTEND")
    got = lookup(node, [[0.5, 0.5]])[0]
    np.testing.assert_allclose(got, textures.srgb_to_linear(0.5), rtol=1e-9)
    assert abs(textures.srgb_to_linear(0.5) - 0.21404) < 1e-5
    np.testing.assert_allclose(textures.srgb_to_linear(textures.linear_to_srgb([0.002, 0.3, 2.0])),
                               [0.002, 0.3, 2.0], rtol=1e-12)


def test_straight_alpha_is_associated_unless_the_alpha_output_is_used():
    px = np.array([[[0.8, 0.4, 0.2, 0.5]]], np.float32)
    image = TextureImage(px)
    np.testing.assert_allclose(lookup(ImageTexture(image), [[0.5, 0.5]])[0], [0.4, 0.2, 0.1])
    np.testing.assert_allclose(lookup(ImageTexture(image, unassociate=True), [[0.5, 0.5]])[0], [0.8, 0.4, 0.2])
    np.testing.assert_allclose(lookup(ImageTexture(image, output="Alpha"), [[0.5, 0.5]]), [0.5])
    ignored = TextureImage(px, alpha_mode="NONE")
    np.testing.assert_allclose(lookup(ImageTexture(ignored, output="Alpha"), [[0.5, 0.5]]), [1.0])
    np.testing.assert_allclose(lookup(ImageTexture(ignored), [[0.5, 0.5]])[0], [0.8, 0.4, 0.2])


def test_mix_and_math_follow_cycles_formulas():
    a, b = (0.2, 0.6, 0.9), (0.5, 0.25, 1.0)
    t = 0.3
    expected = {
        "MIX": 0.7 * np.array(a) + 0.3 * np.array(b),
        "MULTIPLY": np.array(a) * (0.7 + 0.3 * np.array(b)),
        "ADD": np.array(a) + 0.3 * np.array(b),
        "SUBTRACT": np.array(a) - 0.3 * np.array(b),
        "SCREEN": 1 - (0.7 + 0.3 * (1 - np.array(b))) * (1 - np.array(a)),
        "OVERLAY": [0.2 * (0.7 + 0.6 * 0.5), 1 - (0.7 + 0.6 * 0.75) * 0.4, 1 - (0.7 + 0.6 * 0.0) * 0.1],
    }
    for blend, want in expected.items():
        np.testing.assert_allclose(lookup(MixColor(blend, t, a, b), [[0, 0]])[0], want, rtol=1e-12)
    # A colour used as a factor is its luminance; factors clamp to [0, 1].
    np.testing.assert_allclose(lookup(MixColor("MIX", 2.0, a, b), [[0, 0]])[0], b)
    assert lookup(Math("DIVIDE", 1.0, 0.0), [[0, 0]])[0] == 0.0
    assert lookup(Math("POWER", -2.0, 0.5), [[0, 0]])[0] == 0.0
    assert lookup(Math("MULTIPLY_ADD", 2.0, 3.0, 1.0), [[0, 0]])[0] == 7.0
    assert lookup(Math("ADD", 0.7, 0.6, clamp=True), [[0, 0]])[0] == 1.0
    gray = lookup(Math("ADD", (1.0, 0.0, 0.0), 0.0), [[0, 0]])[0]
    assert abs(gray - 0.2126) < 1e-12


# ----------------------------------------------------------------------------
# Scenes: a unit quad in the XY plane, UV = (x, y), seen from +Z.

def uv_quad(uvs=None):
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    if uvs is None:
        uvs = p[tris][..., :2]
    return Mesh(p, tris, uvs=uvs, name="uv quad")


def ortho_scene(material, size=(16, 16), mesh=None, world=1.0):
    cam = Camera(look_at((0.5, 0.5, 2.0), (0.5, 0.5, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=1.0,
                 resolution=size, clip_start=0.01, clip_end=10.0)
    return Scene([mesh or uv_quad()], [Instance(0, materials=[0])], [material], [],
                 World((world, world, world)), cam)


def hits_at(scene, xy, from_below=False):
    """Interactions of rays shot straight down (or up) at points (x, y)."""
    ctx = prepare(scene, RenderSettings())
    xy = np.asarray(xy, float)
    z = -2.0 if from_below else 2.0
    o = np.column_stack([xy, np.full(len(xy), z)])
    d = np.tile([0.0, 0.0, 1.0 if from_below else -1.0], (len(xy), 1))
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(len(xy), np.inf))
    assert (prim >= 0).all()

    class P:
        pass
    paths = P()
    paths.o, paths.d = o, d
    return ctx, _interaction(ctx, paths, t, prim, bu, bv)


def test_hit_uvs_interpolate_the_corners():
    xy = np.random.default_rng(2).uniform(0.05, 0.95, (200, 2))
    _, hit = hits_at(ortho_scene(Material()), xy)
    np.testing.assert_allclose(hit.uv, xy, atol=1e-6)


def test_gather_overwrites_textured_parameters_per_ray():
    node = ImageTexture(IMAGE, interpolation="Closest")
    mat = Material("textured", (Lobe("glossy", node, Math("MULTIPLY", 0.5, 1.0)),))
    xy = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])
    ctx, hit = hits_at(ortho_scene(mat), xy)
    lobes = ctx.materials.gather(hit.mat, hit.uv)
    np.testing.assert_allclose(lobes.color[:, 0], [BL, BR, TL, TR], rtol=1e-5)
    np.testing.assert_allclose(lobes.alpha[:, 0], 0.25)


def test_textured_diffuse_under_a_unit_world_renders_the_texture():
    """Direct light only, albedo rho under a unit world: every sample is rho,
    so pixel centres away from texel edges equal the texture exactly."""
    checker = np.zeros((4, 4, 3), np.float32)
    checker[(np.add.outer(np.arange(4), np.arange(4)) % 2) == 0] = (0.9, 0.5, 0.1)
    checker[(np.add.outer(np.arange(4), np.arange(4)) % 2) == 1] = (0.1, 0.3, 0.7)
    node = ImageTexture(TextureImage(checker), interpolation="Closest")
    scene = ortho_scene(Material("checker", (Lobe("diffuse", node),)))
    result = render(scene, RenderSettings(samples=8, samples_per_pass=8, max_bounces=0, seed=1,
                                          filter_type="BOX", filter_width=1.0))
    img = result.image[..., :3]
    # 16 px over 4 texels: pixels 1..2 of every 4 see one texel only.
    inner = img.reshape(4, 4, 4, 4, 3)[:, 1:3, :, 1:3]
    np.testing.assert_allclose(inner, np.broadcast_to(checker[:, None, :, None], inner.shape), rtol=1e-9)


def test_normal_map_matches_the_tangent_frame():
    """On the quad the tangent frame is (x, y, z): n' = normalize(c x + c y + c z)."""
    color = (0.75, 0.4, 0.9)
    mat = Material("normal mapped", normal=NormalMap(color, 1.0))
    ctx, hit = hits_at(ortho_scene(mat), [[0.3, 0.6], [0.7, 0.2]])
    c = 2 * (np.array(color) - 0.5)
    want = c / np.linalg.norm(c)
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles), [want, want], atol=1e-9)
    # Half strength halves the tangential part and mixes z towards 1.
    mat.normal = NormalMap(color, 0.5)
    ctx, hit = hits_at(ortho_scene(mat), [[0.3, 0.6]])
    half = np.array([0.5 * c[0], 0.5 * c[1], 1 + 0.5 * (c[2] - 1)])
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles)[0],
                               half / np.linalg.norm(half), atol=1e-9)


def test_normal_map_on_back_faces_flips_with_the_surface():
    color = (0.75, 0.4, 0.9)
    mat = Material("normal mapped", normal=NormalMap(color, 1.0))
    ctx, hit = hits_at(ortho_scene(mat), [[0.3, 0.6]], from_below=True)
    c = 2 * (np.array(color) - 0.5)
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles)[0],
                               -c / np.linalg.norm(c), atol=1e-9)


def test_exported_tangents_are_used_and_follow_the_instance_matrix():
    """Tangents along y with sign -1: the frame is (y, -(z x y), z) = (y, x, z)."""
    mesh = uv_quad()
    mesh.tangents = np.tile([0.0, 1.0, 0.0], (2, 3, 1))
    mesh.tangent_signs = -np.ones((2, 3))
    color = (0.75, 0.4, 0.9)
    mat = Material("normal mapped", normal=NormalMap(color, 1.0))
    ctx, hit = hits_at(ortho_scene(mat, mesh=mesh), [[0.3, 0.6]])
    c = 2 * (np.array(color) - 0.5)
    want = np.array([c[1], c[0], c[2]])
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles)[0],
                               want / np.linalg.norm(want), atol=1e-9)


def ramp_image(n=8):
    """Texel i holds (i + 0.5) / n: bilinear lookups with EXTEND give h = u
    exactly between the first and last texel centres."""
    row = (np.arange(n) + 0.5) / n
    return TextureImage(np.tile(row[None, :, None], (n, 1, 1)).astype(np.float32), name="ramp")


@pytest.mark.parametrize("distance, strength, invert", [(0.5, 1.0, False), (0.3, 0.6, True)])
def test_bump_tilts_the_normal_against_the_height_gradient(distance, strength, invert):
    """h = u on a 2 m quad: grad h = (0.5, 0, 0) per metre; Cycles' bump is
    n' = normalize(n - distance * grad h), mixed with n by strength."""
    mesh = uv_quad()
    mesh.positions = mesh.positions * 2.0
    height = ImageTexture(ramp_image(), extension="EXTEND")
    mat = Material("bumped", normal=Bump(height, strength, distance, invert))
    ctx, hit = hits_at(ortho_scene(mat, mesh=mesh), [[0.7, 0.9], [1.2, 0.4]])
    d = -distance if invert else distance
    bumped = np.array([-d * 0.5, 0.0, 1.0])
    want = strength * bumped / np.linalg.norm(bumped) + (1 - strength) * np.array([0, 0, 1.0])
    want /= np.linalg.norm(want)
    got = ctx.materials.textures.perturb(hit, ctx.triangles)
    np.testing.assert_allclose(got, [want, want], atol=1e-6)


def test_bump_of_a_constant_height_changes_nothing():
    mat = Material("flat bump", normal=Bump(Math("ADD", 0.3, 0.2), 1.0, 1.0))
    ctx, hit = hits_at(ortho_scene(mat), [[0.3, 0.6]])
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles), hit.ns)


def test_degenerate_uvs_give_finite_pixels():
    """Every corner at one UV (and NaN-free garbage far away): textures, bump
    and normal map must not produce NaN."""
    uvs = np.full((2, 3, 2), 0.5)
    uvs[1] = 1e30
    mesh = uv_quad(uvs)
    node = ImageTexture(ramp_image(), interpolation="Linear")
    mat = Material("degenerate", (Lobe("diffuse", node),),
                   normal=Bump(ImageTexture(ramp_image()), 1.0, 1.0, normal=NormalMap((0.6, 0.5, 1.0))))
    result = render(ortho_scene(mat, mesh=mesh, size=(8, 8)),
                    RenderSettings(samples=4, samples_per_pass=4, max_bounces=1, seed=0))
    assert np.isfinite(result.image).all()
    assert result.image[..., :3].mean() > 0.05
    assert np.isfinite(textures.sample_texels(textures.prepare_texels(IMAGE),
                                              np.array([[np.nan, np.inf], [-1e300, 3.0]]))).all()


def test_normal_map_without_uvs_keeps_the_normal():
    mesh = uv_quad()
    mesh.uvs = None
    mat = Material("no uv", normal=NormalMap((0.8, 0.5, 0.6)))
    ctx, hit = hits_at(ortho_scene(mat, mesh=mesh), [[0.3, 0.6]])
    np.testing.assert_allclose(ctx.materials.textures.perturb(hit, ctx.triangles), hit.ns)


@pytest.mark.parametrize("bad, message", [
    (ImageTexture(TextureImage(np.zeros((2, 2, 5)), name="fat")), "'fat'"),
    (ImageTexture(TextureImage(np.full((2, 2, 3), np.nan), name="nan")), "NaN"),
    (ImageTexture(IMAGE, extension="WRAP"), "extension"),
    (MixColor("BLUR", 0.5, (1, 1, 1), (0, 0, 0)), "mix blend"),
    (Math("HYPOT", 1.0, 2.0), "math operation"),
    (Math("ADD", "one", 2.0), "expected a number"),
])
def test_bad_textures_raise_scene_errors_naming_the_material(bad, message):
    scene = ortho_scene(Material("broken", (Lobe("diffuse", bad),)))
    with pytest.raises(SceneError, match="broken") as err:
        validate_scene(scene)
    assert message in str(err.value)


def test_textured_emission_per_texel_in_nee_and_bsdf_hits():
    """An emissive quad textured half red, half blue: seen directly it shows
    its texels, and the floor it lights renders the same by light sampling
    (emission evaluated at the sampled point's UVs) and by BSDF sampling."""
    from engine.render import render
    from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
    from engine.testscenes import look_at, quad

    import sys, os
    sys.path.insert(0, os.path.dirname(__file__))
    from ember_stats import block_means_var, family_z, z_scores

    image = TextureImage(np.array([[[4.0, 0.0, 0.0], [0.0, 0.0, 4.0]]], np.float32))
    lamp = quad([[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]])
    lamp.uvs = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    floor = quad([[-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]])
    mats = [Material("lamp", (), emission=ImageTexture(image, interpolation="Closest")),
            Material("floor", (Lobe("diffuse", (0.8, 0.8, 0.8)),))]
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=4.0,
                 resolution=(32, 32), clip_start=0.01)
    scene = Scene([lamp, floor], [Instance(0, materials=[0]), Instance(1, materials=[1])], mats, [],
                  World((0.0, 0.0, 0.0)), cam)
    r = {s: render(scene, RenderSettings(samples=256, samples_per_pass=256, seed=3, strategy=s, max_bounces=0))
         for s in ("light", "bsdf")}
    img = r["light"].image
    left, right = img[16, 13, :3], img[16, 18, :3]   # the lamp's two halves, seen from above
    assert left[0] > 3.9 and left[2] == 0 and right[2] > 3.9 and right[0] == 0
    ma, va = block_means_var(r["light"].image[..., :3].astype(float), r["light"].variance.astype(float), 4)
    mb, vb = block_means_var(r["bsdf"].image[..., :3].astype(float), r["bsdf"].variance.astype(float), 4)
    z = z_scores(ma, va, mb, vb)
    floor_blocks = np.isfinite(z) & (va + vb > 0)
    limit = family_z(__name__, floor_blocks.sum())
    rel = (np.sqrt(va + vb) / np.where(mb != 0, np.abs(mb), 1.0))[floor_blocks]
    print(f"textured emission, light vs bsdf: max |z| {np.abs(z[floor_blocks]).max():.2f} (limit {limit:.2f}); "
          f"detects {limit * np.median(rel):.1%} in a median block with probability 1/2")
    assert np.abs(z[floor_blocks]).max() < limit
    # The floor under the red half is redder than under the blue half.
    floor_left, floor_right = ma[4, 0], ma[4, 7]
    assert floor_left[0] > floor_left[2] and floor_right[2] > floor_right[0]
