"""Ember's variance per sample of a yardstick scene over many seeds, without Blender.

    .venv/bin/python -P tools/variance_seeds.py veach_mis --samples 128 --seeds 64
    .venv/bin/python -P tools/variance_seeds.py veach_mis --selection all tree --samples 32 --seeds 16
    .venv/bin/python -P tools/variance_seeds.py glossy_lights --selection tree ris ris:2 --samples 16 --seeds 8

Renders the scene exported by tools/profile_scene.py (cached pickle, 256 px,
8 bounces) with the engine alone, each seed at the same sample count, and
prints the variance per sample (per-pixel variance across seeds of the pixel
means, times the sample count, averaged over the image and the channels),
its standard error over the seeds, and the thread CPU seconds per 65,536
paths: their product compares settings by time at equal error.

--bright renders only the pixels where bench_cycles' cached Cycles reference
is brighter than 1 (veach_mis: 1,172 pixels hold 99 % of the error), which
makes 64 seeds at 128 spp a minute's work; the figure stays per image pixel.
Pixel samples never leave their pixel (the filter is importance sampled), so
a subset of pixels renders exactly as in the full image (its CPU figure is
that of those pixels' paths, not the image's).

In a scene with a volume the camera rays are guided as in a render (the
guide rebuilt between passes 1, 1, 2, 4, ... samples); --guide off / both
compares without it, --size renders a smaller image of the same scene.
--path-guiding on / both guides the BSDF samples at surface vertices
(trained over --training samples, rebuilt as the renderer does).

This measures Ember's own spread, the reference's noise and any bias left
out; tools/variance_regions.py compares with Cycles through Blender (slow:
eight seeds give a ratio only to +-15-20 % in veach_mis, where a few pixels'
rare bright samples dominate).
"""
import argparse
import dataclasses
import glob
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'tools'))
REFS = os.path.join(ROOT, 'build', 'bench_refs')
BATCH = 65536


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('scene', help="a tools/bench_scenes.py name")
    parser.add_argument('--samples', type=int, default=128)
    parser.add_argument('--seeds', type=int, default=32)
    parser.add_argument('--first-seed', type=int, default=1000)
    parser.add_argument('--selection', nargs='+', default=[None],
                        help="light selections to compare (auto, tree, ris, ris:M with M candidates, power, uniform, "
                             "all); default: the scene's")
    parser.add_argument('--bright', action='store_true', help="only pixels the reference shows brighter than 1")
    parser.add_argument('--size', type=int, default=0, help="render at size x size pixels instead of the pickle's")
    parser.add_argument('--guide', choices=('on', 'off', 'both'), default='on',
                        help="volume scattering probability guiding (scenes with a volume); both: A/B, alternated")
    parser.add_argument('--path-guiding', choices=('on', 'off', 'both'), default='off',
                        help="path guiding at surface vertices (engine/integrator/path_guide.py), trained over "
                             "--training samples; both: A/B, alternated seed by seed")
    parser.add_argument('--training', type=int, default=128, help="path guiding's training samples")
    return parser.parse_args(argv)


def bright_pixels(name, width, height):
    """Film indices (row 0 at the top) of the pixels above 1 in the cached
    256-px Cycles reference (stored bottom row first, as Blender's pixels)."""
    found = sorted(glob.glob(os.path.join(REFS, f'{name}-*-{width}px-8b-*.npy')))
    if not found:
        raise SystemExit(f"no cached {width}-px Cycles reference of {name} in {REFS} (tools/bench_cycles.py makes it)")
    ref = np.load(found[-1])[::-1].reshape(-1, 3)
    assert len(ref) == width * height
    return np.flatnonzero(ref.mean(axis=1) > 1.0)


def pass_starts(samples, passes, guided):
    """First samples of the passes: ``passes`` samples each, or with volume
    guiding the renderer's schedule 1, 1, 2, 4, ... up to ``passes`` (the
    guide is updated between passes, engine/render.py)."""
    starts, start = [], 0
    while start < samples:
        starts.append(start)
        start += min(max(start, 1), passes) if guided else passes
    return starts + [samples]


