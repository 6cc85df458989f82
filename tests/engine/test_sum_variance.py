"""The film's variance of channel sums (RenderSettings.sum_variance,
engine/film.py): the measured variance of each pixel's R + G + B, which the
suite's region totals test (tests/ember_stats.py sum_variance).  The
channels of one path are correlated, so the sum of the channel variances is
too small; these tests show the film's estimate is the sample variance of
the sums and that z-scores built on it have unit variance."""
import dataclasses

import numpy as np

import ember_stats as stats
from engine.film import Film
from engine.render import render
from engine.scene import Lobe, Material, RenderSettings, Scene, World

from analytic import big_plane, ortho_camera

COLOUR = np.array([0.8, 0.5, 0.2])


def correlated_samples(rng, n):
    """(n, 3): a grey-ish path weight times a colour (perfectly correlated
    channels) plus small independent channel noise; mean COLOUR + 0.1."""
    return rng.exponential(1.0, n)[:, None] * COLOUR + rng.uniform(0.0, 0.2, (n, 3))


def film_of(samples, width, height, sum_variance=True):
    """A film fed ``samples`` (pixels, spp, 3) in two tiles per half of the
    samples (two Chan merges per pixel, over differing pixel ranges)."""
    film = Film(width, height, (), sum_variance=sum_variance)
    pixels, spp = samples.shape[:2]
    half = spp // 2
    for first, last, cut in ((0, half, pixels // 3), (half, spp, 2 * pixels // 3)):
        for lo, hi in ((0, cut), (cut, pixels)):
            tile = film.new_tile(lo, hi)
            pix = np.repeat(np.arange(lo, hi), last - first)
            tile.add_radiance(pix, samples[lo:hi, first:last].reshape(-1, 3))
            tile.add_camera(pix, np.ones(len(pix)), np.zeros(len(pix)), np.zeros((len(pix), 3)),
                            np.zeros((len(pix), 3)))
            film.merge(tile)
    return film


def test_film_sum_variance_is_the_sample_variance_of_the_sums():
    rng = np.random.default_rng(11)
    samples = correlated_samples(rng, 12 * 16).reshape(12, 16, 3)
    film = film_of(samples, 4, 3)
    sums = samples.sum(axis=2)
    expected = sums.var(axis=1, ddof=1) / sums.shape[1]
    np.testing.assert_allclose(film.sum_variance().ravel(), expected, rtol=2e-5)
    channels = film.variance().reshape(-1, 3).sum(axis=1)
    assert (expected > 2.0 * channels).all(), "the samples must be strongly correlated for this test to mean much"
    # The images and per-channel variances are those of a film without it, bit for bit.
    plain = film_of(samples, 4, 3, sum_variance=False)
    assert plain.sum_variance() is None
    assert np.array_equal(plain.image(), film.image()) and np.array_equal(plain.variance(), film.variance())
    # A farm shard carries it; a shard without it leaves the sum unknown, not wrong.
    merged = Film.from_state(film.state())
    merged.merge_state(film_of(correlated_samples(rng, 12 * 16).reshape(12, 16, 3), 4, 3).state())
    assert merged.sum_variance() is not None
    merged.merge_state(plain.state())
    assert merged.sum_variance() is None


def test_z_of_region_sums_has_unit_variance():
    """400 independent regions (rows of 64 pixels, 16 correlated samples
    each): the z of each row's total against the truth, with the film's
    variance of sums, has sum of squares chi-square(400); with the channel
    variances added as if independent it is about 3x too large (rejected)."""
    rows, width, spp = 400, 64, 16
    rng = np.random.default_rng(12)
    samples = correlated_samples(rng, rows * width * spp).reshape(rows * width, spp, 3)
    film = film_of(samples, width, rows)
    image = film.image()[..., :3].astype(np.float64)
    truth = width * (COLOUR + 0.1).sum()
    level = stats.family_level(__name__ + ".unit_variance", 2)
    measured = image.sum(axis=(1, 2)) - truth
    # mean z^2 has standard error sqrt(2 / rows) (normal approximation of chi-square(rows) / rows)
    print(f"the mean z^2 detects a variance off by a factor 1 +- "
          f"{stats.detectable(np.sqrt(2.0 / rows), level):.3f} with probability 1/2")
    for label, var, should_pass in (
            ("film sum variance", film.sum_variance().astype(np.float64).sum(axis=1), True),
            ("channel variances summed", film.variance().astype(np.float64).sum(axis=(1, 2)), False)):
        chi2 = float((measured ** 2 / var).sum())
        p = 2.0 * min(stats.chi2_sf(chi2, rows), 1.0 - stats.chi2_sf(chi2, rows))
        print(f"{label}: mean z^2 {chi2 / rows:.3f} (1 +- {np.sqrt(2.0 / rows):.3f}), two-sided p {p:.2g}, "
              f"level {level:.1e}")
        assert (p >= level) == should_pass, (label, chi2 / rows, p)


def test_render_sum_variance():
    """Through render(): the flag changes no image or variance bit; a grey
    scene's channels are equal, so var(R + G + B) = 9 var(R); a coloured
    one's sum variance is within Cauchy-Schwarz's bound."""
    mesh, inst = big_plane()
    cam = ortho_camera((0.0, 0.0, 3.0), (0, 0, 0), (8, 8), 0.5)
    for colour, world in (((0.5, 0.5, 0.5), (1.0, 1.0, 1.0)), ((0.9, 0.4, 0.1), (0.3, 0.6, 1.0))):
        scene = Scene([mesh], [inst], [Material("m", (Lobe("glossy", colour, 0.3),))], [], World(world), cam)
        settings = RenderSettings(samples=16, samples_per_pass=16, max_bounces=2, seed=5)
        plain = render(scene, settings)
        kept = render(scene, dataclasses.replace(settings, sum_variance=True))
        assert plain.sum_variance is None
        assert np.array_equal(plain.image, kept.image) and np.array_equal(plain.variance, kept.variance)
        var, total = kept.variance.astype(np.float64), kept.sum_variance.astype(np.float64)
        assert np.isfinite(total).all() and (total >= 0).all() and total.max() > 0
        bound = stats.sum_variance(kept.image[..., :3], var)
        assert (total <= bound * (1 + 1e-5) + 1e-12).all()
        if colour[0] == colour[1]:
            np.testing.assert_allclose(total, 9.0 * var[..., 0], rtol=1e-5, atol=1e-12)
        assert np.array_equal(kept.variance_with_sum[..., 3], kept.sum_variance)
