"""Rays that shader nodes cast from their shading points (Ambient Occlusion,
Bevel), as Cycles' SVM does with KERNEL_FEATURE_NODE_RAYTRACE.

Cycles ray-traces from shaders only while shading the surface a path hit:
the feature is in the node mask of ``integrator_shade_surface``, not in the
masks of light samples (emission evaluated for next-event estimation),
shadow rays or the world.  The integrator therefore hangs a ``NodeRays`` on
the ShadingContext of its surface hits only; every other context has
``rays = None`` and the nodes return what Cycles returns without the
feature (AO 1, the unchanged normal).

Random numbers come from the render's sampler at the path's own address:
branch ``i`` of ``S`` at sample index ``s`` reads sample index ``s * S + i``
(Cycles' ``path_branched_rng_2D``) in a dimension set of its own per
wavefront step and node kind (``node_set``), so a render stays a pure
function of (seed, pixel, sample index) and disjoint sample ranges still
merge exactly.  As in Cycles every node of a kind shares its dimensions.
"""
import threading
import weakref

import numpy as np

from ..accel import Accel
from ..kernels import helper, where

VIS_SHADOW = 16
# Dimension sets: disjoint from the integrator's (1 + 4 step + k, small)
# and from the all-lights sets (bit 30).
AO, BEVEL = 1, 2
_NODE_SETS = 0x20000000
# Surfaces a node ray may pass (other objects', or invisible ones) before
# it counts as having met nothing more.
MAX_CROSSINGS = 16


def node_set(step, which):
    """Dimension-set id of node kind ``which`` (AO, BEVEL) at wavefront step ``step``."""
    return _NODE_SETS | ((int(step) & 0xFFFF) << 4) | which


