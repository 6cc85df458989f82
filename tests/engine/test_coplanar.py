"""Coincident faces between objects (engine.coplanar): found where two
objects' faces share a plane and overlap, not where they only touch, lie
apart, sit off the plane or only their bounds overlap; opposite faces only
when rays get inside one object (glass, a volume); the same under a tilt and
for instance batches; cheap for 2 M triangles."""
import time

import numpy as np

from engine.coplanar import coincident_pairs
from engine.instance_batch import InstanceBatch
from engine.scene import Instance, Lobe, Material, Mesh, Scene, Volume
from engine.testscenes import box, quad


def moved(x, y, z, scale=1.0):
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = x, y, z
    return m


def tilt():
    a, b = 0.4, 0.9
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ rx
    m[:3, 3] = 0.3, -1.7, 2.2
    return m


def floor(size=12.0):
    h = size / 2
    return quad([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])


# Materials: 0 opaque, 1 glass, 2 a volume only.
MATERIALS = [Material("opaque"), Material("glass", (Lobe("glass"),)), Material("fog", (), volume=Volume())]


def scene_of(meshes, placements, names, materials=None):
    """placements: (mesh index, matrix) per instance; materials: one index
    per instance (default glass: rays get inside)."""
    materials = materials or [1] * len(placements)
    instances = [Instance(m, matrix=matrix, name=name, materials=[k])
                 for (m, matrix), name, k in zip(placements, names, materials)]
    return Scene(meshes=meshes, instances=instances, materials=MATERIALS)


def test_a_box_resting_on_a_floor_is_named():
    scene = scene_of([floor(), box()], [(0, np.eye(4)), (1, moved(0.2, 0.1, 0.5)), (1, moved(3, 0, 0.5001))],
                     ["Floor", "Glass", "Raised"])
    pairs, left_out = coincident_pairs(scene)
    assert pairs == [("Floor", "Glass")] and left_out == 0


def test_opposite_faces_of_opaque_objects_are_not_but_same_facing_ones_are():
    """A closed opaque box on an opaque floor: no ray reaches the faces
    under it.  A fog box or a glass one: rays inside meet both.  A decal (a
    quad facing the floor's way on it) is seen from outside: named."""
    decal = quad([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    names = ["Floor", "Box", "Fog", "Decal"]
    placements = [(0, np.eye(4)), (1, moved(0, 0, 0.5)), (1, moved(3, 0, 0.5)), (2, moved(-3, 0, 0))]
    pairs, _ = coincident_pairs(scene_of([floor(), box(), decal], placements, names, [0, 0, 2, 0]))
    assert pairs == [("Floor", "Fog"), ("Floor", "Decal")]


def test_bounds_that_overlap_with_faces_that_do_not():
    """Two boxes on the floor, one turned 45 degrees, the other beside its
    corner diagonally: their bottoms' bounds overlap, the bottoms do not."""
    turn = np.eye(4)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    turn[:2, :2] = [[c, -s], [s, c]]
    turn[:3, 3] = 0, 0, 0.5
    scene = scene_of([box()], [(0, turn), (0, moved(0.9, 0.9, 0.5))], ["Turned", "Beside"])
    assert coincident_pairs(scene)[0] == []
    closer = scene_of([box()], [(0, turn), (0, moved(0.75, 0.75, 0.5))], ["Turned", "Beside"])
    assert coincident_pairs(closer)[0] == [("Turned", "Beside")]


def test_touching_apart_and_parallel_faces_are_not():
    scene = scene_of([floor(2.0), box()], [
        (0, np.eye(4)), (0, moved(2.0, 0, 0)),        # two floor tiles sharing an edge
        (0, moved(5.0, 0, 0)),                        # a third far away
        (1, moved(0, 0, 0.5 + 1e-4)),                 # a box 0.1 mm up
        (1, moved(0, 0, -0.5))],                      # a box below the floor: its top touches it from below
        ["TileA", "TileB", "TileC", "Up", "Below"])
    pairs, _ = coincident_pairs(scene)
    # The box below shares the floor's plane with its top face (it overlaps it).
    assert pairs == [("TileA", "Below")]


def test_found_under_a_tilt_with_opposite_normals():
    """The box's bottom faces down, the floor up: one plane either way; the
    whole arrangement rotated, so the float planes differ in their last bits."""
    m = tilt()
    scene = scene_of([floor(), box()], [(0, m), (1, m @ moved(0.2, 0.1, 0.5))], ["Floor", "Box"])
    assert coincident_pairs(scene)[0] == [("Floor", "Box")]
    lifted = scene_of([floor(), box()], [(0, m), (1, m @ moved(0.2, 0.1, 0.5 + 1e-4))], ["Floor", "Box"])
    assert coincident_pairs(lifted)[0] == []


def random_turn(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = rng.uniform(-20, 20, size=3)
    return m


def test_found_under_any_rotation():
    """40 random rotations and offsets of a box on a floor: found in each
    (the faces' float normals and offsets differ in their last bits)."""
    rng = np.random.default_rng(3)
    missed = []
    for k in range(40):
        m = random_turn(rng)
        scene = scene_of([floor(), box()], [(0, m), (1, m @ moved(0.2, 0.1, 0.5))], ["Floor", "Box"])
        if coincident_pairs(scene)[0] != [("Floor", "Box")]:
            missed.append(k)
    assert not missed, f"rotations {missed} missed"


def test_instance_batches_and_the_budget():
    templates = [Instance(1, name="Crate", materials=[1])]
    matrices = np.array([moved(x, 0, 0.5) for x in (-3.0, 0.0, 3.0)] + [moved(0, 3, 0.7)])
    batch = InstanceBatch(templates, np.zeros(4, np.int64), matrices, np.zeros(4))
    scene = Scene(meshes=[floor(), box()], instances=batch, materials=MATERIALS)
    # A batch has no Floor: the crates touch nothing coplanar but each other's planes apart.
    assert coincident_pairs(scene) == ([], 0)
    both = InstanceBatch([Instance(0, name="Floor", materials=[0]), Instance(1, name="Crate", materials=[1])],
                         np.array([0, 1, 1, 1, 1]),
                         np.concatenate([[np.eye(4)], matrices]), np.zeros(5))
    assert coincident_pairs(Scene(meshes=[floor(), box()], instances=both, materials=MATERIALS)) == ([("Floor", "Crate")], 0)
    pairs, left_out = coincident_pairs(Scene(meshes=[floor(), box()], instances=both, materials=MATERIALS), budget=2 + 12)
    # Room for the floor and one crate: the two other crates on the floor are
    # left out (the raised one touches nothing: not counted).
    assert pairs == [("Floor", "Crate")] and left_out == 2 * 12


def grid(n):
    """A (n x n)-quad heightmap, 2 n^2 triangles, flat at z = 0 in its middle."""
    x, y = np.meshgrid(np.linspace(-10, 10, n + 1), np.linspace(-10, 10, n + 1))
    z = np.where(np.hypot(x, y) < 3.0, 0.0, 0.3 * np.sin(x) * np.cos(0.7 * y))
    positions = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 2, i.ravel() + n + 1
    return Mesh(positions, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))


def test_two_million_triangles_stay_cheap():
    scene = scene_of([grid(1000), box()], [(0, np.eye(4)), (1, moved(0.5, 0.5, 0.5))], ["Terrain", "Box"])
    start = time.perf_counter()
    pairs, _ = coincident_pairs(scene)
    seconds = time.perf_counter() - start
    print(f"coincident faces over {2 * 1000 ** 2 + 12} triangles: {seconds:.2f} s")
    assert pairs == [("Terrain", "Box")]
    assert seconds < 20.0
