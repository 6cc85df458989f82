"""The farm as users start it: a `dask scheduler` process and `python -m farm
worker` processes on loopback, jobs submitted by `python -m farm render`
processes.  The README's farm commands run as written (hosts, ports, paths
and the job's size substituted); a worker SIGKILLed mid-task while another
joins late; a client killed and its job resumed; workers refusing a task
planned for another Ember, Blender or scene; `farm status` against the live
farm.  Every output equals the same frames (or the same shards, merged)
rendered locally, bit for bit: the same code renders them."""
import glob
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from farmlib import ROOT, make_job, read_exr, require
from proclib import (Processes, checkout_env, free_port, readme_farm_commands, substitute, wait_for,
                     wait_for_port, worker_name, workers_by_name)
from farm import plan

SAMPLES, SPLIT, STILL = 8, 2, 120     # the still of the README: frame 120, here 8 samples in 2 shards
TIMEOUT = 120                         # any one wait (a loaded 2-core machine)


def _distributed():
    require(os.path.isfile(os.path.join(ROOT, '.venv', 'bin', 'dask')), "no .venv/bin/dask (make setup)")
    import distributed
    return distributed


def _run(argv, timeout=TIMEOUT):
    out = subprocess.run(argv, cwd=ROOT, env=checkout_env(), capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{' '.join(argv)}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out


def _readme(tmp, port, dashboard, blend):
    """The README's commands, pointed at this test's farm and a tiny job."""
    text = open(os.path.join(ROOT, 'README.md')).read()
    parts = {'SCHEDULER': '127.0.0.1', '8786': str(port), ':8787': f":{dashboard}",
             '/shared/shot.blend': blend, '/shared/still.blend': blend, '/shared/out/': f"{tmp}/"}
    exact = {'1-250': '1-2', '4096': str(SAMPLES), '16': str(SPLIT), 'still.exr': f"{tmp}/still.exr"}
    commands = [[exact.get(a, a) for a in substitute(argv, parts)] for argv in readme_farm_commands()]
    for placeholder in list(parts) + list(exact):
        assert placeholder in text, f"README's farm section changed: no {placeholder!r} (update this test)"
    kinds = [' '.join(argv[:2] if 'dask' in argv[0] else argv[1:4]) for argv in commands]
    assert kinds == ['.venv/bin/dask scheduler', '-m farm worker', '-m farm render', '-m farm render',
                     '-m farm status', '-m farm merge'], kinds
    return dict(zip(('scheduler', 'worker', 'animation', 'still', 'status', 'merge'), commands))


class Farm:
    def __init__(self, tmp, blend):
        self.tmp, self.blend = str(tmp), blend
        self.port, self.dashboard = free_port(), free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.readme = _readme(self.tmp, self.port, self.dashboard, blend)
        self.procs = Processes(tmp, checkout_env())
        self.client = None

    def start(self, workers):
        sched = self.procs.start('scheduler', self.readme['scheduler'])
        wait_for_port(self.port, TIMEOUT, sched)
        self.client = _distributed().Client(self.address, timeout=60)
        names = [self.start_worker(name) for name in workers]  # all at once: each takes seconds
        wait_for(lambda: set(names) <= set(workers_by_name(self.client)), TIMEOUT, f"workers {names} to join")
        return self

    def start_worker(self, name, extra=()):
        """Start a worker by the README's command; returns its Dask name."""
        proc = self.procs.start(name, self.readme['worker'] + list(extra))
        return extra[-1] if extra else worker_name(proc)

    def render(self, *args):
        return [sys.executable, '-m', 'farm', 'render', self.blend, '--scheduler', self.address, *map(str, args)]

    def status(self):
        """What `farm status` shows (its CLI runs in the README test)."""
        from farm.status import gather
        return gather(self.client)

    def close(self):
        if self.client is not None:
            self.client.close()
        self.procs.close()


@pytest.fixture(scope='module')
def farm(animated_blend, local, tmp_path_factory):
    """Scheduler and two workers started by the README's commands (after the
    local reference render has started: both run at once)."""
    _distributed()
    farm = Farm(tmp_path_factory.mktemp('farm'), animated_blend)
    try:
        yield farm.start(['worker-a', 'worker-b'])
    finally:
        farm.close()


# Run inside the local Blender before each render: frames 1-3 whole, then
# the still's shards one after the other (the shard hook reads these
# variables when a render starts), so one process renders every reference.
LOCAL_PLAN = """
_plan = [None] * 3 + {shards!r}
def _ember_test_next_shard(*_args):
    shard = _plan.pop(0)
    for name in ('EMBER_SHARD_DIR', 'EMBER_SHARD_START', 'EMBER_SHARD_SAMPLES'):
        os.environ.pop(name, None)
    if shard:
        os.environ.update(EMBER_SHARD_DIR=shard[0], EMBER_SHARD_START=str(shard[1]), EMBER_SHARD_SAMPLES=str(shard[2]))
bpy.app.handlers.render_pre.append(_ember_test_next_shard)
"""


class LocalRender:
    """What one machine renders without the farm, with the workers' settings,
    in one bpy process started at once and waited for when first needed
    (it renders while the farm starts): frames 1-3 and the still's shards,
    the shards merged by the farm's merge."""

    def __init__(self, blend, tmp):
        from farm.commands import BPY_RENDER, setup_code
        self.tmp, self.folder = tmp, str(tmp / 'shards')
        self.ranges = plan.sample_ranges(SAMPLES, SPLIT)
        code = setup_code(SAMPLES, 0) + LOCAL_PLAN.format(shards=[(self.folder, a, b - a) for a, b in self.ranges])
        argv = [sys.executable, '-P', BPY_RENDER, blend, '-o', str(tmp / 'frame_####'), '--python-expr', code,
                '-f', '1..3' + f",{STILL}" * SPLIT]
        self.procs = Processes(tmp, checkout_env())
        self.proc = self.procs.start('local', argv)
        self.done = None

    def result(self):
        """({frame: image} of frames 1-3, the still's merged image, its shard folder)."""
        from farm.merge import final_image, merge_files
        if self.done is None:
            assert self.proc.wait(timeout=300) == 0, self.procs.log('local')[-3000:]
            film, meta = merge_files(sorted(glob.glob(os.path.join(self.folder, '*.npz'))), plan=self.ranges)
            frames = {f: read_exr(self.tmp / f"frame_{f:04d}.exr") for f in range(1, 4)}
            self.done = frames, final_image(film, meta), self.folder
        return self.done


@pytest.fixture(scope='module')
def local(animated_blend, tmp_path_factory):
    render = LocalRender(animated_blend, tmp_path_factory.mktemp('local'))
    try:
        yield render
    finally:
        render.procs.close()


def _same_shards(farm_folder, local_folder):
    from farm.shardfile import read
    names = sorted(os.listdir(local_folder))
    assert sorted(n for n in os.listdir(farm_folder) if n.endswith('.npz')) == names
    for name in names:
        got, want = read(os.path.join(farm_folder, name))[0], read(os.path.join(local_folder, name))[0]
        for key in ('count', 'mean', 'm2', 'alpha'):
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{name}: {key}")


def test_readme_commands_render_what_one_machine_renders(farm, local):
    readme, tmp = farm.readme, farm.tmp
    jobs = [farm.procs.start(name, readme[name]) for name in ('animation', 'still')]  # side by side
    for name, proc in zip(('animation', 'still'), jobs):
        assert proc.wait(timeout=TIMEOUT) == 0, farm.procs.log(name)[-3000:]
    for frame in (1, 2):
        np.testing.assert_array_equal(read_exr(plan.frame_path(f"{tmp}/shot", frame)), local.result()[0][frame],
                                      err_msg=f"frame {frame}")
    _, image, local_shards = local.result()
    _same_shards(plan.shard_dir(f"{tmp}/still"), local_shards)
    np.testing.assert_array_equal(read_exr(plan.frame_path(f"{tmp}/still", STILL)), image)
    _run(readme['merge'])
    np.testing.assert_array_equal(read_exr(f"{tmp}/still.exr"), image)
    shown = _run(readme['status']).stdout
    names = [worker_name(farm.procs.procs[w]) for w in ('worker-a', 'worker-b')]
    assert 'workers: 2' in shown and all(n in shown for n in names), shown
    lines = shown.splitlines()
    for out, tasks in (('shot', 1), ('still', SPLIT + 1)):
        (at,) = [i for i, line in enumerate(lines) if line.endswith(f"-> {tmp}/{out}")]
        assert '  done  ' in lines[at] and f"tasks {tasks}/{tasks} finished (0 failed)" in lines[at + 1], shown
    # The scheduler's dashboard address, and whether it draws (bokeh in the venv) or not.
    import importlib.util
    dashboard = shown.splitlines()[1]
    assert f":{farm.dashboard}/status" in dashboard, shown
    assert ('has no bokeh' in dashboard) == (importlib.util.find_spec('bokeh') is None), dashboard


def _running_marker(out_dir):
    for path in glob.glob(os.path.join(out_dir, plan.STATE_DIR, 'running', '*.json')):
        try:
            with open(path) as handle:
                return json.load(handle)
        except (OSError, ValueError):
            pass  # being written
    return None


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def test_worker_killed_mid_task_and_a_late_worker_finish_the_job(animated_blend, local, tmp_path):
    """A farm whose only worker is SIGKILLed (with its render) mid-shard: the
    job waits, `farm status` shows it stalled, a worker that joins late
    renders the lost shard again and the rest, and the frame is exact."""
    _distributed()
    farm = Farm(tmp_path, animated_blend).start([])
    out = str(tmp_path / 'out')
    try:
        farm.start_worker('victim')  # the client starts meanwhile: its tasks wait for a worker
        client = farm.procs.start('client', farm.render('--frames', STILL, '--samples', SAMPLES,
                                                        '--split-samples', SPLIT, '-o', out))
        lost = wait_for(lambda: _running_marker(out), TIMEOUT, "a shard to start")
        time.sleep(0.2)  # mid-task: its Blender has started
        farm.procs.kill('victim')
        wait_for(lambda: not workers_by_name(farm.client), TIMEOUT, "the scheduler to drop the killed worker")
        assert not _alive(lost['child_pid']), "the killed worker's render is still running"
        stalled = wait_for(lambda: (lambda s: s['jobs'] and s)(farm.status()), TIMEOUT, "the job's record")
        (job,) = stalled['jobs']
        assert stalled['workers'] == [] and job['state'] == 'running', stalled
        assert job['live'] == {'waiting': SPLIT + 1, 'running': 0, 'done': 0, 'failed': 0}, job
        farm.start_worker('late', ['--name', 'late'])
        assert client.wait(timeout=TIMEOUT) == 0, farm.procs.log('client')[-3000:]
    finally:
        farm.close()
    with open(os.path.join(out, plan.STATE_DIR, 'logs', f"{lost['task']}.log")) as handle:
        assert handle.readline().startswith(f"# {lost['task']} on worker late "), "the lost shard was not rerun"
    _, image, local_shards = local.result()
    _same_shards(plan.shard_dir(out), local_shards)
    np.testing.assert_array_equal(read_exr(plan.frame_path(out, STILL)), image)
    assert not os.path.exists(os.path.join(out, plan.STATE_DIR, 'tmp')), "scratch folders left behind"


def _no_render_running(out_dir, quiet=1.0):
    """A condition: no task marker seen for ``quiet`` seconds (a task queued
    on a worker may start just after another ends)."""
    since = None

    def settled():
        nonlocal since
        if glob.glob(os.path.join(out_dir, plan.STATE_DIR, 'running', '*')):
            since = None
            return False
        since = since or time.monotonic()
        return time.monotonic() - since >= quiet
    return settled


def test_client_killed_then_resume_renders_only_missing_frames(farm, local):
    """The client dies once renders run (they finish on their workers, the
    scheduler drops the tasks not started); --resume renders the rest only."""
    out = os.path.join(farm.tmp, 'resume')
    argv = farm.render('--frames', '1-3', '-o', out)
    first = farm.procs.start('first-client', argv)
    wait_for(lambda: _running_marker(out), TIMEOUT, "a first render")
    farm.procs.kill('first-client')
    wait_for(_no_render_running(out), TIMEOUT, "the renders already running to end")
    assert first.returncode == -signal.SIGKILL
    done = {path: os.stat(path).st_mtime_ns for path in glob.glob(os.path.join(out, 'frame_*.exr'))}
    assert 1 <= len(done) < 3, sorted(done)
    states = {j['out_dir']: j['state'] for j in farm.status()['jobs']}
    assert states[out] == 'interrupted', states
    second = _run(argv + ['--resume'])
    missing = [f for f in range(1, 4) if plan.frame_path(out, f) not in done]
    (line,) = [l for l in second.stderr.splitlines() if l.startswith('farm:')]
    assert line.split(': ', 2)[2].split() == [f"ember-chunk-{f}-{f}" for f in missing], line
    assert {path: os.stat(path).st_mtime_ns for path in done} == done, "a frame on disk was rendered again"
    for frame in range(1, 4):
        np.testing.assert_array_equal(read_exr(plan.frame_path(out, frame)), local.result()[0][frame],
                                      err_msg=f"frame {frame}")


@pytest.mark.parametrize('field, wrong, what', [('ember_version', '0.0.0', 'Ember version'),
                                                 ('blender_version', 'bpy 4.2.0', 'Blender'),
                                                 ('blend_sha256', '0' * 64, 'scene hash')])
def test_worker_refuses_a_task_planned_for_another_version(farm, tmp_path, field, wrong, what):
    from farm import client as farm_client
    from farm.versions import blender_version, ember_version
    job = make_job(farm.blend, tmp_path, frames=[1], threads=0, ember_version=ember_version(),
                   blender_version=blender_version('', sys.executable))
    setattr(job, field, wrong)
    written, failures = farm_client.run(farm.client, job, retries=0)
    assert written == [] and len(failures) == 1, (written, failures)
    assert f"refuses chunk-1-1: {what} here is " in failures[0], failures[0]
    assert f"the job was planned with {wrong!r}" in failures[0], failures[0]
    assert not glob.glob(os.path.join(str(tmp_path), plan.STATE_DIR, 'logs', '*')), "Blender was started"
