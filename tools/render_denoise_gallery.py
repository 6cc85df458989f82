"""docs/gallery/denoise.png: the Cornell box at 16 samples, the same image
denoised with Open Image Denoise (addon/denoise.py, albedo and normal
guided), and 128 samples, side by side.

    PYTHONPATH=. .venv/bin/python -P tools/render_denoise_gallery.py [--size 256]
"""
import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def to_srgb8(linear):
    c = np.clip(linear, 0.0, 1.0)
    c = np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)
    return (c * 255 + 0.5).astype(np.uint8)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--size', type=int, default=256)
    parser.add_argument('-o', '--output', default=os.path.join(ROOT, 'docs', 'gallery', 'denoise.png'))
    args = parser.parse_args(argv)
    import bpy
    import addon
    addon.register()
    from addon import backend, denoise
    from addon.export import scene as scene_export
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, 'blend_scenes', 'cornell.blend'))
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = args.size
    scene.render.resolution_percentage = 100
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    render = backend.engine().render
    panels = []
    for samples in (16, 128):
        settings = scene_export.render_settings(scene)
        settings.samples, settings.samples_per_pass = samples, samples
        settings.aovs = ("normal", "albedo")   # the denoiser's guides
        result = render(exported.scene, settings)
        panels.append(result.image[..., :3])
        if samples == 16:
            panels.append(denoise.denoise(result.image[..., :3], result.albedo, result.normal))
            print("denoiser:", denoise.describe())
    gap = np.ones((args.size, 4, 3), np.float32)
    strip = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)
    import OpenImageIO as oiio
    pixels = to_srgb8(strip)
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, oiio.UINT8)
    out = oiio.ImageOutput.create(args.output)
    out.open(args.output, spec)
    out.write_image(pixels)
    out.close()
    print("wrote", args.output)


if __name__ == '__main__':
    main()
