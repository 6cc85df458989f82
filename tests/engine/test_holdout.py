"""Holdouts in the engine (issue 26): camera rays uncover the film's alpha
by the holdout weight, with or without a transparent film; the rest of the
light is unchanged (Cycles' integrate_surface_holdout)."""
import numpy as np
import pytest

from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, SceneError, World
from engine.testscenes import look_at, quad
from engine.validate import validate_scene


def _quad_scene(material, holdout_object=False):
    mesh = quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    cam = Camera(look_at((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=1.0,
                 resolution=(8, 8), clip_start=0.01, clip_end=10.0)
    return Scene([mesh], [Instance(0, materials=[0], holdout=holdout_object)], [material], [],
                 World((1.0, 1.0, 1.0)), cam)


SETTINGS = dict(samples=4, samples_per_pass=4, seed=1, max_bounces=1, filter_type="BOX", filter_width=1.0)


@pytest.mark.parametrize("transparent", (False, True))
def test_holdout_weight_uncovers_the_film(transparent):
    """Under a unit world a white diffuse renders 1: a holdout of weight h
    (its diffuse weighed 1 - h by the Mix Shader) renders 1 - h in RGB and alpha."""
    for h in (1.0, 0.25):
        mat = Material("half", (Lobe("diffuse", (1.0, 1.0, 1.0), weight=1.0 - h),), holdout=h)
        image = render(_quad_scene(mat), RenderSettings(transparent=transparent, **SETTINGS)).image
        np.testing.assert_allclose(image[..., 3], 1.0 - h, atol=1e-6)
        np.testing.assert_allclose(image[..., :3], 1.0 - h, atol=1e-6)


def test_holdout_object_is_empty_to_the_camera():
    image = render(_quad_scene(Material("white", (Lobe("diffuse", (1.0, 1.0, 1.0)),)), holdout_object=True),
                   RenderSettings(**SETTINGS)).image
    assert np.all(image == 0.0)


def test_holdout_weight_out_of_range_is_named():
    for bad in (float("nan"), 1.5, -0.1):
        with pytest.raises(SceneError, match="'bad'.*holdout"):
            validate_scene(_quad_scene(Material("bad", holdout=bad)))


def _catcher_scene(with_blocker):
    """A catcher quad under a sun, seen from above, with or without a small
    ordinary quad floating over its middle."""
    from engine.scene import SunLight
    floor = quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    small = quad([[-0.3, -0.3, 0.5], [0.3, -0.3, 0.5], [0.3, 0.3, 0.5], [-0.3, 0.3, 0.5]])
    cam = Camera(look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=2.0,
                 resolution=(16, 16), clip_start=0.01, clip_end=10.0)
    instances = [Instance(0, materials=[0], name="catcher", shadow_catcher=True)]
    if with_blocker:
        instances.append(Instance(1, materials=[0], name="blocker"))
    return Scene([floor, small], instances, [Material("grey", (Lobe("diffuse", (0.5, 0.5, 0.5)),))],
                 [SunLight((0.6, 0.0, -1.0), (3.0, 3.0, 3.0))], World((0.2, 0.3, 0.4)), cam)


def test_shadow_catcher_shows_only_shadows():
    """Alone, the catcher is invisible: alpha 0 on a transparent film, the
    world on an opaque one.  With the blocker, its sun shadow (shifted 0.3
    along +x, partly beside it) is in the alpha, the open floor stays clear."""
    clear = render(_catcher_scene(False), RenderSettings(transparent=True, **SETTINGS)).image
    np.testing.assert_allclose(clear[..., 3], 0.0, atol=1e-6)
    opaque = render(_catcher_scene(False), RenderSettings(**SETTINGS)).image
    np.testing.assert_allclose(opaque[..., :3], np.broadcast_to((0.2, 0.3, 0.4), opaque[..., :3].shape), rtol=1e-5)
    shadowed = render(_catcher_scene(True), RenderSettings(transparent=True, **SETTINGS)).image
    assert np.isfinite(shadowed).all()
    middle, edge, shadow = shadowed[7:9, 7:9], shadowed[0:2, 0:2], shadowed[6:10, 11:12]
    assert np.all(middle[..., 3] == 1.0) and middle[..., :3].min() > 0, "the blocker is an ordinary object"
    np.testing.assert_allclose(edge[..., 3], 0.0, atol=1e-3)
    assert shadow[..., 3].min() > 0.3, f"no shadow in the alpha: {shadow[..., 3]}"


def test_emissive_shadow_catcher_is_finite():
    """Hostile input: a catcher that is also a light (an emissive material)."""
    scene = _catcher_scene(True)
    scene.materials = [Material("glowing", (Lobe("diffuse", (0.5, 0.5, 0.5)),), emission=(4.0, 4.0, 4.0))]
    for transparent in (False, True):
        image = render(scene, RenderSettings(transparent=transparent, **SETTINGS)).image
        assert np.isfinite(image).all() and image[..., 3].min() >= 0.0


def test_catcher_with_transparent_surfaces_is_named():
    """A limit, said: with transparent surfaces in the scene the catcher
    paths' shadow rays see every object."""
    scene = _catcher_scene(True)
    scene.materials = list(scene.materials) + [Material("veil", (Lobe("transparent", (0.5, 0.5, 0.5)),))]
    scene.instances[1].materials = [1]
    result = render(scene, RenderSettings(**SETTINGS))
    assert np.isfinite(result.image).all()
    assert any("shadow catchers with transparent surfaces" in w for w in result.warnings), result.warnings
