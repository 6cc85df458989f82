"""Motion blur: the scene at the shutter's steps (Cycles' BlenderSync::sync_motion).

With Render > Motion Blur on, Cycles exports the scene at the shutter's
centre (frame + shutter / 2 for Position 'Start', - shutter / 2 for 'End')
and then, for each motion step, sets the frame to centre + t shutter / 2
(t = -1 ... 1 over the steps) and reads the objects' matrices, the
camera's and the vertex positions of deforming meshes.  Objects take
2^(motion_steps - 1) + 1 steps (Object > Motion Blur > Steps, default 1: 3
steps); Object > Motion Blur off keeps an object still, Deformation off
keeps its mesh undeformed.  An object whose steps all equal its centre gets
no motion, so a still scene renders as without motion blur.  The camera's
lens is read at the shutter's ends too (focal-length animation), and the
shutter curve and rolling shutter go to the engine camera (set_shutter).
Lamps are not read at the steps: Cycles keeps them at the centre.

Geometry with a ``velocity`` attribute (units per second: point clouds,
Alembic caches, geometry nodes' Store Named Attribute) moves by it instead
of its steps, as Cycles' attr_create_motion_from_velocity: three steps
P - v s / 2, P, P + v s / 2 with s the shutter in seconds (frames over
fps / fps_base; the Vector pass's 2 frames), whatever the object's Steps,
its vertices never read at the steps (sync_motion skips geometry whose
motion an attribute gave), so meshes whose topology changes between frames
blur too.  Object > Motion Blur off or Deformation off: no velocity blur.

The render engine's ``frame_set`` re-evaluates the render's depsgraph; the
original frame is set again afterwards.
"""
import math

import numpy as np

from . import mesh as mesh_export
from .primitive_motion import PrimitiveMotion, velocity_steps


def shutter(scene, is_preview=False):
    """(shutter in frames, position) when the render blurs motion, else None
    (motion blur off, a preview, or a shutter of 0 frames)."""
    render = scene.render
    if is_preview or not render.use_motion_blur:
        return None
    length = float(render.motion_blur_shutter)
    if not length > 0.0 or not math.isfinite(length):
        return None
    position = getattr(render, 'motion_blur_position', None)
    if position is None:   # before Blender 3.x moved it to the render settings
        position = getattr(getattr(scene, 'cycles', None), 'motion_blur_position', 'CENTER')
    return length, position


def centre_time(scene, blur):
    """The frame (with subframe) at the shutter's centre."""
    length, position = blur
    delta = {'START': 0.5 * length, 'END': -0.5 * length}.get(position, 0.0)
    return scene.frame_current + scene.frame_subframe + delta


def set_time(engine, time):
    """Evaluate the render depsgraph at a frame with subframe."""
    frame = math.floor(time)
    engine.frame_set(int(frame), float(time - frame))


def object_steps(obj):
    """Cycles' motion steps of an object: 0 when its motion blur is off."""
    props = getattr(obj, 'cycles', None)
    if props is None:
        return 3
    if not getattr(props, 'use_motion_blur', True):
        return 0
    steps = max(1, int(getattr(props, 'motion_steps', 1)))
    return (2 << (steps - 1)) + 1


def _deform_motion_on(obj):
    """Object > Motion Blur > Deformation."""
    return bool(getattr(getattr(obj, 'cycles', None), 'use_deform_motion', True))


def _step_times(centre, length, steps):
    return [centre + (-1.0 + 2.0 * k / (steps - 1)) * 0.5 * length for k in range(steps)]


