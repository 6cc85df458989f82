"""The farm on a Dask LocalCluster with two workers: an animation in chunks,
a frame split into sample shards, a worker killed mid-task, --resume.
Every output is compared with the same frames rendered locally."""
import glob
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from farmlib import (ROOT, SAMPLES, THREADS, assert_same_image, make_job, read_exr, render_locally, require,
                     run_job)
from farm import plan

def test_animation_in_chunks_equals_local_renders(cluster, animated_blend, references, tmp_path):
    _, dask_client = cluster
    job = make_job(animated_blend, tmp_path, chunk=2)
    written = run_job(dask_client, job)
    assert sorted(written) == [plan.frame_path(str(tmp_path), f) for f in range(1, 5)]
    for frame in range(1, 5):
        assert_same_image(read_exr(plan.frame_path(str(tmp_path), frame)), references[frame], f"frame {frame}")
    # The frames differ from each other (the animation was rendered).
    assert np.abs(references[1] - references[4]).max() > 0.05
    assert not os.path.exists(tmp_path / '.farm' / 'tmp'), "scratch folders left behind"


def test_frame_in_two_shards_equals_local_render(cluster, animated_blend, references, tmp_path):
    from engine.film import Film
    require(hasattr(Film, 'from_state'), "engine.film.Film has no state API (sample ranges) yet")
    _, dask_client = cluster
    job = make_job(animated_blend, tmp_path, frames=[2], split=2)
    assert run_job(dask_client, job) == [plan.frame_path(str(tmp_path), 2)]
    shards = sorted(os.listdir(plan.shard_dir(str(tmp_path))))
    assert shards == ['frame_000002.s000000000-000000004.ViewLayer.npz',
                      'frame_000002.s000000004-000000008.ViewLayer.npz']
    assert_same_image(read_exr(plan.frame_path(str(tmp_path), 2)), references[2], "merged frame 2")


def _kill_first_running_task(out_dir, killed, timeout=60):
    """SIGKILL the worker process of the first task seen running."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not killed:
        for marker in glob.glob(os.path.join(out_dir, '.farm', 'running', '*.json')):
            try:
                with open(marker) as handle:
                    info = json.load(handle)
            except (OSError, ValueError):
                continue  # being written
            os.kill(info['worker_pid'], signal.SIGKILL)
            killed.append(info)
            return
        time.sleep(0.02)


def test_worker_killed_mid_task_job_still_equals_local(cluster, animated_blend, references, tmp_path):
    _, dask_client = cluster
    job = make_job(animated_blend, tmp_path, chunk=2)
    killed = []
    killer = threading.Thread(target=_kill_first_running_task, args=(str(tmp_path), killed))
    killer.start()
    written = run_job(dask_client, job)
    killer.join()
    assert killed, "no task was seen running"
    assert len(written) == 4
    assert not os.path.exists(tmp_path / '.farm' / 'tmp'), "the killed task's scratch folder was left behind"
    for frame in range(1, 5):
        assert_same_image(read_exr(plan.frame_path(str(tmp_path), frame)), references[frame], f"frame {frame}")
    # The killed task's render died with its worker (no orphan left running).
    time.sleep(0.5)
    assert not os.path.exists(f"/proc/{killed[0]['child_pid']}") or \
        open(f"/proc/{killed[0]['child_pid']}/stat").read().split()[2] == 'Z'


def test_resume_after_interrupted_client_submits_only_missing(cluster, animated_blend, references, tmp_path):
    """A client killed once its first renders run; --resume renders the
    others only.  The client dies as soon as a task has started (not after a
    frame is written: on a fast machine all four frames could be done or
    running by then, leaving nothing to resume)."""
    lc, _ = cluster
    cmd = [sys.executable, '-m', 'farm', 'render', animated_blend, '--frames', '1-4', '--scheduler',
           lc.scheduler_address, '--threads', str(THREADS), '--samples', str(SAMPLES), '-o', str(tmp_path)]
    env = dict(os.environ, PYTHONPATH=ROOT)
    first = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             start_new_session=True)
    deadline = time.monotonic() + 120
    try:
        while not glob.glob(str(tmp_path / '.farm' / 'running' / '*')) and time.monotonic() < deadline:
            assert first.poll() is None, first.stdout.read().decode()[-3000:]
            time.sleep(0.05)
    finally:
        os.kill(first.pid, signal.SIGKILL)
        first.wait()
    # Renders already running finish on their workers (the scheduler drops
    # the rest with the client): wait for them, then see what is missing.
    # A task's scratch folder (.farm/tmp) outlives its running marker until
    # its frames are moved into place, and a task a worker had already taken
    # may start just after the kill: wait until neither exists and the
    # finished frames stay the same for two seconds.
    done, quiet_since = None, time.monotonic()
    while time.monotonic() < deadline:
        busy = glob.glob(str(tmp_path / '.farm' / 'running' / '*')) + glob.glob(str(tmp_path / '.farm' / 'tmp' / '*'))
        now_done = sorted(glob.glob(str(tmp_path / 'frame_*.exr')))
        if busy or now_done != done:
            done, quiet_since = now_done, time.monotonic()
        elif time.monotonic() - quiet_since > 2.0:
            break
        time.sleep(0.05)
    assert 1 <= len(done) < 4, done
    missing = [f for f in range(1, 5) if plan.frame_path(str(tmp_path), f) not in done]
    second = subprocess.run(cmd + ['--resume'], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    (line,) = [l for l in second.stderr.splitlines() if l.startswith('farm:')]
    assert line.split(': ', 2)[2].split() == [f"ember-chunk-{f}-{f}" for f in missing], line
    for frame in range(1, 5):
        assert_same_image(read_exr(plan.frame_path(str(tmp_path), frame)), references[frame], f"frame {frame}")


def test_farm_worker_joins_with_one_render_slot(cluster):
    """`python -m farm worker ADDRESS` registers one single-threaded worker
    whose tasks can import the farm and see the render-thread setting."""
    lc, dask_client = cluster
    before = set(dask_client.scheduler_info()['workers'])
    proc = subprocess.Popen([sys.executable, '-m', 'farm', 'worker', lc.scheduler_address, '--name', 'farm-cli',
                             '--render-threads', '3'], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        new = {}
        while not new and time.monotonic() < deadline:
            workers = dask_client.scheduler_info()['workers']
            new = {a: w for a, w in workers.items() if a not in before}
            time.sleep(0.1)
        assert len(new) == 1, "the farm worker did not join"
        (address, info), = new.items()
        assert info['nthreads'] == 1 and info['name'] == 'farm-cli'
        threads = dask_client.submit(lambda: __import__('os').environ.get('EMBER_FARM_RENDER_THREADS'),
                                     workers=[address], pure=False).result(timeout=60)
        assert threads == '3'
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
