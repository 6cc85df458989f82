"""The scene camera and render resolution -> engine.scene.Camera.

The frame size follows Blender's own arithmetic (integer percentage scaling,
border window truncated to whole pixels) so that Ember's pixels line up with
Cycles' exactly.
"""
import numpy as np

from .. import backend


def frame_size(render):
    """Full frame in pixels: resolution times percentage, as Blender rounds it."""
    pct = render.resolution_percentage
    return render.resolution_x * pct // 100, render.resolution_y * pct // 100


def border_window(render):
    """(x, y, width, height) in pixels of the rendered window, y from the bottom.

    Blender truncates border * size to whole pixels (in single precision);
    without a border, or with a degenerate one, the window is the full frame.
    """
    width, height = frame_size(render)
    if not render.use_border:
        return 0, 0, width, height
    fx = np.float32(width)
    fy = np.float32(height)
    xmin = int(np.float32(render.border_min_x) * fx)
    xmax = int(np.float32(render.border_max_x) * fx)
    ymin = int(np.float32(render.border_min_y) * fy)
    ymax = int(np.float32(render.border_max_y) * fy)
    if xmax - xmin < 1 or ymax - ymin < 1:
        return 0, 0, width, height
    return xmin, ymin, xmax - xmin, ymax - ymin


def _without_scale(matrix):
    """Camera-to-world with unit axes: Blender ignores the camera's scale."""
    out = np.array(matrix, dtype=np.float64)
    for axis in range(3):
        length = np.linalg.norm(out[:3, axis])
        if length == 0.0:
            raise ValueError("it has a zero scale")
        out[:3, axis] /= length
    return out


def focus_distance(cam_obj, matrix):
    """Distance to the focal plane, as Cycles measures it (along the view axis)."""
    dof = cam_obj.data.dof
    target = dof.focus_object
    if target is None:
        return float(dof.focus_distance)
    view = -matrix[:3, 2]
    offset = np.array(target.matrix_world.translation) - matrix[:3, 3]
    return float(abs(np.dot(view, offset)))


def camera_from_blender(cam_obj, render):
    """Returns (engine Camera, warnings)."""
    renderer = backend.engine()
    warnings = []
    data = cam_obj.data
    matrix = _without_scale(cam_obj.matrix_world)
    kind = data.type
    if kind not in ('PERSP', 'ORTHO', 'PANO'):
        warnings.append(f"Camera '{cam_obj.name}': {kind.lower()} cameras are not supported, "
                        "rendered as perspective")
        kind = 'PERSP'
    width, height = frame_size(render)
    x, y, w, h = border_window(render)
    border = None
    if (x, y, w, h) != (0, 0, width, height):
        border = (x / width, (x + w) / width, y / height, (y + h) / height)
    fstop = float(data.dof.aperture_fstop) if data.dof.use_dof else 0.0
    aperture = 0.0
    if fstop > 0.0:
        # Cycles: aperture radius = focal length / (2 f-stop) (panoramic too); 1/(2 f) for ortho.
        aperture = (data.lens * 1e-3 if kind != 'ORTHO' else 1.0) / (2.0 * max(fstop, 1e-5))
    camera = renderer.Camera(
        matrix=matrix, kind=kind, lens=float(data.lens),
        sensor_width=float(data.sensor_width), sensor_height=float(data.sensor_height),
        sensor_fit=data.sensor_fit, shift_x=float(data.shift_x), shift_y=float(data.shift_y),
        ortho_scale=float(data.ortho_scale), clip_start=float(data.clip_start),
        clip_end=float(data.clip_end), focus_distance=focus_distance(cam_obj, matrix),
        fstop=fstop, aperture_radius=aperture, resolution=(width, height),
        pixel_aspect=(float(render.pixel_aspect_x), float(render.pixel_aspect_y)),
        border=border, **(panorama(data) if kind == 'PANO' else {}),
    )
    return camera, warnings


