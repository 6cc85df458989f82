"""Point clouds: spheres of each point's radius (Cycles' point cloud objects
and geometry nodes' Points), traced by Embree's RTC_GEOMETRY_TYPE_SPHERE_POINT.

A ``scene.PointCloud`` becomes, before flattening, one mesh and instance of
its own whose "triangle" k is a stand-in for point k (corners p, p + x,
p + y: a row of ``geometry.Triangles`` with the point's material, ray
visibility, object info and per-point attributes as per-corner data, so
every consumer of triangle rows, shader nodes included, reads the point
through the paths it already has).  ``Spheres`` says which rows are points,
with their world centres and radii (radius x cbrt|det M| of the cloud's
matrix, as Cycles' PointCloud::apply_transform): Embree traces those rows
as spheres, the hit point is re-intersected with the sphere in float64 and
its normal is the sphere's.  Lights never sample points, nor moving
triangles (``unlit_rows``: an emissive point or moving triangle is found
by BSDF rays, MIS weight 1: unbiased).
"""
from dataclasses import replace

import numpy as np

from .scene import Instance, Mesh


class Spheres:
    """Rows ``rows`` of Triangles are spheres (centres (N, 3), radii (N,)),
    ``first`` the first such row (they come after every triangle)."""

    def __init__(self, rows, centres, radii, n_rows):
        self.rows, self.centres, self.radii = rows, centres, radii
        self.is_point = np.zeros(n_rows, bool)
        self.is_point[rows] = True
        self.slot = np.full(n_rows, -1, np.int64)
        self.slot[rows] = np.arange(len(rows))

    def __len__(self):
        return len(self.rows)


def expand(scene):
    """(scene with each point cloud as a stand-in mesh and instance, the
    instance indices of those, their radii per cloud)."""
    clouds = list(getattr(scene, "points", ()) or ())
    if not clouds:
        return scene, [], []
    meshes, instances = list(scene.meshes), list(scene.instances)
    owners, radii = [], []
    for cloud in clouds:
        p = np.asarray(cloud.positions, np.float64).reshape(-1, 3)
        r = np.asarray(cloud.radii, np.float64).reshape(-1)
        # a unit stand-in triangle at each point (never traced: only its row is used)
        corners = np.stack([p, p + [1.0, 0.0, 0.0], p + [0.0, 1.0, 0.0]], axis=1)
        attributes = {name: np.repeat(np.asarray(values, np.float64).reshape(len(p), 1, -1), 3, axis=1)
                      for name, values in (cloud.attributes or {}).items()}
        mesh = Mesh(corners.reshape(-1, 3), np.arange(3 * len(p)).reshape(-1, 3),
                    material_slots=None, name=cloud.name, attributes=attributes or None,
                    texspace=None)
        owners.append(len(instances))
        radii.append(r)
        instances.append(Instance(len(meshes), np.asarray(cloud.matrix, np.float64), materials=cloud.materials,
                                  name=cloud.name, visible_camera=cloud.visible_camera,
                                  visible_diffuse=cloud.visible_diffuse, visible_glossy=cloud.visible_glossy,
                                  visible_transmission=cloud.visible_transmission,
                                  visible_shadow=cloud.visible_shadow, color=cloud.color, random=cloud.random,
                                  pass_index=cloud.pass_index))
        meshes.append(mesh)
    return replace(scene, meshes=meshes, instances=instances), owners, radii


def spheres_of(tris, scene, owners, radii):
    """Spheres of the flattened stand-in rows (None without points)."""
    if not owners:
        return None
    owner, local = tris.shading.instance, tris.shading.local
    rows, r_world = [], []
    for inst_index, r in zip(owners, radii):
        mine = np.flatnonzero(owner == inst_index)
        m = np.asarray(scene.instances[inst_index].matrix, np.float64)
        scale = abs(np.linalg.det(m[:3, :3])) ** (1.0 / 3.0)
        rows.append(mine)
        r_world.append(r[local[mine]] * scale)
    rows = np.concatenate(rows)
    return Spheres(rows, tris.p0[rows].copy(), np.concatenate(r_world), len(tris))


def unlit_rows(n_rows, spheres, motion):
    """(T,) bool: the rows no light samples (points, moving triangles: the
    light set holds still triangles only), or None when there are none.
    Their emission is found by BSDF rays alone, with MIS weight 1: unbiased."""
    rows = np.zeros(n_rows, bool)
    if spheres is not None:
        rows[spheres.rows] = True
    if motion is not None and motion.moving:
        rows |= motion.part >= 0
    return rows if rows.any() else None


def for_lights(tris, unlit, default_material):
    """The triangles as the lights see them: ``unlit`` rows carry the
    default (non-emissive) material, so no light samples them."""
    if unlit is None:
        return tris
    material = tris.material.copy()
    material[unlit] = default_material
    return replace(tris, material=material)


def sphere_hits(spheres, o, d, t, prim):
    """(p, ng, back) of rays (o, d) meeting sphere rows ``prim`` near
    Embree's distance t: the root of |o + t d - c| = r closest to it, in
    float64; ng faces the ray."""
    k = spheres.slot[prim]
    c, r = spheres.centres[k], spheres.radii[k]
    oc = o - c
    b = np.einsum("ij,ij->i", oc, d)
    q = np.einsum("ij,ij->i", oc, oc) - r * r
    disc = np.sqrt(np.maximum(b * b - q, 0.0))
    near, far = -b - disc, -b + disc
    t64 = np.where(np.abs(near - t) <= np.abs(far - t), near, far)
    t64 = np.where(np.isfinite(t64), t64, t)
    p = o + d * t64[:, None]
    n = (p - c) / np.maximum(r, 1e-300)[:, None]
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    back = np.einsum("ij,ij->i", d, n) > 0
    return p, np.where(back[:, None], -n, n), back
