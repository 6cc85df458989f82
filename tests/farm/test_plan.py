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
    assert plan.format_frames([1, 2, 3, 4, 7, 9, 10]) == '1-4,7,9-10'   # farm status shows jobs so
    assert plan.parse_frames(plan.format_frames([120])) == [120]
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


def test_blender_command_lines():
    from farm.commands import BPY_RENDER, frame_arg, render_command
    assert frame_arg([3]) == '3' and frame_arg([1, 2, 3]) == '1..3' and frame_arg([1, 3]) == '1,3'
    job = plan.Job(blend='/s/a.blend', out_dir='/o', frames=[1], samples=32, blender='/bin/blender', threads=2)
    cmd = render_command(job, [1, 2], '/o/frame_####', shard=('/o/shards', 16, 8))
    # --addons before the file; -F before the code that sets the EXR depth; -f last.
    assert cmd[:5] == ['/bin/blender', '-b', '--addons', 'ember', '/s/a.blend']
    assert cmd[cmd.index('-F') + 1] == 'OPEN_EXR' and cmd.index('-F') < cmd.index('--python-expr')
    assert cmd[-2:] == ['-f', '1..2']
    code = cmd[cmd.index('--python-expr') + 1]
    for line in ("s.ember.samples = 32", "s.ember.threads = 2", "os.environ['EMBER_SHARD_START'] = '16'",
                 "os.environ['EMBER_SHARD_SAMPLES'] = '8'", "os.environ['EMBER_SHARD_DIR'] = '/o/shards'"):
        assert line in code
    job.blender = ''
    assert render_command(job, [1], '/o/f_####')[1:4] == ['-P', BPY_RENDER, '/s/a.blend']


