"""Volume objects: a Blender Volume's OpenVDB grids as dense voxel arrays.

Cycles (5.0: scene/image_vdb.cpp, kernel/util/image_3d.h) samples a grid
in its index space, the object-space point times the inverse of the grid's
index-to-object transform, with trilinear interpolation between values at
integer index coordinates (the voxel's lower corner, as OpenVDB: Blender 5.0
changed from centres, commit "Use grid voxel corners as value locations";
before 5.0 a value sits half a voxel further up), inactive voxels reading
the background.  Its volume mesh is the padded active voxels' box.

Here each grid becomes its active bounding box as a dense (Z, Y, X[, C])
array padded by one background voxel on each side, and a placement: the
4x4 object-to-unit matrix that engine/media/voxels.py reads it through (its
trilinear CLIP lookup with voxel centres at (i + 0.5) / res).  The object
renders as a box mesh around every grid's padded box with the Volume's
material (Principled Volume reads 'density', 'color', 'temperature' by its
attribute inputs).

The grids are read through the ``openvdb`` Python module that bpy 4.5 and
newer bundle (bpy/<ver>/python/lib/python3.x/site-packages), or a
``pyopenvdb`` / ``openvdb`` on the path (Debian's python3-openvdb in its
Blender 3.4; loaded by file in bpy 4.2, whose CPython 3.11 it was built for): from the file of the current frame
(``grids.frame_filepath``, so frame sequences follow the scene), or, for
grids only in memory (Geometry Nodes, packed files), from a temporary file
``grids.save`` writes.  A grid whose box holds more than MAX_VOXELS voxels
is averaged over blocks of s^3 voxels (named in a warning): a 10^6-voxel-
wide box of a few voxels costs a few bytes, not 10^18.
"""
import glob
import importlib.util
import math
import os
import sys
import tempfile

import numpy as np

MAX_VOXELS = 1 << 25      # per grid: 128 MiB of float32 (a 320^3 box)
ITERATE_LIMIT = 1 << 21   # active values read one by one when downsampling
SCALAR_TYPES = ('float', 'double')
VECTOR_TYPES = ('vec3s', 'vec3d')

_module = []


def openvdb_module():
    """The openvdb Python module of this Blender (None: there is none)."""
    if not _module:
        _module.append(_find_module())
    return _module[0]


def _find_module():
    for name in ('openvdb', 'pyopenvdb'):
        if name in sys.modules:
            return sys.modules[name]
    try:
        import bpy
        root = bpy.utils.resource_path('LOCAL')
    except (ImportError, AttributeError):
        root = ''
    # Loaded by file, not by adding Blender's site-packages to sys.path
    # (its other modules would shadow the add-on's).
    for path in glob.glob(os.path.join(root, 'python', 'lib', 'python3*', 'site-packages', 'openvdb*.so')):
        module = _load('openvdb', path)
        if module is not None:
            return module
    try:
        import openvdb
        return openvdb
    except ImportError:
        pass
    try:
        import pyopenvdb
        return pyopenvdb
    except ImportError:
        pass
    # Debian's python3-openvdb, built for the system Python: bpy 4.2 (no
    # bundled module) runs on the same CPython 3.11 and loads it.
    tag = f"cpython-{sys.version_info[0]}{sys.version_info[1]}"
    for path in glob.glob(f'/usr/lib/python3/dist-packages/pyopenvdb.{tag}-*.so'):
        module = _load('pyopenvdb', path)
        if module is not None:
            return module
    return None


def _load(name, path):
    """A compiled module loaded from its file (None: it does not load)."""
    try:
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except ImportError:
        return None
    sys.modules[name] = module
    return module


def _blender_version():
    try:
        import bpy
        return tuple(bpy.app.version)
    except ImportError:
        return NORMALISED_GENERATED


def value_offset():
    """Where a voxel's value sits in index space: 0 (its lower corner,
    Blender 5.0+) or 0.5 (its centre, Blender before 5.0)."""
    try:
        import bpy
        return 0.0 if bpy.app.version >= (5, 0, 0) else 0.5
    except ImportError:
        return 0.0


