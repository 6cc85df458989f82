"""The render API: progress, cancel, time limit, bounded batches, film
options; plus analytic checks of the sun and spot lights."""
import importlib

import numpy as np

from engine.render import FIXED_PATHS, PASS_PATHS, _batches, _tail_pieces, _pass_samples, adaptive_parameters, render
from engine.scene import Instance, Lobe, Material, PointLight, RenderSettings, Scene, SpotLight, SunLight, World
from engine.testscenes import cornell_box, quad

from ember_stats import family_z
from analytic import analytic_scene, ortho_camera, pixel_centres


class Recorder:
    def __init__(self, stop_after=None):
        self.calls = []
        self.stop_after = stop_after

    def on_pass(self, image, samples, stats):
        assert image.dtype == np.float32 and image.shape[2] == 4
        assert np.isfinite(image).all()
        self.calls.append((samples, stats["rays_per_second"], stats["seconds_left"]))

    def should_stop(self):
        return self.stop_after is not None and len(self.calls) >= self.stop_after


def test_progress_after_every_pass():
    rec = Recorder()
    r = render(cornell_box(32, 32), RenderSettings(samples=10, samples_per_pass=4), rec)
    assert [c[0] for c in rec.calls] == [4, 8, 10]
    assert all(c[1] > 0 for c in rec.calls)
    assert rec.calls[-1][2] == 0.0
    assert r.samples == 10


def test_automatic_passes_one_sample_then_doubling():
    rec = Recorder()
    r = render(cornell_box(16, 16), RenderSettings(samples=40, samples_per_pass=0), rec)
    assert [c[0] for c in rec.calls] == [1, 2, 4, 8, 16, 32, 40] and r.samples == 40
    s = RenderSettings(samples=10 ** 6, samples_per_pass=0)
    # Up to PASS_PATHS paths a pass; never past the total.
    assert _pass_samples(s, 4096, 256 * 256, None) == PASS_PATHS // (256 * 256)
    assert _pass_samples(s, 10, 3840 * 2160, None) == 1
    assert _pass_samples(s, 10 ** 6 - 3, 16, None) == 3


def test_automatic_passes_stop_at_adaptive_checks():
    """With adaptive sampling, automatic passes end where the convergence
    check falls (min samples, then every step) so converged pixels stop
    when Cycles' would."""
    s = RenderSettings(samples=1000, samples_per_pass=0, adaptive_threshold=0.01)
    params = adaptive_parameters(s)
    _, min_samples, step = params
    done, ends = 0, []
    while done < 300:
        done += _pass_samples(s, done, 16, params)   # a tiny frame: passes as long as allowed
        ends.append(done)
    assert ends[0] == 1 and min_samples in ends and all(e <= min_samples for e in ends[:ends.index(min_samples)])
    after = ends[ends.index(min_samples):]
    assert all(e % step == 0 and e - a == step for a, e in zip(after, after[1:]))


def test_cancel_keeps_partial_image():
    rec = Recorder(stop_after=2)
    r = render(cornell_box(32, 32), RenderSettings(samples=100, samples_per_pass=2), rec)
    assert r.samples == 4 and len(rec.calls) == 2
    assert r.image[..., :3].mean() > 0.01


class Clock:
    """Progress that records the render's own clock after every pass."""

    def __init__(self):
        self.seconds = []

    def on_pass(self, image, samples, stats):
        self.seconds.append(stats["seconds"])

    def should_stop(self):
        return False


def test_time_limit_stops_early():
    """The render stops after the first pass that crosses the limit: every
    earlier pass ended before it.  (Checked on the render's own clock, so a
    busy machine slows the passes but cannot fail the test.)"""
    clock = Clock()
    r = render(cornell_box(32, 32), RenderSettings(samples=100000, samples_per_pass=1, time_limit=0.3), clock)
    assert 1 <= r.samples < 100000
    assert len(clock.seconds) == r.samples
    assert clock.seconds[-1] >= 0.3 and all(t < 0.3 for t in clock.seconds[:-1]), clock.seconds[-3:]


