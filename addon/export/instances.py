"""The depsgraph's object instances -> shared meshes plus placements.

``depsgraph.object_instances`` yields every visible object once, and every
copy made by collection instances, particle systems and geometry nodes.
Copies of the same geometry share one evaluated data block, so geometry is
keyed by that block's pointer and exported once (objects with modifiers get a
data block of their own, so they are never merged by mistake).
"""
import numpy as np

from .. import backend
from . import bulk_instances
from . import curve_attributes
from . import mesh as mesh_export
from . import fluid
from . import object_attributes
from . import particle_hair
from . import volume_object
from .motion import instance_key
from .primitive_motion import Source, primitive_key, velocity_of


class InstanceCollector:
    """Accumulates meshes and instances while walking the depsgraph."""

    def __init__(self, material_index, check=None, view_layer=None, scene=None, render=True):
        # material_index(obj) -> list of scene material indices per slot
        self.material_index = material_index
        self.render = render             # a final render's depsgraph (particle hair's render steps)
        self.view_layer = view_layer     # for holdout collections
        self.meshes = []
        self.instances = []
        self.mesh_of_key = {}
        self.skipped_types = set()
        self.warnings = []
        self.keys = []      # per instance: motion.instance_key (motion blur finds it at other times)
        self.points = []    # engine PointClouds (point cloud objects, geometry nodes' Points)
        self.curves = []    # engine HairCurves (Curves objects, hair particle systems)
        self.sources = []   # primitive_motion.Source of each of those (motion blur finds them again)
        self.light_sink = None  # light.LightCollector.add: light instances, read during the walk
        self._warned = set()
        self.check = check or (lambda: None)
        self.scene = scene
        self.depsgraph = None     # the walked depsgraph (a mesh's orco may need a second evaluation)
        self._attribute_requests = {}   # materials -> Attribute nodes of object / instancer / view layer type
        self.used = {}            # geometry key -> names of the objects and instancers that used it
        self.mesh_warnings = {}   # geometry key -> its export's warning
        self.exported = 0         # meshes exported by this walk
        self.want_keys = True     # motion.instance_key per instance (motion blur, the Vector pass)
        self.want_velocity = False   # read velocity attributes (motion blur, the Vector pass)
        self._groups = {}         # InstanceCollector._group's cache
        self._instance_type = backend.engine().Instance
        self.bulk = False         # note hosts for bulk_instances (collect_instances)
        self.host = None          # the last add()'s object when it may be a bulk instancer

    def add(self, inst):
        # Each RNA read costs about a microsecond, and a geometry-nodes
        # instancer brings 10^6 copies: every field is read once here.
        obj = inst.object  # for instances: the instanced (possibly temporary) object
        kind = obj.type
        self.host = None
        if kind == 'LIGHT':   # (whatever show_self says, as light.collect_lights)
            if self.light_sink is not None:
                self.light_sink(obj, np.array(inst.matrix_world, dtype=np.float64), inst)
            return
        is_instance = inst.is_instance
        # a mesh object that may instance by geometry nodes (bulk_instances)
        self.host = obj if self.bulk and kind == 'MESH' and not is_instance else None
        if kind == 'MESH' and inst.show_particles and len(obj.particle_systems):
            self._add_particle_hair(inst)
        if not is_instance and not inst.show_self:
            return  # e.g. a particle emitter with "Show Emitter" off
        if kind == 'POINTCLOUD':
            self._add_points(inst)
            return
        if kind == 'CURVES':
            self._add_curves(inst)
            return
        if kind not in mesh_export.MESHABLE_TYPES:
            if kind == 'VOLUME':
                self._add_volume(inst)
            elif kind in ('GPENCIL', 'GREASEPENCIL'):
                self.skipped_types.add(kind)
            return
        group = self._group(inst, obj, kind, is_instance)
        if group is None:
            return
        matrix = np.array(inst.matrix_world, dtype=np.float64)   # checked in bulk: drop_nonfinite()
        fields, requests = group
        attributes = (object_attributes.instance_values(inst, self.view_layer, self.scene, requests=requests)
                      if requests else {})
        random = _instance_random(inst) if is_instance else fields['random']
        self.instances.append(self._instance_type(matrix=matrix, object_attributes=attributes,
                                                  **dict(fields, random=random)))
        if self.want_keys:
            self.keys.append(instance_key(inst))

    def _group(self, inst, obj, kind, is_instance):
        """(the Instance fields every copy of this object under this
        instancer shares, the Attribute nodes its materials read), or None
        for geometry with nothing to draw.  Computed once per group: a
        geometry-nodes instancer's 10^6 copies of one mesh share all of it
        but the matrix and the random number (issue 25: export time)."""
        parent = inst.parent if is_instance else None
        key = (obj.original.as_pointer(), obj.data.as_pointer() if kind == 'MESH' else mesh_key(obj), is_instance,
               parent.original.as_pointer() if parent is not None else 0)
        if key in self._groups:
            return self._groups[key]
        mesh_id = self._mesh_id(obj)
        self._note_use(inst, obj)
        group = None
        if mesh_id is not None:
            fields = dict(
                mesh=mesh_id,
                materials=self.material_index(obj),
                name=obj.name,
                **ray_visibility(inst),
                holdout=is_holdout(inst, self.view_layer),
                shadow_catcher=bool(getattr(parent if parent is not None else obj, 'is_shadow_catcher', False)),
                **_pass_fields(inst),
                **object_info(inst))
            fields.update(self._fluid(obj))
            group = (fields, object_attributes.requested(obj, self._attribute_requests))
        self._groups[key] = group
        return group

    def _fluid(self, obj):
        """{'voxels': grids} of a gas fluid domain with simulated data ({}
        otherwise; one without data is named in a warning)."""
        grids, warning = fluid.domain_grids(obj)
        if warning:
            self._warn_once(('fluid', obj.name), warning)
        return {'voxels': grids} if grids else {}

    def _add_volume(self, inst):
        """A Volume object: its grids read through openvdb (volume_object.py)
        inside a box mesh with the Volume's material; one that cannot be
        read is named in a warning."""
        obj = inst.object
        key = ('volume', obj.original.as_pointer(), obj.data.as_pointer(), inst.is_instance)
        if key not in self._groups:
            self.check()
            materials = self.material_index(obj)   # no material: Cycles' default volume (MaterialTable)
            grids = volume_object.read_volume(obj)
            for text in grids.warnings:
                self._warn_once(('volume', obj.name, text), text)
            group = None
            if grids.bounds is not None:
                fields = dict(mesh=self._box_id(obj, grids.bounds, grids.generated), materials=materials,
                              name=obj.name,
                              **ray_visibility(inst), holdout=is_holdout(inst, self.view_layer),
                              **_pass_fields(inst), **object_info(inst),
                              voxels=grids.arrays, voxel_placements=grids.placements)
                group = fields
            self._groups[key] = group
        fields = self._groups[key]
        if fields is None:
            return
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        random = _instance_random(inst) if inst.is_instance else fields['random']
        density = volume_object.density_factor(obj, matrix)
        self.instances.append(self._instance_type(matrix=matrix, volume_density=density,
                                                  **dict(fields, random=random)))
        if self.want_keys:
            self.keys.append(instance_key(inst))

    def _box_id(self, obj, bounds, generated=None):
        """Index of a Volume object's box mesh (kept by a persistent cache
        while its bounds and its Generated box stay)."""
        corners = tuple(bounds) + tuple(generated or ())
        key = ('volume box', obj.name_full) + tuple(float(v) for c in corners for v in np.ravel(c))
        if key not in self.mesh_of_key:
            self.mesh_of_key[key] = len(self.meshes)
            self.meshes.append(volume_object.box_mesh(*bounds, _geometry_name(obj), generated))
        self.used.setdefault(key, set()).add(obj.name_full)
        return self.mesh_of_key[key]

    def _add_points(self, inst):
        """A point cloud as spheres of its radius attribute (Cycles' default
        radius 0.01 without one); points with a NaN or infinite position or
        radius are skipped with a warning, negative radii are 0."""
        obj = inst.object
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        data = obj.data
        n = len(data.points)
        if n == 0 or not np.isfinite(matrix).all():
            return
        self.check()
        positions = np.empty(n * 3, np.float32)
        data.attributes['position'].data.foreach_get('vector', positions)
        positions = positions.reshape(n, 3)
        radii = np.full(n, POINT_RADIUS, np.float32)
        if 'radius' in data.attributes:
            data.attributes['radius'].data.foreach_get('value', radii)
        attributes = {}
        for attr in data.attributes:
            if attr.domain == 'POINT' and attr.data_type in ('FLOAT_COLOR', 'BYTE_COLOR') and len(attr.data) == n:
                rgba = np.empty(n * 4, np.float32)
                attr.data.foreach_get('color', rgba)   # linear (Blender converts byte colours)
                attributes[attr.name] = rgba.reshape(n, 4)
        good = np.isfinite(positions).all(axis=1) & np.isfinite(radii)
        keep = None if good.all() else good
        if not good.all():
            self._warn_once(('points', obj.name), f"Object '{obj.name}': {int((~good).sum())} points with "
                            "a NaN or infinite position or radius were skipped")
            positions, radii = positions[good], radii[good]
            attributes = {k: v[good] for k, v in attributes.items()}
        if len(attributes) == 1:
            attributes[''] = next(iter(attributes.values()))   # the default colour attribute
        self.points.append(backend.engine().PointCloud(
            positions=positions, radii=np.maximum(radii, 0.0), matrix=matrix,
            materials=self.material_index(obj), name=obj.name, attributes=attributes or None,
            **ray_visibility(inst), **object_info(inst),
            pass_index=int(getattr(inst.object, 'pass_index', 0))))
        if self.want_velocity:
            self.points[-1].velocity = self._velocity(obj, data, n, keep)
        self._source(self.points[-1], inst, 'points', keep)

    def _add_curves(self, inst):
        """A Curves object as round Catmull-Rom strands of its radius
        attribute (Cycles: radius 0 without one, so nothing renders); curves
        with a NaN or infinite point or radius are skipped with a warning."""
        obj = inst.object
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        data = obj.data
        n, count = len(data.points), len(data.curves)
        if n == 0 or count == 0 or not np.isfinite(matrix).all():
            return
        self.check()
        positions = np.empty(n * 3, np.float32)
        data.attributes['position'].data.foreach_get('vector', positions)
        positions = positions.reshape(n, 3)
        radii = np.zeros(n, np.float32)
        if 'radius' in data.attributes:
            data.attributes['radius'].data.foreach_get('value', radii)
        offsets = np.empty(count + 1, np.int32)
        data.curve_offset_data.foreach_get('value', offsets)
        bad_point = ~(np.isfinite(positions).all(axis=1) & np.isfinite(radii))
        keep_points = keep_curves = None
        if bad_point.any():
            per_curve = np.add.reduceat(bad_point.astype(np.int64), offsets[:-1]) > 0
            self._warn_once(('curves', obj.name), f"Object '{obj.name}': {int(per_curve.sum())} curves with "
                            "a NaN or infinite point or radius were skipped")
            keep = np.repeat(~per_curve, np.diff(offsets))
            keep_points, keep_curves = keep, ~per_curve
            positions, radii = positions[keep], radii[keep]
            sizes = np.diff(offsets)[~per_curve]
            offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
            if len(sizes) == 0:
                return
        point_attrs, curve_attrs, uv = curve_attributes.curve_attributes(
            data, keep_points, keep_curves,
            lambda text: self._warn_once(('curve attributes', obj.name, text), f"Object '{obj.name}': {text}"))
        self.curves.append(backend.engine().HairCurves(
            points=positions, radii=np.maximum(radii, 0.0), offsets=offsets, matrix=matrix,
            normals=_curve_normals(data, n, keep_points),
            materials=self.material_index(obj), name=obj.name, point_attributes=point_attrs or None,
            curve_attributes=curve_attrs or None, uv=uv,
            **ray_visibility(inst), **object_info(inst),
            pass_index=int(getattr(inst.object, 'pass_index', 0))))
        if self.want_velocity:
            self.curves[-1].velocity = self._velocity(obj, data, n, keep_points)
        self._source(self.curves[-1], inst, 'curves', keep_points)

    def _add_particle_hair(self, inst):
        """The emitter's hair particle systems as strands (particle_hair.py),
        placed with the instance, with the material of each system's slot."""
        obj = inst.object
        matrix = np.array(inst.matrix_world, dtype=np.float64)
        if not np.isfinite(matrix).all():
            return
        slots = self.material_index(obj)
        for strands in particle_hair.particle_strands(obj, self.render, self.check):
            if strands.skipped:
                self._warn_once(('particle hair', obj.name, strands.name),
                                f"Object '{obj.name}', particle system '{strands.name}': {strands.skipped} strands "
                                "with a NaN or infinite key were skipped")
            if strands.coincident:
                self._warn_once(('coincident hair', obj.name, strands.name),
                                f"Object '{obj.name}', particle system '{strands.name}': {strands.coincident} strands "
                                "coincide exactly with another (Distribution Jittered places some hairs twice); Cycles "
                                "renders such twins darker than one strand, Ember as one (rendered brighter; "
                                "Distribution Random avoids them)")
            if len(strands.offsets) < 2:
                continue
            slot = min(strands.slot, len(slots) - 1) if len(slots) else 0
            self.curves.append(backend.engine().HairCurves(
                points=strands.points.astype(np.float32), radii=strands.radii.astype(np.float32),
                offsets=strands.offsets.astype(np.int32), matrix=matrix,
                materials=[slots[slot]] if len(slots) else slots, name=f"{obj.name} {strands.name}",
                curve_attributes=strands.curve_attributes or None, uv=strands.uv, first_curve=strands.first_curve,
                texspace=mesh_export.texspace_of(obj.data),
                **ray_visibility(inst), **object_info(inst),
                pass_index=int(getattr(obj, 'pass_index', 0))))
            self._source(self.curves[-1], inst, 'hair', system=strands.name)

    def _source(self, item, inst, kind, keep=None, system=None):
        """Remember where a point cloud or curve set came from (motion blur)."""
        if self.want_keys:
            parent = inst.parent if inst.is_instance and inst.parent is not None else inst.object
            self.sources.append(Source(item, primitive_key(inst), kind, parent.original, keep, system))

    def _mesh_id(self, obj):
        """Index of the object's geometry in self.meshes, exporting it once."""
        key = mesh_key(obj)
        if key not in self.mesh_of_key:
            self.check()
            self.exported += 1
            told = []
            mesh = mesh_export.mesh_from_object(obj, _geometry_name(obj), self.check, self.depsgraph, told.append)
            dropped = mesh_export.drop_nonfinite_triangles(mesh) if mesh is not None else 0
            if dropped:
                told.append(f"Object '{obj.name}': {dropped} triangles with "
                            "NaN or infinite vertex positions were skipped")
            if told:
                self.mesh_warnings[key] = "; ".join(told)
            if mesh is None or len(mesh.triangles) == 0:
                self.mesh_of_key[key] = None
            else:
                self.mesh_of_key[key] = len(self.meshes)
                self.meshes.append(mesh)
                if self.want_velocity and obj.type == 'MESH':
                    mesh.velocity = self._velocity(obj, obj.data, len(mesh.positions))
        if key in self.mesh_warnings:   # also for geometry a persistent cache kept
            self._warn_once(('vertices', key), self.mesh_warnings[key])
        if mesh_export.uses_adaptive_subdivision(obj):
            self._warn_once(('adaptive', obj.name), f"Object '{obj.name}': adaptive subdivision is not rendered "
                            "(its displacement moves the vertices of the modifiers' mesh)")
        return self.mesh_of_key[key]

    def _velocity(self, obj, data, count, keep=None):
        """The geometry's velocity attribute (primitive_motion.velocity_of)
        for the points the export kept, or None; a velocity Ember cannot
        read is named once."""
        velocity, warning = velocity_of(data, count)
        if warning:
            self._warn_once(('velocity', obj.name), f"Object '{obj.name}': {warning}")
        return velocity if velocity is None or keep is None else velocity[keep]

    def _note_use(self, inst, obj):
        """Record which objects use each geometry key (Persistent Data
        forgets a key when one of them changes geometry)."""
        owners = self.used.setdefault(mesh_key(obj), set())
        owners.add(obj.name_full)
        if inst.is_instance and inst.parent is not None:
            owners.add(inst.parent.name_full)


    def drop_nonfinite(self):
        """Leave out the instances whose transform is NaN or infinite, with
        a warning naming the object (one vectorized test of every matrix;
        bulk runs, bulk_instances.take's, test theirs)."""
        runs = [item for item in self.instances if isinstance(item, tuple)]
        single = [inst for inst in self.instances if not isinstance(inst, tuple)]
        if runs:
            self.instances = [self._finite_run(item) if isinstance(item, tuple) else item for item in self.instances]
        if not single:
            return
        bad = ~np.isfinite(np.stack([inst.matrix for inst in single]).reshape(len(single), -1)).all(1)
        if not bad.any():
            return
        bad_ids = {id(inst) for inst, b in zip(single, bad) if b}
        for inst in single:
            if id(inst) in bad_ids:
                self._warn_once(('matrix', inst.name), f"Object '{inst.name}' skipped: its transform is NaN or infinite")
        if self.want_keys:
            self.keys = [key for key, inst in zip(self.keys, self.instances) if id(inst) not in bad_ids]
        self.instances = [inst for inst in self.instances if isinstance(inst, tuple) or id(inst) not in bad_ids]

    def _finite_run(self, run):
        templates, which, matrices, randoms = run
        good = np.isfinite(matrices).all(axis=(1, 2))
        if good.all():
            return run
        for k in np.unique(which[~good]):
            name = templates[k].name
            self._warn_once(('matrix', name), f"Object '{name}' skipped: its transform is NaN or infinite")
        return templates, which[good], matrices[good], randoms[good]

    def _warn_once(self, key, message):
        if key not in self._warned:
            self._warned.add(key)
            self.warnings.append(message)