class NodeRays:
    """What ray-casting nodes need from the renderer for N shading points:
    the scene's ray caster (engine.accel.Accel) and triangles, the sampler,
    the wavefront step and, per point, the sample address (pixel seed and
    sample index, uint32) and what decides ``sharp``: whether the path got
    here without a blurry bounce (Cycles bevels only while min_ray_pdf >= 8).
    Subsets (``take``) only compose row indices: scenes whose nodes cast no
    rays pay nothing for the handle."""

    def __init__(self, accel, triangles, sampler, step, columns, rows=None):
        self.accel = accel
        self.triangles = triangles
        self.sampler = sampler
        self.step = step
        self._columns = columns   # name -> (N,) array of the whole batch
        self._rows = rows

    @classmethod
    def of_paths(cls, ctx, paths, step):
        """The handle for the surface hits of ``paths`` at wavefront step
        ``step`` (engine.integrator's Context and Paths)."""
        return cls(ctx.accel, ctx.triangles, ctx.sampler, step,
                   {"pseed": paths.pseed, "sample": paths.sample, "bounce": paths.bounce,
                    "prev_delta": paths.prev_delta, "prev_pdf": paths.prev_pdf})

    @classmethod
    def of_samples(cls, accel, triangles, sampler, pseed, sample, step=0, sharp=True):
        """A handle for points at explicit sample addresses (tests, tools):
        ``sharp`` True as at camera hits, False as after a diffuse bounce."""
        n = len(pseed)
        return cls(accel, triangles, sampler, step,
                   {"pseed": np.asarray(pseed, np.uint32), "sample": np.asarray(sample, np.uint32),
                    "bounce": np.zeros(n, np.int32) if sharp else np.ones(n, np.int32),
                    "prev_delta": np.zeros(n, bool), "prev_pdf": np.zeros(n)})

    def _column(self, name):
        value = self._columns[name]
        return value if self._rows is None else value[self._rows]

    def take(self, rows):
        rows = np.asarray(rows)
        rows = np.flatnonzero(rows) if rows.dtype == bool else rows
        return NodeRays(self.accel, self.triangles, self.sampler, self.step, self._columns,
                        rows if self._rows is None else self._rows[rows])

    @property
    def sharp(self):
        """Ember keeps the last bounce's pdf, not the path's minimum: a path
        is sharp at its camera hit and after a delta or narrow (pdf >= 8)
        bounce."""
        return (self._column("bounce") == 0) | self._column("prev_delta") | (self._column("prev_pdf") >= 8.0)

    # -- random numbers --------------------------------------------------------

    def uniforms(self, which, branches):
        """(N, branches, 2) values of branch i at sample index s * branches + i."""
        pseed, sample = self._column("pseed"), self._column("sample")
        n = len(pseed)
        index = (sample.astype(np.uint64)[:, None] * np.uint64(branches)
                 + np.arange(branches, dtype=np.uint64)[None, :])
        index = (index & np.uint64(0xFFFFFFFF)).astype(np.uint32).reshape(-1)
        u = self.sampler.get(np.repeat(pseed, branches), index, node_set(self.step, which))
        return u[:, :2].reshape(n, branches, 2)

    # -- objects ---------------------------------------------------------------

    def instance_of(self, prim):
        """Scene instance (Cycles' object) of each triangle."""
        return self.triangles.shading.instance[prim]

    def outward_normal(self, prim):
        """Geometric normals of triangles as Cycles' bevel reads them: the
        winding's, flipped back for mirrored (negative-scale) instances."""
        shading = self.triangles.shading
        mirrored = getattr(shading, "_mirrored", None)
        if mirrored is None:
            det = np.linalg.det(shading.matrix[:, :3, :3]) if len(shading.matrix) else np.zeros(0)
            mirrored = det < 0
            shading._mirrored = mirrored
        flip = np.where(mirrored[self.instance_of(prim)], -1.0, 1.0)
        return self.triangles.ng[prim] * flip[:, None]

    # -- ray casting -------------------------------------------------------------

    def local_hits(self, o, d, tmax, instance, first_only=False):
        """Hits on the surfaces of object ``instance[ray]`` alone along the
        segments o + t d, 0 < t < tmax (Cycles' scene_intersect_local: the
        object's own BVH, so other objects, even coincident ones, are not
        seen).  Returns (rows, prim, t, bu, bv) of every hit (the first per
        ray with first_only); t in units of |d|."""
        found = []
        for inst in np.unique(instance):
            rows = np.nonzero(instance == inst)[0]
            accel, prims = local_accel(self.accel, self.triangles, int(inst))
            r, prim, t, bu, bv = self.hits(o[rows], d[rows], tmax[rows], None, first_only, accel)
            found.append((rows[r], prims[prim], t, bu, bv))
        return _joined(found)

    def hits(self, o, d, tmax, accept, first_only=False, accel=None):
        """Hits along the segments o + t d, 0 < t < tmax, that ``accept(rows,
        prim)`` takes (all with accept None); other surfaces are passed
        through.  Returns (rows, prim, t, bu, bv) of every accepted hit (the
        first per ray with first_only).  t is in units of |d|.  ``accel``:
        another ray caster (an object's own), whose prims are returned."""
        accel = accel or self.accel
        rows = np.arange(len(o))
        t0 = np.zeros(len(o))
        found = []
        for _ in range(MAX_CROSSINGS):
            if len(rows) == 0:
                break
            t, prim, bu, bv = accel.intersect(o, d, tmax - t0)
            hit = prim >= 0
            rows, o, d, tmax, t0 = rows[hit], o[hit], d[hit], tmax[hit], t0[hit]
            t, prim, bu, bv = t[hit], prim[hit], bu[hit], bv[hit]
            took = np.ones(len(rows), bool) if accept is None else accept(rows, prim)
            found.append((rows[took], prim[took], t0[took] + t[took], bu[took], bv[took]))
            go = ~took if first_only else np.ones(len(rows), bool)
            # On from just past the surface (to the side the ray leaves).
            p = o + d * t[:, None]
            start = accel.offset_origin(p, accel.triangles.ng[prim], d)
            dd = np.einsum("ij,ij->i", d, d)
            t_start = t0 + np.einsum("ij,ij->i", start - o, d) / np.where(dd > 0, dd, 1.0)
            go &= t_start < tmax
            rows, o, d, tmax, t0 = rows[go], start[go], d[go], tmax[go], t_start[go]
        return _joined(found)

    def blocked(self, o, d, tmax, instance=None):
        """Whether each segment meets a surface: of object ``instance[ray]``
        only (Cycles' scene_intersect_local), else any surface visible to
        shadow rays (an opaque shadow ray: transparency is not looked at)."""
        out = np.zeros(len(o), bool)
        if instance is not None:
            out[self.local_hits(o, d, tmax, instance, first_only=True)[0]] = True
            return out
        if self.triangles.visibility is None:
            return self.accel.occluded(o, d, tmax)
        vis = self.triangles.visibility
        out[self.hits(o, d, tmax, lambda rows, prim: (vis[prim] & VIS_SHADOW) != 0, first_only=True)[0]] = True
        return out