def test_batches_bound_paths_in_flight():
    s = RenderSettings(max_paths=1 << 16)
    for npix, spp in ((3840 * 2160, 1), (512 * 512, 16), (7, 3), (256 * 256, 1), (64 * 64, 2), (64 * 64, 1), (160 * 90, 16)):
        # Before a barrier (the end, an adaptive check, a guide rebuild): balanced.
        tail = _batches(np.arange(npix), spp, s, threads=2, barrier=True)
        # One batch per thread where each keeps FIXED_PATHS paths; a smaller pass runs whole.
        assert len(tail) >= min(2, npix * spp // FIXED_PATHS, npix)
        if npix * spp < 2 * FIXED_PATHS:
            assert len(tail) == 1
        np.testing.assert_array_equal(np.concatenate(tail), np.arange(npix))
        assert max(len(b) for b in tail) * spp <= max(s.max_paths // 2, spp)
        # Load balance: two batches per thread when each keeps MIN_BATCH_PATHS paths.
        if npix * spp >= 4 * 2 * (1 << 15):
            assert len(tail) >= 4
        # Elsewhere passes overlap: batches as large as memory allows (few
        # batches, each with its fixed cost), the same pixels in order.
        batches = _batches(np.arange(npix), spp, s, threads=2)
        np.testing.assert_array_equal(np.concatenate(batches), np.arange(npix))
        assert max(len(b) for b in batches) * spp <= max(s.max_paths // 2, spp)
        assert len(batches) == -(-npix // max(1, (s.max_paths // 2) // spp))
        sizes = [len(b) for b in batches]
        assert max(sizes) - min(sizes) <= len(batches)   # cut evenly: no sliver at the end
        # The last batches before a barrier are cut smaller.
        if len(tail) > 2 and npix * spp > s.max_paths:
            assert max(len(b) for b in tail[-2:]) * 2 <= max(len(b) for b in batches)



def test_tail_pieces_weigh_the_fixed_cost():
    """The last batches before a barrier are cut into sqrt(B / (2 FIXED_PATHS))
    pieces (B: a batch's paths): a piece's fixed cost against the idle time
    it saves."""
    assert FIXED_PATHS == 4096
    assert _tail_pieces(2 * 4096, 4096, 32) == 1024   # 128k-path batches: 4 pieces
    assert _tail_pieces(2 * 1024, 1024, 32) == 512    # 32k: 2
    assert _tail_pieces(2 * 512, 512, 32) == 512      # 16k: whole
    assert _tail_pieces(1000, 600, 32) == 250         # 2 pieces of 300: 4 even ones over 1000


def test_transparent_film_alpha():
    scene = cornell_box(24, 24)
    scene.camera.lens = 20.0  # wide enough to see past the box into the world
    scene.world = World((1.0, 1.0, 1.0))
    opaque = render(scene, RenderSettings(samples=4, samples_per_pass=4)).image
    clear = render(scene, RenderSettings(samples=4, samples_per_pass=4, transparent=True)).image
    corner = (slice(0, 2), slice(0, 2))  # outside the box opening: the world
    assert np.allclose(opaque[corner][..., :3], 1.0) and np.allclose(clear[corner][..., :3], 0.0)
    assert np.allclose(clear[corner][..., 3], 0.0) and np.allclose(clear[12, 12, 3], 1.0)
    assert np.all(opaque[..., 3] == 1.0)  # no transparent film: alpha is 1 (Cycles)


def test_clamp_limits_every_sample():
    r = render(cornell_box(24, 24), RenderSettings(samples=8, samples_per_pass=8, clamp=0.05))
    assert r.image[..., :3].max() <= 0.05 + 1e-6


def test_sun_irradiance():
    """A sun of irradiance E at elevation 60 deg: L_o = rho E cos(30 deg) / pi."""
    E = 3.0
    for angle in (0.0, np.radians(5.0)):
        d = np.array([0.0, np.sin(np.radians(30)), -np.cos(np.radians(30))])
        scene, rho = analytic_scene(SunLight(d, (E, E, E), angle))
        r = render(scene, RenderSettings(samples=64, samples_per_pass=64, seed=1))
        img = r.image[..., 0].astype(np.float64)
        expected = rho * E * np.cos(np.radians(30)) / np.pi
        if angle == 0:
            np.testing.assert_allclose(img, expected, rtol=1e-6)  # float32 film
        else:
            se = np.sqrt(r.variance[..., 0].astype(np.float64).sum()) / img.size
            limit = family_z(__name__, 1)
            print(f"sun angle {angle}: {img.mean():.6f} +- {se:.6f}, exact {expected:.6f}; detects "
                  f"{limit * se / expected:.3%} with probability 1/2")
            assert abs(img.mean() - expected) < limit * se + 1e-12


def test_spot_cone_and_blend():
    """Inside the cone a spot is a point light; outside it is dark; in the
    blend band Cycles' smoothstep applies."""
    P, h = 40.0, 1.0
    size, blend = np.radians(60), 0.5
    spot = SpotLight((0, 0, h), (P, P, P), radius=0.0, direction=(0, 0, -1), spot_size=size, spot_blend=blend)
    scene, rho = analytic_scene(spot)
    r = render(scene, RenderSettings(samples=4, samples_per_pass=4, filter_type="BOX", filter_width=1e-6))
    x, y = pixel_centres(40, 4.0)
    D2 = x * x + y * y + h * h
    cos = h / np.sqrt(D2)
    cos_half = np.cos(size / 2)
    t = np.clip((cos - cos_half) / ((1 - cos_half) * blend), 0, 1)
    expected = rho / np.pi * P / (4 * np.pi) * cos / D2 * t * t * (3 - 2 * t)
    np.testing.assert_allclose(r.image[..., 0], expected, rtol=2e-5, atol=1e-7)
    assert (expected == 0).any() and ((t > 0) & (t < 1)).any()


class FakeClock:
    """An injected clock for engine.render (its ``time`` module): each read
    advances ``step`` seconds, so the stop poll's timing is a count of
    reads, the same on a busy machine and on a fast one."""

    def __init__(self, step):
        self.now, self.step = 0.0, step

    def perf_counter(self):
        self.now += self.step
        return self.now


class StopOnAsk:
    """Answers should_stop False until its ``answer_at``-th question once
    tracing has begun (``traced`` set by the first batch; questions while
    the scene is prepared are answered False and not counted)."""

    def __init__(self, monkeypatch, render_module, answer_at=1):
        self.asked, self.answer_at, self.traced = 0, answer_at, False
        original = render_module._run_batch

        def run_batch(*args):
            self.traced = True
            return original(*args)
        monkeypatch.setattr(render_module, "_run_batch", run_batch)

    def should_stop(self):
        if not self.traced:
            return False
        self.asked += 1
        return self.asked >= self.answer_at


def test_cancel_within_a_pass(monkeypatch):
    """should_stop is polled while batches run: a long pass stops early.
    Clock injected (every read 0.2 s later than the last, past the 0.1 s
    poll): the first batch waited for asks, the stop lands inside the one
    pass of 64 samples, so fewer samples come back; no wall-clock bound."""
    render_module = importlib.import_module("engine.render")   # engine.render is the function
    monkeypatch.setattr(render_module, "time", FakeClock(0.2))
    stop = StopOnAsk(monkeypatch, render_module, 1)
    scene = cornell_box(64, 64)
    r = render(scene, RenderSettings(samples=64, samples_per_pass=64, max_paths=1 << 10, threads=2), stop)
    assert stop.asked == 1 and r.samples < 64 and np.isfinite(r.image).all()


def test_max_bounces_zero_is_direct_light():
    """Cycles: max_bounces 0 still has direct light; 1 adds one indirect
    bounce.  Truth: the inverse-square law.  A point light (power P, radius
    0) 1 m over a grey floor, under a grey ceiling 2 m up that would light
    the floor indirectly; an orthographic camera between light and floor
    sees the floor.  At max_bounces 0 each pixel is the direct term
    rho / pi * P / (4 pi) * cos / d^2 (deterministic: one light, no
    randomness in its sample); at 1 the ceiling's light adds to every pixel."""
    P, h, rho = 40.0, 1.0, 0.5
    half = 50.0
    floor = quad([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
    ceiling = quad([[-half, -half, 2], [-half, half, 2], [half, half, 2], [half, -half, 2]])   # faces down
    grey = Material("grey", (Lobe("diffuse", (rho, rho, rho)),))
    cam = ortho_camera((0, 0, 0.5), (0, 0, 0), (40, 40), 4.0)
    light = PointLight((0, 0, h), (P, P, P), radius=0.0)
    scene = Scene([floor, ceiling], [Instance(0, materials=[0]), Instance(1, materials=[0])], [grey], [light],
                  World((0.0, 0.0, 0.0)), cam)
    x, y = pixel_centres(40, 4.0)
    d2 = x * x + y * y + h * h
    expected = rho / np.pi * P / (4 * np.pi) * (h / np.sqrt(d2)) / d2
    settings = dict(samples=4, samples_per_pass=4, filter_type="BOX", filter_width=1e-6)
    direct = render(scene, RenderSettings(max_bounces=0, **settings)).image[..., 0]
    np.testing.assert_allclose(direct, expected, rtol=2e-5, atol=1e-7)
    one = render(scene, RenderSettings(max_bounces=1, **settings)).image[..., 0]
    assert (one > direct * (1 + 1e-3)).all(), "one bounce added no indirect light somewhere"


def test_passes_overlap_and_merge_in_order(monkeypatch):
    """A thread that ends a pass early starts the next pass (no barrier),
    yet tiles merge in planned order: with the first batch of every pass
    held back so later batches finish first, the image is the same bit for
    bit and progress still reports whole passes."""
    import threading
    import time
    render_module = importlib.import_module("engine.render")   # engine.render is the function

    settings = RenderSettings(samples=6, samples_per_pass=2, threads=2, max_paths=1024, seed=3, aovs=())
    scene = cornell_box(16, 16)
    plain = render(scene, settings)
    original = render_module._run_batch
    events, lock = [], threading.Lock()

    def slow_first_batch(ctx, film, pixels, spp, first):
        with lock:
            events.append(("start", first))
        if pixels[0] == 0:
            time.sleep(0.3)  # every pass's first batch ends last
        tile = original(ctx, film, pixels, spp, first)
        with lock:
            events.append(("end", first))
        return tile
    monkeypatch.setattr(render_module, "_run_batch", slow_first_batch)
    rec = Recorder()
    delayed = render(scene, settings, rec)
    np.testing.assert_array_equal(delayed.image, plain.image)
    np.testing.assert_array_equal(delayed.film.count, plain.film.count)
    assert [c[0] for c in rec.calls] == [2, 4, 6]
    pass_1_ended = max(i for i, event in enumerate(events) if event == ("end", 0))
    assert ("start", 2) in events[:pass_1_ended], "pass 2 began only after pass 1 ended"


def test_stop_is_asked_while_queued_batches_finish_quickly(monkeypatch):
    """Batches that end within the poll interval, queued ahead so the one
    waited for is often done already: should_stop is still asked every
    0.1 s of the render's clock, and a long pass is cut short.  Clock
    injected: every read 0.04 s later, so the questions come 0.12 s of that
    clock apart (0.16 where a pass-end read falls between), whether a batch
    was done or the wait timed out; the fifth question stops."""
    render_module = importlib.import_module("engine.render")   # engine.render is the function
    clock = FakeClock(0.04)
    monkeypatch.setattr(render_module, "time", clock)
    stop = StopOnAsk(monkeypatch, render_module, 5)
    asked_at = []
    ask = stop.should_stop

    def timed_ask():
        if stop.traced:
            asked_at.append(clock.now)
        return ask()
    stop.should_stop = timed_ask
    # One pass of 16 samples in 1024-path batches: about 260 batches.
    settings = RenderSettings(samples=16, samples_per_pass=16, max_paths=1024, threads=2, aovs=())
    r = render(cornell_box(128, 128), settings, stop)
    assert r.samples < 16 and stop.asked == 5, "the stop was not asked within the pass, or not obeyed"
    gaps = np.diff(asked_at)
    assert ((gaps > 0.1 - 1e-9) & (gaps < 0.2)).all(), f"questions {gaps} s apart on the render's clock"


def test_adaptive_checks_only_where_a_pixel_can_stop():
    """A render of at most Min Samples runs no convergence check, so its
    film keeps no class-A sums (12 bytes a pixel: 380 MiB at 7680x4320);
    one sample past them, the checks and sums are back."""
    from engine.render import _Adaptive
    s = RenderSettings(samples=1, adaptive_threshold=0.01, adaptive_min_samples=0)
    min_samples = adaptive_parameters(s)[1]
    for samples, stops in ((1, False), (min_samples, False), (min_samples + 1, True)):
        adaptive = _Adaptive(RenderSettings(samples=samples, adaptive_threshold=0.01), 16)
        assert adaptive.stops is stops, samples
        assert adaptive.checks_at(min_samples, 0) is stops
    assert not _Adaptive(RenderSettings(samples=1000, adaptive_threshold=0.0), 16).stops
