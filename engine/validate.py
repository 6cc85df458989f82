"""Input checks with messages a user can act on (raised as SceneError)."""
import numpy as np

from .lights import validate_light   # each light type validates its own (engine/lights/)
from .scene import ENV_INTERPOLATIONS, ENV_PROJECTIONS, LOBE_KINDS, SceneError

from . import instance_columns
from . import scene as _scene
from .nodes import REGISTRY
from .passes import unknown as unknown_passes
from .textures import is_texture


def _array(value, what, shape_tail, kinds):
    arr = np.asarray(value)
    if arr.dtype.kind not in kinds:
        raise SceneError(f"{what}: expected a {'float' if 'f' in kinds else 'integer'} "
                         f"array, got dtype {arr.dtype}")
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        want = "(N, " + ", ".join(map(str, shape_tail)) + ")" if shape_tail else "(N,)"
        raise SceneError(f"{what}: expected shape {want}, got {arr.shape}")
    return arr


# Colours, strengths and powers beyond this cannot be summed and stored as
# float32 pixels without overflowing to infinity; 1e30 itself still renders.
MAX_MAGNITUDE = 1e30


def _finite(arr, what):
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise SceneError(f"{what}: {bad} values are NaN or infinite")


def _bounded(arr, what):
    """Finite and at most MAX_MAGNITUDE: a radiance or power that can be rendered."""
    _finite(arr, what)
    if arr.size and np.abs(arr).max() > MAX_MAGNITUDE * (1 + 1e-6):  # 1e30 as float32 passes
        raise SceneError(f"{what}: {np.abs(arr).max():.3g} is beyond the largest value Ember "
                         f"can render ({MAX_MAGNITUDE:g})")


def validate_mesh(mesh, index):
    what = f"mesh {index} ({mesh.name!r})"
    pos = _array(mesh.positions, f"{what} positions", (3,), "fi")
    _finite(pos, f"{what} positions")
    tris = _array(mesh.triangles, f"{what} triangles", (3,), "iu")
    if tris.size and (tris.min() < 0 or tris.max() >= len(pos)):
        raise SceneError(f"{what}: triangle vertex index out of range "
                         f"[0, {len(pos)}) (min {tris.min()}, max {tris.max()})")
    n = len(tris)
    if mesh.normals is not None:
        nrm = _array(mesh.normals, f"{what} normals", (3, 3), "f")
        if len(nrm) != n:
            raise SceneError(f"{what}: {len(nrm)} normal triples for {n} triangles")
    if mesh.uvs is not None:
        uv = _array(mesh.uvs, f"{what} uvs", (3, 2), "f")
        if len(uv) != n:
            raise SceneError(f"{what}: {len(uv)} uv triples for {n} triangles")
    if mesh.material_slots is not None:
        slots = _array(mesh.material_slots, f"{what} material_slots", (), "iu")
        if len(slots) != n:
            raise SceneError(f"{what}: {len(slots)} material slots for {n} triangles")
        if n and slots.min() < 0:
            raise SceneError(f"{what}: negative material slot {slots.min()}")
    smooth = getattr(mesh, "smooth", None)
    if smooth is not None and np.shape(smooth) != (n,):
        raise SceneError(f"{what}: smooth has shape {np.shape(smooth)}, expected ({n},)")
    undisplaced = getattr(mesh, "undisplaced", None)
    if undisplaced is not None and np.shape(undisplaced) != np.shape(pos):
        raise SceneError(f"{what}: undisplaced has shape {np.shape(undisplaced)}, expected {np.shape(pos)}")
    _validate_mesh_motion(mesh, what, len(pos), n)


