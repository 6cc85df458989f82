"""Scenes with every kind of Blender instance, for the dupli random_id and
the bulk instance export (test_dupli_random.py, test_bulk_instances.py).
Import after bpy (the add-on tests' conftest)."""
import bpy


def mesh_object(name, verts, faces, collection=None):
    mesh = bpy.data.meshes.new(name + '_mesh')
    mesh.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    obj = bpy.data.objects.new(name, mesh)
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


QUAD = ([(-0.1, -0.1, 0), (0.1, -0.1, 0), (0.1, 0.1, 0), (-0.1, 0.1, 0)], [(0, 1, 2, 3)])


def _tree(name):
    tree = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    tree.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    return tree, tree.nodes.new('NodeGroupInput'), tree.nodes.new('NodeGroupOutput')


def gn_instancer(name, instance, side=4, distribute=False, keep_host=False, rotate=False, collection=None):
    """A mesh object whose geometry nodes put ``instance`` ('grid': a
    realized quad; an Object; a Collection) on a side x side grid (or on
    points distributed on it: those carry an 'id' attribute); ``keep_host``
    joins the host's own grid to the instances; ``rotate``: random rotations."""
    tree, group_in, group_out = _tree(name + 'Tree')
    nodes, links = tree.nodes, tree.links
    grid = nodes.new('GeometryNodeMeshGrid')
    grid.inputs['Vertices X'].default_value = grid.inputs['Vertices Y'].default_value = side
    grid.inputs['Size X'].default_value = grid.inputs['Size Y'].default_value = 2.0
    place = nodes.new('GeometryNodeInstanceOnPoints')
    if distribute:
        points = nodes.new('GeometryNodeDistributePointsOnFaces')
        points.inputs['Density'].default_value = float(side * side) / 4.0
        links.new(grid.outputs['Mesh'], points.inputs['Mesh'])
        links.new(points.outputs['Points'], place.inputs['Points'])
    else:
        links.new(grid.outputs['Mesh'], place.inputs['Points'])
    if instance == 'grid':
        quad = nodes.new('GeometryNodeMeshGrid')
        quad.inputs['Size X'].default_value = quad.inputs['Size Y'].default_value = 0.8 / side
        quad.inputs['Vertices X'].default_value = quad.inputs['Vertices Y'].default_value = 2
        links.new(quad.outputs['Mesh'], place.inputs['Instance'])
    elif isinstance(instance, bpy.types.Collection):
        info = nodes.new('GeometryNodeCollectionInfo')
        info.inputs['Collection'].default_value = instance
        links.new(info.outputs[0], place.inputs['Instance'])
    else:
        info = nodes.new('GeometryNodeObjectInfo')
        info.inputs['Object'].default_value = instance
        info.inputs['As Instance'].default_value = True
        links.new(info.outputs['Geometry'], place.inputs['Instance'])
    if rotate:
        rnd = nodes.new('FunctionNodeRandomValue')
        rnd.data_type = 'FLOAT_VECTOR'
        links.new(rnd.outputs[0], place.inputs['Rotation'])
    out = place.outputs['Instances']
    if keep_host:
        join = nodes.new('GeometryNodeJoinGeometry')
        links.new(group_in.outputs[0], join.inputs[0])
        links.new(out, join.inputs[0])
        out = join.outputs[0]
    links.new(out, group_out.inputs[0])
    host = mesh_object(name, *QUAD, collection=collection)
    host.modifiers.new('Scatter', 'NODES').node_group = tree
    return host


def hidden_collection(name, objects):
    """A collection outside the view layer holding ``objects``."""
    coll = bpy.data.collections.new(name)
    for obj in objects:
        for owner in list(obj.users_collection):
            owner.objects.unlink(obj)
        coll.objects.link(obj)
    return coll


def collection_instance(name, collection, location=(0, 0, 0)):
    empty = bpy.data.objects.new(name, None)
    empty.instance_type = 'COLLECTION'
    empty.instance_collection = collection
    empty.location = location
    bpy.context.scene.collection.objects.link(empty)
    return empty


def particle_instancer(name, instance=None, collection=None, count=20):
    emitter = mesh_object(name, [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [(0, 1, 2, 3)])
    emitter.modifiers.new('Particles', 'PARTICLE_SYSTEM')
    settings = emitter.particle_systems[0].settings
    settings.type = 'HAIR'
    settings.count = count
    if collection is not None:
        settings.render_type, settings.instance_collection = 'COLLECTION', collection
    else:
        settings.render_type, settings.instance_object = 'OBJECT', instance
    settings.particle_size = 0.2
    return emitter


def every_kind():
    """One scene with geometry-nodes instances (of geometry, an object, a
    collection; with ids; nested), collection instances (nested), particle
    instances (object, collection) and vertex instances, some names
    non-ASCII."""
    scene = bpy.context.scene
    for obj in list(scene.objects):
        if obj.type == 'MESH':
            bpy.data.objects.remove(obj)
    leaf = mesh_object('Leaf', *QUAD)
    leaf.location = (0, 0, 5)
    stone = mesh_object('Stöne', *QUAD)
    inner = hidden_collection('Inner', [leaf, stone])
    nested_gn = gn_instancer('NestedGN', 'grid', side=3, collection=inner)
    outer = bpy.data.collections.new('Outer')
    outer.children.link(inner)
    bush = mesh_object('Bush', *QUAD, collection=outer)
    bush.location = (0.3, 0, 0)
    gn_instancer('GNGrid', 'grid', side=5)
    gn_instancer('GNIds', 'grid', side=6, distribute=True, rotate=True)
    gn_instancer('GNObject', leaf, side=3, keep_host=True)
    gn_instancer('GNCollection', outer, side=2)
    collection_instance('CollOuter', outer, (2, 0, 0))
    collection_instance('CollInner·é', inner, (-2, 0, 0))
    particle_instancer('ParticlesObject', instance=leaf)
    particle_instancer('ParticlesCollection', collection=outer, count=5)
    verts = mesh_object('VertHost', [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [])
    child = mesh_object('VertChild', *QUAD)
    child.parent = verts
    verts.instance_type = 'VERTS'
    assert nested_gn.name == 'NestedGN'
    bpy.context.view_layer.update()
    return scene
