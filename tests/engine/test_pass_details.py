"""Pass details found on an independent check against Cycles (issue 26, item 3).

* UV: Cycles' UV pass is (u, v, 1) on meshes with a UV map and 0 on meshes
  without one (``primitive_uv``: ATTR_STD_NOT_FOUND gives 0 in all three
  channels); Ember wrote a third channel of 1 everywhere.
"""
import numpy as np

from engine.render import render
from engine.scene import Camera, Instance, Material, Mesh, RenderSettings, Scene, World
from engine.testscenes import look_at


def _two_quads():
    """Two unit quads side by side, seen from +Z: the left one with UVs
    (u, v) = (x, y), the right one without a UV map."""
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    with_uv = Mesh(p, tris, uvs=p[tris][..., :2], name="with uv")
    without = Mesh(p, tris, name="without uv")
    cam = Camera(look_at((1.0, 0.5, 2.0), (1.0, 0.5, 0.0), (0, 1, 0)), kind="ORTHO", ortho_scale=2.0,
                 resolution=(16, 8), clip_start=0.01, clip_end=10.0)
    shift = np.eye(4)
    shift[0, 3] = 1.0
    return Scene([with_uv, without], [Instance(0, materials=[0]), Instance(1, matrix=shift, materials=[0])],
                 [Material()], [], World((1.0, 1.0, 1.0)), cam)


def test_uv_pass_is_zero_on_meshes_without_a_uv_map():
    result = render(_two_quads(), RenderSettings(samples=4, samples_per_pass=4, seed=1, max_bounces=0,
                                                 filter_type="BOX", filter_width=1.0, passes=("UV",)))
    uv = result.passes["UV"]
    left, right = uv[:, 1:7], uv[:, 9:15]        # pixels wholly on one quad
    assert np.all(right == 0.0), f"UV on the mesh without a UV map: max {np.abs(right).max(axis=(0, 1))}"
    np.testing.assert_allclose(left[..., 2], 1.0, rtol=1e-6)
    assert left[..., 0].min() > 0.0 and left[..., 0].max() < 1.0
