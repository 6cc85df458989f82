"""Emissive triangles: one emitter per emissive material, the material's
emission (constant or textured), two-sided.  A triangle of the group is
picked by area or by a tree over the group; triangles near the shading
point's plane are sampled by solid angle (Arvo), as Cycles."""
from dataclasses import dataclass

import numpy as np

from .. import testscenes
from ..lightbounds import Bounds, triangle_bounds
from ..nodes import ShadingContext
from ..nodes.context import PATH_COLUMNS
from ..sampling import Distribution1D, spherical_triangle, triangle_solid_angle, uniform_triangle
from ..scene import Instance, Lobe, Material, Scene
from ..vec import dot
from . import common
from .common import normals, selection_power
from .registry import SURFACE, LightDef, LightExample, LightTable, register

MESH = 3
# Emissive triangles of one material up to which the light-tree strategy
# picks them by importance (a tree over them); above, by area.
MAX_TREE_TRIANGLES = 16384


# Cycles evaluates a light sample's emission with the emission nodes only
# (KERNEL_FEATURE_NODE_MASK_SURFACE_LIGHT: no closures are allocated), so the
# Principled BSDF's sheen and coat, which dim its emission by their albedo
# where the shader allocates them, do not dim it there: only the coat tint
# (applied outside the closure) does.  BSDF rays that hit the surface see
# it dimmed.  Matched here (the integrator's MIS then blends the two as
# Cycles' does).
LIGHT_SAMPLES_DIM_BY_ALBEDO = False