def _steps(value, what, tail):
    """A motion array (S, ...) of at least two finite steps."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fi" or arr.ndim != 1 + len(tail) or tuple(arr.shape[1:]) != tail:
        raise SceneError(f"{what}: expected shape (steps, {', '.join(map(str, tail))}), got {arr.shape}")
    if len(arr) < 2:
        raise SceneError(f"{what}: motion needs at least 2 steps, got {len(arr)}")
    _finite(arr, what)
    return arr


def _validate_mesh_motion(mesh, what, n_vertices, n_triangles):
    if getattr(mesh, "motion", None) is not None:
        steps = _steps(mesh.motion, f"{what} motion", (n_vertices, 3))
        if getattr(mesh, "motion_normals", None) is not None:
            normals = _steps(mesh.motion_normals, f"{what} motion_normals", (n_triangles, 3, 3))
            if len(normals) != len(steps):
                raise SceneError(f"{what}: {len(normals)} steps of motion normals for {len(steps)} of positions")


def validate_instance(inst, index, n_meshes, n_materials):
    what = f"instance {index} ({inst.name!r})"
    if not 0 <= inst.mesh < n_meshes:
        raise SceneError(f"{what}: mesh index {inst.mesh} out of range [0, {n_meshes})")
    m = np.asarray(inst.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError(f"{what}: matrix must be 4x4, got {m.shape}")
    _finite(m, f"{what} matrix")
    if getattr(inst, "motion", None) is not None:
        _steps(inst.motion, f"{what} motion", (4, 4))
    for slot, mat in enumerate(inst.materials):
        if not -1 <= mat < n_materials:
            raise SceneError(f"{what}: slot {slot} names material {mat}, "
                             f"but the scene has {n_materials}")


def validate_instances(instances, n_meshes, n_materials):
    """validate_instance for every instance, vectorized: a million instances
    (particles, geometry nodes) took ~40 s one by one.  Only an instance that
    fails a check is looked at alone, for its message."""
    if len(instances) < 64:
        for i, inst in enumerate(instances):
            validate_instance(inst, i, n_meshes, n_materials)
        return
    cols = instance_columns.columns(instances)
    bad = _first_bad_instance(cols, n_meshes, n_materials)
    if bad is not None:
        validate_instance(instances[bad], bad, n_meshes, n_materials)
    for i in np.flatnonzero(cols.moving):
        validate_instance(instances[i], int(i), n_meshes, n_materials)


def _first_bad_instance(cols, n_meshes, n_materials):
    """Index of the first instance that may fail validate_instance, or None."""
    suspects = [np.flatnonzero((cols.mesh < 0) | (cols.mesh >= n_meshes))]
    if cols.matrix is None:
        suspects.append(np.arange(len(cols)))  # a wrong shape somewhere: check one by one
    else:
        suspects.append(np.flatnonzero(~np.isfinite(cols.matrix).all(axis=(1, 2))))
    for k, slots in enumerate(cols.slot_sets):
        if any(not -1 <= mat < n_materials for mat in slots):
            suspects.append(np.flatnonzero(cols.slot_set == k)[:1])
    found = np.concatenate(suspects)
    return int(found.min()) if found.size else None


def _rgb(value, what):
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise SceneError(f"{what}: expected an RGB triple, got shape {arr.shape}")
    _bounded(arr, what)
    return arr


def validate_material(mat, index):
    what = f"material {index} ({mat.name!r})"
    _color_param(mat.emission, f"{what} emission")
    if getattr(mat, "normal", None) is not None:
        validate_normal(mat.normal, f"{what} normal")
    if getattr(mat, "tangent", None) is not None:
        validate_texture(mat.tangent, f"{what} tangent")
    if getattr(mat, "displacement", None) is not None:
        validate_displacement(mat.displacement, f"{what} displacement")
    for k in getattr(mat, "emission_layers", ()):
        if not (isinstance(k, (int, np.integer)) and 0 <= k < len(mat.lobes)):
            raise SceneError(f"{what}: emission layer {k!r} is no lobe of its {len(mat.lobes)}")
    for k, lobe in enumerate(mat.lobes):
        if lobe.kind not in LOBE_KINDS:
            raise SceneError(f"{what}: lobe {k} has unknown kind {lobe.kind!r} "
                             f"(expected one of {LOBE_KINDS})")
        _color_param(lobe.color, f"{what} lobe {k} colour")
        if lobe.fresnel not in _scene.FRESNEL_MODES:
            raise SceneError(f"{what}: lobe {k} has unknown fresnel {lobe.fresnel!r} "
                             f"(expected one of {_scene.FRESNEL_MODES})")
        if is_texture(lobe.roughness):
            validate_texture(lobe.roughness, f"{what} lobe {k} roughness")
        elif not np.isfinite(lobe.roughness):
            raise SceneError(f"{what}: lobe {k} roughness is not finite")
        _validate_lobe_extras(lobe, k, what, len(mat.lobes))
    if getattr(mat, "volume", None) is not None:
        validate_volume(mat.volume, what)
    holdout = getattr(mat, "holdout", 0.0)
    if not (np.isfinite(holdout) and 0.0 <= holdout <= 1.0):
        raise SceneError(f"{what}: holdout must lie in [0, 1], got {holdout}")


def validate_displacement(disp, what):
    if disp.space not in _scene.DISPLACEMENT_SPACES:
        raise SceneError(f"{what}: unknown space {disp.space!r} (expected one of {_scene.DISPLACEMENT_SPACES})")
    if disp.method not in _scene.DISPLACEMENT_METHODS:
        raise SceneError(f"{what}: unknown method {disp.method!r} (expected one of {_scene.DISPLACEMENT_METHODS})")
    if is_texture(disp.height):
        validate_texture(disp.height, f"{what} height")
    elif not np.isfinite(np.asarray(disp.height, dtype=np.float64)).all():
        raise SceneError(f"{what}: height is not finite")


def validate_volume(vol, what):
    """A medium: finite, non-negative constant coefficients or texture
    expressions (a heterogeneous medium, repaired where evaluated), |g| <= 1."""
    for name in ("absorption", "scattering", "emission"):
        if is_texture(getattr(vol, name)):
            validate_texture(getattr(vol, name), f"{what} volume {name}")
            continue
        arr = _rgb(getattr(vol, name), f"{what} volume {name}")
        if np.any(arr < 0):
            raise SceneError(f"{what}: volume {name} must be >= 0, got {tuple(arr)}")
    g = vol.anisotropy
    phase = getattr(vol, "phase", "HENYEY_GREENSTEIN")
    if is_texture(g):   # per point (media/field.py clamps it), Henyey-Greenstein only
        validate_texture(g, f"{what} volume anisotropy")
        if phase != "HENYEY_GREENSTEIN":
            raise SceneError(f"{what}: a textured volume anisotropy needs the Henyey-Greenstein phase function, "
                             f"not {phase!r}")
    elif not (np.isfinite(g) and -1.0 <= g <= 1.0):
        raise SceneError(f"{what}: volume anisotropy must lie in [-1, 1], got {g}")
    if phase not in _scene.PHASE_FUNCTIONS:
        raise SceneError(f"{what}: unknown volume phase function {phase!r} (expected one of "
                         f"{_scene.PHASE_FUNCTIONS})")
    for name, lo, hi in (("alpha", 0.0, 1e6), ("backscatter", 1e-6, 0.5 - 1e-6), ("ior", 1.0 + 1e-6, 10.0),
                         ("diameter", 0.0, 1e6)):
        v = float(getattr(vol, name, lo))
        if not (np.isfinite(v) and lo <= v <= hi):
            raise SceneError(f"{what}: volume {name} must lie in [{lo:g}, {hi:g}], got {v}")


def _validate_lobe_extras(lobe, k, what, n_lobes):
    """The Fresnel, IOR, layering and weight parameters of a lobe."""
    for name in ("ior", "weight", "anisotropy"):
        value = getattr(lobe, name, None)
        if is_texture(value):
            validate_texture(value, f"{what} lobe {k} {name}")
        elif value is not None and not np.isfinite(value):
            raise SceneError(f"{what}: lobe {k} {name} is not finite")
    anisotropy = getattr(lobe, "anisotropy", 0.0)
    if not is_texture(anisotropy) and not -1.0 <= anisotropy <= 1.0:   # the Glossy node's range
        raise SceneError(f"{what}: lobe {k} anisotropy must be in [-1, 1], got {anisotropy}")
    ior = getattr(lobe, "ior", 1.5)
    if not is_texture(ior) and ior <= 0:
        raise SceneError(f"{what}: lobe {k} IOR must be > 0, got {ior}")
    for name in ("f0", "edge_tint", "transmission_tint", "absorb"):
        value = getattr(lobe, name, None)
        if value is not None:
            _color_param(value, f"{what} lobe {k} {name}")
    covers = getattr(lobe, "covers", 0)
    if not 0 <= covers < n_lobes - k:
        raise SceneError(f"{what}: lobe {k} covers {covers} lobes, but only "
                         f"{n_lobes - k - 1} follow it")


def validate_world(world):
    _rgb(world.color, "world colour")
    vol = getattr(world, "volume", None)
    if vol is not None:   # textured: a field over the scene (media/field.py WorldField)
        validate_volume(vol, "world")
    tex = world.texture
    if tex is None:
        return
    what = f"world texture {tex.name!r}"
    px = np.asarray(tex.pixels)
    if px.dtype.kind != "f":
        raise SceneError(f"{what}: pixels must be a float array, got dtype {px.dtype}")
    if px.ndim != 3 or px.shape[2] != 3 or px.shape[0] < 1 or px.shape[1] < 1:
        raise SceneError(f"{what}: pixels must have shape (H, W, 3), got {px.shape}")
    _finite(px, f"{what} pixels")
    if not np.isfinite(tex.strength):
        raise SceneError(f"{what}: strength is not finite")
    m = np.asarray(tex.matrix, dtype=np.float64)
    if m.shape != (3, 3):
        raise SceneError(f"{what}: matrix must be 3x3, got {m.shape}")
    _finite(m, f"{what} matrix")
    if abs(np.linalg.det(m)) < 1e-12 * max(1.0, np.abs(m).max()) ** 3:
        raise SceneError(f"{what}: matrix is singular (a Mapping scale of 0?)")
    if tex.interpolation not in ENV_INTERPOLATIONS:
        raise SceneError(f"{what}: unknown interpolation {tex.interpolation!r} "
                         f"(expected one of {ENV_INTERPOLATIONS})")
    if getattr(tex, "projection", "EQUIRECTANGULAR") not in ENV_PROJECTIONS:
        raise SceneError(f"{what}: unknown projection {tex.projection!r} (expected one of {ENV_PROJECTIONS})")
    sun = getattr(tex, "sun", None)
    if sun is not None:
        axis = np.asarray(sun.direction, dtype=np.float64)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or not np.linalg.norm(axis) > 0:
            raise SceneError(f"{what}: sun direction must be a finite non-zero 3-vector, got {sun.direction}")
        if not (np.isfinite(sun.half_angle) and 0 < sun.half_angle <= np.pi):
            raise SceneError(f"{what}: sun half angle must be in (0, pi], got {sun.half_angle}")
        if not (np.isfinite(sun.power) and sun.power >= 0):
            raise SceneError(f"{what}: sun power must be finite and >= 0, got {sun.power}")


def validate_camera(cam):
    m = np.asarray(cam.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError("camera: matrix must be 4x4")
    _finite(m, "camera matrix")
    if getattr(cam, "motion", None) is not None:
        _steps(cam.motion, "camera motion", (4, 4))
    if cam.kind not in ("PERSP", "ORTHO", "PANO"):
        raise SceneError(f"camera: unsupported type {cam.kind!r} (PERSP, ORTHO or PANO)")
    if cam.kind == "PANO":
        _validate_panorama(cam)
    w, h = cam.resolution
    if int(w) < 1 or int(h) < 1:
        raise SceneError(f"camera: resolution {w}x{h} has no pixels")
    if cam.kind == "PERSP" and cam.lens <= 0:
        raise SceneError("camera: focal length must be > 0")
    if cam.sensor_fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
        raise SceneError(f"camera: unknown sensor fit {cam.sensor_fit!r}")
    if not 0 <= cam.clip_start < cam.clip_end:
        raise SceneError(f"camera: clip start {cam.clip_start} must be below clip end {cam.clip_end}")
    _validate_stereo(cam)


def _validate_stereo(cam):
    offset = float(getattr(cam, "stereo_offset", 0.0))
    if not np.isfinite(offset):
        raise SceneError(f"camera: the stereo interocular distance must be finite, got {2 * offset}")
    convergence = float(getattr(cam, "stereo_convergence", np.inf))
    if np.isnan(convergence) or convergence <= 0:
        raise SceneError(f"camera: the stereo convergence distance must be > 0, got {convergence}")
    merge = np.asarray(getattr(cam, "stereo_pole_merge", (0.0, 0.0)), np.float64)
    if merge.shape != (2,) or not np.isfinite(merge).all():
        raise SceneError(f"camera: the stereo pole merge angles must be 2 finite numbers, got {merge!r}")


def _validate_panorama(cam):
    from .panorama import TYPES
    kind = getattr(cam, "panorama_type", None)
    if kind not in TYPES:
        raise SceneError(f"camera: unknown panorama type {kind!r} (one of {', '.join(TYPES)})")
    for name in ("fisheye_fov", "fisheye_lens", "sensor_width", "sensor_height"):
        value = float(getattr(cam, name))
        if not (np.isfinite(value) and value > 0):
            raise SceneError(f"camera: {name} must be finite and > 0, got {value}")
    for name, size in (("latitude", 2), ("longitude", 2), ("fisheye_polynomial", 5), ("cylinder", 5)):
        values = np.asarray(getattr(cam, name), np.float64)
        if values.shape != (size,) or not np.isfinite(values).all():
            raise SceneError(f"camera: {name} must be {size} finite numbers, got {getattr(cam, name)!r}")
    if not cam.cylinder[4] > 0:
        raise SceneError(f"camera: the central cylinder's radius must be > 0, got {cam.cylinder[4]}")


def validate_settings(s):
    if s.samples < 1:
        raise SceneError("settings: samples must be >= 1")
    if s.samples_per_pass < 0:
        raise SceneError("settings: samples per pass must be >= 0 (0 = automatic)")
    if s.light_selection not in ("uniform", "power", "all", "tree", "ris", "tree_bsdf", "auto"):
        raise SceneError(f"settings: unknown light selection {s.light_selection!r}")
    if s.strategy not in ("mis", "light", "bsdf"):
        raise SceneError(f"settings: unknown strategy {s.strategy!r}")
    if s.filter_type not in ("BOX", "GAUSSIAN", "BLACKMAN_HARRIS"):
        raise SceneError(f"settings: unknown pixel filter {s.filter_type!r}")
    if s.max_bounces < 0:
        raise SceneError("settings: max bounces must be >= 0")
    if s.transparent_max_bounces < 0:
        raise SceneError("settings: transparent max bounces must be >= 0")
    if not s.filter_glossy >= 0:
        raise SceneError("settings: filter glossy must be >= 0")
    for kind in ("diffuse", "glossy", "transmission"):
        if getattr(s, kind + "_bounces") < 0:
            raise SceneError(f"settings: {kind} bounces must be >= 0")
    if getattr(s, "volume_bounces", 0) < 0:
        raise SceneError("settings: volume bounces must be >= 0")
    if s.max_paths < 1024:
        raise SceneError("settings: max_paths must be >= 1024")
    if s.sample_start < 0 or s.sample_start + s.samples > 2 ** 32:
        raise SceneError("settings: sample indices must lie in [0, 2^32)")
    if s.sampling_pattern not in ("sobol", "random"):
        raise SceneError(f"settings: unknown sampling pattern {s.sampling_pattern!r}")
    if getattr(s, "path_guiding_training_samples", 0) < 0:
        raise SceneError("settings: path_guiding_training_samples must be >= 0 (0: train over every sample)")
    if not (s.adaptive_threshold >= 0.0) or s.adaptive_min_samples < 0:
        raise SceneError("settings: adaptive threshold and min samples must be >= 0")
    unknown = set(s.aovs) - {"depth", "normal", "albedo"}
    if unknown:
        raise SceneError(f"settings: unknown AOVs {sorted(unknown)}")
    _validate_passes(s)


def _validate_passes(s):
    bad = unknown_passes(getattr(s, "passes", ()) or ())
    if bad:
        raise SceneError(f"settings: unknown render passes {bad}")


def _radii_and_matrix(item, positions, name, what):
    """The positions (N, 3) of a point cloud or curve set, checked with its
    radii (N,, finite, >= 0) and matrix."""
    pos = _array(positions, f"{what} {name}", (3,), "fi")
    _finite(pos, f"{what} {name}")
    radii = _array(item.radii, f"{what} radii", (), "fi")
    if len(radii) != len(pos):
        raise SceneError(f"{what}: {len(radii)} radii for {len(pos)} points")
    _finite(radii, f"{what} radii")
    if len(radii) and radii.min() < 0:
        raise SceneError(f"{what}: negative radius {radii.min()}")
    m = np.asarray(item.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError(f"{what}: matrix must be 4x4, got {m.shape}")
    _finite(m, f"{what} matrix")
    return pos


def _validate_primitive_motion(item, what, n_points):
    """Transform steps (S, 4, 4) and positions (S, N, 3) / radii (S, N) at
    the steps of a point cloud or curve set, finite, radii >= 0."""
    if getattr(item, "motion", None) is not None:
        _steps(item.motion, f"{what} motion", (4, 4))
    if getattr(item, "motion_positions", None) is not None:
        steps = _steps(item.motion_positions, f"{what} motion_positions", (n_points, 3))
        radii = getattr(item, "motion_radii", None)
        if radii is not None:
            radii = _steps(radii, f"{what} motion_radii", (n_points,))
            if len(radii) != len(steps):
                raise SceneError(f"{what}: {len(radii)} steps of motion radii for {len(steps)} of positions")
            if radii.size and radii.min() < 0:
                raise SceneError(f"{what}: negative motion radius {radii.min()}")
    elif getattr(item, "motion_radii", None) is not None:
        raise SceneError(f"{what}: motion_radii without motion_positions")
    for name, tail in (("vector_motion", (4, 4)), ("vector_positions", (n_points, 3))):
        value = getattr(item, name, None)
        if value is not None:
            _vector_steps(value, f"{what} {name}", tail)


def _vector_steps(value, what, tail):
    """The Vector pass's 3 steps (frame - 1, frame, frame + 1) of the right
    shape; NaN or infinite ones are dropped by engine/vector_pass.py (the
    item is taken as still, with a warning), not refused."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "fi" or tuple(arr.shape) != (3,) + tail:
        raise SceneError(f"{what}: expected shape (3, {', '.join(map(str, tail))}), got {arr.shape}")