class VolumeGrids:
    """The grids of one evaluated Volume: ``arrays`` {name: (Z, Y, X[, C])},
    ``placements`` {name: object-to-unit 4x4}, ``bounds`` (lo, hi) in object
    space (None: nothing to render), ``generated`` (lo, hi): the box its
    Generated coordinates run 0..1 over, ``warnings``."""

    def __init__(self, name):
        self.name = name
        self.arrays, self.placements = {}, {}
        self.bounds = None
        self.generated = None
        self.warnings = []

    def add(self, key, array, placement):
        self.arrays[key], self.placements[key] = array, placement
        corners = np.array([[x, y, z, 1.0] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
        q = corners @ np.linalg.inv(placement).T
        lo, hi = q[:, :3].min(axis=0), q[:, :3].max(axis=0)
        if self.bounds is not None:
            lo, hi = np.minimum(lo, self.bounds[0]), np.maximum(hi, self.bounds[1])
        self.bounds = (lo, hi)


def read_volume(obj, wanted=None):
    """VolumeGrids of an evaluated Volume object (``wanted``: grid names to
    read, None: all); its ``bounds`` are None when it renders nothing, and a
    warning then says why."""
    out = VolumeGrids(obj.name)
    module = openvdb_module()
    if module is None:
        out.warnings.append(f"Volume object '{obj.name}' not rendered: this Blender has no openvdb Python module "
                            "(bpy 4.5 and newer bundle one; Debian's python3-openvdb serves Blender 3.4 and bpy 4.2)")
        return out
    grids = _file_grids(module, obj, out)
    if grids is None:
        return out
    offset = value_offset()
    for grid in grids:
        if wanted is not None and grid.name not in wanted:
            continue
        _add_grid(out, grid, offset)
    if out.bounds is None and not out.warnings:
        out.warnings.append(f"Volume object '{obj.name}' not rendered: it has no active voxels in a float or "
                            "vector grid")
    if out.bounds is not None:
        out.generated = generated_bounds(obj, out.bounds)
    return out


# The first Blender whose Cycles normalises a Volume object's Generated
# coordinates to its bounds (measured: 4.2, 4.5, 5.0 and 5.1 do not).
NORMALISED_GENERATED = (5, 2, 0)


def generated_bounds(obj, fallback, version=None):
    """(lo, hi) in object space that a Volume object's Generated coordinates
    map to 0..1 in the Cycles of Blender ``version`` (None: the running one).

    Before 5.2 Cycles gives a Volume object no generated transform
    (kernel/geom/volume.h volume_normalized_position then returns the
    object-space point): the unit box, Generated = Object coordinates.
    From 5.2 (blender/volume.cpp sync_volume_object) it is made from
    BKE_volume_min_max: every grid's leaf-node box (8^3-voxel blocks, not
    the active voxels) grown by half a voxel, in object space, which is the
    evaluated object's bound_box; ``fallback`` (the grids' padded box) where
    that is not finite or is flat."""
    if version is None:
        version = _blender_version()
    if tuple(version) < NORMALISED_GENERATED:
        return np.zeros(3), np.ones(3)
    try:
        corners = np.array([tuple(c) for c in obj.bound_box], np.float64)
    except (AttributeError, TypeError, ValueError):
        return fallback
    if corners.shape != (8, 3) or not np.isfinite(corners).all():
        return fallback
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    if not (hi > lo).all():
        return fallback
    return lo, hi


def _file_grids(module, obj, out):
    """The openvdb grids of the object's current frame (None: a warning)."""
    data = obj.data
    grids = data.grids
    try:
        grids.load()
    except (RuntimeError, AttributeError):
        pass
    path = _frame_path(data)
    if path and os.path.isfile(path):
        return _read_file(module, path, obj, out)
    if len(grids) == 0:
        reason = getattr(grids, 'error_message', '') or 'it has no grids'
        where = f" (file '{path}' not found)" if path else ''
        out.warnings.append(f"Volume object '{obj.name}' not rendered: {reason}{where}")
        return None
    # Grids in memory only (Geometry Nodes, packed): written out once.
    handle, temp = tempfile.mkstemp(suffix='.vdb', prefix='ember_volume_')
    os.close(handle)
    try:
        if not grids.save(temp):
            out.warnings.append(f"Volume object '{obj.name}' not rendered: its grids could not be saved for "
                                f"reading ({getattr(grids, 'error_message', '')})")
            return None
        return _read_file(module, temp, obj, out)
    finally:
        os.remove(temp)


def _frame_path(data):
    path = getattr(data.grids, 'frame_filepath', '') or ''
    if not path:
        return ''
    try:
        import bpy
        return bpy.path.abspath(path, library=data.library)
    except (ImportError, AttributeError):
        return path


def _read_file(module, path, obj, out):
    try:
        grids, _meta = module.readAll(path)
    except Exception as exc:     # openvdb raises its own IoError/ValueError kinds
        out.warnings.append(f"Volume object '{obj.name}' not rendered: '{path}' could not be read ({exc})")
        return None
    return grids


def _add_grid(out, grid, offset):
    kind = grid.valueTypeName
    if kind not in SCALAR_TYPES + VECTOR_TYPES:
        return
    if grid.activeVoxelCount() == 0:
        return
    index_to_object = _index_matrix(grid)
    if index_to_object is None:
        out.warnings.append(f"Volume object '{out.name}': grid '{grid.name}' has a singular or non-finite "
                            "transform and is left out")
        return
    channels = 3 if kind in VECTOR_TYPES else 1
    lo, hi = (np.array(c, np.int64) for c in grid.evalActiveVoxelBoundingBox())
    dims = hi - lo + 1
    step = 1
    if float(np.prod(dims.astype(np.float64))) > MAX_VOXELS:
        step = int(math.ceil((float(np.prod(dims.astype(np.float64))) / MAX_VOXELS) ** (1.0 / 3.0)))
        while float(np.prod(np.ceil(dims / step))) > MAX_VOXELS:
            step += 1
        out.warnings.append(f"Volume object '{out.name}': grid '{grid.name}' ({dims[0]} x {dims[1]} x {dims[2]} "
                            f"voxels) averaged over blocks of {step}^3 voxels to fit in memory")
    background = _background(grid, channels)
    if step == 1:
        dense = _dense(grid, lo, dims, channels)
    else:
        dense = _coarse(grid, lo, dims, step, channels, background)
    array = _padded(dense, background)          # (X, Y, Z[, C]) as openvdb indexes
    array = np.ascontiguousarray(np.swapaxes(array, 0, 2))   # (Z, Y, X[, C]): x fastest
    # Element a of the padded array holds the value at index position
    # base + step * a; the lookup puts element a at unit (a + 0.5) / res.
    res = np.array(array.shape[:3][::-1], np.float64)
    base = lo - step + 0.5 * (step - 1) + offset
    unit_from_index = np.eye(4)
    unit_from_index[:3, :3] = np.diag(1.0 / (step * res))
    unit_from_index[:3, 3] = (0.5 - base / step) / res
    out.add(grid.name, array, unit_from_index @ np.linalg.inv(index_to_object))


def _index_matrix(grid):
    """The grid's index-to-object 4x4 (its affine map, probed at four
    points), or None when it is singular or not finite."""
    t = grid.transform
    o = np.array(t.indexToWorld((0.0, 0.0, 0.0)), np.float64)
    m = np.eye(4)
    for axis in range(3):
        e = [0.0, 0.0, 0.0]
        e[axis] = 1.0
        m[:3, axis] = np.array(t.indexToWorld(tuple(e)), np.float64) - o
    m[:3, 3] = o
    if not np.isfinite(m).all() or abs(np.linalg.det(m[:3, :3])) < 1e-300:
        return None
    return m


def _background(grid, channels):
    value = np.array(grid.background, np.float64).reshape(-1)
    value = np.where(np.isfinite(value), value, 0.0)
    return value if channels > 1 else value[:1]


def _dense(grid, lo, dims, channels):
    shape = tuple(int(d) for d in dims) + ((channels,) if channels > 1 else ())
    array = np.zeros(shape, np.float32)
    grid.copyToArray(array, ijk=tuple(int(v) for v in lo))
    return array


def _coarse(grid, lo, dims, step, channels, background):
    """Block means over step^3 voxels of the active bounding box (inactive
    voxels read as the background): from the active values one by one, or
    slab by slab where they are too many."""
    cells = tuple(int(c) for c in np.ceil(dims / step).astype(np.int64))
    total = np.zeros(cells + (channels,), np.float64)
    if grid.activeVoxelCount() <= ITERATE_LIMIT:
        counted = np.zeros(cells, np.float64)
        for item in grid.iterOnValues():
            _add_box(total, counted, np.array(item.min) - lo, np.array(item.max) - lo, step,
                     np.array(item.value, np.float64).reshape(-1))
        total += (step ** 3 - counted)[..., None] * background
    else:
        for z in range(0, int(dims[2]), step):
            depth = int(min(step, dims[2] - z))
            slab = _dense(grid, lo + np.array([0, 0, z]), np.array([dims[0], dims[1], depth]), channels)
            slab = slab.reshape(slab.shape[:3] + (channels,)).astype(np.float64)
            pad = [(0, cells[0] * step - int(dims[0])), (0, cells[1] * step - int(dims[1])), (0, step - depth), (0, 0)]
            slab = np.pad(slab, pad, constant_values=0.0)
            sums = slab.reshape(cells[0], step, cells[1], step, 1, step, channels).sum(axis=(1, 3, 5))
            total[:, :, z // step] = sums[:, :, 0]
    mean = (total / step ** 3).astype(np.float32)
    return mean if channels > 1 else mean[..., 0]


def _add_box(total, counted, a, b, step, value):
    """Add a value over the voxels a..b (inclusive, box-relative) to the
    step^3 cells they overlap."""
    spans = []
    for axis in range(3):
        first, last = int(a[axis] // step), int(b[axis] // step)
        cells = np.arange(first, last + 1)
        start = np.maximum(cells * step, a[axis])
        end = np.minimum(cells * step + step - 1, b[axis])
        keep = (cells >= 0) & (cells < total.shape[axis])
        spans.append((cells[keep], (end - start + 1)[keep].astype(np.float64)))
    (ix, wx), (iy, wy), (iz, wz) = spans
    weight = wx[:, None, None] * wy[None, :, None] * wz[None, None, :]
    region = np.ix_(ix, iy, iz)
    total[region] += weight[..., None] * value
    counted[region] += weight


def _padded(dense, background):
    """One background voxel around the box, where trilinear lookups fade
    out as Cycles' reads of the inactive neighbours do."""
    if dense.ndim == 3:
        return np.pad(dense, 1, constant_values=float(background[0]))
    out = np.empty(tuple(s + 2 for s in dense.shape[:3]) + dense.shape[3:], np.float32)
    out[...] = background.astype(np.float32)
    out[1:-1, 1:-1, 1:-1] = dense
    return out


def density_factor(obj, matrix):
    """Cycles' object_volume_density: with Render > Space 'OBJECT' (the
    default) the density is per object-space length, 1 / |M (1, 1, 1) /
    sqrt 3| in world space; 'WORLD': 1."""
    render = getattr(obj.data, 'render', None)
    if render is not None and getattr(render, 'space', 'OBJECT') != 'OBJECT':
        return 1.0
    length = float(np.linalg.norm(np.asarray(matrix, np.float64)[:3, :3] @ np.full(3, 1.0 / math.sqrt(3.0))))
    return 1.0 / length if np.isfinite(length) and length > 1e-30 else 1.0


def box_mesh(lo, hi, name, generated=None):
    """The 12 outward-facing triangles of the box lo..hi (object space),
    whose texture space maps ``generated`` (lo, hi; None: the box itself)
    to Generated 0..1 (engine/nodes/context.py texture_space)."""
    from .. import backend
    g_lo, g_hi = (np.asarray(v, np.float64) for v in (generated if generated is not None else (lo, hi)))
    texspace = (0.5 * (g_lo + g_hi), 0.5 * (g_hi - g_lo))
    x = np.array([[lo[0], hi[0]][i & 1] for i in range(8)])
    y = np.array([[lo[1], hi[1]][(i >> 1) & 1] for i in range(8)])
    z = np.array([[lo[2], hi[2]][(i >> 2) & 1] for i in range(8)])
    positions = np.stack([x, y, z], axis=1).astype(np.float32)
    quads = ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5))
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return backend.engine().Mesh(positions=positions, triangles=np.array(tris, np.int32), name=name,
                                 texspace=texspace)
