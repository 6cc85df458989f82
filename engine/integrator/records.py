"""The records the bounce's stages pass each other (struct of arrays, one
row per path), each with one ``take(rows)``.

``Paths``: the state a path carries from bounce to bounce.  ``RayHits``:
what each path's ray met (the closest triangle it may see and the analytic
lights before it).  ``Hit``: the surface point.  ``Vertex``: a hit that
scatters, with its shading frame, its lobes and their wo-only weights.
``LightSample`` and ``ShadowBatch``: one round of next-event estimation
and the shadow rays it needs.
"""
from dataclasses import dataclass, replace

import numpy as np

from ..rows import rows_of, take_arrays, take_rows
from ..vec import to_local, to_world


@dataclass
class Paths:
    pix: np.ndarray
    o: np.ndarray
    d: np.ndarray
    tmax: np.ndarray
    beta: np.ndarray
    L: np.ndarray
    prev_pdf: np.ndarray
    prev_delta: np.ndarray
    # The previous path vertex and its normal as the light tree reads it
    # (N, 4: stages.tree_normals): the tree's selection probability at that
    # vertex weighs emitters hit by MIS.
    prev_p: np.ndarray
    prev_n: np.ndarray
    # NEE sampled every light at the previous vertex (light selection
    # 'auto' at a glossy vertex): its selection probability is 1 there; or
    # resampled its light candidates ('ris'): stages.resampled_mis_pmf.
    prev_every: np.ndarray
    # VIS_* bit of the ray: camera, or the kind of the bounce that cast it
    # (tracked only when something in the scene is invisible to some rays).
    ray: np.ndarray
    # Where the ray's straight line started (the last vertex; transparent
    # passes move o, not this): lights hit are weighed by MIS from here.
    mis_o: np.ndarray
    bounce: np.ndarray    # vertices scattered so far (0 = camera ray)
    tbounce: np.ndarray   # transparent surfaces passed so far
    # The sample's address for the sampler: pixel scramble seed and sample
    # index (uint32), so every random number is fixed by (seed, pixel,
    # sample index, dimension), whatever the batching.
    pseed: np.ndarray
    sample: np.ndarray
    aux: np.ndarray       # (N, k) per-path state of the extra passes (k = 0 without)
    # Bounces so far by Cycles' kind (KIND_DIFFUSE, KIND_GLOSSY,
    # KIND_TRANSMISSION columns), for the per-kind limits and the Light Path
    # node's depths; (N, 0) when neither needs them.
    kinds: np.ndarray
    # The smallest pdf of the path's non-singular bounces (inf: none yet),
    # Cycles' min_ray_pdf: Filter Glossy blurs by it.
    min_pdf: np.ndarray
    # Volumes (engine/media): the materials whose media the path is in,
    # (N, STACK_SIZE) with -1 for empty slots, or (N, 0) in a scene without
    # volumes; and its scattering events in volumes so far.
    stack: np.ndarray
    vbounce: np.ndarray
    # Subsurface scattering (integrator/subsurface.py): the triangle of the
    # exit point the ray leads to (-1: none; -2: being shaded this bounce)
    # and its barycentrics and distance (N, 3).
    exit_prim: np.ndarray
    exit_hit: np.ndarray
    # The instance of the previous vertex (-1: the camera), for light linking.
    prev_inst: np.ndarray
    # Shadow catcher (catcher.py): 0 a matte path (no catcher met yet), 1 the
    # main path after the split, 2 the catcher path (sees catchers only).
    catcher: np.ndarray
    # Motion blur: the sample's time over the shutter, (N, 1) in [0, 1], or
    # (N, 0) in a still scene (engine.motion.path_time).
    time: np.ndarray
    # A diffuse bounce happened on the way (Cycles' PATH_RAY_DIFFUSE_ANCESTOR:
    # Christensen-Burley is a diffuse lobe after one); tracked with subsurface only.
    diffuse_ancestor: np.ndarray
    # The curve segment's row the ray leaves (-1: none, or not a curve): its
    # hits are passed (Accel.intersect_skipping, Cycles' self-intersection rule).
    self_prim: np.ndarray
    # Light selection 'tree_bsdf': the previous vertex's glossy-lobe terms
    # (stages.lobe_terms), for the tree's selection pdf in MIS; (N, 5).
    prev_lobe: np.ndarray
    # Ray Portal BSDF (engine/lobes/ray_portal.py): portals passed so far
    # (Cycles' portal_bounce, the Light Path node's Portal Depth), and
    # whether the ray left one since the last vertex: Cycles sets
    # PATH_RAY_MIS_SKIP, so emitters it finds count whole, as after a
    # singular bounce (prev_delta keeps the last vertex's own kind).
    portal: np.ndarray
    mis_skip: np.ndarray
    # Cycles' compact ray differentials (N, 2): the footprint's radius at
    # mis_o (the ray's dP) and its growth per unit length (the camera ray's
    # dD, kept at bounces as Cycles keeps ray->dD); NaN: none (a bake's
    # texels).  A hit's footprint is stages.footprint.
    spread: np.ndarray
    # Volume scattering probability guiding (volume_guide.py): (N, COLUMNS)
    # where the film guides camera rays in media, else (N, 0).
    guide: np.ndarray
    # The previous vertex took its direct light from its volume segment's
    # light selection (LightSet.select_segment): the segment's length
    # (prev_p its start, prev_n[:, :3] its direction), for the selection pdf
    # in MIS; negative: the vertex's own selection at prev_p.
    prev_seg: np.ndarray
    # Path guiding (path_guide.py): the last guided vertices' records,
    # (N, path_guide.COLUMNS) where the tile trains the guide, else (N, 0).
    guide_path: np.ndarray

    def __len__(self):
        return len(self.pix)

    def take(self, keep):
        """The paths where ``keep`` (a mask or indices).  np.take with
        indices copies rows 4-5x faster than boolean indexing."""
        idx = rows_of(keep)
        return Paths(*(take_rows(getattr(self, f), idx) for f in self.__dataclass_fields__))

    def finish_rows(self, keep):
        """Pixel, radiance and sample index of the paths where ``keep``: all
        that ending a path needs."""
        idx = rows_of(keep)
        return np.take(self.pix, idx), np.take(self.L, idx, axis=0), np.take(self.sample, idx)

    def concat(self, *others):
        parts = (self,) + others
        return Paths(*(np.concatenate([getattr(p, f) for p in parts]) for f in self.__dataclass_fields__))


