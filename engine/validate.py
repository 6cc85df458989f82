"""Input checks with messages a user can act on (raised as SceneError)."""
import numpy as np

from .scene import (AREA_SHAPES, LOBE_KINDS, AreaLight, PointLight, SceneError,
                    SpotLight, SunLight)


def _array(value, what, shape_tail, kinds):
    arr = np.asarray(value)
    if arr.dtype.kind not in kinds:
        raise SceneError(f"{what}: expected a {'float' if 'f' in kinds else 'integer'} "
                         f"array, got dtype {arr.dtype}")
    if arr.ndim != 1 + len(shape_tail) or tuple(arr.shape[1:]) != shape_tail:
        want = "(N, " + ", ".join(map(str, shape_tail)) + ")" if shape_tail else "(N,)"
        raise SceneError(f"{what}: expected shape {want}, got {arr.shape}")
    return arr


def _finite(arr, what):
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise SceneError(f"{what}: {bad} values are NaN or infinite")


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


def validate_instance(inst, index, n_meshes, n_materials):
    what = f"instance {index} ({inst.name!r})"
    if not 0 <= inst.mesh < n_meshes:
        raise SceneError(f"{what}: mesh index {inst.mesh} out of range [0, {n_meshes})")
    m = np.asarray(inst.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError(f"{what}: matrix must be 4x4, got {m.shape}")
    _finite(m, f"{what} matrix")
    for slot, mat in enumerate(inst.materials):
        if not -1 <= mat < n_materials:
            raise SceneError(f"{what}: slot {slot} names material {mat}, "
                             f"but the scene has {n_materials}")


def _rgb(value, what):
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (3,):
        raise SceneError(f"{what}: expected an RGB triple, got shape {arr.shape}")
    _finite(arr, what)
    return arr


def validate_material(mat, index):
    what = f"material {index} ({mat.name!r})"
    _rgb(mat.emission, f"{what} emission")
    for k, lobe in enumerate(mat.lobes):
        if lobe.kind not in LOBE_KINDS:
            raise SceneError(f"{what}: lobe {k} has unknown kind {lobe.kind!r} "
                             f"(expected one of {LOBE_KINDS})")
        _rgb(lobe.color, f"{what} lobe {k} colour")
        if lobe.fresnel not in ("none", "schlick"):
            raise SceneError(f"{what}: lobe {k} has unknown fresnel {lobe.fresnel!r}")
        if not np.isfinite(lobe.roughness):
            raise SceneError(f"{what}: lobe {k} roughness is not finite")


def validate_light(light, index):
    what = f"light {index} ({light.name!r})"
    if isinstance(light, SunLight):
        _rgb(light.strength, f"{what} strength")
        d = _rgb(light.direction, f"{what} direction")
        if np.linalg.norm(d) == 0:
            raise SceneError(f"{what}: direction is zero")
        if not 0 <= light.angle <= np.pi:
            raise SceneError(f"{what}: angle {light.angle} outside [0, pi]")
    elif isinstance(light, AreaLight):
        _rgb(light.power, f"{what} power")
        m = np.asarray(light.matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise SceneError(f"{what}: matrix must be 4x4")
        _finite(m, f"{what} matrix")
        if light.shape not in AREA_SHAPES:
            raise SceneError(f"{what}: unknown shape {light.shape!r}")
    elif isinstance(light, PointLight):
        _rgb(light.power, f"{what} power")
        _rgb(light.position, f"{what} position")
        if light.radius < 0 or not np.isfinite(light.radius):
            raise SceneError(f"{what}: radius must be >= 0")
        if isinstance(light, SpotLight):
            d = _rgb(light.direction, f"{what} direction")
            if np.linalg.norm(d) == 0:
                raise SceneError(f"{what}: direction is zero")
    else:
        raise SceneError(f"{what}: unknown light type {type(light).__name__}")


def validate_camera(cam):
    m = np.asarray(cam.matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise SceneError("camera: matrix must be 4x4")
    _finite(m, "camera matrix")
    if cam.kind not in ("PERSP", "ORTHO"):
        raise SceneError(f"camera: unsupported type {cam.kind!r} (PERSP or ORTHO)")
    w, h = cam.resolution
    if int(w) < 1 or int(h) < 1:
        raise SceneError(f"camera: resolution {w}x{h} has no pixels")
    if cam.kind == "PERSP" and cam.lens <= 0:
        raise SceneError("camera: focal length must be > 0")
    if cam.sensor_fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
        raise SceneError(f"camera: unknown sensor fit {cam.sensor_fit!r}")
    if not 0 <= cam.clip_start < cam.clip_end:
        raise SceneError(f"camera: clip start {cam.clip_start} must be below clip end {cam.clip_end}")


def validate_settings(s):
    if s.samples < 1:
        raise SceneError("settings: samples must be >= 1")
    if s.light_selection not in ("uniform", "power", "all"):
        raise SceneError(f"settings: unknown light selection {s.light_selection!r}")
    if s.strategy not in ("mis", "light", "bsdf"):
        raise SceneError(f"settings: unknown strategy {s.strategy!r}")
    if s.filter_type not in ("BOX", "GAUSSIAN", "BLACKMAN_HARRIS"):
        raise SceneError(f"settings: unknown pixel filter {s.filter_type!r}")
    if s.max_bounces < 0:
        raise SceneError("settings: max bounces must be >= 0")
    if s.max_paths < 1024:
        raise SceneError("settings: max_paths must be >= 1024")


def validate_scene(scene):
    for i, mesh in enumerate(scene.meshes):
        validate_mesh(mesh, i)
    for i, inst in enumerate(scene.instances):
        validate_instance(inst, i, len(scene.meshes), len(scene.materials))
    for i, mat in enumerate(scene.materials):
        validate_material(mat, i)
    for i, light in enumerate(scene.lights):
        validate_light(light, i)
    _rgb(scene.world.color, "world colour")
    validate_camera(scene.camera)
