"""Fixtures for the render-farm tests (no bpy in this process: Blender runs
in subprocesses, as on a farm)."""
import importlib.util
import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
for path in (os.path.dirname(os.path.dirname(HERE)), os.path.dirname(HERE), HERE):  # repository, tests/, farmlib
    if path not in sys.path:
        sys.path.insert(0, path)

from farmlib import make_animation, render_locally, require  # noqa: E402


@pytest.fixture(scope='session')
def animated_blend(tmp_path_factory):
    require(sys.version_info[:2] == (3, 11), "the bpy module needs Python 3.11")
    require(importlib.util.find_spec('bpy') is not None, "the bpy module is not installed in this Python")
    return make_animation(tmp_path_factory.mktemp('anim') / 'anim.blend')


@pytest.fixture(scope='session')
def cluster():
    require(importlib.util.find_spec('distributed') is not None, "dask distributed is not installed")
    import distributed
    lc = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    dask_client = distributed.Client(lc)
    yield lc, dask_client
    dask_client.close()
    lc.close()


@pytest.fixture(scope='session')
def references(animated_blend, tmp_path_factory):
    """Frames 1-4 rendered by one local Blender process, no farm involved."""
    return render_locally(animated_blend, tmp_path_factory.mktemp('local'), '1..4')
