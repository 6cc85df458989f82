"""Rays per second: embreex against Embree's C API through ctypes
(engine/embree_c.py: numba's one-ray loop, NumPy-filled 16-ray packets) on
the same triangles, one thread, best of several runs.

    .venv/bin/python tools/bench_embree_c.py [triangles] [rays]
"""
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from engine import embree_c, kernels, motion  # noqa: E402
from engine.accel import _import_embreex  # noqa: E402
from engine.testscenes import uv_sphere  # noqa: E402


def best(fn, runs=5):
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(triangles=200_000, rays=500_000):
    rings = int(np.sqrt(triangles / 2))
    sphere = uv_sphere(1.0, segments=2 * rings, rings=rings, smooth=False)
    corners = sphere.positions[sphere.triangles].astype(np.float32)
    vertices, indices = corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3)
    rng = np.random.default_rng(1)
    cases = {}
    # camera-like: from one point towards the sphere; incoherent: random points and directions
    o = np.tile([0.0, -4.0, 0.3], (rays, 1))
    d = rng.normal(0, 0.15, (rays, 3)) + [0.0, 1.0, 0.0]
    cases["coherent"] = (o, d / np.linalg.norm(d, axis=1)[:, None])
    o = rng.uniform(-1.5, 1.5, (rays, 3))
    d = rng.normal(size=(rays, 3))
    cases["incoherent"] = (o, d / np.linalg.norm(d, axis=1)[:, None])
    mc, rs = _import_embreex()
    from embreex import rtcore
    ex = rs.EmbreeScene(rtcore.EmbreeDevice())
    mc.TriangleMesh(ex, vertices, indices.astype(np.int32))
    still = embree_c.TriangleScene([(vertices[None], indices, np.arange(len(corners)))])
    # the same triangles moving: an instance with 3 transform steps
    steps = np.array([np.eye(4)] * 3)
    steps[:, 0, 3] = [-0.1, 0.0, 0.1]
    moving = embree_c.TriangleScene([], [(vertices[None], indices, np.arange(len(corners)),
                                          motion.decompose(steps).astype(np.float32))])
    kernels._state["enabled"] = True
    loops = embree_c._compiled_loops()
    kernels._state["enabled"] = False
    print(f"{len(corners)} triangles, {rays} rays, one thread; Mrays/s (best of 5)")
    for name, (o, d) in cases.items():
        of, df = o.astype(np.float32), d.astype(np.float32)
        tfar = np.full(rays, 1e30)
        ex.run(of[:10], df[:10])
        time_s = np.full(rays, 0.5)
        row = {
            "embreex": best(lambda: ex.run(of, df, dists=tfar.astype(np.float32), query="INTERSECT", output=1)),
            "C numba": best(lambda: still.intersect(o, d, tfar, time_s, loops=loops)) if loops else np.nan,
            "C packets": best(lambda: still.intersect(o, d, tfar, time_s, loops=False)),
            "C moving numba": best(lambda: moving.intersect(o, d, tfar, time_s, loops=loops)) if loops else np.nan,
            "embreex occl": best(lambda: ex.run(of, df, dists=tfar.astype(np.float32), query="OCCLUDED")),
            "C occl numba": best(lambda: still.occluded(o, d, tfar, time_s, loops=loops)) if loops else np.nan,
        }
        print(f"  {name}: " + ", ".join(f"{k} {rays / v / 1e6:.2f}" for k, v in row.items()))
    print(f"memory: embree_c keeps the float32 corners it was given ({still.nbytes / 1e6:.1f} MB here) "
          "besides Embree's BVH")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
