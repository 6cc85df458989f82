"""Motion blur of point clouds, Curves objects and particle hair (Cycles'
sync_pointcloud_motion, export_hair_curves_motion and the particle hair's
motion keys, read at each motion step by BlenderSync::sync_motion).

At every shutter step motion.add_motion sets, each exported cloud or curve
set is found again among the depsgraph's instances (by the instance it came
from: ``primitive_key``; particle hair by its emitter and system) and its
object-to-world matrix and points are read.  A set whose steps all equal
its centre gets no motion; one whose point count changes, or whose steps
are NaN or infinite, gets none either and is named in a warning (Cycles
drops the motion attribute when the count changes).  Object > Motion Blur
off keeps it still, Deformation off keeps its points.  Curves keep their
radii over the shutter (Cycles' Embree setup reads the centre's), points
take theirs at each step.

A cloud or curve set with a ``velocity`` attribute (``velocity_of``, read at
export into the item's ``velocity``) moves by it instead: Cycles'
attr_create_motion_from_velocity builds three steps P - v s / 2, P,
P + v s / 2 (s: the shutter in seconds) and never reads its points at the
steps (BlenderSync::sync_motion skips geometry whose motion an attribute
gave); its transform still moves it.  Radii stay the centre's.
"""
import numpy as np

from . import particle_hair


class Source:
    """Where an exported PointCloud / HairCurves (``item``) came from: its
    instance's ``key``, ``kind`` ('points', 'curves' or 'hair'), the
    original object, the mask of points the export kept (None: all), and
    for hair the particle system's name."""

    def __init__(self, item, key, kind, obj, keep=None, system=None):
        self.item, self.key, self.kind, self.obj = item, key, kind, obj
        self.keep, self.system = keep, system


# float3 conversions of attribute types (Blender's attribute_math on the point domain)
_VELOCITY_READ = {'FLOAT_VECTOR': ('vector', 3), 'FLOAT2': ('vector', 2), 'FLOAT': ('value', 1),
                  'INT': ('value', 1), 'BOOLEAN': ('value', 1), 'FLOAT_COLOR': ('color', 4),
                  'BYTE_COLOR': ('color', 4)}


def velocity_of(data, count):
    """(a geometry's ``velocity`` attribute as (count, 3) float32 units per
    second on its points, or None; a warning or None), as Cycles reads it
    (``get<float3>(AttrDomain::Point)``): a float as (f, f, f), a colour's
    r, g, b; a mesh's faces, corners or edges averaged onto their points
    and a curve's value on each of its points (Blender's domain
    interpolation); other types or domains are named and not read."""
    attributes = getattr(data, 'attributes', None)
    attr = attributes.get('velocity') if attributes is not None else None
    if attr is None:
        return None, None
    read = _VELOCITY_READ.get(attr.data_type)
    if read is None or (attr.domain != 'POINT' and attr.data_type == 'BOOLEAN'):
        return None, f"its 'velocity' attribute ({attr.data_type.lower()}) is not read: Ember reads vectors and numbers"
    prop, width = read
    size = len(attr.data)
    raw = np.empty(size * width, {'INT': np.int32, 'BOOLEAN': bool}.get(attr.data_type, np.float32))
    attr.data.foreach_get(prop, raw)
    raw = raw.reshape(size, width).astype(np.float32)
    if width == 1:
        raw = np.repeat(raw, 3, axis=1)
    elif width == 2:
        raw = np.concatenate([raw, np.zeros((size, 1), np.float32)], axis=1)
    values = np.ascontiguousarray(raw[:, :3])
    if attr.domain != 'POINT':
        values = _onto_points(data, attr.domain, values, count)
        if values is None:
            return None, f"its 'velocity' attribute (on {attr.domain.lower()}) is not read: Ember reads it on points"
    if len(values) != count:
        return None, "its 'velocity' attribute is not read: its size is not the point count"
    return values, None


