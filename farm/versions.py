"""What a job was planned with and what a worker has: Ember's version, the
Blender that renders (the bpy module's version, or the binary's) and the
scene's hash.  The client records them in the Job; every task checks them on
its worker before it starts Blender, so a machine with another checkout,
another Blender or an out-of-sync copy of the .blend refuses the task with a
message that names both values, instead of rendering frames (or shards) that
do not belong together.  The Ember version checked first is the worker's
checkout's; a Blender binary renders with its installed add-on instead, so
each shard's recorded version is checked again after the render and by the
merge (a whole frame rendered by a binary carries no version to check)."""
import functools
import hashlib
import os
import re
import socket
import subprocess
import sys

from .commands import ROOT


class WorkerMismatch(RuntimeError):
    """This worker cannot render the job as the client planned it."""


def ember_version(root=ROOT):
    """'0.1.0' from addon/version.py of the checkout (without importing the
    add-on, which needs bpy)."""
    with open(os.path.join(root, 'addon', 'version.py')) as handle:
        match = re.search(r'^VERSION\s*=\s*\(([^)]*)\)', handle.read(), re.M)
    if not match:
        raise WorkerMismatch(f"cannot read VERSION from {root}/addon/version.py")
    return '.'.join(part.strip() for part in match.group(1).split(',') if part.strip())


@functools.lru_cache(maxsize=8)
def _blender_version(blender, python, stamp):
    """Cached per program and its file's (size, mtime): a worker asks once."""
    if blender:
        cmd = [blender, '-b', '--factory-startup', '--version']
    else:
        cmd = [python or sys.executable, '-c',
               "import importlib.metadata as m; print('bpy', m.version('bpy'))"]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise WorkerMismatch(f"cannot run {cmd[0]} to read its version: {err}") from None
    for line in out.stdout.splitlines():
        if line.startswith(('Blender ', 'bpy ')):
            return line.strip()
    raise WorkerMismatch(f"{cmd[0]} printed no version (status {out.returncode}): "
                         f"{(out.stdout + out.stderr)[-500:]}")


def blender_version(blender='', python=''):
    """'Blender 3.4.1' (a binary) or 'bpy 5.0.1' (the bpy module of ``python``)."""
    program = blender or python or sys.executable
    try:
        stat = os.stat(program)
    except OSError as err:
        raise WorkerMismatch(f"{program}: {err.strerror}") from None
    return _blender_version(blender, python, (program, stat.st_size, stat.st_mtime_ns))


@functools.lru_cache(maxsize=32)
def _file_hash(path, stamp):
    digest = hashlib.sha256()
    with open(path, 'rb') as handle:
        for block in iter(lambda: handle.read(1 << 20), b''):
            digest.update(block)
    return digest.hexdigest()


def scene_hash(path):
    """sha256 of the .blend, cached per (path, size, mtime)."""
    try:
        stat = os.stat(path)
    except OSError as err:
        raise WorkerMismatch(f"cannot read the scene {path}: {err.strerror}") from None
    return _file_hash(path, (stat.st_size, stat.st_mtime_ns))


def worker_label():
    """'worker NAME (pid P) on HOST' inside a Dask worker, else 'HOST (pid P)'."""
    try:
        from distributed import get_worker
        return f"worker {get_worker().name} (pid {os.getpid()}) on {socket.gethostname()}"
    except (ImportError, ValueError):
        return f"{socket.gethostname()} (pid {os.getpid()})"


def check_worker(job, task, renders=True):
    """Raise WorkerMismatch if this machine differs from what the job expects.
    ``renders=False`` (a merge: no Blender, no .blend read; it checks each
    shard's recorded hash instead) checks the Ember version only."""
    found = [('Ember version', job.ember_version, ember_version)]
    if renders:
        found += [('Blender', job.blender_version, lambda: blender_version(job.blender, job.python)),
                  ('scene hash', job.blend_sha256, lambda: scene_hash(job.blend))]
    for what, expected, measure in found:
        if not expected:
            continue  # a job made without this check (older client, tests)
        here = measure()
        if here != expected:
            raise WorkerMismatch(
                f"{worker_label()} refuses {task}: {what} here is {here!r}, the job was planned with {expected!r}"
                f"{_advice(what, job)}")


def _advice(what, job):
    if what == 'scene hash':
        return f" ({job.blend} differs from the client's copy: is the shared storage in sync?)"
    if what == 'Ember version':
        return f" (update the checkout {ROOT} on this machine, or the client's)"
    return " (install the same Blender / bpy on every machine)"