def validate_point_cloud(cloud, index, n_materials):
    what = f"point cloud {index} ({cloud.name!r})"
    pos = _radii_and_matrix(cloud, cloud.positions, "positions", what)
    _validate_primitive_motion(cloud, what, len(pos))
    for slot, mat in enumerate(cloud.materials):
        if not -1 <= mat < n_materials:
            raise SceneError(f"{what}: slot {slot} names material {mat}, but the scene has {n_materials}")
    for name, values in (cloud.attributes or {}).items():
        arr = np.asarray(values)
        if arr.ndim != 2 or len(arr) != len(pos) or arr.dtype.kind not in "fi":
            raise SceneError(f"{what}: attribute {name!r} must be (N, C) numbers, got {arr.shape}")
        _finite(arr, f"{what} attribute {name!r}")


def validate_curves(strands, index, n_materials):
    what = f"curves {index} ({strands.name!r})"
    pos = _radii_and_matrix(strands, strands.points, "points", what)
    _validate_primitive_motion(strands, what, len(pos))
    offsets = _array(strands.offsets, f"{what} offsets", (), "iu")
    if len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != len(pos) or np.any(np.diff(offsets) < 1):
        raise SceneError(f"{what}: offsets must rise from 0 to {len(pos)} with every curve holding a point")
    for domain, count in (("point_attributes", len(pos)), ("curve_attributes", len(offsets) - 1)):
        for name, values in (getattr(strands, domain, None) or {}).items():
            arr = np.asarray(values)
            if arr.ndim not in (1, 2) or len(arr) != count or arr.dtype.kind not in "fi":
                raise SceneError(f"{what}: {domain} {name!r} must be ({count}, C) numbers, got {arr.shape}")
            _finite(arr, f"{what} {domain} {name!r}")
    space = getattr(strands, "texspace", None)
    if space is not None:
        _finite(_array(space, f"{what} texspace", (3,), "fi"), f"{what} texspace")
    uv = getattr(strands, "uv", None)
    if uv is not None and uv not in {**(strands.point_attributes or {}), **(strands.curve_attributes or {})}:
        raise SceneError(f"{what}: the UV map {uv!r} is none of its attributes")


