"""Render the README gallery: every blend scene by Ember and by Cycles with
the same bounces and pixel filter, saved side by side (Ember left).

    .venv/bin/python -P tools/render_gallery.py [--samples 128] [--cycles-samples 512]
"""
import argparse
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ("cornell", "veach_mis", "instances_lights")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--cycles-samples", type=int, default=512)
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "gallery"))
    args = ap.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="ember-gallery-"))
    sys.path[:0] = [ROOT, os.path.join(ROOT, "tests", "addon")]
    import bpy
    import OpenImageIO as oiio

    import addon
    from ember_testlib import setup_cycles, setup_ember

    addon.register()
    os.makedirs(args.out, exist_ok=True)
    for name in SCENES:
        paths = []
        for engine, spp in (("ember", args.samples), ("cycles", args.cycles_samples)):
            bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "blend_scenes", name + ".blend"))
            scene = bpy.context.scene
            bounces = scene.ember.max_bounces
            (setup_ember if engine == "ember" else setup_cycles)(scene, spp, 1, bounces)
            scene.render.image_settings.file_format = "PNG"
            path = os.path.join(args.out, f"{name}_{engine}.png")
            scene.render.filepath = path
            bpy.ops.render.render(write_still=True)
            paths.append(path)
        a, b = (oiio.ImageBuf(p) for p in paths)
        w, h = a.spec().width, a.spec().height
        both = oiio.ImageBuf(oiio.ImageSpec(2 * w, h, a.spec().nchannels, oiio.UINT8))
        oiio.ImageBufAlgo.paste(both, 0, 0, 0, 0, a)
        oiio.ImageBufAlgo.paste(both, w, 0, 0, 0, b)
        both.write(os.path.join(args.out, f"{name}.png"))
        for p in paths:
            os.remove(p)
        print("wrote", os.path.join(args.out, f"{name}.png"))


if __name__ == "__main__":
    main()
