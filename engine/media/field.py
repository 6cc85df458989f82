"""Heterogeneous media: a material's volume coefficients given by its node
tree (texture expressions of engine.scene), evaluated at points inside the
object, and the majorant grid over the object's bounds that the null-
scattering trackers (tracking.py) sample against.

A ``Field`` is one material's medium inside one instance: Object
coordinates are that instance's inverse matrix times the point, Generated
its mesh's texture space applied to them (Cycles' generated transform in a
volume), so two objects of one smoke material see their own coordinates.

The majorant grid (Cycles 5.0 builds an octree the same way, bvh/octree.cpp:
the density shader evaluated over the object's bounding box) has GRID^3
cells in object space; each holds MARGIN x the largest extinction (max over
colour channels) found at the (LATTICE + 1)^3 lattice points of the cell,
and at least FLOOR x the object's largest one.  A cell whose true extinction
exceeds its majorant is no bias: the trackers' null weights
(sigma_maj - sigma_t) / sigma_maj may go negative (weighted tracking), and
the floor keeps every cell's collision rate positive.  Points outside the
grid's box are outside the object: the medium there is empty.

A fluid domain's medium also carries the object's voxel grids (voxels.py),
which its node tree reads by name (Attribute nodes, Principled Volume's
Density / Color / Temperature attributes).  The lattice that builds the
majorant grid reads them max-filtered over the lattice spacing, so for a
node tree that grows with its grids (density x a constant, the usual
case) each cell's majorant bounds every voxel lookup inside it.

Evaluated coefficients are made renderable as Cycles' closures do: NaN is 0,
negative densities are 0 (fmaxf(density, 0)), and values past SIGMA_MAX
(1/m) are SIGMA_MAX; each kind of repair is named in a warning with the
material.  Emission may be negative (as in Cycles: a blackbody below about
1500 K in blue, a negative Emission colour), only its NaN and magnitudes
past SIGMA_MAX repaired.  A textured Henyey-Greenstein g is clamped to
[-1, 1], NaN read as 0 (named).
"""
import numpy as np

from .. import kernels
from ..geometry import corner_bounds
from ..nodes import ShadingContext
from ..nodes.context import texture_space
from ..textures import Compiler, is_texture
from .voxels import Voxels

FIELDS = ("absorption", "scattering", "emission")
EMISSION = 2    # FIELDS' index of the emission (signed)
GRID = 16
LATTICE = 2
MARGIN = 1.25
FLOOR = 1e-3
FLOOR_DEPTH = 100.0
EMISSIVE_RATE = 16.0
SIGMA_MAX = 1e8
# The world medium beyond its grid's box: absorbing at once (1/m).
OPAQUE = SIGMA_MAX
# A majorant holds along the ray for STEP cells along each axis (the
# segment's bounding box spans at most STEP + 1 cells per axis).
STEP = 3


def is_heterogeneous(volume):
    """A medium with a textured coefficient or a textured anisotropy (its
    g varies per point: the trackers evaluate it where paths scatter)."""
    return volume is not None and (any(is_texture(getattr(volume, f)) for f in FIELDS)
                                   or is_texture(getattr(volume, "anisotropy", 0.0)))


