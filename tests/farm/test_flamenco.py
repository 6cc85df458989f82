"""The Flamenco job type farm/flamenco/ember.js, compiled under Node with
stand-ins for Flamenco's ``author`` API (flamenco_harness.js)."""
import json
import os
import shutil
import subprocess
import sys

import pytest

from farmlib import ROOT, require

SCRIPT = os.path.join(ROOT, 'farm', 'flamenco', 'ember.js')
HARNESS = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'flamenco_harness.js')


def compile_job(**settings):
    node = shutil.which('node')
    require(node is not None, "Node.js is needed to test the Flamenco job type (tools/setup_test_env.sh)")
    settings.setdefault('render_output_root', '/farm/out')
    settings.setdefault('blendfile', '/farm/scene.blend')
    out = subprocess.run([node, HARNESS, SCRIPT, json.dumps(settings)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def args_of(task):
    (command,) = task['commands']
    return command['parameters']['args']


def option(args, name):
    return args[args.index(name) + 1]


def test_frame_chunks():
    job = compile_job(frames='1-5,9', chunk_size=2, samples=16)
    assert [t['name'] for t in job['tasks']] == ['render-1-2', 'render-3-4', 'render-5-5', 'render-9-9']
    assert [option(args_of(t), '--render-frame') for t in job['tasks']] == ['1..2', '3..4', '5', '9']
    first = job['tasks'][0]
    assert first['type'] == 'blender' and first['dependencies'] == []
    params = first['commands'][0]['parameters']
    assert params['exe'] == '{blender}' and params['blendfile'] == '/farm/scene.blend'
    args = args_of(first)
    assert option(args, '-E') == 'EMBER' and option(args, '--render-output') == '/farm/out/frame_####'
    code = option(args, '--python-expr')
    assert "s.ember.samples = 16" in code and "color_depth = '32'" in code and 'EMBER_SHARD' not in code
    compile(code, 'python-expr', 'exec')  # valid Python


def test_split_samples_shards_then_merge():
    job = compile_job(frames='3-4', samples=10, split_samples=3, render_threads=2)
    names = [t['name'] for t in job['tasks']]
    assert names == ['shard-3-s0-3', 'shard-3-s3-6', 'shard-3-s6-10', 'merge-3',
                     'shard-4-s0-3', 'shard-4-s3-6', 'shard-4-s6-10', 'merge-4']
    shard = job['tasks'][2]
    code = option(args_of(shard), '--python-expr')
    compile(code, 'python-expr', 'exec')
    for line in ("os.environ['EMBER_SHARD_START'] = '6'", "os.environ['EMBER_SHARD_SAMPLES'] = '4'",
                 "s.ember.samples = 10", "s.ember.threads = 2", 'EMBER_SHARD_DIR\'] = "/farm/out/shards"'):
        assert line in code
    assert option(args_of(shard), '--render-frame') == '3'
    merge = job['tasks'][3]
    assert merge['dependencies'] == ['shard-3-s0-3', 'shard-3-s3-6', 'shard-3-s6-10']
    assert merge['commands'][0]['name'] == 'exec'
    margs = merge['commands'][0]['parameters']['args']
    assert margs[2:] == ['merge', '/farm/out/shards/frame_000003.s*.npz', '--plan', '0-3,3-6,6-10',
                         '-o', '/farm/out/frame_0003.exr']
    assert job['tasks'][-1]['name'] == 'merge-4'


@pytest.mark.parametrize('settings, message', [
    ({'frames': '5-1'}, 'ends before'),
    ({'frames': 'x'}, 'bad frame range'),
    ({'frames': '1', 'split_samples': 4, 'samples': 2}, 'samples >= 4'),
    ({'frames': '1', 'render_output_root': ''}, 'render_output_root'),
])
def test_bad_settings_are_refused(settings, message):
    job = compile_job(**settings)
    assert message in job.get('error', ''), job


def test_compiled_split_job_runs_and_equals_local_render(animated_blend, references, tmp_path):
    """Run what the job type compiled, as Flamenco workers would: the shard
    tasks' blender-render commands ({blender} = the bpy module through
    farm/bpy_render.py) in parallel, then the merge task's exec command."""
    from engine.film import Film
    require(hasattr(Film, 'from_state'), "engine.film.Film has no state API (sample ranges) yet")
    from farm.commands import BPY_RENDER
    from farmlib import SAMPLES, THREADS, assert_same_image, read_exr
    job = compile_job(frames='2', samples=SAMPLES, split_samples=2, render_threads=THREADS,
                      render_output_root=str(tmp_path), blendfile=animated_blend,
                      ember_python=sys.executable, ember_root=ROOT)
    env = dict(os.environ, PYTHONPATH=ROOT)
    *shards, merge = job['tasks']
    running = []
    for task in shards:
        params = task['commands'][0]['parameters']
        argv = [sys.executable, '-P', BPY_RENDER, '-b', '-y', *params['argsBefore'], params['blendfile'],
                *params['args']]
        running.append(subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
    for proc in running:
        out, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, out[-3000:]
    params = merge['commands'][0]['parameters']
    out = subprocess.run([params['exe'], *params['args']], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    assert "merged 2 shards, samples [0, 8)" in out.stdout
    assert_same_image(read_exr(tmp_path / 'frame_0002.exr'), references[2], "frame 2 from Flamenco tasks")
