"""Material, world and light previews with Ember in Debian's Blender 3.4.

Its background mode crashes in any preview render (Cycles too), so
tests/addon/previews_gui.py asks for them in a window under Xvfb, as the
interface does; this file judges (tests/addon/test_previews.py covers bpy 5.0,
test_render_engine.py's preview test bpy 4.2-5.3)."""
import json
import os
import signal
import subprocess

from ember_testlib import ROOT
from test_viewport import BLENDER, _site, require_blender_34_window


def test_previews_render_with_ember_in_blender_34(tmp_path):
    require_blender_34_window()
    out = tmp_path / 'out'
    out.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / 'user'))
    env.pop('PYTHONPATH', None)
    cmd = ['xvfb-run', '-a', '-s', '-screen 0 800x600x24', BLENDER, '--factory-startup',
           '-p', '0', '0', '480', '360', '-P', os.path.join(ROOT, 'tests', 'addon', 'previews_gui.py'),
           '--', str(out), _site(tmp_path)]
    # Its own session: on a timeout Blender and Xvfb go too (xvfb-run alone leaves them running).
    process = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               text=True, start_new_session=True)
    try:
        output, _ = process.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        output, _ = process.communicate()
    result_path = out / 'result.json'
    assert result_path.exists(), output[-4000:]
    result = json.loads(result_path.read_text())
    print(f"Blender {result['version']}: previews in {result.get('seconds', 0):.1f} s; {result.get('renders')}")
    assert not result['errors'], result['errors']
    renders = [r for r in result['renders'] if r['preview']]
    assert len(renders) >= 3, f"Blender did not render the three previews with Ember: {result['renders']}"
    assert all(r['error'] is None for r in renders), renders
    for kind in ('material', 'world', 'light'):
        preview = result[kind]
        assert preview is not None and preview['size'][0] > 0, kind
        assert preview['finite'] and preview['max'] > 0.05, f"{kind} preview is black: {preview}"
    assert result['material']['reddish'] > 0.1, \
        f"the material preview must show the material's red ({result['material']['reddish']:.3f} of it is red)"
