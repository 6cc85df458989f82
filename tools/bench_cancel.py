"""Cancel latency and progress of a 1920x1080 render in a real Blender binary.

Blender in background mode has no Esc key, but it has the same flag: its
SIGINT handler sets G.is_break, which is what RenderEngine.test_break()
reads (Blender prints "Sent an internal break event").  This tool starts
`blender -b` with the Ember add-on (legacy zip) on a scene with a 2-million-
triangle grid, sends SIGINT after a chosen delay, and reads the timestamps a
probe script inside Blender records: when each phase (export, scene
preparation with the BVH build, each pass) started, when Ember saw the
break, and when render() returned.  Latency = render() returned - SIGINT sent.

    python -P tools/bench_cancel.py                      # delays 0.5 1 2 3 5 s
    python -P tools/bench_cancel.py --delays 0.2 4 --triangles 200000

Prints one line per delay plus the phase the signal landed in, and checks
that progress and time-left never went backwards.  --json writes the rows.
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLENDER = shutil.which('blender') or '/usr/bin/blender'

# Runs inside Blender after the add-on is enabled: wraps the add-on's phases
# and writes {events, progress, break_seen} to $EMBER_CANCEL_LOG when render() returns.
PROBE = r'''
import importlib, json, os, time, bpy
pkg = 'ember'
out = importlib.import_module(pkg + '.output')
eng = importlib.import_module(pkg + '.engine')
exp = importlib.import_module(pkg + '.export.scene')
LOG = {'events': [], 'progress': [], 'break_seen': None}
PATH = os.environ['EMBER_CANCEL_LOG']

def event(name):
    LOG['events'].append([name, time.time()])

PHASE = os.environ.get('EMBER_CANCEL_PHASE', '')

def interrupt_later():
    """Tell the parent that PHASE has begun: it sends SIGINT from outside
    (a timer thread here would wait for the GIL that a long foreach_get holds,
    while Blender's Esc does not)."""
    with open(PATH + '.phase', 'w') as f:
        f.write(str(time.time()))

def timed(module, name, label):
    real = getattr(module, name)
    def wrapper(*args, **kwargs):
        event(label + '_start')
        if label == PHASE:
            interrupt_later()
        try:
            return real(*args, **kwargs)
        finally:
            event(label + '_end')
            if label == 'prepare' and PHASE == 'passes':
                interrupt_later()  # DELAY s into the first pass
    setattr(module, name, wrapper)

timed(exp, 'export_scene', 'export')
backend = importlib.import_module(pkg + '.backend')
render_module = importlib.import_module(backend.engine().__name__ + '.render')  # the module
timed(render_module, 'prepare', 'prepare')
real_on_pass = out.Progress.on_pass
def on_pass(self, image, samples_done, stats):
    real_on_pass(self, image, samples_done, stats)
    LOG['progress'].append([time.time(), samples_done, stats.get('samples_total'),
                            getattr(self, 'shown_seconds_left', stats.get('seconds_left'))])
out.Progress.on_pass = on_pass
real_break = out.break_requested
def break_requested(engine):
    seen = real_break(engine)
    if seen and LOG['break_seen'] is None:
        LOG['break_seen'] = time.time()
    return seen
out.break_requested = break_requested

real_render = eng.EmberRenderEngine.render
def render(self, depsgraph):
    event('render_start')
    with open(PATH + '.started', 'w') as f:
        f.write(str(time.time()))
    try:
        return real_render(self, depsgraph)
    finally:
        event('render_end')
        LOG['cpu_end'] = time.process_time()  # all threads of this Blender
        LOG['log'] = {k: v for k, v in eng.RENDER_LOG[-1].items() if k in ('error', 'samples', 'cancelled', 'passes')}
        with open(PATH, 'w') as f:
            json.dump(LOG, f)
eng.EmberRenderEngine.render = render

scene = bpy.context.scene
scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
scene.render.resolution_percentage = 100
scene.ember.samples = int(os.environ.get('EMBER_CANCEL_SAMPLES', '64'))
scene.ember.max_bounces = 4
triangles = int(os.environ.get('EMBER_CANCEL_TRIANGLES', '0'))
if triangles:
    side = max(1, int((triangles / 2) ** 0.5))
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=side, y_subdivisions=side, size=0.5, location=(0, 0, 0.5))
event('ready')
'''


def install_addon(zip_path, folder):
    scripts = os.path.join(folder, 'scripts')
    addons = os.path.join(scripts, 'addons')
    os.makedirs(addons)
    with zipfile.ZipFile(zip_path) as archive:
        archive.extractall(addons)
    for path, _, files in os.walk(addons):
        for name in files:
            if '.so' in name:
                os.chmod(os.path.join(path, name), 0o755)
    return scripts


def build_legacy_zip(folder):
    sys.path.insert(0, os.path.join(ROOT, 'tools'))
    import build_zip
    return build_zip.main(['--dist', folder, '--build', os.path.join(folder, 'build'),
                           '--wheels', os.path.join(ROOT, 'build', 'wheels'), '--legacy'])[0]


def run_once(scripts, delay, folder, triangles, samples, scene, phase=None, timeout=300):
    """One render cancelled `delay` s after render() started, or, with
    `phase` ('export', 'prepare' or 'passes' = after the first pass), `delay`
    s after that phase began;
    returns a dict of timings (delay=None: render to the end)."""
    log_path = tempfile.mktemp(prefix=f'cancel_{phase}_{delay}_', suffix='.json', dir=folder)
    probe = os.path.join(folder, 'probe.py')
    with open(probe, 'w') as f:
        f.write(PROBE)
    env = dict(os.environ, BLENDER_USER_SCRIPTS=scripts, EMBER_CANCEL_LOG=log_path,
               EMBER_CANCEL_TRIANGLES=str(triangles), EMBER_CANCEL_SAMPLES=str(samples),
               EMBER_CANCEL_PHASE=phase or '', EMBER_CANCEL_DELAY=str(delay or 0))
    env.pop('PYTHONPATH', None)
    cmd = [BLENDER, '-b', '--addons', 'ember', scene, '-E', 'EMBER', '--python', probe,
           '-o', os.path.join(folder, 'frame_####'), '-F', 'PNG', '-f', '1']
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    started = time.time()
    sent = cpu_sent = None
    try:
        if delay is not None:
            # Count the delay from the moment render() (or the phase) starts: the probe marks it.
            marker = log_path + ('.phase' if phase else '.started')
            while not os.path.exists(marker) and proc.poll() is None:
                if time.time() - started > timeout:
                    raise subprocess.TimeoutExpired(cmd, timeout)
                time.sleep(0.002)
            time.sleep(delay)
            sent = time.time()
            proc.send_signal(signal.SIGINT)
            cpu_sent = process_cpu_seconds(proc.pid)
        rest, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return {'delay': delay, 'error': f'no exit within {timeout} s'}
    exited = time.time()
    if not os.path.exists(log_path):
        return {'delay': delay, 'error': 'no probe log: ' + (rest or '')[-1500:]}
    with open(log_path) as f:
        log = json.load(f)
    row = summarize(log, delay, sent, exited, proc.returncode)
    row['phase_requested'] = phase
    if cpu_sent is not None and log.get('cpu_end') is not None:
        # CPU seconds Blender spent between the signal and render() returning:
        # what the latency would be on idle cores (wall time grows with load).
        row['cpu_latency_s'] = log['cpu_end'] - cpu_sent
    return row


def process_cpu_seconds(pid):
    """User + system CPU time of a process so far (all its threads)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def phase_at(events, moment):
    """The phase ('export', 'prepare' (BVH), 'passes') running at `moment`."""
    times = dict((name, t) for name, t in events)
    for phase in ('export', 'prepare'):
        start, end = times.get(phase + '_start'), times.get(phase + '_end')
        if start is not None and start <= moment and (end is None or moment <= end):
            return phase
    if times.get('prepare_end') and moment > times['prepare_end']:
        return 'passes'
    return 'before export'


def summarize(log, delay, sent, exited, returncode):
    events = log['events']
    times = dict((name, t) for name, t in events)
    progress = log['progress']
    fractions = [done / max(total or 1, 1) for _, done, total, _ in progress]
    lefts = [left for *_, left in progress if left is not None]
    row = {
        'delay': delay, 'returncode': returncode,
        'export_s': _span(times, 'export'), 'prepare_s': _span(times, 'prepare'),
        'passes': len(progress), 'samples': log.get('log', {}).get('samples'),
        'cancelled': log.get('log', {}).get('cancelled'), 'error': log.get('log', {}).get('error'),
        'progress_monotone': all(b >= a for a, b in zip(fractions, fractions[1:])),
        'time_left_monotone': all(b <= a for a, b in zip(lefts, lefts[1:])),
        'render_s': times['render_end'] - times['render_start'],
    }
    if sent is not None:
        row['phase'] = phase_at(events, sent)
        row['latency_s'] = times['render_end'] - sent
        row['break_seen_after_s'] = (log['break_seen'] - sent) if log['break_seen'] else None
        row['exit_after_s'] = exited - sent
        if progress:
            row['last_pass_after_s'] = progress[-1][0] - sent
    return row


def _span(times, phase):
    start, end = times.get(phase + '_start'), times.get(phase + '_end')
    return round(end - start, 3) if start and end else None


def measure(scripts, folder, phases, delays, triangles, samples, scene, full_render=False):
    rows = []
    for phase in phases:
        for delay in delays:
            rows.append(run_once(scripts, delay, folder, triangles, samples, scene, phase or None))
    if full_render:
        rows.append(run_once(scripts, None, folder, triangles, samples, scene))
    return rows


def report(rows, triangles):
    latencies = [r['latency_s'] for r in rows if r.get('latency_s') is not None]
    if not latencies:
        return "no cancel measured"
    by_phase = {}
    for r in rows:
        if r.get('latency_s') is not None:
            by_phase.setdefault(r['phase'], []).append(r['latency_s'])
    parts = ", ".join(f"{phase} max {max(v):.2f} s (n={len(v)})" for phase, v in sorted(by_phase.items()))
    cpu = [r['cpu_latency_s'] for r in rows if r.get('cpu_latency_s') is not None]
    if cpu:
        parts += f"; CPU seconds from signal to return: max {max(cpu):.2f}"
    return (f"cancel latency at 1920x1080 with {triangles} triangles in Blender's binary: "
            f"max {max(latencies):.2f} s over {len(latencies)} cancels; {parts}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--delays', type=float, nargs='*', default=[0.2, 0.6])
    parser.add_argument('--phases', nargs='*', default=['export', 'prepare', 'passes'],
                        help="cancel `delay` s into each of these phases ('' = from render() start)")
    parser.add_argument('--triangles', type=int, default=1_000_000)
    parser.add_argument('--samples', type=int, default=64)
    parser.add_argument('--scene', default=os.path.join(ROOT, 'blend_scenes', 'cornell.blend'))
    parser.add_argument('--zip', help="a built legacy add-on zip (default: build one)")
    parser.add_argument('--full-render', action='store_true', help="also render once to the end")
    parser.add_argument('--json', help="write the rows here")
    args = parser.parse_args(argv)
    folder = tempfile.mkdtemp(prefix='ember-cancel-')
    scripts = install_addon(args.zip or build_legacy_zip(folder), folder)
    rows = measure(scripts, folder, args.phases, args.delays, args.triangles, args.samples, args.scene,
                   args.full_render)
    for row in rows:
        print(json.dumps(row), flush=True)
    print(report(rows, args.triangles))
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
