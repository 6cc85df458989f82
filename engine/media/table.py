"""A scene's media as plain arrays, and the volume stack of each path.

Row i of every table is material i's medium (zero where the material has
no Volume); one more zero row at the end is what an empty stack slot (-1)
reads, so summing a stack's rows needs no mask.  The stack (N, STACK_SIZE)
int32 holds the materials whose media a path is in (-1: empty slot):
crossing a front face of a material with a volume enters it, a back face
leaves it (Cycles' volume_stack_enter_exit, keyed by material where Cycles
keys by object: two overlapping objects of one volume material count once).
Overlapping media add their coefficients, as Cycles sums the closures of
every stack entry.
"""
import numpy as np

from .. import instance_batch, kernels
from . import equiangular
from .field import WorldField, build_fields, is_heterogeneous
from .phase import HG, mixture_of

STACK_SIZE = 4
TRACKING_EVENTS = 512     # tracking.MAX_EVENTS
# Crossings looked at along the camera's axis to find the media the camera
# starts in (Cycles' volume_stack_init casts rays the same way).
_CAMERA_PROBES = 64


class MediumTable:
    """sigma_a, sigma_s, emission (M + 1, 3), g (M + 1,), has (M + 1,) bool,
    names: per material (the scene's materials and the default one)."""

    def __init__(self, volumes, names):
        m = len(volumes)
        self.sigma_a = np.zeros((m + 1, 3))
        self.sigma_s = np.zeros((m + 1, 3))
        self.emission = np.zeros((m + 1, 3))
        self.g = np.zeros(m + 1)
        self.has = np.zeros(m + 1, bool)
        # Each medium's phase function: (k1, a1, b1, k2, a2, b2, w), a
        # mixture of two lobes (phase.mixture_of); HG of g 0 by default.
        self.phase = np.zeros((m + 1, 7))
        # How each medium samples its segments' direct-light points
        # (equiangular.DISTANCE / EQUIANGULAR / MIS).
        self.sampling = np.full(m + 1, equiangular.DISTANCE, np.int64)
        for i, vol in enumerate(volumes):
            if vol is None:
                continue
            self.has[i] = True
            self.sampling[i] = equiangular.METHODS.get(getattr(vol, "sampling", ""), equiangular.MIS)
            self.phase[i] = mixture_of(vol)
            if is_heterogeneous(vol):
                continue     # its rows are the Fields' (attach), these stay zero
            self.sigma_a[i] = vol.absorption
            self.sigma_s[i] = vol.scattering
            self.emission[i] = vol.emission
            self.g[i] = vol.anisotropy
        self.names = list(names) + [""]
        # Heterogeneous media (field.py): one medium id per (material,
        # instance), ids first_field + j after the materials' rows; the
        # triangles' medium ids (attach); without any, a medium id is its
        # material's.
        self.first_field = m
        self.fields = []
        self.tri_medium = None
        self.truncated = {}     # material name -> rays the trackers stopped
        # Volume boundaries: a volume-only material's pass-through surface,
        # which paths and shadow rays cross without counting a transparent
        # bounce (Cycles' volume_bounds_bounce); set by ``of``.
        self.boundary = np.zeros(m + 1, bool)
        self.camera = np.full(STACK_SIZE, -1, np.int32)   # the stack camera rays start with
        self.world = -1     # the world volume's medium id (-1: none; a textured one's is its field's)
        self.world_volume = None
        self.warnings = []

    @classmethod
    def of(cls, materials, world=None):
        """The table of a list of scene Materials and the world's volume
        (row len(materials), after the materials'); None when there is no
        volume."""
        volumes = [getattr(m, "volume", None) for m in materials]
        if all(v is None for v in volumes) and world is None:
            return None
        names = [m.name for m in materials]
        if world is not None:
            volumes, names = volumes + [world], names + ["world"]
        table = cls(volumes, names)
        table.boundary[:len(materials)] = [v is not None and _pass_through(m) for v, m in zip(volumes, materials)]
        if world is not None:
            table.world = len(materials)
            table.camera[0] = table.world
        table.world_volume = world
        return table

    def attach(self, materials, scene, tris):
        """Build the Fields of the heterogeneous media among the triangles
        and give every triangle its medium id (``medium_of``)."""
        self.fields, self.tri_medium = build_fields(self, materials, scene, tris)
        h = len(self.fields)
        if h == 0:
            return
        m = self.first_field
        def grow(a, fill=0):
            extra = np.full((h,) + a.shape[1:], fill, a.dtype)
            return np.concatenate([a[:m], extra, a[m:]])
        self.sigma_a, self.sigma_s, self.emission = grow(self.sigma_a), grow(self.sigma_s), grow(self.emission)
        self.g = grow(self.g)
        self.has = grow(self.has, True)
        self.phase = np.concatenate([self.phase[:m], self.phase[[f.material for f in self.fields]], self.phase[m:]])
        self.sampling = np.concatenate([self.sampling[:m], self.sampling[[f.material for f in self.fields]],
                                        self.sampling[m:]])
        self.names = self.names[:m] + [f.name for f in self.fields] + self.names[m:]
        if isinstance(self.fields[-1], WorldField):
            # A textured world medium is its field, in every camera stack.
            self.camera[self.camera == self.world] = m + h - 1
            self.world = m + h - 1

    def phase_medium(self, stack):
        """(N,) the medium whose phase function a scattering in ``stack``
        follows where it is not Henyey-Greenstein (-1: Henyey-Greenstein of
        the scattering-weighted mean g): the medium scattering most (a
        heterogeneous one before any homogeneous)."""
        return self.stack_media(stack)[4]

    def stack_media(self, stack):
        """(sigma_a, sigma_s, emission (N, 3), g (N,), phase medium (N,)) of
        stacks (N, K) in one compiled pass (``coefficients``,
        ``phase_medium``)."""
        n = len(stack)
        out = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, np.int64))
        het = np.zeros(len(self.has), bool)
        het[self.first_field:self.first_field + len(self.fields)] = True
        plain = (self.phase[:, 0] == HG) & (self.phase[:, 6] == 0)
        _stack_media_rows(np.ascontiguousarray(stack, np.int32), self.sigma_a, self.sigma_s, self.emission,
                          self.g, het, plain, *out)
        return out

    def vertex_phase(self, g, medium):
        """The 7 arrays of the phase mixtures at scattering points: HG of g
        where ``medium`` is -1, else that medium's phase function."""
        n = len(g)
        out = np.zeros((n, 7))
        out[:, 1] = out[:, 4] = g
        use = medium >= 0
        out[use] = self.phase[medium[use]]
        return tuple(out[:, j].copy() for j in range(7))

    def medium_of(self, prim, mat):
        """Medium ids of the triangles ``prim`` (material ``mat``)."""
        if self.tri_medium is None or not self.fields:
            return mat
        return self.tri_medium[prim]

    def heterogeneous(self, stack):
        """(N,) which stacks hold a heterogeneous medium."""
        if not self.fields:
            return np.zeros(len(stack), bool)
        return np.any((stack >= self.first_field) & (stack < self.first_field + len(self.fields)), axis=1)

    def field_warnings(self):
        out = [w for w in (f.warning() for f in self.fields) if w]
        grids = {id(f.voxels): f.voxels for f in self.fields if f.voxels is not None}
        out += [w for w in (v.warning() for v in grids.values()) if w]
        for name, count in sorted(self.truncated.items()):
            out.append(f"material {name!r}: {count} rays stopped (opaque) after {TRACKING_EVENTS} collisions in "
                       "its medium (a density far above its majorant grid's, or huge)")
        return out

    def note_truncated(self, stacks):
        """Rays the trackers stopped: counted per heterogeneous material."""
        for k, j, rows in self._field_rows(stacks):
            name = self.fields[j].name
            self.truncated[name] = self.truncated.get(name, 0) + len(rows)

    def local(self, stack, p, d):
        """(sigma_a, sigma_s, emission (N, 3), g weight (N,)) of the
        heterogeneous media of ``stack`` at points p: their sums, and the sum
        of mean(sigma_s) x g."""
        n = len(stack)
        sa, ss, em, gw = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n)
        for k, j, rows in self._field_rows(stack):
            f = self.fields[j]
            a, s, e, g = f.evaluate_phase(p[rows], d[rows])
            sa[rows] += a
            ss[rows] += s
            em[rows] += e
            gw[rows] += s.mean(axis=1) * g
        return sa, ss, em, gw

    def majorant(self, stack, p, d):
        """(mu (N,), dist (N,)): the heterogeneous media's summed majorant at
        p and the distance along d over which it holds."""
        n = len(stack)
        mu, dist = np.zeros(n), np.full(n, np.inf)
        for k, j, rows in self._field_rows(stack):
            m, t = self.fields[j].majorant(p[rows], d[rows])
            mu[rows] += m
            dist[rows] = np.minimum(dist[rows], t)
        return mu, dist

    def mean_majorant(self, stack):
        """(N,) the heterogeneous media's summed mean grid majorant: the
        extinction of a homogeneous stand-in that distance-samples direct-
        light points in them (engine/integrator/volume.py)."""
        out = np.zeros(len(stack))
        for k, j, rows in self._field_rows(stack):
            out[rows] += float(self.fields[j].grid.mean())
        return out

    def _field_rows(self, stack):
        lo, h = self.first_field, len(self.fields)
        for k in self._used_slots(stack):
            ids = stack[:, k] - lo
            use = (ids >= 0) & (ids < h)
            for j in np.unique(ids[use]):
                yield k, int(j), np.flatnonzero(ids == j)

    # -- a stack's medium ------------------------------------------------------
    def coefficients(self, stack):
        """(sigma_a, sigma_s, emission (N, 3), g (N,)) of stacks (N, K): the
        sums over their media; g is the scattering-weighted mean of theirs."""
        return self.stack_media(stack)[:4]

    def extinction(self, stack):
        """(N, 3) the stacks' summed homogeneous extinction (shadow rays' transmittance)."""
        sa, ss = self.stack_media(stack)[:2]
        return sa + ss

    @staticmethod
    def _used_slots(stack):
        return _used_slots(stack)

    # -- entering and leaving ---------------------------------------------------
    def cross(self, stack, rows, mat, back):
        """Rows ``rows`` of ``stack`` cross a surface of material ``mat``
        (per row) from its front (back False: enter its medium) or its back
        (leave it).  In place; a full stack drops the entry (STACK_SIZE
        nested media).  One compiled loop (``_cross_rows``): the NumPy form
        took a dozen gathers per crossing, 5 % of a fog batch."""
        if len(rows) == 0 or stack.shape[1] == 0:
            return
        rows = _loop_column(rows, len(rows), np.int64)
        mat, back = _loop_column(mat, len(rows), np.int64), _loop_column(back, len(rows), bool)
        if stack.dtype == np.int32 and stack.flags.c_contiguous and stack.flags.writeable:
            _cross_rows(stack, rows, mat, back, self.has)
            return
        work = np.array(stack, np.int32)   # a copy: the stack may be strided, int64 or read-only
        _cross_rows(work, rows, mat, back, self.has)
        stack[...] = work


