"""Ember against Cycles on the yardstick scenes, both through Blender (bpy module).

    make bench-cycles                 (or: .venv/bin/python -P tools/bench_cycles.py)
    .venv/bin/python -P tools/bench_cycles.py --quick --scenes cornell,principled

Every scene is rendered by Ember through the add-on and by Cycles (CPU) with
the same settings (default 256x256, 8 bounces, Blackman-Harris 1.5, no
denoising, no clamping), at a few sample counts each, and compared with a
converged Cycles reference rendered once and cached in build/bench_refs/
(keyed by scene, settings and the bpy version).

Model per engine and scene (adaptive sampling off): wall time t(n) = t0 + s n
(least squares over the sample counts: s = seconds per sample pass) and mean
squared error against the reference MSE(n) = v / n (v = variance per sample,
after removing the reference's own noise, from the mean MSE of ``--seeds``
renders at the largest count: one render's is noisy where few pixels hold
most of the error).  "time at equal RMSE" is the time
Ember's model needs to reach the MSE Cycles reaches at its largest sample
count, divided by Cycles' time for that count.  With adaptive sampling on (for
both, at Cycles' defaults; Ember only when it has ``use_adaptive_sampling``)
time no longer grows linearly with the sample count, so log MSE is fitted
linearly in log time instead, per engine, and Ember's fit is solved at Cycles'
last MSE.

Also per scene: CPU cores used (process CPU time / wall time, largest
count), paths/s (pixels x samples / wall time) and, for Ember, the share of
thread time inside Embree (engine stats ``embree_seconds``).  The full run
writes its tables into docs/benchmarks.md (between the bench-cycles markers).
"""
import argparse
import json
import os
import resource
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REFS = os.path.join(ROOT, 'build', 'bench_refs')
DOCS = os.path.join(ROOT, 'docs', 'benchmarks.md')
MARK_BEGIN = '<!-- bench-cycles: begin (tools/bench_cycles.py writes this section) -->'
MARK_END = '<!-- bench-cycles: end -->'

# Ember's counts end at Cycles' largest, so variance per sample compares at
# equal counts: with scrambled Sobol samples the error falls faster than
# 1/n over the first tens of samples (silhouettes, stratified lights), and
# extrapolating Ember from 24 spp to Cycles' 128 overstated its time (emissive
# meshes: variance per sample 2.29x at 24 vs 128 spp, 1.12x both at 128).
FULL = dict(size=256, ember=(2, 8, 32, 128), cycles=(8, 32, 128), reference=1024)
QUICK = dict(size=64, ember=(4, 16, 64), cycles=(16, 64), reference=1024)

# Scenes whose single render's MSE is decided by rare samples: the fog's
# scattering points next to the spot's disk whose phase ray meets the lamp
# (L ~ 200; both engines, as Cycles 5.0 weighs them: docs/benchmarks.md) put
# one 64-spp render in 12 at 20-100x the usual MSE.  --quick renders them
# with several seeds and fits the *median* MSE over the seeds for both
# engines (a typical render's error; the mean is printed beside it).
QUICK_SEEDS = {'fog': 8}
MEDIAN_SCENES = {'fog'}


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help="64x64, two sample counts, smaller reference")
    parser.add_argument('--scenes', help="comma-separated subset of the scenes")
    parser.add_argument('--size', type=int, help="square resolution (default 256, quick 64)")
    parser.add_argument('--bounces', type=int, default=8)
    parser.add_argument('--no-adaptive', action='store_true', help="skip the adaptive-sampling table")
    parser.add_argument('--docs', dest='docs', action='store_true', default=None,
                        help="write the tables into docs/benchmarks.md (default for full runs)")
    parser.add_argument('--no-docs', dest='docs', action='store_false')
    parser.add_argument('--json', help="also write the raw measurements here")
    parser.add_argument('--seeds', type=int, default=None,
                        help="renders (seeds) at the largest count, adaptive off (default 3, quick 1)")
    return parser.parse_args(argv)


def setup():
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-bench-'))
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    import addon
    addon.register()
    return jit_warm_up()


