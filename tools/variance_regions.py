"""Where the variance of a yardstick scene comes from, Ember against Cycles.

    .venv/bin/python -P tools/variance_regions.py --scene veach_mis --samples 128 --seeds 8

Renders the scene with both engines at the SAME sample count over several
seeds (bench_cycles' set-up, adaptive sampling off) and splits the mean
squared error against bench_cycles' cached Cycles reference, times the
sample count (variance per sample, the reference's own noise included for
both), into the pixels where the reference is brighter than 1 and the rest,
and prints the standard error of the whole-image figure over the seeds.

bench_cycles takes its variance per sample from ONE render per engine: in
veach_mis nearly all of it (97-99 %) comes from a few dozen pixels (the highlights of
the small lights on the smooth plates; four pixels of the smallest light's
highlight on the smoothest plate hold about 40 %), whose squared error varies by 2-3x
from seed to seed, so a single render's ratio moves by tens of percent: at 128 spp
one seed's figure ranged 0.6-2.4 for Ember and 0.5-2.0 for Cycles, and bench_cycles'
1.91x (Ember seed 20 against Cycles seed 19) came out 1.04 +- 0.09 over 64 Ember
and 48 Cycles seeds (2026-11-26).  Hence the ratio's standard error below.
"""
import argparse
import os
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'tools'))

import bench_cycles  # noqa: E402  (tools/ on the path first)


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--scene', default='veach_mis')
    parser.add_argument('--samples', type=int, default=24)
    parser.add_argument('--seeds', type=int, default=8)
    parser.add_argument('--size', type=int, default=256)
    parser.add_argument('--bounces', type=int, default=8)
    return parser.parse_args(argv)


def render(name, engine, samples, seed, cfg, folder):
    import bench_scenes
    scene = bench_scenes.SCENES[name][1]()
    bench_cycles.configure(scene, engine, samples, seed, cfg, adaptive=False)
    image, _, _, _ = bench_cycles.render(scene, folder)
    return image


def classes(ref):
    """Boolean pixel masks: bright (reference above 1), rest."""
    bright = ref.mean(axis=2) > 1.0
    return {'bright (reference > 1)': bright, 'rest': ~bright}


def variance_map(name, engine, cfg, ref, args, folder):
    """Per-pixel squared error times the sample count, averaged over seeds,
    and the whole image's figure per seed."""
    total = np.zeros(ref.shape[:2])
    per_seed = []
    for s in range(args.seeds):
        image = render(name, engine, args.samples, 101 + s, cfg, folder)
        err = ((image - ref) ** 2).mean(axis=2) * args.samples
        per_seed.append(err.mean())
        total += err
    return total / args.seeds, np.array(per_seed)


def standard_error(per_seed):
    return per_seed.std(ddof=1) / np.sqrt(len(per_seed)) if len(per_seed) > 1 else float('nan')


def ratio_error(ember, cycles):
    """Ratio of the mean per-seed figures and its standard error (first-order
    propagation; the two engines' seeds are independent)."""
    e, c = ember.mean(), cycles.mean()
    ratio = e / max(c, 1e-30)
    relative = np.hypot(standard_error(ember) / max(e, 1e-30), standard_error(cycles) / max(c, 1e-30))
    return ratio, ratio * relative


def pixels_holding(vmap, share):
    """How many of the worst pixels hold ``share`` of the image's total."""
    values = np.sort(vmap.ravel())[::-1]
    total = values.sum()
    if total <= 0:
        return 0
    return int(np.searchsorted(np.cumsum(values), share * total) + 1)


def main(argv=None):
    args = parse_args(argv)
    cfg = dict(bench_cycles.FULL, size=args.size, bounces=args.bounces)
    bench_cycles.setup()
    with tempfile.TemporaryDirectory(prefix='ember-variance-') as folder:
        ref, _ = bench_cycles.reference(args.scene, cfg, folder)
        masks = classes(ref)
        maps = {engine: variance_map(args.scene, engine, cfg, ref, args, folder)
                for engine in ('EMBER', 'CYCLES')}
    pixels = ref.shape[0] * ref.shape[1]
    print(f"\n{args.scene}, {args.samples} spp, {args.seeds} seeds: variance per sample "
          "(image mean of squared error x spp; share of the image's total in brackets)")
    for engine, (vmap, per_seed) in maps.items():
        print(f"  {engine.lower():6s} whole image {vmap.mean():.4f} +- {standard_error(per_seed):.4f} "
              f"(standard error over seeds); half of it in the {pixels_holding(vmap, 0.5)} worst pixels")
    ratio, error = ratio_error(maps['EMBER'][1], maps['CYCLES'][1])
    print(f"  ratio Ember / Cycles {ratio:.2f} +- {error:.2f} (one render's ratio scatters far more)")
    for label, mask in masks.items():
        e, c = (maps[k][0][mask].sum() / pixels for k in ('EMBER', 'CYCLES'))
        print(f"  {label:24s} [{mask.sum():6d} px]: Ember {e:.4f} ({e / maps['EMBER'][0].mean():4.0%}), "
              f"Cycles {c:.4f} ({c / maps['CYCLES'][0].mean():4.0%}), ratio {e / max(c, 1e-30):.2f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
