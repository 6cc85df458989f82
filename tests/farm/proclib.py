"""A farm of real processes on loopback for the tests: a `dask scheduler`
and `python -m farm worker` processes started as a user starts them, each in
its own process group so that it is ended, with everything it started, by
its id; the README's farm commands, parsed out of README.md."""
import os
import re
import shlex
import signal
import socket
import subprocess
import time

from farmlib import ROOT

VENV_BIN = os.path.join(ROOT, '.venv', 'bin')


def free_port():
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def checkout_env():
    """The environment of every farm process: this checkout on the path,
    unless `make setup` put it there already (ember-checkout.pth), in which
    case the test runs exactly what a user runs."""
    import site
    pth = [os.path.join(d, 'ember-checkout.pth') for d in site.getsitepackages()]
    on_path = any(os.path.isfile(p) and open(p).read().strip() == ROOT for p in pth)
    # NumPy kernels in these Blenders: what runs here is the farm's own code
    # (the kernels are the same either way and tested in tests/engine), and
    # loading numba costs about 1.5 CPU-s in each of the ~10 Blender processes.
    env = dict(os.environ, EMBER_JIT='0')
    if not on_path:
        env['PYTHONPATH'] = os.pathsep.join(p for p in (ROOT, env.get('PYTHONPATH')) if p)
    return env


def readme_farm_commands():
    """The commands of the README's render-farm block: argv lists, in order."""
    with open(os.path.join(ROOT, 'README.md')) as handle:
        text = handle.read()
    section = text.split('### Render farm', 1)[1]
    block = re.search(r'```sh\n(.*?)```', section, re.S).group(1)
    return [shlex.split(line, comments=True) for line in block.replace('\\\n', ' ').splitlines()
            if line.strip() and not line.lstrip().startswith('#')]


def substitute(argv, values):
    """argv with every placeholder of ``values`` replaced (as a substring)."""
    out = []
    for arg in argv:
        for old, new in values.items():
            arg = arg.replace(old, new)
        out.append(arg)
    return out


class Processes:
    """Processes of one test farm; ``close`` ends all of them by id."""

    def __init__(self, log_dir, env):
        self.log_dir, self.env, self.procs = str(log_dir), env, {}

    def start(self, name, argv):
        log = open(os.path.join(self.log_dir, f"{name}.log"), 'w')
        proc = subprocess.Popen(argv, cwd=ROOT, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        log.close()
        self.procs[name] = proc
        return proc

    def log(self, name):
        with open(os.path.join(self.log_dir, f"{name}.log")) as handle:
            return handle.read()

    def kill(self, name, sig=signal.SIGKILL):
        """Signal the process group of ``name`` (it and its children)."""
        proc = self.procs[name]
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        if sig == signal.SIGKILL:
            proc.wait(timeout=30)

    def close(self):
        for name, proc in self.procs.items():
            if proc.poll() is None:
                self.kill(name, signal.SIGTERM)
        deadline = time.monotonic() + 15
        for name, proc in self.procs.items():
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            self.kill(name)  # the group too: a worker's render may outlive it


def wait_for(condition, timeout, what, poll=0.05):
    """condition() until truthy, or AssertionError after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def wait_for_port(port, timeout, proc):
    def listening():
        assert proc.poll() is None, f"the process exited with status {proc.returncode}"
        with socket.socket() as sock:
            return sock.connect_ex(('127.0.0.1', port)) == 0
    wait_for(listening, timeout, f"a listener on port {port}")


def workers_by_name(dask_client):
    return {w['name']: a for a, w in dask_client.scheduler_info()['workers'].items()}


def worker_name(proc):
    """The name `python -m farm worker` gives itself: ember-HOST-PID."""
    return f"ember-{socket.gethostname()}-{proc.pid}"
