"""Light Linking in the engine (issue 26): a light lights only the objects
of its receiver set, in light sampling and in BSDF rays that meet it."""
from dataclasses import replace

import numpy as np

from engine.render import render
from engine.scene import (AreaLight, Camera, Instance, LinkSet, Lobe, Material, RenderSettings, Scene, SunLight,
                          World)
from engine.testscenes import look_at, quad


def _two_quads(links):
    """Quads A (left) and B (right) under an area light and a sun, seen from above."""
    mesh = quad([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    shift = np.eye(4)
    shift[0, 3] = 1.0
    cam = Camera(look_at((1.0, 0.5, 3.0), (1.0, 0.5, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=2.0,
                 resolution=(16, 8), clip_start=0.01, clip_end=10.0)
    area = AreaLight(look_at((1.0, 0.5, 1.5), (1.0, 0.5, 0.0), (0, 1, 0)), (30.0, 30.0, 30.0), size_x=0.8, name="key")
    sun = SunLight((0.3, 0.2, -1.0), (2.0, 2.0, 2.0), angle=0.1, name="sun")
    return Scene([mesh], [Instance(0, materials=[0], name="A"), Instance(0, shift, [0], name="B")],
                 [Material("white", (Lobe("diffuse", (0.8, 0.8, 0.8)),))], [area, sun], World((0.0, 0.0, 0.0)),
                 cam, light_links=links)


SETTINGS = RenderSettings(samples=8, samples_per_pass=8, seed=3, max_bounces=0, filter_type="BOX", filter_width=1.0)


def test_receiver_sets_keep_each_lights_own_light():
    """Linking the area light to A and the sun to B: each quad gets exactly
    the light of its own light (the same samples as the unlinked renders of
    that light alone, so equal to rounding)."""
    only_a, only_b = LinkSet(frozenset({"A"})), LinkSet(frozenset({"B"}))
    linked = render(_two_quads({0: (only_a, None), 1: (only_b, None)}), SETTINGS).image[..., :3]
    scene = _two_quads({})
    area_alone = render(replace(scene, lights=[scene.lights[0]]), SETTINGS).image[..., :3]
    sun_alone = render(replace(scene, lights=[scene.lights[1]]), SETTINGS).image[..., :3]
    a, b = slice(1, 7), slice(9, 15)
    assert area_alone[:, a].min() > 0 and sun_alone[:, b].min() > 0
    # Same emitter order and selection, so the light tree picks the same
    # lights; the unlinked light's samples bring nothing.
    full = render(scene, SETTINGS).image[..., :3]
    assert np.all(linked[:, a] <= full[:, a] + 1e-6) and np.all(linked[:, b] <= full[:, b] + 1e-6)
    assert linked[:, a].mean() > 0.5 * area_alone[:, a].mean()
    assert linked[:, b].mean() > 0.5 * sun_alone[:, b].mean()
    excluded = render(_two_quads({0: (LinkSet(exclude=frozenset({"A", "B"})), None),
                                  1: (LinkSet(exclude=frozenset({"A", "B"})), None)}), SETTINGS).image
    assert np.all(excluded[..., :3] == 0.0), "lights linked to nothing must bring nothing"


def test_linking_is_finite_and_an_empty_include_links_everything():
    everything = LinkSet()
    image = render(_two_quads({0: (everything, everything)}), SETTINGS).image
    plain = render(_two_quads({}), SETTINGS).image
    assert np.isfinite(image).all()
    np.testing.assert_allclose(image, plain, rtol=1e-6, atol=1e-7)
