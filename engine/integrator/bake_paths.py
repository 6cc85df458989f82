"""Light bakes: paths that start at the texels of a baked object instead of
at a camera (Cycles' kernel/integrator/init_from_bake.h), and the closure
filter Cycles applies to them (scene/integrator.cpp filter_closures,
surface_shader_prepare_closures, integrator_intersect_skip_lights).

``BakeTarget`` stands in for the camera: the film has one pixel per baked
texel, ``generate`` puts each sample at the texel's point (sample 0 at its
centre, later samples jittered across the texel by Blender's barycentric
differentials, mirrored at the triangle's edges as Cycles does) and hands
the integrator the first hit directly (no ray is traced to find it), seen
along the shading normal: the ray comes from P + N towards -N.

``BakeFilter`` is what Blender's pass filter leaves on: at vertex 0 only the
lobes of the kept light classes scatter (a glass lobe stays while glossy or
transmission does; subsurface stays as Cycles never filters a BSSRDF unless
the bake is of another class's pass; transparent lobes absorb: the bake
sees the object itself); without Combined's Emit no surface a path meets
emits (Cycles zeroes the emission at every surface, not only the baked one,
while light sampling still reaches emissive meshes: so does Ember), and a
Diffuse / Glossy / Transmission bake leaves out the texel's own emission
(not in the class's pass) but keeps the others';
and without Direct light vertex 0 samples no light and its BSDF rays see no
lamp and no world (the emissive meshes they meet still count, as Cycles).
Without Indirect the render stops at max_bounces 0 (engine/bake.py).
"""
from dataclasses import dataclass, replace

import numpy as np

from .. import bsdf
from ..lobe_ids import GLASS, NONE, SUBSURFACE_BURLEY, SUBSURFACE_RANDOM_WALK, SUBSURFACE_SKIN
from ..lobes import kinds_of_class
from .records import RayHits

CLASSES = ("diffuse", "glossy", "transmission")


@dataclass(frozen=True)
class BakeFilter:
    classes: tuple = CLASSES     # light classes whose lobes scatter at vertex 0
    emission: bool = True        # emission of the surfaces paths meet (Combined's Emit)
    direct: bool = True          # light sampled at vertex 0 / met by its BSDF rays
    subsurface: bool = True      # subsurface lobes scatter at vertex 0
    texel_emission: bool = True  # the baked surface's own emission (vertex 0)
    # Which of a glass lobe's events count at vertex 0: +1 its reflection
    # (a Glossy bake), -1 its refraction (a Transmission bake), 0 both.
    glass_side: int = 0

    def emits(self, depth):
        """Whether surface emission met at wavefront step ``depth`` counts."""
        return self.emission and (depth > 0 or self.texel_emission)

    def dropped_kinds(self):
        """Lobe kinds that do not scatter at vertex 0."""
        keep = set()
        for name in self.classes:
            keep.update(kinds_of_class(name))
        if "glossy" in self.classes or "transmission" in self.classes:
            keep.add(GLASS)
        subsurface = {SUBSURFACE_RANDOM_WALK, SUBSURFACE_SKIN, SUBSURFACE_BURLEY}
        keep = (keep - subsurface) | (subsurface if self.subsurface else set())
        every = set(kinds_of_class("diffuse") + kinds_of_class("glossy") + kinds_of_class("transmission")
                    + kinds_of_class("transparent"))
        return tuple(sorted(every - keep))


