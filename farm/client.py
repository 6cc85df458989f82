"""The farm client: plans a job, skips what is done (--resume), submits the
rest to a Dask scheduler with retries, draws a progress bar with an ETA and
reports failures.  A worker lost mid-task (killed, crashed, unplugged) has
its tasks rerun elsewhere by the scheduler; a task that raises is retried
``retries`` times."""
import glob
import hashlib
import json
import os
import shutil
import sys
import time
import uuid

from . import plan, shardfile, status

RETRIES = 2


def blend_hash(path):
    digest = hashlib.sha256()
    with open(path, 'rb') as handle:
        for block in iter(lambda: handle.read(1 << 20), b''):
            digest.update(block)
    return digest.hexdigest()


def frame_done(job, frame):
    return bool(os.path.isfile(plan.frame_path(job.out_dir, frame))
                or glob.glob(os.path.join(job.out_dir, f"frame_{frame:04d}.*.exr")))


def shard_done(job, frame, start, end):
    files = shardfile.find(plan.shard_dir(job.out_dir), frame, start, end)
    try:
        return bool(files) and all(shardfile.read_meta(p).get('blend_sha256') == job.blend_sha256
                                   for p in files)
    except (OSError, ValueError, KeyError):
        return False


def pending(job, resume=False):
    """The tasks left to run: all of them, or with ``resume`` those whose
    frames and shards are not on disk yet."""
    if not resume:
        return plan.tasks(job)
    left = [f for f in job.frames if not frame_done(job, f)]
    if job.split <= 1:
        return [plan.Task('chunk', tuple(run)) for run in plan.chunks(left, job.chunk)] if left else []
    out = []
    for frame in left:
        out += [plan.Task('shard', (frame,), a, b) for a, b in plan.sample_ranges(job.samples, job.split)
                if not shard_done(job, frame, a, b)]
        out.append(plan.Task('merge', (frame,)))
    return out


def manifest_path(job):
    return os.path.join(job.out_dir, plan.STATE_DIR, 'job.json')


def check_manifest(job, resume):
    """Record what the job renders; --resume refuses to mix two jobs' outputs."""
    path = manifest_path(job)
    if resume and os.path.isfile(path):
        with open(path) as handle:
            old = json.load(handle)
        new = job.fingerprint()
        # Keys an older manifest lacks (the versions, before issue 28) are not compared.
        changed = sorted(k for k in old if k in new and old[k] != new[k])
        if changed:
            raise SystemExit(f"--resume: {job.out_dir} holds a different job (changed: {', '.join(changed)}); "
                             "use another output folder or drop --resume")
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = path + f".{os.getpid()}.tmp"
    with open(tmp, 'w') as handle:
        json.dump(job.fingerprint(), handle)
    os.replace(tmp, path)


def submit(client, job, todo, retries=RETRIES, token=None):
    """Futures of the tasks, merges depending on their frame's shards.  Keys
    end in the job's ``token`` (``python -m farm status`` groups by it)."""
    from . import tasks as run
    token = token or uuid.uuid4().hex[:8]
    futures, shards = [], {}
    for task in todo:
        key = f"{task.key}-{token}"
        if task.kind == 'chunk':
            fut = client.submit(run.run_chunk, job, list(task.frames), key=key, retries=retries, pure=False)
        elif task.kind == 'shard':
            fut = client.submit(run.run_shard, job, task.frames[0], task.start, task.end, key=key,
                                retries=retries, pure=False)
            shards.setdefault(task.frames[0], []).append(fut)
        else:
            fut = client.submit(run.run_merge, job, task.frames[0], *shards.get(task.frames[0], []), key=key,
                                retries=retries, pure=False)
        futures.append((task, fut))
    return futures


def weight(job, task):
    """Work in frame-samples, for the ETA (a merge is nearly free)."""
    if task.kind == 'chunk':
        return len(task.frames) * max(job.samples, 1)
    if task.kind == 'shard':
        return task.end - task.start
    return 0


class ProgressBar:
    def __init__(self, total_tasks, total_work, stream=sys.stderr, width=30):
        self.total_tasks, self.total_work = total_tasks, max(total_work, 1)
        self.tasks = self.work = 0
        self.stream, self.width = stream, width
        self.started = time.monotonic()

    def update(self, work):
        self.tasks += 1
        self.work += work
        elapsed = time.monotonic() - self.started
        fraction = self.work / self.total_work
        eta = elapsed / fraction * (1 - fraction) if fraction > 0 else float('nan')
        filled = int(self.width * fraction)
        end = "\n" if self.tasks == self.total_tasks else ""
        self.stream.write(f"\r[{'#' * filled}{'-' * (self.width - filled)}] {self.tasks}/{self.total_tasks} tasks"
                          f"  {_clock(elapsed)} elapsed  ETA {_clock(eta)}{end}")
        self.stream.flush()


def _clock(seconds):
    if seconds != seconds:
        return "--:--"
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def run(client, job, resume=False, stream=sys.stderr, retries=RETRIES):
    """Render the job; returns (written files, failures)."""
    from distributed import as_completed
    check_manifest(job, resume)
    todo = pending(job, resume)
    print(f"farm: {len(todo)} tasks to run: {' '.join(t.key for t in todo) or '(nothing left)'}",
          file=stream, flush=True)
    if todo and not client.scheduler_info().get('workers'):
        print("farm: no workers yet: start some with `python -m farm worker ADDRESS`", file=stream, flush=True)
    token = uuid.uuid4().hex[:8]
    futures = submit(client, job, todo, retries, token)
    by_future = {fut.key: task for task, fut in futures}
    bar = ProgressBar(len(futures), sum(weight(job, t) for t, _ in futures), stream)
    record = status.job_record(job, token, bar.total_tasks, bar.total_work)
    status.publish(client, token, record)
    written, failures = [], []
    for fut in as_completed([f for _, f in futures]):
        task = by_future[fut.key]
        if fut.status == 'finished':
            if task.kind != 'shard':  # shards are intermediate files
                written += fut.result()
        else:
            failures.append(f"{task.key}: {fut.exception()}")
        bar.update(weight(job, task))
        record.update(done=bar.tasks, failed=len(failures), work_done=bar.work)
        status.publish(client, token, record)
    record['state'] = 'failed' if failures else 'done'
    status.publish(client, token, record)
    if not failures:
        # Scratch folders and markers of tasks killed on the way.
        for name in ('tmp', 'running'):
            shutil.rmtree(os.path.join(job.out_dir, plan.STATE_DIR, name), ignore_errors=True)
    return written, failures