# Blender's panorama settings and their defaults (Blender 5.0's DNA defaults).
PANORAMA_DEFAULTS = (
    ("panorama_type", "FISHEYE_EQUISOLID"), ("fisheye_fov", np.pi), ("fisheye_lens", 10.5),
    ("latitude_min", -0.5 * np.pi), ("latitude_max", 0.5 * np.pi), ("longitude_min", -np.pi),
    ("longitude_max", np.pi), ("fisheye_polynomial_k0", -1.1735100088117179e-05),
    ("fisheye_polynomial_k1", -0.019988736137747765), ("fisheye_polynomial_k2", -3.3525000162626384e-06),
    ("fisheye_polynomial_k3", 3.099300101894187e-06), ("fisheye_polynomial_k4", -2.6100000383166844e-08),
    ("central_cylindrical_range_u_min", -np.pi), ("central_cylindrical_range_u_max", np.pi),
    ("central_cylindrical_range_v_min", -1.0), ("central_cylindrical_range_v_max", 1.0),
    ("central_cylindrical_radius", 1.0))


def panorama(data):
    """A panoramic camera's settings, as Cycles' blender_camera_from_object
    reads them: on the Camera datablock since Blender 4.0 (on its ``cycles``
    settings before; the central cylinder is Blender 4.4's)."""
    source = data if hasattr(data, 'panorama_type') else getattr(data, 'cycles', data)
    got = {name: getattr(source, name, default) for name, default in PANORAMA_DEFAULTS}
    number = {name: float(value) for name, value in got.items() if name != 'panorama_type'}
    return dict(
        panorama_type=str(got['panorama_type']), fisheye_fov=number['fisheye_fov'],
        fisheye_lens=number['fisheye_lens'], latitude=(number['latitude_min'], number['latitude_max']),
        longitude=(number['longitude_min'], number['longitude_max']),
        fisheye_polynomial=tuple(number[f"fisheye_polynomial_k{i}"] for i in range(5)),
        cylinder=tuple(number["central_cylindrical_" + name]
                       for name in ("range_u_min", "range_u_max", "range_v_min", "range_v_max", "radius")))


def view_camera(engine, cam_obj, camera, view):
    """The engine camera of one multiview view (left, right or a named
    view), as Cycles' sync_camera per view: Blender's camera matrix and
    shift for the active view (off-axis, toe-in or parallel stereo), or,
    with Spherical Stereo on (panoramic and perspective cameras), the
    centre's matrix and an offset per ray (engine/stereo.py).  Camera
    motion steps take the view's offset in the camera's own frame."""
    import dataclasses
    spherical = bool(engine.use_spherical_stereo(cam_obj))
    changes = dict(shift_x=float(engine.camera_shift_x(cam_obj, use_spherical_stereo=spherical)))
    centre = np.asarray(camera.matrix, np.float64)
    seen = _without_scale(engine.camera_model_matrix(cam_obj, use_spherical_stereo=spherical))
    local = np.linalg.inv(centre) @ seen
    if not np.allclose(local, np.eye(4), atol=1e-12):
        changes['matrix'] = seen
        for name in ('motion', 'vector_motion'):
            steps = getattr(camera, name, None)
            if steps is not None:
                changes[name] = np.asarray(steps, np.float64) @ local
    if spherical:
        stereo = cam_obj.data.stereo
        half = 0.5 * float(stereo.interocular_distance)
        # Cycles' stereo_eye: only the views named left and right are eyes.
        offset = {'left': -half, 'right': half}.get(view, 0.0)
        parallel = stereo.convergence_mode == 'PARALLEL'
        merge = ((float(stereo.pole_merge_angle_from), float(stereo.pole_merge_angle_to))
                 if stereo.use_pole_merge else (0.0, 0.0))
        changes.update(stereo_offset=offset, stereo_pole_merge=merge,
                       stereo_convergence=float('inf') if parallel else float(stereo.convergence_distance))
    return dataclasses.replace(camera, **changes)
