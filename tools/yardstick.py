"""The honest yardstick (issue 25): Ember's measured time to Cycles' noise.

    .venv/bin/python -P tools/yardstick.py --quick --scenes cornell,veach_mis
    .venv/bin/python -P tools/yardstick.py                     (256x256, every scene)

Unlike ``tools/bench_cycles.py`` (which models Ember's time at equal RMSE
from its variance per sample, as if that were constant over sample counts),
nothing here is extrapolated:

1. Cycles runs both its light-tree settings (on, off), and with
   ``--cycles-guiding both`` each of them with its path guiding on and off
   (CPU, OpenPGL: the issue asks for it wherever Ember guides), at its
   sample count, ``--seeds`` renders each; the setting with the best
   efficiency (1 / (MSE x time)) is Cycles' for the scene and is recorded.  Its mean MSE
   is the target; its mean wall time the time to beat.
2. Ember's sample count reaching that MSE is found by bisection on samples
   (geometric, a few seeds per step), then rendered with ``--seeds`` seeds:
   Ember's time is the mean wall time of those renders, interpolated in
   log-log between the two measured counts that bracket the target.
3. Both engines render from a warm process (a first untimed render per
   engine and scene) and the MSE is against a converged Cycles reference
   (build/bench_refs/, as bench_cycles), its own noise removed.

The spread over seeds is printed with each number.  Timings vary 10-20 % on
a shared machine; the load average is printed at the start and the end.
"""
import argparse
import math
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import bench_cycles as bc  # noqa: E402

FULL = dict(size=256, cycles_spp=128, reference=1024)
QUICK = dict(size=64, cycles_spp=64, reference=1024)
BISECTION_STEPS = 5
BISECTION_SEEDS = 2


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help="64x64, Cycles at 64 spp")
    p.add_argument('--scenes', help="comma-separated subset of tools/bench_scenes.py's scenes")
    p.add_argument('--seeds', type=int, default=5, help="renders per engine at the final counts (>= 5)")
    p.add_argument('--bounces', type=int, default=8)
    p.add_argument('--cycles-guiding', choices=('off', 'both'), default='both',
                   help="also try Cycles with its path guiding on (default both)")
    p.add_argument('--docs', action='store_true', help="write the table into docs/benchmarks.md")
    return p.parse_args(argv)


def render_once(name, engine, samples, seed, cfg, folder, ref, tree=None):
    """(MSE against the reference, wall seconds) of one render.  ``tree``:
    Cycles' setting, (light tree, path guiding) or None for its defaults."""
    import bench_scenes
    scene = bench_scenes.SCENES[name][1]()
    bc.configure(scene, engine, samples, seed, cfg, adaptive=False)
    if engine == 'CYCLES' and tree is not None:
        configure_cycles(scene, *tree)
    image, wall, _, _ = bc.render(scene, folder)
    if not np.isfinite(image).all():
        raise RuntimeError(f"{name}: {engine} rendered non-finite pixels")
    return float(np.mean((image - ref) ** 2)), wall


def renders(name, engine, samples, seeds, cfg, folder, ref, tree=None, first_seed=101):
    """Arrays (MSE, wall) over ``seeds`` seeds."""
    out = [render_once(name, engine, samples, first_seed + k, cfg, folder, ref, tree) for k in range(seeds)]
    mse, wall = (np.array(v) for v in zip(*out))
    return mse, wall


def configure_cycles(scene, tree, guiding):
    """Cycles' light tree and path guiding (surface and volume, its
    defaults otherwise) where this Cycles has them; None leaves a default."""
    cycles = scene.cycles
    if tree is not None and hasattr(cycles, 'use_light_tree'):
        cycles.use_light_tree = tree
    if guiding is not None and hasattr(cycles, 'use_guiding'):
        cycles.use_guiding = guiding
        cycles.use_surface_guiding = guiding
        cycles.use_volume_guiding = guiding


def cycles_settings(guiding):
    """The (light tree, path guiding) pairs to try in this Cycles."""
    import bpy
    import _cycles
    cycles = bpy.context.scene.cycles
    trees = (True, False) if hasattr(cycles, 'use_light_tree') else (None,)
    guided = guiding == 'both' and hasattr(cycles, 'use_guiding') and getattr(_cycles, 'with_path_guiding', False)
    return [(tree, g) for tree in trees for g in ((False, True) if guided else (None,))]


