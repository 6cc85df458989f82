"""The engine's front door: ``render(scene, settings, progress)``.

Progressive: passes of ``samples_per_pass`` samples accumulate in a Film;
after each pass ``progress.on_pass(image, samples_done, stats)`` receives the
current image and ``progress.should_stop()`` may end the render (the partial
image is kept).  Within a pass, pixels are cut into batches of at most
``max_paths / threads`` paths and the batches run on a thread pool: NumPy and
embreex both release the GIL, so the cores stay busy and memory stays bounded
whatever the resolution.  Passes overlap (a thread that ends one early starts
the next) and tiles merge in planned order, so images do not depend on timing.
"""
import collections
import dataclasses
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
import numpy as np

from . import accel as accel_module
from . import allocator
from .accel import Accel
from .motion import MotionAccel, MotionGeometry, has_motion
from . import vector_pass
from .blas import single_threaded_blas
from .bsdf import MaterialTable, bump_model
from .camera import CameraModel, PixelFilter
from .displacement import displaced_scene
from . import instance_columns, kernels, media, pass_events, points
from .film import Film
from .geometry import flatten, material_table
from .integrator.catcher import catcher_triangles
from .integrator.linking import LightLinks
from .integrator import Context, path_guide, subsurface, trace_batch
from .lights import LightSet
from .sampler import CAMERA, Sampler
from .scene import Cancelled, RenderSettings, SceneError
from .validate import validate_scene, validate_settings


class RenderResult:
    """The finished (or stopped) render: the RGBA image, the film behind it
    (per-pixel counts, means and M2; ``film.state()`` is a farm shard) and
    first-hit AOVs and variance computed from the film on demand."""

    def __init__(self, film, image, samples, stats=None, warnings=None, passes=None, pass_metadata=None):
        self.film = film
        self.image = image          # (H, W, 4) float32, row 0 at the top
        self.samples = samples
        self.stats = stats or {}
        self.warnings = warnings or []
        # Requested extra passes {name: (H, W, C) float32} and their metadata
        # (Cryptomatte manifests): engine/passes.py.
        self.passes = passes or {}
        self.pass_metadata = pass_metadata or {}

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

    @property
    def sum_variance(self):
        """(H, W) variance of each pixel's mean of R + G + B (the channels'
        covariances included), or None unless RenderSettings.sum_variance."""
        return self.film.sum_variance()

    @property
    def variance_with_sum(self):
        """(H, W, 4): ``variance`` and, last, ``sum_variance`` (the form
        tests/ember_stats.py reads: one more channel than the image's RGB)."""
        total = self.film.sum_variance()
        if total is None:
            raise ValueError("the render kept no sum variance: RenderSettings(sum_variance=True)")
        return np.concatenate([self.film.variance(), total[..., None]], axis=2)

    @property
    def sample_count(self):
        """(H, W) samples each pixel received (fewer where adaptive sampling stopped)."""
        return self.film.sample_count()


def prepare(scene, settings, bake=None):
    """Validate and compile a Scene into the read-only Context batches share.
    ``bake``: an integrator.bake_paths.BakeTarget, the camera of a light
    bake (its texels are the film's pixels), or None."""
    with instance_columns.prepared():   # each instance list read once by every stage
        return _prepare(scene, settings, bake)


