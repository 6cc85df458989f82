"""The Principled Hair BSDF's Random Roughness and Random Color (Cycles'
svm_node_closure_bsdf): the hair lobe's roughness, radial roughness and
absorption become the expression engine/nodes/hair_random.py evaluates per
shading point, from the node's Random input, or, unlinked, the Curves Info
node's Random on strands (Cycles reads ATTR_STD_CURVE_RANDOM then) and the
socket's value elsewhere (Cycles' fallback where no curve attribute is
found)."""
from .. import backend


def lobe_fields(translator, node, props):
    """{Lobe field: expression} for a hair node whose ``props`` (the
    EmberPrincipledHairRandom node's: parametrization, constants, amounts)
    randomize it; {} when both amounts are 0."""
    if not props['random_roughness'] and not (props['random_color'] and props['parametrization'] == 'MELANIN'):
        return {}
    scene = backend.engine()
    socket = node.inputs.get('Random')
    props = dict(props)
    if socket is not None and socket.is_linked:
        inputs = {'Random': translator.value(node, 'Random', 0.0), 'Is Strand': 1.0}
    else:
        info = scene.NodeCall('ShaderNodeHairInfo', {}, {})
        inputs = {'Random': scene.NodeOutput(info, 'Random'), 'Is Strand': scene.NodeOutput(info, 'Is Strand')}
        props['random_default'] = translator._hair_constant(node, 'Random', 0.0)
    call = scene.NodeCall('EmberPrincipledHairRandom', inputs, props)
    return {'roughness': scene.NodeOutput(call, 'Roughness'),
            'radial_roughness': scene.NodeOutput(call, 'Radial Roughness'),
            'absorption': scene.NodeOutput(call, 'Absorption')}