CURVE_SHAPES = ("THICK", "RIBBONS", "THICK_LINEAR")


def validate_scene(scene):
    shape = getattr(scene, "curve_shape", "THICK")
    if shape not in CURVE_SHAPES:
        raise SceneError(f"curve_shape must be one of {CURVE_SHAPES}, got {shape!r}")
    subdivisions = getattr(scene, "curve_subdivisions", 2)
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or subdivisions < 0:
        raise SceneError(f"curve_subdivisions must be a whole number >= 0, got {subdivisions!r}")
    for i, strands in enumerate(getattr(scene, "curves", ()) or ()):
        validate_curves(strands, i, len(scene.materials))
    for i, cloud in enumerate(getattr(scene, "points", ()) or ()):
        validate_point_cloud(cloud, i, len(scene.materials))
    for i, mesh in enumerate(scene.meshes):
        validate_mesh(mesh, i)
    validate_instances(scene.instances, len(scene.meshes), len(scene.materials))
    for i, mat in enumerate(scene.materials):
        validate_material(mat, i)
    for i, light in enumerate(scene.lights):
        validate_light(light, i)
        # A light's node tree (engine/lights/shader.py), a colour expression
        # like any texture: validated here, as the light modules cannot import
        # this one (it imports them).
        if getattr(light, "shader", None) is not None:
            validate_texture(light.shader, f"light {i} ({getattr(light, 'name', '?')!r}) shader")
    validate_world(scene.world)
    validate_camera(scene.camera)


