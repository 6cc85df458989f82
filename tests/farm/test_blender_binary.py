"""Farm tasks run by a real Blender binary (Debian's 3.4) with the add-on
installed from the legacy zip: frames equal the bpy module's, a failing
render fails its task with Blender's log."""
import os

import pytest

from blender34 import BLENDER, require_blender_34

from farmlib import (assert_same_image, make_animation_with_binary, make_job, read_exr, render_locally,
                     require, run_job)
from farm import client as farm_client
from farm import plan, shardfile



@pytest.fixture(scope='module')
def blender34(tmp_path_factory, legacy_addon):
    """A 3.4-saved animation and the env that makes the binary find the
    session's legacy install (tests/conftest.py: one kernel compile for all)."""
    require_blender_34()
    folder = tmp_path_factory.mktemp('blender34')
    scripts = legacy_addon[1]
    blend = make_animation_with_binary(BLENDER, folder / 'anim34.blend', scripts)
    return blend, {'BLENDER_USER_SCRIPTS': scripts}


@pytest.fixture(scope='module')
def references34(blender34, tmp_path_factory):
    """Frames 1-2 of the 3.4-saved animation rendered by the bpy module."""
    return render_locally(blender34[0], tmp_path_factory.mktemp('local34'), '1..2')


def test_frames_from_blender_34_binary_equal_bpy_module(cluster, blender34, references34, tmp_path):
    blend, env = blender34
    _, dask_client = cluster
    job = make_job(blend, tmp_path / 'farm', frames=[1, 2], chunk=2, blender=BLENDER, extra_env=env)
    run_job(dask_client, job)
    for frame in (1, 2):
        assert_same_image(read_exr(plan.frame_path(job.out_dir, frame)), references34[frame], f"frame {frame}")


def test_failing_render_in_blender_34_fails_its_task_with_the_log(cluster, blender34, tmp_path):
    """A shard whose render cannot start (bad sample range): the task fails
    with Blender's output; nothing is written."""
    blend, env = blender34
    _, dask_client = cluster
    from farm import tasks
    job = make_job(blend, tmp_path, frames=[1], blender=BLENDER, extra_env=env)
    future = dask_client.submit(tasks.run_shard, job, 1, -4, 4, pure=False)
    with pytest.raises(tasks.TaskFailed, match=r"(?s)status 1.*bad shard sample range"):
        future.result(timeout=120)
    assert not os.path.exists(plan.shard_dir(job.out_dir)) or not os.listdir(plan.shard_dir(job.out_dir))
    assert farm_client.pending(job, resume=True) == plan.tasks(job)


def test_split_frame_from_blender_34_binary_equals_bpy_module(cluster, blender34, references34, tmp_path):
    """The add-on's shard hook inside the real binary: two shards of frame 2
    merged equal the frame rendered whole by the bpy module."""
    from engine.film import Film
    require(hasattr(Film, 'from_state'), "engine.film.Film has no state API (sample ranges) yet")
    blend, env = blender34
    _, dask_client = cluster
    job = make_job(blend, tmp_path / 'farm', frames=[2], split=2, blender=BLENDER, extra_env=env)
    assert run_job(dask_client, job) == [plan.frame_path(job.out_dir, 2)]
    (shard,) = shardfile.find(plan.shard_dir(job.out_dir), 2, 4, 8)
    meta = shardfile.read_meta(shard)
    assert meta['blend_sha256'] == job.blend_sha256 and meta['ember_version'] == '0.1.0'
    assert_same_image(read_exr(plan.frame_path(job.out_dir, 2)), references34[2], "frame 2 merged from 3.4 shards")
