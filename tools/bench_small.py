"""Where a small render's time goes (issue 25 item 4): warm process, wall
time of ``bpy.ops.render.render()`` through the add-on, split into export,
``prepare``, the batches (count, thread CPU each) and the film's merges.

    .venv/bin/python -P tools/bench_small.py --scenes cornell,principled --sizes 64x64,160x90 --spp 32
    .venv/bin/python -P tools/bench_small.py --ab HEAD~1     (that commit's engine/render.py alternated
                                                              with this tree's, render by render)

With ``--ab`` the other version's ``engine/render.py`` is loaded beside this
one (the rest of the engine is shared, so the kernel cache stays warm) and
the two render in turn, same seed: the table gives both and whether their
images are the same bit for bit.
"""
import argparse
import collections
import importlib
import importlib.util
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

import bench_cycles as bc  # noqa: E402


class Probe:
    """Counts and times the engine's pieces of one render (monkeypatched)."""

    def __init__(self, modules):
        film = importlib.import_module("engine.film")
        self.reset()
        for module in modules:
            self._wrap(module, "prepare", "prepare", time.perf_counter)
            self._wrap(module, "_run_batch", "batch", time.thread_time)
        self._wrap(film.Film, "merge", "merge", time.perf_counter)

    def reset(self):
        self.seconds = collections.defaultdict(float)
        self.counts = collections.Counter()
        self.batches = []   # (paths, thread ms) of each batch

    def _wrap(self, owner, name, key, clock):
        original = getattr(owner, name)

        def timed(*args, **kwargs):
            t0 = clock()
            try:
                return original(*args, **kwargs)
            finally:
                self.seconds[key] += clock() - t0
                self.counts[key] += 1
                if key == "batch":
                    self.batches.append((len(args[2]) * args[3], round((clock() - t0) * 1e3, 1)))
        setattr(owner, name, timed)


def other_render_module(rev):
    """``engine/render.py`` of git revision ``rev``, imported as engine.render_ab."""
    source = subprocess.run(["git", "-C", ROOT, "show", f"{rev}:engine/render.py"], check=True,
                            capture_output=True, text=True).stdout
    path = os.path.join(tempfile.mkdtemp(prefix="ember-ab-"), "render_ab.py")
    with open(path, "w") as handle:
        handle.write(source)
    spec = importlib.util.spec_from_file_location("engine.render_ab", path)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "engine"
    sys.modules["engine.render_ab"] = module
    spec.loader.exec_module(module)
    return module


def one_render(scene, folder, probe, variant, ember_engine):
    probe.reset()
    image, wall, cpu, _ = bc.render(scene, folder)
    log = ember_engine.RENDER_LOG[-1]
    return image, dict(variant=variant, wall=wall, cpu=cpu, export=log.get('export_seconds') or 0.0,
                       prepare=probe.seconds['prepare'], batches=probe.counts['batch'],
                       batch_cpu=probe.seconds['batch'], merge=probe.seconds['merge'], sizes=list(probe.batches))


def summary(rows):
    med = {k: float(np.median([r[k] for r in rows])) for k in ('wall', 'cpu', 'export', 'prepare', 'batch_cpu',
                                                              'merge')}
    return (f"wall {med['wall']:.3f} s (min {min(r['wall'] for r in rows):.3f}), CPU {med['cpu']:.3f} s, "
            f"export {med['export'] * 1e3:.1f} ms, prepare {med['prepare'] * 1e3:.1f} ms, "
            f"{rows[0]['batches']} batches {med['batch_cpu']:.3f} thread-s, merges {med['merge'] * 1e3:.1f} ms")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--scenes', default='cornell,principled')
    p.add_argument('--sizes', default='64x64,160x90')
    p.add_argument('--spp', type=int, default=32)
    p.add_argument('--runs', type=int, default=5)
    p.add_argument('--ab', help="a git revision whose engine/render.py renders in turn with this tree's")
    args = p.parse_args(argv)
    print(bc.setup(), f"load {os.getloadavg()[0]:.1f}", flush=True)
    import bench_scenes
    import engine
    from addon import engine as ember_engine
    new = importlib.import_module("engine.render")
    variants = {'new': new}
    if args.ab:
        variants = {'old': other_render_module(args.ab), 'new': new}
    probe = Probe(list(variants.values()))
    folder = tempfile.mkdtemp(prefix='ember-small-')
    try:
        for name in args.scenes.split(','):
            for size in args.sizes.split(','):
                w, h = (int(v) for v in size.split('x'))
                scene = bench_scenes.SCENES[name][1]()
                bc.configure(scene, 'EMBER', args.spp, 1, dict(size=w, bounces=8), adaptive=False)
                scene.render.resolution_x, scene.render.resolution_y = w, h
                rows, images = collections.defaultdict(list), {}
                for run in range(args.runs + 1):
                    for label, module in (variants.items() if run % 2 == 0 else reversed(variants.items())):
                        engine.render = module.render
                        image, row = one_render(scene, folder, probe, label, ember_engine)
                        images[label] = image
                        if run:   # the first round warms up
                            rows[label].append(row)
                same = "" if len(images) < 2 else \
                    f"; images identical: {np.array_equal(images['old'], images['new'])}"
                print(f"{name} {size} x {args.spp}, load {os.getloadavg()[0]:.1f}{same}", flush=True)
                for label in variants:
                    print(f"  {label}: {summary(rows[label])}", flush=True)
                    print(f"    batches (paths, thread ms): {rows[label][-1]['sizes']}", flush=True)
                if len(variants) == 2:
                    ratio = np.median([r['wall'] for r in rows['new']]) / np.median([r['wall'] for r in rows['old']])
                    cpu = np.median([r['cpu'] for r in rows['new']]) / np.median([r['cpu'] for r in rows['old']])
                    print(f"  new / old: wall {ratio:.3f}, CPU {cpu:.3f}", flush=True)
    finally:
        engine.render = new.render


if __name__ == '__main__':
    main()
