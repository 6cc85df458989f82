"""Dense voxel grids of one object (a Blender fluid domain's density,
flame, temperature, heat and colour), looked up as Cycles looks up a
domain's volume attributes.

Cycles (3.4, blender/volume.cpp BlenderSmokeLoader) loads each grid as a 3D
image over the domain mesh's texture space (its Generated coordinates, 0..1
over the box) and samples it with linear interpolation and CLIP extension
(kernel/device/cpu/image.h interp_3d): voxel centres at (i + 0.5) / res,
trilinear between them, the edge voxels' values held out to the box's faces
and 0 outside it.  A scalar grid reads as (v, v, v, 1), a colour grid as its
RGBA: what the Attribute node and Principled Volume's attribute inputs see
(engine/nodes/context.py ShadingContext.attribute).

Grids are (Z, Y, X) or (Z, Y, X, C) arrays, x fastest as Blender's
``domain_settings.*_grid`` arrays are.  Hostile values are made finite once
here: NaN is 0 and +-inf +-LIMIT, counted for a warning naming the object;
a grid with a zero-sized axis reads 0 everywhere.

A Volume object's grids (addon/export/volume_object.py) are *placed*: each
has its own 4x4 object-to-unit matrix (the inverse of its OpenVDB index-to-
object transform, scaled to its padded box), so they are read at the
point's Object coordinates instead of Generated ones.
"""
import numpy as np

LIMIT = 1e30


class Voxels:
    """The named grids of one object."""

    def __init__(self, grids, name="object", placements=None):
        self.name = name
        self.grids = {}
        self.placements = {k: np.asarray(m, np.float64).reshape(4, 4) for k, m in (placements or {}).items()}
        self.repaired = {"NaN": 0, "infinite": 0}
        for key, grid in grids.items():
            self.grids[key] = self._checked(key, grid)

    def _checked(self, key, grid):
        g = np.asarray(grid, np.float32)
        if g.ndim == 3:
            g = g[..., None]
        if g.ndim != 4 or g.shape[3] not in (1, 3, 4):
            from ..scene import SceneError
            raise SceneError(f"object {self.name!r}: voxel grid {key!r} has shape {np.shape(grid)}, "
                             "not (Z, Y, X) or (Z, Y, X, 1 / 3 / 4)")
        nan, inf = np.isnan(g), np.isinf(g)
        if nan.any() or inf.any():
            self.repaired["NaN"] += int(nan.sum())
            self.repaired["infinite"] += int(inf.sum())
            g = np.where(nan, 0.0, np.clip(g, -LIMIT, LIMIT)).astype(np.float32)
        return g

    def __contains__(self, key):
        return key in self.grids

    def warning(self):
        bad = [f"{k} ({n} values)" for k, n in self.repaired.items() if n]
        if not bad:
            return None
        return f"object {self.name!r}: voxel grid values " + ", ".join(bad) + f" read as 0 (NaN) or +-{LIMIT:g}"

    def lookup(self, key, u):
        """(N, 4) RGBA of grid ``key`` at Generated coordinates u (N, 3)."""
        return trilinear(self.grids[key], u)

    def read(self, key, ctx):
        """(N, 4) RGBA of grid ``key`` at a ShadingContext's points: placed
        grids at its Object coordinates, the others at its Generated ones."""
        m = self.placements.get(key)
        if m is None:
            return self.lookup(key, ctx.generated)
        q = ctx.object_coords
        return trilinear(self.grids[key], q @ m[:3, :3].T + m[:3, 3])

    def dilated(self, reach):
        """A copy whose every voxel holds the largest value within ``reach``
        voxels along each axis (an int, or {grid: int}): its lookups bound
        this one's from above anywhere within reach - 1 voxels (the majorant
        lattice's)."""
        out = Voxels({}, self.name)
        out.placements = self.placements
        out.grids = {k: _max_filter(g, reach[k] if isinstance(reach, dict) else reach)
                     for k, g in self.grids.items()}
        return out

    def placed_reach(self, spacing):
        """{grid: voxels} to max-filter each placed grid over so that lookups
        at a lattice of ``spacing`` (3,) object units bound the lookups
        between its points: half a lattice step in the grid's voxels plus
        the one voxel trilinear interpolation reaches."""
        out = {}
        for key, g in self.grids.items():
            m = self.placements.get(key)
            if m is None or min(g.shape[:3]) == 0:
                continue
            voxels = (np.abs(m[:3, :3]) @ np.asarray(spacing, np.float64)) * np.array(g.shape[:3][::-1])
            out[key] = int(min(np.ceil(0.5 * voxels.max()), max(g.shape[:3]))) + 1
        return out

    def voxel_size(self):
        """The smallest voxel edge in Generated units (1: no voxels)."""
        sizes = [1.0 / max(s) for g in self.grids.values() for s in [g.shape[:3]] if min(s) > 0]
        return min(sizes) if sizes else 1.0


def trilinear(grid, u):
    """Linear interpolation of a (Z, Y, X, C) grid at u (N, 3) in 0..1
    (CLIP: 0 outside the unit box, the edge voxels held inside it)."""
    n = len(u)
    out = np.zeros((n, 4))
    out[:, 3] = 1.0
    res = np.array(grid.shape[:3][::-1])          # (X, Y, Z)
    if n == 0 or res.min() == 0:
        return out
    with np.errstate(invalid="ignore"):
        inside = np.all((u >= 0.0) & (u <= 1.0), axis=1)
    f = np.where(inside[:, None], u, 0.0) * res - 0.5
    i0 = np.floor(f)
    t = f - i0
    i0 = i0.astype(np.int64)
    lo = np.clip(i0, 0, res - 1)
    hi = np.clip(i0 + 1, 0, res - 1)
    value = np.zeros((n, grid.shape[3]))
    for cx in (0, 1):
        x, wx = (hi[:, 0], t[:, 0]) if cx else (lo[:, 0], 1.0 - t[:, 0])
        for cy in (0, 1):
            y, wy = (hi[:, 1], t[:, 1]) if cy else (lo[:, 1], 1.0 - t[:, 1])
            for cz in (0, 1):
                z, wz = (hi[:, 2], t[:, 2]) if cz else (lo[:, 2], 1.0 - t[:, 2])
                value += (wx * wy * wz)[:, None] * grid[z, y, x]
    value[~inside] = 0.0
    c = grid.shape[3]
    if c == 1:
        out[:, :3] = value
    else:
        out[:, :c] = value      # RGB keeps alpha 1; RGBA reads its own (0 outside)
    return out


def _max_filter(grid, reach):
    """Each voxel: the maximum over the (2 reach + 1)^3 voxels around it."""
    g = grid
    for axis in range(3):
        m = g.copy()
        size = g.shape[axis]
        for s in range(1, min(reach, size - 1) + 1):
            lo = [slice(None)] * 4
            hi = [slice(None)] * 4
            lo[axis], hi[axis] = slice(0, size - s), slice(s, size)
            m[tuple(lo)] = np.maximum(m[tuple(lo)], g[tuple(hi)])
            m[tuple(hi)] = np.maximum(m[tuple(hi)], g[tuple(lo)])
        g = m
    return g
