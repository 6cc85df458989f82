"""The Environment Texture node on surfaces (ImageTexture with an environment
projection), exact against Cycles' formulas written out here
(kernel/svm/image.h svm_node_tex_environment, kernel/camera/projection.h):
the unlinked Vector is the world position (LINK_POSITION), normalized;
equirectangular and mirror-ball UVs; REPEAT always; the Color stays
associated with alpha.  Live-Cycles parity: tests/addon/test_environment_node_parity.py."""
import numpy as np
import pytest

from engine import textures
from engine.nodes import ShadingContext
from engine.scene import (Camera, ImageTexture, Instance, Lobe, Material, NodeCall, NodeOutput, Scene,
                          SceneError, TextureImage, World)
from engine.testscenes import look_at, quad
from engine.validate import validate_scene

H, W = 8, 16
RNG = np.random.default_rng(5)
PIXELS = RNG.random((H, W, 3)).astype(np.float32)     # row 0 = the top
IMAGE = TextureImage(PIXELS, name="env")


def evaluate(node, ctx):
    fn, _ = textures.Compiler().compile(node)
    return fn(ctx)


def cycles_equirect(d):
    """direction_to_equirectangular_range with Cycles' default range."""
    u = (np.arctan2(d[:, 1], d[:, 0]) - np.pi) / (-2.0 * np.pi)
    v = (np.arccos(d[:, 2] / np.linalg.norm(d, axis=1)) - np.pi) / (-np.pi)
    return u, v


def cycles_mirrorball(d):
    d = d / np.linalg.norm(d, axis=1)[:, None]
    d = d - np.array([0.0, 1.0, 0.0])
    div = 2.0 * np.sqrt(np.maximum(-0.5 * d[:, 1], 0.0))
    d = d / np.where(div > 0, div, 1.0)[:, None]
    return 0.5 * (d[:, 0] + 1.0), 0.5 * (d[:, 2] + 1.0)


def closest_texels(u, v):
    """Cycles' Closest lookup, REPEAT: texel floor(u W), row floor(v H) from the bottom."""
    ix = np.floor(u * W).astype(int) % W
    iy = np.floor(v * H).astype(int) % H
    return PIXELS[H - 1 - iy, ix].astype(np.float64)


def points(n=400):
    p = RNG.normal(size=(n, 3)) * RNG.uniform(0.1, 30.0, size=(n, 1))
    return p


def test_unlinked_vector_reads_the_world_position_as_a_direction():
    p = points()
    node = ImageTexture(IMAGE, interpolation="Closest", projection="EQUIRECTANGULAR")
    got = evaluate(node, ShadingContext(len(p), p=p))
    np.testing.assert_allclose(got, closest_texels(*cycles_equirect(p)), rtol=1e-6)
    # Only the direction counts: scaling the positions changes nothing.
    np.testing.assert_allclose(evaluate(node, ShadingContext(len(p), p=p * 7.5)), got, rtol=1e-6)


def test_linked_vector_mirror_ball():
    """The Vector from Geometry > Normal (a linked direction), mirror ball."""
    n = points()
    n /= np.linalg.norm(n, axis=1)[:, None]
    p = points()       # not read: the Vector is linked
    normal = NodeOutput(NodeCall("ShaderNodeNewGeometry", {}), "Normal")
    node = ImageTexture(IMAGE, interpolation="Closest", uv=normal, projection="MIRROR_BALL")
    got = evaluate(node, ShadingContext(len(n), p=p, ng=n, ns=n, wo=n))
    np.testing.assert_allclose(got, closest_texels(*cycles_mirrorball(n)), rtol=1e-6)


@pytest.mark.parametrize("projection, uv", [("EQUIRECTANGULAR", (0.0, 0.0)), ("MIRROR_BALL", (0.5, 0.5))])
def test_zero_vector(projection, uv):
    """A linked zero Vector: Cycles' equirectangular lookup returns (0, 0)
    for it, the mirror ball its centre (safe_normalize keeps it zero)."""
    node = ImageTexture(IMAGE, interpolation="Closest", uv=(0.0, 0.0, 0.0), projection=projection)
    got = evaluate(node, ShadingContext(3, p=points(3)))
    np.testing.assert_allclose(got, closest_texels(np.full(3, uv[0]), np.full(3, uv[1])), rtol=1e-6)


def test_linear_wraps_across_the_seam_whatever_the_extension():
    """-X is u = 0 and the horizon v = 1/2: Linear blends the four texels
    around that corner, columns 0 and W - 1 (REPEAT; Cycles' node has no
    other extension)."""
    p = np.array([[-3.0, 0.0, 0.0]])
    rows = PIXELS[[H // 2 - 1, H // 2]][:, [0, W - 1]].astype(np.float64)
    for extension in ("REPEAT", "CLIP", "EXTEND"):
        node = ImageTexture(IMAGE, extension=extension, projection="EQUIRECTANGULAR")
        np.testing.assert_allclose(evaluate(node, ShadingContext(1, p=p))[0], rows.mean(axis=(0, 1)), rtol=1e-6)


def test_color_stays_associated_with_alpha_linked():
    """svm_node_tex_environment has no unassociate flag: Color = colour x
    alpha for a straight-alpha image, Alpha = alpha."""
    rgba = np.tile(np.array([0.6, 0.4, 0.2, 0.5], np.float32), (H, W, 1))
    image = TextureImage(rgba, name="straight", alpha_mode="STRAIGHT")
    p = points(10)
    colour = ImageTexture(image, interpolation="Closest", projection="EQUIRECTANGULAR", unassociate=False)
    alpha = ImageTexture(image, interpolation="Closest", output="Alpha", projection="EQUIRECTANGULAR")
    np.testing.assert_allclose(evaluate(colour, ShadingContext(10, p=p)), np.tile([0.3, 0.2, 0.1], (10, 1)),
                               rtol=1e-6)
    np.testing.assert_allclose(evaluate(alpha, ShadingContext(10, p=p)), np.full(10, 0.5), rtol=1e-6)


def test_tiles_are_not_read():
    """Cycles' Environment Texture loads no UDIM tiles: the image's own pixels."""
    other = TextureImage(np.zeros((2, 2, 3), np.float32), name="tile 1002")
    tiled = TextureImage(PIXELS, name="tiled", tiles=((1001, other), (1002, other)))
    p = points(50)
    node = ImageTexture(tiled, interpolation="Closest", projection="EQUIRECTANGULAR")
    np.testing.assert_allclose(evaluate(node, ShadingContext(50, p=p)), closest_texels(*cycles_equirect(p)),
                               rtol=1e-6)


def test_unknown_projection_is_a_scene_error():
    bad = ImageTexture(IMAGE, projection="CUBE")
    mesh = quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), resolution=(4, 4))
    scene = Scene([mesh], [Instance(0, materials=[0])], [Material("env on a quad", (Lobe("diffuse", bad),))], [],
                  World((0.0, 0.0, 0.0)), cam)
    with pytest.raises(SceneError, match="env on a quad") as err:
        validate_scene(scene)
    assert "image projection" in str(err.value)
