"""Shards are exact: one render of S samples equals the merge of K renders
of disjoint sample ranges (to float32 rounding), and with adaptive sampling
the merge holds exactly the statistics of the samples the shards traced.
The engine alone, no Blender."""
import dataclasses

import numpy as np
import pytest

from engine.film import Film
from engine.render import prepare, render
from engine.scene import RenderSettings
from engine.testscenes import cornell_box
from farm import shardfile
from farm.merge import merge_files, merge_states
from farm.plan import sample_ranges
from farmlib import require

SIZE = 24


def settings(**kw):
    require(hasattr(RenderSettings(), 'sample_start') and hasattr(Film, 'from_state'),
            "the engine has no sample ranges / film state (RenderSettings.sample_start, Film.state)")
    base = dict(samples=12, samples_per_pass=4, seed=3, max_bounces=4, threads=2)
    base.update(kw)
    return RenderSettings(**base)


@pytest.fixture(scope='module')
def scene():
    return cornell_box(SIZE, SIZE)


def shard_states(scene, base, parts):
    return [render(scene, dataclasses.replace(base, sample_start=a, samples=b - a)).film.state()
            for a, b in sample_ranges(base.samples, parts)]


def assert_same_film(got, want):
    np.testing.assert_array_equal(got.count, want.count)
    scale = float(np.abs(want.mean).max())
    np.testing.assert_allclose(got.mean, want.mean, rtol=0, atol=2e-6 * scale)
    np.testing.assert_allclose(got.alpha, want.alpha, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got.m2, want.m2, rtol=1e-4, atol=1e-5 * float(np.abs(want.m2).max()))


def test_one_render_equals_merged_shards(scene, tmp_path):
    base = settings(transparent=True)
    whole = render(scene, base)
    states = shard_states(scene, base, 3)
    merged = merge_states(states)
    assert_same_film(merged, whole.film)
    np.testing.assert_allclose(merged.image(True), whole.image, rtol=0, atol=2e-6 * float(whole.image.max()))
    np.testing.assert_allclose(merged.variance(), whole.variance, rtol=1e-3, atol=1e-9)
    # The same through shard files, given in another order and one twice.
    paths = []
    for (a, b), state in zip(sample_ranges(base.samples, 3), states):
        paths.append(str(tmp_path / f"s{a}.npz"))
        shardfile.write_atomic(paths[-1], state, {
            'format': shardfile.FORMAT, 'sample_start': a, 'sample_end': b, 'ember_version': '0', 'seed': 3,
            'blend_sha256': 'x', 'frame': 1, 'layer': 'L', 'transparent': True, 'settings': {}})
    film, meta = merge_files([paths[2], paths[0], paths[1], paths[0]])
    assert_same_film(film, whole.film)
    assert (meta['sample_start'], meta['sample_end']) == (0, 12) and len(meta['shards']) == 3


def test_adaptive_shards_merge_to_the_samples_they_traced(scene):
    """With adaptive sampling each shard stops converged pixels on its own
    (so the merge is not the image of one adaptive render, which would stop
    other pixels): the merged counts, means and M2 are those of exactly the
    samples traced, recomputed here in one batch from (pixel, sample index)."""
    if not hasattr(RenderSettings(), 'adaptive_threshold'):
        require(False, "the engine has no adaptive sampling (RenderSettings.adaptive_threshold)")
    base = settings(samples=64, samples_per_pass=8, adaptive_threshold=0.05, adaptive_min_samples=8)
    ranges = sample_ranges(base.samples, 2)
    states = shard_states(scene, base, 2)
    counts = [s['count'].astype(int) for s in states]
    assert all((c < 32).any() and (c == 32).any() for c in counts), "adaptive sampling stopped no pixel"
    merged = merge_states(states)
    # Every (pixel, sample index) the shards traced: a prefix of each range.
    pix = np.concatenate([np.repeat(np.arange(SIZE * SIZE), c) for c in counts])
    sample = np.concatenate([np.concatenate([np.arange(a, a + n) for n in c]) for (a, _), c in zip(ranges, counts)])
    from engine.integrator import trace_batch
    ctx = prepare(scene, base)
    union = Film(SIZE, SIZE, base.aovs, adaptive=True)
    order = np.argsort(pix, kind='stable')
    tile = union.new_tile(0, SIZE * SIZE)
    trace_batch(ctx, pix[order], sample[order], tile)
    union.merge(tile)
    assert_same_film(merged, union)


def _write_shard(folder, frame, start, end, layer, state, **meta):
    name = f"frame_{frame:06d}.s{start:09d}-{end:09d}.{layer}.npz"
    fields = {'format': shardfile.FORMAT, 'sample_start': start, 'sample_end': end, 'ember_version': '0.1.0',
              'seed': 3, 'blend_sha256': 'abc', 'frame': frame, 'layer': layer, 'transparent': False,
              'settings': {}}
    fields.update(meta)
    shardfile.write_atomic(str(folder / name), state, fields)