def _onto_points(data, domain, values, count):
    """Per-point values of a mesh's face, corner or edge values (their mean
    over the point's, 0 on a point with none) or of a curve's (repeated on
    its points); None for another domain."""
    if domain == 'CURVE' and hasattr(data, 'curve_offset_data'):
        offsets = np.empty(len(data.curves) + 1, np.int32)
        data.curve_offset_data.foreach_get('value', offsets)
        return np.repeat(values, np.diff(offsets), axis=0)
    if domain not in ('FACE', 'CORNER', 'EDGE') or not hasattr(data, 'loops'):
        return None
    if domain == 'EDGE':
        ids = np.empty(len(data.edges) * 2, np.int32)
        data.edges.foreach_get('vertices', ids)
        per = np.repeat(values, 2, axis=0)
    else:
        ids = np.empty(len(data.loops), np.int32)
        data.loops.foreach_get('vertex_index', ids)
        per = values
        if domain == 'FACE':
            sizes = np.empty(len(data.polygons), np.int32)
            data.polygons.foreach_get('loop_total', sizes)
            per = np.repeat(values, sizes, axis=0)
    sums = np.zeros((count, 3), np.float64)
    np.add.at(sums, ids, per)
    hits = np.bincount(ids, minlength=count)[:count]
    return (sums / np.maximum(hits, 1)[:, None]).astype(np.float32)


def velocity_steps(positions, velocity, seconds):
    """(3, N, 3) float64 points at the shutter's start, centre and end of
    points moving at ``velocity`` (units per second) over a shutter of
    ``seconds`` (Cycles' attr_create_motion_from_velocity), or None when a
    step is NaN or infinite in float32 (as Embree would hold it)."""
    p = np.asarray(positions, np.float64)
    v = np.asarray(velocity, np.float64)
    with np.errstate(over='ignore', invalid='ignore'):
        steps = np.stack([p - v * (0.5 * seconds), p, p + v * (0.5 * seconds)])
        finite = np.isfinite(steps.astype(np.float32)).all()
    return steps if finite else None


def primitive_key(inst):
    """(kind, name or persistent id) of a depsgraph instance, stable across frames."""
    if inst.is_instance:
        parent = inst.parent.original.name if inst.parent is not None else ''
        return ('instance', (parent, tuple(inst.persistent_id)))
    return ('object', inst.object.original.name)


def _read(source, inst, render):
    """(positions (N, 3), radii (N,) or None) of the source's points in the instance now."""
    obj = inst.object
    if source.kind == 'hair':
        for strands in particle_hair.particle_strands(obj, render):
            if strands.name == source.system:
                return np.asarray(strands.points, np.float64), None
        return None, None
    data = obj.data
    n = len(data.points)
    positions = np.empty(n * 3, np.float32)
    data.attributes['position'].data.foreach_get('vector', positions)
    positions = positions.reshape(n, 3).astype(np.float64)
    radii = None
    if source.kind == 'points':
        radii = np.full(n, float(np.asarray(source.item.radii).max(initial=0.0)), np.float32)
        if 'radius' in data.attributes:
            data.attributes['radius'].data.foreach_get('value', radii)
        radii = radii.astype(np.float64)
    if source.keep is not None:
        if len(source.keep) != n:
            return np.zeros((0, 3)), None   # the count changed: no deformation blur
        positions = positions[source.keep]
        radii = radii[source.keep] if radii is not None else None
    return positions, radii


