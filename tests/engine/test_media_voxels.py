"""Voxel grids in media (engine/media/voxels.py: a fluid domain's density,
flame, temperature and colour grids read by Attribute nodes inside its
volume).

Truths: exact lookups on hand-made grids (voxel centres, the trilinear
blend between them, the edge voxels held to the box's faces, 0 outside);
the majorant grid bounding every lookup in its cells; Beer-Lambert through
a slab whose density grid is linear in z (the interpolant's integral is
exactly 1/2 of the thickness at any resolution); hostile grids (NaN, inf,
negative values, a zero-sized axis, a wrong shape) giving finite pixels and
a warning or error naming the object.
"""
import numpy as np
import pytest

from analytic import ortho_camera
from ember_stats import family_level
from engine.media import field as fieldmod
from engine.media.voxels import Voxels, trilinear
from engine.render import prepare, render
from engine.scene import (Camera, Instance, Lobe, Material, MixColor, NodeCall, NodeOutput,
                          RenderSettings, Scene, SceneError, Volume, World)
from engine.testscenes import box, look_at
from test_media_field import assert_image_mean

PASS = (Lobe("transparent", (1.0, 1.0, 1.0)),)


def attribute(name, output="Fac"):
    return NodeOutput(NodeCall("ShaderNodeAttribute", {}, {"attribute_name": name, "attribute_type": "GEOMETRY"}),
                      output)


def by_density(rgb):
    return MixColor("MULTIPLY", 1.0, tuple(rgb), attribute("density"), clamp_factor=False)


def linear_z(res):
    """A (Z, Y, X) grid whose voxel centres hold their Generated z."""
    z = (np.arange(res[0]) + 0.5) / res[0]
    return np.broadcast_to(z[:, None, None], res).astype(np.float32)


def slab(volume, voxels, size=(12, 12), world=(1.0, 1.0, 1.0)):
    cam = ortho_camera((0, 0, 3), (0, 0, 0), size, 1.0)
    inst = Instance(0, np.eye(4), [0], "domain", voxels=voxels)
    return Scene([box((3.0, 3.0, 0.5))], [inst], [Material("smoke", PASS, volume=volume)], [], World(world), cam)


def test_lookups_are_cycles_trilinear_with_clip():
    rng = np.random.default_rng(3)
    grid = rng.uniform(0, 1, (3, 4, 5)).astype(np.float32)     # (Z, Y, X)
    res = np.array([5, 4, 3])
    # Voxel centres read their voxel.
    idx = np.stack(np.meshgrid(range(5), range(4), range(3), indexing="ij"), -1).reshape(-1, 3)
    got = trilinear(grid[..., None], (idx + 0.5) / res)
    np.testing.assert_allclose(got[:, 0], grid[idx[:, 2], idx[:, 1], idx[:, 0]], rtol=1e-6)
    np.testing.assert_array_equal(got[:, 3], 1.0)
    # Midway between two centres along x: their mean; at the box's faces the edge voxel.
    u = np.array([[2.0 / 5, 1.5 / 4, 0.5 / 3], [0.0, 0.5 / 4, 0.5 / 3], [1.0, 3.5 / 4, 2.5 / 3]])
    got = trilinear(grid[..., None], u)[:, 0]
    np.testing.assert_allclose(got, [0.5 * (grid[0, 1, 1] + grid[0, 1, 2]), grid[0, 0, 0], grid[2, 3, 4]],
                               rtol=1e-6)
    # Outside the unit box: 0 (Cycles' CLIP); a colour grid reads its RGBA.
    assert (trilinear(grid[..., None], np.array([[-0.01, 0.5, 0.5], [0.5, 1.01, 0.5]]))[:, :3] == 0).all()
    rgba = np.stack([grid, 2 * grid, 3 * grid, grid], -1)
    got = trilinear(rgba, np.array([[0.5 / 5, 0.5 / 4, 0.5 / 3]]))[0]
    np.testing.assert_allclose(got, [grid[0, 0, 0] * k for k in (1, 2, 3, 1)], rtol=1e-6)


def test_field_reads_grids_through_generated_space_and_bounds_them():
    """A Field of a 2 m cube whose absorption is its density grid: points
    in world space read the grid through Generated coordinates, and each
    majorant cell bounds the lookups at random points inside it."""
    rng = np.random.default_rng(5)
    grid = (rng.uniform(0, 1, (20, 24, 28)) ** 8 * 50).astype(np.float32)
    scene = Scene([box((2.0, 2.0, 2.0))], [Instance(0, np.eye(4), [0], "domain", voxels={"density": grid})],
                  [Material("smoke", PASS, volume=Volume(absorption=by_density((1, 1, 1))))], [], World((1, 1, 1)),
                  Camera(look_at((0, -6, 0), (0, 0, 0)), resolution=(4, 4)))
    field = prepare(scene, RenderSettings(samples=1)).media.fields[0]
    p = rng.uniform(-1, 1, (20000, 3))
    sa, _, _ = field.evaluate(p, np.tile([0.0, 0.0, 1.0], (len(p), 1)))
    np.testing.assert_allclose(sa[:, 0], trilinear(grid[..., None], (p + 1) / 2)[:, 0], rtol=1e-5, atol=1e-6)
    cell = np.clip(np.floor((p - field.lo) / field.cell), 0, fieldmod.GRID - 1).astype(int)
    bound = field.grid[cell[:, 0], cell[:, 1], cell[:, 2]]
    assert (sa[:, 0] <= bound * (1 + 1e-6)).all(), (sa[:, 0] - bound).max()


