"""The suite's statistics (tests/ember_stats.py): exact tails, thresholds,
power, and the comparisons accept equal means and reject different ones."""
import math

import numpy as np
import pytest

import ember_stats as stats


def cauchy_p(t):       # Student's t with 1 degree of freedom
    return 1.0 - 2.0 * math.atan(abs(t)) / math.pi


def t2_p(t):           # 2 degrees of freedom: closed form
    return 1.0 - abs(t) / math.sqrt(2.0 + t * t)


@pytest.mark.parametrize("t", [0.0, 0.3, 1.0, 2.5, 7.0, 40.0, 8000.0, 16000.0, 1e6])
def test_t_tail_is_exact_against_closed_forms(t):
    # Closed forms lose relative precision for large t; compare with 1/t
    # asymptotics there (2/(pi t) and 1/t^2).
    if t < 100:
        assert stats.t_two_sided_p(t, 1) == pytest.approx(cauchy_p(t), rel=1e-10, abs=1e-15)
        assert stats.t_two_sided_p(t, 2) == pytest.approx(t2_p(t), rel=1e-10, abs=1e-15)
    else:
        assert stats.t_two_sided_p(t, 1) == pytest.approx(2.0 / (math.pi * t), rel=1e-6)
        assert stats.t_two_sided_p(t, 2) == pytest.approx(1.0 / t ** 2, rel=1e-6)


def test_t_tail_known_values_and_extremes():
    assert stats.t_two_sided_p(2.228139, 10) == pytest.approx(0.05, rel=1e-5)
    assert stats.t_two_sided_p(1.959964, 1e6) == pytest.approx(0.05, rel=1e-4)
    assert stats.t_two_sided_p(3.0, math.inf) == pytest.approx(math.erfc(3.0 / math.sqrt(2.0)), rel=1e-12)
    assert stats.t_two_sided_p(0.0, 5) == 1.0
    # The Simpson tail this replaced gave p(8000) = 0.0048 and p(16000) = 0.18.
    for dof in (7, 63, 1000):
        assert stats.t_two_sided_p(8000.0, dof) < 1e-20
        assert stats.t_two_sided_p(1e6, dof) < 1e-39
        assert stats.t_two_sided_p(math.inf, dof) == 0.0
    assert stats.t_two_sided_p(math.nan, 5) == 0.0    # a NaN statistic always fails
    # Monotone in t, and tends to the normal tail as dof grows.
    ps = [stats.t_two_sided_p(t, 30) for t in np.linspace(0, 50, 200)]
    assert all(a >= b for a, b in zip(ps, ps[1:]))
    assert stats.t_two_sided_p(4.0, 1e7) == pytest.approx(stats.normal_two_sided_p(4.0), rel=1e-5)


@pytest.mark.parametrize("level,dof", [(0.05, 10), (1e-4, 63), (1e-9, 7), (5e-5, math.inf)])
def test_thresholds_invert_the_tails(level, dof):
    t = stats.t_threshold(level, dof)
    assert stats.t_two_sided_p(t, dof) == pytest.approx(level, rel=1e-8)
    if math.isinf(dof):
        assert t == pytest.approx(stats.z_threshold(level))


def test_chi2_and_sidak_known_values():
    assert stats.chi2_sf(3.841459, 1) == pytest.approx(0.05, rel=1e-5)
    assert stats.chi2_sf(18.307038, 10) == pytest.approx(0.05, rel=1e-5)
    assert stats.chi2_sf(2.0, 2) == pytest.approx(math.exp(-1.0), rel=1e-12)
    assert stats.chi2_sf(1e5, 10) == 0.0 or stats.chi2_sf(1e5, 10) < 1e-300
    assert stats.sidak(0.01, 1) == pytest.approx(0.01)
    assert (1 - stats.sidak(0.01, 100)) ** 100 == pytest.approx(0.99, rel=1e-12)
    assert stats.sidak(1e-5, 1000) == pytest.approx(1e-8, rel=1e-5)   # no cancellation


def test_budget_is_one_for_the_suite():
    before = len(stats.families_used())
    level = stats.family_level("test_stats budget", 10)
    assert len(stats.families_used()) == before + 1
    assert level == pytest.approx(stats.sidak(stats.SUITE_ALPHA / stats.FAMILIES, 10))
    assert stats.FAMILIES * stats.FAMILY_ALPHA == pytest.approx(stats.SUITE_ALPHA)


def test_detectable_bias_is_found_half_the_time():
    """The power helper's promise, checked by simulation: a true shift of
    ``detectable(se, level)`` is rejected in about half of the trials, one of
    half that size almost never."""
    level, se = 1e-3, 0.01
    shift = stats.detectable(se, level)
    rng = np.random.default_rng(11)
    z = rng.normal(shift, se, 20000) / se
    rejected = np.mean(np.abs(z) > stats.z_threshold(level))
    assert abs(rejected - 0.5) < 4 * math.sqrt(0.25 / z.size)
    assert np.mean(np.abs(rng.normal(shift / 2, se, 20000) / se) > stats.z_threshold(level)) < 0.05


def test_equal_means_pass_and_shifted_means_fail():
    rng = np.random.default_rng(7)
    a = rng.normal(1.0, 0.3, size=(64, 6, 6, 3))
    b = rng.normal(1.0, 0.2, size=(8, 6, 6, 3))
    failures, details = stats.failing_blocks(a, b)
    assert len(failures) == 0, details
    b[:, 2, 3, 1] += 2.0  # one block-channel off by ~28 standard errors (dof ~8, level 5e-7)
    failures, _ = stats.failing_blocks(a, b)
    assert failures.tolist() == [[2, 3, 1]]


