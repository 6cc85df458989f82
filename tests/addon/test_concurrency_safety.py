"""Concurrent work and safety (issue 11).

* A final render while the viewport's render thread renders another scene,
  and two scenes rendered one after the other in one session, give exactly
  the pixels each gives alone: no mutable state is shared between renders.
* Nothing from a .blend is evaluated or run: names, paths, node labels and
  text blocks carrying shell and Python payloads render as plain data, and
  the add-on and engine sources contain no eval/exec/shell call.
* Image paths resolve as Blender resolves them (relative to the .blend or
  its library), never elsewhere.
"""
import ast
import dataclasses
import os
import threading
import time

import bpy
import numpy as np
import pytest

from addon import engine as ember_engine
from addon.export import images as image_export
from addon.export import scene as scene_export
from ember_testlib import ROOT, open_scene, render_array, setup_ember, small_resolution


def _cornell(width=32, height=24, samples=8):
    scene = open_scene('cornell')
    small_resolution(scene, width, height)
    setup_ember(scene, samples, seed=5, max_bounces=4)
    scene.ember.threads = 2
    return scene


def test_final_render_while_the_viewport_renders(tmp_path, needs_engine):
    from addon import backend, viewport
    scene = _cornell()
    alone = render_array(scene, tmp_path, 'alone')
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    view_scene = dataclasses.replace(exported.scene, camera=dataclasses.replace(
        exported.scene.camera, resolution=(48, 40)))
    view_settings = dataclasses.replace(scene_export.render_settings(scene), samples=12, seed=9)
    # Alone with the viewport's own pass schedule (one sample a pass): the
    # film's rounding depends on how samples are grouped into passes.
    view_alone = backend.engine().render(view_scene, dataclasses.replace(view_settings,
                                                                           samples_per_pass=1)).image
    thread = viewport.RenderThread()
    try:
        job = thread.submit(viewport.Job(view_scene, view_settings, changed_at=time.perf_counter()))
        while not thread.busy and thread.finished_job != job:
            time.sleep(0.001)
        together = render_array(scene, tmp_path, 'together')
        overlapped = thread.busy  # the viewport was still rendering when F12 finished
        deadline = time.perf_counter() + 120
        while thread.finished_job != job and time.perf_counter() < deadline:
            time.sleep(0.01)
        assert thread.error is None, thread.error
        view_together = thread.image
    finally:
        thread.close()
    print(f"\nviewport still rendering when the final render ended: {overlapped}")
    assert ember_engine.RENDER_LOG[-1]['error'] is None
    np.testing.assert_array_equal(together, alone)
    np.testing.assert_array_equal(view_together, view_alone)


def test_two_scenes_in_one_session_do_not_interfere(tmp_path, needs_engine):
    scene = _cornell()
    first = render_array(scene, tmp_path, 'a1')
    other = bpy.data.scenes.new('Other')
    other.render.engine = 'EMBER'
    other.camera = scene.camera
    small_resolution(other, 20, 20)
    other.ember.samples = 3
    other.ember.seed = 1
    for obj in list(scene.objects)[:2]:
        other.collection.objects.link(obj)
    bpy.context.window.scene = other if bpy.context.window else None
    with bpy.context.temp_override(scene=other):
        bpy.ops.render.render(scene=other.name)
    assert ember_engine.RENDER_LOG[-1]['error'] is None
    with bpy.context.temp_override(scene=scene):
        again = render_array(scene, tmp_path, 'a2')
    np.testing.assert_array_equal(again, first)


def test_two_engine_renders_in_parallel_threads(needs_engine):
    """The engine's render() called from two threads at once (what two
    RenderEngine instances do) gives each scene its solo pixels."""
    from addon import backend
    from engine import testscenes
    render = backend.engine().render
    scenes = [testscenes.cornell_box(24, 24), testscenes.cornell_box(16, 20, light_power=40.0)]
    settings = [backend.engine().RenderSettings(samples=4, seed=s, threads=2) for s in (1, 2)]
    solo = [render(s, r).image for s, r in zip(scenes, settings)]
    out = [None, None]

    def work(k):
        out[k] = render(scenes[k], settings[k]).image
    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k in range(2):
        np.testing.assert_array_equal(out[k], solo[k])


# ----------------------------------------------------------------------------
# safety

