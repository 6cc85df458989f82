"""The shutter (engine/shutter.py): Cycles' shutter-curve table, the time
sampler against the curve's density (chi-square), the rolling shutter, the
focal-length animation of the camera, and hostile curves and durations."""
import numpy as np
import pytest

from engine import sampler as smp
from engine import shutter
from engine.camera import CameraModel, PixelFilter
from engine.scene import Camera

import ember_stats
from chi2 import chi2_sf, density_error_detected

X = np.linspace(0.0, 1.0, shutter.TABLE_SIZE)
CURVES = {
    'ramp': X.copy(),                                   # opening: density grows with time
    'bump': np.exp(-0.5 * ((X - 0.3) / 0.12) ** 2),     # a short bright pulse early in the shutter
}


def _sampler_times(curve, n=40000, rolling="NONE", duration=0.1, resolution=(64, 48)):
    cam = Camera(resolution=resolution, shutter_curve=curve, rolling_shutter=rolling, rolling_duration=duration)
    model = CameraModel(cam, PixelFilter('BOX', 1.0))
    pix = np.arange(n) % (resolution[0] * resolution[1])
    s = smp.Sampler(3)
    u = s.get(s.pixel_seeds(pix), (np.arange(n) // len(np.unique(pix))).astype(np.uint32), smp.TIME)[:, 0]
    return model.shutter_times(pix, u), pix, model


def test_flat_curve_table_is_cycles():
    """The default flat curve: Cycles' table is (i + 0.5) 255 / 256^2, so
    times run over [0.002, 0.994], not [0, 1]."""
    table = shutter.shutter_table(np.ones(shutter.TABLE_SIZE))
    expect = (np.arange(256) + 0.5) * 255.0 / 256.0 ** 2
    assert np.allclose(table, expect, atol=1e-12)
    t = shutter.table_read(table, np.array([0.0, 0.5, 1.0]))
    assert np.allclose(t, [0.5 * 255 / 256 ** 2, (127.5 + 0.5) * 255 / 256 ** 2, 255.5 * 255 / 256 ** 2])


@pytest.mark.parametrize("name", sorted(CURVES))
def test_table_follows_the_curve(name):
    """The tabulated law's CDF is the curve's own (trapezoid integral)
    within the table's resolution."""
    curve = CURVES[name]
    table = shutter.shutter_table(curve)
    assert np.all(np.diff(table) >= 0)
    t = np.linspace(0.0, 1.0, 1001)
    dens = np.interp(t, X, curve)
    own = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]))])
    own /= own[-1]
    assert np.abs(shutter.table_cdf(table, t) - own).max() < 0.01


def test_time_sampler_follows_the_shutter_curve():
    """Chi-square of 40,000 camera-sample times (the sampler's TIME set
    through CameraModel.shutter_times) over 32 bins against the law of
    Cycles' table, for each curve; the same test rejects the flat law, so it
    sees the curve."""
    bins = np.linspace(0.0, 1.0, 33)
    checks, flat, dofs = [], [], []
    for curve in CURVES.values():
        times, _, _ = _sampler_times(curve)
        counts = np.histogram(times, bins)[0]
        expected = len(times) * np.diff(shutter.table_cdf(shutter.shutter_table(curve), bins))
        keep = expected > 5
        checks.append(chi2_sf(((counts - expected)[keep] ** 2 / expected[keep]).sum(), keep.sum() - 1))
        dofs.append((keep.sum() - 1, len(times)))
        uniform = len(times) * np.diff(bins)
        flat.append(chi2_sf(((counts - uniform) ** 2 / uniform).sum(), len(bins) - 2))
    level = ember_stats.family_level(__name__, len(checks))
    print(f"shutter curve chi-square p {['%.3g' % p for p in checks]} (level {level:.2g}); "
          f"against a flat shutter p {['%.3g' % p for p in flat]}; each detects a density error of "
          f"{max(density_error_detected(level, dof, n) for dof, n in dofs):.2%} (rms over the bins) or less")
    assert min(checks) > level, checks
    assert max(flat) < level, flat


def test_rolling_shutter_rows():
    """Top-Bottom: Cycles' time 1 - y / height (y from the bottom) mixed
    with the curve's time by the duration; duration 0 is the row alone,
    1 the curve alone."""
    curve = CURVES['ramp']
    plain, pix, model = _sampler_times(curve, 6144)
    for duration in (0.0, 0.3, 1.0):
        times, _, model = _sampler_times(curve, 6144, 'TOP', duration)
        row = 47 - pix // 64
        rolled = 1.0 - row / 48.0
        expect = (plain - 0.5) * duration + (rolled - 0.5) * (1.0 - duration) + 0.5
        assert np.allclose(times, rolled if duration == 0.0 else expect, atol=1e-12)
        assert times[pix // 64 == 0].mean() < times[pix // 64 == 47].mean() or duration == 1.0
    assert np.allclose(_sampler_times(curve, 6144, 'TOP', 1.0)[0], plain)


@pytest.mark.parametrize("curve", [np.zeros(256), np.full(256, np.nan), np.full(256, np.inf), np.array([]),
                                   np.r_[np.zeros(128), np.full(128, -2.0)]])
@pytest.mark.parametrize("duration", [0.0, 1.0, np.nan, -3.0, 7.0])
def test_hostile_curves_and_durations_give_times_in_the_shutter(curve, duration):
    times, _, _ = _sampler_times(curve, 2000, 'TOP', duration)
    assert np.isfinite(times).all() and times.min() >= 0.0 and times.max() <= 1.0


def test_zero_curve_is_cycles_end_of_shutter():
    """A flat-zero curve: Cycles' CDF is 0 up to its last entry, so every
    time lands in the last 1/128 of the shutter (not a crash, not NaN)."""
    times, _, _ = _sampler_times(np.zeros(256), 2000)
    assert times.min() > 254.0 / 256.0 - 1e-9


def _rays(lens, lens_motion=None, time=None, dof=0.0):
    cam = Camera(resolution=(32, 24), lens=lens, lens_motion=lens_motion, fstop=dof, focus_distance=3.0)
    model = CameraModel(cam, PixelFilter('BOX', 1.0))
    pix = np.arange(32 * 24)
    half = np.full(len(pix), 0.5)
    t = None if time is None else np.full(len(pix), time)
    return model.generate(pix, half - 0.5, half - 0.5, half, half * 0.3, time=t)


def test_focal_length_animation():
    """Lens 35 at the shutter's start, 50 at its centre, 80 at its end:
    at times 0 and 1 the rays are those of the end lenses; in between the
    near-plane point moves linearly (Cycles' perspective motion)."""
    for time, lens in ((0.0, 35.0), (1.0, 80.0), (0.5, 50.0)):
        o, d, _ = _rays(50.0, (35.0, 80.0), time)
        o2, d2, _ = _rays(lens)
        assert np.allclose(d, d2, atol=1e-12) and np.allclose(o, o2, atol=1e-12)
    _, d, _ = _rays(50.0, (35.0, 80.0), 0.25)
    _, d0, _ = _rays(50.0)
    slope = d[:, :2] / -d[:, 2:]
    assert np.allclose(slope, d0[:, :2] / -d0[:, 2:] * (0.5 * 50 / 35 + 0.5), atol=1e-12)
    for bad in ((np.nan, 80.0), (0.0, 50.0), (-1.0, 1e30)):
        o, d, _ = _rays(50.0, bad, 0.1)
        assert np.isfinite(o).all() and np.isfinite(d).all()
