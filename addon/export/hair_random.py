"""The Principled Hair BSDF's Random Roughness and Random Color (Cycles'
svm_node_closure_bsdf): the hair lobe's roughness, radial roughness and
absorption become the expression engine/nodes/hair_random.py evaluates per
shading point, from the node's Random input, or, unlinked, the Curves Info
node's Random (Cycles reads ATTR_STD_CURVE_RANDOM then; on a mesh, where
Cycles falls back to the socket's value, Ember's Curves Info Random is 0).
bpy-free but for the node handed in."""
from .. import backend


def lobe_fields(translator, node, props):
    """{Lobe field: expression} for a hair node whose ``props`` (the
    EmberPrincipledHairRandom node's: parametrization, constants, amounts)
    randomize it; {} when both amounts are 0."""
    if not props['random_roughness'] and not (props['random_color'] and props['parametrization'] == 'MELANIN'):
        return {}
    scene = backend.engine()
    socket = node.inputs.get('Random')
    if socket is not None and socket.is_linked:
        random = translator.value(node, 'Random', 0.0)
    else:
        random = scene.NodeOutput(scene.NodeCall('ShaderNodeHairInfo', {}, {}), 'Random')
    call = scene.NodeCall('EmberPrincipledHairRandom', {'Random': random}, dict(props))
    return {'roughness': scene.NodeOutput(call, 'Roughness'),
            'radial_roughness': scene.NodeOutput(call, 'Radial Roughness'),
            'absorption': scene.NodeOutput(call, 'Absorption')}