def test_merge_task_writes_each_view_layer_and_checks_the_blend(scene, tmp_path):
    from engine.imageio import read_image
    from farm import plan, tasks
    base = settings()
    states = shard_states(scene, base, 2)
    whole = merge_states(states)
    job = plan.Job(blend='scene.blend', out_dir=str(tmp_path), frames=[5], samples=12, split=2, blend_sha256='abc')
    folder = tmp_path / 'shards'
    for layer in ('Front', 'Back'):
        for (a, b), state in zip(sample_ranges(12, 2), states):
            _write_shard(folder, 5, a, b, layer, state)
    written = tasks.run_merge(job, 5)
    assert sorted(written) == [str(tmp_path / 'frame_0005.Back.exr'), str(tmp_path / 'frame_0005.Front.exr')]
    for path in written:
        np.testing.assert_array_equal(read_image(path), whole.image(False))
    # A shard of another blend file under a planned name is refused.
    _write_shard(folder, 5, 6, 12, 'Front', states[1], blend_sha256='other')
    with pytest.raises(shardfile.ShardError, match="blend_sha256"):
        tasks.run_merge(job, 5)


def test_denoising_happens_after_the_merge(scene):
    """Shards of a scene that denoises are merged first, then the merged
    image is denoised with the merged albedo and normal."""
    from farm.merge import denoiser, final_image
    denoise = denoiser()
    try:
        denoise.oidn_program()
    except denoise.DenoiseError as err:
        require(False, f"OIDN is needed for denoising: {err}")
    base = settings(samples=8, aovs=('albedo', 'normal'))
    merged = merge_states(shard_states(scene, base, 2))
    meta = {'transparent': False, 'frame': 1, 'denoise': True}
    image = final_image(merged, meta)
    noisy = merged.image(False)
    expected = denoise.denoise(noisy[..., :3], merged.aov('albedo'), merged.aov('normal'))
    np.testing.assert_allclose(image[..., :3], expected, rtol=1e-6, atol=1e-7)
    assert np.abs(image[..., :3] - noisy[..., :3]).mean() > 1e-3 * noisy[..., :3].mean()
    np.testing.assert_array_equal(image[..., 3], noisy[..., 3])
    np.testing.assert_array_equal(final_image(merged, dict(meta, denoise=False)), noisy)


def test_adaptive_split_frame_stops_each_shard_on_its_own_samples(scene):
    """What a split frame does with adaptive sampling (docs/sampling.md,
    "Adaptive sampling across farm shards"): each shard is an adaptive render
    of its sample range alone.  Its min samples and its checks every 16
    samples count from the shard's first sample, and its error estimate uses
    its own samples only, so every pixel gets at least min samples in every
    shard: the split frame traces more samples than one adaptive render
    (which may stop a pixel at min samples in all)."""
    if not hasattr(RenderSettings(), 'adaptive_threshold'):
        require(False, "the engine has no adaptive sampling (RenderSettings.adaptive_threshold)")
    base = settings(samples=60, samples_per_pass=0, adaptive_threshold=0.05, adaptive_min_samples=16)
    ranges = sample_ranges(base.samples, 3)                 # [0, 20) [20, 40) [40, 60)
    shards = [s['count'].astype(int) for s in shard_states(scene, base, 3)]
    for (a, b), count in zip(ranges, shards):
        # Stopped at the shard's own check point (16 = min samples) or ran to its end.
        assert set(np.unique(count)) <= {16, b - a}, (a, b, np.unique(count))
        assert (count < b - a).any(), f"adaptive sampling stopped no pixel in shard {a}-{b}"
    one = render(scene, base).film.count.astype(int)
    assert set(np.unique(one)) <= {16, 32, 48, 60}, np.unique(one)
    split = sum(shards)
    print(f"samples traced: one adaptive render {one.sum()}, 3 shards {split.sum()}; "
          f"fewest per pixel: {one.min()} vs {split.min()}")
    assert split.min() >= 3 * 16 and one.min() == 16
    assert split.sum() > one.sum()


def test_merge_task_refuses_shards_of_another_ember_version(scene, tmp_path, monkeypatch):
    """Shards rendered by another Ember (a Blender binary's installed add-on
    can differ from the checkout the job was planned with) are refused, also
    by a worker whose checkout matches the job."""
    from farm import plan, tasks, versions
    monkeypatch.setattr(versions, 'ember_version', lambda: '0.2.0')
    states = shard_states(scene, settings(), 2)
    job = plan.Job(blend='scene.blend', out_dir=str(tmp_path), frames=[5], samples=12, split=2, blend_sha256='abc',
                   ember_version='0.2.0')
    for (a, b), state in zip(sample_ranges(12, 2), states):
        _write_shard(tmp_path / 'shards', 5, a, b, 'ViewLayer', state)      # written by Ember 0.1.0
    with pytest.raises(shardfile.ShardError, match="ember_version is '0.1.0', the job expects '0.2.0'"):
        tasks.run_merge(job, 5)