class Field:
    """The medium of material ``material`` inside scene instance ``instance``."""

    def __init__(self, material, name, volume, matrix, mesh, tri, tris, compiler, voxels=None, density=1.0):
        self.material, self.name = material, name
        self.voxels = voxels
        self.fns = [_scaled(compiler.color(getattr(volume, f)), density) for f in FIELDS]
        g = getattr(volume, "anisotropy", 0.0)
        self.g_fn = compiler.compile(g)[0] if is_texture(g) else None
        self.g = 0.0 if self.g_fn is not None else float(g)
        m = np.asarray(matrix, np.float64).reshape(4, 4)
        self.matrix = m
        self.inverse = np.linalg.inv(m) if np.isfinite(m).all() and abs(np.linalg.det(m[:3, :3])) > 1e-300 \
            else np.eye(4)
        self.loc, self.factor = self._texture_space(mesh)
        pos = np.asarray(mesh.positions, np.float64).reshape(-1, 3)
        lo, hi = pos.min(axis=0), pos.max(axis=0)
        pad = 1e-4 * (hi - lo).max() + 1e-9
        self.lo, self.hi = lo - pad, hi + pad
        self.pad = pad
        self.cell = (self.hi - self.lo) / GRID
        self.tri, self.tris = int(tri), tris
        self.repaired = {"NaN": 0, "negative": 0, "too large": 0, "NaN anisotropy": 0}
        self.evaluated = 0     # points evaluated (statistics)
        self.grid = np.ascontiguousarray(self._majorants(), np.float64)

    @staticmethod
    def _texture_space(mesh):
        return texture_space(mesh)

    # -- coefficients at points -----------------------------------------------
    def context(self, p, d, q=None):
        """A shading context for world points p (N, 3) inside the object,
        the ray travelling along d."""
        n = len(p)
        ctx = ShadingContext(n, self.tris, np.full(n, self.tri, np.int64), None, p, wo=-d)
        ctx.voxels = self.voxels
        q = self.to_object(p) if q is None else q
        ctx._cache["object"] = q
        ctx._cache[("generated",)] = (q - self.loc) * self.factor + 0.5
        return ctx

    def to_object(self, p):
        return p @ self.inverse[:3, :3].T + self.inverse[:3, 3]

    def evaluate(self, p, d, q=None, inside=True):
        """(sigma_a, sigma_s, emission) (N, 3) at world points p (``inside``
        False: the grid's lattice, partly outside the mesh, where a negative
        value is no user error)."""
        return self.evaluate_phase(p, d, q, inside)[:3]

    def evaluate_phase(self, p, d, q=None, inside=True):
        """(sigma_a, sigma_s, emission (N, 3), g (N,)) at world points p:
        the coefficients (``evaluate``) and the Henyey-Greenstein g there
        (a textured one clamped to [-1, 1] as Cycles' closure setup, NaN
        read as 0 and counted), one shading context for both."""
        ctx = self.context(p, d, q)
        self.evaluated += len(p)
        out = tuple(self._renderable(fn(ctx), inside, k == EMISSION) for k, fn in enumerate(self.fns))
        if self.g_fn is None:
            return out + (np.full(len(p), self.g),)
        return out + (self._anisotropy(self.g_fn(ctx), len(p)),)

    def _anisotropy(self, g, n):
        g = np.array(np.broadcast_to(np.asarray(g, np.float64), (n,)))
        nan = np.isnan(g)
        if nan.any():
            self.repaired["NaN anisotropy"] += int(nan.sum())
            g[nan] = 0.0
        return np.clip(g, -1.0, 1.0)

    def _renderable(self, v, inside=True, signed=False):
        """``signed``: the emission, which may be negative as in Cycles (a
        Principled Volume's blackbody below about 1500 K, a negative
        Emission colour): only NaN and magnitudes past SIGMA_MAX repaired."""
        v = np.array(np.broadcast_to(v, (len(v), 3)), np.float64)
        nan = np.isnan(v)
        neg = np.zeros(v.shape, bool) if signed else v < 0
        big = np.abs(v) > SIGMA_MAX if signed else v > SIGMA_MAX
        if nan.any() or neg.any() or big.any():
            self.repaired["NaN"] += int(nan.sum())
            self.repaired["negative"] += int(neg.sum()) if inside else 0
            self.repaired["too large"] += int(big.sum())
            v = np.where(nan | neg, 0.0, np.clip(v, -SIGMA_MAX, SIGMA_MAX))
        return v

    def warning(self):
        bad = [f"{k} ({n} values)" for k, n in self.repaired.items() if n and k != "NaN anisotropy"]
        parts = []
        if bad:
            parts.append("textured volume coefficients " + ", ".join(bad)
                         + f" read as 0 (NaN, negative) or {SIGMA_MAX:g}/m (too large)")
        if self.repaired.get("NaN anisotropy"):
            parts.append(f"NaN anisotropy ({self.repaired['NaN anisotropy']} values) read as 0")
        if not parts:
            return None
        return f"material {self.name!r}: " + "; ".join(parts)

    # -- the majorant grid ----------------------------------------------------
    def _majorants(self):
        k = GRID * LATTICE + 1
        axes = [np.linspace(self.lo[a], self.hi[a], k) for a in range(3)]
        q = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        p = q @ self.matrix[:3, :3].T + self.matrix[:3, 3]
        d = np.tile([0.0, 0.0, 1.0], (len(p), 1))
        ctx = self.context(p, d, q)
        if self.voxels is not None:
            reach = self.voxels.placed_reach((self.hi - self.lo) / (GRID * LATTICE))
            plain = _reach(self.voxels)
            ctx.voxels = self.voxels.dilated({k: reach.get(k, plain) for k in self.voxels.grids})
        raw = [np.broadcast_to(fn(ctx), (len(p), 3)) for fn in self.fns]
        # Negative values inside the mesh's bounds (not on the padded edge)
        # are the texture's own: counted.
        core = np.all((q > self.lo + 0.5 * self.pad) & (q < self.hi - 0.5 * self.pad), axis=1)
        self.repaired["negative"] += int(sum(np.count_nonzero(core[:, None] & (r < 0)) for r in raw[:EMISSION]))
        sa, ss, em = (self._renderable(r, False, j == EMISSION) for j, r in enumerate(raw))
        self.emits = bool(np.any(em != 0))
        v = _cell_max((sa + ss).max(axis=1).reshape(k, k, k))
        self.grid_raw = v
        e = _cell_max(np.abs(em).max(axis=1).reshape(k, k, k))
        top = float(v.max())
        self.max = top
        # The floor: a collision rate in cells that looked empty, at most
        # one per FLOOR_DEPTH object sizes; where the medium emits, at
        # least EMISSIVE_RATE collisions per object size (emission is
        # collected at collisions, also where nothing extinguishes).
        size = max(float(np.linalg.norm((self.hi - self.lo) @ np.abs(self.matrix[:3, :3]).T)), 1e-9)
        grid = np.maximum(MARGIN * v, min(FLOOR * top, 1.0 / (FLOOR_DEPTH * size)))
        if self.emits:
            grid = np.maximum(grid, np.where(e > 0, EMISSIVE_RATE / size, 1.0 / (FLOOR_DEPTH * size)))
        return grid

    def majorant(self, p, d):
        """(mu, dist): a majorant of the medium along the ray from p (N, 3)
        in direction d (unit) for a distance dist: the largest cell
        majorant in the cells of the segment's bounding box, the segment
        reaching at most STEP cells along any axis (and ending where the
        ray leaves the grid's box).  Outside the box mu is 0 and dist the
        distance to it (inf: it is not ahead).  One compiled pass
        (``_majorant_rows``)."""
        q = np.ascontiguousarray(self.to_object(p), np.float64)
        dq = np.ascontiguousarray(d @ self.inverse[:3, :3].T, np.float64)
        mu, dist = np.empty(len(p)), np.empty(len(p))
        _majorant_rows(q, dq, self.lo, self.hi, self.cell, self.grid, mu, dist)
        return mu, dist


