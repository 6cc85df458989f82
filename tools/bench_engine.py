"""Engine benchmark: Cornell box (or --scene cornell-spheres, ~0.9 M
instanced triangles) at 512x512, 8 bounces.

    make bench          (or: python -m tools.bench_engine [--samples N])

Prints paths/s, rays/s, the share of wall time spent inside embreex calls
(summed over worker threads / (threads x wall)), raw embreex throughput for
the very same rays replayed alone on the same thread count, and peak memory
for two frame sizes with the same ``max_paths`` (memory is bounded by paths
in flight, not by pixels).
"""
import argparse
import importlib
import os
import resource
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from engine.accel import Accel
from engine.render import render
from engine.scene import RenderSettings
from engine.testscenes import SCENES


class RecordingAccel(Accel):
    """Keeps the first rays of every query so they can be replayed alone."""
    LIMIT = 2_000_000

    def __init__(self, triangles):
        super().__init__(triangles)
        self.recorded = {"INTERSECT": [], "OCCLUDED": []}
        self.count = {"INTERSECT": 0, "OCCLUDED": 0}

    def _keep(self, kind, o, d, tmax):
        if self.count[kind] < self.LIMIT:
            self.recorded[kind].append((o.astype(np.float32), d.astype(np.float32),
                                        np.minimum(tmax, 1e37).astype(np.float32)))
            self.count[kind] += len(o)

    def intersect(self, o, d, tmax):
        self._keep("INTERSECT", o, d, tmax)
        return super().intersect(o, d, tmax)

    def occluded(self, o, d, tmax):
        self._keep("OCCLUDED", o, d, tmax)
        return super().occluded(o, d, tmax)


def replay(accel, threads):
    """Raw embreex Mrays/s for the recorded rays, chunked over a thread pool."""
    out = {}
    for kind, batches in accel.recorded.items():
        o = np.concatenate([b[0] for b in batches])
        d = np.concatenate([b[1] for b in batches])
        t = np.concatenate([b[2] for b in batches])
        chunks = np.array_split(np.arange(len(o)), threads * 4)

        def run(idx):
            accel.scene.run(o[idx], d[idx], dists=t[idx].copy(), query=kind,
                            output=1 if kind == "INTERSECT" else None)

        t0 = time.perf_counter()
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, chunks))
        out[kind] = len(o) / (time.perf_counter() - t0) / 1e6
    return out


def memory_probe(size, max_paths):
    """Peak RSS (MiB) of a fresh process rendering 1 spp at size x size.

    Read from VmHWM: ru_maxrss survives fork + exec on Linux, so a child of
    this (large) process would report our peak instead of its own."""
    code = ("from engine.render import render; from engine.scene import RenderSettings;"
            "from engine.testscenes import cornell_box;"
            f"render(cornell_box({size},{size}), RenderSettings(samples=1, max_paths={max_paths}));"
            "print([int(l.split()[1]) / 1024 for l in open('/proc/self/status') if l.startswith('VmHWM')][0])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--max-paths", type=int, default=1 << 18)
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--scene", default="cornell", choices=sorted(SCENES))
    args = ap.parse_args(argv)

    render_mod = importlib.import_module("engine.render")   # the module: engine.render is the function
    made = []
    original = render_mod.Accel

    class Tracked(RecordingAccel):
        def __init__(self, tris):
            super().__init__(tris)
            made.append(self)

    render_mod.Accel = Tracked
    try:
        scene = SCENES[args.scene](512, 512)
        threads = args.threads or os.cpu_count()
        settings = RenderSettings(samples=args.samples, samples_per_pass=args.samples, max_bounces=8,
                                  threads=threads, max_paths=args.max_paths)
        t0 = time.perf_counter()
        result = render(scene, settings)
        wall = time.perf_counter() - t0
    finally:
        render_mod.Accel = original
    s = result.stats
    share = s["embree_seconds"] / (threads * s["seconds"])
    raw = replay(made[0], threads)
    print(f"{args.scene} ({len(made[0].triangles):,} triangles) 512x512, {args.samples} spp, 8 bounces, "
          f"{threads} threads, max_paths {args.max_paths}")
    print(f"  wall {wall:.2f} s (tracing {s['seconds']:.2f} s, prepare {s['prepare_seconds']:.3f} s)")
    print(f"  paths/s          {s['paths_per_second'] / 1e6:8.3f} M")
    print(f"  rays/s           {s['rays_per_second'] / 1e6:8.3f} M  ({s['rays'] / 1e6:.1f} M rays)")
    print(f"  embreex share    {100 * share:8.1f} %  ({s['embree_seconds']:.2f} thread-s of "
          f"{threads * s['seconds']:.2f})")
    print(f"  raw embreex, same rays replayed on {threads} threads: "
          f"{raw['INTERSECT']:.2f} Mrays/s intersect, {raw['OCCLUDED']:.2f} Mrays/s occluded")
    print(f"  peak RSS this process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    if not args.skip_memory:
        for size in (512, 2048):
            print(f"  peak RSS, 1 spp {size}x{size}, max_paths 2^16: {memory_probe(size, 1 << 16):.0f} MiB")


if __name__ == "__main__":
    main()