# ----------------------------------------------------------------------------
# Texture expressions

def _color_param(value, what):
    if is_texture(value):
        validate_texture(value, what)
    else:
        _rgb(value, what)


def validate_image(image, what):
    what = f"{what} image {image.name!r}"
    px = np.asarray(image.pixels)
    if px.dtype.kind not in "fiu":
        raise SceneError(f"{what}: pixels must be numbers, got dtype {px.dtype}")
    if px.ndim not in (2, 3) or px.shape[0] < 1 or px.shape[1] < 1 or (px.ndim == 3 and not 1 <= px.shape[2] <= 4):
        raise SceneError(f"{what}: pixels must have shape (H, W) or (H, W, 1..4), got {px.shape}")
    _finite(px, f"{what} pixels")
    if image.alpha_mode not in _scene.ALPHA_MODES:
        raise SceneError(f"{what}: unknown alpha mode {image.alpha_mode!r} (expected one of {_scene.ALPHA_MODES})")
    for number, tile in getattr(image, "tiles", ()):
        if not 1001 <= int(number) <= 2000:   # u in [0, 10), v in [0, 100): Blender's tile range
            raise SceneError(f"{what}: UDIM tile number {number} outside 1001-2000")
        validate_image(tile, what)


def _choice(value, allowed, what, name):
    if value not in allowed:
        raise SceneError(f"{what}: unknown {name} {value!r} (expected one of {allowed})")


