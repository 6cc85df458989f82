"""Every emitter of a scene, for next-event estimation and for the pdf and
radiance that BSDF-sampled rays need when they hit one.

Units follow Cycles (scene/light.cpp, kernel/light/*.h); each light type is
a module of this package with its entry in registry.py (point.py: point and
spot lights, sun.py, area.py, world.py: an HDRI world, mesh.py: emissive
triangles).  ``LightSet`` builds one table per registered type, in the
registry's emitter order, and every emitter is one entry of a selection
distribution (uniform, by power, or the light tree over the types' bounds).
``select``/``sample`` give NEE samples; ``intersect``, ``sun_hits``,
``environment_hits`` and ``triangle_pdf`` give what a BSDF ray sees.
Returned pdfs are solid-angle pdfs *without* the selection probability;
``selection_pdf`` supplies that.
"""
import numpy as np

from ..lightproxy import LightProxies
from ..lighttree import LightTree
from ..sampling import Distribution1D
from ..vec import count, subset
from .common import LightSample, normals
from .shader import path_rows
from .registry import ESCAPE, RAY, SURFACE, WORLD, BuildInputs, lights_of, ordered

# Light selection 'auto' picks one light by the light tree, except at
# vertices whose BSDF is mostly a narrow glossy lobe (integrator
# _every_light), where it samples every light, in scenes of 2 to this many
# lights none of which is an emissive mesh.  The tree weighs lights by power,
# distance and orientation but not by the BSDF, so over a glossy surface it
# often picks a light outside the lobe.  Every light at every vertex, measured
# with tools/variance_seeds.py (tree / all, 16 spp, 8-12 seeds): Veach's MIS
# scene (4 sphere lights over GGX plates) 5.7x less variance for 1.5x the CPU
# per path, 3.9x less time to equal error; but a diffuse Cornell box with 3
# area lights 10 % less variance for 1.5x the CPU, 3 emissive meshes 10 % for
# 1.4x (each mesh's sample descends its own triangle tree), and 64 lights'
# shadow rays cost far more.
AUTO_ALL_LIGHTS = 4


def resolve_selection(strategy, lights, mesh_emitters):
    """(the selection a LightSet builds for, whether NEE samples every light
    at glossy vertices): 'auto' is the light tree, with every light at glossy
    vertices when there are 2 to AUTO_ALL_LIGHTS emitters, none an emissive
    mesh.  Other selections stand for themselves."""
    if strategy in ("ris", "tree_bsdf"):
        return "tree", False
    if strategy != "auto":
        return strategy, False
    return "tree", mesh_emitters == 0 and 2 <= lights <= AUTO_ALL_LIGHTS


def _rows(a, rows):
    return None if a is None else a[rows]


class _Group:
    """One registered type's table and the emitter index of its first light."""

    def __init__(self, definition, table, base):
        self.definition, self.table, self.base = definition, table, base
        self.stop = base + table.count


