"""Peak memory and time of many strands and points, still and moving (engine only).

    .venv/bin/python -P tools/bench_primitives.py            # every case, each in its own process
    .venv/bin/python -P tools/bench_primitives.py strands_moving

Cases: 100k strands of 9 control points (8 segments) and 10^6 points, each
still and with motion blur (3 transform steps and 3 deformation steps), a
diffuse floor under a point light, 64x48 at 1 sample.  Prints the peak RSS
of the process (ru_maxrss) before the scene, after building it and after
the render, and the render's wall time.
"""
import os
import resource
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

CASES = ('strands_still', 'strands_moving', 'points_still', 'points_moving')


def _peak_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _scene(case):
    import numpy as np
    from engine.scene import (Camera, HairCurves, Instance, Lobe, Material, PointCloud, PointLight, Scene)
    from engine.testscenes import look_at, quad
    rng = np.random.default_rng(1)
    slide = np.repeat(np.eye(4)[None], 3, axis=0)
    slide[:, 0, 3] = [-0.2, 0.0, 0.2]
    moving = case.endswith('moving')
    points, curves = [], []
    if case.startswith('strands'):
        count, keys = 100_000, 9
        roots = np.c_[rng.uniform(-2, 2, (count, 2)), np.zeros(count)]
        p = (roots[:, None, :] + np.arange(keys)[None, :, None] * [0.01, 0.0, 0.05]).reshape(-1, 3)
        kw = dict(motion=slide, motion_positions=np.stack([p - 0.02, p, p + 0.02])) if moving else {}
        curves.append(HairCurves(p, np.full(len(p), 0.004), np.arange(count + 1) * keys, materials=[0], **kw))
    else:
        count = 1_000_000
        p = np.c_[rng.uniform(-2, 2, (count, 2)), rng.uniform(0, 0.3, count)]
        r = np.full(count, 0.005)
        kw = dict(motion=slide, motion_positions=np.stack([p - 0.02, p, p + 0.02])) if moving else {}
        points.append(PointCloud(p, r, materials=[0], **kw))
    floor = quad([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]])
    return Scene(meshes=[floor], instances=[Instance(0, materials=[0])], points=points, curves=curves,
                 materials=[Material("diffuse", lobes=(Lobe("diffuse", color=(0.7, 0.6, 0.5)),))],
                 lights=[PointLight((0, -1, 4), (500, 500, 500))],
                 camera=Camera(matrix=look_at((0, -4, 3), (0, 0, 0)), resolution=(64, 48)))


def run(case):
    from engine.render import render
    from engine.scene import RenderSettings
    before = _peak_mib()
    scene = _scene(case)
    built = _peak_mib()
    start = time.perf_counter()
    result = render(scene, RenderSettings(samples=1, samples_per_pass=1, max_bounces=2))
    seconds = time.perf_counter() - start
    import numpy as np
    print(f"{case}: peak RSS {before:.0f} MiB before the scene, {built:.0f} MiB with it, "
          f"{_peak_mib():.0f} MiB after the render; render {seconds:.1f} s; finite {bool(np.isfinite(result.image).all())}",
          flush=True)


def main(argv):
    if argv:
        for case in argv:
            run(case)
        return
    for case in CASES:
        subprocess.run([sys.executable, '-P', os.path.abspath(__file__), case], check=False)


if __name__ == '__main__':
    main(sys.argv[1:])
