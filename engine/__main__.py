"""Render an engine-native test scene without Blender.

    python -m engine [--scene cornell] [--size 512 512] [--samples 64] [-o out/cornell]
    python -m engine --compile-kernels

Writes <out>.exr (linear) and <out>.png (sRGB) through OpenImageIO and prints
progress and throughput; useful to profile the engine alone.
"""
import argparse
import os
import sys

from . import kernels
from .imageio import write_image
from .render import render
from .scene import RenderSettings, SceneError
from .testscenes import SCENES


class ConsoleProgress:
    def on_pass(self, image, samples, stats):
        total = stats["samples_total"]
        bar = "#" * int(30 * samples / total)
        sys.stderr.write(f"\r[{bar:<30}] {samples}/{total} spp  "
                         f"{stats['rays_per_second'] / 1e6:5.2f} Mrays/s  "
                         f"{stats['seconds_left']:5.1f} s left ")
        sys.stderr.flush()

    def on_status(self, text, fraction):
        sys.stderr.write(f"\r{text}   ")
        sys.stderr.flush()

    def should_stop(self):
        return False


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m engine", description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="cornell", choices=sorted(SCENES))
    ap.add_argument("--size", type=int, nargs=2, default=(512, 512), metavar=("W", "H"))
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--samples-per-pass", type=int, default=4)
    ap.add_argument("--max-bounces", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--strategy", default="mis", choices=("mis", "light", "bsdf"))
    ap.add_argument("--light-selection", default="auto", choices=("auto", "tree", "ris", "tree_bsdf", "power", "uniform", "all"))
    ap.add_argument("--max-paths", type=int, default=1 << 18)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("-o", "--output", default=os.path.join("out", "engine_cornell"))
    ap.add_argument("--compile-kernels", action="store_true",
                    help="only compile every kernel into the disk cache (make setup does this), then exit")
    args = ap.parse_args(argv)
    if args.compile_kernels:
        seconds = kernels.warm_cache()
        print(f"ember: {len(kernels.KERNELS)} kernels compiled or loaded in {seconds:.1f} s ({kernels.cache_dir()})")
        return 0

    scene = SCENES[args.scene](*args.size)
    settings = RenderSettings(samples=args.samples, samples_per_pass=args.samples_per_pass,
                              max_bounces=args.max_bounces, seed=args.seed, strategy=args.strategy,
                              light_selection=args.light_selection, max_paths=args.max_paths,
                              threads=args.threads)
    try:
        result = render(scene, settings, ConsoleProgress())
    except SceneError as exc:
        print(f"\nerror: {exc}", file=sys.stderr)
        return 2
    sys.stderr.write("\n")
    os.makedirs(os.path.dirname(args.output) or ".", exist_ok=True)
    for ext in (".exr", ".png"):
        write_image(args.output + ext, result.image)
    s = result.stats
    print(f"wrote {args.output}.exr and .png: {result.samples} spp in {s['seconds']:.2f} s, "
          f"{s['paths_per_second'] / 1e6:.3f} Mpaths/s, {s['rays_per_second'] / 1e6:.2f} Mrays/s, "
          f"{s['kernels']} kernels")
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
