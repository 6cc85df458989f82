"""The comparison statistics must accept equal means and reject different ones."""
import numpy as np

import ember_stats as stats


def test_t_tail_matches_known_values():
    assert abs(stats.t_two_sided_p(1.959964, 1e6) - 0.05) < 1e-4
    assert abs(stats.t_two_sided_p(2.228139, 10) - 0.05) < 1e-4
    assert stats.t_two_sided_p(0.0, 5) == 1.0


def test_equal_means_pass_and_shifted_means_fail():
    rng = np.random.default_rng(7)
    a = rng.normal(1.0, 0.3, size=(64, 6, 6, 3))
    b = rng.normal(1.0, 0.2, size=(8, 6, 6, 3))
    failures, details = stats.failing_blocks(a, b)
    assert len(failures) == 0, details
    b[:, 2, 3, 1] += 0.5  # one block-channel off by ~7 standard errors
    failures, _ = stats.failing_blocks(a, b)
    assert failures.tolist() == [[2, 3, 1]]


def test_block_means():
    images = np.arange(2 * 4 * 4 * 1, dtype=float).reshape(2, 4, 4, 1)
    blocks = stats.block_means(images, 2)
    assert blocks.shape == (2, 2, 2, 1)
    assert blocks[0, 0, 0, 0] == np.mean([0, 1, 4, 5])


def test_single_render_against_batches():
    rng = np.random.default_rng(3)
    batches = rng.normal(2.0, 1.0, size=(32, 4, 4, 3))
    single = rng.normal(2.0, 1.0 / np.sqrt(32), size=(4, 4, 3))
    failures, details = stats.failing_single(single, batches)
    assert len(failures) == 0, details
    single[1, 1, 0] += 2.0  # ~8 standard errors of the difference
    failures, _ = stats.failing_single(single, batches)
    assert failures.tolist() == [[1, 1, 0]]
