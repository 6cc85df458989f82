"""Textured lobe weights and IORs (issue 4: Metallic, Alpha, Mix Fac, IOR
driven by textures): per-ray overrides of any Lobe field render exactly as
the constant materials they select, f0 follows a textured IOR, and the value
ranges the exporter uses to leave lobes out bound every value."""
import numpy as np
import pytest

from engine import textures
from engine.render import render
from engine.scene import (Camera, ImageTexture, Instance, Lobe, Material, Math, Mesh, MixColor,
                          RenderSettings, Scene, SceneError, TextureImage, World)
from engine.testscenes import look_at
from engine.validate import validate_scene

N = 4                       # checker cells per side
SIZE = 16                   # pixels per side: 4 x 4 per cell


def checker(a=1.0, b=0.0):
    img = np.full((N, N, 3), b, np.float32)
    img[(np.add.outer(np.arange(N), np.arange(N)) % 2) == 0] = a
    return img


CHECKER = ImageTexture(TextureImage(checker(), name="checker"), interpolation="Closest")


def metal(weight):
    return Lobe("glossy", (1.0, 1.0, 1.0), 0.4, "f82", f0=(0.9, 0.6, 0.3), edge_tint=(1.0, 0.9, 0.8),
                multiscatter=True, weight=weight)


def plastic(metallic, ior=1.5):
    """Principled-like: metal over [specular over diffuse], weighed by metallic."""
    rest = Math("SUBTRACT", 1.0, metallic) if textures.is_texture(metallic) else 1.0 - metallic
    return Material("plastic", (
        metal(metallic),
        Lobe("glossy", (1.0, 1.0, 1.0), 0.3, "dielectric", ior=ior, covers=1, multiscatter=True,
             weight=rest),
        Lobe("diffuse", (0.2, 0.5, 0.8), weight=rest)))


