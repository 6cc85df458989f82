"""A textured world volume (engine/media/field.py WorldField): the world's
medium evaluated per point at Object = Generated = P (Cycles' background
volume, object none), tracked against a majorant grid over the scene's
bounds, opaque beyond them where density is left on their faces (Cycles'
infinite rays through world fog are extinguished).

Truth in closed form: an emissive card 4 m below an orthographic camera in
a world whose absorption grows linearly with height, k max(z + 1, 0): the optical
depth to the card is k x 3.99^2 / 2 per channel; rays past the card (the
white background) are extinguished, as in Cycles.
"""
import numpy as np

from analytic import ortho_camera
from ember_stats import detectable, family_level, z_threshold
from engine.render import render
from engine.scene import (Instance, Lobe, Material, Math, MixColor, NodeCall, NodeOutput, RenderSettings, Scene,
                          Volume, World)
from engine.testscenes import quad

K = np.array([0.05, 0.1, 0.2])


def height():
    """P.z through Generated (the world's Generated is the point)."""
    coords = NodeCall("ShaderNodeTexCoord", {}, {"object_inverse": None})
    return NodeOutput(NodeCall("ShaderNodeSeparateXYZ", {"Vector": NodeOutput(coords, "Generated")}), "Z")


def world_scene(absorption, half=1.0):
    card = quad([[-half, -2, -1], [half, -2, -1], [half, 2, -1], [-half, 2, -1]])
    cam = ortho_camera((0, 0, 3), (0, 0, 0), (12, 12), 3.0)
    return Scene([card], [Instance(0, np.eye(4), [0], "card")],
                 [Material("card", (Lobe("diffuse", (0, 0, 0)),), emission=(1, 1, 1))],
                 [], World((1, 1, 1), volume=Volume(absorption=absorption)), cam)


def test_linear_world_absorption_is_beer_lambert_and_opaque_beyond():
    # max(z + 1, 0): 0 below the card, where the box reaches too.
    rising = MixColor("MULTIPLY", 1.0, tuple(K), Math("MAXIMUM", Math("ADD", height(), 1.0), 0.0),
                      clamp_factor=False)
    r = render(world_scene(rising), RenderSettings(samples=1024, samples_per_pass=256))
    assert np.isfinite(r.image).all() and not r.warnings, r.warnings
    img = r.image[..., :3].astype(np.float64)
    var = r.variance[..., :3].astype(np.float64)
    # Columns 3-8 see the card (x in [-1, 1] of a 3 m frame), 0 and 11 only the background.
    inner = (slice(None), slice(3, 9))
    n = img[inner].shape[0] * img[inner].shape[1]
    mean = img[inner].mean(axis=(0, 1))
    se = np.sqrt(var[inner].sum(axis=(0, 1))) / n
    expected = np.exp(-K * 3.99 ** 2 / 2.0)
    level = family_level(__name__ + ".world_slab", 3)
    z = (mean - expected) / se
    print(f"world field: {mean} against {expected}, |z| {np.abs(z).max():.2f} (limit {z_threshold(level):.2f}), "
          f"detects {detectable(se / expected, level).max():.2%}")
    assert np.abs(z).max() < z_threshold(level)
    assert detectable(se / expected, level).max() < 0.025
    # Past the card the rays are infinite: extinguished (the background is 1).
    np.testing.assert_array_equal(img[:, [0, 11]], 0.0)   # the pixel filter reaches the card from 1, 10


def test_world_density_gone_at_the_bounds_leaves_the_background():
    """A world medium that is 0 on every face of its box (here: a ball of
    radius 0.5 at the origin) is empty beyond it: the background shows past
    the card unattenuated (1), the card beside the ball through clear air
    (1), darker through the ball."""
    coords = NodeCall("ShaderNodeTexCoord", {}, {"object_inverse": None})
    radius = NodeOutput(NodeCall("ShaderNodeVectorMath", {"Vector": NodeOutput(coords, "Generated")},
                                 {"operation": "LENGTH"}), "Value")
    ball = MixColor("MULTIPLY", 1.0, (2.0, 2.0, 2.0), Math("LESS_THAN", radius, 0.5), clamp_factor=False)
    r = render(world_scene(ball), RenderSettings(samples=4, samples_per_pass=4))
    img = r.image[..., :3].astype(np.float64)
    clear = [0, 1, 2, 9, 10, 11]     # background, and the card at |x| in (0.75, 1)
    np.testing.assert_allclose(img[:, clear], 1.0, rtol=1e-6)
    assert img[5:7, 5:7].max() < 0.5    # through the ball's middle: exp(-2 x ~1)


def test_world_field_bounds_hold_points_curves_camera_and_lights():
    """The world field's box (beyond it the medium is opaque) holds every
    point cloud, curve, light position and the camera, padded."""
    from engine.media.field import scene_bounds
    from engine.scene import PointCloud, PointLight
    m = np.eye(4)
    m[:3, 3] = (30.0, 0.0, 0.0)
    cloud = PointCloud(positions=np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]), radii=np.array([0.5, 0.2]),
                       matrix=m, materials=[0])
    scene = world_scene((0.1, 0.1, 0.1))
    scene.points = [cloud]
    scene.lights = [PointLight(position=(0.0, -20.0, 1.0), power=(1.0, 1.0, 1.0))]
    lo, hi = scene_bounds(scene, None)
    assert np.all(lo < [-1.5, -20.0, -1.0]) and np.all(hi > [31.5, 2.0, 6.5]), (lo, hi)