def _loop_column(a, n, dtype):
    """``a`` (a scalar or n values) as a writeable contiguous column (what
    a compiled loop's signature takes; broadcasts are read-only)."""
    a = np.asarray(a)
    if a.shape != (n,):
        return np.full(n, a, dtype)
    a = np.ascontiguousarray(a, dtype)
    return a if a.flags.writeable else a.copy()


def _cross_numpy(stack, rows, mat, back, has):
    """The reference form of ``_cross_rows`` (rows unique)."""
    use = has[mat]
    if not use.any():
        return
    rows, mat, back = rows[use], mat[use], back[use]
    sub = stack[rows]
    present = sub == mat[:, None]
    leave = back
    sub[leave] = np.where(present[leave], -1, sub[leave])
    enter = ~back & ~present.any(axis=1)
    empty = sub < 0
    slot = np.argmax(empty, axis=1)
    put = np.flatnonzero(enter & empty.any(axis=1))
    sub[put, slot[put]] = mat[put]
    stack[rows] = sub


@kernels.loop_kernel("void(int32[:, ::1], int64[::1], int64[::1], boolean[::1], boolean[::1])", _cross_numpy)
def _cross_rows(stack, rows, mat, back, has):
    for i in range(rows.shape[0]):
        m = mat[i]
        if not has[m]:
            continue
        r = rows[i]
        if back[i]:   # leave: every slot holding the medium
            for k in range(stack.shape[1]):
                if stack[r, k] == m:
                    stack[r, k] = -1
            continue
        present, slot = False, -1
        for k in range(stack.shape[1]):
            if stack[r, k] == m:
                present = True
            elif stack[r, k] < 0 and slot < 0:
                slot = k
        if not present and slot >= 0:
            stack[r, slot] = m


