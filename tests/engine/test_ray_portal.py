"""The Ray Portal lobe (engine/lobes/ray_portal.py, engine/integrator/portal.py)
in exact cases: an orthographic camera looks down at a portal plate over a
black floor; what it sees through the portal is an emitter, so every pixel
is the portal's colour times the emitter's radiance (no noise: camera rays
and emission only).  Cycles parity: tests/addon/test_ray_portal_parity.py."""
import numpy as np
import pytest

from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
from engine.testscenes import look_at, quad

SIZE, SCALE = 8, 2.0
LE = np.array([2.0, 1.0, 0.5])
COLOR = (0.9, 0.6, 0.8)
FAR = (20.0, 0.0, 0.0)   # the emitter the portal looks at


def portal_scene(**portal):
    """A black floor at z = 0, an emitter under the plate (straight on) and
    one far away at FAR (through a teleport), the portal plate at z = 1."""
    meshes = [quad([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]]),
              quad([[-3, -3, 0.5], [3, -3, 0.5], [3, 3, 0.5], [-3, 3, 0.5]]),
              quad([[FAR[0] - 3, -3, 0.5], [FAR[0] + 3, -3, 0.5], [FAR[0] + 3, 3, 0.5], [FAR[0] - 3, 3, 0.5]]),
              quad([[-2, -2, 1.0], [2, -2, 1.0], [2, 2, 1.0], [-2, 2, 1.0]])]
    black = Material("black", (Lobe("diffuse", (0.0, 0.0, 0.0)),))
    near = Material("near", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=tuple(LE))
    far = Material("far", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=tuple(2.0 * LE))
    gate = Material("portal", (Lobe("ray_portal", COLOR, **portal),))
    instances = [Instance(k, materials=[k], name=name) for k, name in enumerate(("floor", "near", "far", "portal"))]
    cam = Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=SCALE,
                 resolution=(SIZE, SIZE), clip_start=0.01, clip_end=100.0)
    return Scene(meshes, instances, [black, near, far, gate], [], World((0.0, 0.0, 0.0)), cam)


def image_of(scene, **kw):
    settings = dict(samples=4, samples_per_pass=4, seed=1, max_bounces=2, filter_type="BOX", filter_width=1e-3)
    settings.update(kw)
    image = render(scene, RenderSettings(**settings)).image[..., :3]
    assert np.isfinite(image).all()
    return image


def test_default_portal_continues_the_ray_straight():
    """Position and Direction not given: the ray goes on from the hit along
    itself, weighted by the colour (the near emitter, x colour)."""
    image = image_of(portal_scene())
    np.testing.assert_allclose(image, np.broadcast_to(np.multiply(COLOR, LE), image.shape), rtol=1e-5)


def test_portal_moves_the_ray_to_position_and_direction():
    """A given Position and Direction teleport every camera ray above the
    far emitter, looking down (unnormalized Direction: normalized)."""
    image = image_of(portal_scene(portal_position=(FAR[0], 0.0, 3.0), portal_direction=(0.0, 0.0, -4.0)))
    np.testing.assert_allclose(image, np.broadcast_to(np.multiply(COLOR, 2.0 * LE), image.shape), rtol=1e-5)


def test_portal_pointing_away_sees_the_black_world():
    image = image_of(portal_scene(portal_position=(FAR[0], 0.0, 3.0), portal_direction=(0.0, 0.0, 1.0)))
    assert np.all(image == 0.0)


@pytest.mark.parametrize("position,direction", [
    ((np.nan, 0.0, 0.0), (0.0, 0.0, 0.0)),        # NaN Position: the hit; zero Direction: the incoming ray
    ((np.inf, 1.0, 1.0), (np.nan, 0.0, -1.0)),     # infinite Position, NaN Direction: the same
    ((1e31, 0.0, 0.0), (0.0, -np.inf, 0.0)),
])
def test_hostile_portal_vectors_are_the_defaults(position, direction):
    """Non-finite (or out of reach) Position and Direction render as the
    defaults, finite pixels, no error."""
    image = image_of(portal_scene(portal_position=position, portal_direction=direction))
    np.testing.assert_allclose(image, np.broadcast_to(np.multiply(COLOR, LE), image.shape), rtol=1e-5)


@pytest.mark.parametrize("limit", [1, 4])
def test_a_portal_onto_itself_ends_at_transparent_max_bounces(limit):
    """A portal pass is a transparent bounce (Cycles' path_state_next): a
    portal that sends rays back above itself is met again and again until
    Transparent Max Bounces, where the path ends (black), never looping."""
    scene = portal_scene(portal_position=(0.0, 0.0, 1.5), portal_direction=(0.0, 0.0, -1.0))
    assert np.all(image_of(scene, transparent_max_bounces=limit) == 0.0)


def test_shadow_rays_stop_at_portals():
    """Cycles disables transparent shadows for ray portals: a point light
    above a portal plate does not light the floor under it by NEE (the
    light-sampling strategy, where BSDF rays do not count)."""
    from engine.scene import PointLight
    scene = portal_scene()
    white = Material("white", (Lobe("diffuse", (0.8, 0.8, 0.8)),))
    scene = Scene(scene.meshes, scene.instances, [white, white, white, scene.materials[3]],
                  [PointLight((0, 0, 3.0), (50.0, 50.0, 50.0), radius=0.0)], scene.world, scene.camera)
    image = image_of(scene, strategy="light")
    assert np.all(image == 0.0)
