"""``python -m farm status --scheduler tcp://HOST:8786``: the farm's workers,
its jobs with their tasks and an ETA, and the dashboard's address.

Each client publishes its job on the scheduler (Dask's metadata store, under
``ember-farm/jobs/TOKEN``) and updates it as tasks finish; the live state of
every task (waiting, running and where, finished, failed) comes from the
scheduler's task table.  A job whose client is gone (killed, interrupted)
has no tasks left on the scheduler and is shown as ``interrupted``: run the
same command with --resume."""
import json
import socket
import sys
import time
from urllib.parse import urlparse

META = 'ember-farm'
STATES = ('waiting', 'running', 'done', 'failed')


def publish(client, token, info):
    """Store (or update) one job's record on the scheduler; never fails the job."""
    try:
        client.set_metadata([META, 'jobs', token], dict(info, updated=time.time()))
    except Exception as err:  # noqa: BLE001 - status is a convenience, the render goes on
        print(f"farm: cannot publish the job's status on the scheduler: {err}", file=sys.stderr)


def job_record(job, token, total_tasks, total_work):
    from .plan import format_frames
    return {'token': token, 'blend': job.blend, 'out_dir': job.out_dir, 'frames': format_frames(job.frames),
            'tasks': total_tasks, 'done': 0, 'failed': 0, 'work': total_work, 'work_done': 0,
            'started': time.time(), 'state': 'running', 'client': f"{socket.gethostname()}"}


def scheduler_tasks(client):
    """{task key: (state, worker name or None)} of the farm's tasks on the scheduler."""
    def ember_tasks(dask_scheduler):  # nested: pickled by value, the scheduler needs no farm import
        out = {}
        for key, ts in dask_scheduler.tasks.items():
            if isinstance(key, str) and key.startswith('ember-'):
                worker = ts.processing_on
                out[key] = (ts.state, worker.name if worker is not None else None)
        return out
    return client.run_on_scheduler(ember_tasks)


def _kind(state):
    if state == 'processing':
        return 'running'
    if state == 'memory':
        return 'done'
    if state == 'erred':
        return 'failed'
    return 'waiting'      # released, waiting, queued, no-worker


def gather(client):
    """Everything ``status`` prints, as plain data."""
    info = client.scheduler_info()
    tasks = scheduler_tasks(client)
    running = {}
    for key, (state, worker) in tasks.items():
        if state == 'processing':
            running.setdefault(str(worker), []).append(key)
    workers = [{'name': str(w.get('name')), 'address': address, 'threads': w.get('nthreads'),
                'running': sorted(running.get(str(w.get('name')), []))}
               for address, w in sorted(info.get('workers', {}).items())]
    now = time.time()
    jobs = []
    for token, record in sorted(client.get_metadata([META, 'jobs'], default={}).items(),
                                key=lambda item: item[1].get('started', 0)):
        mine = [state for key, (state, _) in tasks.items() if key.endswith('-' + token)]
        counts = {kind: sum(_kind(s) == kind for s in mine) for kind in STATES}
        state = record.get('state', 'running')
        if state == 'running' and not mine:
            state = 'interrupted'
        elapsed = (record.get('updated', now) if state != 'running' else now) - record.get('started', now)
        fraction = record.get('work_done', 0) / max(record.get('work', 1), 1)
        eta = elapsed / fraction * (1 - fraction) if state == 'running' and fraction > 0 else None
        jobs.append(dict(record, state=state, live=counts, elapsed=elapsed, eta=eta))
    dashboard = info.get('services', {}).get('dashboard')
    host = urlparse(info.get('address', '')).hostname or 'SCHEDULER'
    url = f"http://{host}:{dashboard}/status" if dashboard else None
    return {'scheduler': info.get('address'), 'workers': workers, 'jobs': jobs, 'dashboard': url,
            'dashboard_note': _dashboard_note(url) if url else ''}


def _dashboard_note(url, timeout=2.0):
    """'' if the dashboard draws, else why not: without bokeh the scheduler's
    page only says how to install it."""
    from urllib.request import urlopen
    try:
        with urlopen(url, timeout=timeout) as page:
            text = page.read(4000).decode('utf-8', 'replace')
    except OSError as err:
        return f" (not reachable from here: {err})"
    return " (the scheduler has no bokeh: pip install bokeh there)" if 'needs bokeh' in text else ''


def format_status(data):
    from .client import _clock
    lines = [f"scheduler {data['scheduler']}",
             f"dashboard {data['dashboard'] or 'off'}{data.get('dashboard_note', '')}",
             f"workers: {len(data['workers'])}"]
    for w in data['workers']:
        doing = ', '.join(w['running']) or 'idle'
        lines.append(f"  {w['name']}  {w['address']}  {w['threads']} slot(s)  {doing}")
    lines.append(f"jobs: {len(data['jobs'])}")
    for j in data['jobs']:
        live = j['live']
        eta = _clock(j['eta']) if j['eta'] is not None else '--:--'
        lines.append(f"  {j['token']}  {j['state']}  {j['blend']} frames {j['frames']} -> {j['out_dir']}")
        lines.append(f"      tasks {j['done']}/{j['tasks']} finished ({j['failed']} failed); now {live['running']} "
                     f"running, {live['waiting']} waiting  elapsed {_clock(j['elapsed'])}  ETA {eta}")
    return "\n".join(lines)


def main(address, as_json=False, timeout=10):
    from distributed import Client
    try:
        client = Client(address, timeout=timeout)
    except (OSError, TimeoutError) as err:
        print(f"farm status: cannot reach the scheduler at {address}: {err}", file=sys.stderr)
        return 2
    try:
        data = gather(client)
    finally:
        client.close()
    print(json.dumps(data, indent=1) if as_json else format_status(data))
    return 0
