"""Renders run with one BLAS thread (engine/blas.py) and give the count back."""
import threadpoolctl

from engine.render import render
from engine.scene import RenderSettings
from engine.testscenes import cornell_box


def blas_threads():
    return [info["num_threads"] for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas"]


class Recorder:
    def __init__(self):
        self.seen = []

    def on_pass(self, image, samples, stats):
        self.seen.append(blas_threads())


def test_render_limits_blas_to_one_thread_and_restores_it():
    before = blas_threads()
    assert before, "NumPy's BLAS is not visible to threadpoolctl"
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        recorder = Recorder()
        render(cornell_box(8, 8), RenderSettings(samples=2, samples_per_pass=1, max_bounces=1, threads=2),
               recorder)
        assert recorder.seen and all(counts == [1] * len(before) for counts in recorder.seen)
        assert blas_threads() == [2] * len(before)
