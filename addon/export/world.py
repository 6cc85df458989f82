"""Blender world -> engine.scene.World (a constant background radiance).

Radiance = Background colour * strength of the node linked to the World
Output, as Cycles; without nodes, ``world.color``; no world renders black, as
in Cycles.  Textures (sky, HDRI) are read as the Background's constant colour
and reported.
"""
BLACK = (0.0, 0.0, 0.0)


def _output_node(tree):
    try:
        node = tree.get_output_node('CYCLES')
    except (AttributeError, TypeError):
        node = None
    if node is None:
        node = next((n for n in tree.nodes if n.type == 'OUTPUT_WORLD'), None)
    return node


def _source(socket):
    """The node feeding a socket, skipping reroutes."""
    while socket.is_linked:
        node = socket.links[0].from_node
        if node.type != 'REROUTE':
            return node
        socket = node.inputs[0]
    return None


def _constant(node, name):
    socket = node.inputs[name]
    value = socket.default_value
    return value if isinstance(value, float) else tuple(value)[:3]


def world_color(world):
    """Returns (rgb radiance, warning or None)."""
    if world is None:
        return BLACK, None
    tree = world.node_tree if _uses_nodes(world) else None
    if tree is None:
        return tuple(float(c) for c in world.color), None
    output = _output_node(tree)
    if output is None:
        return BLACK, None
    node = _source(output.inputs['Surface'])
    if node is None:
        return BLACK, None
    if node.type != 'BACKGROUND':
        return BLACK, f"World '{world.name}': '{node.name}' ({node.bl_idname}) is not supported, world is black"
    warning = None
    if node.inputs['Color'].is_linked or node.inputs['Strength'].is_linked:
        warning = f"World '{world.name}': linked Background inputs are read as their constant values"
    color, strength = _constant(node, 'Color'), float(_constant(node, 'Strength'))
    return tuple(float(c) * strength for c in color), warning


def world_from_blender(world):
    """Returns (engine World, warning or None)."""
    from .. import backend
    color, warning = world_color(world)
    return backend.scene_module().World(color=color), warning


def _uses_nodes(datablock):
    """Blender 5.0 always uses nodes and deprecates the ``use_nodes`` switch."""
    import bpy
    if bpy.app.version >= (5, 0, 0):
        return True
    return bool(getattr(datablock, 'use_nodes', False))