class MeshLights(LightTable):
    """Emissive triangles, one emitter per emissive material.

    Within its group a triangle is picked by area, or (by_importance, the
    light-tree strategy) by a light tree over the group's triangles that
    weighs each by its importance at the shading point, as Cycles' light tree
    holds every emissive triangle: a group's triangles can lie far apart
    (objects sharing a material), and area alone sends most samples to the
    ones far from the shading point.  Groups larger than MAX_TREE_TRIANGLES
    keep area selection: the tree is built in Python (about 60 us per
    triangle).  make_tree(bounds): the tree to build over them."""

    def __init__(self, triangles, materials, by_importance=False, make_tree=None, motion=None):
        emissive = materials.emissive
        self.tris = triangles
        # Moving triangles are picked by their area and bounds at the
        # shutter's centre and sampled where they are at the path's time, as
        # Cycles (light/triangle.h: its CDF's area at a fixed time).
        self.motion = motion if motion is not None and motion.moving else None
        mats = np.unique(triangles.material[emissive[triangles.material]]) if len(triangles) else []
        self.material = np.array(mats, np.int64)
        self.count = len(self.material)
        self.L = materials.emission[self.material].reshape(-1, 3)
        self.textures = materials.textures
        self.materials = materials
        self.members, self.dists, self.total_area, self.trees = [], [], [], []
        # Index of each triangle within its group (for the group's tree pmf).
        self.rank = np.zeros(len(triangles), np.int64)
        for m in self.material:
            members = np.nonzero(triangles.material == m)[0]
            self.members.append(members)
            self.rank[members] = np.arange(len(members))
            self.dists.append(Distribution1D(triangles.area[members]))
            self.total_area.append(triangles.area[members].sum())
            tree = by_importance and make_tree is not None and 1 < len(members) <= MAX_TREE_TRIANGLES
            self.trees.append(make_tree(triangle_bounds(triangles, members)) if tree else None)
        self.total_area = np.array(self.total_area, float)
        self.group_of_material = np.full(max(1, len(materials.emission)), -1, np.int64)
        self.group_of_material[self.material] = np.arange(self.count)

    def power(self, radius):
        # Two-sided Lambertian emitter: flux = pi * L * A per side.
        return selection_power(self.L) * 2.0 * np.pi * self.total_area if self.count else []

    def bounds(self, j, phi):
        tr = self.tris
        members = self.members[j]
        corners = np.concatenate([tr.p0[members], tr.p0[members] + tr.e1[members],
                                  tr.p0[members] + tr.e2[members]])
        ng = tr.ng[members]
        # Two-sided emitters: a cone around +-w holding every normal.
        ref = ng[np.argmax(tr.area[members])]
        signed = ng * np.where(ng @ ref < 0, -1.0, 1.0)[:, None]
        w = (signed * tr.area[members, None]).sum(axis=0)
        length = np.linalg.norm(w)
        if length > 1e-12:
            w = w / length
            cos_o = float(np.min(np.abs(ng @ w)))
        else:
            w, cos_o = ref, -1.0
        return Bounds(corners.min(axis=0), corners.max(axis=0), phi, w, cos_o, 0.0, True)

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        tri, p_tri = self._pick(j, p, u3, n)
        b1, b2 = uniform_triangle(u1, u2)
        tr = self._at(tri, None if out.time is None else out.time[idx])
        tri_at = np.arange(len(tri))      # rows of ``tr``
        q = tr.p0 + b1[:, None] * tr.e1 + b2[:, None] * tr.e2
        sph, solid_angle = _spherical(tr, tri_at, p)
        s = np.nonzero(sph)[0]
        if len(s):
            ts = s
            d, _ = spherical_triangle(p[s], tr.p0[ts], tr.p0[ts] + tr.e1[ts], tr.p0[ts] + tr.e2[ts],
                                      u1[s], u2[s])
            # The point where the sampled direction meets the triangle's plane.
            ng = tr.ng[ts]
            with np.errstate(divide="ignore", invalid="ignore"):
                th = dot(tr.p0[ts] - p[s], ng) / dot(d, ng)
            q[s] = p[s] + d * np.nan_to_num(th)[:, None]
        v = q - p
        t = np.linalg.norm(v, axis=1)
        wi = v / np.maximum(t, 1e-30)[:, None]
        cos_l = np.abs(dot(wi, tr.ng))
        q_tex = q
        if self.motion is not None and out.time is not None:
            # textures read the centre's triangle at the point's barycentrics
            bary = _barycentrics(tr, q)
            q_tex = self.tris.p0[tri] + bary[0][:, None] * self.tris.e1[tri] + bary[1][:, None] * self.tris.e2[tri]
        path = None if out.path is None else (out.path[0][idx], out.path[1][idx])
        Le = self._radiance(tri, q_tex, self.L[j], path, t)
        if self.materials.emission_layers:
            Le = self._dimmed(tri, q_tex, wi, Le)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, t, Le
        out.pdf[idx] = _pdf(tr.area, tri_at, p_tri, t * t, cos_l, sph, solid_angle)
        out.on_surface[idx] = True

    def _at(self, tri, time):
        """The triangles ``tri`` (rows of the result: p0, e1, e2, ng, area)
        where they are at ``time``; the still table itself when nothing moves."""
        if self.motion is None or time is None:
            return _Rows(self.tris.p0[tri], self.tris.e1[tri], self.tris.e2[tri], self.tris.ng[tri],
                         self.tris.area[tri])
        p0, e1, e2 = self.motion.corners_at(self.tris, tri, np.asarray(time, np.float64).reshape(-1))
        cross = np.cross(e1, e2)
        length = np.linalg.norm(cross, axis=1)
        ng = cross / np.maximum(length, 1e-300)[:, None]
        return _Rows(p0, e1, e2, ng, 0.5 * length)

    def _pick(self, j, p, u, n):
        """A triangle of each ray's group j and its probability within the group."""
        tri = np.empty(len(p), np.int64)
        prob = np.empty(len(p))
        for g in np.unique(j):
            sel = np.nonzero(j == g)[0]
            if self.trees[g] is not None:
                k, prob[sel] = self.trees[g].select(u[sel], p[sel], normals(n, len(p))[sel])
            else:
                k, _ = self.dists[g].sample(u[sel])
                prob[sel] = self.dists[g].pmf[k]
            tri[sel] = self.members[g][k]
        return tri, prob

    def _pick_pmf(self, tri, o, n):
        """Probability that ``_pick`` at o (normal n) picks triangle tri."""
        group = self.group_of_material[self.tris.material[tri]]
        prob = np.zeros(len(tri))
        for g in np.unique(group):
            if g < 0:
                continue
            sel = np.nonzero(group == g)[0]
            k = self.rank[tri[sel]]
            if self.trees[g] is not None:
                prob[sel] = self.trees[g].pmf(k, o[sel], normals(n, len(tri))[sel])
            else:
                prob[sel] = self.dists[g].pmf[k]
        return prob

    def _radiance(self, tri, q, L, path=None, t=None):
        """Emission at points q on triangles tri: the constant, or the
        material's emission texture evaluated at q's UVs (and, for a Light
        Path node, ``path`` = (depth, columns) of the sampling paths at
        distance t)."""
        if not self.textures.emission:
            return L
        tr = self.tris
        shading = self._shading(tri, q)
        if path is not None:
            shading.depth, shading.path = path[0], path[1].copy()
            shading.path[:, PATH_COLUMNS.index("Ray Length")] = t
        return self.textures.emission_at(tr.material[tri], shading, np.broadcast_to(L, q.shape))

    def _dimmed(self, tri, q, wi, Le):
        """Le toward the shading point (-wi) dimmed by the layers over the
        emission (bsdf.MaterialTable.dim_emission), at the smooth normal of q."""
        tr = self.tris
        shading = self._shading(tri, q)
        Le = np.array(np.broadcast_to(Le, q.shape), dtype=np.float64)
        return self.materials.dim_emission(tr.material[tri], shading, dot(wi, shading.ns), Le,
                                           albedo=LIGHT_SAMPLES_DIM_BY_ALBEDO)

    def _shading(self, tri, q):
        tr = self.tris
        b1, b2 = _barycentrics(_Rows(tr.p0[tri], tr.e1[tri], tr.e2[tri], None, None), q)
        # No ray kind: Cycles evaluates a light sample's emission with
        # PATH_RAY_EMISSION, so Light Path's 'Is ... Ray' outputs read 0.
        return ShadingContext.at(tr, tri, b1, b2, ray=np.zeros(len(tri), np.uint8))

    def pdf(self, prim, o, p_hit, ng, n=None, time=None):
        """Solid-angle pdf of ``sample`` from o (normal n) giving p_hit on
        prim (the triangle where it is at the rays' ``time``)."""
        v = p_hit - o
        t2 = dot(v, v)
        cos_l = np.abs(dot(v, ng)) / np.sqrt(np.maximum(t2, 1e-300))
        tr = self._at(prim, time)
        rows = np.arange(len(prim))
        sph, solid_angle = _spherical(tr, rows, o)
        return _pdf(tr.area, rows, self._pick_pmf(prim, o, n), t2, cos_l, sph, solid_angle)


