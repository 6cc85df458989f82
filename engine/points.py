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

from . import curve_attributes, instance_batch, primitive_motion
from .scene import Instance, Mesh


class _Rows:
    """Rows ``rows`` of Triangles that are not triangles: ``mask`` (T,) marks
    them, ``slot`` (T,) is each one's index among them (-1 elsewhere)."""

    def __init__(self, rows, n_rows):
        self.rows = rows
        self.mask = np.zeros(n_rows, bool)
        self.mask[rows] = True
        self.slot = np.full(n_rows, -1, np.int64)
        self.slot[rows] = np.arange(len(rows))

    def __len__(self):
        return len(self.rows)


class Spheres(_Rows):
    """Rows ``rows`` of Triangles are spheres (centres (N, 3), radii (N,))."""

    def __init__(self, rows, centres, radii, n_rows):
        super().__init__(rows, n_rows)
        self.centres, self.radii = centres, radii
        self.is_point = self.mask
        self.moving = None   # primitive_motion.MovingRows of moving clouds

    def rows_at(self, slots, time=None):
        """(n, 1, 4) world (centre, radius) of spheres ``slots`` at each ray's time."""
        return primitive_motion.world_rows(
            self, slots, time, 1, lambda k: np.concatenate([self.centres[k], self.radii[k, None]], axis=1)[:, None])


def _placed(cloud, mesh_index):
    """The stand-in Instance of a point cloud or curve set."""
    return Instance(mesh_index, np.asarray(cloud.matrix, np.float64), materials=cloud.materials,
                    name=cloud.name, visible_camera=cloud.visible_camera,
                    visible_diffuse=cloud.visible_diffuse, visible_glossy=cloud.visible_glossy,
                    visible_transmission=cloud.visible_transmission,
                    visible_shadow=cloud.visible_shadow, color=cloud.color, random=cloud.random,
                    pass_index=cloud.pass_index)


def _stand_ins(p):
    """A unit stand-in triangle at each point (never traced: only its row is used)."""
    return np.stack([p, p + [1.0, 0.0, 0.0], p + [0.0, 1.0, 0.0]], axis=1)


def expand_curves(scene):
    """(scene with each curve set as a stand-in mesh and instance, one row
    per segment; per set: its instance index and its curves)."""
    sets = list(getattr(scene, "curves", ()) or ())
    if not sets:
        return scene, []
    ribbons = getattr(scene, "curve_shape", "THICK") == "RIBBONS"
    meshes, instances, added = list(scene.meshes), scene.instances, []
    owners = []
    for strands in sets:
        points = np.asarray(strands.points, np.float64).reshape(-1, 3)
        starts = segment_starts(np.asarray(strands.offsets, np.int64))
        corners = _stand_ins(points[starts[0]])
        uvs, uv_maps = curve_attributes.uv_maps(strands)
        texspace, orco = curve_attributes.generated(strands)
        mesh = Mesh(corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3), uvs=uvs,
                    name=strands.name, uv_maps=uv_maps or None,
                    attributes=curve_attributes.corner_attributes(strands, ribbons), texspace=texspace, orco=orco)
        owners.append((len(instances) + len(added), strands))
        added.append(_placed(strands, len(meshes)))
        meshes.append(mesh)
    return replace(scene, meshes=meshes, instances=instance_batch.extended(instances, added)), owners


