"""The bounce's shape (engine/integrator/): the Context declares every field
and stays as built through a render, and the pass observer is told of every
bit of light the stages add."""
import dataclasses
import importlib
import threading
from dataclasses import replace

import numpy as np
import pytest

from engine import pass_events
from engine.film import Film
from engine.integrator import Context, ShadowBatch, Vertex
from engine.passes import PassConfig
from engine.render import prepare, render
from engine.scene import Lobe, Material, PointLight, RenderSettings
from engine.testscenes import cornell_box

# engine.render is the render function (engine/__init__.py); the module by path.
render_module = importlib.import_module("engine.render")


def glowing_box(size=12, emission=(2.0, 1.0, 0.5)):
    """The Cornell box with a glossy tall block, a second light and an
    emissive short block; without emission, light selection 'auto' samples
    every light at the glossy vertices and picks one at the others."""
    scene = cornell_box(size, size)
    glow = Material("glow", (Lobe("diffuse", (0.5, 0.5, 0.5)),), emission=emission)
    shiny = Material("shiny", (Lobe("glossy", (0.9, 0.9, 0.9), 0.2), Lobe("diffuse", (0.3, 0.3, 0.3))))
    instances = list(scene.instances)
    instances[5] = replace(instances[5], materials=[4])
    instances[6] = replace(instances[6], materials=[3])
    return replace(scene, materials=list(scene.materials) + [glow, shiny], instances=instances,
                   lights=list(scene.lights) + [PointLight((0.4, -0.5, 1.5), (5.0, 5.0, 5.0), radius=0.05)])


def test_context_declares_every_field_and_is_not_changed_by_a_render(monkeypatch):
    """A render with centre-ray passes and light groups (which once hung
    their state on the Context) leaves it with exactly its declared fields,
    each the object it was built with."""
    built = []

    def keep(scene, settings):
        built.append(prepare(scene, settings))
        return built[-1]
    monkeypatch.setattr(render_module, "prepare", keep)
    config = PassConfig(lightgroup_of={"area": "key"})
    render(glowing_box(), RenderSettings(samples=2, samples_per_pass=1, passes=("Depth", "Combined_key"),
                                         pass_config=config))
    ctx, = built
    names = {f.name for f in dataclasses.fields(Context)}
    assert set(vars(ctx)) == names
    assert ctx.emitter_groups is not None and ctx.pass_config.group_parts is not None
    with pytest.raises(dataclasses.FrozenInstanceError):
        ctx.sampler = None
    before = {name: id(getattr(ctx, name)) for name in names}
    render_module._run_batch(ctx, Film(12, 12, (), passes=("Depth",)), np.arange(144), 1, 0)
    assert {name: id(getattr(ctx, name)) for name in names} == before


class Recorder(pass_events.NoPasses):
    """An observer summing the light each hook reports."""
    active = True

    def __init__(self):
        self.total = 0.0
        self.kinds = set()
        self.lock = threading.Lock()

    def emitter(self, paths, rows, unweighted, w, world=False, bsdf_only=False, emitters=None):
        with self.lock:
            self.total += float((unweighted * w[:, None]).sum())
            self.kinds.add("world" if world else "emitter")

    def vertex(self, paths, v, depth):
        assert isinstance(v, Vertex) and len(v) == len(paths.pix) and v.path_rows is None

    def light_sample(self, paths, batch):
        assert isinstance(batch, ShadowBatch) and np.isin(batch.free, batch.rows).all()
        added = np.take(batch.sample.contrib, batch.free, axis=0) if batch.added is None else batch.added
        with self.lock:
            self.total += float(added.sum())
            self.kinds.add("subset" if batch.at.path_rows is not None else "nee")


@pytest.mark.parametrize("emission", [(2.0, 1.0, 0.5), (0.0, 0.0, 0.0)])
def test_the_observer_is_told_of_all_the_light_added(monkeypatch, emission):
    """Emitters, the world and light samples reported to the observer add
    up to the image (no clamping): no stage adds light unseen.  Without an
    emissive surface light selection 'auto' makes row subsets."""
    recorder = Recorder()
    monkeypatch.setattr(pass_events, "observer", lambda ctx, tile: recorder)
    r = render(glowing_box(emission=emission), RenderSettings(samples=4, samples_per_pass=4, seed=2,
                                                              max_bounces=3, light_selection="auto"))
    image = (r.image[..., :3].astype(np.float64) * r.sample_count[..., None]).sum()
    assert {"world", "emitter", "subset" if max(emission) == 0 else "nee"} <= recorder.kinds
    assert image > 0 and abs(recorder.total - image) <= 1e-6 * image


def test_batches_without_extra_passes_get_the_no_op_observer():
    ctx = prepare(glowing_box(), RenderSettings(samples=1))
    assert pass_events.observer(ctx, Film(12, 12, ()).new_tile(0, 144)) is pass_events.NO_PASSES
    with_passes = Film(12, 12, (), passes=("Emission",)).new_tile(0, 144)
    assert isinstance(pass_events.observer(ctx, with_passes), pass_events.PassObserver)


def test_take_rows_is_np_take_also_for_arrays_without_columns():
    """rows.take_rows (Paths.take, RowView, take_arrays): np.take's rows,
    shape and dtype, an (N, 0) array's made without NumPy's per-row take."""
    from engine.rows import take_rows
    rng = np.random.default_rng(3)
    idx = np.sort(rng.choice(1000, 300, replace=False))
    for a in (rng.random(1000), rng.random((1000, 3)), np.zeros((1000, 0), np.int16),
              np.zeros((1000, 0, 2)), rng.integers(0, 9, (1000, 2, 3)).astype(np.int8)):
        got, want = take_rows(a, idx), np.take(a, idx, axis=0)
        assert got.shape == want.shape and got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