class PrimitiveMotion:
    """The sources' matrices and points at the shutter's steps."""

    def __init__(self, sources, steps_for, deforms, render=True, seconds=0.0):
        self.sources = [s for s in sources if steps_for(s.obj) >= 2]
        self.steps = [steps_for(s.obj) for s in self.sources]
        self.deforms = [deforms(s.obj) for s in self.sources]
        # a velocity attribute stands for the points at the steps (Cycles' rule)
        self.velocity = [getattr(s.item, 'velocity', None) is not None for s in self.sources]
        self.seconds = seconds     # the shutter in seconds (velocity's scale)
        self.render = render
        self.by_key = {}
        for index, source in enumerate(self.sources):
            self.by_key.setdefault(source.key, []).append(index)
        self.seen = {}   # time -> {source index: (matrix, positions, radii)}

    def step_counts(self):
        return set(self.steps)

    def visit(self, time, inst):
        """Read the sources this depsgraph instance holds at ``time``."""
        wanted = self.by_key.get(primitive_key(inst)) if self.by_key else None
        if not wanted:
            return
        matrix = np.array(inst.matrix_world, np.float64)
        for index in wanted:
            source = self.sources[index]
            if source.kind == 'hair' and inst.object.type != 'MESH':
                continue
            reads = self.deforms[index] and not self.velocity[index]
            positions, radii = _read(self.sources[index], inst, self.render) if reads else (None, None)
            self.seen.setdefault(time, {})[index] = (matrix, positions, radii)

    def finish(self, step_times):
        """Fill the items' motion (``step_times(steps)``: the times of a
        count of steps); returns warnings."""
        warnings = []
        for index, source in enumerate(self.sources):
            found = [self.seen.get(t, {}).get(index) for t in step_times(self.steps[index])]
            item = source.item
            name = source.obj.name
            if self.deforms[index] and self.velocity[index]:
                warnings += _from_velocity(item, name, source.kind, self.seconds)
            if any(f is None for f in found):
                continue   # not there at every step: no transform motion (Cycles' rule)
            stack = np.array([f[0] for f in found])
            if not np.isfinite(stack).all():
                warnings.append(f"Object '{name}': its transform is NaN or infinite during the shutter, "
                                "rendered without motion blur")
            elif not np.allclose(stack, np.asarray(item.matrix)[None], rtol=0.0, atol=1e-9):
                item.motion = stack
            if self.deforms[index] and not self.velocity[index]:
                warnings += _deformation(item, name, found, source.kind)
        return warnings


def _from_velocity(item, name, kind, seconds):
    """Set item.motion_positions from its velocity attribute (radii stay
    the centre's), or return the warning why not."""
    centre = np.asarray(item.points if kind != 'points' else item.positions, np.float64)
    velocity = np.asarray(item.velocity)
    steps = velocity_steps(centre, velocity, seconds)
    if steps is None:
        return [f"Object '{name}': its velocity attribute is NaN or infinite (or beyond float range over "
                "the shutter), rendered without motion blur from it"]
    if velocity.any():
        item.motion_positions = steps
    return []


def _deformation(item, name, found, kind):
    """Set item.motion_positions (and a cloud's motion_radii) from the
    steps' points, or return the warning why not."""
    centre = np.asarray(item.points if kind != 'points' else item.positions, np.float64)
    if any(f[1] is None or f[1].shape != centre.shape for f in found):
        return [f"Object '{name}': its points change during the shutter, rendered without deformation blur"]
    steps = np.array([f[1] for f in found])
    radii = np.array([f[2] for f in found]) if kind == 'points' else None
    if not np.isfinite(steps).all() or (radii is not None and not np.isfinite(radii).all()):
        return [f"Object '{name}': NaN or infinite points during the shutter, rendered without deformation blur"]
    # (particle hair's keys come back through the emitter's inverse matrix: a little rounding)
    atol = 1e-6 if kind == 'hair' else 1e-7
    still = np.allclose(steps, centre[None], rtol=0.0, atol=atol)
    if radii is not None:
        radii = np.maximum(radii, 0.0)
        still = still and np.allclose(radii, np.asarray(item.radii, np.float64)[None], rtol=0.0, atol=1e-9)
    if not still:
        item.motion_positions = steps
        if radii is not None:
            item.motion_radii = radii
    return []
