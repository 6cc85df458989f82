"""The RenderEngine's contract with Blender, driven by a scripted renderer.

These tests stand a small scripted renderer in for engine.render so that they
check exactly what the add-on owns (progressive writes, orientation, border and
crop, cancel, error reporting, view layers, frames) independently of the
path tracer; tests/addon/test_render_scenes.py renders with the real engine.
"""
import os
from dataclasses import dataclass, field

import bpy
import numpy as np
import pytest

from addon import backend, output
from addon import engine as ember_engine
from ember_testlib import load_exr


@dataclass
class FakeResult:
    image: np.ndarray
    depth: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    samples: int
    stats: dict = field(default_factory=dict)


def window_of(camera):
    """The border window the engine is asked to render, in pixels."""
    width, height = camera.resolution
    if camera.border is None:
        return width, height
    xmin, xmax, ymin, ymax = camera.border
    return round(xmax * width) - round(xmin * width), round(ymax * height) - round(ymin * height)


def pattern(camera, scale):
    """RGBA where R encodes the column, G the row counted from the TOP, B the
    first instance's x position (so frames differ), A = 1."""
    width, height = window_of(camera)
    image = np.zeros((height, width, 4), np.float32)
    image[..., 0] = (np.arange(width)[None, :] + 0.5) / width
    image[..., 1] = (np.arange(height)[:, None] + 0.5) / height
    image[..., 3] = 1.0
    return image * np.array([scale, scale, 1.0, 1.0], np.float32)


class ScriptedRenderer:
    """Calls on_pass like the engine does and records what it was given."""

    def __init__(self, passes=4, fail_at=None, nan=False):
        self.passes = passes
        self.fail_at = fail_at
        self.nan = nan
        self.calls = []

    def __call__(self, scene, settings, progress=None):
        self.calls.append((scene, settings))
        done = 0
        image = pattern(scene.camera, 0.0)
        for index in range(self.passes):
            if progress is not None and progress.should_stop():
                break
            if index == self.fail_at:
                raise RuntimeError("scripted failure")
            image = pattern(scene.camera, (index + 1) / self.passes)
            if scene.instances:
                image[..., 2] = scene.instances[0].matrix[0, 3]
            if self.nan:
                image[0, 0, 0] = np.nan
            done += 1
            if progress is not None:
                stats = {'samples': done, 'samples_total': self.passes, 'seconds': 0.01 * done,
                         'rays_per_second': 1e6, 'seconds_left': 0.01 * (self.passes - done)}
                progress.on_pass(image, done, stats)
        h, w = image.shape[:2]
        return FakeResult(image, np.ones((h, w), np.float32), np.zeros((h, w, 3), np.float32),
                          np.ones((h, w, 3), np.float32), done)


@pytest.fixture
def scripted(monkeypatch):
    """Install a scripted renderer in place of engine.render.render (and skip
    engine.validate, which belongs to the engine's own tests)."""
    def install(**kwargs):
        renderer = ScriptedRenderer(**kwargs)
        monkeypatch.setattr(backend, 'require_ray_tracer', lambda: None)   # it traces no rays
        monkeypatch.setattr(backend.engine(), 'render', renderer)
        monkeypatch.setattr(backend.engine(), 'validate_scene', lambda scene: None)
        return renderer
    return install


@pytest.fixture
def small(factory_scene):
    render = factory_scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 40, 30, 100
    render.image_settings.file_format = 'OPEN_EXR'
    return factory_scene


def render_pixels(scene, tmp_path, name="out"):
    """Render the scene and return the saved EXR as (H, W, 4), row 0 = top."""
    bpy.ops.render.render()
    path = os.path.join(str(tmp_path), name + ".exr")
    bpy.data.images['Render Result'].save_render(path)
    return load_exr(path)


def test_final_image_orientation_and_values(small, scripted, tmp_path):
    renderer = scripted(passes=3)
    pixels = render_pixels(small, tmp_path)
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None and log['passes'] == 3
    expected = pattern(renderer.calls[0][0].camera, 1.0)
    np.testing.assert_allclose(pixels[..., :2], expected[..., :2], atol=1e-6)
    assert pixels[0, 0, 1] < pixels[-1, 0, 1]  # row 0 of the engine is the top row


def test_progressive_updates_and_stats(small, scripted, monkeypatch):
    seen = []
    monkeypatch.setattr(output, 'progress_listeners', [lambda done, total, stats: seen.append((done, total))])
    stats_lines = []
    original = output.format_stats
    monkeypatch.setattr(output, 'format_stats', lambda *a: stats_lines.append(original(*a)) or stats_lines[-1])
    scripted(passes=5)
    bpy.ops.render.render()
    assert seen == [(i, 5) for i in range(1, 6)]
    assert stats_lines[0].startswith("Sample 1/5") and "Mrays/s" in stats_lines[0] and "left" in stats_lines[0]
    assert ember_engine.RENDER_LOG[-1]['first_pass_seconds'] > 0


def test_cancel_keeps_partial_image(small, scripted, monkeypatch, tmp_path):
    def esc_after_two_passes(engine):
        # Also asked during export (between objects): Esc only once two passes are shown.
        return ember_engine.RENDER_LOG[-1]['passes'] >= 2
    monkeypatch.setattr(output, 'break_requested', esc_after_two_passes)
    renderer = scripted(passes=10)
    pixels = render_pixels(small, tmp_path)
    log = ember_engine.RENDER_LOG[-1]
    assert log['cancelled'] and log['passes'] == 2 and log['error'] is None
    expected = pattern(renderer.calls[0][0].camera, 0.2)  # the second of ten passes
    np.testing.assert_allclose(pixels[..., 0], expected[..., 0], atol=1e-6)