@dataclass
class RayHits:
    """What each path's ray meets before its tmax: the closest triangle
    visible to the ray's kind (prim -1: none; Embree's float32 t and
    barycentrics) and whether an analytic light comes first (its LightSet
    index, radiance and MIS pdf)."""
    t: np.ndarray
    prim: np.ndarray
    bu: np.ndarray
    bv: np.ndarray
    light: np.ndarray
    emitter: np.ndarray
    Le: np.ndarray
    pdf: np.ndarray
    light_t: object = None   # the light's distance along the ray (from Paths.mis_o with transparent shadows)

    @property
    def surface(self):
        """(t, prim, bu, bv): what the surface stages read."""
        return self.t, self.prim, self.bu, self.bv

    def take(self, keep):
        return take_arrays(self, keep)


@dataclass
class Hit:
    """Surface interaction at the closest hit, in world space."""
    p: np.ndarray
    ng: np.ndarray   # geometric normal facing the incoming ray
    ns: np.ndarray   # shading normal on the same side
    wo: np.ndarray
    mat: np.ndarray
    prim: np.ndarray
    eps: np.ndarray  # ray-origin offset for this point
    uv: np.ndarray   # (N, 2) interpolated texture coordinates (0 without UVs)
    # For normal maps: interpolated world tangent (N, 3) and bitangent sign
    # (N,), or None; back: the ray hit the triangle's back face.
    tangent: object = None
    tangent_sign: object = None
    back: object = None
    # For shader nodes (engine.nodes.ShadingContext): barycentrics (N, 2),
    # bounces before this hit and the VIS_* bit of the ray that found it.
    bary: object = None
    depth: object = None
    ray: object = None
    # The Light Path node's path columns (nodes.context.PATH_COLUMNS), only
    # when some material reads that node (Context.light_path).
    path: object = None
    # Curves (points.Strands): the strand's tangent dC/du (N, 3) at curve hits,
    # zero elsewhere; None without curves.  The shading frame's x on strands.
    fibre: object = None
    # The ray footprint's radius at the points (Cycles' compact sd->dP), the
    # bump's differentials; None without (engine.textures._has_footprint).
    dp: object = None
    # The ShadingContext of these points, made on first use
    # (ShadingContext.of_hit); a taken Hit makes its own.
    shading: object = None

    def take(self, keep):
        return replace(take_arrays(self, keep), shading=None)


