"""Point clouds in the engine (engine/points.py): spheres traced by Embree's
SPHERE_POINT geometry through the C API.

* Every ray finds the sphere a brute-force float64 ray-sphere test finds
  first, at its distance; the hit point lies on that sphere (float64
  re-intersection) with the outward normal facing the ray.
* The radius scales with the cloud's matrix (cbrt |det|, as Cycles).
* Per-point colour attributes reach shader nodes.
* Hostile input: NaN or negative radii are named errors; an emissive cloud
  (found by BSDF rays only, never light-sampled) and radius-0 points render
  finite pixels.
"""
import numpy as np
import pytest

from engine import embree_c
from engine.geometry import flatten
from engine.points import expand, sphere_hits, spheres_of
from engine.render import prepare, render
from engine.scene import (Camera, Instance, Lobe, Material, NodeCall, NodeOutput, PointCloud, PointLight,
                          RenderSettings, Scene, SceneError)
from engine.testscenes import look_at, quad, translate_rotate_z

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")


def _cloud(n=300, seed=0, **kw):
    rng = np.random.default_rng(seed)
    return PointCloud(rng.uniform(-1, 1, (n, 3)), rng.uniform(0.02, 0.15, n), materials=[0], **kw)


def _scene(clouds, lights=(), camera=None):
    floor = quad([[-3, -3, -1.2], [3, -3, -1.2], [3, 3, -1.2], [-3, 3, -1.2]])
    mats = [Material("points", lobes=(Lobe("diffuse", color=(0.7, 0.5, 0.3)),)), Material("floor")]
    return Scene(meshes=[floor], instances=[Instance(0, materials=[1])], points=clouds, materials=mats,
                 lights=list(lights) or [PointLight((1, -1, 3), (300, 300, 300))],
                 camera=camera or Camera(matrix=look_at((0, -4, 2), (0, 0, 0)), resolution=(24, 16)))


def test_rays_find_the_first_sphere():
    matrix = translate_rotate_z((0.3, -0.2, 0.1), 25.0, scale=1.3)
    cloud = _cloud(matrix=matrix)
    ctx = prepare(_scene([cloud]), RenderSettings(samples=1))
    spheres = ctx.spheres
    assert len(spheres) == 300
    assert np.allclose(spheres.radii, cloud.radii * 1.3)     # radius x cbrt|det| of a uniform scale
    rng = np.random.default_rng(4)
    n = 8000
    o = rng.uniform(-1.5, 1.5, (n, 3)) + [0.0, 0.0, 4.0]
    d = rng.normal(0, 0.3, (n, 3)) + [0.0, 0.0, -1.0]
    d /= np.linalg.norm(d, axis=1)[:, None]
    t, prim, bu, bv = ctx.accel.intersect(o, d, np.full(n, np.inf))
    # brute force, float64: the first sphere along each ray
    oc = o[:, None, :] - spheres.centres[None]
    b = np.einsum("nkj,nj->nk", oc, d)
    q = np.einsum("nkj,nkj->nk", oc, oc) - spheres.radii[None] ** 2
    disc = b * b - q
    root = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    root = np.where(root > 0, root, np.inf)
    first = np.argmin(root, axis=1)
    t_ref = root[np.arange(n), first]
    on_sphere = np.isfinite(t_ref)
    hit_sphere = (prim >= 0) & spheres.is_point[np.maximum(prim, 0)]
    # rays that graze a sphere's edge within float32 may differ; all others agree
    edge = np.abs(disc[np.arange(n), first]) < 1e-5
    assert np.array_equal(hit_sphere[~edge], on_sphere[~edge])
    both = hit_sphere & on_sphere & ~edge
    assert both.sum() > 800
    assert np.array_equal(spheres.rows[first[both]], prim[both])
    assert np.allclose(t[both], t_ref[both], rtol=1e-5, atol=1e-5)
    p, ng, back = sphere_hits(spheres, o[both], d[both], t[both], prim[both])
    c, r = spheres.centres[spheres.slot[prim[both]]], spheres.radii[spheres.slot[prim[both]]]
    assert np.allclose(np.linalg.norm(p - c, axis=1), r, rtol=1e-12, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", ng, d[both]) <= 0) and not back.any()


def test_colour_attributes_reach_the_nodes():
    cloud = _cloud(n=50)
    colours = np.random.default_rng(1).uniform(0, 1, (50, 4))
    cloud.attributes = {"col": colours}
    scene = _scene([cloud])
    expanded, owners, radii = expand(scene)
    tris = flatten(expanded)
    spheres = spheres_of(tris, expanded, owners, radii)
    corners = tris.shading.corners(("attr", "col"))[spheres.rows]
    assert np.allclose(corners, colours[tris.shading.local[spheres.rows]][:, None, :])


def test_points_render_and_an_attribute_colours_them():
    cloud = _cloud(n=400)
    cloud.attributes = {"col": np.tile([0.9, 0.1, 0.1, 1.0], (400, 1))}
    scene = _scene([cloud])
    red = NodeOutput(NodeCall("ShaderNodeAttribute", {}, {"attribute_name": "col", "attribute_type": "GEOMETRY"}),
                     "Color")
    scene.materials[0] = Material("points", lobes=(Lobe("diffuse", color=red),))
    image = render(scene, RenderSettings(samples=8, samples_per_pass=8, max_bounces=1)).image
    assert np.isfinite(image).all()
    plain = _scene([_cloud(n=400)])
    plain.materials[0] = Material("points", lobes=(Lobe("diffuse", color=(0.9, 0.9, 0.9)),))
    grey = render(plain, RenderSettings(samples=8, samples_per_pass=8, max_bounces=1)).image
    assert image[..., 1].sum() < 0.8 * grey[..., 1].sum()    # red points reflect little green


@pytest.mark.parametrize("radii, message", [(np.nan, "radii: 1 values are NaN"), (-0.1, "negative radius")])
def test_bad_radii_are_named(radii, message):
    cloud = _cloud(n=20)
    cloud.radii = cloud.radii.copy()
    cloud.radii[3] = radii
    with pytest.raises(SceneError, match=r"point cloud 0 \('points'\).*" + message):
        render(_scene([cloud]), RenderSettings(samples=1))


def test_emissive_and_zero_radius_points_render_finite():
    cloud = _cloud(n=200)
    cloud.radii = cloud.radii.copy()
    cloud.radii[:50] = 0.0
    scene = _scene([cloud])
    scene.materials[0] = Material("glow", lobes=(Lobe("diffuse", color=(0.5, 0.5, 0.5)),), emission=(4.0, 3.0, 2.0))
    ctx = prepare(scene, RenderSettings(samples=1))
    assert ctx.lights.emitter_of_triangle(np.array([0]))[0] == -1   # no light samples the points
    result = render(scene, RenderSettings(samples=8, samples_per_pass=8, max_bounces=2))
    assert np.isfinite(result.image).all() and result.image.max() > 1.0
