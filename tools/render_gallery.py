"""Render the README gallery: every blend scene by Ember and by Cycles with
the same bounces and pixel filter, saved side by side (Ember left).

    .venv/bin/python -P tools/render_gallery.py [--samples 128] [--cycles-samples 512]
"""
import argparse
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ("cornell", "veach_mis", "instances_lights", "materials", "subsurface", "lobes", "motion", "smoke",
          "points", "bump", "thinfilm", "hair", "light_textures", "displacement")
# Gallery scenes that are parity scenes of tests/addon (module, scene name, upscale of its resolution).
PARITY = {"subsurface": ("test_subsurface_parity", "spheres", 6), "lobes": ("test_lobe_parity", "lobes", 4),
          "motion": ("test_motion_parity", "objects", 4), "smoke": ("test_volume_field_parity", "smoke_in_fog", 10),
          "points": ("test_points_parity", "heap", 4), "bump": ("test_bump_correction_parity", "sphere", 4),
          "thinfilm": ("test_thinfilm_parity", "films", 5), "hair": ("test_hair_parity", "particles", 5),
          "light_textures": ("test_light_texture_parity", "light_textures", 5),
          "displacement": ("test_displacement_parity", "only", 6)}


def build_parity_scene(name):
    """A tests/addon parity scene, at a gallery resolution."""
    import importlib
    module, scene_name, upscale = PARITY[name]
    scene, bounces = importlib.import_module(module).reference_scene(scene_name)
    scene.render.resolution_x *= upscale
    scene.render.resolution_y *= upscale
    return scene, bounces


def build_materials_scene(bpy):
    """Principled glass, gold, coated plastic and sheen spheres on a checker
    floor under the forest HDRI that bpy ships (built here: the 4.x
    Principled inputs do not exist in the 3.4 files of blend_scenes/)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    hdri = os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", "forest.exr")
    world = bpy.data.worlds.new("forest")
    world.use_nodes = True
    tree = world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(hdri)
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    scene.world = world

    def principled(name, **inputs):
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        node = mat.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            node.inputs[key].default_value = value
        return mat

    spheres = [
        ((-2.4, 0, 0.5), principled("glass", **{"Base Color": (1, 1, 1, 1), "Transmission Weight": 1.0,
                                                 "Roughness": 0.0, "IOR": 1.5})),
        ((-0.8, 0, 0.5), principled("gold", **{"Base Color": (1.0, 0.77, 0.34, 1), "Metallic": 1.0,
                                                "Roughness": 0.25})),
        ((0.8, 0, 0.5), principled("coated", **{"Base Color": (0.6, 0.05, 0.04, 1), "Roughness": 0.6,
                                                 "Coat Weight": 1.0, "Coat Roughness": 0.05})),
        ((2.4, 0, 0.5), principled("velvet", **{"Base Color": (0.1, 0.15, 0.5, 1), "Roughness": 0.8,
                                                 "Sheen Weight": 1.0, "Sheen Tint": (1, 1, 1, 1)})),
    ]
    for location, mat in spheres:
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=location, segments=64, ring_count=32)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(mat)
    bpy.ops.mesh.primitive_plane_add(size=12)
    floor = bpy.data.materials.new("checker")
    floor.use_nodes = True
    nodes = floor.node_tree.nodes
    checker = nodes.new("ShaderNodeTexImage")
    image = bpy.data.images.new("checker", 8, 8)
    pixels = [(0.8 if (i // 8 + i % 8) % 2 else 0.15) for i in range(64) for _ in range(1)]
    image.pixels.foreach_set([v for p in pixels for v in (p, p, p, 1.0)])
    image.pack()
    checker.image = image
    checker.interpolation = "Closest"
    floor.node_tree.links.new(checker.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    nodes["Principled BSDF"].inputs["Roughness"].default_value = 0.35
    bpy.context.active_object.data.materials.append(floor)
    bpy.ops.object.camera_add(location=(0, -7.5, 2.6), rotation=(1.25, 0, 0))
    scene.camera = bpy.context.active_object
    scene.camera.data.lens = 40
    scene.render.resolution_x, scene.render.resolution_y = 320, 160
    scene.render.resolution_percentage = 100
    scene.ember.max_bounces = 8
    return scene


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=128)
    ap.add_argument("--cycles-samples", type=int, default=512)
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "gallery"))
    ap.add_argument("scenes", nargs="*", help=f"which of {', '.join(SCENES)} (default all)")
    args = ap.parse_args(argv)
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="ember-gallery-"))
    sys.path[:0] = [ROOT, os.path.join(ROOT, "tests", "addon"), os.path.join(ROOT, "tests")]
    import bpy
    import OpenImageIO as oiio

    import addon
    from ember_testlib import setup_cycles, setup_ember

    addon.register()
    os.makedirs(args.out, exist_ok=True)
    for name in args.scenes or SCENES:
        paths = []
        for engine, spp in (("ember", args.samples), ("cycles", args.cycles_samples)):
            if name in PARITY:
                scene, bounces = build_parity_scene(name)
            else:
                if name == "materials":
                    scene = build_materials_scene(bpy)
                else:
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
