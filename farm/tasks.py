"""What a Dask worker runs: one Blender subprocess per task.

The render runs in a child process so that a crash (or a segfault in native
code) fails the task, never the worker; the child is killed with its worker
(PR_SET_PDEATHSIG), so a worker killed mid-task leaves no orphan render
behind.  Outputs are renamed into place only when complete, so a frame file
or shard file that exists is whole, and running a task twice (Dask reruns the
tasks of a lost worker) writes the same files again.
"""
import ctypes
import json
import os
import shutil
import signal
import socket
import subprocess
import time
import uuid

from . import plan, shardfile
from .commands import ROOT, render_command
from .merge import merge_to_image
from .versions import check_worker, worker_label

# One render owns the machine's cores through Ember's own thread pool:
# keep BLAS pools in the child from multiplying it.
CHILD_ENV = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}
THREADS_ENV = 'EMBER_FARM_RENDER_THREADS'
LOG_TAIL = 3000


class TaskFailed(RuntimeError):
    """A render subprocess failed; the message carries its log's tail."""


def _die_with_parent():
    try:
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _state_path(job, *parts):
    path = os.path.join(job.out_dir, plan.STATE_DIR, *parts)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return path


def _threads(job):
    return job.threads or int(os.environ.get(THREADS_ENV, '0') or 0)


def run_blender(job, key, frames, out_pattern, shard=None):
    """Run one Blender process; raise TaskFailed with its log on failure."""
    from dataclasses import replace
    cmd = render_command(replace(job, threads=_threads(job)), frames, out_pattern, shard)
    env = dict(os.environ, **CHILD_ENV, **job.extra_env)
    if not job.blender:
        env['PYTHONPATH'] = ROOT
        # bpy's user folder inside the scratch folder: gone with it, also
        # when the task is killed.
        env.setdefault('BLENDER_USER_RESOURCES', os.path.join(os.path.dirname(out_pattern), 'user'))
    log_path = _state_path(job, 'logs', f"{key}.log")
    running = _state_path(job, 'running', f"{key}.{socket.gethostname()}.{os.getpid()}.json")
    with open(log_path, 'w') as log:
        log.write(f"# {key} on {worker_label()}\n")
        log.flush()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=ROOT,
                                preexec_fn=_die_with_parent)
        with open(running, 'w') as marker:
            json.dump({'task': key, 'worker_pid': os.getpid(), 'child_pid': proc.pid,
                       'host': socket.gethostname(), 'started': time.time()}, marker)
        try:
            code = proc.wait()
        finally:
            if proc.poll() is None:
                proc.kill()
            os.unlink(running)
    if code != 0:
        with open(log_path) as log:
            tail = log.read()[-LOG_TAIL:]
        raise TaskFailed(f"{key}: Blender exited with status {code} on {socket.gethostname()}; "
                         f"log {log_path}:\n{tail}")


def _scratch(job, key):
    """A fresh folder for one run of a task (a rerun never sees a stale file)."""
    path = os.path.join(job.out_dir, plan.STATE_DIR, 'tmp', f"{key}-{uuid.uuid4().hex[:8]}")
    os.makedirs(path)
    return path


def run_chunk(job, frames):
    """Render consecutive frames; returns the finished frame files."""
    key = f"chunk-{frames[0]}-{frames[-1]}"
    check_worker(job, key)
    scratch = _scratch(job, key)
    try:
        run_blender(job, key, frames, os.path.join(scratch, 'frame_####'))
        done = []
        for frame in frames:
            made = os.path.join(scratch, f"frame_{frame:04d}.exr")
            if not os.path.isfile(made):
                raise TaskFailed(f"{key}: Blender exited cleanly but wrote no image for frame {frame}")
            target = plan.frame_path(job.out_dir, frame)
            os.replace(made, target)
            done.append(target)
        return done
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_shard(job, frame, start, end):
    """Render sample indices [start, end) of one frame; returns its state files."""
    key = f"shard-{frame}-s{start}-{end}"
    check_worker(job, key)
    scratch = _scratch(job, key)
    folder = plan.shard_dir(job.out_dir)
    try:
        run_blender(job, key, [frame], os.path.join(scratch, 'frame_####'), (folder, start, end - start))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    files = shardfile.find(folder, frame, start, end)
    if not files:
        raise TaskFailed(f"{key}: Blender exited cleanly but saved no film state in {folder}")
    for path in files:
        meta = shardfile.read_meta(path)
        if meta.get('blend_sha256') != job.blend_sha256:
            raise TaskFailed(f"{key}: the worker rendered a different {job.blend} (hash "
                             f"{meta.get('blend_sha256')}, job {job.blend_sha256}): is the shared storage in sync?")
        if job.ember_version and meta.get('ember_version') != job.ember_version:
            # A Blender binary renders with its installed add-on, which may not be the checkout's.
            raise TaskFailed(f"{key}: rendered by Ember {meta.get('ember_version')} on {socket.gethostname()}, "
                             f"the job was planned with Ember {job.ember_version} (update the add-on "
                             f"installed in {job.blender or 'the bpy module'})")
    return files


def run_merge(job, frame, *_shards):
    """Merge the planned shards of one frame (each view layer apart) into its
    image.  The shard results are only dependencies: the files are found
    by the plan, so shards kept from an earlier run count too."""
    check_worker(job, f"merge-{frame}", renders=False)
    ranges = plan.sample_ranges(job.samples, job.split)
    layers = {}
    for start, end in ranges:
        for path in shardfile.find(plan.shard_dir(job.out_dir), frame, start, end):
            layers.setdefault(path.rsplit('.', 2)[-2], []).append(path)
    if not layers:
        raise TaskFailed(f"merge of frame {frame}: no shards found")
    written = []
    expect = {'blend_sha256': job.blend_sha256, 'frame': frame, 'ember_version': job.ember_version or None}
    for layer, paths in sorted(layers.items()):
        target = plan.frame_path(job.out_dir, frame, layer if len(layers) > 1 else None)
        merge_to_image(paths, target, plan=ranges, expect=expect)
        written.append(target)
    return written