def test_linear_density_grid_slab_is_beer_lambert():
    """Camera rays down through a 0.5 m slab whose density grid is linear
    in z (12 voxels): the trilinear interpolant (edge voxels held) has mean
    exactly 1/2 over z, so the optical depth is k x 0.25 and T = exp(-0.25 k)
    per channel; an emitting slab renders 0.25 k."""
    k = np.array([0.6, 2.0, 5.0])
    level = family_level(f"{__name__}.slab", 6)
    grids = {"density": linear_z((12, 5, 5))}
    cases = (("absorbing", Volume(absorption=by_density(k)), (1, 1, 1), np.exp(-0.25 * k)),
             ("emitting", Volume(emission=by_density(k)), (0, 0, 0), 0.25 * k))
    for what, volume, world, expected in cases:
        assert_image_mean(slab(volume, grids, size=(16, 16), world=world), expected, level, f"{what} voxel slab")


@pytest.mark.parametrize("bad, word", [(np.nan, "NaN"), (np.inf, "infinite")])
def test_hostile_grid_values_are_named_and_finite(bad, word):
    grid = linear_z((6, 6, 6)).copy()
    grid[2:4, 2:4, 2:4] = bad
    grid[0] = -3.0            # negative densities: Cycles' fmaxf(density, 0) (the Field names them)
    volume = Volume(scattering=by_density((1, 1, 1)), emission=by_density((1, 0.2, 0)))
    r = render(slab(volume, {"density": grid}, size=(6, 6)),
               RenderSettings(samples=4, samples_per_pass=4, volume_bounces=2, max_bounces=4))
    assert np.isfinite(r.image).all()
    assert any("'domain'" in w and word in w for w in r.warnings), r.warnings
    assert any("'smoke'" in w and "negative" in w for w in r.warnings), r.warnings


def test_empty_and_misshapen_grids():
    """A zero-sized axis reads 0 everywhere (the slab is clear); a grid of
    the wrong shape is a SceneError naming the object."""
    volume = Volume(absorption=by_density((5, 5, 5)))
    r = render(slab(volume, {"density": np.zeros((0, 4, 4), np.float32)}, size=(4, 4)),
               RenderSettings(samples=2, samples_per_pass=2))
    np.testing.assert_allclose(r.image[..., :3], 1.0, rtol=1e-6)
    with pytest.raises(SceneError, match="'domain'"):
        render(slab(volume, {"density": np.zeros((4, 4), np.float32)}, size=(4, 4)), RenderSettings(samples=1))
    assert Voxels({"density": np.ones((2, 2, 2))}, "d").warning() is None


def test_placed_grids_read_at_object_coordinates_and_are_bounded():
    """A Volume object's grid (addon/export/volume_object.py) is placed by
    its object-to-unit matrix: a rotated, scaled placement reads the voxel
    whose centre a point maps to, and the Field's majorant cells (the grid
    max-filtered over its placed reach) bound lookups at random points."""
    rng = np.random.default_rng(11)
    grid = (rng.uniform(0, 1, (10, 12, 14)) ** 6 * 40).astype(np.float32)   # (Z, Y, X)
    res = np.array([14, 12, 10], np.float64)
    c, s = np.cos(0.6), np.sin(0.6)
    index_to_object = np.array([[0.1 * c, -0.1 * s, 0, -0.3], [0.1 * s, 0.1 * c, 0, -0.2],
                                [0, 0, 0.15, -0.7], [0, 0, 0, 1]])
    unit_from_index = np.diag([1 / res[0], 1 / res[1], 1 / res[2], 1.0])
    unit_from_index[:3, 3] = 0.5 / res          # element a at index position a
    placement = unit_from_index @ np.linalg.inv(index_to_object)
    voxels = Voxels({"density": grid}, "vdb", {"density": placement})
    idx = np.array([[3, 4, 5], [0, 0, 0], [13, 11, 9]], np.float64)
    q = np.c_[idx, np.ones(3)] @ index_to_object.T

    class Ctx:
        object_coords = q[:, :3]
    got = voxels.read("density", Ctx())[:, 0]
    np.testing.assert_allclose(got, [grid[5, 4, 3], grid[0, 0, 0], grid[9, 11, 13]], rtol=1e-6)
    corners = np.array([[x, y, z, 1.0] for x in (0, 1) for y in (0, 1) for z in (0, 1)]) @ np.linalg.inv(placement).T
    lo, hi = corners[:, :3].min(axis=0), corners[:, :3].max(axis=0)
    mesh = box(tuple(hi - lo))
    mesh.positions = np.asarray(mesh.positions) + 0.5 * (lo + hi)
    inst = Instance(0, np.eye(4), [0], "vdb", voxels={"density": grid}, voxel_placements={"density": placement})
    scene = Scene([mesh], [inst], [Material("smoke", PASS, volume=Volume(absorption=by_density((1, 1, 1))))], [],
                  World((1, 1, 1)), Camera(look_at((0, -6, 0), (0, 0, 0)), resolution=(4, 4)))
    field = prepare(scene, RenderSettings(samples=1)).media.fields[0]
    p = rng.uniform(lo, hi, (20000, 3))
    sa, _, _ = field.evaluate(p, np.tile([0.0, 0.0, 1.0], (len(p), 1)))
    u = p @ placement[:3, :3].T + placement[:3, 3]
    np.testing.assert_allclose(sa[:, 0], trilinear(grid[..., None], u)[:, 0], rtol=1e-5, atol=1e-6)
    cell = np.clip(np.floor((p - field.lo) / field.cell), 0, fieldmod.GRID - 1).astype(int)
    bound = field.grid[cell[:, 0], cell[:, 1], cell[:, 2]]
    assert (sa[:, 0] <= bound * (1 + 1e-6)).all(), (sa[:, 0] - bound).max()
    assert sa[:, 0].max() > 1.0    # the grid is seen, not empty
