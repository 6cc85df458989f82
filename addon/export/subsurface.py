"""Subsurface scattering closures: the Principled BSDF's Subsurface inputs
and the Subsurface Scattering node -> engine subsurface lobes
(engine/lobes/subsurface.py), as Cycles' svm_node_closure_bsdf and
bssrdf_setup build them.

Radius x Scale is the closure's radius (negative and NaN read as 0, as
Cycles' max(radius * scale, 0) does); a channel whose radius is below
Cycles' BSSRDF_MIN_RADIUS (1e-8) scatters as a diffuse lobe of that
channel's weight instead, and a closure with no channel left is a diffuse
lobe.  Radius, Scale, Subsurface IOR and Anisotropy are read as constants
(a linked one is named in the material's warning).  Christensen-Burley
renders as Random Walk (named in the warning).
"""
import math

from .. import backend
from . import nodes

MIN_RADIUS = 1e-8        # Cycles' BSSRDF_MIN_RADIUS
LARGEST = 1e30           # a larger (or infinite) radius renders as this
HUGE = 1e6               # a radius above this (metres) is named in the warning
METHODS = {'RANDOM_WALK': 'subsurface', 'RANDOM_WALK_SKIN': 'subsurface_skin', 'BURLEY': 'subsurface',
           'RANDOM_WALK_FIXED_RADIUS': 'subsurface'}


def _engine():
    return backend.engine()


def _constant(translator, node, name, default):
    """An input's own value (a linked input is named in the warning)."""
    socket = node.inputs.get(name)
    if socket is None:
        return default
    if socket.is_linked:
        translator._note_texture(node, name)
    return nodes.constant(socket)


def _finite(x, default=0.0):
    x = float(x)
    if math.isnan(x):
        return default
    return min(max(x, -LARGEST), LARGEST)


def radius_of(translator, node, radius_name, scale_name):
    """Radius x Scale per channel, clamped to [0, 1e30] (NaN: 0); what is
    unusable or renders unlike its value is named in the warning."""
    radius = _constant(translator, node, radius_name, (1.0, 0.2, 0.1))
    if isinstance(radius, float):
        radius = (radius,) * 3
    raw_scale = _constant(translator, node, scale_name, 1.0) if scale_name else 1.0
    scale = _finite(raw_scale)
    out = tuple(min(max(_finite(_finite(r) * scale), 0.0), LARGEST) for r in radius)
    label = f"'{node.name}'"
    if math.isnan(float(raw_scale)) or any(math.isnan(float(r)) for r in radius):
        translator.reader.warnings.append(f"{label} subsurface {radius_name} x {scale_name} is not a number, "
                                          "read as 0 (diffuse)")
    elif any(r < MIN_RADIUS for r in out):
        translator.reader.warnings.append(f"{label} subsurface radius below 1e-8 m in some channel: those channels "
                                          "render as diffuse (as Cycles)")
    if any(r > HUGE for r in out):
        translator.reader.warnings.append(f"{label} subsurface radius above {HUGE:g} m: light crosses the object "
                                          "almost unscattered")
    return out


def _method(translator, node, prop):
    method = getattr(node, prop, 'RANDOM_WALK')
    if method == 'BURLEY':
        translator._approximate(node, "Christensen-Burley subsurface as Random Walk")
    return METHODS.get(method, 'subsurface')


def _times(color, mask):
    """A colour (or colour expression) times a per-channel 0/1 mask."""
    if nodes.is_expr(color):
        return _engine().MixColor('MULTIPLY', 1.0, color, mask, clamp_factor=False)
    return tuple(float(c) * m for c, m in zip(color, mask))


def lobes(kind, albedo, radius, weight, roughness, ior, anisotropy):
    """The subsurface lobe of a closure and, for channels of too small a
    radius, the diffuse lobe that takes them (Cycles' bssrdf_setup)."""
    scene = _engine()
    small = tuple(1.0 if r < MIN_RADIUS else 0.0 for r in radius)
    if all(small):
        return [scene.Lobe('diffuse', albedo, weight=weight)]
    out = []
    if any(small):
        out.append(scene.Lobe('diffuse', _times(albedo, small), weight=weight))
        albedo = _times(albedo, tuple(1.0 - s for s in small))
        radius = tuple(1.0 if s else r for r, s in zip(radius, small))
    return [scene.Lobe(kind, albedo, roughness, ior=ior, radius=radius, phase_g=anisotropy, weight=weight)] + out


def principled_lobes(translator, node, p, weight):
    """The Principled BSDF's subsurface closure (4.x inputs), weight
    ``weight`` x Subsurface Weight: (lobes, Subsurface Weight); no lobes
    where that is zero (or in 3.x, whose Subsurface input is not rendered)."""
    if 'Subsurface Weight' not in node.inputs:
        return [], 0.0
    ss = nodes.clamp01(translator.value(node, 'Subsurface Weight', 0.0))
    if not nodes.may_exceed(ss, 1e-5):
        return [], 0.0
    kind = _method(translator, node, 'subsurface_method')
    radius = radius_of(translator, node, 'Subsurface Radius', 'Subsurface Scale')
    ior = p['ior']
    if kind == 'subsurface_skin':
        ior = _finite(_constant(translator, node, 'Subsurface IOR', 1.4), 1.4)
    if nodes.is_expr(ior):
        ior = nodes.constant(node.inputs['IOR'])
    anisotropy = _finite(_constant(translator, node, 'Subsurface Anisotropy', 0.0))
    return lobes(kind, p['base_clamped'], radius, nodes.multiply(weight, ss), p['roughness'], _finite(ior, 1.45),
                 anisotropy), ss


def node_lobes(translator, node):
    """The Subsurface Scattering node: albedo Color, radius Radius x Scale,
    entry roughness alpha = Roughness (Cycles' saturate, not squared), IOR,
    Anisotropy."""
    color = translator.color(node, 'Color', (0.8, 0.8, 0.8))
    radius = radius_of(translator, node, 'Radius', 'Scale')
    alpha = min(max(_finite(_constant(translator, node, 'Roughness', 1.0)), 0.0), 1.0)
    ior = _finite(_constant(translator, node, 'IOR', 1.4), 1.4)
    anisotropy = _finite(_constant(translator, node, 'Anisotropy', 0.0))
    return lobes(_method(translator, node, 'falloff'), color, radius, 1.0, math.sqrt(alpha), ior, anisotropy)