def test_error_is_reported_not_swallowed(small, scripted):
    scripted(passes=4, fail_at=1)
    with pytest.raises(RuntimeError, match="Ember: RuntimeError: scripted failure"):
        bpy.ops.render.render()
    assert "scripted failure" in ember_engine.RENDER_LOG[-1]['error']


def test_missing_renderer_is_reported(small, monkeypatch):
    def missing():
        raise ImportError("Ember needs the 'embreex' package (test)")
    monkeypatch.setattr(backend, 'require_ray_tracer', missing)
    with pytest.raises(RuntimeError, match="embreex"):
        bpy.ops.render.render()


def test_nan_pixels_never_reach_the_image(small, scripted, tmp_path):
    scripted(passes=2, nan=True)
    pixels = render_pixels(small, tmp_path)
    assert np.isfinite(pixels).all() and pixels[0, 0, 0] == 0.0
    assert any("non-finite" in w for w in ember_engine.RENDER_LOG[-1]['warnings'])


def test_export_warnings_are_reported(small, scripted):
    scripted(passes=1)
    tree = bpy.data.materials['Material'].node_tree
    toon = tree.nodes.new('ShaderNodeBsdfToon')   # a node Ember does not translate
    tree.links.new(toon.outputs[0], tree.nodes['Material Output'].inputs['Surface'])
    bpy.ops.render.render()
    warnings = ember_engine.RENDER_LOG[-1]['warnings']
    assert len(warnings) == 1 and "Toon" in warnings[0]


@pytest.mark.parametrize("crop", [True, False])
def test_border_and_crop(small, scripted, tmp_path, crop):
    render = small.render
    render.use_border, render.use_crop_to_border = True, crop
    render.border_min_x, render.border_max_x = 0.25, 0.75
    render.border_min_y, render.border_max_y = 0.1, 0.6
    renderer = scripted(passes=2)
    pixels = render_pixels(small, tmp_path)
    x, y, w, h = 10, 3, 20, 15  # 40x30 frame
    window = pattern(renderer.calls[0][0].camera, 1.0)
    assert window.shape[:2] == (h, w)
    if crop:
        assert pixels.shape[:2] == (h, w)
        np.testing.assert_allclose(pixels[..., :2], window[..., :2], atol=1e-6)
    else:
        assert pixels.shape[:2] == (30, 40)
        top = 30 - (y + h)  # the window's top row counted from the image top
        np.testing.assert_allclose(pixels[top:top + h, x:x + w, :2], window[..., :2], atol=1e-6)
        outside = pixels.copy()
        outside[top:top + h, x:x + w] = 0
        assert np.abs(outside[..., :3]).max() == 0


def test_every_view_layer_is_rendered(small, scripted):
    scripted(passes=1)
    small.view_layers.new("Second")
    del ember_engine.RENDER_LOG[:]
    bpy.ops.render.render()
    assert sorted(entry['layer'] for entry in ember_engine.RENDER_LOG) == sorted(
        layer.name for layer in small.view_layers)


def test_animation_frames(small, scripted, tmp_path):
    renderer = scripted(passes=1)
    cube = bpy.data.objects['Cube']
    cube.location.x = 0.0
    cube.keyframe_insert('location', frame=1)
    cube.location.x = 2.0
    cube.keyframe_insert('location', frame=2)
    small.frame_start, small.frame_end = 1, 2
    small.render.filepath = os.path.join(str(tmp_path), "frame_####")
    bpy.ops.render.render(animation=True)
    xs = [scene.instances[0].matrix[0, 3] for scene, _ in renderer.calls]
    assert xs == pytest.approx([0.0, 2.0])
    frames = [load_exr(os.path.join(str(tmp_path), f"frame_{i:04d}.exr")) for i in (1, 2)]
    assert frames[0][0, 0, 2] == pytest.approx(0.0) and frames[1][0, 0, 2] == pytest.approx(2.0)


def test_settings_reach_the_renderer(small, scripted):
    renderer = scripted(passes=1)
    small.ember.samples, small.ember.max_bounces = 9, 3
    bpy.ops.render.render()
    settings = renderer.calls[0][1]
    assert (settings.samples, settings.max_bounces) == (9, 3)


def test_material_preview_renders_with_ember(small, scripted):
    """bpy 4.2-5.3 (background previews_ensure).  Blender 3.4's background mode
    crashes in any preview render (Cycles too): its previews are rendered in a
    window under Xvfb by test_previews_34.py, and the 3.4 run deselects this."""
    renderer = scripted(passes=1)
    del ember_engine.RENDER_LOG[:]
    bpy.ops.wm.previews_ensure()
    previews = [entry for entry in ember_engine.RENDER_LOG if entry['preview']]
    assert previews, "no material preview was rendered by Ember"
    assert all(entry['error'] is None for entry in previews)
    assert renderer.calls[-1][1].samples == small.ember.preview_samples


def test_bad_scene_is_reported_with_a_reason(small, scripted):
    scripted(passes=1)
    small.camera.scale = (0.0, 1.0, 1.0)
    with pytest.raises(RuntimeError, match="Ember: Camera 'Camera': it has a zero scale"):
        bpy.ops.render.render()
    assert "zero scale" in ember_engine.RENDER_LOG[-1]['error']


def test_depth_and_normal_passes(small, scripted):
    scripted(passes=1)
    layer = small.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = True
    bpy.ops.render.render()
    assert ember_engine.RENDER_LOG[-1]['error'] is None
    result = bpy.data.images['Render Result']
    assert result.type == 'RENDER_RESULT'
