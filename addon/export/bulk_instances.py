"""A geometry-nodes instancer's copies read in bulk (issue 25).

``depsgraph.object_instances`` yields an instancer's copies right after the
instancer itself, in the order of its instances; reading each copy's fields
costs about 5 us (10^6 copies: 5 s), the iteration alone 0.7 us.  Where the
instancer's evaluated geometry (bpy 4.5+: ``Object.evaluated_geometry()``)
holds only instances of realized meshes, its transforms, reference indices
and ids come from ``instances_pointcloud()`` in a few foreach_get calls, and
each copy's random_id from dupli_random (Blender's hash).  The walk then
reads, through the ordinary InstanceCollector.add, only the first copy of
each reference (the template every other copy of it shares) and the last
copy, each checked against the plan (instancer, persistent id, random_id,
matrix), and skips the rest without reading them.  A check that fails raises
BulkMismatch: the export starts again with the per-copy walk.  Copies whose
materials read Object / Instancer attributes (per-copy values) are read
through the walk, as are instancers this does not cover (object or
collection references, nested instances, ids that collide, other components).
"""
import collections
import itertools
from dataclasses import dataclass

import numpy as np

from . import dupli_random

# Fewer copies than this are walked (the bulk read's set-up costs more).
BULK_MIN = 256
OTHER_COMPONENTS = ('curves', 'pointcloud', 'volume', 'grease_pencil')


class BulkMismatch(Exception):
    """The depsgraph's copies were not those the plan foresaw."""


@dataclass
class Plan:
    """The copies of one instancer, in the depsgraph's order."""
    host: int              # the instancer's original object's pointer
    matrix: np.ndarray     # (N, 4, 4) float64 object-to-world
    reference: np.ndarray  # (N,) int64 instance reference index
    persistent: np.ndarray  # (N, MAX_DUPLI_RECUR) int64 persistent ids
    random_id: np.ndarray  # (N,) uint32
    random: np.ndarray     # (N,) float64 Object Info Random

    def __len__(self):
        return len(self.reference)


def plan(obj):
    """The Plan of the copies the evaluated mesh object ``obj`` makes by
    geometry nodes, or None where the bulk read does not apply."""
    geometry_of = getattr(obj, 'evaluated_geometry', None)
    if geometry_of is None or obj.type != 'MESH' or obj.instance_type != 'NONE' or len(obj.particle_systems):
        return None
    try:
        geometry = geometry_of()
        if any(getattr(geometry, kind, None) is not None for kind in OTHER_COMPONENTS):
            return None   # those make copies of their own before the instances (another id level)
        references = geometry.instance_references()
        if not references or not all(_realized_mesh(ref) for ref in references):
            return None
        cloud = geometry.instances_pointcloud()
    except (AttributeError, RuntimeError, TypeError):
        return None
    n = len(cloud.points)
    if n < BULK_MIN:
        return None
    attributes = cloud.attributes
    transforms = _read(attributes, 'instance_transform', np.float32, n * 16)
    reference = _read(attributes, '.reference_index', np.int32, n)
    if transforms is None or reference is None or reference.min() < 0 or reference.max() >= len(references):
        return None
    ids = _read(attributes, 'id', np.int32, n) if 'id' in attributes else np.arange(n)
    if ids is None or len(np.unique(ids)) != n:
        return None   # Blender replaces colliding ids by random numbers (almost_unique_ids)
    # Blender's float4x4 is column-major: each 16 floats are 4 columns.
    local = transforms.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)
    persistent = dupli_random.geometry_instance_ids(ids)
    random_id = dupli_random.random_ids(obj.name, persistent)
    return Plan(host=obj.original.as_pointer(), matrix=np.array(obj.matrix_world, np.float64) @ local,
                reference=reference.astype(np.int64), persistent=persistent, random_id=random_id,
                random=dupli_random.unit_float(random_id))


def _realized_mesh(ref):
    """A reference the instancer copies as one mesh (no other component, no
    instances of its own)."""
    return (getattr(ref, 'mesh', None) is not None and not ref.instance_references()
            and all(getattr(ref, kind, None) is None for kind in OTHER_COMPONENTS))