def jit_warm_up():
    """Compile Ember's kernels (or load them from the cache) before timing:
    renders would otherwise start on the NumPy forms.  Returns a note."""
    try:
        # Every kernel is defined once the renderer's modules are imported:
        # compile them all now, not only those of modules already loaded.
        from engine import kernels, render  # noqa: F401
    except ImportError:
        return "Ember without compiled kernels"
    if not kernels.configure(True):
        return f"Ember's compiled kernels off ({kernels.UNAVAILABLE})"
    ready = kernels.wait(900)
    return (f"Ember's compiled kernels {'ready' if ready else 'NOT ready'} after "
            f"{kernels.warm_up_seconds() or 0:.1f} s")


# ----------------------------------------------------------------------------
# engines

def configure(scene, engine, samples, seed, cfg, adaptive):
    scene.render.resolution_x = scene.render.resolution_y = cfg['size']
    scene.render.resolution_percentage = 100
    scene.render.use_border = False
    scene.render.film_transparent = False
    if engine == 'CYCLES':
        configure_cycles(scene, samples, seed, cfg['bounces'], adaptive)
    else:
        configure_ember(scene, samples, seed, cfg['bounces'], adaptive)


def configure_cycles(scene, samples, seed, bounces, adaptive):
    """The parity tests' Cycles set-up (tests/addon/ember_testlib.py), but at
    Cycles' own default light threshold (a speed feature a user has on), and
    its default adaptive sampling when asked."""
    for folder in (os.path.join(ROOT, 'tests'), os.path.join(ROOT, 'tests', 'addon')):
        if folder not in sys.path:   # ember_testlib, and the prerequisites module it imports
            sys.path.insert(0, folder)
    from ember_testlib import setup_cycles
    setup_cycles(scene, samples, seed, bounces)
    c = scene.cycles
    c.light_sampling_threshold = c.bl_rna.properties['light_sampling_threshold'].default
    c.use_adaptive_sampling = adaptive
    if adaptive:
        c.adaptive_threshold = 0.01  # Cycles' defaults
        c.adaptive_min_samples = 0


def configure_ember(scene, samples, seed, bounces, adaptive):
    scene.render.engine = 'EMBER'
    e = scene.ember
    e.samples = samples
    e.seed = seed
    e.max_bounces = bounces
    e.transparent_max_bounces = bounces
    e.diffuse_bounces = e.glossy_bounces = e.transmission_bounces = bounces
    e.filter_glossy = 0.0
    e.clamp = 0.0
    e.time_limit = 0.0
    e.filter_type = 'BLACKMAN_HARRIS'
    e.filter_width = 1.5
    e.threads = 0
    if hasattr(e, 'use_adaptive_sampling'):
        e.use_adaptive_sampling = adaptive
        if adaptive and hasattr(e, 'adaptive_threshold'):
            e.adaptive_threshold = 0.01
        if adaptive and hasattr(e, 'adaptive_min_samples'):
            e.adaptive_min_samples = 0


def ember_has_adaptive():
    import bpy
    return hasattr(bpy.context.scene.ember, 'use_adaptive_sampling')


def render(scene, folder):
    """Render with the scene's engine; returns (RGB float64, wall s, CPU s, Ember stats or None)."""
    import bpy
    from addon import engine as ember_engine
    del ember_engine.RENDER_LOG[:]
    cpu0 = _cpu_seconds()
    t0 = time.perf_counter()
    bpy.ops.render.render()
    wall = time.perf_counter() - t0
    cpu = _cpu_seconds() - cpu0
    stats = None
    if scene.render.engine == 'EMBER':
        log = ember_engine.RENDER_LOG[-1]
        if log['error']:
            raise RuntimeError(f"Ember failed: {log['error']}")
        stats = dict(log.get('stats') or {}, export_seconds=log.get('export_seconds'),
                     first_pass_seconds=log.get('first_pass_seconds'))
    return load_result(scene, folder), wall, cpu, stats