def setting_name(setting):
    tree, guiding = setting
    words = {True: 'on', False: 'off', None: '-'}
    name = f"tree {words[tree]}"
    return name if guiding is None else f"{name}, guiding {words[guiding]}"


def cycles_best(name, cfg, folder, ref, seeds, ref_noise, guiding='both'):
    """Cycles' best (light tree, path guiding) setting by efficiency; returns
    a dict (its MSE and wall times, the setting, its gain over the next best)."""
    results = {}
    for setting in cycles_settings(guiding):
        render_once(name, 'CYCLES', 4, 1, cfg, folder, ref, setting)           # warm
        mse, wall = renders(name, 'CYCLES', cfg['cycles_spp'], seeds, cfg, folder, ref, setting)
        err = np.maximum(mse - ref_noise, 1e-30)
        results[setting] = dict(mse=err, wall=wall, efficiency=1.0 / (err.mean() * wall.mean()))
        print(f"  cycles {setting_name(setting)}: {wall.mean():.2f} s, RMSE {math.sqrt(err.mean()):.5f} "
              f"(seeds {err.min() ** 0.5:.5f}-{err.max() ** 0.5:.5f})", flush=True)
    ranked = sorted(results, key=lambda t: results[t]['efficiency'], reverse=True)
    best = ranked[0]
    gain = results[best]['efficiency'] / results[ranked[1]]['efficiency'] if len(ranked) > 1 else 1.0
    return dict(results[best], tree=best, gain=gain)