def _prepare(scene, settings, bake):
    allocator.tune()   # once per process: the batches' arrays reuse freed heap pages
    kernels.configure(getattr(settings, "use_jit", True))   # flatten has a kernel too
    validate_scene(scene)
    validate_settings(settings)
    scene = displaced_scene(scene)   # true displacement moves vertices before anything is placed
    source = scene
    scene, point_owners, point_radii = points.expand(scene)   # point clouds and curves as stand-in rows
    scene, curve_owners = points.expand_curves(scene)
    tris = flatten(scene, with_instance=bool(settings.passes), threads=settings.threads)
    spheres = points.spheres_of(tris, scene, point_owners, point_radii, list(getattr(source, "points", ()) or ()))
    shape = getattr(scene, "curve_shape", "THICK")
    strands = points.strands_of(tris, curve_owners, ribbons=shape == "RIBBONS", linear=shape == "THICK_LINEAR",
                                rate=points.curve_rate(getattr(scene, "curve_subdivisions", 2)))
    motion = MotionGeometry(scene, tris) if has_motion(source) else None
    unlit = points.unlit_rows(len(tris), spheres, strands)
    materials = MaterialTable(material_table(scene))
    lights = LightSet(scene, points.for_lights(tris, unlit, len(scene.materials)), materials,
                      settings.light_selection,
                      env_compensation=settings.mis_compensation and settings.strategy == "mis",
                      motion=motion if motion is not None and motion.moving else None)
    # 'auto' stays only where it samples every light at glossy vertices;
    # else it is the light tree.
    chosen = ("auto" if lights.every_at_glossy else "ris" if lights.resampled
              else "tree_bsdf" if lights.lobe_term else lights.strategy)
    settings = dataclasses.replace(settings, light_selection=chosen)
    try:
        camera = CameraModel(scene.camera, PixelFilter(settings.filter_type, settings.filter_width))
    except ValueError as exc:
        raise SceneError(f"camera: {exc}") from None
    if bake is not None:
        camera = bake.bind(tris)
    # Only moving triangles and points need Embree's C API (a moving camera alone does not).
    moving = motion is not None and motion.moving
    special = moving or spheres is not None or strands is not None
    accel = (MotionAccel(tris, motion if moving else None, spheres, strands) if special
             else Accel(tris, reuse=persistent_bvh(settings)))
    world = np.asarray(scene.world.color, dtype=np.float64)
    primitives = (spheres, point_owners, list(getattr(source, "points", ()) or ()), strands, curve_owners)
    ctx = Context.build(accel, tris, materials, lights, camera, world, settings,
                        sampler=Sampler(settings.seed, settings.sampling_pattern),
                        bump_model=bump_model(getattr(scene, "cycles_version", (5, 0, 0))),
                        pass_config=_with_vector(pass_events.configure(scene, settings), source, scene, tris,
                                                 settings, primitives),
                        media=_media(scene, accel, tris, camera, bake is None), holdout=holdout_weights(scene, tris),
                        links=LightLinks.build(scene, lights, tris), catcher=catcher_triangles(scene, tris),
                        motion=motion, spheres=spheres, unlit=unlit, strands=strands)
    if bake is not None:
        ctx = dataclasses.replace(ctx, bake=bake)
    if ctx.subsurface:
        ctx = dataclasses.replace(ctx, subsurface_warnings=tuple(subsurface.open_mesh_warnings(scene)))
    return ctx


def persistent_bvh(settings):
    """The BVH cache a render may reuse (Persistent Data on), else None; a
    render without Persistent Data frees what an earlier one kept."""
    if getattr(settings, "persistent", False):
        return accel_module.PERSISTENT
    accel_module.PERSISTENT.clear()
    return None


def _with_vector(cfg, source, scene, tris, settings, primitives):
    """The pass config with the Vector pass's motion when that pass is written
    (``primitives``: the points' and curves' rows, for VectorMotion)."""
    if not vector_pass.wanted(source, settings.passes):
        return cfg
    return dataclasses.replace(cfg, vector=vector_pass.VectorMotion(scene, tris, primitives))


def holdout_weights(scene, tris):
    """(T,) holdout weight of every triangle for camera rays, or None when
    nothing in the scene is a holdout: 1 on holdout objects, else the
    material's Holdout shader weight."""
    mats = material_table(scene)
    per_material = np.array([float(getattr(m, "holdout", 0.0)) for m in mats])
    per_instance = np.append(instance_columns.columns(scene.instances).holdout, False)
    if not (per_material.any() or per_instance.any()) or len(tris.material) == 0:
        return None
    weights = per_material[np.asarray(tris.material, np.int64)]
    owner = getattr(tris.shading, "instance", None)
    if owner is not None and per_instance.any():
        weights = np.where(per_instance[np.asarray(owner, np.int64)], 1.0, weights)
    return weights if weights.any() else None


