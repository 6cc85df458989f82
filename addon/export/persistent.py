"""Persistent Data (Render > Performance > Final Render > Persistent Data):
the exported meshes kept between the renders of one RenderEngine, so that the
frames of an animation re-export only the geometry the depsgraph says
changed.  Transforms, materials, lights, the world and the camera are read
again every frame (they are cheap); the BVH is reused by the renderer when the
triangles it traces are the same (engine/accel.py BuiltScenes).

Blender keeps the RenderEngine and its depsgraph between frames when the
option is on, and ``depsgraph.updates`` then lists what changed since the
last render (as Cycles' BlenderSync reads it).  A different depsgraph (another
view layer, a reloaded file) starts the cache afresh.
"""
import dataclasses


class MeshCache:
    """Geometry key (as InstanceCollector makes it) -> exported engine Mesh."""

    def __init__(self):
        self.depsgraph_key = None
        self.meshes = []          # engine Meshes, indexed by mesh_of_key's values
        self.mesh_of_key = {}     # key -> index into meshes, or None (no triangles)
        self.warnings_of = {}     # key -> the warning its export gave
        self.owners = {}          # key -> names of the objects (and instancers) that used it
        self.reused = 0           # meshes the last walk did not export again
        self.exported = 0

    def begin(self, depsgraph, view_layer_name):
        """Forget what the depsgraph's updates invalidate (everything when it
        is not the depsgraph of the last render).  Geometry is forgotten by
        the names of the objects that used it (an object, or the instancer
        of its copies), not by data-block address alone: an evaluated mesh
        rebuilt by a modifier may come back at the old address."""
        key = (view_layer_name, depsgraph.as_pointer())
        if key != self.depsgraph_key:
            self.depsgraph_key = key
            self.meshes, self.mesh_of_key, self.warnings_of, self.owners = [], {}, {}, {}
            return
        names, pointers = set(), set()
        for update in depsgraph.updates:
            if not update.is_updated_geometry:
                continue
            ident = update.id
            if type(ident).__name__ == 'Object':
                names.add(ident.name_full)
            else:
                pointers.add(ident.as_pointer())
                original = getattr(ident, 'original', None)
                names.update(user.name_full for user in _users(depsgraph, original or ident))
        for k in list(self.mesh_of_key):
            if k in pointers or self.owners.get(k, set()) & names:
                del self.mesh_of_key[k]
                self.owners.pop(k, None)
                self.warnings_of.pop(k, None)

    def end(self, used, instances, exported):
        """After the walk (``used``: key -> owner names this walk saw): drop
        geometry no instance used (its data block may be freed and its
        address reused) and return (the meshes in use, the instances with
        their indices into that list)."""
        self.exported = exported
        for key in [k for k in self.mesh_of_key if k not in used]:
            del self.mesh_of_key[key]
            self.warnings_of.pop(key, None)
        self.owners = {key: set(names) for key, names in used.items()}
        live = sorted({i for i in self.mesh_of_key.values() if i is not None})
        remap = {old: new for new, old in enumerate(live)}
        self.meshes[:] = [self.meshes[i] for i in live]
        for key, index in self.mesh_of_key.items():
            if index is not None:
                self.mesh_of_key[key] = remap[index]
        self.reused = max(0, len(live) - exported)
        instances = [dataclasses.replace(inst, mesh=remap[inst.mesh]) for inst in instances]
        return list(self.meshes), instances


def _users(depsgraph, data):
    """Objects of the depsgraph whose data is ``data`` (a Mesh or Curve update)."""
    pointer = data.as_pointer()
    for obj in depsgraph.objects:
        source = getattr(obj, 'original', obj)
        if source.data is not None and source.data.as_pointer() == pointer:
            yield obj