def test_region_means_see_a_spread_bias_the_blocks_miss():
    """A 1 % bias over the whole image hides in every block but not in the
    image mean: the reason every parity test has both."""
    rng = np.random.default_rng(5)
    a = rng.normal(1.0, 0.5, size=(64, 32, 32, 3))
    b = rng.normal(1.0, 0.5, size=(64, 32, 32, 3))
    tests, level = stats.region_mean_tests(a, b)
    assert not [t for t in tests if t.p < level], tests
    b *= 1.01
    failures, _ = stats.failing_blocks(stats.block_means(a, 8), stats.block_means(b, 8))
    assert len(failures) == 0
    tests, level = stats.region_mean_tests(a, b)
    assert tests[0].name == 'image' and tests[0].p < level, tests[0]
    assert tests[0].relative == pytest.approx(-0.01 / 1.01, abs=3 * tests[0].relative_se)


def test_region_means_with_pixel_variances():
    rng = np.random.default_rng(9)
    truth = rng.uniform(0.5, 2.0, size=(16, 16, 3))
    var_a, var_b = np.full_like(truth, 1e-3), np.full_like(truth, 1e-4)
    a = truth + rng.normal(0.0, np.sqrt(var_a))
    b = truth + rng.normal(0.0, np.sqrt(var_b))
    tests, level = stats.region_mean_tests_var(a, var_a, math.inf, b, var_b, 7)
    assert not [t for t in tests if t.p < level], tests
    tests, level = stats.region_mean_tests_var(a * 0.99, var_a, math.inf, b, var_b, 7)
    assert tests[0].p < level, tests[0]


def test_sum_variance_measured_or_bounded():
    """A variance with one channel more than its image carries the channel
    sum's (read as is); without it the sum's is bounded by Cauchy-Schwarz,
    never the channel variances summed; any other shape is refused."""
    image = np.ones((2, 2, 3))
    var = np.tile([1.0, 4.0, 9.0], (2, 2, 1))
    assert np.array_equal(stats.sum_variance(image, var), np.full((2, 2), 36.0))
    measured = np.concatenate([var, np.full((2, 2, 1), 20.0)], axis=2)
    assert np.array_equal(stats.sum_variance(image, measured), np.full((2, 2), 20.0))
    assert np.array_equal(stats.channel_variances(image, measured), var)
    with pytest.raises(ValueError, match="channels"):
        stats.sum_variance(image, var[..., :2])
    tests, _ = stats.region_mean_tests_var(image, measured, 7, image, measured, 7)
    assert tests[0].relative_se == pytest.approx(math.sqrt(2 * 4 * 20.0) / 12, rel=1e-9)


def test_block_means():
    images = np.arange(2 * 4 * 4 * 1, dtype=float).reshape(2, 4, 4, 1)
    blocks = stats.block_means(images, 2)
    assert blocks.shape == (2, 2, 2, 1)
    assert blocks[0, 0, 0, 0] == np.mean([0, 1, 4, 5])
    m, v = stats.block_means_var(images[0], np.ones((4, 4, 1)), 2)
    assert m[0, 0, 0] == np.mean([0, 1, 4, 5]) and v[0, 0, 0] == pytest.approx(0.25)


def test_single_render_against_batches():
    rng = np.random.default_rng(3)
    batches = rng.normal(2.0, 1.0, size=(32, 4, 4, 3))
    single = rng.normal(2.0, 1.0 / np.sqrt(32), size=(4, 4, 3))
    failures, details = stats.failing_single(single, batches)
    assert len(failures) == 0, details
    single[1, 1, 0] += 2.0  # ~8 standard errors of the difference
    failures, _ = stats.failing_single(single, batches)
    assert failures.tolist() == [[1, 1, 0]]


def test_blocks_with_pixel_variances_and_float32_floor():
    rng = np.random.default_rng(13)
    truth = rng.uniform(0.5, 2.0, size=(16, 16, 3))
    var = np.full_like(truth, 1e-3)
    a = truth + rng.normal(0.0, np.sqrt(var))
    failures, details = stats.failing_blocks_var(a, var, 255, truth, np.zeros_like(var), 7, 4)
    assert len(failures) == 0, details
    a[4:8, 8:12, 1] *= 1.2
    failures, _ = stats.failing_blocks_var(a, var, 255, truth, np.zeros_like(var), 7, 4)
    assert failures.tolist() == [[1, 2, 1]]
    # Noiseless on both sides (a constant world): equal up to float32 sums.
    sky = np.full((8, 8, 3), 0.9, np.float32).astype(float)
    summed = np.float32(0.0)
    for _ in range(2048):
        summed += np.float32(0.9)
    cycles_like = np.full_like(sky, float(summed / np.float32(2048)))
    zero = np.zeros_like(sky)
    failures, _ = stats.failing_blocks_var(sky, zero, 63, cycles_like, zero, 7, 4, float32_sums_b=2048)
    assert len(failures) == 0
    failures, _ = stats.failing_blocks_var(sky * 1.002, zero, 63, cycles_like, zero, 7, 4, float32_sums_b=2048)
    assert len(failures) == 4 * 3