PAYLOADS = ["$(touch {s}_a)", "`touch {s}_b`", "'; touch {s}_c; '", "__import__('os').system('touch {s}_d')",
            "{{os.system('touch {s}_e')}}", "%(x)s %s {{0}}", "../../../../etc/passwd"]


def test_hostile_names_paths_and_text_are_only_data(factory_scene, tmp_path, needs_engine):
    sentinel = str(tmp_path / 'pwned')
    payloads = [p.format(s=sentinel) for p in PAYLOADS]
    scene = factory_scene
    small_resolution(scene, 16, 16)
    scene.ember.samples = 1
    cube = scene.objects['Cube']
    mat = bpy.data.materials.new(payloads[0])
    mat.use_nodes = True
    cube.data.materials.append(mat)
    tree = mat.node_tree
    for k, payload in enumerate(payloads):
        node = tree.nodes.new('ShaderNodeTexImage')
        node.label = payload
        node.name = payload
        image = bpy.data.images.new(payload, 2, 2)
        image.source = 'FILE'
        image.filepath = payload
        node.image = image
        if k == 0:
            tree.links.new(node.outputs['Color'], tree.nodes['Principled BSDF'].inputs['Base Color'])
    cube.name = payloads[3]
    cube.data.name = payloads[2]
    scene.objects['Light'].name = payloads[1]
    text = bpy.data.texts.new(payloads[4])
    text.write(f"import os\nos.system('touch {sentinel}_text')\n")
    text.use_module = True  # Blender would run it at load only with scripts trusted; Ember never does
    bpy.ops.render.render()
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert not [p for p in os.listdir(tmp_path) if p.startswith('pwned')]
    assert any('could not be loaded' in w for w in log['warnings'])  # the payload path is just a missing file


FORBIDDEN_CALLS = {'eval', 'exec', 'compile', '__import__'}
# Reviewed exceptions: (file, call) -> why nothing from a .blend reaches it.
ALLOWED = {
    ('engine/kernels.py', 'exec()'): "numba wrapper source from the engine's own kernel names and arity",
    ('engine/kernels.py', 'compile()'): "the same wrapper source",
}
FORBIDDEN_ATTRS = {('os', 'system'), ('os', 'popen'), ('pickle', 'loads'), ('pickle', 'load'),
                   ('marshal', 'loads')}


def test_sources_never_evaluate_or_shell_out():
    """No eval/exec/compile, no os.system/popen, no pickle, and every
    subprocess call takes an argument list without shell=True."""
    found = []
    for package in ('addon', 'engine'):
        for folder, _, files in os.walk(os.path.join(ROOT, package)):
            for name in files:
                if not name.endswith('.py') or 'vendor' in folder:
                    continue
                path = os.path.join(folder, name)
                with open(path) as f:
                    tree = ast.parse(f.read(), path)
                for node in ast.walk(tree):
                    if not isinstance(node, ast.Call):
                        continue
                    func = node.func
                    relative = os.path.relpath(path, ROOT)
                    if isinstance(func, ast.Name) and func.id in FORBIDDEN_CALLS:
                        if (relative, f"{func.id}()") not in ALLOWED:
                            found.append(f"{path}:{node.lineno} {func.id}()")
                    if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
                        if (func.value.id, func.attr) in FORBIDDEN_ATTRS:
                            found.append(f"{path}:{node.lineno} {func.value.id}.{func.attr}()")
                    for keyword in node.keywords:
                        if keyword.arg == 'shell' and not (isinstance(keyword.value, ast.Constant)
                                                           and keyword.value.value is False):
                            found.append(f"{path}:{node.lineno} shell=")
    assert not found, found


def test_image_paths_resolve_as_blender_does(factory_scene, tmp_path):
    blend = tmp_path / 'sub' / 'scene.blend'
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    cases = ['//tex.png', '//../up.png', '//a/b/../c.png', str(tmp_path / 'abs.png'), 'plain.png']
    for filepath in cases:
        image = bpy.data.images.new('Probe', 2, 2)
        image.source = 'FILE'
        image.filepath = filepath
        ours = image_export._external_path(image)
        blender = os.path.normpath(bpy.path.abspath(image.filepath, library=image.library))
        assert os.path.normpath(ours) == blender, (filepath, ours, blender)
        assert os.path.normpath(ours) == os.path.normpath(image.filepath_from_user()), filepath
        bpy.data.images.remove(image)