@dataclass
class _Rows:
    """Triangles as MeshLights samples them (one row each)."""
    p0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    ng: np.ndarray
    area: np.ndarray


def _barycentrics(rows, q):
    """(b1, b2) of points q on triangle rows (q = p0 + b1 e1 + b2 e2)."""
    d = q - rows.p0
    e1, e2 = rows.e1, rows.e2
    d00, d01, d11 = dot(e1, e1), dot(e1, e2), dot(e2, e2)
    d20, d21 = dot(d, e1), dot(d, e2)
    denom = np.where(d00 * d11 - d01 * d01 > 0, d00 * d11 - d01 * d01, 1.0)
    return (d11 * d20 - d01 * d21) / denom, (d00 * d21 - d01 * d20) / denom


def _pdf(area, tri, p_tri, t2, cos_l, sph, solid_angle):
    """Solid-angle pdf of a point on triangle tri: p_tri times the
    triangle's own (area or solid-angle) pdf."""
    area = area[tri]
    ok = (cos_l > 1e-12) & (t2 > 0) & (area > 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        pdf = np.where(ok, p_tri * t2 / (np.maximum(cos_l, 1e-12) * np.maximum(area, 1e-300)), 0.0)
        pdf = np.where(ok & sph, p_tri / solid_angle, pdf)
    return np.where(np.isfinite(pdf), pdf, 0.0)


def _spherical(tr, tri, p):
    """Which shading points sample their triangle (rows ``tri`` of
    ``tr``) by solid angle (Arvo), and that solid angle: as Cycles
    (light/triangle.h), those near the triangle's plane against its
    longest edge, where area sampling's pdf varies much over the triangle;
    farther, area sampling is about as good and far cheaper.  Cycles'
    "distance to the plane" is dot(N0, V0 - P) / dot(N0, N0) with N0 the
    unnormalized cross product, i.e. the distance divided by twice the
    area: matched, as the choice sets the light pdf that MIS weighs, and a
    bake without Emit (or any split of BSDF-hit and light-sampled emission)
    keeps only the light-sampled share (+20 % under a 0.8 m panel with the
    plain distance).  The solid-angle limits guard the warp."""
    e1, e2 = tr.e1[tri], tr.e2[tri]
    e3 = e2 - e1
    longest2 = np.maximum(np.maximum(dot(e1, e1), dot(e2, e2)), dot(e3, e3))
    twice_area = 2.0 * np.asarray(tr.area[tri], np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        plane = dot(tr.p0[tri] - p, tr.ng[tri]) / twice_area
    plane = np.where(np.isfinite(plane), plane, np.inf)   # a zero-area triangle: area sampling (pdf 0)
    close = np.nonzero(longest2 > plane * plane)[0]
    solid_angle = np.zeros(len(tri))
    if len(close):
        tc = tri[close]
        solid_angle[close] = triangle_solid_angle(p[close], tr.p0[tc], tr.p0[tc] + tr.e1[tc],
                                                  tr.p0[tc] + tr.e2[tc])[0]
    return (solid_angle >= common.MIN_SPHERICAL) & (solid_angle <= common.MAX_SPHERICAL), solid_angle




def _build(inputs):
    tree = inputs.strategy in ("tree", "auto", "tree_bsdf")
    return MeshLights(inputs.triangles, inputs.materials, tree, inputs.make_tree, inputs.motion)


def _glow_scene(corners, emission=(2.0, 1.0, 0.5)):
    def scene():
        glow = Material("glow", (Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=emission)
        return Scene([testscenes.quad(corners)], [Instance(0, materials=[0], name="glow")], [glow])
    return scene


def _examples():
    a, b, h = 0.5, 0.3, 2.0
    # A rectangle of half sizes a x b at height h over p: solid angle
    # 4 asin(a b / sqrt((a^2 + h^2)(b^2 + h^2))).
    far = 4 * np.arcsin(a * b / np.sqrt((a * a + h * h) * (b * b + h * h)))
    near = 4 * np.arcsin(1.0 / np.sqrt(2.0 * 2.0))   # a 2 x 2 square at height 1
    return [LightExample("quad", _glow_scene([[-a, -b, h], [a, -b, h], [a, b, h], [-a, b, h]]), (0, 0, 0),
                         solid_angle=far),
            LightExample("near quad", _glow_scene([[-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]]), (0, 0, 0),
                         solid_angle=near)]


def _set_emission(value):
    return lambda s: setattr(s.materials[0], "emission", value)


register(LightDef(
    "mesh", MESH, 4, _build, SURFACE, "meshes", source="material", examples=_examples,
    hostile=(("NaN emission", _set_emission((1.0, np.nan, 1.0)), "emission"),
             ("NaN vertex", lambda s: setattr(s.meshes[0], "positions", np.full((4, 3), np.nan)), "NaN"))))