def _media(scene, accel, tris, camera, from_camera=True):
    """The scene's media (None without a volume), with the media the camera
    starts in (none for a bake's texels: ``from_camera`` False) and a
    warning per object whose volume mesh is open."""
    table = media.MediumTable.of(material_table(scene), getattr(scene.world, "volume", None))
    if table is None:
        return None
    table.attach(material_table(scene), scene, tris)
    if from_camera and scene.camera.kind in ("PERSP", "PANO"):   # rays from one point
        media.camera_media(table, accel, tris, np.asarray(scene.camera.matrix, np.float64)[:3, 3], camera.forward)
    table.warnings = [f"object {name!r}: its volume mesh is not closed; paths may never leave the volume"
                      for name in media.open_volume_meshes(scene)]
    return table


def _choose_kernels(settings, progress):
    """Compiled or NumPy kernels for the whole render (engine/kernels.py):
    a render waits for the compile rather than start on NumPy and switch
    half-way, so a seed's image depends on the choice only, not on timing."""
    try:
        return kernels.for_render(getattr(settings, "use_jit", True), progress)
    except kernels.CompileCancelled as exc:
        raise Cancelled(str(exc)) from None


def prepare_interruptibly(scene, settings, progress, poll=0.05, bake=None):
    """``prepare`` (flattening, light set, BVH build: seconds on millions of
    triangles, none of it interruptible) in a daemon thread, asking
    ``progress.should_stop`` every ``poll`` seconds.  On a stop the thread is
    abandoned (it finishes in the background, its result is dropped) and
    ``Cancelled`` is raised at once."""
    def prepared():
        return prepare(scene, settings) if bake is None else prepare(scene, settings, bake)
    if not hasattr(progress, "should_stop"):
        return prepared()
    outcome = {}

    def work():
        try:
            outcome["ctx"] = prepared()
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


def _emitting_media(ctx):
    return ctx.media is not None and (bool(np.any(ctx.media.emission > 0)) or
                                      any(f.emits for f in ctx.media.fields))


def warnings_for(ctx):
    out = []
    if ctx.triangles.dropped:
        out.append(f"{ctx.triangles.dropped} degenerate triangles were skipped")
    if len(ctx.triangles) == 0 and ctx.lights.count == 0:
        out.append("the scene has no geometry and no lights")
    elif ctx.lights.count == 0 and not np.any(ctx.world > 0) and not _emitting_media(ctx):
        out.append("the scene has no lights and a black world: the image will be black")
    if ctx.media is not None:
        out.extend(ctx.media.warnings)
        out.extend(ctx.media.field_warnings())
    out.extend(ctx.subsurface_warnings)
    vector = getattr(ctx.pass_config, "vector", None)
    if vector is not None:
        out.extend(vector.warnings)
    if ctx.transparent_shadows and ctx.links is not None and ctx.links.any_blockers:
        out.append("shadow linking is not applied to shadow rays through transparent surfaces: "
                   "every object casts the shadows of shadow-linked lights in this scene")
    if ctx.transparent_shadows and ctx.catcher is not None:
        out.append("shadow catchers with transparent surfaces in the scene: the catchers' own light "
                   "is shadowed by every object, so shadows fade from the catcher's alpha")
    return out


# A batch's fixed cost (~200 NumPy calls per bounce) is small next to its
# paths' work from about this many paths on (tools/bench_engine.py: 4K-path
# batches cost 1.9x the CPU per path of 64K ones, 16K 1.2x).
MIN_BATCH_PATHS = 1 << 15
# A batch's fixed cost in paths' worth of work: 6-13 ms of interpreter work
# a batch against ~3 us a path (tools/bench_small.py, Cornell and Principled
# through the add-on, 2026-12-07).  The cuts before a barrier weigh it.
FIXED_PATHS = 1 << 12
# Automatic passes (samples_per_pass = 0): one sample first (a first image
# soon), then doubling, up to about this many paths per pass (1-3 s on two
# cores): few progress updates, yet a live progressive image.  The schedule
# depends on the frame only, never on timing, so a seed's image is the same
# bit for bit on any machine.
PASS_PATHS = 1 << 20