def _used_slots(stack):
    return [k for k in range(stack.shape[1]) if (stack[:, k] >= 0).any()]


def _stack_media_numpy(stack, sigma_a, sigma_s, emission, g_table, het, plain, sa, ss, em, g, phase_medium):
    """The reference form of ``_stack_media_rows``: sums of the stacks'
    rows (an empty slot, -1, reads the zero row at the end), g the
    scattering-weighted mean, and the phase medium (the one scattering
    most, a heterogeneous one first; -1 where that is plain HG)."""
    n = len(stack)
    sa[:], ss[:], em[:] = 0.0, 0.0, 0.0
    gw, w = np.zeros(n), np.zeros(n)
    best, best_w = np.full(n, -1), np.full(n, -np.inf)
    for k in _used_slots(stack):
        m = stack[:, k]
        sa += np.take(sigma_a, m, axis=0)
        s = np.take(sigma_s, m, axis=0)
        ss += s
        em += np.take(emission, m, axis=0)
        wk = s.mean(axis=1)
        w += wk
        gw += wk * np.take(g_table, m)
        pw = np.where(m < 0, -np.inf, np.where(het[m], np.inf, wk))
        better = pw > best_w
        best, best_w = np.where(better, m, best), np.where(better, pw, best_w)
    g[:] = np.where(w > 0, gw / np.where(w > 0, w, 1.0), 0.0)
    phase_medium[:] = np.where((best < 0) | plain[np.maximum(best, 0)], -1, best)


