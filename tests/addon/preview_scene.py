"""What the preview tests ask Blender to preview (test_previews.py in bpy,
previews_gui.py in Blender 3.4's window): a red Principled material on the
factory cube, the world's colour, the factory light."""
import bpy

RED = (0.8, 0.05, 0.05, 1.0)


def preview_datablocks(scene):
    """Set the factory scene up; returns {'material', 'world', 'light'}."""
    material = bpy.data.materials.new('Preview Red')
    material.use_nodes = True
    bsdf = next(n for n in material.node_tree.nodes if n.type == 'BSDF_PRINCIPLED')
    bsdf.inputs['Base Color'].default_value = RED
    bpy.data.objects['Cube'].data.materials.append(material)
    scene.world.color = (0.2, 0.3, 0.5)
    return {'material': material, 'world': scene.world, 'light': bpy.data.lights[0]}