def test_error_check_stops_blender_with_status_1():
    """The render_post handler of the setup code: Ember's recorded error ends
    the Blender process with status 1 (Blender would exit 0 with a black frame)."""
    import subprocess
    import sys
    from farm.commands import ERROR_CHECK
    fake = ("import sys, types\n"
            "bpy = types.SimpleNamespace(app=types.SimpleNamespace(handlers=types.SimpleNamespace(render_post=[])))\n"
            "mod = types.ModuleType('ember.engine'); mod.RENDER_LOG = [{'error': None}]\n"
            "sys.modules['ember.engine'] = mod\n" + ERROR_CHECK +
            "bpy.app.handlers.render_post[0](None)\nprint('fine')\n"
            "mod.RENDER_LOG.append({'error': 'boom'})\nbpy.app.handlers.render_post[0](None)\nprint('not reached')\n")
    out = subprocess.run([sys.executable, '-c', fake], capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and out.stdout.split() == ['fine', 'EMBER-FARM-ERROR:', 'boom'], out


def test_resume_refuses_another_jobs_folder(tmp_path):
    job = _job(tmp_path, samples=8)
    client.check_manifest(job, resume=False)
    client.check_manifest(job, resume=True)           # same job: fine
    other = _job(tmp_path, samples=16)
    with pytest.raises(SystemExit, match="changed: samples"):
        client.check_manifest(other, resume=True)
    client.check_manifest(other, resume=False)        # a fresh job takes the folder over
    upgraded = _job(tmp_path, samples=16, ember_version='0.2.0')
    with pytest.raises(SystemExit, match="changed: ember_version"):
        client.check_manifest(upgraded, resume=True)  # frames of two Embers in one job: no
    import json
    with open(client.manifest_path(other), 'w') as handle:  # a manifest written before the versions
        json.dump({'blend_sha256': 'abc', 'samples': 16, 'split': 1}, handle)
    client.check_manifest(upgraded, resume=True)


@pytest.mark.parametrize('argv, message', [
    (['--frames', '1-3', '--local', '1', '-o', 'x', 'missing.blend'], 'no such .blend'),
    (['--frames', '3-1', '--local', '1', '-o', 'x', 'BLEND'], 'ends before'),
    (['--frames', '1', '--split-samples', '4', '--local', '1', '-o', 'x', 'BLEND'], 'needs --samples'),
    (['--frames', '1', '--samples', '2', '--split-samples', '4', '--local', '1', '-o', 'x', 'BLEND'],
     'cannot split 2 samples'),
    (['--frames', '1', '--blender', '/nonexistent/blender', '--local', '1', '-o', 'x', 'BLEND'],
     'not an executable'),
])
def test_bad_render_arguments_get_a_clear_message(tmp_path, argv, message):
    from farm.__main__ import make_job, parse
    blend = tmp_path / 'scene.blend'
    blend.write_bytes(b'BLENDER')
    args = parse(['render'] + [str(blend) if a == 'BLEND' else a for a in argv])
    with pytest.raises(SystemExit, match=message):
        make_job(args)


def test_worker_check_names_what_differs(tmp_path):
    """A task planned for another Ember, Blender or scene is refused before
    Blender starts, with both values in the message (farm/versions.py)."""
    from farm import versions
    blend = tmp_path / 'x.blend'
    blend.write_bytes(b'BLENDER scene')
    job = plan.Job(blend=str(blend), out_dir=str(tmp_path), frames=[1], blend_sha256=client.blend_hash(str(blend)),
                   ember_version=versions.ember_version(), blender_version='bpy 0.0.1')
    with pytest.raises(versions.WorkerMismatch, match=r"refuses shard-1: Blender here is 'bpy [0-9.]+', "
                                                       r"the job was planned with 'bpy 0.0.1'"):
        versions.check_worker(job, 'shard-1')
    versions.check_worker(job, 'merge-1', renders=False)     # a merge runs no Blender
    job.blender_version = versions.blender_version('', job.python)
    versions.check_worker(job, 'shard-1')
    blend.write_bytes(b'BLENDER another scene')
    with pytest.raises(versions.WorkerMismatch, match="scene hash here is .* is the shared storage in sync"):
        versions.check_worker(job, 'shard-1')


def test_status_counts_tasks_and_gives_an_eta(monkeypatch):
    """`farm status` from a scheduler's task table and a job's record: the
    tasks of each job by state, who runs what, the ETA from the work done,
    and a job whose client is gone shown as interrupted."""
    import time
    from types import SimpleNamespace as NS
    from farm import status
    now = time.time()
    worker = NS(name='ember-a')
    tasks = {'ember-shard-1-s0-4-aaaa': NS(state='memory', processing_on=None),
             'ember-shard-1-s4-8-aaaa': NS(state='processing', processing_on=worker),
             'ember-merge-1-aaaa': NS(state='waiting', processing_on=None),
             'other-key': NS(state='processing', processing_on=worker)}
    jobs = {'aaaa': dict(token='aaaa', blend='/s/x.blend', out_dir='/s/out', frames='1', tasks=3, done=1,
                         failed=0, work=8, work_done=2, started=now - 10, state='running'),
            'bbbb': dict(token='bbbb', blend='/s/y.blend', out_dir='/s/old', frames='1-3', tasks=3, done=1,
                         failed=0, work=3, work_done=1, started=now - 100, updated=now - 90, state='running')}

    class Client:
        def scheduler_info(self):
            return {'address': 'tcp://10.0.0.5:8786', 'services': {'dashboard': 8787},
                    'workers': {'tcp://10.0.0.6:4000': {'name': 'ember-a', 'nthreads': 1}}}

        def run_on_scheduler(self, function):
            return function(dask_scheduler=NS(tasks=tasks))

        def get_metadata(self, keys, default=None):
            assert keys == ['ember-farm', 'jobs']
            return jobs

    monkeypatch.setattr(status.time, 'time', lambda: now)
    monkeypatch.setattr(status, '_dashboard_note', lambda url: '')   # no HTTP to 10.0.0.5
    data = status.gather(Client())
    assert data['dashboard'] == 'http://10.0.0.5:8787/status'
    assert data['workers'] == [{'name': 'ember-a', 'address': 'tcp://10.0.0.6:4000', 'threads': 1,
                                'running': ['ember-shard-1-s4-8-aaaa']}]
    old, live = data['jobs']                       # oldest first
    assert old['state'] == 'interrupted' and old['eta'] is None
    assert live['live'] == {'waiting': 1, 'running': 1, 'done': 1, 'failed': 0}
    assert live['eta'] == pytest.approx(30)        # 10 s for a quarter of the work
    shown = status.format_status(data)
    assert 'ETA 0:00:30' in shown and 'bbbb  interrupted' in shown and 'ember-a  tcp://10.0.0.6:4000' in shown