def validate_texture(expr, what):
    """A texture expression (or constant operand): enums, images, operands."""
    if isinstance(expr, _scene.ImageTexture):
        validate_image(expr.image, what)
        _choice(expr.interpolation, _scene.INTERPOLATIONS, what, "interpolation")
        _choice(expr.extension, _scene.EXTENSIONS, what, "extension")
        _choice(expr.output, ("Color", "Alpha"), what, "image output")
        _choice(expr.projection, ("FLAT",) + ENV_PROJECTIONS, what, "image projection")
        if expr.uv is not None:
            validate_texture(expr.uv, f"{what} vector")
    elif isinstance(expr, _scene.MixColor):
        _choice(expr.blend, _scene.MIX_BLENDS, what, "mix blend")
        for name in ("fac", "a", "b"):
            validate_texture(getattr(expr, name), f"{what} mix {name}")
    elif isinstance(expr, _scene.Math):
        _choice(expr.operation, _scene.MATH_OPERATIONS, what, "math operation")
        for name in ("a", "b", "c"):
            validate_texture(getattr(expr, name), f"{what} math {name}")
    elif isinstance(expr, _scene.NodeOutput):
        validate_node_call(expr.call, what)
        if expr.output not in dict(_node_def(expr.call, what).outputs):
            raise SceneError(f"{what}: node {expr.call.idname} has no output {expr.output!r}")
    elif isinstance(expr, (_scene.NormalMap, _scene.Bump)):
        raise SceneError(f"{what}: a {type(expr).__name__} gives a normal, not a colour or value")
    else:
        arr = np.asarray(expr, dtype=np.float64) if _numeric(expr) else None
        if arr is None or arr.shape not in ((), (3,)):
            raise SceneError(f"{what}: expected a number, an RGB triple or a texture, got {expr!r}")
        _finite(arr, what)


