"""``python -m farm worker tcp://HOST:8786``: a Dask worker with one render
slot.  It takes one task at a time (one thread) and lets that task's render
use every core (``--render-threads`` to cap it); the worker process runs
under a nanny, which restarts it if it dies."""
import os
import socket

from .commands import ROOT
from .tasks import THREADS_ENV


def worker_args(address, name=None, render_threads=0, local_directory=None):
    args = [address, '--nworkers', '1', '--nthreads', '1',
            '--name', name or f"ember-{socket.gethostname()}-{os.getpid()}"]
    if local_directory:
        args += ['--local-directory', local_directory]
    return args


def main(address, name=None, render_threads=0, local_directory=None):
    from distributed.cli.dask_worker import main as dask_worker
    os.environ[THREADS_ENV] = str(render_threads)
    # Tasks are farm.tasks functions: the worker must import this checkout.
    os.environ['PYTHONPATH'] = os.pathsep.join(p for p in (ROOT, os.environ.get('PYTHONPATH')) if p)
    dask_worker.main(args=worker_args(address, name, render_threads, local_directory), prog_name='farm worker')
