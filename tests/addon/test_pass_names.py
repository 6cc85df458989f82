"""Cycles-named passes in every supported Blender (3.4 binary, bpy 4.2, bpy
5.0; this file is in test_other_blenders.PORTABLE_TESTS): the View Layer
checkboxes turn them on, the render result holds them under this Blender's
names (5.0: "Object Index", "Diffuse Direct" ...; older: "IndexOB",
"DiffDir" ...), every pixel written is finite, and the Cryptomatte manifest
lands in the result's metadata."""
import bpy
import numpy as np
import pytest

from addon import output
from addon import passes as render_passes

LEGACY = {"Object Index": "IndexOB", "Diffuse Direct": "DiffDir", "Emission": "Emit",
          "Environment": "Env", "Ambient Occlusion": "AO"}


@pytest.fixture
def recorded(monkeypatch, factory_scene, needs_engine):
    """Render the factory scene at 16x12 with most passes on; record what
    the writer put into Blender's result."""
    scene = factory_scene
    scene.render.resolution_x, scene.render.resolution_y = 16, 12
    scene.render.resolution_percentage = 100
    scene.ember.samples = 4
    layer = bpy.context.view_layer
    for name in ('use_pass_z', 'use_pass_mist', 'use_pass_normal', 'use_pass_object_index',
                 'use_pass_diffuse_direct', 'use_pass_diffuse_color', 'use_pass_emit',
                 'use_pass_environment', 'use_pass_ambient_occlusion', 'use_pass_cryptomatte_object'):
        setattr(layer, name, True)
    layer.ember.use_pass_strategies = True
    layer.ember.use_pass_sample_count = True
    seen = {'passes': {}, 'metadata': {}}
    real_write, real_meta = output.ResultWriter.write, output.ResultWriter.add_metadata

    def write(self, image, extra=None):
        seen['layer'] = [p.name for p in self.layer.passes]
        for name, data in (extra or {}).items():
            if data is not None:
                seen['passes'][name] = np.array(data)
        return real_write(self, image, extra)

    def add_metadata(self, fields):
        seen['metadata'].update(fields)
        return real_meta(self, fields)
    monkeypatch.setattr(output.ResultWriter, 'write', write)
    monkeypatch.setattr(output.ResultWriter, 'add_metadata', add_metadata)
    bpy.ops.render.render()
    from addon import engine as ember_engine
    assert ember_engine.RENDER_LOG[-1]['error'] is None, ember_engine.RENDER_LOG[-1]['error']
    return seen


def test_passes_have_this_blenders_names(recorded):
    modern = bpy.app.version >= (5, 0, 0)
    for name, legacy in LEGACY.items():
        expected = name if modern else legacy
        assert expected in recorded['layer'], (expected, recorded['layer'])
        assert expected in recorded['passes'], expected
    for name in ("Depth", "Mist", "Normal", "Debug Sample Count", "Strategy Light", "Strategy BSDF",
                 "MIS Weight Light", "CryptoObject00", "CryptoObject02"):
        assert name in recorded['layer'], name


def test_written_passes_are_finite_and_meaningful(recorded):
    passes = recorded['passes']
    for name, data in passes.items():
        assert np.isfinite(data).all(), name
    index = passes["Object Index" if bpy.app.version >= (5, 0, 0) else "IndexOB"]
    assert set(np.unique(index)) <= {0.0}   # the factory objects' pass_index is 0
    assert np.allclose(passes["Debug Sample Count"], 1.0)
    weight = passes["MIS Weight Light"]
    assert weight.min() >= 0.0 and weight.max() <= 1.0
    # The cube covers the middle of the frame: its Cryptomatte coverage is 1.
    crypto = passes["CryptoObject00"]
    assert crypto[6, 8, 1] == pytest.approx(1.0)


def test_cryptomatte_manifest_in_metadata(recorded):
    import json
    fields = recorded['metadata']
    names = [v for k, v in fields.items() if k.endswith('/name')]
    assert names == [f"{bpy.context.view_layer.name}.CryptoObject"]
    manifest = json.loads(next(v for k, v in fields.items() if k.endswith('/manifest')))
    from engine.passes import crypto_hash
    assert manifest["Cube"] == f"{crypto_hash('Cube'):08x}"


def test_engine_names_are_registered_once(factory_scene):
    layer = bpy.context.view_layer
    layer.use_pass_emit = True
    layer.ember.use_pass_strategies = True
    names = [blender for _, blender, *_ in render_passes.requested(layer)]
    assert len(names) == len(set(names))