POINT_RADIUS = 0.01   # Cycles' radius of points without a radius attribute

VISIBILITY_FLAGS = ('visible_camera', 'visible_diffuse', 'visible_glossy', 'visible_transmission',
                    'visible_shadow')


def is_holdout(inst, view_layer=None):
    """Object > Visibility > Mask > Holdout, or a holdout collection of the
    view layer (Cycles: the instancer's flag for its instances)."""
    obj = inst.parent if inst.is_instance and inst.parent is not None else inst.object
    for candidate in (obj, inst.object):
        test = getattr(candidate, 'holdout_get', None)
        if test is not None and view_layer is not None:
            try:
                if test(view_layer=view_layer):
                    return True
            except (TypeError, RuntimeError):
                pass
        if getattr(candidate, 'is_holdout', False):
            return True
    return False


def ray_visibility(inst):
    """Object > Visibility > Ray Visibility as engine Instance fields.  An
    instance is hidden from the rays its instancer is hidden from (Cycles)."""
    flags = {}
    parent = inst.parent if inst.is_instance else None
    for name in VISIBILITY_FLAGS:
        visible = bool(getattr(inst.object, name, True))
        if parent is not None:
            visible = visible and bool(getattr(parent, name, True))
        flags[name] = visible
    return flags


def object_info(inst):
    """Object Info node data: colour and Cycles' random number
    (float32(random_id) / 2^32, random_id read as uint32)."""
    obj = inst.object
    if inst.is_instance:
        random = _instance_random(inst)
    else:
        # Cycles: hash_uint2(hash_string(name), 0) for objects that are not instances.
        h = 0
        for ch in obj.name.encode('utf-8'):
            h = (h * 37 + ch) & 0xFFFFFFFF
        rid = int(backend.engine().hash_uint(np.uint32(h), np.uint32(0)))
        random = float(np.float32(rid) * np.float32(1.0 / 4294967296.0))
    return {'color': tuple(float(c) for c in tuple(getattr(obj, 'color', (1.0, 1.0, 1.0)))[:3]),
            'random': random}