def ember_bisect(name, cfg, folder, ref, target, ref_noise):
    """Measured (samples, mean MSE, mean wall) points, bracketing ``target``."""
    render_once(name, 'EMBER', 4, 1, cfg, folder, ref)                      # warm
    points = {}

    def at(n):
        if n not in points:
            mse, wall = renders(name, 'EMBER', n, BISECTION_SEEDS, cfg, folder, ref, first_seed=500 + n)
            points[n] = (float(np.maximum(mse - ref_noise, 1e-30).mean()), float(wall.mean()))
            print(f"  ember {n:5d} spp: {points[n][1]:.2f} s, RMSE {math.sqrt(points[n][0]):.5f}", flush=True)
        return points[n][0]

    lo, hi = 1, cfg['cycles_spp']
    while at(hi) > target and hi < 64 * cfg['cycles_spp']:
        lo, hi = hi, hi * 4
    for _ in range(BISECTION_STEPS):
        if hi - lo <= max(1, lo // 8):
            break
        mid = int(round(math.sqrt(lo * hi)))
        if mid in (lo, hi):
            break
        if at(mid) > target:
            lo = mid
        else:
            hi = mid
    return lo, hi, points


def ember_final(name, cfg, folder, ref, target, ref_noise, lo, hi, seeds):
    """Ember at the bracketing counts with ``seeds`` seeds; the time at the
    target by log-log interpolation between them."""
    ends = []
    for n in sorted({max(lo, 1), hi}):
        mse, wall = renders(name, 'EMBER', n, seeds, cfg, folder, ref, first_seed=900 + n)
        ends.append((n, np.maximum(mse - ref_noise, 1e-30), wall))
    if len(ends) == 1:
        n, mse, wall = ends[0]
        return dict(samples=n, time=wall.mean(), mse=mse, wall=wall)
    (n0, m0, w0), (n1, m1, w1) = ends
    lm0, lm1, lt = math.log(m0.mean()), math.log(m1.mean()), math.log(target)
    a = 0.0 if lm0 == lm1 else min(max((lm0 - lt) / (lm0 - lm1), 0.0), 1.0)
    time_at = math.exp((1 - a) * math.log(w0.mean()) + a * math.log(w1.mean()))
    samples = math.exp((1 - a) * math.log(n0) + a * math.log(n1))
    return dict(samples=samples, time=time_at, mse=m1, wall=w1, low=(n0, m0, w0))


def measure_scene(name, cfg, folder, seeds, guiding='both'):
    ref, ref_spp = bc.reference(name, dict(cfg, bounces=cfg['bounces']), folder)
    # The reference's own noise: Cycles' variance per sample / ref_spp,
    # estimated from a Cycles render (as bench_cycles' cycles_variance).
    mse_probe, _ = render_once(name, 'CYCLES', cfg['cycles_spp'], 7, cfg, folder, ref)
    ref_noise = mse_probe / (1.0 + cfg['cycles_spp'] / ref_spp) * (cfg['cycles_spp'] / ref_spp)
    cycles = cycles_best(name, cfg, folder, ref, seeds, ref_noise, guiding)
    target = float(cycles['mse'].mean())
    lo, hi, _ = ember_bisect(name, cfg, folder, ref, target, ref_noise)
    ember = ember_final(name, cfg, folder, ref, target, ref_noise, lo, hi, seeds)
    ratio = ember['time'] / cycles['wall'].mean()
    # Spread: each seed's time ratio at the hi count, and the MSE spread.
    return dict(scene=name, cycles=cycles, ember=ember, ratio=ratio,
                ratio_range=(ember['wall'].min() / cycles['wall'].max(), ember['wall'].max() / cycles['wall'].min()),
                mse_spread=(float(ember['mse'].std(ddof=1) / ember['mse'].mean()),
                            float(cycles['mse'].std(ddof=1) / cycles['mse'].mean())))


def table(rows, cfg):
    import bench_scenes
    lines = ["| scene | Cycles' best setting (efficiency gain over the next) | Cycles: spp, s | "
             "Ember: spp to Cycles' RMSE, s | Ember time / Cycles time | spread over seeds: time ratio range, "
             "MSE sd / mean Ember (Cycles) |", "|---|---|---|---|---|---|"]
    for r in rows:
        c, e = r['cycles'], r['ember']
        lines.append(f"| {bench_scenes.SCENES[r['scene']][0]} | {setting_name(c['tree'])} ({c['gain']:.2f}x) | "
                     f"{cfg['cycles_spp']}, {c['wall'].mean():.2f} | {e['samples']:.0f}, {e['time']:.2f} | "
                     f"**{r['ratio']:.2f}x** | {r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f}x, "
                     f"{r['mse_spread'][0]:.2f} ({r['mse_spread'][1]:.2f}) |")
    return '\n'.join(lines)


def main(argv=None):
    args = parse_args(argv)
    if args.seeds < 5:
        print("--seeds: at least 5 (the issue's minimum)", file=sys.stderr)
        return 2
    cfg = dict(QUICK if args.quick else FULL, bounces=args.bounces)
    cfg['ember'], cfg['cycles'] = (), ()
    load = os.getloadavg()[0]
    note = bc.setup()
    import bench_scenes
    names = args.scenes.split(',') if args.scenes else list(bench_scenes.SCENES)
    unknown = [name for name in names if name not in bench_scenes.SCENES]
    if unknown:  # before any render: a typo must not cost the minutes of the scenes before it
        print(f"unknown scene(s) {', '.join(unknown)}; tools/bench_scenes.py has: "
              f"{', '.join(bench_scenes.SCENES)}", file=sys.stderr)
        return 2
    rows = []
    with tempfile.TemporaryDirectory(prefix='ember-yardstick-') as folder:
        for name in names:
            print(f"{name}:", flush=True)
            rows.append(measure_scene(name, cfg, folder, args.seeds, args.cycles_guiding))
    import bpy
    head = (f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} with bpy {bpy.app.version_string} "
            f"({note}): {cfg['size']}x{cfg['size']}, {cfg['bounces']} bounces, adaptive sampling off, "
            f"{args.seeds} seeds per engine at the final counts; load average {load:.1f} at the start, "
            f"{os.getloadavg()[0]:.1f} at the end on {os.cpu_count()} cores.")
    text = head + "\n\n" + table(rows, cfg)
    print("\n" + text)
    if args.docs:
        with open(bc.DOCS, 'a', encoding='utf-8') as handle:
            handle.write("\n\n### Honest yardstick (`tools/yardstick.py`)\n\n" + text + "\n")
    return 0


if __name__ == '__main__':
    sys.exit(main())