def _read(attributes, name, dtype, size):
    attribute = attributes.get(name)
    if attribute is None:
        return None
    out = np.empty(size, dtype)
    attribute.data.foreach_get('value', out)
    return out


def take(collector, walk, plan):
    """Consume the plan's copies from the depsgraph iterator ``walk``
    (positioned right after the instancer) into ``collector``: the checked
    copies through collector.add, the rest as runs of
    (templates, template of each row, matrices, randoms)."""
    n = len(plan)
    firsts = np.unique(plan.reference, return_index=True)[1]
    templates = {}      # reference -> its first copy's Instance
    state = {}          # reference -> 'bulk', 'walk' (read every copy) or 'drop' (nothing to draw)
    stops = _stops(firsts, n, plan.reference, ())
    i = 0
    while i < n:
        k = int(plan.reference[i])
        if state.get(k) in (None, 'walk') or i == n - 1:
            if _read_one(collector, walk, plan, i, k, templates, state) == 'walk':
                stops = _stops(firsts, n, plan.reference, [r for r, s in state.items() if s == 'walk'])
            i += 1
            continue
        j = int(stops[np.searchsorted(stops, i)])   # the next row to read (> i)
        collections.deque(itertools.islice(walk, j - i), maxlen=0)   # skipped in C, unread
        collector.check()
        _append_run(collector, plan, i, j, templates, state)
        i = j


def _stops(firsts, n, reference, walked):
    """Sorted rows that are read: first copies, copies of walked references, the last."""
    rows = [firsts, [n - 1]]
    if len(walked):
        rows.append(np.flatnonzero(np.isin(reference, list(walked))))
    return np.unique(np.concatenate(rows)).astype(np.int64)


def _read_one(collector, walk, plan, i, k, templates, state):
    """Row i through the walk; at a reference's first copy, its state (returned)."""
    inst = next(walk, None)
    _check(inst, plan, i)
    before = len(collector.instances)
    collector.add(inst)
    added = collector.instances[before:]
    if k in state:
        return None
    if not added:
        state[k] = 'drop'        # every copy of it shares the mesh and group: none draws
    elif added[0].object_attributes:
        state[k] = 'walk'        # per-copy Attribute node values
    else:
        state[k], templates[k] = 'bulk', added[0]
    return state[k]


def _check(inst, plan, i):
    """BulkMismatch unless ``inst`` is the plan's row i."""
    if inst is None or not inst.is_instance or inst.parent is None:
        raise BulkMismatch(f"row {i}: not a copy")
    if inst.parent.original.as_pointer() != plan.host:
        raise BulkMismatch(f"row {i}: another instancer's copy")
    if tuple(inst.persistent_id) != tuple(int(v) for v in plan.persistent[i]):
        raise BulkMismatch(f"row {i}: persistent id {tuple(inst.persistent_id)}")
    if (int(inst.random_id) & 0xFFFFFFFF) != int(plan.random_id[i]):
        raise BulkMismatch(f"row {i}: random_id differs from Blender's")
    matrix = np.array(inst.matrix_world, np.float64)
    if not np.allclose(matrix, plan.matrix[i], rtol=1e-5, atol=1e-5 * (1.0 + np.abs(matrix).max()), equal_nan=True):
        raise BulkMismatch(f"row {i}: transform differs")


def _append_run(collector, plan, lo, hi, templates, state):
    """Rows lo..hi-1 (all of references read in bulk or dropped) as one run."""
    rows = np.arange(lo, hi)
    refs = plan.reference[rows]
    keep = np.isin(refs, [r for r, s in state.items() if s == 'bulk'])
    rows, refs = rows[keep], refs[keep]
    if not len(rows):
        return
    order = sorted(templates)
    which = np.searchsorted(np.array(order), refs)
    collector.instances.append(([templates[r] for r in order], which, plan.matrix[rows], plan.random[rows]))