def _instance_random(inst):
    """A copy's Object Info Random: its random_id as uint32, times 2^-32 in
    float32 (Cycles)."""
    return uint32_unit_float32(int(getattr(inst, 'random_id', 0)) & 0xFFFFFFFF)


def uint32_unit_float32(rid):
    """float(np.float32(rid) * np.float32(2^-32)) for a uint32 ``rid``,
    without NumPy scalars (ten times faster, once per instance): float32
    keeps 24 significant bits, rounded half to even (Python's round), and
    the power-of-two scale is exact."""
    shift = rid.bit_length() - 24
    if shift > 0:
        rid = round(rid / (1 << shift)) << shift
    return rid / 4294967296.0


def mesh_key(obj):
    """The key geometry is shared by: a mesh's evaluated data block; a
    curve's or text's mesh depends on the object's own modifiers, not only on
    its data block, so it is shared only between copies of the object."""
    if obj.type == 'MESH':
        return obj.data.as_pointer()
    return ('object', obj.name_full)


def _geometry_name(obj):
    data = obj.data
    return data.name if data is not None else obj.name


def _curve_normals(data, n, keep_points):
    """(N, 3) Blender's curve normals per point (Curves.normals: what Cycles'
    Huang hair aligns elliptical fibres with), or None where bpy has none."""
    normals = getattr(data, 'normals', None)
    if normals is None or len(normals) != n:
        return None
    out = np.empty(n * 3, np.float32)
    normals.foreach_get('vector', out)
    out = out.reshape(n, 3)
    return out if keep_points is None else out[keep_points]


