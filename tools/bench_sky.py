"""Time of the single-scattering sky precompute (engine.nodes.sky.sky_table)
at the default resolution, fresh (cache cleared) and cached: the timing
tests/engine/test_sky.py used to assert (about 0.8 s on one idle core).

    PYTHONPATH=. .venv/bin/python tools/bench_sky.py [--repeat 3]
"""
import argparse
import time

from engine.nodes import sky


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    fresh = []
    for _ in range(args.repeat):
        sky.sky_table.cache_clear()
        start = time.perf_counter()
        sky.sky_table("single", 0.3, 100.0, 1.0, 1.0, 1.0)
        fresh.append(time.perf_counter() - start)
    start = time.perf_counter()
    sky.sky_table("single", 0.3, 100.0, 1.0, 1.0, 1.0)
    cached = time.perf_counter() - start
    print(f"sky table precompute: fresh {min(fresh):.3f} s (best of {args.repeat}), cached {cached * 1e6:.0f} us")


if __name__ == "__main__":
    main()
