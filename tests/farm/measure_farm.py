"""Wall time of one farm job with 1 and with 2 workers, and what losing a
worker mid-task costs, on this machine with real processes (a `dask
scheduler`, `python -m farm worker`s, a `python -m farm render` client):

    .venv/bin/python tests/farm/measure_farm.py [--size 64] [--samples 32] [--frames 1-4] [--split 2]

Not a test (pytest does not collect it): numbers for docs/benchmarks.md.
The load average is printed with each run: on a shared machine it is the
largest source of variation."""
import argparse
import glob
import json
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(os.path.dirname(HERE)), os.path.dirname(HERE), HERE]

from farmlib import make_animation  # noqa: E402
from proclib import Processes, checkout_env, free_port, wait_for, wait_for_port, workers_by_name  # noqa: E402


def farm(tmp, workers):
    import distributed
    port = free_port()
    procs = Processes(tmp, checkout_env())
    sched = procs.start('scheduler', [os.path.join('.venv', 'bin', 'dask'), 'scheduler', '--port', str(port),
                                      '--dashboard-address', f":{free_port()}"])
    wait_for_port(port, 120, sched)
    address = f"tcp://127.0.0.1:{port}"
    client = distributed.Client(address, timeout=60)
    names = [f"w{i}" for i in range(workers)]
    for name in names:
        procs.start(name, [sys.executable, '-m', 'farm', 'worker', address, '--name', name])
    wait_for(lambda: set(names) <= set(workers_by_name(client)), 120, "the workers")
    return procs, client, address


def markers(out):
    found = []
    for path in glob.glob(os.path.join(out, '.farm', 'running', '*.json')):
        try:
            with open(path) as handle:
                found.append(json.load(handle))
        except (OSError, ValueError):
            pass
    return found


def run(args, blend, tmp, workers, kill_after=None):
    procs, client, address = farm(tmp, workers)
    out = os.path.join(tmp, 'out')
    try:
        started = time.monotonic()
        job = procs.start('client', [sys.executable, '-m', 'farm', 'render', blend, '--frames', args.frames,
                                     '--samples', str(args.samples), '--split-samples', str(args.split),
                                     '--scheduler', address, '-o', out])
        lost = None
        if kill_after is not None:
            # Kill the worker of the (kill_after+1)-th task to start, kill_delay seconds into it.
            order, running = [], {}
            while len(order) <= kill_after:
                for marker in markers(out):
                    running[marker['task']] = marker
                    if marker['task'] not in order:
                        order.append(marker['task'])
                time.sleep(0.05)
            lost = running[order[kill_after]]
            time.sleep(args.kill_delay)
            (worker,) = [n for n, p in procs.procs.items() if n.startswith('w') and _owns(p.pid, lost['worker_pid'])]
            lost.update(ran_for=time.time() - lost['started'], worker=worker, key=lost['task'])
            procs.kill(worker)
        code = job.wait(timeout=1800)
        wall = time.monotonic() - started
        assert code == 0, procs.log('client')[-3000:]
        return wall, lost
    finally:
        client.close()
        procs.close()


def _owns(group_leader, pid):
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return int(handle.read().rsplit(')', 1)[1].split()[3]) == group_leader  # pgrp
    except OSError:
        return False


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument('--size', type=int, default=64)
    parser.add_argument('--samples', type=int, default=32)
    parser.add_argument('--frames', default='1-4')
    parser.add_argument('--split', type=int, default=2)
    parser.add_argument('--kill-delay', type=float, default=2.0, help="seconds into the killed task")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix='ember-farm-timing-') as tmp:
        blend = make_animation(os.path.join(tmp, 'anim.blend'), size=args.size, samples=args.samples)
        print(f"job: frames {args.frames} x {args.split} shards, {args.size}x{args.size}, {args.samples} spp")
        for workers, kill in ((1, None), (2, None), (2, 2)):
            folder = tempfile.mkdtemp(dir=tmp)
            load = os.getloadavg()[0]
            wall, lost = run(args, blend, folder, workers, kill)
            what = f"{workers} worker(s)" + (", one SIGKILLed mid-task" if kill is not None else "")
            print(f"{what}: {wall:.1f} s wall (load average {load:.1f} before, {os.getloadavg()[0]:.1f} after)")
            if lost:
                print(f"  lost: {lost['key']} on {lost['worker']} after {lost['ran_for']:.1f} s of rendering "
                      f"(that task rendered again on the other worker)")
            sys.stdout.flush()


if __name__ == '__main__':
    main()