class BakeTarget:
    """The texels of one baked instance as the render's camera.
    ``scene_rows``: each texel's triangle as a row of the scene's triangles
    before flattening (the instance's first row + its mesh triangle),
    ``u, v``: Blender's barycentrics (corner weights u, v, 1 - u - v),
    ``diff``: (N, 4) Blender's BakeDifferential (du/dx, du/dy, dv/dx, dv/dy)
    or None (every sample at the texel's centre).  After ``bind``,
    ``valid`` says which texels kept their triangle (flatten drops
    degenerate ones; the others are traced on row 0 and must be ignored).
    ``rejection``: jitter as Cycles 3.5+ (retried until inside the triangle),
    else as before (mirrored back at its edges)."""

    def __init__(self, scene_rows, u, v, diff=None, bake_filter=BakeFilter(), rejection=True):
        self.scene_rows = np.asarray(scene_rows, np.int64)
        self.rows = np.zeros(len(self.scene_rows), np.int64)
        self.valid = np.ones(len(self.scene_rows), bool)
        self.u = np.asarray(u, np.float64)
        self.v = np.asarray(v, np.float64)
        self.diff = None if diff is None else np.asarray(diff, np.float64)
        self.filter = bake_filter
        self.rejection = bool(rejection)
        self.width, self.height = len(self.scene_rows), 1
        self.tris = None
        self._dropped = bake_filter.dropped_kinds()
        # What the integrator reads of a camera beside generate (depth AOV, media).
        self.forward = np.array([0.0, 0.0, -1.0])
        self.pos = np.zeros(3)
        self.cam = type("BakeLens", (), {"clip_start": 0.0})()

    def bind(self, tris):
        """Attach the flattened triangles (engine.render.prepare)."""
        rows = self.scene_rows
        if tris.kept is not None:
            row_of = np.where(tris.kept, np.cumsum(tris.kept) - 1, -1)
            rows = row_of[rows]
        self.valid = rows >= 0
        self.rows = np.where(self.valid, rows, 0)
        self.tris = tris
        return self

    def generate(self, pix, u0, u1, sample):
        """(o, d, tmax, RayHits) of the samples ``sample`` of texels ``pix``."""
        u, v = self.u[pix], self.v[pix]
        if self.diff is not None:
            jitter = np.asarray(sample) > 0
            d = self.diff[pix]
            if self.rejection:
                u, v = _jitter_inside(u, v, d, jitter, u0, u1)
            else:
                fx = np.where(jitter, u0, 0.5) - 0.5
                fy = np.where(jitter, u1, 0.5) - 0.5
                u = np.where(jitter, _mirror(u + d[:, 0] * fx + d[:, 1] * fy, 1.0), u)
                v = np.where(jitter, _mirror(v + d[:, 2] * fx + d[:, 3] * fy, 1.0 - u), v)
        k = self.rows[pix]
        bu, bv = v, 1.0 - u - v          # Blender's (u, v) -> Embree's
        tr = self.tris
        p = tr.p0[k] + bu[:, None] * tr.e1[k] + bv[:, None] * tr.e2[k]
        if tr.ns is not None:
            w = np.stack([1.0 - bu - bv, bu, bv], axis=1)
            ns = np.einsum("nc,ncj->nj", w, tr.ns[k])
        else:
            ns = np.array(tr.ng[k], np.float64)
        ns = ns / np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-30)
        n = len(pix)
        o, d = p + ns, -ns
        first = RayHits(np.ones(n), k, bu, bv, np.zeros(n, bool), np.full(n, -1, np.int64), np.zeros((n, 3)),
                        np.zeros(n), np.full(n, np.inf))
        return o, d, np.full(n, np.inf), first

    def filter_weights(self, lobes, w):
        """Zero the effective colours of the lobes that do not scatter at
        vertex 0 (after the layering that dims lobes below them, which
        Cycles applies when it builds the closures)."""
        if not self._dropped:
            return w
        drop = bsdf.kind_in(lobes.kind, self._dropped)
        if drop.any():
            w = np.where(drop[:, :, None], 0.0, w)
        return w


    def glass_f(self, v, wi_l, f, first):
        """f of the vertices ``v`` towards wi_l without the glass lobes'
        part on the side the bake's pass does not count, at the vertices 0
        (``first``): Cycles keeps the glass closure but counts its light as
        glossy above the closure's normal and as transmission below
        (film/light_passes.h bsdf_eval_init), as the render's passes."""
        rows = self._glass_rows(v, wi_l, first)
        if len(rows) == 0:
            return f
        f = np.array(f, copy=True)
        f[rows] = np.maximum(f[rows] - self._glass_part(v, wi_l, rows), 0.0)
        return f

    def glass_weight(self, v, wi_l, weight, delta, first):
        """The BSDF samples' weights (f / pdf) of ``v`` with glass_f's rule:
        a sample on the side left out keeps only the other lobes' share of
        f; a delta one there (a smooth glass lobe's) brings nothing."""
        rows = self._glass_rows(v, wi_l, first)
        if len(rows) == 0:
            return weight
        weight = np.array(weight, copy=True)
        delta = np.broadcast_to(np.asarray(delta, bool), (len(wi_l),))
        smooth = rows[delta[rows]]
        weight[smooth] = 0.0
        rows = rows[~delta[rows]]
        if len(rows):
            sub = v.take(rows)
            f = bsdf.eval_pdf(sub.lobes, sub.wo_l, wi_l[rows], *sub.lobes_wo)[0]
            rest = np.maximum(f - self._glass_part(v, wi_l, rows), 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                weight[rows] *= np.where(f > 0, rest / np.where(f > 0, f, 1.0), 0.0)
        return weight

    def _glass_rows(self, v, wi_l, first):
        side = self.filter.glass_side
        if side == 0:
            return np.zeros(0, np.int64)
        left_out = (wi_l[:, 2] < 0) if side > 0 else (wi_l[:, 2] > 0)
        has_glass = (v.lobes.kind == GLASS).any(axis=1)
        return np.flatnonzero(first & left_out & has_glass)

    def _glass_part(self, v, wi_l, rows):
        """(R, 3) the glass lobes' f at rows of ``v`` (their effective colours)."""
        sub = v.take(rows)
        kind = np.where(sub.lobes.kind == GLASS, sub.lobes.kind, NONE).astype(sub.lobes.kind.dtype)
        glass = replace(sub.lobes, kind=kind)
        return bsdf.eval_pdf(glass, sub.wo_l, wi_l[rows], *sub.lobes_wo)[0]


def _jitter_inside(u, v, d, jitter, r0, r1, tries=10):
    """Cycles' bake_jitter_barycentric (3.5+): the texel's (u, v) moved by
    its differentials d times (r - 0.5), retried with r hashed
    (hash_float2_to_float2) until inside the triangle, the centre after
    ``tries`` misses; rows not ``jitter`` stay at the centre."""
    from ..nodes.hashing import hash_to_float2
    u, v = np.array(u, np.float64), np.array(v, np.float64)
    todo = np.flatnonzero(jitter)
    r = np.stack([np.asarray(r0, np.float64)[todo], np.asarray(r1, np.float64)[todo]], axis=1)
    for _ in range(tries):
        if len(todo) == 0:
            break
        fx, fy = r[:, 0] - 0.5, r[:, 1] - 0.5
        ju = u[todo] + fx * d[todo, 0] + fy * d[todo, 1]
        jv = v[todo] + fx * d[todo, 2] + fy * d[todo, 3]
        inside = (ju > 0) & (jv > 0) & (ju + jv < 1)
        u[todo[inside]], v[todo[inside]] = ju[inside], jv[inside]
        todo, r = todo[~inside], r[~inside]
        r = hash_to_float2(r[:, 0].astype(np.float32), r[:, 1].astype(np.float32)).astype(np.float64)
    return u, v


def _mirror(x, top):
    """Cycles' bake_clamp_mirror_repeat: x mirrored back into [0, top]."""
    top = np.maximum(top, 1e-30)
    x = x / top
    f = np.floor(x)
    x = x - f
    return np.where(f.astype(np.int64) & 1, 1.0 - x, x) * top