@kernels.loop_kernel("void(int32[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], "
                     "boolean[::1], boolean[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], "
                     "float64[::1], int64[::1])", _stack_media_numpy)
def _stack_media_rows(stack, sigma_a, sigma_s, emission, g_table, het, plain, sa, ss, em, g, phase_medium):
    for i in range(stack.shape[0]):
        for c in range(3):
            sa[i, c] = 0.0
            ss[i, c] = 0.0
            em[i, c] = 0.0
        gw, w = 0.0, 0.0
        best, best_w = -1, -np.inf
        for k in range(stack.shape[1]):
            m = stack[i, k]
            if m < 0:
                continue
            for c in range(3):
                sa[i, c] += sigma_a[m, c]
                ss[i, c] += sigma_s[m, c]
                em[i, c] += emission[m, c]
            wk = (sigma_s[m, 0] + sigma_s[m, 1] + sigma_s[m, 2]) / 3.0
            w += wk
            gw += wk * g_table[m]
            pw = np.inf if het[m] else wk
            if pw > best_w:
                best, best_w = m, pw
        g[i] = gw / w if w > 0 else 0.0
        phase_medium[i] = -1 if best < 0 or plain[best] else best


def _pass_through(material):
    """The surface of a volume-only material: one white transparent lobe of
    weight 1 (what the exporter gives a material with only a Volume output)."""
    lobes = list(material.lobes)
    if len(lobes) != 1 or lobes[0].kind != "transparent":
        return False
    color, weight = lobes[0].color, lobes[0].weight
    return (isinstance(color, tuple) and tuple(float(c) for c in color) == (1.0, 1.0, 1.0)
            and isinstance(weight, (int, float)) and float(weight) == 1.0)


