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
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout

import numpy as np

from .accel import Accel
from .bsdf import MaterialTable
from .camera import CameraModel, PixelFilter
from .film import Film, Tile
from .geometry import flatten, material_table
from .integrator import Context, trace_batch
from .lights import LightSet
from .scene import Cancelled, RenderSettings, SceneError
from .validate import validate_settings


class RenderResult:
    """The finished (or stopped) render: the RGBA image and the film behind
    it; first-hit AOVs and variance are computed from the film on demand
    (each is a full-frame array: seconds at 8K that a cancel must not wait for)."""

    def __init__(self, film, image, samples, stats=None, warnings=None):
        self.film = film
        self.image = image          # (H, W, 4) float32, row 0 at the top
        self.samples = samples
        self.stats = stats or {}
        self.warnings = warnings or []

    @property
    def depth(self):
        return self.film.aov("depth")

    @property
    def normal(self):
        return self.film.aov("normal")

    @property
    def albedo(self):
        return self.film.aov("albedo")

    @property
    def variance(self):
        """(H, W, 3) variance of each pixel's mean."""
        return self.film.variance()


def prepare(scene, settings):
    """Validate and compile a Scene into the read-only Context batches share."""
    scene.validate()
    validate_settings(settings)
    tris = flatten(scene)
    materials = MaterialTable(material_table(scene))
    lights = LightSet(scene, tris, materials, settings.light_selection,
                      env_compensation=settings.mis_compensation and settings.strategy == "mis")
    try:
        camera = CameraModel(scene.camera, PixelFilter(settings.filter_type, settings.filter_width))
    except ValueError as exc:
        raise SceneError(f"camera: {exc}") from None
    accel = Accel(tris)
    world = np.asarray(scene.world.color, dtype=np.float64)
    return Context(accel, tris, materials, lights, camera, world, settings)


def prepare_interruptibly(scene, settings, progress, poll=0.05):
    """``prepare`` (flattening, light set, BVH build: seconds on millions of
    triangles, none of it interruptible) in a daemon thread, asking
    ``progress.should_stop`` every ``poll`` seconds.  On a stop the thread is
    abandoned (it finishes in the background, its result is dropped) and
    ``Cancelled`` is raised at once."""
    if not hasattr(progress, "should_stop"):
        return prepare(scene, settings)
    outcome = {}

    def work():
        try:
            outcome["ctx"] = prepare(scene, settings)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            outcome["error"] = exc
    worker = threading.Thread(target=work, name="ember-prepare", daemon=True)
    worker.start()
    while True:
        worker.join(poll)
        if not worker.is_alive():
            break
        if _stop_requested(progress):
            raise Cancelled("stopped while preparing the scene")
    if "error" in outcome:
        raise outcome["error"]
    return outcome["ctx"]


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
    ctx = prepare_interruptibly(scene, settings, progress)
    cam = ctx.camera
    film = Film(cam.width, cam.height)
    threads = settings.threads or os.cpu_count() or 1
    spp_pass = max(1, min(settings.samples_per_pass, settings.samples))
    n_passes = -(-settings.samples // spp_pass)
    batches = _batches(cam.width * cam.height, spp_pass, settings, threads)
    stats = {"samples": 0, "samples_total": settings.samples, "prepare_seconds": time.perf_counter() - t_start}
    t_trace = time.perf_counter()
    image = None  # the last pass's image: the film does not change after it
    with _AbandonablePool(threads, film) as pool:
        for pass_index in range(n_passes):
            spp = min(spp_pass, settings.samples - pass_index * spp_pass)
            jobs = [pool.submit(_run_batch, ctx, pool.film, lo, hi, spp, settings.seed, pass_index)
                    for lo, hi in batches]
            cancelled = _wait(jobs, progress)
            stats.update(_stats(ctx, film, stats, spp, t_trace, settings))
            if cancelled:
                pool.abandon()  # batches still running finish unseen
                # Part of a pass was traced: pixels carry unequal counts, each
                # mean is still unbiased.  Report the fewest samples any pixel has.
                stats["samples"] = int(film.count.min())
            if progress is not None and hasattr(progress, "on_pass"):
                image = film.image(settings.transparent)
                progress.on_pass(image, stats["samples"], dict(stats))
            if cancelled or _should_stop(progress, stats, settings):
                break
    if image is None:
        image = film.image(settings.transparent)
    return RenderResult(film, image, stats["samples"], stats, warnings_for(ctx))


def _wait(jobs, progress, poll=0.1):
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
    """Drop the batches not started; the running ones are abandoned (see
    _AbandonablePool): waiting for them cost up to a batch's time (seconds
    on a busy machine) between Esc and the render stopping."""
    for job in jobs:
        job.cancel()


class _GatedFilm:
    """The film as the batches see it: merges stop once ``close`` returns,
    so a batch abandoned at a cancel never changes the image being returned."""

    def __init__(self, film):
        self._film = film
        self._lock = threading.Lock()
        self._open = True

    def __getattr__(self, name):
        return getattr(self._film, name)

    def new_tile(self, lo, hi):
        make = getattr(self._film, "new_tile", None)
        return _GatedTile(make(lo, hi) if make else Tile(lo, hi), self)

    def merge(self, tile):
        with self._lock:
            if self._open:
                self._film.merge(getattr(tile, "tile", tile))

    def close(self):
        with self._lock:
            self._open = False


class _Abandoned(Exception):
    """Raised inside an abandoned batch to end it at its next film write."""


class _GatedTile:
    """A batch's tile that ends the batch (raises _Abandoned) at its next
    write once the gate is closed: an abandoned batch stops within a
    bounce instead of competing for the cores with what follows a cancel."""

    def __init__(self, tile, gate):
        self.tile = tile
        self._gate = gate

    def __getattr__(self, name):
        value = getattr(self.tile, name)
        if not callable(value):
            return value

        def checked(*args, **kwargs):
            if not self._gate._open:
                raise _Abandoned()
            return value(*args, **kwargs)
        return checked


class _AbandonablePool(ThreadPoolExecutor):
    """A thread pool that, once ``abandon``ed, is left without waiting for
    its running batches (their threads end on their own, results dropped)."""

    def __init__(self, threads, film):
        super().__init__(max_workers=threads, thread_name_prefix="ember-batch")
        self.film = _GatedFilm(film)
        self.abandoned = False

    def abandon(self):
        self.abandoned = True
        self.film.close()

    def __exit__(self, *exc):
        self.shutdown(wait=not self.abandoned, cancel_futures=True)
        return False


def _stop_requested(progress):
    return progress is not None and hasattr(progress, "should_stop") and bool(progress.should_stop())


def _run_batch(ctx, film, lo, hi, spp, seed, pass_index):
    rng = np.random.default_rng([seed, pass_index, lo])
    tile = film.new_tile(lo, hi)
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