def add_motion(engine, depsgraph, exported, keys, blur, centre, camera_object, steps_of=None, sources=(),
               deforms_of=None):
    """Fill Instance.motion, Mesh.motion and Camera.motion of ``exported``
    (exported at the shutter's centre, frame ``centre``; ``keys`` names each
    instance as ``instance_key`` does), and the motion of its point clouds
    and curve sets (``sources``: primitive_motion.Source of each) by
    evaluating the scene at every step (``steps_of(object)``: Cycles'
    object_steps unless given; ``deforms_of(object)``: whether its
    deformation counts, Object > Motion Blur > Deformation unless given).
    Returns warnings."""
    steps_for = steps_of or object_steps
    deform_on = deforms_of or _deform_motion_on
    scene = depsgraph.scene
    length = blur[0]
    seconds = shutter_seconds(scene, length)
    primitives = PrimitiveMotion(sources, steps_for, deform_on,
                                 render=getattr(depsgraph, 'mode', 'RENDER') == 'RENDER', seconds=seconds)
    result = exported.scene
    wanted = {}          # steps -> instance indices
    for index, key in enumerate(keys):
        if key is None:
            continue
        steps = steps_for(key[2])
        if steps >= 2:
            wanted.setdefault(steps, []).append(index)
    camera_steps = steps_for(camera_object.original)
    all_steps = sorted(set(wanted) | ({camera_steps} if camera_steps >= 2 else set()) | primitives.step_counts())
    # Cycles always reads the camera at the shutter's ends (its fov_pre / fov_post)
    ends = (centre - 0.5 * length, centre + 0.5 * length)
    times = sorted({t for s in all_steps for t in _step_times(centre, length, s)} | set(ends))
    matrices = {}        # time -> {instance key: matrix}
    positions = {}       # time -> {mesh index: engine Mesh there}
    cameras = {}
    lenses = {}
    deforming = {}
    moving_by_velocity = {}   # mesh index -> the key of an instance using it
    for index, key in enumerate(keys):
        if key is None or not deform_on(key[2]):
            continue
        mesh_index = result.instances[index].mesh
        if getattr(result.meshes[mesh_index], 'velocity', None) is not None:
            if steps_for(key[2]) >= 2:
                moving_by_velocity.setdefault(mesh_index, key)
        elif key[3] and key[2].type == 'MESH' and key[2].is_deform_modified(scene, 'RENDER'):
            deforming.setdefault(mesh_index, key)
    warnings = _velocity_motion(result.meshes, moving_by_velocity, seconds)
    for t in times:
        set_time(engine, t)
        matrices[t] = {}
        for inst in depsgraph.object_instances:
            key = instance_key(inst)
            if key is not None:
                matrices[t][key[:2]] = np.array(inst.matrix_world, np.float64)
            primitives.visit(t, inst)
        cam = camera_object.original.evaluated_get(depsgraph)
        cameras[t] = np.array(cam.matrix_world, np.float64)
        lenses[t] = float(getattr(cam.data, 'lens', 0.0))
        positions[t] = {}
        for mesh_index, key in deforming.items():
            obj = key[2].evaluated_get(depsgraph)
            positions[t][mesh_index] = mesh_export.mesh_from_object(obj, obj.name)
    set_time(engine, centre)
    for steps, indices in wanted.items():
        step_times = _step_times(centre, length, steps)
        for index in indices:
            inst = result.instances[index]
            found = [matrices[t].get(keys[index][:2]) for t in step_times]
            if any(m is None for m in found):
                continue   # the instance does not exist at every step: no motion (Cycles' rule)
            stack = np.array(found)
            if not np.isfinite(stack).all():
                warnings.append(f"Object '{inst.name}': its transform is NaN or infinite during the shutter, "
                                "rendered without motion blur")
                continue
            if not np.allclose(stack, np.asarray(inst.matrix)[None], rtol=0.0, atol=1e-9):
                inst.motion = stack
    for mesh_index, key in deforming.items():
        mesh = result.meshes[mesh_index]
        steps = steps_for(key[2])
        if steps < 2:
            continue
        found = [positions[t].get(mesh_index) for t in _step_times(centre, length, steps)]
        if any(m is None or m.positions.shape != mesh.positions.shape
               or not np.array_equal(m.triangles, mesh.triangles) for m in found):
            warnings.append(f"Object '{key[2].name}': its vertices or faces change during the shutter, "
                            "rendered without deformation blur")
            continue
        stack = np.array([m.positions for m in found], np.float64)
        if not np.isfinite(stack).all():
            warnings.append(f"Object '{key[2].name}': NaN or infinite vertices during the shutter, "
                            "rendered without deformation blur")
            continue
        if not np.allclose(stack, np.asarray(mesh.positions, np.float64)[None], rtol=0.0, atol=1e-7):
            mesh.motion = stack
            if mesh.normals is not None and all(m.normals is not None for m in found):
                mesh.motion_normals = np.array([m.normals for m in found], np.float64)
    warnings += primitives.finish(lambda steps: _step_times(centre, length, steps))
    _drop_velocities(result)
    set_shutter(result.camera, scene, [lenses[t] for t in ends])
    if camera_steps >= 2:
        stack = np.array([mesh_export_unit_axes(cameras[t]) for t in _step_times(centre, length, camera_steps)])
        if np.isfinite(stack).all() and not np.allclose(stack, np.asarray(result.camera.matrix)[None],
                                                        rtol=0.0, atol=1e-9):
            result.camera.motion = stack
    return warnings


def shutter_seconds(scene, length):
    """The shutter of ``length`` frames in seconds (0 for a frame rate that is 0 or not finite)."""
    rate = float(scene.render.fps) / float(scene.render.fps_base or 1.0)
    seconds = length / rate if rate > 0.0 else 0.0
    return seconds if math.isfinite(seconds) else 0.0


def _velocity_motion(meshes, moving, seconds):
    """Mesh.motion of the meshes ``moving`` (index -> instance key) from
    their velocity attribute (Cycles' three steps) and their shading
    normals there (``_step_normals``); returns warnings."""
    warnings = []
    for mesh_index, key in moving.items():
        mesh = meshes[mesh_index]
        steps = velocity_steps(mesh.positions, mesh.velocity, seconds)
        if steps is None:
            warnings.append(f"Object '{key[2].name}': its velocity attribute is NaN or infinite (or beyond float "
                            "range over the shutter), rendered without motion blur from it")
        elif np.asarray(mesh.velocity).any():
            mesh.motion = steps
            if mesh.normals is not None:
                mesh.motion_normals = _step_normals(mesh, steps)
    return warnings