def _majorant_numpy(q, dq, lo, hi, cell, grid, mu, dist):
    """The reference form of ``_majorant_rows`` (Field.majorant), rays in
    object space (q, dq)."""
    inside = np.all((q >= lo) & (q < hi), axis=1)
    mu[:] = 0.0
    dist[:] = np.inf
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t0 = (lo - q) / dq
        t1 = (hi - q) / dq
        near = np.max(np.where(np.isnan(t0), -np.inf, np.minimum(t0, t1)), axis=1)
        far = np.min(np.where(np.isnan(t1), np.inf, np.maximum(t0, t1)), axis=1)
        i = np.flatnonzero(inside)
        if len(i):
            reach = STEP * np.min(np.where(dq[i] != 0, cell / np.abs(dq[i]), np.inf), axis=1)
            length = np.minimum(reach, far[i])
            q1 = q[i] + dq[i] * np.where(np.isfinite(length), length, 0.0)[:, None]
            a = np.clip(np.floor((np.minimum(q[i], q1) - lo) / cell), 0, GRID - 1).astype(np.int64)
            b = np.clip(np.floor((np.maximum(q[i], q1) - lo) / cell), 0, GRID - 1).astype(np.int64)
            best = np.zeros(len(i))
            for ox in range(STEP + 1):
                x = np.minimum(a[:, 0] + ox, b[:, 0])
                for oy in range(STEP + 1):
                    y = np.minimum(a[:, 1] + oy, b[:, 1])
                    for oz in range(STEP + 1):
                        z = np.minimum(a[:, 2] + oz, b[:, 2])
                        best = np.maximum(best, grid[x, y, z])
            mu[i] = best
            dist[i] = length
        o = np.flatnonzero(~inside)
        if len(o):
            ahead = (far[o] >= np.maximum(near[o], 0.0)) & (near[o] >= 0)
            dist[o] = np.where(ahead, near[o], np.inf)


@kernels.loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], "
                     "float64[:, :, ::1], float64[::1], float64[::1])", _majorant_numpy)
