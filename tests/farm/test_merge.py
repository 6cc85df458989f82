"""Merge arithmetic and the rules of a merge (no rendering)."""
import numpy as np
import pytest

from engine.film import Film
from farm.merge import merge_states, select
from farm.shardfile import ShardError
from farmlib import require


W, H = 8, 5


def _shards(rng, shards=3):
    """Per pixel and shard a different number of samples (as adaptive
    sampling leaves them, zero included): radiance with a heavy tail, alpha
    in [0, 1], a depth, and each sample's index (disjoint ranges per shard)."""
    out, first = [], 0
    for _ in range(shards):
        counts = rng.integers(0, 9, size=W * H)
        counts[rng.integers(W * H)] = 0
        pix = np.repeat(np.arange(W * H), counts)
        n = len(pix)
        index = first + np.concatenate([np.arange(c) for c in counts])
        first += int(counts.max())
        out.append({'pix': pix, 'L': rng.lognormal(0.0, 1.5, size=(n, 3)), 'alpha': rng.uniform(size=n),
                    'depth': rng.uniform(1, 5, size=n), 'index': index.astype(np.uint32)})
    return out


def _film_state(shard):
    film = Film(W, H, aovs=('depth',), adaptive=True)
    tile = film.new_tile(0, W * H)
    n = len(shard['pix'])
    tile.add_radiance(shard['pix'], shard['L'], shard['index'])
    tile.add_camera(shard['pix'], shard['alpha'], shard['depth'], np.zeros((n, 3)), np.zeros((n, 3)))
    film.merge(tile)
    return film.state()


def test_merged_film_states_hold_the_statistics_of_all_samples():
    """(count, mean, M2) per pixel of the merged shards equal those of all
    their samples taken at once; alpha, depth and the adaptive half-buffer
    add up; pixels without samples stay empty."""
    require(hasattr(Film, 'from_state'), "engine.film.Film has no state API")
    from engine.sampler import is_class_a
    shards = _shards(np.random.default_rng(5))
    film = merge_states([_film_state(s) for s in shards])
    union = {key: np.concatenate([s[key] for s in shards]) for key in shards[0]}
    for p in range(W * H):
        mine = union['pix'] == p
        L = union['L'][mine]
        assert film.count[p] == len(L)
        if not len(L):
            assert not film.mean[p].any() and not film.m2[p].any() and film.alpha[p] == 0
            continue
        np.testing.assert_allclose(film.mean[p], L.mean(0), rtol=2e-6)
        np.testing.assert_allclose(film.m2[p], ((L - L.mean(0)) ** 2).sum(0), rtol=1e-5)
        np.testing.assert_allclose(film.alpha[p], union['alpha'][mine].sum(), rtol=1e-6)
        np.testing.assert_allclose(film.aovs['depth'][p, 0], union['depth'][mine].sum(), rtol=1e-6)
        class_a = is_class_a(union['index'][mine])
        np.testing.assert_allclose(film.aux[p], L[class_a].sum(0), rtol=1e-5, atol=1e-6)
    # Grouping does not matter: (a + b) + c == a + (b + c).
    states = [_film_state(s) for s in shards]
    other = merge_states([states[0], merge_states(states[1:]).state()])
    np.testing.assert_array_equal(other.count, film.count)
    np.testing.assert_allclose(other.mean, film.mean, rtol=1e-6)
    np.testing.assert_allclose(other.m2, film.m2, rtol=1e-5, atol=1e-6)


def test_states_of_different_sizes_do_not_merge():
    require(hasattr(Film, 'from_state'), "engine.film.Film has no state API")
    with pytest.raises(ValueError, match="size"):
        merge_states([Film(4, 4).state(), Film(4, 5).state()])


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