def quad_scene(material, world=1.0):
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    cam = Camera(look_at((0.5, 0.5, 2.0), (0.5, 0.5, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=1.0,
                 resolution=(SIZE, SIZE), clip_start=0.01, clip_end=10.0)
    return Scene([Mesh(p, tris, uvs=p[tris][..., :2])], [Instance(0, materials=[0])], [material], [],
                 World((world, world, world)), cam)


def furnace(material, samples=16):
    """Direct light only under a uniform world: every sample is the BSDF's
    sample weight, so two materials agree per pixel wherever their lobes do."""
    settings = RenderSettings(samples=samples, samples_per_pass=samples, max_bounces=0, seed=7,
                              filter_type="BOX", filter_width=1.0)
    return render(quad_scene(material), settings).image[..., :3]


def cells(img):
    """(cell row, cell col, 2, 2, 3): the pixels of each cell away from its edges."""
    s = SIZE // N
    return img.reshape(N, s, N, s, 3)[:, 1:s - 1, :, 1:s - 1].transpose(0, 2, 1, 3, 4)


def test_checker_metallic_renders_each_cell_as_the_constant_material():
    textured = cells(furnace(plastic(CHECKER)))
    metal_only = cells(furnace(plastic(1.0)))
    dielectric = cells(furnace(plastic(0.0)))
    # Image row 0 is the top, as the render: cell (0, 0) holds checker value 1.
    is_metal = (np.add.outer(np.arange(N), np.arange(N)) % 2) == 0
    np.testing.assert_allclose(textured[is_metal], metal_only[is_metal], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(textured[~is_metal], dielectric[~is_metal], rtol=1e-9, atol=1e-12)
    # The two constant materials differ, so the test tells the cells apart.
    assert np.abs(metal_only.mean((2, 3)) - dielectric.mean((2, 3))).max() > 0.05


def test_textured_mix_factor_weighs_two_lobes_per_ray():
    """A Mix-like pair of lobes weighed by t and 1 - t from a texture with
    two grey levels renders as the constant mixes of those levels."""
    fac = ImageTexture(TextureImage(checker(0.75, 0.25)), interpolation="Closest")

    def mixed(t):
        rest = Math("SUBTRACT", 1.0, t) if textures.is_texture(t) else 1.0 - t
        return Material("mix", (metal(t), Lobe("diffuse", (0.8, 0.2, 0.1), weight=rest)))
    textured = cells(furnace(mixed(fac)))
    high, low = cells(furnace(mixed(0.75))), cells(furnace(mixed(0.25)))
    is_high = (np.add.outer(np.arange(N), np.arange(N)) % 2) == 0
    np.testing.assert_allclose(textured[is_high], high[is_high], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(textured[~is_high], low[~is_high], rtol=1e-9, atol=1e-12)
    assert np.abs(high.mean((2, 3)) - low.mean((2, 3))).max() > 0.02


def test_textured_ior_moves_f0_with_it_and_matches_constant_iors():
    ior = ImageTexture(TextureImage(checker(2.25, 1.375)), interpolation="Closest")
    textured = cells(furnace(plastic(0.0, ior)))
    high, low = cells(furnace(plastic(0.0, 2.25))), cells(furnace(plastic(0.0, 1.375)))
    is_high = (np.add.outer(np.arange(N), np.arange(N)) % 2) == 0
    np.testing.assert_allclose(textured[is_high], high[is_high], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(textured[~is_high], low[~is_high], rtol=1e-9, atol=1e-12)
    assert np.abs(high.mean((2, 3)) - low.mean((2, 3))).max() > 0.02


def test_gathered_weight_ior_and_f0_per_ray():
    from engine.bsdf import MaterialTable
    glass = Lobe("glass", (1.0, 1.0, 1.0), 0.2, ior=ImageTexture(TextureImage(checker(2.0, 1.5)),
                                                                  interpolation="Closest"),
                 weight=Math("MULTIPLY", CHECKER, 0.5))
    table = MaterialTable([Material("g", (glass,))])
    uv = np.array([[0.1, 0.9], [0.35, 0.9]])    # top-left cell (value a), the next one (b)
    lobes = table.gather(np.zeros(2, np.int64), uv)
    np.testing.assert_allclose(lobes.ior[:, 0], [2.0, 1.5])
    np.testing.assert_allclose(lobes.weight[:, 0], [0.5, 0.0])
    f0 = ((lobes.ior[:, 0] - 1) / (lobes.ior[:, 0] + 1)) ** 2
    np.testing.assert_allclose(lobes.f0[:, 0], np.repeat(f0[:, None], 3, axis=1), rtol=1e-12)


def test_negative_textured_weights_clamp_to_zero():
    from engine.bsdf import MaterialTable
    table = MaterialTable([Material("m", (Lobe("diffuse", weight=Math("SUBTRACT", 0.0, CHECKER)),))])
    lobes = table.gather(np.zeros(2, np.int64), np.array([[0.1, 0.9], [0.35, 0.9]]))
    np.testing.assert_array_equal(lobes.weight[:, 0], [0.0, 0.0])


def test_textured_weight_and_ior_are_validated():
    bad = Lobe("glass", ior=Math("HYPOT", CHECKER, 1.0))
    with pytest.raises(SceneError, match="lobe 0 ior"):
        validate_scene(quad_scene(Material("bad", (bad,))))
    with pytest.raises(SceneError, match="lobe 0 weight"):
        validate_scene(quad_scene(Material("bad", (Lobe("diffuse", weight=MixColor("BLUR", 0.5, 1.0, 0.0)),))))


# ----------------------------------------------------------------------------
# value ranges

RNG_IMAGE = TextureImage(np.random.default_rng(4).uniform(-0.5, 2.0, (6, 5, 4)).astype(np.float32))
EXPRESSIONS = [
    ImageTexture(RNG_IMAGE),
    ImageTexture(RNG_IMAGE, output="Alpha", extension="CLIP"),
    Math("SUBTRACT", 1.0, ImageTexture(RNG_IMAGE)),
    Math("MULTIPLY_ADD", ImageTexture(RNG_IMAGE), -0.7, 0.3, clamp=True),
    Math("POWER", Math("ADD", ImageTexture(RNG_IMAGE), 1.0), 1.7),
    Math("DIVIDE", 1.0, Math("MAXIMUM", ImageTexture(RNG_IMAGE), 0.2)),
    Math("ABSOLUTE", ImageTexture(RNG_IMAGE)),
    Math("LESS_THAN", ImageTexture(RNG_IMAGE), 0.5),
    MixColor("MIX", ImageTexture(RNG_IMAGE, output="Alpha"), (0.2, 0.3, 0.4), ImageTexture(RNG_IMAGE)),
    MixColor("OVERLAY", 0.6, ImageTexture(RNG_IMAGE), (0.9, 0.1, 0.5)),
    MixColor("DIFFERENCE", 1.5, ImageTexture(RNG_IMAGE), 0.3, clamp_factor=False),
    MixColor("LIGHTEN", 0.5, ImageTexture(RNG_IMAGE), 0.8, clamp_result=True),
]


@pytest.mark.parametrize("index", range(len(EXPRESSIONS)))
def test_value_range_bounds_every_value(index):
    expr = EXPRESSIONS[index]
    lo, hi = textures.value_range(expr)
    uv = np.random.default_rng(index).uniform(-1.0, 2.0, (4000, 2))
    fn, _ = textures.Compiler().compile(expr)
    values = fn(uv)
    assert lo <= values.min() + 1e-12 and values.max() <= hi + 1e-12, (lo, hi, values.min(), values.max())
    assert np.isfinite([lo, hi]).all()


def test_value_range_of_constants_and_unbounded_operations():
    assert textures.value_range(0.3) == (0.3, 0.3)
    assert textures.value_range((0.1, 0.5, 0.2)) == (0.1, 0.5)
    assert textures.value_range(ImageTexture(TextureImage(checker()))) == (0.0, 1.0)
    assert textures.value_range(Math("TANGENT", CHECKER)) == textures.UNBOUNDED
    # A divisor that may be zero leaves the range open.
    assert textures.value_range(Math("DIVIDE", 1.0, CHECKER)) == textures.UNBOUNDED