def _batches(pixels, spp, settings, threads, barrier=False):
    """Pixel lists for one pass: at most max_paths / threads paths each
    (memory), cut evenly.  Passes overlap (a thread that ends one batch
    takes the next, of this pass or the next), so only a pass before a
    barrier (an adaptive check, a guide rebuild, the end) needs cutting for
    balance: there two batches per thread where that leaves at least
    MIN_BATCH_PATHS paths each, one per thread where each keeps FIXED_PATHS
    (a smaller pass runs whole: a second batch's fixed cost, serialised by
    the GIL, would outweigh the half it saves), and the last ``threads``
    batches cut into pieces (_tail_pieces), so the threads run out of work
    at nearly the same time.  Other passes keep batches as large as memory
    allows: a batch's fixed cost is most of a small pass's time.
    ``pixels`` is a sorted index array (all pixels, or the unconverged ones).
    How pixels are grouped never changes the image: each pixel's samples of
    a pass are binned in one batch and merged in pass order."""
    n, paths = len(pixels), len(pixels) * spp
    largest = max(1, max(1024, settings.max_paths // threads) // spp)   # pixels a batch may hold
    count = -(-n // largest)
    if barrier:
        count = max(count, min(2 * threads, paths // MIN_BATCH_PATHS), min(threads, paths // FIXED_PATHS))
    size = max(1, -(-n // max(1, min(count, n))))   # even batches: no sliver at the end
    starts = list(range(0, n, size))
    if barrier and len(starts) > threads:
        tail = starts[-threads]
        starts = starts[:-threads] + list(range(tail, n, _tail_pieces(n - tail, size, spp)))
    return [pixels[lo:hi] for lo, hi in zip(starts, starts[1:] + [n])]


def _tail_pieces(n, size, spp):
    """Pixels per piece of the last batches before a barrier (``n`` pixels
    in batches of ``size``).  Cutting a batch of B paths into k pieces costs
    (k - 1) fixed costs and leaves a thread idle for about half a piece at
    the barrier, B / (2k) paths: the sum is least at k = sqrt(B / (2
    FIXED_PATHS)) (4 pieces of a 128k-path batch, 2 of a 32k one, 1 below
    18k)."""
    pieces = max(1, round((size * spp / (2 * FIXED_PATHS)) ** 0.5))
    return -(-n // -(-n // max(1, size // pieces)))   # even pieces


def _pass_samples(settings, done, pixels, adaptive_params):
    """Samples in the next pass: ``samples_per_pass``, or with 0 the
    automatic schedule 1, 1, 2, 4, ... up to PASS_PATHS paths over the
    ``pixels`` still sampling.  Never past the total, nor past adaptive
    sampling's next convergence check."""
    if settings.samples_per_pass > 0:
        spp = settings.samples_per_pass
    else:
        spp = min(max(done, 1), max(PASS_PATHS // max(pixels, 1), 1))
    spp = min(spp, settings.samples - done)
    if adaptive_params is not None and settings.samples_per_pass <= 0:
        _, min_samples, step = adaptive_params
        check = min_samples if done < min_samples else (done // step + 1) * step
        spp = min(spp, max(check - done, 1))
    return max(spp, 1)


def adaptive_parameters(settings):
    """(threshold as the convergence test uses it, min samples, step), as
    Cycles derives them from Noise Threshold and Min Samples; None when
    adaptive sampling is off."""
    threshold = settings.adaptive_threshold
    if threshold <= 0:
        return None
    if settings.adaptive_min_samples == 0:
        min_samples = max(4, int(np.ceil(16.0 / threshold ** 0.3)))
    else:
        min_samples = max(4, settings.adaptive_min_samples)
    return threshold * 5.0, min_samples, 16


class _Adaptive:
    """Which pixels still sample: all until min samples, then re-checked
    every ``step`` samples; converged pixels stop for good."""

    def __init__(self, settings, npix):
        self.params = adaptive_parameters(settings)
        self.active = np.arange(npix)
        # Only a check before the last sample can stop a pixel: a render of
        # at most min samples keeps the adaptive pass schedule but needs no
        # check, nor the film's class-A sums (12 bytes a pixel).
        self.stops = self.params is not None and settings.samples > self.params[1]

    def checks_at(self, done, last_checked):
        """Whether a convergence check runs once ``done`` samples are in."""
        if not self.stops:
            return False
        _, min_samples, step = self.params
        return done >= min_samples and done // step != last_checked // step

    def update(self, film, done, last_checked):
        if not self.checks_at(done, last_checked):
            return last_checked
        threshold = self.params[0]
        noisy = film.unconverged(threshold)
        self.active = self.active[noisy[self.active]]
        return done


def render(scene, settings=None, progress=None, bake=None):
    """Render ``scene``; given a ``bake`` (integrator.bake_paths.BakeTarget)
    the film's pixels are its texels instead of the camera's (engine/bake.py)."""
    with single_threaded_blas():
        return _render(scene, settings or RenderSettings(), progress, bake)


def _guides(ctx, settings):
    """Whether camera rays in media are guided (Cycles 5.0 always guides
    them where the scene has a volume; not for a bake)."""
    return ctx.media is not None and ctx.bake is None and settings.volume_guiding


def _path_guide(ctx, settings):
    """The film's path guide (integrator/path_guide.py) when guiding is on
    (not for a bake, nor with subsurface scattering), else None."""
    if not settings.path_guiding or ctx.bake is not None or ctx.subsurface:
        return None
    lo, inv_size = path_guide.bounds_of(ctx.triangles)
    return path_guide.PathGuide(lo, inv_size, settings.path_guiding_training_samples)


def _render(scene, settings, progress, bake=None):
    t_start = time.perf_counter()
    kernel_mode = _choose_kernels(settings, progress)
    compile_wait = time.perf_counter() - t_start
    ctx = prepare_interruptibly(scene, settings, progress, bake=bake)
    cam = ctx.camera
    adaptive = _Adaptive(settings, cam.width * cam.height)
    film = Film(cam.width, cam.height, settings.aovs, adaptive.stops, settings.passes,
                ctx.pass_config.crypto_levels, guide=_guides(ctx, settings), sum_variance=settings.sum_variance,
                path_guide=_path_guide(ctx, settings))
    threads = settings.threads or os.cpu_count() or 1
    stats = {"samples": 0, "samples_total": settings.samples, "kernels": kernel_mode,
             "compile_wait_seconds": compile_wait, "prepare_seconds": time.perf_counter() - t_start - compile_wait,
             "bvh_reused": bool(getattr(ctx.accel, "reused", False))}
    t_trace = time.perf_counter()
    image = None  # the last pass's image: the film does not change after it
    with _AbandonablePool(threads, film) as pool:
        plan = _Plan(settings, adaptive, threads, film)
        queue = collections.deque()  # (pass, batch job), in planned order
        stop_poll = _StopPoll(progress)
        while True:
            _submit(queue, plan, pool, ctx, QUEUE_PER_THREAD * threads)
            if not queue:
                break
            done_pass, job = queue.popleft()
            cancelled = stop_poll.wait(job)
            if not cancelled:
                film.merge(job.result().tile)
                done_pass.left -= 1
            if done_pass.left and not cancelled:
                continue
            plan.done += 0 if cancelled else done_pass.spp
            stats.update(_stats(ctx, stats, plan.done, 0 if cancelled else done_pass.paths, t_trace, settings))
            if not cancelled:
                plan.checked = adaptive.update(film, plan.done, plan.checked)
            stats["active_pixels"] = len(adaptive.active)
            if cancelled:
                _cancel([job] + [j for _, j in queue])
                pool.abandon()  # batches still running finish unseen
                # Part of a pass was traced: pixels carry unequal counts, each
                # mean is still unbiased.  Report the fewest samples any pixel has.
                stats["samples"] = int(film.count.min())
            if progress is not None and hasattr(progress, "on_pass"):
                image = film.image(settings.transparent, "Shadow Catcher" not in settings.passes)
                progress.on_pass(image, stats["samples"], dict(stats))
            if cancelled or _should_stop(progress, stats, settings):
                if queue:
                    _cancel([j for _, j in queue])
                    pool.abandon()  # the next pass, already started, is dropped
                break
    if image is None:
        image = film.image(settings.transparent, "Shadow Catcher" not in settings.passes)
    return RenderResult(film, image, stats["samples"], stats, warnings_for(ctx),
                        film.pass_images(ctx.pass_config), pass_events.metadata(ctx.pass_config, settings.passes))


# Batches submitted ahead of the one merged next, per thread: a thread that
# ends a pass early starts the next pass's batches instead of idling at a
# barrier (passes are planned ahead; only a convergence check waits for the
# film), while the finished tiles waiting to merge in order stay few.
QUEUE_PER_THREAD = 4


class _Pass:
    def __init__(self, spp, first, pixels, batches):
        self.spp, self.first = spp, first
        self.paths = spp * pixels
        self.left = batches  # batches not merged yet


class _Plan:
    """The passes ahead, batch by batch.  ``done``: samples merged into the
    film; ``planned``: samples submitted.  Planning runs ahead of the film
    except past an adaptive convergence check, whose outcome (the pixels
    still sampling) needs the film up to it."""

    def __init__(self, settings, adaptive, threads, film=None):
        self.settings, self.adaptive, self.threads = settings, adaptive, threads
        self.film = film
        # Guides rebuilt from the samples so far at pass barriers: the volume
        # guide (integrator/volume_guide.py) and the path guide while it
        # trains (integrator/path_guide.py).
        self.guide = None if film is None else film.guide
        self.path_guide = None if film is None else film.path_guide
        self.guided = 0   # samples in the film when the guides were last rebuilt (0: never)
        self.rebuilt_at = 0
        self.done = self.planned = self.checked = 0
        self.batches = collections.deque()  # (pass, pixels) not submitted yet

    def _guiding(self):
        """Whether a guide still learns: the volume guide always, the path
        guide until the records of its training samples are in."""
        learning = self.path_guide is not None and self.guided < self.path_guide.training
        return self.guide is not None or learning

    def next_batch(self):
        if not self.batches and not self._plan_pass():
            return None
        return self.batches.popleft()

    def _plan_pass(self):
        settings, adaptive = self.settings, self.adaptive
        if self.planned >= settings.samples or not len(adaptive.active):
            return False
        if self.planned > self.done and adaptive.checks_at(self.planned, self.checked):
            return False  # wait for the film to reach the check
        if self._guiding() and self.planned >= 2 * self.guided:
            # Guides read the samples so far, rebuilt when they have
            # doubled (1, 2, 4, ... as the automatic passes): that pass waits
            # for the last to merge, so every batch reads the guide of the
            # same samples whatever the timing.
            if self.planned > self.done:
                return False
            if self.guide is not None:
                self.guide.update(self.film.count)
            if self.path_guide is not None:   # from the samples since the last rebuild
                self.path_guide.update(self.planned - self.rebuilt_at)
            self.guided = max(self.planned, 1)
            self.rebuilt_at = self.planned
        spp = _pass_samples(settings, self.planned, len(adaptive.active), adaptive.params)
        end = self.planned + spp
        rebuild = self._guiding() and end >= 2 * self.guided   # the next pass waits for this one
        barrier = end >= settings.samples or adaptive.checks_at(end, self.checked) or rebuild
        batches = _batches(adaptive.active, spp, settings, self.threads, barrier)
        run = _Pass(spp, settings.sample_start + self.planned, len(adaptive.active), len(batches))
        self.batches.extend((run, pixels) for pixels in batches)
        self.planned += spp
        return True


def _submit(queue, plan, pool, ctx, limit):
    while len(queue) < limit:
        batch = plan.next_batch()
        if batch is None:
            return
        run, pixels = batch
        queue.append((run, pool.submit(_run_batch, ctx, pool.film, pixels, run.spp, run.first)))


class _StopPoll:
    """Asks ``progress.should_stop`` about every ``poll`` seconds while the
    render loop waits for batches, however fast they finish, so a cancel
    lands within a fraction of a second, not a pass."""

    def __init__(self, progress, poll=0.1):
        self.progress, self.poll = progress, poll
        self.last = time.perf_counter()

    def wait(self, job):
        """Wait for one batch; True if a stop was requested meanwhile."""
        while True:
            try:
                job.result(timeout=self.poll)
                finished = True
            except FuturesTimeout:
                finished = False
            now = time.perf_counter()
            if now - self.last >= self.poll:
                self.last = now
                if _stop_requested(self.progress):
                    return True
            if finished:
                return False


def _cancel(jobs):
    """Drop the batches not started; the running ones are abandoned (see
    _AbandonablePool): waiting for them cost up to a batch's time (seconds
    on a busy machine) between Esc and the render stopping."""
    for job in jobs:
        job.cancel()


class _GatedFilm:
    """The film as the batches see it: once ``close`` returns, an abandoned
    batch ends at its next tile write (its tile is never merged: merges are
    the render loop's, in planned order)."""

    def __init__(self, film):
        self._film = film
        self._lock = threading.Lock()
        self._open = True

    def __getattr__(self, name):
        return getattr(self._film, name)

    def new_tile(self, lo, hi, first=0):
        return _GatedTile(self._film.new_tile(lo, hi, first), self)

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


def _run_batch(ctx, film, pixels, spp, first):
    """Samples [first, first + spp) of each pixel in ``pixels`` (sorted)."""
    tile = film.new_tile(int(pixels[0]), int(pixels[-1]) + 1, int(first) - ctx.settings.sample_start)
    pix = np.repeat(pixels, spp)
    sample = np.tile(np.arange(first, first + spp, dtype=np.uint32), len(pixels))
    pix, sample = _beyond_the_rim(ctx, tile, pix, sample)
    if len(pix):
        trace_batch(ctx, pix, sample, tile)
    tile.flush()  # binned here, on the batch's thread; merged in order by the caller
    return tile


def _beyond_the_rim(ctx, tile, pix, sample):
    """A fisheye's or mirror ball's camera samples beyond its rim are
    counted and nothing else (Cycles' zero camera throughput: black and
    opaque, transparent film or not); the others are returned to trace."""
    if ctx.bake is not None or getattr(ctx.camera, "pano", None) is None:
        return pix, sample
    pass_events.centre_passes(ctx, pix, tile)   # pixels whose every sample falls beyond the rim too
    u = ctx.sampler.get(ctx.sampler.pixel_seeds(pix), sample, CAMERA)
    out = ctx.camera.outside(pix, u[:, 0], u[:, 1])
    if out.any():
        n = int(out.sum())
        tile.add_camera(pix[out], np.ones(n), np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3)))
        pix, sample = pix[~out], sample[~out]
    return pix, sample


def _stats(ctx, stats, done, paths, t_trace, settings):
    elapsed = time.perf_counter() - t_trace
    totals = ctx.accel.totals()
    left = elapsed / done * (settings.samples - done) if done else 0.0
    paths_total = stats.get("paths", 0) + paths
    return {
        "samples": done,
        "seconds": elapsed,
        "paths": paths_total,
        "paths_per_second": paths_total / max(elapsed, 1e-9),
        "rays": totals["rays"],
        "rays_per_second": totals["rays"] / max(elapsed, 1e-9),
        "embree_seconds": totals["seconds"],
        "seconds_left": left,
    }


def _should_stop(progress, stats, settings):
    if settings.time_limit > 0 and stats["seconds"] >= settings.time_limit:
        return True
    return _stop_requested(progress)
