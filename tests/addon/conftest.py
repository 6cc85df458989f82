"""Fixtures for the add-on tests, run with the bpy module (pytest tests/addon).

BLENDER_USER_RESOURCES points at a temporary folder before bpy is imported so
that tests never read or write the user's Blender configuration.  The add-on is
registered once per session; every test starts from Blender's factory scene.
Tests that need something this machine lacks call ``require``: they skip on a
developer machine and FAIL under CI=true, so CI never passes by skipping.
"""
import os
import sys
import tempfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES_DIR = os.path.join(ROOT, 'blend_scenes')

os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-blender-user-'))
for path in (ROOT, os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
             os.path.dirname(os.path.abspath(__file__))):  # repo, tests/ember_stats.py, test helpers
    if path not in sys.path:
        sys.path.insert(0, path)

import bpy  # noqa: E402

import addon  # noqa: E402


from ember_testlib import PassTap, empty_factory_scene, engine_available, require  # noqa: E402
from addon import backend  # noqa: E402


@pytest.fixture(scope='session', autouse=True)
def registered_addon():
    addon.register()
    yield addon
    addon.unregister()


@pytest.fixture
def factory_scene(registered_addon):
    """Blender's default scene (cube, light, camera) with Ember selected."""
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    return scene


@pytest.fixture
def empty_scene(registered_addon):
    """The factory scene without its cube and light, camera kept."""
    scene = empty_factory_scene()
    scene.render.engine = 'EMBER'
    return scene


@pytest.fixture
def needs_engine():
    ok, reason = engine_available()
    require(ok, "engine.render is not importable: " + reason)


class Taps(list):
    """The PassTaps of the renders so far.  ``samples_per_pass`` (if set)
    replaces the add-on's (one sample per pass) in the renders that follow:
    a test that needs no per-pass estimates renders faster in one pass."""
    samples_per_pass = None


@pytest.fixture
def tapped_engine(monkeypatch, needs_engine):
    """Record Ember's progressive images, and its result, while rendering
    through Blender."""
    import dataclasses
    real = backend.engine().render
    taps = Taps()

    def render(scene, settings, progress=None):
        tap = PassTap(progress)
        taps.append(tap)
        if taps.samples_per_pass:
            settings = dataclasses.replace(settings, samples_per_pass=taps.samples_per_pass)
        # The variance of channel sums too (result.variance_with_sum): images unchanged.
        settings = dataclasses.replace(settings, sum_variance=True)
        tap.result = real(scene, settings, tap)
        return tap.result
    monkeypatch.setattr(backend.engine(), 'render', render)
    return taps
