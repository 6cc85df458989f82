"""Engine-native scenes for the command line, tests and benchmarks (no Blender)."""
import numpy as np

from .scene import (AreaLight, Camera, Instance, Lobe, Material, Mesh, Scene, World)


def look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """Camera-to-world matrix for a Blender camera (looks down -Z, +Y up)."""
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, true_up, -fwd, eye
    return m


def quad(corners):
    """Mesh of one planar quad (4 corners, counter-clockwise seen from the front)."""
    return Mesh(np.asarray(corners, float), np.array([[0, 1, 2], [0, 2, 3]]), name="quad")


def box(size=(1.0, 1.0, 1.0)):
    """Axis-aligned box centred on the origin with outward-facing triangles."""
    sx, sy, sz = (0.5 * s for s in size)
    p = np.array([[x, y, z] for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)])
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [[a, b, c] for a, b, c, d in faces] + [[a, c, d] for a, b, c, d in faces]
    return Mesh(p, np.array(tris), name="box")


def uv_sphere(radius=1.0, segments=48, rings=24, smooth=True):
    """UV sphere; smooth=True gives per-corner vertex normals."""
    theta = np.linspace(0, np.pi, rings + 1)
    phi = np.linspace(0, 2 * np.pi, segments + 1)[:-1]
    t, f = np.meshgrid(theta, phi, indexing="ij")
    pts = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], axis=-1).reshape(-1, 3)
    tris = []
    for r in range(rings):
        for s in range(segments):
            a = r * segments + s
            b = r * segments + (s + 1) % segments
            c, d = a + segments, b + segments
            if r > 0:
                tris.append([a, c, b])
            if r < rings - 1:
                tris.append([b, c, d])
    tris = np.array(tris)
    normals = pts[tris] if smooth else None
    return Mesh(pts * radius, tris, normals=normals, name="sphere")


def translate_rotate_z(offset, angle_deg=0.0, scale=1.0):
    a = np.radians(angle_deg)
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    m[:3, 3] = offset
    return m


WHITE = Material("white", (Lobe("diffuse", (0.73, 0.73, 0.73)),))
RED = Material("red", (Lobe("diffuse", (0.63, 0.065, 0.05)),))
GREEN = Material("green", (Lobe("diffuse", (0.14, 0.45, 0.091)),))


def cornell_box(width=256, height=256, light_power=25.0):
    """The Cornell box: 2 m cube, a 0.5 m square area light under the ceiling."""
    c = 1.0
    meshes = [
        quad([[-c, -c, 0], [c, -c, 0], [c, c, 0], [-c, c, 0]]),            # floor
        quad([[-c, -c, 2], [-c, c, 2], [c, c, 2], [c, -c, 2]]),            # ceiling
        quad([[-c, c, 0], [c, c, 0], [c, c, 2], [-c, c, 2]]),              # back
        quad([[-c, -c, 0], [-c, c, 0], [-c, c, 2], [-c, -c, 2]]),          # left
        quad([[c, -c, 0], [c, -c, 2], [c, c, 2], [c, c, 0]]),              # right
        box((0.6, 0.6, 1.2)),
        box((0.6, 0.6, 0.6)),
    ]
    instances = [
        Instance(0, materials=[0], name="floor"), Instance(1, materials=[0], name="ceiling"),
        Instance(2, materials=[0], name="back"), Instance(3, materials=[1], name="left"),
        Instance(4, materials=[2], name="right"),
        Instance(5, translate_rotate_z((-0.35, 0.3, 0.6), 17), [0], "tall block"),
        Instance(6, translate_rotate_z((0.35, -0.3, 0.3), -17), [0], "short block"),
    ]
    light_m = np.eye(4)
    light_m[:3, 3] = (0.0, 0.0, 1.99)
    lights = [AreaLight(light_m, (light_power, 0.8 * light_power, 0.6 * light_power), "SQUARE", 0.5,
                        visible_camera=True)]
    camera = Camera(look_at((0, -3.4, 1.0), (0, 0, 1.0)), lens=50.0, sensor_width=36.0,
                    resolution=(width, height), clip_start=0.1)
    return Scene(meshes, instances, [WHITE, RED, GREEN], lights, World((0.0, 0.0, 0.0)), camera)


