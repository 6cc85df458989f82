"""The differences between the Blender versions Ember supports (3.4 to 5.3)
that more than one exporter module meets, in one place."""
import bpy


def uses_nodes(datablock):
    """Whether a material, world or light is shaded by its node tree.

    Blender 5.0 gives every material and world a node tree and deprecates their
    ``use_nodes`` switch; 5.1 does the same for lights (reading the switch
    there prints a DeprecationWarning and it is always True).  Before that the
    switch decides.
    """
    always_from = (5, 1, 0) if isinstance(datablock, bpy.types.Light) else (5, 0, 0)
    if bpy.app.version >= always_from:
        return getattr(datablock, 'node_tree', None) is not None
    return bool(getattr(datablock, 'use_nodes', False))