def segment_starts(offsets):
    """(the first control point of each segment, its index in the padded
    control points Embree gets: each curve's first and last point doubled,
    Cycles' layout) for curves of at least 2 points."""
    first, last = offsets[:-1], offsets[1:]
    count = np.maximum(last - first - 1, 0)
    curve = np.repeat(np.arange(len(first)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    point = first[curve] + k
    return point, point + 2 * curve


def expand(scene):
    """(scene with each point cloud as a stand-in mesh and instance, the
    instance indices of those, their radii per cloud)."""
    clouds = list(getattr(scene, "points", ()) or ())
    if not clouds:
        return scene, [], []
    meshes, instances, added = list(scene.meshes), scene.instances, []
    owners, radii = [], []
    for cloud in clouds:
        p = np.asarray(cloud.positions, np.float64).reshape(-1, 3)
        r = np.asarray(cloud.radii, np.float64).reshape(-1)
        corners = _stand_ins(p)
        attributes = {name: np.repeat(np.asarray(values, np.float64).reshape(len(p), 1, -1), 3, axis=1)
                      for name, values in (cloud.attributes or {}).items()}
        mesh = Mesh(corners.reshape(-1, 3), np.arange(3 * len(p)).reshape(-1, 3),
                    material_slots=None, name=cloud.name, attributes=attributes or None,
                    texspace=None)
        owners.append(len(instances) + len(added))
        radii.append(r)
        added.append(_placed(cloud, len(meshes)))
        meshes.append(mesh)
    return replace(scene, meshes=meshes, instances=instance_batch.extended(instances, added)), owners, radii


def spheres_of(tris, scene, owners, radii, clouds=()):
    """Spheres of the flattened stand-in rows (None without points);
    ``clouds`` the PointClouds of ``owners`` (their motion blur)."""
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
    spheres = Spheres(rows, tris.p0[rows].copy(), np.concatenate(r_world), len(tris))
    primitive_motion.attach_points(spheres, tris, owners, clouds)
    return spheres


class Strands(_Rows):
    """Rows ``rows`` of Triangles are curve segments: ``cvs`` (V, 4) the
    padded world-space control points and radii Embree holds, ``start``
    each row's first control point there (4 consecutive ones make a
    segment).  ``ribbon``: flat strands facing each ray (Cycles' ribbons,
    Embree's RTC_GEOMETRY_TYPE_FLAT_CATMULL_ROM_CURVE) instead of round ones;
    ``linear``: round linear segments between the keys as they are (Cycles'
    Linear 3D Curves, Embree's RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE: cones
    with end spheres; a segment is the middle two of its 4 padded control
    points); ``rate``: Embree's tessellation rate (``curve_rate``)."""

    def __init__(self, rows, cvs, start, n_rows, curve=None, normals=None, ribbon=False, rate=5, linear=False):
        super().__init__(rows, n_rows)
        self.cvs, self.start = cvs, start
        self.ribbon, self.rate = bool(ribbon), int(rate)
        self.linear = bool(linear) and not self.ribbon
        # (V, 3) world-space curve normals beside cvs (zero where a set has none)
        self.normals = normals
        self.is_curve = self.mask
        self.moving = None   # primitive_motion.MovingRows of moving curve sets
        # (n_rows,) the curve (strand) each segment row belongs to, numbered
        # over every curve set, -1 on other rows: rays leaving a strand pass
        # all of its segments (curve_rows).
        self.curve = np.full(n_rows, -1, np.int64)
        if curve is not None:
            self.curve[rows] = curve

    def rows_at(self, prim, time=None):
        """(n, 4, 4) world control points (x, y, z, r) of segment rows
        ``prim`` at each ray's time."""
        slots = self.slot[prim]
        return primitive_motion.world_rows(
            self, slots, time, 4, lambda k: self.cvs[self.start[k][:, None] + np.arange(4)[None, :]])


def padded_index(offsets):
    """Embree's control points of curves ``offsets`` as indices of their
    points: each curve's first and last point doubled (Cycles' Catmull-Rom layout)."""
    first, last = offsets[:-1], offsets[1:] - 1
    return (np.concatenate([np.r_[a, np.arange(a, b + 1), b] for a, b in zip(first, last)])
            if len(first) else np.zeros(0, np.int64))


def segment_padded_starts(offsets):
    """Each segment's first control point in padded_index's order."""
    return segment_starts(offsets)[1]


def strands_of(tris, owners, ribbons=False, rate=5, linear=False):
    """Strands of the flattened segment rows (None without curves);
    ``ribbons``: Render > Curves > Shape is Ribbons, ``linear``: Linear 3D
    Curves; ``rate``: curve_rate."""
    if not owners:
        return None
    owner = tris.shading.instance
    rows, cvs, starts, curves, normals = [], [], [], [], []
    base = curve_base = 0
    for inst_index, strands in owners:
        mine = np.flatnonzero(owner == inst_index)
        m = np.asarray(strands.matrix, np.float64)
        scale = abs(np.linalg.det(m[:3, :3])) ** (1.0 / 3.0)
        offsets = np.asarray(strands.offsets, np.int64)
        p = np.asarray(strands.points, np.float64) @ m[:3, :3].T + m[:3, 3]
        r = np.asarray(strands.radii, np.float64) * scale
        first, last = offsets[:-1], offsets[1:] - 1
        index = padded_index(offsets)
        padded = np.concatenate([p[index], r[index, None]], axis=1)
        _, start = segment_starts(offsets)
        curve = np.repeat(np.arange(len(first)), np.maximum(last - first, 0))   # each segment's curve
        local = tris.shading.local[mine]
        rows.append(mine)
        starts.append(start[local] + base)
        curves.append(curve[local] + curve_base)
        cvs.append(padded)
        normals.append(_world_normals(strands, m)[index])
        base += len(padded)
        curve_base += len(first)
    strands = Strands(np.concatenate(rows), np.concatenate(cvs), np.concatenate(starts), len(tris),
                      np.concatenate(curves), np.concatenate(normals), ribbon=ribbons, rate=rate, linear=linear)
    primitive_motion.attach_curves(strands, tris, owners, padded_index, segment_padded_starts)
    return strands


def _world_normals(strands, m):
    """(N, 3) a curve set's normals in world space (the normal matrix; NaN
    and missing ones zero)."""
    n = getattr(strands, "normals", None)
    count = len(strands.points)
    if n is None or np.shape(n) != (count, 3):
        return np.zeros((count, 3))
    with np.errstate(all="ignore"):
        try:
            normal_matrix = np.linalg.inv(m[:3, :3]).T
        except np.linalg.LinAlgError:
            normal_matrix = np.zeros((3, 3))
        out = np.asarray(n, np.float64) @ normal_matrix.T
    return np.where(np.isfinite(out).all(axis=1)[:, None], out, 0.0)


def curve_key_mix(strands, prim, u, values):
    """Cycles' curve_attribute of per-key ``values`` (padded as cvs) at
    segment rows ``prim``: the two keys of the segment mixed linearly by u."""
    start = strands.start[strands.slot[prim]]
    u = np.clip(u, 0.0, 1.0)[:, None]
    return (1.0 - u) * values[start + 1] + u * values[start + 2]


def _catmull_rom(t):
    """Embree's uniform Catmull-Rom basis at t (N,) -> (N, 4)."""
    t2, t3 = t * t, t * t * t
    return 0.5 * np.stack([-t3 + 2 * t2 - t, 3 * t3 - 5 * t2 + 2, -3 * t3 + 4 * t2 + t, t3 - t2], axis=1)


def _catmull_rom_derivative(t):
    """d/dt of _catmull_rom."""
    t2 = t * t
    return 0.5 * np.stack([-3 * t2 + 4 * t - 1, 9 * t2 - 10 * t, -9 * t2 + 8 * t + 1, 3 * t2 - 2 * t], axis=1)


def _linear(t):
    """The round linear segment's basis over its 4 padded control points:
    the middle two mixed by t (the outer two are the neighbours)."""
    zero = np.zeros_like(t)
    return np.stack([zero, 1.0 - t, t, zero], axis=1)


def _linear_derivative(t):
    """d/dt of _linear: the chord P2 - P1."""
    zero = np.zeros_like(t)
    return np.stack([zero, zero - 1.0, zero + 1.0, zero], axis=1)


def _basis(strands, t):
    return _linear(t) if strands.linear else _catmull_rom(t)


def _basis_derivative(strands, t):
    return _linear_derivative(t) if strands.linear else _catmull_rom_derivative(t)


def curve_tangents(strands, prim, u, time=None):
    """The strands' tangents dC/du (unnormalized) at segment rows ``prim``,
    parameter u, at each ray's time (the chord on linear curves)."""
    cv = strands.rows_at(prim, time)
    return np.einsum("nk,nkj->nj", _basis_derivative(strands, np.clip(u, 0.0, 1.0)), cv[:, :, :3])


def curve_hits(strands, o, d, t, prim, u, time=None, v=None):
    """(p, ng, back, radius) of rays (o, d) meeting segment rows ``prim`` at
    Embree's distance t and curve parameter u (at each ray's time): the
    point moved onto the round curve's surface around its centre C(u)
    (radius r(u)), the normal from C(u) to it, facing the ray (C and r
    linear in u on linear curves, whose end spheres Embree reports at u = 0
    or 1: the same rule gives their normals).  On ribbons ``ribbon_hits``
    (``v``: Embree's hit v there, rebuilt when not given)."""
    if strands.ribbon:
        return ribbon_hits(strands, o, d, t, prim, u, time, v)
    cv = strands.rows_at(prim, time)                                     # (n, 4, 4)
    w = _basis(strands, np.clip(u, 0.0, 1.0))
    centre = np.einsum("nk,nkj->nj", w, cv[:, :, :3])
    radius = np.maximum(np.einsum("nk,nk->n", w, cv[:, :, 3]), 0.0)
    p = o + d * t[:, None]
    n = p - centre
    length = np.linalg.norm(n, axis=1)
    n = np.where((length > 0)[:, None], n / np.maximum(length, 1e-300)[:, None], -d)
    p = centre + n * radius[:, None]
    back = np.einsum("ij,ij->i", d, n) > 0
    return p, np.where(back[:, None], -n, n), back, radius


# -- ribbons (Render > Curves > Shape = Ribbons) -------------------------------
# Embree's flat Catmull-Rom curves: each segment cut into ``curve_rate`` pieces
# (Embree's tessellation rate), each a quad facing the ray, 2 r wide across
# the curve's projection (curve_intersector_ribbon.h).

def curve_rate(subdivisions=2):
    """Embree's tessellation rate of Cycles' curves for Render > Curves >
    Curve Subdivisions s: its curve_subdivisions() = clamp(2^s, 1, 16), plus
    1 (bvh/embree.cpp), which Embree clamps to 16; 5 at the default s = 2."""
    return min(min(1 << min(max(int(subdivisions), 0), 8), 16) + 1, 16)


def _cross2(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _ray_plane(d):
    """(x, y) (n, 3) unit axes across unit rays d, right-handed with d (as
    Embree's ray space: x cross y = d)."""
    pick = np.where((np.abs(d[:, 0]) < 0.6)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    x = np.cross(d, pick)
    x /= np.linalg.norm(x, axis=1)[:, None]
    return x, np.cross(d, x)


def ribbon_v(cv, o, d, u, rate=5):
    """Embree's hit v in [-1, 1] across a ribbon (Cycles' sd->v, what its
    ribbon normal and the hair BSDFs' h = -v read) of rays (o, d) meeting
    segments ``cv`` (n, 4, 4) at curve parameter u: the ray's place in the
    tessellated piece's quad, in the plane across the ray, by the quad's two
    triangles as quad_intersector.h splits it (v = -1 on the side of the
    projected tangent turned clockwise)."""
    unit = d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    x, y = _ray_plane(unit)
    rel = cv[:, :, :3] - o[:, None, :]
    flat = np.stack([np.einsum("nkj,nj->nk", rel, x), np.einsum("nkj,nj->nk", rel, y)], axis=2)   # (n, 4, 2)
    piece = np.clip(np.floor(np.clip(u, 0.0, 1.0) * rate), 0, rate - 1)
    edges = []
    for s in (piece / rate, (piece + 1) / rate):
        w = _catmull_rom(s)
        p = np.einsum("nk,nkj->nj", w, flat)
        r = np.einsum("nk,nk->n", w, cv[:, :, 3])
        dp = np.einsum("nk,nkj->nj", _catmull_rom_derivative(s), flat)
        edges.append((p, r, dp))
    (p0, r0, dp0), (p1, r1, dp1) = edges
    sides = []
    for p, r, dp in edges:   # a vanishing tangent: the piece's chord (Embree's eps rule)
        dp = np.where((np.abs(dp).max(axis=1) < 4.8e-7 * (np.abs(flat).max(axis=(1, 2)) + 1e-30))[:, None], p1 - p0, dp)
        n = np.stack([dp[:, 1], -dp[:, 0]], axis=1)
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        sides.append((p + r[:, None] * n, p - r[:, None] * n))
    (lp0, up0), (lp1, up1) = sides
    first = _cross2(up0, lp1 - up0) <= 0   # which triangle of (lp0, lp1, up1, up0) the ray meets
    a, b, c = (np.where(first[:, None], q, q2) for q, q2 in ((lp0, up1), (lp1, up0), (up0, lp1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        v = _cross2(b, a) / _cross2(a - b, c - a)
    v = np.where(first, v, 1.0 - v)
    return np.clip(np.nan_to_num(2.0 * v - 1.0), -1.0, 1.0)


def ribbon_normal(tangent, d, v):
    """Cycles' ribbon shading normal (curve_shader_setup): rounded across the
    flat strand as if it were a thick curve, sin = v along the bitangent
    cross(T, -d); it faces the ray (the direction back along it where T
    runs along the ray)."""
    t = tangent / np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    b = np.cross(t, -d)
    length = np.linalg.norm(b, axis=1)
    ok = length > 1e-12
    b = b / np.where(ok, length, 1.0)[:, None]
    cos = np.sqrt(np.maximum(1.0 - v * v, 0.0))
    n = v[:, None] * b - cos[:, None] * np.cross(t, b)
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    back = -d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]
    return np.where(ok[:, None], n, back)


def ribbon_hits(strands, o, d, t, prim, u, time=None, v=None):
    """(p, n, back, radius) of rays meeting ribbon segments: the point where
    Embree's ray met the flat strand (Cycles keeps it, unmoved), the rounded
    ribbon normal (``ribbon_normal``; Cycles' Ng is the view direction, which
    faces it), never a back face, and the radius r(u).  ``v``: Embree's
    hit v (Cycles' sd->v); rebuilt by ``ribbon_v`` when not given."""
    cv = strands.rows_at(prim, time)
    uc = np.clip(u, 0.0, 1.0)
    radius = np.maximum(np.einsum("nk,nk->n", _catmull_rom(uc), cv[:, :, 3]), 0.0)
    tangent = np.einsum("nk,nkj->nj", _catmull_rom_derivative(uc), cv[:, :, :3])
    if v is None:
        v = ribbon_v(cv, o, d, u, strands.rate)
    n = ribbon_normal(tangent, d, v)
    return o + d * t[:, None], n, np.zeros(len(t), bool), radius


def curve_rows(strands, prim):
    """(N,) int64: the curve of each hit row ``prim`` (strands.curve), -1
    for other rows and misses: what rays leaving them pass."""
    prim = np.asarray(prim, np.int64)
    return np.where(prim >= 0, strands.curve[np.maximum(prim, 0)], -1)


def unlit_rows(n_rows, spheres, strands=None):
    """(T,) bool: the rows no light samples (points and curve segments),
    or None when there are none.  Their emission is found by BSDF rays
    alone, with MIS weight 1: unbiased.  (Moving triangles are sampled at
    the path's time: lights/mesh.py.)"""
    rows = np.zeros(n_rows, bool)
    if spheres is not None:
        rows[spheres.rows] = True
    if strands is not None:
        rows[strands.rows] = True
    return rows if rows.any() else None


def for_lights(tris, unlit, default_material):
    """The triangles as the lights see them: ``unlit`` rows carry the
    default (non-emissive) material, so no light samples them."""
    if unlit is None:
        return tris
    material = tris.material.copy()
    material[unlit] = default_material
    return replace(tris, material=material)


def sphere_hits(spheres, o, d, t, prim, time=None):
    """(p, ng, back) of rays (o, d) meeting sphere rows ``prim`` near
    Embree's distance t (at each ray's time): the root of |o + t d - c| = r
    closest to it, in float64; ng faces the ray."""
    rows = spheres.rows_at(spheres.slot[prim], time)[:, 0]
    c, r = rows[:, :3], rows[:, 3]
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