def _cpu_seconds():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def load_result(scene, folder):
    import bpy
    settings = scene.render.image_settings
    if hasattr(settings, 'media_type'):
        settings.media_type = 'IMAGE'
    settings.file_format = 'OPEN_EXR'
    settings.color_depth = '32'
    path = os.path.join(folder, 'result.exr')
    bpy.data.images['Render Result'].save_render(path, scene=scene)
    image = bpy.data.images.load(path)
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[..., :3].astype(np.float64)


# ----------------------------------------------------------------------------
# reference

def reference(name, cfg, folder):
    """The converged Cycles image, cached by scene, settings and bpy version."""
    import bpy
    import bench_scenes
    key = (f"{name}-{bench_scenes.scene_key(name)}-{cfg['size']}px-{cfg['bounces']}b-bh1.5-"
           f"{cfg['reference']}spp-bpy{bpy.app.version_string.replace(' ', '')}")
    path = os.path.join(REFS, key + '.npy')
    if os.path.isfile(path):
        return np.load(path), cfg['reference']
    scene = bench_scenes.SCENES[name][1]()
    configure(scene, 'CYCLES', cfg['reference'], 1234, cfg, adaptive=False)
    t0 = time.perf_counter()
    image, _, _, _ = render(scene, folder)
    print(f"  reference: Cycles {cfg['reference']} spp in {time.perf_counter() - t0:.1f} s -> {path}",
          flush=True)
    os.makedirs(REFS, exist_ok=True)
    np.save(path, image)
    return image, cfg['reference']


# ----------------------------------------------------------------------------
# measuring one engine

def measure(name, engine, counts, cfg, folder, ref, adaptive, seeds=1, median=False):
    """Renders at each count; the largest ``seeds`` times (other seeds):
    one render's MSE is a noisy estimate where a few pixels hold most of
    the error (Veach MIS: a single 128-spp render's variance per sample
    ranged 0.6-2.4x its mean over 64 seeds, tools/variance_seeds.py), so
    the largest count keeps the mean MSE and wall time of its renders
    (``median``: the median MSE, the mean kept as mse_mean)."""
    import bench_scenes
    runs = []
    for i, n in enumerate(counts):
        repeats = seeds if i == len(counts) - 1 else 1
        done = []
        for k in range(repeats):
            scene = bench_scenes.SCENES[name][1]()
            configure(scene, engine, n, 17 + i + 1000 * k, cfg, adaptive)
            image, wall, cpu, stats = render(scene, folder)
            mse = float(np.mean((image - ref) ** 2))
            done.append(dict(samples=n, wall=wall, cpu=cpu, mse=mse, stats=stats,
                             finite=bool(np.isfinite(image).all())))
            print(f"  {engine.lower():6s} {n:5d} spp: {wall:7.2f} s, RMSE {mse ** 0.5:.5f}, "
                  f"{cpu / wall:.2f} cores", flush=True)
        run = dict(done[0], mse_seeds=[d['mse'] for d in done], finite=all(d['finite'] for d in done))
        for key in ('wall', 'cpu', 'mse'):
            run[key] = float(np.mean([d[key] for d in done]))
        run['mse_mean'] = run['mse']
        if median and repeats > 1:
            run['mse'] = float(np.median(run['mse_seeds']))
            print(f"  {engine.lower():6s} {n:5d} spp: median RMSE {run['mse'] ** 0.5:.5f} over {repeats} seeds "
                  f"(mean MSE {run['mse_mean']:.3g})", flush=True)
        runs.append(run)
    return runs


def fit_linear(runs, ref_spp, v_ref):
    """t = t0 + s n (least squares over the runs) and MSE = v / n, v from the
    run with the most samples (reference noise v_ref / ref_spp removed).
    Both engines sample a scrambled Sobol sequence, whose error falls faster
    than 1 / n over the first few samples per pixel: a fit over every count
    would take its v mostly from the 2-spp run and overstate it (up to 2.6x
    for Ember's emissive scene); both engines' largest count is the same
    (FULL, QUICK), the one nearest to the counts the comparison needs."""
    n = np.array([r['samples'] for r in runs], float)
    t = np.array([r['wall'] for r in runs])
    mse = np.array([max(r['mse'] - v_ref / ref_spp, 1e-30) for r in runs])
    s, t0 = np.polyfit(n, t, 1) if len(n) > 1 else (t[0] / n[0], 0.0)
    v = float(mse[-1] * n[-1])
    return dict(t0=max(float(t0), 0.0), s=float(s), v=v, mse=mse)


