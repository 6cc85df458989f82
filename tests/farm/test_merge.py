"""Merge arithmetic and the rules of a merge (no rendering)."""
import numpy as np
import pytest

from farm import moments
from farm.merge import select
from farm.shardfile import ShardError


def _shards(rng, pixels=40, shards=3):
    """Per pixel and shard a different number of samples (as adaptive
    sampling leaves them, zero included): RGB radiance with a heavy tail and
    an alpha in [0, 1]."""
    out = []
    for _ in range(shards):
        counts = rng.integers(0, 9, size=pixels)
        counts[rng.integers(pixels)] = 0
        out.append([np.concatenate([rng.lognormal(0.0, 1.5, size=(n, 3)),
                                    rng.uniform(size=(n, 1))], axis=1) for n in counts])
    return out


def _union(shards, pixel):
    return np.concatenate([shard[pixel] for shard in shards])


def test_combined_moments_equal_all_samples_at_once():
    rng = np.random.default_rng(5)
    shards = _shards(rng)
    pixels = len(shards[0])
    parts = []
    for shard in shards:  # each shard's own (count, mean, M2) per pixel, RGBA
        count = np.array([len(s) for s in shard], float)
        mean = np.array([s.mean(0) if len(s) else np.zeros(4) for s in shard])
        m2 = np.array([((s - s.mean(0)) ** 2).sum(0) if len(s) else np.zeros(4) for s in shard])
        parts.append((count, mean, m2))
    count, mean, m2 = moments.combine_all(parts)
    for p in range(pixels):
        union = _union(shards, p)
        assert count[p] == len(union)
        if len(union):
            np.testing.assert_allclose(mean[p], union.mean(0), rtol=1e-12)
            np.testing.assert_allclose(m2[p], ((union - union.mean(0)) ** 2).sum(0), rtol=1e-9, atol=1e-12)
        else:
            assert not mean[p].any() and not m2[p].any()
    # Order and grouping do not matter: ((a, b), c) == (a, (b, c)).
    other = moments.combine(parts[0], moments.combine(parts[1], parts[2]))
    for x, y in zip((count, mean, m2), other):
        np.testing.assert_allclose(x, y, rtol=1e-10, atol=1e-12)


def test_summed_film_sums_give_the_same_statistics():
    """What shards store (sums of x and x^2, counts, alpha sums) added up
    gives the mean, variance and coverage of the union."""
    rng = np.random.default_rng(6)
    shards = _shards(rng)
    pixels = len(shards[0])
    count = sum(np.array([len(s) for s in shard], float) for shard in shards)
    s1 = sum(np.array([s[:, :3].sum(0) for s in shard]) for shard in shards)
    s2 = sum(np.array([(s[:, :3] ** 2).sum(0) for s in shard]) for shard in shards)
    alpha = sum(np.array([s[:, 3].sum() for s in shard]) for shard in shards)
    n, mean, m2 = moments.from_sums(count, s1, s2)
    for p in range(pixels):
        union = _union(shards, p)
        if len(union) == 0:
            assert n[p] == 0 and not mean[p].any()
            continue
        np.testing.assert_allclose(mean[p], union[:, :3].mean(0), rtol=1e-12)
        np.testing.assert_allclose(m2[p], ((union[:, :3] - union[:, :3].mean(0)) ** 2).sum(0), rtol=1e-7)
        np.testing.assert_allclose(alpha[p] / n[p], union[:, 3].mean(), rtol=1e-12)


def _meta(start, end, path=None, **changes):
    meta = {'path': path or f"s{start}-{end}", 'sample_start': start, 'sample_end': end,
            'ember_version': '0.1.0', 'blend_sha256': 'abc', 'seed': 7, 'frame': 3, 'layer': 'ViewLayer',
            'transparent': False, 'settings': {'max_bounces': 3}}
    meta.update(changes)
    return meta


def test_select_counts_each_range_once_in_order():
    metas = [_meta(32, 64), _meta(0, 32), _meta(32, 64, path='retry-copy')]
    chosen = select(metas)
    assert [(m['sample_start'], m['sample_end']) for m in chosen] == [(0, 32), (32, 64)]
    assert chosen[1]['path'] == 's32-64'


@pytest.mark.parametrize('ranges, words', [
    ([(0, 32), (40, 64)], "gap"),
    ([(0, 40), (32, 64)], "overlap"),
    ([(8, 64)], "gap"),
])
def test_select_refuses_gaps_and_overlaps(ranges, words):
    with pytest.raises(ShardError, match=words):
        select([_meta(a, b) for a, b in ranges])


@pytest.mark.parametrize('key, value', [
    ('blend_sha256', 'other'), ('seed', 8), ('ember_version', '0.2.0'), ('frame', 4),
    ('settings', {'max_bounces': 4}), ('transparent', True), ('layer', 'Other')])
def test_select_refuses_mismatched_shards(key, value):
    with pytest.raises(ShardError, match=key):
        select([_meta(0, 32), _meta(32, 64, **{key: value})])
    # Also when the odd one is a duplicate of a planned range.
    with pytest.raises(ShardError, match=key):
        select([_meta(0, 32), _meta(32, 64), _meta(32, 64, path='dup', **{key: value})])


def test_select_follows_the_plan():
    metas = [_meta(0, 32), _meta(32, 64), _meta(0, 16, path='older-split')]
    assert [m['path'] for m in select(metas, plan=[(0, 32), (32, 64)])] == ['s0-32', 's32-64']
    with pytest.raises(ShardError, match=r"\(32, 64\)"):
        select([_meta(0, 32)], plan=[(0, 32), (32, 64)])
    with pytest.raises(ShardError, match="no shards"):
        select([])