def start_stack(table, n):
    """(n, K) stacks of paths leaving the camera."""
    if table is None:
        return np.zeros((n, 0), np.int32)
    return np.repeat(table.camera[None, :], n, axis=0)


def camera_media(table, accel, triangles, origin, direction):
    """The media a point starts in: walking from it along ``direction``,
    a material's first crossing from its back side means the point is inside
    its mesh.  Sets table.camera."""
    seen = {}
    o = np.asarray(origin, np.float64)[None, :]
    d = np.asarray(direction, np.float64)[None, :]
    d = d / np.linalg.norm(d)
    for _ in range(_CAMERA_PROBES):
        t, prim, _, _ = accel.intersect(o, d, np.array([np.inf]))
        if prim[0] < 0 or not np.isfinite(t[0]):
            break
        k = int(prim[0])
        mat = int(table.medium_of(prim[:1], triangles.material[prim[:1]])[0])
        ng = triangles.ng[k]
        if table.has[mat] and mat not in seen:
            seen[mat] = float(np.dot(ng, d[0])) > 0   # leaving through its outside: inside it
        p = o + d * t[0]
        o = accel.offset_origin(p, ng[None, :], d)
    inside = ([table.world] if table.world >= 0 else []) + [m for m, back in seen.items() if back]
    inside = inside[:STACK_SIZE]
    table.camera[:] = -1
    table.camera[:len(inside)] = inside


def open_volume_meshes(scene):
    """Names of objects whose volume material's triangles do not close
    (an edge not shared by exactly two of them): paths entering such a
    volume may never leave it."""
    return [name for name, _ in open_meshes(scene, lambda m: getattr(m, "volume", None) is not None)]


def open_meshes(scene, uses):
    """(object name, material names) of the objects whose triangles with a
    material ``uses(material)`` picks do not close (an edge not shared by
    exactly two of them)."""
    out = []
    checked = {}
    for inst in instance_batch.distinct(scene.instances):
        mesh = scene.meshes[inst.mesh]
        tris = np.asarray(mesh.triangles).reshape(-1, 3)
        if len(tris) == 0:
            continue
        slots = np.zeros(len(tris), np.int64) if mesh.material_slots is None else np.asarray(mesh.material_slots)
        mats = np.array([inst.materials[s] if s < len(inst.materials) else -1 for s in range(int(slots.max()) + 1)])
        picked = np.array([m >= 0 and bool(uses(scene.materials[m])) for m in mats])
        if not picked.any():
            continue
        key = (inst.mesh, tuple(picked))
        if key not in checked:
            checked[key] = not _closed(np.asarray(mesh.positions, np.float64), tris[picked[slots]])
        if checked[key]:
            out.append((inst.name, [scene.materials[m].name for m, p in zip(mats, picked) if p]))
    return out


def _closed(positions, tris):
    """Every edge of ``tris`` is shared by exactly two of them (vertices
    welded by position: exporters split vertices at UV seams)."""
    _, weld = np.unique(np.round(positions, 9), axis=0, return_inverse=True)
    t = weld.reshape(-1)[tris]
    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))
