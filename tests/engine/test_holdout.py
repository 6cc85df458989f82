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
