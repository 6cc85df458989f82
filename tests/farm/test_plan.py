"""Frames, chunks, sample ranges and what --resume leaves to do."""
import os

import numpy as np
import pytest

from farm import client, plan, shardfile


def test_frames_chunks_and_ranges():
    assert plan.parse_frames('1-4,7, 9-10,3') == [1, 2, 3, 4, 7, 9, 10]
    assert plan.parse_frames('5') == [5]
    for bad in ('4-1', 'a', '1-', ''):
        with pytest.raises(ValueError):
            plan.parse_frames(bad)
    assert plan.chunks([1, 2, 3, 4, 7, 9, 10], 3) == [[1, 2, 3], [4], [7], [9, 10]]
    assert plan.sample_ranges(10, 3) == [(0, 3), (3, 6), (6, 10)]
    with pytest.raises(ValueError):
        plan.sample_ranges(2, 3)


def _job(tmp_path, **kw):
    kw.setdefault('frames', [1, 2, 3, 4])
    return plan.Job(blend='x.blend', out_dir=str(tmp_path), blend_sha256='abc', **kw)


def _shard(job, frame, start, end, sha='abc'):
    path = os.path.join(plan.shard_dir(job.out_dir), f"frame_{frame:06d}.s{start:09d}-{end:09d}.ViewLayer.npz")
    shardfile.write_atomic(path, {'rgb': np.zeros(3)}, {'blend_sha256': sha, 'format': shardfile.FORMAT})


def test_resume_leaves_only_missing_frames_and_shards(tmp_path):
    job = _job(tmp_path, chunk=2)
    assert [t.key for t in client.pending(job, resume=True)] == ['ember-chunk-1-2', 'ember-chunk-3-4']
    open(plan.frame_path(job.out_dir, 2), 'w').close()
    assert [t.key for t in client.pending(job, resume=True)] == ['ember-chunk-1-1', 'ember-chunk-3-4']
    assert len(client.pending(job, resume=False)) == 2

    split = _job(tmp_path / 'split', frames=[1, 2], samples=8, split=2)
    _shard(split, 1, 0, 4)
    _shard(split, 1, 4, 8, sha='stale')   # another blend's shard: rendered again
    _shard(split, 2, 0, 4)
    _shard(split, 2, 4, 8)
    open(plan.frame_path(split.out_dir, 2), 'w').close()
    assert [t.key for t in client.pending(split, resume=True)] == ['ember-shard-1-s4-8', 'ember-merge-1']