def _node_def(call, what):
    entry = REGISTRY.get(call.idname)
    if entry is None:
        raise SceneError(f"{what}: unknown shader node {call.idname!r}")
    return entry


def validate_node_call(call, what):
    """A registered node: known inputs, each a constant or an expression."""
    entry = _node_def(call, what)
    reason = entry.accepts(call.props) if entry.accepts is not None else None
    if reason:
        raise SceneError(f"{what}: node {call.idname}: {reason}")
    known = dict(entry.inputs)
    for name, value in call.inputs.items():
        if name not in known:
            raise SceneError(f"{what}: node {call.idname} has no input {name!r}")
        validate_texture(value, f"{what} {call.idname}.{name}")


def _numeric(value):
    try:
        np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return True


def validate_normal(expr, what):
    if isinstance(expr, _scene.NormalMap):
        _choice(getattr(expr, "space", "TANGENT"), _scene.NORMAL_MAP_SPACES, what, "normal map space")
        validate_texture(expr.color, f"{what} normal map colour")
        validate_texture(expr.strength, f"{what} normal map strength")
    elif isinstance(expr, _scene.Bump):
        for name in ("height", "strength", "distance"):
            validate_texture(getattr(expr, name), f"{what} bump {name}")
        if expr.normal is not None:
            validate_normal(expr.normal, what)
    elif isinstance(expr, _scene.NodeOutput):
        validate_texture(expr, f"{what} vector")
    else:
        raise SceneError(f"{what}: expected a NormalMap, Bump or node output, got {type(expr).__name__}")