def _step_normals(mesh, steps):
    """Per-corner shading normals (3, T, 3, 3) at velocity's three steps:
    the centre's, and at the ends Cycles' Mesh::add_vertex_normals of the
    moved vertices (a velocity gives no motion normals, so Cycles computes
    them: each vertex the normalized sum of its triangles' unit normals, a
    triangle of no area counting as (1, 0, 0))."""
    tri = np.asarray(mesh.triangles, np.int64)
    out = []
    for k, p in enumerate(steps):
        if k == 1:
            out.append(np.asarray(mesh.normals, np.float64))
            continue
        face = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
        length = np.linalg.norm(face, axis=1)
        face = np.where(length[:, None] > 0, face / np.where(length > 0, length, 1.0)[:, None], [1.0, 0.0, 0.0])
        vertex = np.zeros_like(p)
        np.add.at(vertex, tri.ravel(), np.repeat(face, 3, axis=0))
        vertex /= np.maximum(np.linalg.norm(vertex, axis=1), 1e-300)[:, None]
        out.append(vertex[tri])
    return np.array(out)


def _drop_velocities(scene):
    """Forget the velocity attributes read for motion (the engine does not use them)."""
    for item in list(scene.meshes) + list(getattr(scene, 'points', ()) or ()) + list(getattr(scene, 'curves', ()) or ()):
        vars(item).pop('velocity', None)


def set_shutter(camera, scene, end_lenses):
    """The engine camera's shutter curve, rolling shutter and lens at the
    shutter's ends (Cycles' sync_camera and sync_camera_motion)."""
    camera.shutter_curve = shutter_curve(scene.render)
    props = getattr(scene, 'cycles', None)
    camera.rolling_shutter = str(getattr(props, 'rolling_shutter_type', 'NONE'))
    camera.rolling_duration = float(getattr(props, 'rolling_shutter_duration', 0.1))
    if camera.kind == 'PERSP' and any(lens != camera.lens for lens in end_lenses):
        camera.lens_motion = tuple(end_lenses)


def shutter_curve(render, size=256):
    """Render > Motion Blur > Shutter Curve at ``size`` points (Cycles'
    curvemapping_to_array), None when it is flat at 1 (the default)."""
    mapping = getattr(render, 'motion_blur_shutter_curve', None)
    if mapping is None:
        return None
    mapping.update()
    curve = mapping.curves[0]
    values = np.array([mapping.evaluate(curve, i / (size - 1)) for i in range(size)], np.float64)
    return None if np.all(values == 1.0) else values


def mesh_export_unit_axes(matrix):
    """Camera-to-world without scale (as the camera export)."""
    out = np.array(matrix, np.float64)
    for axis in range(3):
        length = np.linalg.norm(out[:3, axis])
        if length > 0:
            out[:3, axis] /= length
    return out


def instance_key(inst):
    """(kind, name or persistent id, original object, is a real object) of a
    depsgraph object instance, stable across frames; None for what the
    export skips."""
    obj = inst.object
    if obj.type not in mesh_export.MESHABLE_TYPES:
        return None
    if inst.is_instance:
        parent = inst.parent.original.name if inst.parent is not None else ''
        return ('instance', (parent, tuple(inst.persistent_id)), obj.original, False)
    return ('object', obj.original.name, obj.original, True)


# ----------------------------------------------------------------------------
# The Vector pass (engine/vector_pass.py)

def wants_vector(depsgraph, blur, is_preview):
    """Whether to export frame - 1 and frame + 1 for the Vector pass: Cycles
    writes it only with motion blur off, in final renders."""
    return blur is None and not is_preview and bool(getattr(depsgraph.view_layer, 'use_pass_vector', False))


def add_vector_motion(engine, depsgraph, exported, keys, frame, camera_object, sources=()):
    """Fill ``vector_motion`` of ``exported`` (exported at ``frame``) with
    the scene at frame - 1, frame, frame + 1 (Cycles' MOTION_PASS: three
    steps for every object and its deformation, whatever its motion blur
    settings), and ``vector_positions`` of its point clouds and curve sets
    (``sources``, as add_motion's), leaving the render still.  Returns
    warnings."""
    warnings = add_motion(engine, depsgraph, exported, keys, (2.0, 'CENTER'), frame, camera_object,
                          steps_of=lambda obj: 3, sources=sources, deforms_of=lambda obj: True)
    result = exported.scene
    result.camera.lens_motion = None     # (the render stays still)
    for item in list(result.instances) + list(result.meshes) + [result.camera]:
        item.vector_motion, item.motion = item.motion, None
        if hasattr(item, 'motion_normals'):
            item.motion_normals = None
    for item in list(getattr(result, 'points', ()) or ()) + list(getattr(result, 'curves', ()) or ()):
        item.vector_motion, item.motion = item.motion, None
        item.vector_positions, item.motion_positions = item.motion_positions, None
        if hasattr(item, 'motion_radii'):
            item.motion_radii = None
    return [w.replace("rendered without motion blur", "its Vector pass is 0")
             .replace("rendered without deformation blur", "its Vector pass ignores deformation")
            for w in warnings]