@dataclass
class Vertex:
    """A path vertex that scatters: the hit (its ``ns`` the shading normal
    after normal maps and bump), the shading frame (tt, bb, ns), the
    direction to the viewer in that frame, the lobes and their weights and
    selection probabilities, which depend on wo only and so serve light
    sampling and BSDF sampling alike."""
    hit: Hit
    tt: np.ndarray
    bb: np.ndarray
    wo_l: np.ndarray
    lobes: object        # bsdf.Lobes
    weights: np.ndarray  # (N, K, 3) bsdf.weights
    selection: np.ndarray  # (N, K) bsdf.selection
    # Rows of the batch's paths these vertices are (None: all, in order):
    # set on the row subsets light sampling makes.
    path_rows: object = None
    # The kind of the OWN_WEIGHT lobe that drew each BSDF sample (NONE:
    # another lobe; None: not recorded), set by stages.scatter.
    sampled_labels: object = None
    # (N, 4) stages.tree_normals, made on first use: light selection, the
    # candidates' selection and the next bounce's MIS all read it.
    tree_n: object = None
    # Path guiding at these vertices (path_guide.GuideAt; None: none) and,
    # once scatter sampled, the BSDF's own pdf of each row's direction.
    guide: object = None
    bsdf_pdf: object = None

    def __len__(self):
        return len(self.wo_l)

    @property
    def lobes_wo(self):
        """(selection, weights): the per-vertex arguments of bsdf.eval_pdf and bsdf.sample."""
        return self.selection, self.weights

    def local(self, v):
        return to_local(v, self.tt, self.bb, self.hit.ns)

    def world(self, v_l):
        return to_world(v_l, self.tt, self.bb, self.hit.ns)

    def take(self, rows):
        """The vertices ``rows`` (indices), remembering which paths they are."""
        n = len(self)
        return Vertex(RowView(self.hit, rows, n), self.tt[rows], self.bb[rows], self.wo_l[rows],
                      take_arrays(self.lobes, rows, n), self.weights[rows], self.selection[rows],
                      rows if self.path_rows is None else self.path_rows[rows],
                      tree_n=None if self.tree_n is None else self.tree_n[rows],
                      guide=None if self.guide is None else self.guide.take(rows))


@dataclass
class LightSample:
    """One light sample at each of N vertices (one emitter each): the
    direction (world and shading frame), the BSDF's value there, the MIS
    weight, whether the light is a delta light (per vertex, or one bool for
    all) and the radiance it brings if unblocked (0 where it brings none)."""
    emitter: np.ndarray
    wi: np.ndarray
    wi_l: np.ndarray
    f: np.ndarray
    w: np.ndarray
    delta: np.ndarray
    contrib: np.ndarray


@dataclass
class ShadowBatch:
    """The shadow rays of one LightSample: ``rows`` are the sampled
    vertices whose sample brings light (one ray each), with the ray, its
    emitter, and, once traced, the vertices the light reached (``free``,
    a subset of rows) and what it added there (``added``, per free row)."""
    at: Vertex
    sample: LightSample
    rows: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    tmax: np.ndarray
    free: object = None
    added: object = None
    skip: object = None   # (len(rows),) the curve row each ray leaves and passes (-1: none), or None


class RowView:
    """The rows ``rows`` of an object's per-row arrays, each taken when
    first read (light sampling reads a few of the path's and hit's dozen)."""

    def __init__(self, obj, rows, n):
        self._obj, self._rows, self._n = obj, rows, n   # n: the object's row count

    def __getattr__(self, name):
        value = getattr(self._obj, name)
        if isinstance(value, np.ndarray) and value.ndim and len(value) == self._n:
            value = take_rows(value, self._rows)
        setattr(self, name, value)
        return value