def _joined(found):
    if not found:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), np.zeros(0, np.int64), empty, empty, empty
    return tuple(np.concatenate([f[k] for f in found]) for k in range(5))


class _Part:
    """The triangles of one object, as engine.accel.Accel reads them."""

    def __init__(self, triangles, prims):
        self.p0, self.e1, self.e2 = triangles.p0[prims], triangles.e1[prims], triangles.e2[prims]
        self.ng = triangles.ng[prims]

    def __len__(self):
        return len(self.p0)

    def corners_float32(self):
        v = np.empty((len(self.p0), 3, 3), dtype=np.float32)
        v[:, 0], v[:, 1], v[:, 2] = self.p0, self.p0 + self.e1, self.p0 + self.e2
        return v


def _by_instance(triangles):
    """Triangle indices sorted by instance, and where each instance starts."""
    instance = triangles.shading.instance
    order = np.argsort(instance, kind="stable")
    count = int(instance.max()) + 2 if len(instance) else 1
    starts = np.searchsorted(instance[order], np.arange(count))
    return order, starts


_LOCAL = weakref.WeakKeyDictionary()   # scene Accel -> {instance: (Accel, global prims)}
_LOCAL_LOCK = threading.Lock()


def local_accel(accel, triangles, instance):
    """A ray caster of one object's triangles (built once per scene and
    object, shared by the render's threads) and their global indices."""
    with _LOCAL_LOCK:
        per_scene = _LOCAL.setdefault(accel, {})
        entry = per_scene.get(instance)
        if entry is None:
            order, starts = per_scene.get("order") or per_scene.setdefault("order", _by_instance(triangles))
            prims = order[starts[instance]:starts[instance + 1]]
            entry = (Accel(_Part(triangles, prims)), prims)
            per_scene[instance] = entry
    return entry


# ----------------------------------------------------------------------------
# shared geometry helpers

def make_orthonormals(n):
    """Cycles' make_orthonormals on rows n: (a, b), a = ``orthonormal_a``,
    b = n x a."""
    a = np.stack(orthonormal_a(n[:, 0], n[:, 1], n[:, 2]), axis=1)
    return a, np.cross(n, a)


@helper
def orthonormal_a(nx, ny, nz):
    """make_orthonormals' a = normalize((1, 1, 1) x n) (or (-1, 1, 1) x n
    when n is along the diagonal), per component: for arrays and inside
    compiled kernels (textures.bump_steps)."""
    diagonal = (nx == ny) & (nx == nz)
    ax = nz - ny
    ay = where(diagonal, nx + nz, nx - nz)
    az = where(diagonal, -ny - nx, ny - nx)
    length = np.sqrt(ax * ax + ay * ay + az * az)
    length = where(length > 0, length, 1.0)
    return ax / length, ay / length, az / length


def concentric_disk(u1, u2):
    """Shirley-Chiu concentric map of [0, 1)^2 to the unit disk."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    first = np.abs(a) > np.abs(b)
    safe_a = np.where(a != 0, a, 1.0)
    safe_b = np.where(b != 0, b, 1.0)
    r = np.where(first, a, b)
    phi = np.where(first, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    r = np.where((a == 0) & (b == 0), 0.0, r)
    return r * np.cos(phi), r * np.sin(phi)