def cycles_variance(runs, ref_spp):
    """Cycles' variance per sample with the reference noise inside, from its
    largest count (see fit_linear): MSE = v (1/n + 1/N)."""
    last = runs[-1]
    return float(last['mse'] / (1.0 / last['samples'] + 1.0 / ref_spp))


def summarise(name, ember_runs, cycles_runs, ref_spp, cfg):
    v_ref = cycles_variance(cycles_runs, ref_spp)
    fe = fit_linear(ember_runs, ref_spp, v_ref)
    fc = fit_linear(cycles_runs, ref_spp, v_ref)
    last = cycles_runs[-1]
    target = fc['mse'][-1]
    ember_n = fe['v'] / target
    ember_time = fe['t0'] + fe['s'] * ember_n
    return row(name, ember_runs, cycles_runs, cfg,
               time_ratio=ember_time / last['wall'], spp_ratio=fe['s'] / max(fc['s'], 1e-9),
               var_ratio=fe['v'] / fc['v'], var_ratio_se=ratio_se(ember_runs[-1], cycles_runs[-1]),
               ember_spp_needed=ember_n)


def ratio_se(ember, cycles):
    """Standard error of mean(Ember's MSE) / mean(Cycles' MSE) at the
    largest count, from the spread over seeds (None with one seed each)."""
    e, c = np.array(ember.get('mse_seeds', [])), np.array(cycles.get('mse_seeds', []))
    if len(e) < 2 or len(c) < 2:
        return None
    rel = e.var(ddof=1) / len(e) / e.mean() ** 2 + c.var(ddof=1) / len(c) / c.mean() ** 2
    return float(e.mean() / c.mean() * np.sqrt(rel))


def median_ratio_se(ember, cycles, draws=2000):
    """Bootstrap spread of median(Ember's MSE) / median(Cycles') over the
    seeds (resampled with replacement, a fixed generator): half its 16-84 %
    range (a standard deviation would follow the rare draws of the tail)."""
    rng = np.random.default_rng(0)
    e, c = np.asarray(ember), np.asarray(cycles)
    ratios = [np.median(rng.choice(e, len(e))) / np.median(rng.choice(c, len(c))) for _ in range(draws)]
    lo, hi = np.percentile(ratios, [16, 84])
    return float(0.5 * (hi - lo))


def summarise_adaptive(name, ember_runs, cycles_runs, ref_spp, cfg):
    """log MSE linear in log time per engine; Ember's line solved at Cycles' last MSE."""
    v_ref = cycles_variance(cycles_runs, ref_spp)

    def line(runs):
        t = np.log([r['wall'] for r in runs])
        m = np.log([max(r['mse'] - v_ref / ref_spp, 1e-30) for r in runs])
        return np.polyfit(t, m, 1) if len(runs) > 1 else (-1.0, m[0] + t[0])

    slope, offset = line(ember_runs)
    target = np.log(max(cycles_runs[-1]['mse'] - v_ref / ref_spp, 1e-30))
    ember_time = np.exp((target - offset) / slope) if slope < 0 else float('inf')
    return row(name, ember_runs, cycles_runs, cfg, time_ratio=ember_time / cycles_runs[-1]['wall'],
               spp_ratio=None, var_ratio=None, ember_spp_needed=None)


def row(name, ember_runs, cycles_runs, cfg, **values):
    e, c = ember_runs[-1], cycles_runs[-1]
    pixels = cfg['size'] ** 2
    stats = e['stats'] or {}
    threads = os.cpu_count() or 1
    embree = stats.get('embree_seconds', 0.0) / max(stats.get('seconds', 0.0) * threads, 1e-9)
    return dict(scene=name, ember_cores=e['cpu'] / e['wall'], cycles_cores=c['cpu'] / c['wall'],
                ember_paths_per_second=pixels * e['samples'] / e['wall'],
                cycles_paths_per_second=pixels * c['samples'] / c['wall'],
                embree_share=embree, ember_rmse=e['mse'] ** 0.5, cycles_rmse=c['mse'] ** 0.5,
                first_pass_seconds=stats.get('first_pass_seconds'),
                finite=all(r['finite'] for r in ember_runs + cycles_runs), **values)