def cornell_spheres(width=256, height=256, grid=10, segments=96, rings=48):
    """The Cornell box with a grid x grid carpet of instanced smooth spheres
    (about 0.9 M triangles with the defaults): Embree has real work here."""
    scene = cornell_box(width, height)
    sphere = uv_sphere(1.0, segments, rings, smooth=True)
    scene.meshes = list(scene.meshes) + [sphere]
    glossy = Material("glossy", (Lobe("glossy", (0.8, 0.8, 0.8), 0.3),))
    scene.materials = list(scene.materials) + [glossy]
    mesh_id, mat_id = len(scene.meshes) - 1, len(scene.materials) - 1
    r = 0.8 / grid
    instances = list(scene.instances)
    for i in range(grid):
        for k in range(grid):
            x = -0.9 + 1.8 * (i + 0.5) / grid
            y = -0.9 + 1.8 * (k + 0.5) / grid
            instances.append(Instance(mesh_id, translate_rotate_z((x, y, r), 0.0, r), [mat_id]))
    scene.instances = instances
    return scene


SCENES = {"cornell": cornell_box, "cornell-spheres": cornell_spheres}


def veach_plates(size=(48, 36), near_mirror=0.12, rough=0.4, small=0.3, big=1.2, power=20.0):
    """Veach's MIS test (thesis fig. 9.2, simplified): a near-mirror and a
    rough glossy plate, each tilted to reflect a small disk light and a large
    square light into the camera.  No floor: every pixel is a contest
    between light sampling and BSDF sampling."""
    eye = np.array([0.0, -4.0, 1.5])
    light_mid = np.array([0.0, 2.5, 2.0])
    meshes, instances = [], []
    mats = [Material("near-mirror", (Lobe("glossy", (0.9, 0.9, 0.9), near_mirror),)),
            Material("rough", (Lobe("glossy", (0.9, 0.9, 0.9), rough),))]
    for k, y in enumerate((-0.45, 0.45)):
        p = np.array([0.0, y, 0.0])
        n = (eye - p) / np.linalg.norm(eye - p) + (light_mid - p) / np.linalg.norm(light_mid - p)
        n /= np.linalg.norm(n)
        x_axis = np.array([1.0, 0.0, 0.0])
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x_axis, np.cross(n, x_axis), n, p
        meshes.append(quad([[-1.5, -0.4, 0], [1.5, -0.4, 0], [1.5, 0.4, 0], [-1.5, 0.4, 0]]))
        instances.append(Instance(k, m, [k], mats[k].name + " plate"))
    lights = []
    for x, diameter, shape in ((-0.8, small, "DISK"), (0.8, big, "SQUARE")):
        m = look_at(light_mid + [x, 0, 0], (0, 0, 0))  # -Z (emission) towards the plates
        lights.append(AreaLight(m, (power, power, power), shape, diameter, visible_camera=True))
    cam = Camera(look_at(eye, (0, 0, 0)), lens=45.0, resolution=size)
    return Scene(meshes, instances, mats, lights, World((0.0, 0.0, 0.0)), cam)


def veach_four(size=(240, 180), roughness=(0.08, 0.16, 0.3, 0.55), diameters=(0.06, 0.2, 0.5, 1.2),
               power=60.0):
    """Veach's MIS figure (thesis fig. 9.2): four glossy plates from
    near-mirror (front) to rough (back), each tilted to reflect four disk
    lights of equal power and growing size (left to right) into the camera."""
    eye = np.array([0.0, -6.0, 1.0])
    light_mid = np.array([0.0, 0.5, 3.5])
    meshes, instances, mats = [], [], []
    for k, (r, y) in enumerate(zip(roughness, (-0.9, -0.3, 0.3, 0.9))):
        mats.append(Material(f"plate {r}", (Lobe("glossy", (0.8, 0.8, 0.8), r),)))
        p = np.array([0.0, y, 0.35 * k])
        n = (eye - p) / np.linalg.norm(eye - p) + (light_mid - p) / np.linalg.norm(light_mid - p)
        n /= np.linalg.norm(n)
        x_axis = np.array([1.0, 0.0, 0.0])
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x_axis, np.cross(n, x_axis), n, p
        meshes.append(quad([[-2.2, -0.26, 0], [2.2, -0.26, 0], [2.2, 0.26, 0], [-2.2, 0.26, 0]]))
        instances.append(Instance(k, m, [k], f"plate {k}", pass_index=k + 1))
    lights = []
    for x, diameter in zip((-1.8, -0.6, 0.6, 1.8), diameters):
        m = look_at(light_mid + [x, 0, 0], (0.0, -0.3, 0.0))
        lights.append(AreaLight(m, (power, power, power), "DISK", diameter, visible_camera=True))
    cam = Camera(look_at(eye, (0, 0, 0.55)), lens=62.0, resolution=size)
    return Scene(meshes, instances, mats, lights, World((0.0, 0.0, 0.0)), cam)
