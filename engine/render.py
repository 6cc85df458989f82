"""The engine's front door: ``render(scene, settings, progress)``.

Progressive: passes of ``samples_per_pass`` samples accumulate in a Film;
after each pass ``progress.on_pass(image, samples_done, stats)`` receives the
current image and ``progress.should_stop()`` may end the render (the partial
image is kept).  Within a pass, pixels are cut into batches of at most
``max_paths / threads`` paths and the batches run on a thread pool: NumPy and
embreex both release the GIL, so the cores stay busy and memory stays bounded
whatever the resolution.
"""
import os
import time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from dataclasses import dataclass, field

import numpy as np

from .accel import Accel
from .bsdf import MaterialTable
from .camera import CameraModel, PixelFilter
from . import pass_events
from .film import Film, Tile
from .geometry import flatten, material_table
from .integrator import Context, trace_batch
from .lights import LightSet
from .scene import RenderSettings, SceneError
from .validate import validate_settings


@dataclass
class RenderResult:
    image: np.ndarray          # (H, W, 4) float32, row 0 at the top
    depth: np.ndarray          # (H, W)
    normal: np.ndarray         # (H, W, 3)
    albedo: np.ndarray         # (H, W, 3)
    variance: np.ndarray       # (H, W, 3) variance of each pixel's mean
    samples: int
    stats: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    # Requested extra passes {name: (H, W, C) float32} and their metadata
    # (Cryptomatte manifests): engine/passes.py.
    passes: dict = field(default_factory=dict)
    pass_metadata: dict = field(default_factory=dict)


def prepare(scene, settings):
    """Validate and compile a Scene into the read-only Context batches share."""
    scene.validate()
    validate_settings(settings)
    tris = flatten(scene, with_instance=bool(settings.passes))
    materials = MaterialTable(material_table(scene))
    lights = LightSet(scene, tris, materials, settings.light_selection,
                      env_compensation=settings.mis_compensation and settings.strategy == "mis")
    try:
        camera = CameraModel(scene.camera, PixelFilter(settings.filter_type, settings.filter_width))
    except ValueError as exc:
        raise SceneError(f"camera: {exc}") from None
    accel = Accel(tris)
    world = np.asarray(scene.world.color, dtype=np.float64)
    ctx = Context(accel, tris, materials, lights, camera, world, settings)
    ctx.pass_config = pass_events.configure(scene, settings)
    return ctx


def warnings_for(ctx):
    out = []
    if ctx.triangles.dropped:
        out.append(f"{ctx.triangles.dropped} degenerate triangles were skipped")
    if len(ctx.triangles) == 0 and ctx.lights.count == 0:
        out.append("the scene has no geometry and no lights")
    elif ctx.lights.count == 0 and not np.any(ctx.world > 0):
        out.append("the scene has no lights and a black world: the image will be black")
    return out


def _batches(npix, spp, settings, threads):
    """Contiguous pixel ranges: at most max_paths / threads paths each, and at
    least one per thread so small frames keep every core busy."""
    per_thread = max(1024, settings.max_paths // threads)
    pixels = max(1, min(per_thread // spp, -(-npix // threads)))
    return [(lo, min(npix, lo + pixels)) for lo in range(0, npix, pixels)]


def render(scene, settings=None, progress=None):
    settings = settings or RenderSettings()
    t_start = time.perf_counter()
    ctx = prepare(scene, settings)
    cam = ctx.camera
    film = Film(cam.width, cam.height, settings.passes)
    threads = settings.threads or os.cpu_count() or 1
    spp_pass = max(1, min(settings.samples_per_pass, settings.samples))
    n_passes = -(-settings.samples // spp_pass)
    batches = _batches(cam.width * cam.height, spp_pass, settings, threads)
    stats = {"samples": 0, "samples_total": settings.samples, "prepare_seconds": time.perf_counter() - t_start}
    t_trace = time.perf_counter()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for pass_index in range(n_passes):
            spp = min(spp_pass, settings.samples - pass_index * spp_pass)
            jobs = [pool.submit(_run_batch, ctx, film, lo, hi, spp, settings.seed, pass_index)
                    for lo, hi in batches]
            cancelled = _wait(jobs, progress)
            stats.update(_stats(ctx, film, stats, spp, t_trace, settings))
            if cancelled:
                # Part of a pass was traced: pixels carry unequal counts, each
                # mean is still unbiased.  Report the fewest samples any pixel has.
                stats["samples"] = int(film.count.min())
            if progress is not None and hasattr(progress, "on_pass"):
                progress.on_pass(film.image(settings.transparent), stats["samples"], dict(stats))
            if cancelled or _should_stop(progress, stats, settings):
                break
    return RenderResult(film.image(settings.transparent), film.aov("depth"),
                        film.aov("normal"), film.aov("albedo"), film.variance(),
                        stats["samples"], stats, warnings_for(ctx),
                        film.pass_images(ctx.pass_config), pass_events.metadata(ctx.pass_config, settings.passes))


def _wait(jobs, progress, poll=0.2):
    """Wait for a pass's batches, asking ``should_stop`` about every ``poll``
    seconds so a cancel lands within a fraction of a second, not a whole
    pass.  Returns True if the pass was cut short."""
    last_check = time.perf_counter()
    for job in jobs:
        while True:
            try:
                job.result(timeout=poll)
                done = True
            except FuturesTimeout:
                done = False
            now = time.perf_counter()
            if now - last_check >= poll:
                last_check = now
                if _stop_requested(progress):
                    _cancel(jobs)
                    return True
            if done:
                break
    return False


def _cancel(jobs):
    for job in jobs:
        job.cancel()
    for job in jobs:
        if not job.cancelled():
            job.result()


def _stop_requested(progress):
    return progress is not None and hasattr(progress, "should_stop") and bool(progress.should_stop())


def _run_batch(ctx, film, lo, hi, spp, seed, pass_index):
    rng = np.random.default_rng([seed, pass_index, lo])
    tile = Tile(lo, hi, ctx.settings.passes)
    pix = np.repeat(np.arange(lo, hi), spp)
    trace_batch(ctx, pix, rng, tile)
    film.merge(tile)


def _stats(ctx, film, stats, spp, t_trace, settings):
    elapsed = time.perf_counter() - t_trace
    done = stats["samples"] + spp
    totals = ctx.accel.totals()
    npix = film.width * film.height
    left = elapsed / done * (settings.samples - done) if done else 0.0
    return {
        "samples": done,
        "seconds": elapsed,
        "paths": done * npix,
        "paths_per_second": done * npix / max(elapsed, 1e-9),
        "rays": totals["rays"],
        "rays_per_second": totals["rays"] / max(elapsed, 1e-9),
        "embree_seconds": totals["seconds"],
        "seconds_left": left,
    }


def _should_stop(progress, stats, settings):
    if settings.time_limit > 0 and stats["seconds"] >= settings.time_limit:
        return True
    return _stop_requested(progress)