# ----------------------------------------------------------------------------
# tables

def table(rows, adaptive):
    import bench_scenes
    head = ("| scene | Ember time / Cycles time at equal RMSE | s per sample pass, Ember / Cycles "
            "| variance per sample, Ember / Cycles | cores used, Ember (Cycles) | paths/s, Ember (Cycles) "
            "| Embree share of Ember's thread time | Ember's first image (s) |")
    if adaptive:
        head = ("| scene | Ember time / Cycles time at equal RMSE | cores used, Ember (Cycles) "
                "| paths/s, Ember (Cycles) | Embree share of Ember's thread time |")
    lines = [head, '|' + '---|' * (head.count('|') - 1)]
    for r in rows:
        title = bench_scenes.SCENES[r['scene']][0]
        # No finite ratio when Ember's error does not fall with time in the
        # measured range (e.g. a fixed cost larger than all sampling).
        ratio = f"{r['time_ratio']:.1f}x" if np.isfinite(r['time_ratio']) and r['time_ratio'] > 0 else "-"
        cells = [title, ratio]
        if not adaptive:
            # A slope lost in the fixed cost (tiny frames, busy machine) has no ratio.
            spp = f"{r['spp_ratio']:.1f}x" if 0 < r['spp_ratio'] < 1e3 else "-"
            se = r.get('var_ratio_se')
            cells += [spp, f"{r['var_ratio']:.2f}x" + (f" +- {se:.2f}" if se is not None else "")]
        cells += [f"{r['ember_cores']:.2f} ({r['cycles_cores']:.2f})",
                  f"{r['ember_paths_per_second'] / 1e6:.3f} M ({r['cycles_paths_per_second'] / 1e6:.2f} M)",
                  f"{100 * r['embree_share']:.0f} %"]
        if not adaptive:
            first = r.get('first_pass_seconds')
            cells.append(f"{first:.2f}" if first is not None else "-")
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def write_docs(text):
    with open(DOCS, encoding='utf-8') as handle:
        doc = handle.read()
    section = f"{MARK_BEGIN}\n{text}\n{MARK_END}"
    if MARK_BEGIN in doc and MARK_END in doc:
        head, rest = doc.split(MARK_BEGIN, 1)
        doc = head + section + rest.split(MARK_END, 1)[1]
    else:
        doc = doc.rstrip('\n') + '\n\n## Ember against Cycles (`make bench-cycles`)\n\n' + section + '\n'
    with open(DOCS, 'w', encoding='utf-8') as handle:
        handle.write(doc)


def report(rows, adaptive_rows, cfg, quick, adaptive_note, jit_note, seeds=1):
    import bpy
    import numpy
    when = time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())
    lines = [f"Measured {when} on {os.cpu_count()} cores with bpy {bpy.app.version_string}, numpy "
             f"{numpy.__version__}{' (--quick)' if quick else ''}: {cfg['size']}x{cfg['size']}, "
             f"{cfg['bounces']} bounces, Blackman-Harris 1.5, no denoising, no clamping, each engine's "
             f"default light selection; Ember at {', '.join(map(str, cfg['ember']))} spp, Cycles at "
             f"{', '.join(map(str, cfg['cycles']))} spp, reference Cycles {cfg['reference']} spp. "
             f"Times are the wall time of `bpy.ops.render.render()` (export/sync included). {jit_note}.",
             "", f"Adaptive sampling off ({seeds} render{'s' if seeds > 1 else ''} of each engine at the "
             f"largest count, their mean MSE, unless listed below; +- the variance ratio's standard error over "
             f"those seeds):",
             "", table(rows, False)]
    medians = [f"{r['scene']} ({r['median_of']} seeds)" for r in rows if r.get('median_of')]
    if medians:
        lines += ["", "Median MSE over the seeds instead of the mean, +- half a bootstrap 68 % range (rare bright "
                  "samples decide a render's mean there; tools/bench_cycles.py MEDIAN_SCENES): "
                  + ', '.join(medians) + "."]
    if adaptive_rows:
        lines += ["", "Adaptive sampling on for both (Cycles' defaults: threshold 0.01, min samples auto):",
                  "", table(adaptive_rows, True)]
    elif adaptive_note:
        lines += ["", adaptive_note]
    bad = [r['scene'] for r in rows + adaptive_rows if not r['finite']]
    if bad:
        lines += ["", "Non-finite pixels in: " + ', '.join(bad)]
    return '\n'.join(lines)