def render_seeds(ctx, pixels, samples, seeds, first_seed, guided=False, path_guiding=(False,), training=128):
    """Pixel means {path guiding: (seeds, len(pixels), 3)} and the thread CPU
    seconds spent tracing; with several path-guiding modes each seed renders
    them in turn (A/B alternated: the machine's load weighs them alike)."""
    from engine.film import Film
    from engine.integrator import path_guide, trace_batch
    from engine.sampler import Sampler
    width, height = ctx.camera.width, ctx.camera.height
    means = {g: np.empty((seeds, len(pixels), 3)) for g in path_guiding}
    cpu = dict.fromkeys(path_guiding, 0.0)
    # Batches of about BATCH paths, whole sample passes each (the renderer's own batch size).
    passes = max(1, BATCH // len(pixels))
    starts = pass_starts(samples, passes, guided or any(path_guiding))
    for k in range(seeds):
        seeded = dataclasses.replace(ctx, sampler=Sampler(first_seed + k, ctx.settings.sampling_pattern))
        for g in path_guiding:
            guide = path_guide.PathGuide(*path_guide.bounds_of(ctx.triangles), training) if g else None
            film = Film(width, height, (), guide=guided, path_guide=guide)
            guided_at = rebuilt = 0   # as engine/render.py: rebuilt when the samples have doubled
            for start, end in zip(starts, starts[1:]):
                sample = np.arange(start, end, dtype=np.uint32)
                if film.guide is not None:
                    film.guide.update(film.count)
                if guide is not None and start >= 2 * guided_at and guided_at < training:
                    guide.update(start - rebuilt)
                    guided_at, rebuilt = max(start, 1), start
                tile = film.new_tile(int(pixels.min()), int(pixels.max()) + 1, start)
                t0 = time.thread_time()
                trace_batch(seeded, np.tile(pixels, len(sample)), np.repeat(sample, len(pixels)), tile)
                cpu[g] += time.thread_time() - t0
                film.merge(tile)
            means[g][k] = film.mean[pixels]
    return means, cpu


def summary(means, samples, image_pixels):
    """Variance per sample of the image and its standard error over seeds."""
    seeds = len(means)
    per_seed = ((means - means.mean(axis=0)) ** 2).mean(axis=2).sum(axis=1) * samples / image_pixels
    per_seed *= seeds / (seeds - 1)   # deviations from the seeds' own mean
    return per_seed.mean(), per_seed.std(ddof=1) / np.sqrt(seeds)


def main(argv=None):
    args = parse_args(argv)
    if args.seeds < 2:
        raise SystemExit("--seeds must be at least 2 (the variance is taken across seeds)")
    sys.path.insert(0, ROOT)
    from dataclasses import replace
    from engine import kernels
    from engine.blas import single_threaded_blas
    from engine.render import prepare
    from profile_scene import load
    scene, settings = load(args.scene)
    if args.size:
        scene = replace(scene, camera=replace(scene.camera, resolution=(args.size, args.size)))
    kernels.configure(True)
    kernels.wait(900)
    from engine.integrator import stages
    default_candidates = stages.RIS_CANDIDATES
    for selection in args.selection:
        # 'ris:M': resampled selection with M candidates per vertex.
        selection, _, candidates = (selection or '').partition(':')
        stages.RIS_CANDIDATES = int(candidates) if candidates else default_candidates
        chosen = replace(settings, light_selection=selection) if selection else settings
        ctx = prepare(scene, chosen)
        image_pixels = ctx.camera.width * ctx.camera.height
        pixels = (bright_pixels(args.scene, ctx.camera.width, ctx.camera.height) if args.bright
                  else np.arange(image_pixels))
        modes = {'on': [True], 'off': [False], 'both': [False, True]}[args.guide]
        guided = [g and ctx.media is not None and ctx.bake is None for g in modes]
        pg_modes = {'on': (True,), 'off': (False,), 'both': (False, True)}[args.path_guiding]
        for g in guided:
            with single_threaded_blas():
                means, cpu = render_seeds(ctx, pixels, args.samples, args.seeds, args.first_seed, g, pg_modes,
                                          args.training)
            for p in pg_modes:
                v, error = summary(means[p], args.samples, image_pixels)
                per_64k = cpu[p] / (args.seeds * args.samples * len(pixels)) * 65536
                label = chosen.light_selection + (f":{stages.RIS_CANDIDATES}" if chosen.light_selection == "ris" else "")
                label += ", volume guiding" if g else ""
                label += f", path guiding ({args.training} training samples)" if p else ""
                print(f"{args.scene} ({label}, {args.samples} spp, {args.seeds} seeds, "
                      f"{len(pixels)} px): variance per sample {v:.5g} +- {error:.2g}, "
                      f"{per_64k:.3f} CPU-s per 64k paths, product {v * per_64k:.5g}", flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