class LightSet:
    """env_compensation: sample an HDRI world by max(L - mean, 0) (only
    unbiased when BSDF sampling is combined by MIS: RenderSettings
    ``mis_compensation`` with strategy 'mis')."""

    def __init__(self, scene, triangles, materials, strategy="power", env_compensation=False, motion=None):
        self.groups, base = [], 0
        for d in ordered():
            inputs = BuildInputs(lights_of(d, scene.lights), scene, triangles, materials, strategy,
                                 env_compensation, LightTree, motion)
            group = _Group(d, d.build(inputs), base)
            self.groups.append(group)
            base = group.stop
        self.count = base
        surface = sum(g.table.count for g in self.groups if g.definition.hit == SURFACE)
        self.resampled = strategy == "ris"
        # 'tree_bsdf': the tree weighs nodes by the glossy lobe too (lighttree LOBE_COLUMNS).
        self.lobe_term = strategy == "tree_bsdf"
        strategy, self.every_at_glossy = resolve_selection(strategy, self.count, surface)
        self.strategy = strategy
        radius = _scene_radius(triangles)
        # Emitter index -> (type, index within type), in the registry's order.
        self.kind = np.concatenate([np.full(g.table.count, g.definition.kind, np.int64) for g in self.groups])
        self.local = np.concatenate([np.arange(g.table.count, dtype=np.int64) for g in self.groups])
        power = [float(x) for g in self.groups for x in g.table.power(radius)]
        self.power = np.array(power, float)
        if self.count:
            weights = np.ones(self.count) if strategy == "uniform" else self.power
            self.dist = Distribution1D(weights)
        self.visibility = np.concatenate([g.table.visibility() for g in self.groups]).astype(np.uint8)
        self.delta = np.concatenate([np.asarray(g.table.is_delta(), bool) for g in self.groups])
        # Light tree (strategy 'tree'): built over every emitter's bounds and power.
        self.tree = LightTree(self.emitter_bounds()) if strategy == "tree" and self.count else None
        self.proxies = LightProxies.for_lights([g.table for g in self.groups if g.definition.hit == RAY])
        self._surface = self._only(SURFACE)
        self._world = self._only(WORLD)
        self.mesh_emitter = self._surface.base + self._surface.table.group_of_material
        self.mesh_emitter[self._surface.table.group_of_material < 0] = -1
        # Some light's node tree reads a Light Path node (its depths): the
        # integrator then hands the paths to sample, intersect and sun_hits.
        self.light_path = any(getattr(getattr(g.table, "shaders", None), "light_path", False)
                              for g in self.groups)

    def __getattr__(self, name):
        """A type's table by its registry ``attr`` (points, suns, areas, env,
        meshes), as other modules and tests read it."""
        for g in self.__dict__.get("groups", ()):
            if g.definition.attr == name:
                return g.table
        raise AttributeError(name)

    def _only(self, hit):
        found = [g for g in self.groups if g.definition.hit == hit]
        if len(found) != 1:
            raise RuntimeError(f"exactly one light type must have hit {hit!r}, found {len(found)}")
        return found[0]

    def emitter_bounds(self):
        """lightbounds.Bounds per emitter (None: no position), for the tree."""
        return [g.table.bounds(e - g.base, self.power[e]) for g in self.groups for e in range(g.base, g.stop)]

    @property
    def env_emitter(self):
        return self._world.base

    def per_emitter(self, lights, world, material):
        """A value per emitter from values per scene light (in the order
        ``registry.scene_lights_in_order`` gives), for the world and per
        material (an emissive-mesh emitter's material): e.g. light groups."""
        out, k = [], 0
        for g in self.groups:
            source, table = g.definition.source, g.table
            if source == "lights":
                out += list(lights[k:k + table.count])
                k += table.count
            elif source == "world":
                out += [world] * table.count
            else:
                out += list(np.asarray(material)[table.material])
        return out

    # -- selection ----------------------------------------------------------
    def select(self, u, p=None, n=None, lobe=None):
        """Emitter per uniform u and its probability; the tree needs the
        shading points p and their normals n (zero rows: no normal), and
        under 'tree_bsdf' the vertices' glossy-lobe terms (None: none)."""
        if self.tree is not None:
            return self.tree.select(u, p, normals(n, len(u)), lobe)
        return self.dist.sample(u)

    def select_segment(self, u, o, d, t):
        """``select`` for ray segments o + s d, 0 <= s <= t in volumes (the
        tree weighs lights along the whole segment, Cycles'
        light_tree_sample<true>; other selections do not look at it)."""
        if self.tree is not None:
            return self.tree.select_segment(u, o, d, t)
        return self.dist.sample(u)

    def select_many(self, u, p=None, n=None):
        """``select`` of each column of u (N, M), rows ascending: emitters
        and probabilities (N, M)."""
        if self.tree is not None:
            return self.tree.select_many(u, p, normals(n, len(u)))
        picks = [self.dist.sample(u[:, k]) for k in range(u.shape[1])]
        return np.stack([e for e, _ in picks], axis=1), np.stack([q for _, q in picks], axis=1)

    def selection_pdf(self, emitter, p=None, n=None, every=None, lobe=None, segment=None):
        """Probability that ``select`` at p (normal n, lobe terms) picks
        ``emitter``; 1 where ``every`` (per row: NEE sampled every light there).
        ``segment``: per row, the length of the volume segment whose light
        ``select_segment`` picked (p its start, n[:, :3] its direction), or
        negative where ``select`` picked at p (None: every row)."""
        if self.strategy == "all":
            return np.ones(len(emitter))
        if segment is not None and self.tree is not None and np.any(segment >= 0):
            seg = segment >= 0
            out = np.empty(len(emitter))
            s, rest = np.flatnonzero(seg), np.flatnonzero(~seg)
            out[s] = self.tree.pmf_segment(emitter[s], p[s], n[s, :3], segment[s])
            if len(rest):
                out[rest] = self.selection_pdf(emitter[rest], p[rest], n[rest], _rows(every, rest), _rows(lobe, rest))
            return out
        if every is not None and every.any():
            out = np.ones(len(emitter))
            some = np.flatnonzero(~every)
            if len(some):
                out[some] = self.selection_pdf(emitter[some], _rows(p, some), _rows(n, some),
                                               lobe=_rows(lobe, some))
            return out
        if self.tree is not None:
            return self.tree.pmf(emitter, p, normals(n, len(emitter)), lobe)
        return self.dist.pmf[emitter]

    # -- NEE ----------------------------------------------------------------
    def sample(self, emitter, p, u1, u2, u3, n=None, path=None, time=None):
        """Sample a point on each ray's emitter as seen from p (normal n: a
        mesh group picks its triangle by importance there, the light tree
        strategy only).  ``path``: (depth, PATH_COLUMNS) of the sampling
        paths, for emissions that read a Light Path node (None: none does);
        ``time``: their shutter times (moving emissive triangles)."""
        m = len(p)
        out = LightSample(np.zeros((m, 3)), np.full(m, np.inf), np.zeros((m, 3)),
                          np.zeros(m), np.zeros(m, bool), np.zeros(m, bool), path, time)
        kind = self.kind[emitter]
        local = self.local[emitter]
        for g in self.groups:
            idx = subset(kind == g.definition.kind)
            if count(idx, len(p)):
                j = local[idx]
                g.table.sample(out, idx, j, p[idx], u1[idx], u2[idx], u3[idx], None if n is None else n[idx])
                if g.table.falloff is not None:
                    out.Le[idx] *= g.table.falloff.factor(j, out.dist[idx])[:, None]
        return out

    # -- what BSDF rays see -------------------------------------------------
    def intersect(self, o, d, tmax, camera=False, ray=None, path=None, tmin=None):
        """Closest light a ray can hit (the types with hit RAY: point, spot,
        area) past tmin (per ray; None: 0) and before tmax.

        camera: the rays are camera rays, which see only lights with
        ``visible_camera``; ray: per-ray VIS_* bits (camera, diffuse, glossy,
        transmission), when set, see only lights with a common bit; path:
        what the lights' node trees read of the rays' paths
        (shader.emission_path), None where none reads it.  Returns
        t (inf = none), emitter index, Le and the solid-angle pdf of sampling
        that point from o.  With several lights only the rays their proxies
        (engine/lightproxy.py) say may meet one are tested exactly."""
        n = len(o)
        if self.proxies is None:
            return self._intersect_exact(o, d, tmax, camera, ray, path, tmin)
        rows = np.flatnonzero(self.proxies.candidates(o, d, tmax))
        out = (np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3)), np.zeros(n))
        if len(rows):
            tm = np.broadcast_to(tmax, (n,))[rows]
            found = self._intersect_exact(o[rows], d[rows], tm, camera, None if ray is None else ray[rows],
                                          path_rows(path, rows), None if tmin is None else tmin[rows])
            for whole, part in zip(out, found):
                whole[rows] = part
        return out

    def _intersect_exact(self, o, d, tmax, camera, ray, path=None, tmin=None):
        n = len(o)
        t = np.array(tmax, dtype=np.float64, copy=True)
        hit_t = np.full(n, np.inf)
        emitter = np.full(n, -1, np.int64)
        Le = np.zeros((n, 3))
        pdf = np.zeros(n)
        for g in self.groups:
            if g.definition.hit != RAY or not g.table.count:
                continue
            # Each type's nearest only reports hits closer than t, and lowers t.
            th, index, le, pw = g.table.nearest(o, d, t, ray, self.visibility[g.base:g.stop], camera, path, tmin)
            rows = np.flatnonzero(index >= 0)
            if len(rows) == 0:
                continue
            if g.table.falloff is not None:
                le[rows] *= g.table.falloff.factor(index[rows], th[rows])[:, None]
            hit_t[rows], emitter[rows] = th[rows], g.base + index[rows]
            Le[rows], pdf[rows] = le[rows], pw[rows]
        return hit_t, emitter, Le, pdf

    def sun_hits(self, d, ray=None, path=None):
        """Radiance of sun disks along escaping directions, with MIS pdfs;
        ray: per-ray VIS_* bits, path: the rays' paths, as in ``intersect``.

        Returns a list of (mask, emitter, Le, pdf) per sun with angle > 0."""
        hits = []
        for g in self.groups:
            if g.definition.hit != ESCAPE:
                continue
            for mask, j, Le, pdf in g.table.escape_hits(d, path):
                e = g.base + j
                if ray is not None:
                    seen = (ray & self.visibility[e]) != 0
                    if np.ndim(Le) == 2:   # a tree's Le per masked row: keep the rows that stay
                        Le = Le[seen[mask]]
                    mask = mask & seen
                hits.append((mask, e, Le, pdf))
        return hits

    def environment_hits(self, d):
        """What escaping rays see of an HDRI world: (emitter, Le, pdf), the
        pdf NEE has for these directions; None for a constant world."""
        world = self._world
        if not world.table.count:
            return None
        return world.base, world.table.map.eval(d), world.table.map.pdf(d)

    def triangle_pdf(self, prim, o, p_hit, ng, n=None, time=None):
        """Solid-angle pdf of NEE picking this emissive triangle's point from o
        (n: the normal ``sample`` had there, as for ``selection_pdf``) at
        the rays' shutter ``time``."""
        return self._surface.table.pdf(prim, o, p_hit, ng, n, time)

    def emitter_of_triangle(self, material):
        return self.mesh_emitter[material]


def _scene_radius(triangles):
    if len(triangles) == 0:
        return 1.0
    lo = triangles.p0.min(axis=0)
    hi = triangles.p0.max(axis=0)
    return max(1.0, 0.5 * float(np.linalg.norm(hi - lo)))