def main(argv=None):
    args = parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    cfg['size'] = args.size or cfg['size']
    cfg['bounces'] = args.bounces
    load_start = os.getloadavg()[0]
    jit_note = setup()
    print(jit_note, flush=True)
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import bench_scenes
    names = args.scenes.split(',') if args.scenes else list(bench_scenes.SCENES)
    unknown = [n for n in names if n not in bench_scenes.SCENES]
    if unknown:
        print(f"unknown scenes {unknown}; choose from {', '.join(bench_scenes.SCENES)}", file=sys.stderr)
        return 2
    adaptive = not args.no_adaptive and ember_has_adaptive()
    note = None if adaptive or args.no_adaptive else \
        "Adaptive sampling: not measured (this Ember has no `use_adaptive_sampling` setting)."
    rows, adaptive_rows, raw = [], [], {}
    with tempfile.TemporaryDirectory(prefix='ember-bench-cycles-') as folder:
        for name in names:
            print(f"{name}:", flush=True)
            ref, ref_spp = reference(name, cfg, folder)
            seeds = args.seeds or (QUICK_SEEDS.get(name, 1) if args.quick else 3)
            median = args.quick and name in MEDIAN_SCENES
            ember = measure(name, 'EMBER', cfg['ember'], cfg, folder, ref, False, seeds, median)
            cycles = measure(name, 'CYCLES', cfg['cycles'], cfg, folder, ref, False, seeds, median)
            rows.append(summarise(name, ember, cycles, ref_spp, cfg))
            rows[-1]['median_of'] = seeds if median and seeds > 1 else None
            if rows[-1]['median_of']:
                rows[-1]['var_ratio_se'] = median_ratio_se(ember[-1]['mse_seeds'], cycles[-1]['mse_seeds'])
                mean_ratio = ember[-1]['mse_mean'] / max(cycles[-1]['mse_mean'], 1e-30)
                print(f"  {name}: MSE ratio at the largest count, median {ember[-1]['mse'] / cycles[-1]['mse']:.2f}x, "
                      f"mean {mean_ratio:.2f}x over {seeds} seeds", flush=True)
            raw[name] = dict(ember=ember, cycles=cycles)
            if adaptive:
                print(" adaptive on:", flush=True)
                ember_a = measure(name, 'EMBER', cfg['ember'], cfg, folder, ref, True)
                cycles_a = measure(name, 'CYCLES', cfg['cycles'], cfg, folder, ref, True)
                adaptive_rows.append(summarise_adaptive(name, ember_a, cycles_a, ref_spp, cfg))
                raw[name].update(ember_adaptive=ember_a, cycles_adaptive=cycles_a)
    # Other jobs on the machine skew wall times and "cores used": say how busy it was.
    jit_note += (f". Load average {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end "
                 f"(on {os.cpu_count()} cores; above that, both engines shared the CPU with other jobs)")
    text = report(rows, adaptive_rows, cfg, args.quick, note, jit_note, args.seeds or (1 if args.quick else 3))
    print()
    print(text)
    if args.docs if args.docs is not None else not args.quick:
        write_docs(text)
        print(f"\nwritten to {DOCS}")
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as handle:
            json.dump(dict(rows=rows, adaptive_rows=adaptive_rows, raw=raw, cfg=cfg), handle, indent=1,
                      default=str)
    return 0


if __name__ == '__main__':
    sys.exit(main())
