"""Material, world and light previews render with Ember (bl_use_preview):
Blender renders its preview scenes through render() with is_preview set."""
import bpy
import numpy as np

from addon import engine as ember_engine
from preview_scene import preview_datablocks


def test_material_world_and_light_previews(factory_scene, needs_engine):
    previews = preview_datablocks(factory_scene)
    material = previews['material']
    # The log keeps only its last entries: start it empty (an index into a
    # full log would point past every new entry).
    del ember_engine.RENDER_LOG[:]
    bpy.ops.wm.previews_ensure()
    renders = [info for info in ember_engine.RENDER_LOG if info['preview']]
    assert renders, "Blender did not render previews with Ember"
    assert all(info['error'] is None for info in renders), [info['error'] for info in renders]
    for info in renders:
        print(f"preview {info['seconds']:.3f} s ({info['cpu_seconds']:.3f} CPU-s), {info.get('samples')} samples")
    for kind, datablock in previews.items():
        preview = datablock.preview
        assert preview is not None and preview.image_size[0] > 0, kind
        pixels = np.array(preview.image_pixels_float[:], np.float32).reshape(-1, 4)
        assert np.isfinite(pixels).all() and pixels[:, :3].max() > 0.05, f"{kind} preview is black"
    red = np.array(material.preview.image_pixels_float[:], np.float32).reshape(-1, 4)[:, :3]
    reddish = np.mean(red[:, 0] > 2 * red[:, 1] + 0.02)
    assert reddish > 0.1, f"the material preview must show the material's red ({reddish:.3f} of it is red)"