def _majorant_rows(q, dq, lo, hi, cell, grid, mu, dist):
    nan = np.nan
    for i in range(q.shape[0]):
        inside = True
        near, far, reach = -np.inf, np.inf, np.inf
        for a in range(3):
            inside = inside and q[i, a] >= lo[a] and q[i, a] < hi[a]
            t0 = (lo[a] - q[i, a]) / dq[i, a]
            t1 = (hi[a] - q[i, a]) / dq[i, a]
            # NumPy's rules as the reference's: minimum / maximum / max
            # propagate NaN, a NaN t0 (t1) reads as -inf (inf).
            lo_t = -np.inf if t0 != t0 else (nan if t1 != t1 else min(t0, t1))
            hi_t = np.inf if t1 != t1 else (nan if t0 != t0 else max(t0, t1))
            near = nan if (near != near or lo_t != lo_t) else max(near, lo_t)
            far = nan if (far != far or hi_t != hi_t) else min(far, hi_t)
            if dq[i, a] != 0:
                reach = min(reach, cell[a] / abs(dq[i, a]))
        mu[i] = 0.0
        dist[i] = np.inf
        if inside:
            reach *= STEP
            length = nan if far != far else min(reach, far)
            step = length if np.isfinite(length) else 0.0
            lo_c = np.empty(3, np.int64)
            hi_c = np.empty(3, np.int64)
            for a in range(3):
                q1 = q[i, a] + dq[i, a] * step
                x0 = np.floor((min(q[i, a], q1) - lo[a]) / cell[a])
                x1 = np.floor((max(q[i, a], q1) - lo[a]) / cell[a])
                lo_c[a] = int(min(max(x0, 0.0), GRID - 1.0))
                hi_c[a] = int(min(max(x1, 0.0), GRID - 1.0))
            best = 0.0
            for x in range(lo_c[0], min(lo_c[0] + STEP, hi_c[0]) + 1):
                for y in range(lo_c[1], min(lo_c[1] + STEP, hi_c[1]) + 1):
                    for z in range(lo_c[2], min(lo_c[2] + STEP, hi_c[2]) + 1):
                        best = max(best, grid[x, y, z])
            mu[i] = best
            dist[i] = length
        elif far >= max(near, 0.0) and near >= 0:
            dist[i] = near


class WorldField(Field):
    """The world's textured medium (Cycles' background volume, object
    none): Object and Generated coordinates are the point itself (what
    Cycles 5.0 gives there, measured: a noise over Object, Generated,
    Position or its default coordinates renders alike).  Its majorant grid
    spans ``bounds`` (the scene's geometry, camera and lights, padded);
    beyond them the medium is opaque (rays leaving the box are infinite:
    Cycles' exp(-sigma_t x FLT_MAX) extinguishes them where any density is
    left along the way: its background and distant lights are black
    through world fog, measured) unless the density on the box's faces is
    0 everywhere, when it is empty there."""

    def __init__(self, material, volume, bounds, tris, compiler):
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        box = type("Box", (), {"positions": corners, "texspace": None})()
        self.beyond = 0.0     # the box's own lattice is evaluated without it
        super().__init__(material, "world", volume, np.eye(4), box, 0, tris, compiler)
        self.beyond = OPAQUE if self._faces_extinguish() else 0.0

    @staticmethod
    def _texture_space(mesh):
        """Generated = Object = P: (q - loc) x factor + 0.5 with loc 0.5, factor 1."""
        return np.full(3, 0.5), np.ones(3)

    def _faces_extinguish(self):
        g = self.grid_raw
        return bool(max(g[0].max(), g[-1].max(), g[:, 0].max(), g[:, -1].max(), g[:, :, 0].max(),
                        g[:, :, -1].max()) > 0)

    def evaluate_phase(self, p, d, q=None, inside=True):
        out = super().evaluate_phase(p, d, q, inside)
        if self.beyond > 0:
            q = self.to_object(p) if q is None else q
            out[0][~np.all((q >= self.lo) & (q < self.hi), axis=1)] = self.beyond
        return out

    def majorant(self, p, d):
        mu, dist = super().majorant(p, d)
        if self.beyond > 0:
            q = self.to_object(p)
            out = ~np.all((q >= self.lo) & (q < self.hi), axis=1)
            mu[out], dist[out] = self.beyond, np.inf
        return mu, dist


