"""engine/allocator.py: glibc keeps a batch's freed arrays for the next one.

What it changes is page faults.  Under glibc's defaults a working set of
some 90 MB of 4.5 MB arrays, freed and allocated again, is handed back to
the kernel each time (the heap's top is trimmed) and faults in 23,000 fresh
pages a round; a 128x128 Cornell render on two threads faults ~14,000
pages in every render after the first.  Tuned: none, and ~500."""
import resource
import sys

import numpy as np
import pytest

from engine import allocator, kernels, testscenes
from engine.render import render
from engine.scene import RenderSettings

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc is Linux's")


def _faults(fn):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    fn()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def _working_set(rounds=10):
    for _ in range(rounds):
        arrays = [np.ones(65536 * 9) for _ in range(20)]   # 20 x 4.5 MB live, as a batch's
        del arrays


def test_tune_keeps_a_freed_working_set():
    assert allocator.tune() is True   # glibc here: both settings accepted
    assert allocator.tune() is True   # once per process, then remembered
    _working_set(1)                   # the heap grows to hold it
    pages = 20 * 65536 * 9 * 8 // 4096
    faults = _faults(_working_set)
    assert faults < pages, f"{faults} page faults in 10 rounds (untuned: ~10 x {pages})"


def test_a_render_reuses_its_pages():
    """Renders after the first fault in few pages (untuned: ~14,000 each)."""
    kernels.configure(True)
    assert kernels.wait(900)
    scene = testscenes.cornell_box(128, 128)
    settings = RenderSettings(samples=8, samples_per_pass=8, threads=2, max_bounces=8)
    render(scene, settings)
    faults = min(_faults(lambda: render(scene, settings)) for _ in range(2))
    assert faults < 4000, f"{faults} page faults in a render"