def collect_instances(depsgraph, material_index, check=None, keys=None, points=None, curves=None, cache=None,
                      light_sink=None, sources=None, bulk=False):
    """Walk every object instance; returns (meshes, instances, warnings).
    ``check()`` (which raises to cancel) runs every 256 instances and before
    each mesh is exported; ``keys`` (a list) receives each instance's key;
    ``light_sink(object, matrix, inst)`` (light.LightCollector.add) each light
    instance's, so one walk serves both (10^6 instances: 1.6 s a walk).
    ``cache``: a persistent.MeshCache whose meshes serve where the
    depsgraph's updates left them valid (Persistent Data).  ``bulk``: read
    geometry-nodes instancers' copies in bulk (bulk_instances; not with
    ``keys`` or ``cache``), the instances then an engine InstanceBatch;
    raises bulk_instances.BulkMismatch when the depsgraph's copies were not
    the ones foreseen (export again without)."""
    view_layer = getattr(depsgraph, 'view_layer', None)
    collector = InstanceCollector(material_index, check, view_layer, getattr(depsgraph, 'scene', None),
                                  render=getattr(depsgraph, 'mode', 'RENDER') == 'RENDER')
    collector.want_keys = collector.want_velocity = keys is not None
    collector.depsgraph = depsgraph
    collector.light_sink = light_sink
    if cache is not None:
        cache.begin(depsgraph, getattr(view_layer, 'name', ''))
        collector.meshes, collector.mesh_of_key = cache.meshes, cache.mesh_of_key
        collector.mesh_warnings = cache.warnings_of
    collector.bulk = bulk and keys is None and cache is None
    walk = iter(depsgraph.object_instances)
    for count, inst in enumerate(walk):
        if count % 256 == 255:
            collector.check()
        collector.add(inst)
        if collector.host is not None:
            plan = bulk_instances.plan(collector.host)
            if plan is not None:
                bulk_instances.take(collector, walk, plan)
    collector.drop_nonfinite()
    if keys is not None:
        keys.extend(collector.keys)
    if points is not None:
        points.extend(collector.points)
    if curves is not None:
        curves.extend(collector.curves)
    if sources is not None:
        sources.extend(collector.sources)
    warnings = collector.warnings + [f"Ember skips {kind.lower()} objects (not supported yet)"
                for kind in sorted(collector.skipped_types)]
    if cache is not None:
        meshes, instances = cache.end(collector.used, collector.instances, collector.exported)
        return meshes, instances, warnings
    return collector.meshes, backend.engine().join_instances(collector.instances), warnings


def _pass_fields(inst):
    """Object Index and the Cryptomatte asset (the topmost parent's name; for
    instances, the instancer's), as Cycles."""
    obj = inst.parent if inst.is_instance and inst.parent is not None else inst.object
    root = obj
    while root.parent is not None:
        root = root.parent
    return {'pass_index': int(getattr(inst.object, 'pass_index', 0)), 'asset': root.name}
