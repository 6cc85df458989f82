"""blend_scenes/: the committed files open here and match their build script."""
import importlib.util
import os

import bpy
import pytest

from ember_testlib import SCENE_NAMES, SCENES_DIR, open_scene


def load_builder():
    spec = importlib.util.spec_from_file_location('build_scenes', os.path.join(SCENES_DIR, 'build_scenes.py'))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def summary():
    """What a scene is made of, rounded so that float noise does not matter."""
    scene = bpy.context.scene
    objects = sorted(
        (obj.name, obj.type, tuple(round(v, 4) for v in obj.matrix_world.translation),
         len(obj.data.polygons) if obj.type == 'MESH' else None)
        for obj in scene.objects)
    lights = sorted((light.name, light.type, round(light.energy, 4)) for light in bpy.data.lights)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    instances = sum(1 for _ in depsgraph.object_instances)
    return objects, lights, instances, tuple(scene.render.resolution[:] if hasattr(scene.render, 'resolution')
                                             else (scene.render.resolution_x, scene.render.resolution_y))


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_committed_scene_matches_builder(name, registered_addon):
    open_scene(name)
    committed = summary()
    load_builder().build(name)
    built = summary()
    assert committed == built, "run blend_scenes/build_scenes.py with Blender 3.4 to refresh the files"


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_scene_opens_with_ember(name, registered_addon):
    """The committed file opens, has a camera, and Ember's export translates
    all of it: no warning (every node known) and a scene that validates."""
    from addon import backend
    from addon.export import scene as scene_export
    scene = open_scene(name)
    assert scene.camera is not None
    assert bpy.data.filepath.endswith(name + '.blend')
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    assert exported.warnings == [], exported.warnings
    backend.engine().validate_scene(exported.scene)
    assert exported.triangles > 0 and exported.scene.lights, "no geometry or no lights exported"