def scene_bounds(scene, tris):
    """(lo, hi) of the scene's triangles, points, curves, camera and positioned lights,
    padded by a tenth of the diagonal and the camera's orthographic scale
    (rays start across it)."""
    pts = [np.asarray(scene.camera.matrix, np.float64)[:3, 3][None, :]]
    corners = corner_bounds(tris) if tris is not None and len(tris) else None
    if corners is not None:
        pts += [corners[0][None, :], corners[1][None, :]]
    # Point clouds and curves (their object-space points placed, grown by their largest radius).
    groups = ((getattr(scene, "points", ()) or (), "positions"), (getattr(scene, "curves", ()) or (), "points"))
    for group, name in groups:
        for item in group:
            local = np.asarray(getattr(item, name), np.float64).reshape(-1, 3)
            if not len(local):
                continue
            m = np.asarray(getattr(item, "matrix", np.eye(4)), np.float64).reshape(4, 4)
            r = float(np.max(np.abs(np.asarray(item.radii, np.float64)), initial=0.0)) * (1.0 + np.abs(m[:3, :3]).sum())
            placed = local @ m[:3, :3].T + m[:3, 3]
            pts += [placed - r, placed + r]
    for light in scene.lights:
        where = getattr(light, "position", None)
        if where is None and getattr(light, "matrix", None) is not None and not hasattr(light, "direction"):
            where = np.asarray(light.matrix, np.float64)[:3, 3]
        if where is not None:
            pts.append(np.asarray(where, np.float64).reshape(1, 3))
    pts = np.concatenate(pts)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.1 * float(np.linalg.norm(hi - lo)) + 1e-3
    if scene.camera.kind == "ORTHO":
        pad += float(scene.camera.ortho_scale)
    return lo - pad, hi + pad


def _scaled(fn, factor):
    """fn times the object's volume density factor (1: fn itself)."""
    factor = float(factor) if np.isfinite(factor) and factor > 0 else 1.0
    if factor == 1.0:
        return fn
    return lambda ctx: np.asarray(fn(ctx)) * factor


def _reach(voxels):
    """Voxels to max-filter over so that lookups at the lattice's points
    bound the lookups anywhere between them: half the lattice spacing plus
    the one voxel trilinear interpolation reaches."""
    spacing = 1.0 / (GRID * LATTICE)
    return int(np.ceil(0.5 * spacing / voxels.voxel_size())) + 1


def _cell_max(v):
    """(GRID,) * 3 maxima over each cell's (LATTICE + 1)^3 lattice points."""
    for axis in range(3):
        v = np.moveaxis(v, axis, 0)
        v = np.max([v[s:s + GRID * LATTICE:LATTICE] for s in range(LATTICE + 1)], axis=0)
        v = np.moveaxis(v, 0, axis)
    return v


def build_fields(table, materials, scene, tris):
    """The Fields of every (heterogeneous material, instance) pair among the
    triangles, and each triangle's medium id (-1: no volume)."""
    compiler = Compiler()
    voxels = {}
    tri_medium = np.asarray(tris.material, np.int64).copy()
    het = np.array([is_heterogeneous(getattr(m, "volume", None)) for m in materials])
    fields = []
    shading = getattr(tris, "shading", None)
    rows = np.flatnonzero(het[tri_medium]) if len(tri_medium) else np.zeros(0, np.int64)
    if len(rows) and shading is not None:
        inst = shading.instance[rows].astype(np.int64)
        key = tri_medium[rows] * (len(scene.instances) + 1) + inst
        keys, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        for j, k in enumerate(keys):
            mat, i = int(k // (len(scene.instances) + 1)), int(k % (len(scene.instances) + 1))
            instance = scene.instances[i]
            if i not in voxels:
                voxels[i] = instance_voxels(instance)
            fields.append(Field(mat, materials[mat].name, materials[mat].volume, instance.matrix,
                                scene.meshes[instance.mesh], rows[first[j]], tris, compiler, voxels[i],
                                getattr(instance, "volume_density", 1.0)))
        tri_medium[rows] = table.first_field + inverse
    world = getattr(table, "world_volume", None)
    if is_heterogeneous(world):
        fields.append(WorldField(table.world, world, scene_bounds(scene, tris), tris, compiler))
    return fields, tri_medium


def instance_voxels(instance):
    """The Voxels of an instance's grids (a fluid domain's, a Volume
    object's placed ones), or None."""
    grids = getattr(instance, "voxels", None)
    return Voxels(grids, instance.name, getattr(instance, "voxel_placements", None)) if grids else None
