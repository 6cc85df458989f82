"""Blender shader node trees -> engine.scene.Material (a weighted set of lobes).

Covered: Diffuse (Oren-Nayar at Roughness > 0), Glossy (anisotropic),
Metallic, Glass, Refraction, Translucent, Transparent, Ray Portal, Sheen, Emission, Hair BSDF,
Principled Hair BSDF (Chiang),
Principled BSDF (Cycles' layering, Anisotropic, Diffuse Roughness, Thin
Film, emission dimmed by sheen and coat), Mix Shader and Add Shader; anisotropic lobes
take the material's tangent (the Tangent input, Cycles' radial tangent
about the object's Z when unlinked); in
the Volume output, Volume Absorption, Volume Scatter, Principled Volume,
Emission, Add and Mix Shader (a medium whose inputs, a Mix Shader's Fac too,
may be textures evaluated at points inside it, engine/media/field.py).  A
node Ember cannot translate becomes a grey diffuse (or a diffuse of the
node's Color input) and is named in one warning per material.  Inputs may be
driven by textures (nodes.SocketReader): lobe colours, roughness, IOR and
weights become texture expressions evaluated per ray, and a lobe is left out
only where its weight's range (nodes.may_exceed) shows it is always zero.
Inputs of features Ember does not render (CONSTANT_VALUE_INPUTS) are read as
their unlinked value, with a warning.
"""
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .. import backend
from . import compat, fluid, hair_random, nodes, subsurface

GREY = (0.8, 0.8, 0.8)
# Principled BSDF inputs (3.x and 4.x names) whose features are not rendered
# yet (3.x's Subsurface renders as diffuse).
PRINCIPLED_UNSUPPORTED = (
    'Subsurface',
    # Blender 5.2: thin-walled transmission; 5.3: dispersion.
    'Thin Wall', 'Transmission Dispersion Scale',
)
# How a warning names them (default: the input's first word).
PRINCIPLED_LABELS = {'Thin Wall': 'Thin Wall', 'Transmission Dispersion Scale': 'Dispersion'}
# Cycles' Diffuse BSDF and Principled switch to Oren-Nayar above this roughness.
DIFFUSE_ROUGHNESS_CUTOFF = 1e-5
# The Glossy BSDF's anisotropy is clamped to this, and isotropic below 1e-4.
GLOSSY_ANISOTROPY_LIMIT = 0.99
# Weights below this are no closure in Cycles (CLOSURE_WEIGHT_CUTOFF).
CUTOFF = 1e-5
# A thin film at most this thick (nm) is no film (Cycles' THINFILM_THICKNESS_CUTOFF).
FILM_CUTOFF = 0.1
BLACK = (0.0, 0.0, 0.0)


@dataclass
class Closure:
    """What a shader socket evaluates to: lobes and emission, before
    weighting.  ``emission_layers``: the indices of the lobes (sheen, coat)
    that dim the emission by their albedo, as Cycles' Principled BSDF."""
    lobes: list = field(default_factory=list)
    emission: tuple = BLACK
    emission_layers: tuple = ()
    holdout: object = 0.0      # the Holdout shader's weight (a constant or an expression)

    def scaled(self, weight):
        """Every lobe and the emission times a Mix Shader factor.  A lobe's
        weight carries it (its colour also enters Fresnel, multiscatter and
        layering terms, which a mix must not change)."""
        lobes = [dataclasses.replace(lobe, weight=nodes.multiply(lobe.weight, weight))
                 for lobe in self.lobes]
        return Closure(lobes, _scale(self.emission, weight), self.emission_layers,
                       _holdout_op(nodes.multiply, self.holdout, weight))

    def plus(self, other):
        """Both closures; the emission keeps the layers of the one that has
        emission (two emissions, one under layers: the caller is told by
        ``mixed_dimming``)."""
        shifted = tuple(k + len(self.lobes) for k in other.emission_layers)
        layers = self.emission_layers if _has_emission(self.emission) else ()
        if _has_emission(other.emission):
            layers = layers + shifted
        return Closure(self.lobes + other.lobes, _add(self.emission, other.emission), layers,
                       _holdout_op(lambda a, b: nodes.math('ADD', a, b), self.holdout, other.holdout))

    def mixed_dimming(self, other):
        """Two emissions of which only one lies under layers (rendered with
        the layers dimming both)."""
        return (_has_emission(self.emission) and _has_emission(other.emission)
                and bool(self.emission_layers) != bool(other.emission_layers))


def _holdout_op(op, holdout, other):
    """op(holdout, other) for a Holdout weight; no Holdout (the constant 0)
    stays 0 under a Mix factor and adds nothing, so most materials carry no
    holdout expression."""
    if not nodes.is_expr(holdout) and float(holdout) == 0.0:
        return 0.0 if op is nodes.multiply else other
    return op(holdout, other)


def _has_emission(emission):
    return nodes.is_expr(emission) or any(c != 0.0 for c in emission)


# Colours, roughness, IOR and weights may be texture expressions: nodes'
# helpers combine constants and expressions alike.
_scale = nodes.scale
_add = nodes.add
_mix = nodes.mix
_clamp01 = nodes.clamp01
_mul = nodes.multiply
_one_minus = nodes.one_minus
# Float inputs of features Ember does not render (they only decide a
# warning): a texture on them is read as its constant.
CONSTANT_VALUE_INPUTS = PRINCIPLED_UNSUPPORTED + ('Anisotropy',)


class NodeTranslator:
    """Translates one material's node tree, remembering what it could not."""

    def __init__(self, material_name):
        self.material_name = material_name
        self.unsupported = []   # node labels, in order of discovery
        self.textured = []      # "node.input" names read as constants
        self.approximated = []  # Principled BSDF features not rendered yet
        self.unsupported_volume = []   # volume nodes not rendered
        self.volume_notes = []         # volume features approximated
        self.reader = nodes.SocketReader(self._linked_node)
        self.tangent = None            # the anisotropic lobes' tangent expression

    # -- socket values --------------------------------------------------------

    def _linked_node(self, socket):
        """The node feeding a socket: reroutes and muted links skipped,
        node groups inlined (nodes.linked_node)."""
        return nodes.linked_node(socket)

    def _read(self, node, name):
        """The input's constant or texture expression (nodes.SocketReader);
        an untranslatable link falls back to the socket's own value."""
        socket = node.inputs.get(name)
        value = self.reader.read(socket)
        if value is None:
            self._note_texture(node, name)
            value = nodes.constant(socket)
        return value

    def color(self, node, name, default=GREY):
        """RGB tuple or texture expression."""
        if node.inputs.get(name) is None:
            return default
        value = self._read(node, name)
        return (value, value, value) if isinstance(value, float) else value

    def value(self, node, name, default=0.0):
        """A float, or a float texture expression (a colour one is read as
        its luminance); CONSTANT_VALUE_INPUTS are always constants."""
        socket = node.inputs.get(name)
        if socket is None:
            return default
        value = self._read(node, name)
        if nodes.is_expr(value) and name in CONSTANT_VALUE_INPUTS:
            self._note_texture(node, name)
            value = nodes.constant(socket)
        if nodes.is_expr(value):
            return nodes.as_value(value)
        return nodes.luminance(value) if isinstance(value, tuple) else float(value)

    def _note_texture(self, node, name):
        label = f"{node.name}.{name}"
        if label not in self.textured:
            self.textured.append(label)

    # -- closures -------------------------------------------------------------

    def surface(self, socket):
        node, out = self._linked_node(socket)
        if node is None or node.type == 'GROUP_DEFAULT':
            return Closure()  # an unlinked surface renders black, as in Cycles
        if node.mute:
            # Cycles passes a muted node's first matching input through.
            source = nodes.muted_source(node, out)
            return Closure() if source is None else self.surface(source)
        handler = getattr(self, '_node_' + node.type.lower(), None)
        if handler is None:
            return self._fallback(node)
        return handler(node)

    def _fallback(self, node):
        """Grey diffuse, or a diffuse of the node's Color input if it has one."""
        label = f"'{node.name}' ({node.bl_idname})"
        if label not in self.unsupported:
            self.unsupported.append(label)
        socket = node.inputs.get('Color')
        color = GREY
        if socket is not None and not isinstance(socket.default_value, float):
            color = tuple(socket.default_value)[:3]
        return Closure([_scene().Lobe('diffuse', color)])

    def _node_bsdf_diffuse(self, node):
        """Lambert, or Cycles' energy-preserving Oren-Nayar where Roughness
        may exceed 1e-5 (Cycles' switch)."""
        color = self.color(node, 'Color')
        roughness = self._finite_value(node, 'Roughness', self.value(node, 'Roughness', 0.0), 0.0)
        if nodes.may_exceed(roughness, DIFFUSE_ROUGHNESS_CUTOFF):
            return Closure([_scene().Lobe('oren_nayar', color, diffuse_roughness=_clamp01(roughness))])
        return Closure([_scene().Lobe('diffuse', color)])

    def _finite_value(self, node, name, value, fallback):
        """A constant input read as ``fallback`` where it is not finite (NaN,
        infinities), named in the material's warning; expressions are made
        finite per ray by the engine."""
        if nodes.is_expr(value) or math.isfinite(value):
            return value
        note = f"'{node.name}' {name} {value} read as {fallback:g}"
        if note not in self.reader.warnings:
            self.reader.warnings.append(note)
        return fallback

    def _use_tangent(self, node):
        """The material's tangent for an anisotropic lobe of ``node``: its
        Tangent input, Cycles' default radial tangent about Z when unlinked
        (ShaderGraph's LINK_TANGENT); one tangent per material."""
        socket = node.inputs.get('Tangent')
        value = None
        if socket is not None and socket.is_linked:
            value = self.reader.read(socket)
            if not isinstance(value, _scene().NodeOutput):
                self._approximate(node, "Tangent input read as the radial tangent")
                value = None
        if value is None:
            value = _scene().NodeOutput(_scene().NodeCall('ShaderNodeTangent', {}, {
                'direction_type': 'RADIAL', 'axis': 'Z', 'uv_map': ''}), 'Tangent')
        if self.tangent is None:
            self.tangent = value
        elif not _same_tangent(self.tangent, value):
            self.reader.warnings.append(f"one tangent per material: the tangent of '{node.name}' is replaced by "
                                        "the first anisotropic shader's")

    def _anisotropic(self, node, kind, anisotropy, rotation, **lobe):
        """A glossy lobe, anisotropic (with the material's tangent) where
        ``anisotropy`` (Ember's lobe value, Principled mapping) may be > 0."""
        if nodes.may_exceed(anisotropy, 0.0):
            self._use_tangent(node)
            return _scene().Lobe('glossy_anisotropic', anisotropy=anisotropy, rotation=rotation, **lobe)
        return _scene().Lobe(kind, **lobe)

    def _multiscatter(self, node):
        """Multiscatter GGX (Blender 5.0's default) or single-scatter GGX;
        Beckmann and Ashikhmin-Shirley are rendered as GGX, with a warning."""
        dist = getattr(node, 'distribution', 'GGX')
        if dist not in ('GGX', 'MULTI_GGX', 'SHARP'):
            self._approximate(node, f"{dist.title()} as GGX")
        return dist == 'MULTI_GGX'

    def _approximate(self, node, what):
        label = f"'{node.name}' ({what})"
        if label not in self.approximated:
            self.approximated.append(label)

    def _node_bsdf_glossy(self, node):
        """GGX reflection; with Anisotropy (Blender 4.0+, clamped to +-0.99,
        isotropic below 1e-4) Cycles' Glossy mapping alpha_x = alpha (1 - a),
        alpha_y = alpha / (1 - a) (a > 0; the reverse for a < 0), held as the
        Principled mapping's (1 - (1 - |a|)^2) / 0.9 with the tangent turned a
        quarter where the long axis is the bitangent."""
        roughness = _clamp01(self.value(node, 'Roughness', 0.5))
        lobe = dict(color=self.color(node, 'Color'), roughness=roughness, fresnel='none',
                    multiscatter=self._multiscatter(node))
        a = 0.0
        if 'Anisotropy' in node.inputs:
            a = self._finite_value(node, 'Anisotropy', self.value(node, 'Anisotropy', 0.0), 0.0)
            a = min(max(a, -GLOSSY_ANISOTROPY_LIMIT), GLOSSY_ANISOTROPY_LIMIT)
        if abs(a) <= 1e-4:
            return Closure([_scene().Lobe('glossy', **lobe)])
        rotation = self._finite_value(node, 'Rotation', self.value(node, 'Rotation', 0.0), 0.0)
        rotation = nodes.math('ADD', rotation, 0.25) if a > 0 else rotation
        aspect = 1.0 - abs(a)
        return Closure([self._anisotropic(node, 'glossy', (1.0 - aspect * aspect) / 0.9, rotation, **lobe)])

    def _node_bsdf_metallic(self, node):
        """Cycles' Metallic BSDF (4.3+): F82 Tint (Base Color as F0, Edge Tint
        as F82 tint), or a Physical Conductor (IOR n and Extinction k per
        channel: the exact conductor Fresnel, Cycles' MicrofacetFresnel::
        CONDUCTOR, its film over n + i k); Principled anisotropy mapping."""
        roughness = _clamp01(self.value(node, 'Roughness', 0.5))
        if getattr(node, 'fresnel_type', 'F82') == 'PHYSICAL_CONDUCTOR':
            # The conductor lobe holds n in f0 and k in edge_tint (engine/lobes/registry.py).
            fresnel = 'conductor'
            f0 = _conductor_part(_constant_color(self, node, 'IOR', (0.2, 0.9, 1.1)))
            tint = _conductor_part(_constant_color(self, node, 'Extinction', (3.9, 2.45, 2.14)))
        else:
            fresnel = 'f82'
            f0 = _clamp_color(self.color(node, 'Base Color', (0.617, 0.577, 0.540)))
            tint = _clamp_color(self.color(node, 'Edge Tint', (0.695, 0.726, 0.770)))
        anisotropy = _clamp01(self._finite_value(node, 'Anisotropy', self.value(node, 'Anisotropy', 0.0), 0.0))
        rotation = self._finite_value(node, 'Rotation', self.value(node, 'Rotation', 0.0), 0.0)
        lobe = dict(color=(1.0, 1.0, 1.0), roughness=roughness, fresnel=fresnel, f0=f0, edge_tint=tint,
                    multiscatter=getattr(node, 'distribution', 'MULTI_GGX') == 'MULTI_GGX', **self._thin_film(node))
        if getattr(node, 'distribution', 'MULTI_GGX') not in ('GGX', 'MULTI_GGX'):
            self._approximate(node, f"{node.distribution.title()} as GGX")
        return Closure([self._anisotropic(node, 'glossy', anisotropy, rotation, **lobe)])

    def _thin_film(self, node):
        """The thin-film lobe parameters of a node with Thin Film Thickness /
        IOR inputs (Principled 4.2+, Metallic and Glass 5.0): none where the
        thickness is never above the cutoff (Cycles' no film); the film IOR
        at least 1e-5 (svm_node_closure_bsdf)."""
        if 'Thin Film Thickness' not in node.inputs:
            return {}
        thickness = self._finite_value(node, 'Thin Film Thickness', self.value(node, 'Thin Film Thickness', 0.0), 0.0)
        if not nodes.may_exceed(thickness, FILM_CUTOFF):
            return {}
        film_ior = self._finite_value(node, 'Thin Film IOR', self.value(node, 'Thin Film IOR', 1.33), 1.33)
        return dict(thin_film_thickness=thickness, thin_film_ior=nodes.at_least(film_ior, 1e-5))

    def _value_linked(self, node, name):
        socket = node.inputs.get(name)
        return socket is not None and socket.is_linked

    # Blender 5.0 registers the Glossy BSDF under the anisotropic type.
    _node_bsdf_anisotropic = _node_bsdf_glossy

    def _node_bsdf_glass(self, node):
        """Cycles' Glass BSDF: the colour tints reflection and refraction
        (5.3's Anisotropy renders as isotropic, with a warning)."""
        roughness = _clamp01(self.value(node, 'Roughness', 0.0))
        if 'Anisotropy' in node.inputs and self.value(node, 'Anisotropy', 0.0) != 0.0:
            self._approximate(node, "Anisotropy")
        ior = nodes.at_least(self.value(node, 'IOR', 1.5), 1e-5)
        return Closure([_scene().Lobe('glass', self.color(node, 'Color', (1.0, 1.0, 1.0)), roughness,
                                      'dielectric', ior=ior, multiscatter=self._multiscatter(node),
                                      **self._thin_film(node))])

    def _node_bsdf_refraction(self, node):
        """Refraction only, no Fresnel (total internal reflection absorbs)."""
        roughness = _clamp01(self.value(node, 'Roughness', 0.0))
        ior = nodes.at_least(self.value(node, 'IOR', 1.5), 1e-5)
        self._multiscatter(node)
        return Closure([_scene().Lobe('refraction', self.color(node, 'Color', (1.0, 1.0, 1.0)),
                                      roughness, ior=ior)])

    def _node_bsdf_translucent(self, node):
        return Closure([_scene().Lobe('translucent', self.color(node, 'Color'))])

    def _node_bsdf_transparent(self, node):
        return Closure([_scene().Lobe('transparent', self.color(node, 'Color', (1.0, 1.0, 1.0)))])

    def _node_bsdf_ray_portal(self, node):
        """Ray Portal BSDF (4.2+, engine/lobes/ray_portal.py): an unlinked
        Position is the hit point (Cycles' LINK_POSITION), left NaN; an
        unlinked or zero Direction the incoming ray's."""
        socket = node.inputs.get('Position')
        linked = socket is not None and self._linked_node(socket)[0] is not None
        position = self.color(node, 'Position') if linked else (float('nan'),) * 3
        direction = self.color(node, 'Direction', (0.0, 0.0, 0.0))
        if not nodes.is_expr(direction) and not any(direction):
            direction = (float('nan'),) * 3
        return Closure([_scene().Lobe('ray_portal', self.color(node, 'Color', (1.0, 1.0, 1.0)),
                                      portal_position=position, portal_direction=direction)])

    def _node_bsdf_sheen(self, node):
        """Blender 4.0+ Sheen BSDF (Microfiber: Cycles' LTC sheen)."""
        roughness = _clamp01(self.value(node, 'Roughness', 0.5))
        return Closure([_scene().Lobe('sheen', self.color(node, 'Color'), roughness)])

    def _hair_constant(self, node, name, default):
        """A hair input as a finite constant (a linked one: its own value, named)."""
        socket = node.inputs.get(name)
        if socket is None:
            return default
        value = self.value(node, name, default)
        if nodes.is_expr(value):
            self._note_texture(node, name)
            value = float(nodes.constant(socket))
        return self._finite_value(node, name, float(value), default)

    def _node_bsdf_hair_principled(self, node):
        """Cycles' Principled Hair BSDF, Chiang model (svm_node_closure_bsdf):
        the absorption from Direct Coloring, Melanin Concentration or the
        Absorption Coefficient; roughness, radial roughness, coat, IOR and
        offset as constants; Random Roughness and Random Color per strand
        (hair_random.py).  The Huang model (4.0+): its Aspect Ratio and the
        Reflection / Transmission / Secondary Reflection gains as constants,
        the radial roughness its roughness (as Cycles' svm node)."""
        huang = getattr(node, 'model', 'CHIANG') == 'HUANG'
        c = lambda name, default: self._hair_constant(node, name, default)  # noqa: E731
        roughness = _clamp01(c('Roughness', 0.3))
        radial = roughness if huang else _clamp01(c('Radial Roughness', 0.3))
        mode = getattr(node, 'parametrization', 'COLOR')
        if mode == 'ABSORPTION':
            sigma = _constant_color(self, node, 'Absorption Coefficient', (0.245531, 0.52, 1.365))
        elif mode == 'MELANIN':
            sigma = _scene().hair_sigma_from_melanin(c('Melanin', 0.8), c('Melanin Redness', 1.0),
                                                     _constant_color(self, node, 'Tint', (1.0, 1.0, 1.0)), radial)
        else:
            sigma = _scene().hair_sigma_from_color(
                _constant_color(self, node, 'Color', (0.017513, 0.005763, 0.002059)), radial)
        sigma = tuple(float(x) for x in np.nan_to_num(np.maximum(sigma, 0.0), nan=0.0, posinf=1e30))
        fields = dict(roughness=roughness, absorption=sigma, radial_roughness=radial)
        fields.update(hair_random.lobe_fields(self, node, dict(
            parametrization=mode, melanin=c('Melanin', 0.8), redness=c('Melanin Redness', 1.0),
            tint=_constant_color(self, node, 'Tint', (1.0, 1.0, 1.0)),
            color=_constant_color(self, node, 'Color', (0.017513, 0.005763, 0.002059)),
            absorption=_constant_color(self, node, 'Absorption Coefficient', (0.245531, 0.52, 1.365)),
            roughness=roughness, radial_roughness=radial, random_roughness=c('Random Roughness', 0.0),
            random_color=c('Random Color', 0.0))))
        if huang:
            gains = tuple(max(c(name, 1.0), 0.0) for name in ('Reflection', 'Transmission', 'Secondary Reflection'))
            if not any(gains):
                return Closure([])   # Cycles allocates no closure
            fields.pop('radial_roughness', None)
            return Closure([_scene().Lobe('hair_huang', (1.0, 1.0, 1.0), ior=c('IOR', 1.55),
                                          offset=c('Offset', 2.0 * math.pi / 180.0),
                                          aspect_ratio=c('Aspect Ratio', 0.85), hair_gains=gains, **fields)])
        return Closure([_scene().Lobe('hair_chiang', (1.0, 1.0, 1.0), ior=c('IOR', 1.55), coat=_clamp01(c('Coat', 0.0)),
                                      offset=c('Offset', 2.0 * math.pi / 180.0), **fields)])

    def _node_bsdf_hair(self, node):
        """Cycles' Hair BSDF (bsdf_hair.h): one Reflection or Transmission
        lobe about the curve's tangent (engine/lobes/hair_bsdf.py); RoughnessV
        and Offset as constants.  A linked Tangent input is read as the
        curve's tangent, with a warning."""
        if self._value_linked(node, 'Tangent'):
            self._approximate(node, "Tangent input read as the curve's tangent")
        kind = 'hair_transmission' if getattr(node, 'component', 'Reflection') == 'Transmission' else 'hair_reflection'
        roughness = _clamp01(self._finite_value(node, 'RoughnessU', self.value(node, 'RoughnessU', 0.1), 0.1))
        return Closure([_scene().Lobe(kind, self.color(node, 'Color'), roughness,
                                      radial_roughness=_clamp01(self._hair_constant(node, 'RoughnessV', 1.0)),
                                      offset=self._hair_constant(node, 'Offset', 0.0))])

    def _node_subsurface_scattering(self, node):
        """Cycles' Subsurface Scattering node (Random Walk, Skin, Christensen-Burley)."""
        return Closure(subsurface.node_lobes(self, node))

    def _node_holdout(self, node):
        """Cycles' Holdout: no light, and camera rays uncover the film."""
        return Closure(holdout=1.0)

    def _node_emission(self, node):
        strength = self.value(node, 'Strength', 1.0)
        return Closure([], _scale(self.color(node, 'Color', (1.0, 1.0, 1.0)), strength))

    def _node_bsdf_principled(self, node):
        """Cycles' Principled BSDF (svm/closure.h): transparency, then sheen
        over coat over [metal | transmission | specular over diffuse], each
        layer weighing down what it covers by its albedo."""
        p = _principled_inputs(self, node)
        self._note_principled_features(node)
        top = self._principled_layers(p)
        base = self._principled_base(p, node)
        for i, lobe in enumerate(top):
            top[i] = dataclasses.replace(lobe, covers=len(top) - 1 - i + len(base))
        lobes = top + base
        layers = tuple(range(len(top)))       # sheen and coat dim the emission (Cycles)
        if nodes.may_be_below(p['alpha'], 1.0):
            lobes = [_scene().Lobe('transparent', (1.0, 1.0, 1.0), weight=_one_minus(p['alpha']))] + lobes
            layers = tuple(k + 1 for k in layers)
        return Closure(lobes, _scale(_principled_emission(self, node), p['alpha']), layers)

    def _principled_layers(self, p):
        """Sheen and coat, the layers on top (covers set by the caller)."""
        scene = _scene()
        layers = []
        if nodes.may_exceed(p['sheen'], CUTOFF):
            layers.append(scene.Lobe('sheen', _scale(p['sheen_tint'], p['sheen']), p['sheen_roughness'],
                                     weight=p['alpha']))
        if nodes.may_exceed(p['coat'], CUTOFF):
            # The coat weight is the layer's colour (its albedo estimate and
            # the coat tint's mix both scale with it).
            layers.append(scene.Lobe('glossy', _grey(p['coat']), p['coat_roughness'], 'dielectric',
                                     ior=p['coat_ior'], multiscatter=True, absorb=p['coat_tint'],
                                     weight=p['alpha']))
        return layers

    def _principled_base(self, p, node):
        """Metal, transmission, specular layer and diffuse, with their weights
        (per ray where an input is textured; a lobe is left out where its
        weight is zero everywhere)."""
        scene = _scene()
        lobes = []
        w = p['alpha']
        ms = p['multiscatter']
        film = self._thin_film(node)     # over the metal, the glass and the specular layer (Cycles)
        if nodes.may_exceed(p['metallic'], CUTOFF):
            lobes.append(self._anisotropic(p['node'], 'glossy', p['anisotropic'], p['rotation'],
                                           color=(1.0, 1.0, 1.0), roughness=p['roughness'], fresnel='f82',
                                           f0=p['base_clamped'], edge_tint=_clamp_color(p['specular_tint']),
                                           multiscatter=ms, weight=_mul(w, p['metallic']), **film))
            w = _mul(w, _one_minus(p['metallic']))
        if nodes.may_exceed(p['transmission'], CUTOFF) and nodes.may_exceed(w, 0.0):
            f0 = _clamp_color(_scale(p['specular_tint'], _f0_from_ior(p['ior'])))
            lobes.append(scene.Lobe('glass', (1.0, 1.0, 1.0), p['roughness'], 'dielectric', ior=p['ior'],
                                    f0=f0, transmission_tint=_sqrt_color(p['base_clamped']),
                                    multiscatter=ms, weight=_mul(w, p['transmission']), **film))
            w = _mul(w, _one_minus(p['transmission']))
        if not nodes.may_exceed(w, 0.0):
            return lobes
        eta, f0 = p['specular_eta'], p['specular_f0']
        below, ss = subsurface.principled_lobes(self, node, p, w)   # under the specular layer
        rest = _mul(w, _one_minus(ss)) if below else w
        if not below or nodes.may_exceed(rest, 0.0):
            if nodes.may_exceed(p['diffuse_roughness'], DIFFUSE_ROUGHNESS_CUTOFF):
                below.append(scene.Lobe('oren_nayar', p['base'], diffuse_roughness=p['diffuse_roughness'],
                                        weight=rest))
            else:
                below.append(scene.Lobe('diffuse', p['base'], weight=rest))
        # Cycles' specular layer: where eta != 1 or a film is on it.
        if nodes.is_expr(eta) or eta != 1.0 or film:
            lobes.append(self._anisotropic(p['node'], 'glossy', p['anisotropic'], p['rotation'],
                                           color=(1.0, 1.0, 1.0), roughness=p['roughness'], fresnel='dielectric',
                                           ior=eta, f0=_clamp_color(_scale(p['specular_tint'], f0)),
                                           covers=len(below), multiscatter=ms, weight=w, **film))
        return lobes + below

    def _note_principled_features(self, node):
        """Name the Principled features in use that Ember does not render yet."""
        used = [PRINCIPLED_LABELS.get(name, name.split()[0]) for name in PRINCIPLED_UNSUPPORTED
                if name in node.inputs and (self._value_linked(node, name)
                                            or self._finite_value(node, name, self.value(node, name, 0.0), 0.0) > 0.0)]
        if used:
            self._approximate(node, ', '.join(used))

    def _node_mix_shader(self, node):
        fac = _clamp01(self.value(node, 'Fac', 0.5))
        first = self.surface(node.inputs[1]).scaled(_one_minus(fac))
        second = self.surface(node.inputs[2]).scaled(fac)
        return self._sum(node, first, second)

    def _node_add_shader(self, node):
        return self._sum(node, self.surface(node.inputs[0]), self.surface(node.inputs[1]))

    def _sum(self, node, a, b):
        if a.mixed_dimming(b):
            self._approximate(node, "an emission beside a sheen- or coat-dimmed one dimmed alike")
        return a.plus(b)

    # -- volumes ---------------------------------------------------------------

    def volume(self, socket):
        """The medium a Volume socket evaluates to (its inputs constants or
        texture expressions; an untranslatable link is read as the socket's
        own value, with a warning)."""
        node, out = self._linked_node(socket)
        if node is None or node.type == 'GROUP_DEFAULT':
            return VolumeClosure()
        if node.mute:
            source = nodes.muted_source(node, out)
            return VolumeClosure() if source is None else self.volume(source)
        handler = getattr(self, '_volume_' + node.type.lower(), None)
        if handler is None:
            label = f"'{node.name}' ({node.bl_idname}) in the Volume output"
            if label not in self.unsupported_volume:
                self.unsupported_volume.append(label)
            return VolumeClosure()
        return handler(node)

    def _volume_const(self, node, name, default, color=False):
        """A constant input of a volume node (a texture on it is read as
        the socket's own value, named in a warning), with NaN read as 0 and
        infinities as the largest value, named in a warning."""
        socket = node.inputs.get(name)
        if socket is None:
            return default
        value = self.reader.read(socket) if socket.is_linked else nodes.constant(socket)
        if value is None or nodes.is_expr(value):
            self._note_texture(node, name)
            value = nodes.constant(socket)
        return self._const(node, name, value, color)

    def _const(self, node, name, value, color):
        if color:
            value = (float(value),) * 3 if isinstance(value, (float, int)) else tuple(float(c) for c in value[:3])
            return tuple(self._finite(node, name, c) for c in value)
        return self._finite(node, name, nodes.luminance(value) if isinstance(value, tuple) else float(value))

    def _volume_input(self, node, name, default, color=False):
        """A volume node's input: a constant, or a texture expression
        evaluated at points inside the medium (a heterogeneous medium:
        engine/media/field.py); an untranslatable link is read as the
        socket's value, named in a warning."""
        socket = node.inputs.get(name)
        if socket is None:
            return default
        if not socket.is_linked:
            return self._const(node, name, nodes.constant(socket), color)
        value = self.reader.read(socket)
        if value is None:
            self._note_texture(node, name)
            return self._const(node, name, nodes.constant(socket), color)
        if not nodes.is_expr(value):
            return self._const(node, name, value, color)
        if color:
            return value
        return nodes.as_value(value)

    def _finite(self, node, name, value):
        if math.isfinite(value):
            return value
        fixed = 0.0 if math.isnan(value) else math.copysign(VOLUME_LIMIT, value)
        note = f"'{node.name}' {name} {value} read as {fixed:g}"
        if note not in self.reader.warnings:
            self.reader.warnings.append(note)
        return fixed

    def _density(self, node):
        """Density, negative read as 0 (Cycles' fmaxf(density, 0))."""
        d = self._volume_input(node, 'Density', 1.0)
        return nodes.at_least(d, 0.0) if nodes.is_expr(d) else max(d, 0.0)

    def _volume_volume_absorption(self, node):
        color = self._volume_input(node, 'Color', GREY, color=True)
        return VolumeClosure(absorption=_times(_positive(_one_minus_color(color)), self._density(node)))

    def _volume_volume_scatter(self, node):
        """Henyey-Greenstein; the other phase functions (Blender 4.2+) are
        rendered as Henyey-Greenstein of the node's Anisotropy (Rayleigh: 0)."""
        color = self._volume_input(node, 'Color', GREY, color=True)
        d = self._density(node)
        phase = getattr(node, 'phase', 'HENYEY_GREENSTEIN')
        # Henyey-Greenstein's g may vary per point (the medium's field
        # evaluates it); the other phase functions take constants.
        g = (self._volume_input(node, 'Anisotropy', 0.0) if phase == 'HENYEY_GREENSTEIN'
             else self._volume_const(node, 'Anisotropy', 0.0))
        out = VolumeClosure(scattering=_times(_positive(color), d)).with_phase(g)
        if phase != 'HENYEY_GREENSTEIN':
            spec = (phase, self._volume_const(node, 'Alpha', 0.5), self._volume_const(node, 'Backscatter', 0.1),
                    self._volume_const(node, 'IOR', 1.33), self._volume_const(node, 'Diameter', 20.0))
            out = dataclasses.replace(out, phase_spec=_valid_phase(spec))
        return out

    def _volume_principled_volume(self, node):
        """Cycles' svm_node_principled_volume: scattering Color x Density,
        absorption (1 - Color)(1 - sqrt(Absorption Color)) x Density,
        emission Strength x Color plus blackbody.  In a gas fluid domain's
        material, Density, Color and Temperature are multiplied by the
        domain's grids their attribute inputs name (Cycles: where the
        object has such an attribute); so in a Volume object's material."""
        fluid_grids = fluid.material_on_grids(self.material_name)
        color = self._volume_input(node, 'Color', (0.5, 0.5, 0.5), color=True)
        d = self._density(node)
        if fluid_grids:
            d = self._by_attribute(node, 'Density Attribute', d)
            color = self._by_attribute(node, 'Color Attribute', color, color=True)
        g = self._volume_input(node, 'Anisotropy', 0.0)
        ac = self._volume_input(node, 'Absorption Color', (0.0, 0.0, 0.0), color=True)
        strength = self._volume_input(node, 'Emission Strength', 0.0)
        ec = self._volume_input(node, 'Emission Color', (1.0, 1.0, 1.0), color=True)
        blackbody = self._volume_input(node, 'Blackbody Intensity', 0.0)
        out = VolumeClosure()
        if nodes.may_exceed(d, 0.0):
            tint = _absorption_tint(ac)
            out = VolumeClosure(absorption=_times(_times(_positive(_one_minus_color(color)), tint), d),
                                scattering=_times(_positive(color), d)).with_phase(g)
        if nodes.may_exceed(strength, CUTOFF):
            # Cycles emits where Strength > CUTOFF (per point where textured).
            strength = nodes.math('MULTIPLY', strength, _above(strength, CUTOFF)) if nodes.is_expr(strength) \
                else strength
            out = out.plus(VolumeClosure(emission=_times(ec, strength)))
        if nodes.may_exceed(blackbody, CUTOFF):
            temperature = self._attribute_name(node, 'Temperature Attribute') if fluid_grids else ''
            out = out.plus(VolumeClosure(emission=self._blackbody(node, blackbody, temperature)))
        return out

    def _attribute_name(self, node, name):
        socket = node.inputs.get(name)
        return str(socket.default_value) if socket is not None else ''

    def _attribute(self, name, output):
        return grid_attribute(name, output)

    def _by_attribute(self, node, socket_name, value, color=False):
        name = self._attribute_name(node, socket_name)
        if not name or (not nodes.is_expr(value) and not color and value == 0.0):
            return value
        if color:
            return _times(value, self._attribute(name, 'Color'))
        return nodes.at_least(nodes.math('MULTIPLY', value, self._attribute(name, 'Fac')), 0.0)

    def _blackbody(self, node, intensity, attribute=''):
        """Cycles' Principled Volume blackbody emission: tint x sigma x
        mix(1, T^4, intensity) x the blackbody colour of T (the fit
        unclamped where textured, negative in blue below about 1500 K as
        Cycles'; a constant's clamped at 0), T = max(T, 0)
        (times max(the attribute, 0): a domain's temperature grid), none
        where the intensity or sigma x mix(...) is at most CUTOFF (Stefan-
        Boltzmann, sigma = 5.670373e-8 1e-6 / pi).  Temperature, intensity
        and tint may be textured: an expression evaluated per point."""
        t = self._volume_input(node, 'Temperature', 1000.0)
        tint = self._volume_input(node, 'Blackbody Tint', (1.0, 1.0, 1.0), color=True)
        if attribute:
            t = nodes.math('MULTIPLY', nodes.at_least(self._attribute(attribute, 'Fac'), 0.0), t)
        sigma = 5.670373e-8 * 1e-6 / math.pi
        if not any(nodes.is_expr(x) for x in (t, intensity, tint)):
            t = max(t, 0.0)
            power = sigma * ((1.0 - intensity) + intensity * min(t, 1e75) ** 4)
            if power <= CUTOFF:
                return BLACK
            rgb = _blackbody_rgb(t)
            return tuple(min(float(c) * power * float(x), VOLUME_LIMIT) for c, x in zip(tint, rgb))
        renderer = backend.engine()
        t = nodes.at_least(t, 0.0)
        rgb = (_blackbody_rgb(t) if not nodes.is_expr(t)
               else renderer.NodeOutput(renderer.NodeCall('ShaderNodeBlackbody', {'Temperature': t},
                                                          {'_unclamped': True}), 'Color'))
        t4 = nodes.math('MULTIPLY', nodes.math('MULTIPLY', t, t), nodes.math('MULTIPLY', t, t))
        power = nodes.math('ADD', nodes.math('MULTIPLY', t4, nodes.math('MULTIPLY', intensity, sigma)),
                           nodes.math('MULTIPLY', nodes.math('SUBTRACT', 1.0, intensity), sigma))
        # Cycles' two cut-offs, per point: 1 where both pass, else 0.
        gate = nodes.math('MULTIPLY', _above(power, CUTOFF), _above(intensity, CUTOFF))
        return _times(_times(rgb, nodes.math('MULTIPLY', power, gate)), tint)

    def _volume_emission(self, node):
        strength = self._volume_input(node, 'Strength', 1.0)
        color = self._volume_input(node, 'Color', (1.0, 1.0, 1.0), color=True)
        return VolumeClosure(emission=_times(color, strength))

    def _volume_add_shader(self, node):
        return self._volume_sum(self.volume(node.inputs[0]), self.volume(node.inputs[1]), node)

    def _volume_mix_shader(self, node):
        """Cycles' svm_node_mix_closure: the two closures weighted by
        1 - saturate(Fac) and saturate(Fac), per point where Fac is textured."""
        fac = nodes.clamp01(self._volume_input(node, 'Fac', 0.5))
        return self._volume_sum(self.volume(node.inputs[1]).scaled(_one_minus(fac)),
                                self.volume(node.inputs[2]).scaled(fac), node)

    def _volume_note(self, node, what):
        label = f"'{node.name}' ({what})"
        if label not in self.volume_notes:
            self.volume_notes.append(label)

    def _volume_sum(self, a, b, node):
        if a.phase_spec is not None and b.phase_spec is not None and a.phase_spec != b.phase_spec:
            self._volume_note(node, f"two {a.phase_spec[0].replace('_', '-').title()} / "
                                    f"{b.phase_spec[0].replace('_', '-').title()} phase functions rendered as "
                                    "the first")
        elif (a.phase_spec is None) != (b.phase_spec is None) and a.scattering != BLACK and b.scattering != BLACK:
            self._volume_note(node, "a Henyey-Greenstein and another phase function mixed rendered as the other")
        if a.phases_differ(b):
            self._volume_note(node, "volume phase functions of different anisotropy rendered as one of "
                                    "their mean")
        return a.plus(b)

    # -- report ----------------------------------------------------------------

    def warning(self):
        """One sentence naming everything approximated, or None."""
        parts = []
        if self.unsupported:
            parts.append("unsupported node " + ", ".join(self.unsupported) + " rendered as diffuse")
        if self.unsupported_volume:
            parts.append("unsupported node " + ", ".join(self.unsupported_volume) + " not rendered")
        if self.volume_notes:
            parts.append("volume " + ", ".join(self.volume_notes))
        if self.approximated:
            parts.append("not rendered as Cycles yet: " + ", ".join(self.approximated))
        if self.textured:
            parts.append("linked input " + ", ".join(self.textured) + " read as its constant value")
        if self.reader.unsupported:
            parts.append("texture node " + ", ".join(self.reader.unsupported) + " not translated")
        parts += self.reader.warnings
        if not parts:
            return None
        return f"Material '{self.material_name}': " + "; ".join(parts)


# Coefficients past this (1/m) render as opaque as any larger: validation's
# largest renderable value.
VOLUME_LIMIT = 1e30


@dataclass
class VolumeClosure:
    """What a Volume socket evaluates to: the summed coefficients of its
    volume closures (constants or texture expressions) and their
    scattering-weighted anisotropy (g constants or expressions)."""
    absorption: tuple = BLACK
    scattering: tuple = BLACK
    emission: tuple = BLACK
    g_weight: object = 0.0       # sum of w x g over the closures (w: _mean_weight of each)
    g_total: object = 0.0        # sum of w (an expression where a Mix Shader's Fac is textured)
    phases: tuple = ()           # the distinct g of the scattering closures
    # A Volume Scatter's other phase function: (phase, alpha, backscatter,
    # ior, diameter), None for Henyey-Greenstein.
    phase_spec: tuple = None

    def with_phase(self, g):
        w = _mean_weight(self.scattering)
        g = _clamp_g(g)
        return dataclasses.replace(self, g_weight=nodes.multiply(w, g), g_total=w, phases=(g,))

    def scaled(self, w):
        """The closures weighted by w (a constant or a float expression)."""
        if nodes.is_expr(w):
            used = nodes.may_exceed(w, 0.0)
            scatters = nodes.is_expr(self.g_total) or self.g_total > 0
            return VolumeClosure(_weighted(self.absorption, w), _weighted(self.scattering, w),
                                 _weighted(self.emission, w),
                                 nodes.math('MULTIPLY', self.g_weight, w) if scatters else 0.0,
                                 nodes.math('MULTIPLY', self.g_total, w) if scatters else 0.0,
                                 self.phases if used else (), self.phase_spec if used else None)
        return VolumeClosure(_scale3(self.absorption, w), _scale3(self.scattering, w), _scale3(self.emission, w),
                             nodes.multiply(self.g_weight, w), nodes.multiply(self.g_total, w),
                             self.phases if w > 0 else (), self.phase_spec if w > 0 else None)

    def plus(self, other):
        return VolumeClosure(_add3(self.absorption, other.absorption), _add3(self.scattering, other.scattering),
                             _add3(self.emission, other.emission), _plus(self.g_weight, other.g_weight),
                             _plus(self.g_total, other.g_total), _distinct(self.phases + other.phases),
                             self.phase_spec if self.phase_spec is not None else other.phase_spec)

    def phases_differ(self, other):
        return len(_distinct(self.phases + other.phases)) > 1

    def anisotropy(self):
        """The medium's g: the weighted mean of its closures' (an expression
        where one is textured: the engine clamps it per point; a textured
        weight divides per point, 0 where it is 0)."""
        if nodes.is_expr(self.g_total):
            return nodes.math('DIVIDE', self.g_weight, self.g_total)
        if self.g_total <= 0:
            return 0.0
        if nodes.is_expr(self.g_weight):
            return nodes.multiply(self.g_weight, 1.0 / self.g_total)
        return min(max(self.g_weight / self.g_total, -1.0), 1.0)


def _weighted(c, w):
    """A coefficient times a float expression (none stays none)."""
    if not nodes.is_expr(c) and all(float(x) == 0.0 for x in c):
        return BLACK
    return _times(c, w)


def _clamp_g(g):
    if nodes.is_expr(g):
        return g     # clamped to [-1, 1] where the engine evaluates it
    return min(max(float(g), -1.0), 1.0)


def _plus(a, b):
    if nodes.is_expr(a) or nodes.is_expr(b):
        return nodes.math('ADD', a, b)
    return a + b


def _distinct(phases):
    """The distinct g among constants and expressions (an expression is
    itself: two links to one socket are one)."""
    out = []
    for g in phases:
        if not any(g is h or (not nodes.is_expr(g) and not nodes.is_expr(h) and g == h) for h in out):
            out.append(g)
    return tuple(out)


def _valid_phase(spec):
    """The phase parameters clamped to what Cycles accepts (IOR > 1,
    backscatter in (0, 0.5), alpha and diameter >= 0)."""
    phase, alpha, back, ior, diameter = spec
    return (phase, min(max(alpha, 0.0), 1e6), min(max(back, 1e-6), 0.5 - 1e-6), min(max(ior, 1.0 + 1e-6), 10.0),
            min(max(diameter, 0.0), 1e6))


def _mean_weight(c):
    """The mean scattering a closure's g is weighted by: a textured one's
    is taken as 1 (its g then counts as one constant medium's)."""
    return 1.0 if nodes.is_expr(c) else sum(c) / 3.0


def _scale3(c, w):
    if nodes.is_expr(c):
        return nodes.scale(c, w)
    return tuple(min(x * w, VOLUME_LIMIT) for x in c)


def _add3(a, b):
    if nodes.is_expr(a) or nodes.is_expr(b):
        return nodes.add(a, b)
    return tuple(min(x + y, VOLUME_LIMIT) for x, y in zip(a, b))


def _times(color, w):
    """A colour times a float or a colour (constants or expressions)."""
    if nodes.is_expr(color) or nodes.is_expr(w) or isinstance(w, tuple):
        if isinstance(w, tuple) and isinstance(color, tuple):
            return tuple(min(x * y, VOLUME_LIMIT) for x, y in zip(color, w))
        return backend.engine().MixColor('MULTIPLY', 1.0, color, w, clamp_factor=False)
    return _scale3(color, float(w))


def _positive(color):
    """max(c, 0) per channel."""
    if nodes.is_expr(color):
        return backend.engine().MixColor('LIGHTEN', 1.0, color, BLACK, clamp_factor=False)
    return tuple(max(c, 0.0) for c in color)


def _one_minus_color(color):
    if nodes.is_expr(color):
        return backend.engine().MixColor('SUBTRACT', 1.0, (1.0, 1.0, 1.0), color, clamp_factor=False)
    return tuple(1.0 - c for c in color)


def _absorption_tint(ac):
    """Cycles' Principled Volume absorption tint max(1 - max(sqrt(Absorption
    Color), 0), 0) per channel (a negative colour's square root, NaN there,
    is 0); an expression is evaluated per point (a Gamma of 0.5 is the
    square root where the colour is positive, the colour itself elsewhere)."""
    if not nodes.is_expr(ac):
        return tuple(max(1.0 - math.sqrt(max(a, 0.0)), 0.0) for a in ac)
    renderer = backend.engine()
    root = renderer.NodeOutput(renderer.NodeCall('ShaderNodeGamma', {'Color': ac, 'Gamma': 0.5}), 'Color')
    return _positive(_one_minus_color(_positive(root)))


def _above(value, level):
    """1 where value > level, else 0 (a constant or an expression)."""
    if not nodes.is_expr(value):
        return 1.0 if float(value) > level else 0.0
    return nodes.math('GREATER_THAN', value, level)


def _blackbody_rgb(t):
    """The Blackbody node's colour of a constant temperature."""
    renderer = backend.engine()
    entry = renderer.NODE_REGISTRY['ShaderNodeBlackbody']
    return tuple(float(c) for c in
                 entry.evaluate(renderer.ShadingContext(1), {'Temperature': np.array([float(t)])}, {})['Color'][0])


def _f0_from_ior(ior):
    if nodes.is_expr(ior):
        ratio = nodes.math('DIVIDE', nodes.math('SUBTRACT', ior, 1.0), nodes.math('ADD', ior, 1.0))
        return nodes.math('MULTIPLY', ratio, ratio)
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def _ior_from_f0(f0):
    if nodes.is_expr(f0):
        s = nodes.math('SQRT', nodes.math('MINIMUM', nodes.at_least(f0, 0.0), 0.99))
        return nodes.math('DIVIDE', nodes.math('ADD', 1.0, s), nodes.math('SUBTRACT', 1.0, s))
    s = math.sqrt(min(max(f0, 0.0), 0.99))
    return (1.0 + s) / (1.0 - s)


def _grey(value):
    """A float weight as a colour: an expression is grey by itself."""
    return value if nodes.is_expr(value) else (value,) * 3


def _clamp_color(color):
    if nodes.is_expr(color):
        return color
    return tuple(min(max(float(c), 0.0), 1.0) for c in color)


def _sqrt_color(color):
    """sqrt of a colour (Cycles' transmission tint); a textured colour is
    used as it is (expressions have no square root yet)."""
    if nodes.is_expr(color):
        return color
    return tuple(math.sqrt(max(float(c), 0.0)) for c in color)


def _first_input(translator, node, names, default, color=False):
    """The first of ``names`` the node has (4.x name first, then 3.x)."""
    for name in names:
        if name in node.inputs:
            return translator.color(node, name, default) if color else translator.value(node, name, default)
    return default


def _specular(translator, node, ior):
    """IOR and F0 of the Principled specular layer.

    4.x: F0 of the IOR times 2 * Specular IOR Level (0.5 keeps it), the IOR
    recomputed from that F0 (Cycles' svm_node_closure_bsdf).
    3.x: F0 = 0.08 * Specular (0.5 -> 0.04, i.e. IOR 1.5)."""
    if 'Specular IOR Level' in node.inputs:
        level = nodes.at_least(translator.value(node, 'Specular IOR Level', 0.5), 0.0)
        f0 = _f0_from_ior(ior)
        if not nodes.is_expr(level) and level == 0.5:
            return ior, f0
        f0 = _mul(f0, _mul(2.0, level))
        eta = _ior_from_f0(f0)
        return _inverted_below_one(eta, ior), f0
    f0 = _mul(0.08, nodes.at_least(translator.value(node, 'Specular', 0.5), 0.0))
    if nodes.is_expr(f0):
        return _ior_from_f0(f0), f0   # f0 = 0 gives IOR 1 there
    return (_ior_from_f0(f0) if f0 > 0 else 1.0), f0


def _inverted_below_one(eta, ior):
    """1 / eta where ior < 1 (a specular layer seen from inside), else eta."""
    if not nodes.is_expr(ior):
        return nodes.math('DIVIDE', 1.0, eta) if ior < 1.0 else eta
    # eta + [ior < 1] (1 / eta - eta)
    flip = nodes.math('LESS_THAN', ior, 1.0)
    return nodes.math('ADD', eta, nodes.math('MULTIPLY', flip,
                                             nodes.math('SUBTRACT', nodes.math('DIVIDE', 1.0, eta), eta)))


def _principled_inputs(translator, node):
    """The Principled BSDF's inputs, clamped as Cycles does, for 4.x and the
    3.x names (3.x float tints become white: the 4.x model has colour tints)."""
    t = translator
    base = _first_input(t, node, ('Base Color',), GREY, color=True)
    ior = nodes.at_least(t.value(node, 'IOR', 1.45), 1e-5)
    tint = t.color(node, 'Specular Tint', (1.0, 1.0, 1.0)) if 'Specular IOR Level' in node.inputs \
        else (1.0, 1.0, 1.0)
    eta, f0 = _specular(t, node, ior)
    sheen_tint = (1.0, 1.0, 1.0)
    if 'Sheen Weight' in node.inputs:
        sheen_tint = t.color(node, 'Sheen Tint', (1.0, 1.0, 1.0))
    return {
        'base': _max0(base), 'base_clamped': _clamp_color(_max0(base)),
        'metallic': _clamp01(t.value(node, 'Metallic', 0.0)),
        'roughness': _clamp01(t.value(node, 'Roughness', 0.5)),
        'ior': ior, 'specular_tint': _max0(tint), 'specular_eta': eta, 'specular_f0': f0,
        'transmission': _clamp01(_first_input(t, node, ('Transmission Weight', 'Transmission'), 0.0)),
        'coat': nodes.at_least(_first_input(t, node, ('Coat Weight', 'Clearcoat'), 0.0), 0.0),
        'coat_roughness': _clamp01(_first_input(t, node, ('Coat Roughness', 'Clearcoat Roughness'), 0.03)),
        'coat_ior': nodes.at_least(_first_input(t, node, ('Coat IOR',), 1.5), 1.0),
        'coat_tint': _max0(_first_input(t, node, ('Coat Tint',), (1.0, 1.0, 1.0), color=True)),
        'sheen': nodes.at_least(_first_input(t, node, ('Sheen Weight', 'Sheen'), 0.0), 0.0),
        'sheen_roughness': _clamp01(_first_input(t, node, ('Sheen Roughness',), 0.5)),
        'sheen_tint': _max0(sheen_tint),
        'alpha': _clamp01(t.value(node, 'Alpha', 1.0)) if 'Alpha' in node.inputs else 1.0,
        'multiscatter': getattr(node, 'distribution', 'GGX') == 'MULTI_GGX',
        'anisotropic': _clamp01(t._finite_value(node, 'Anisotropic', t.value(node, 'Anisotropic', 0.0), 0.0))
        if 'Anisotropic' in node.inputs else 0.0,
        'rotation': t._finite_value(node, 'Anisotropic Rotation', t.value(node, 'Anisotropic Rotation', 0.0), 0.0)
        if 'Anisotropic Rotation' in node.inputs else 0.0,
        'diffuse_roughness': _clamp01(t._finite_value(node, 'Diffuse Roughness',
                                                      t.value(node, 'Diffuse Roughness', 0.0), 0.0))
        if 'Diffuse Roughness' in node.inputs else 0.0,
        'node': node,
    }


def _same_tangent(a, b):
    return a is b or (a.output == b.output and a.call.idname == b.call.idname and a.call.props == b.call.props
                      and not a.call.inputs and not b.call.inputs)


def _conductor_part(value):
    """A conductor's n or k per channel in [0, 1e6]: past 1e6 its Fresnel is 1
    to float precision, and the squares of 1e200 would overflow."""
    return tuple(min(max(c, 0.0), 1e6) for c in value)


def _constant_color(translator, node, name, default):
    """A colour input as a constant (linked: its own value, named), NaN as 0."""
    socket = node.inputs.get(name)
    if socket is None:
        return default
    if socket.is_linked:
        translator._note_texture(node, name)
    value = tuple(float(c) for c in tuple(socket.default_value)[:3])
    return tuple(translator._finite_value(node, name, c, 0.0) for c in value)


def _max0(color):
    if nodes.is_expr(color):
        return color
    return tuple(max(float(c), 0.0) for c in color)


def _principled_emission(translator, node):
    strength = translator.value(node, 'Emission Strength', 1.0)
    name = 'Emission Color' if 'Emission Color' in node.inputs else 'Emission'
    return _scale(translator.color(node, name, BLACK), strength)


def _output_node(tree):
    return nodes.output_node(tree, 'OUTPUT_MATERIAL')


def translate(material):
    """Returns (engine Material, warning or None) for a bpy material."""
    scene = _scene()
    name = material.name
    sampling = volume_sampling(material, 'MULTIPLE_IMPORTANCE')
    tree = material.node_tree if compat.uses_nodes(material) else None
    if tree is None:
        color = tuple(material.diffuse_color)[:3]
        return scene.Material(name, (scene.Lobe('diffuse', color),)), None
    translator = NodeTranslator(name)
    output = _output_node(tree)
    if output is None:
        return scene.Material(name, ()), f"Material '{name}': no Material Output node, rendered black"
    closure = translator.surface(output.inputs['Surface'])
    normal, displacement = _displacement_bump(translator, output, _material_normal(translator, output),
                                              _displacement_method(material))
    lobes, volume = tuple(closure.lobes), _volume(translator, output)
    if volume is not None and not output.inputs['Surface'].is_linked:
        # Only a Volume output: Cycles' surface is a pass-through boundary.
        lobes = (scene.Lobe('transparent', (1.0, 1.0, 1.0)),)
    material = scene.Material(name, lobes, closure.emission, normal=normal,
                              holdout=_holdout_weight(translator, closure.holdout))
    if volume is not None:
        volume.sampling = sampling
        material.volume = volume
    if displacement is not None:
        material.displacement = displacement
    if translator.tangent is not None and any(lobe.kind == 'glossy_anisotropic' for lobe in lobes):
        material.tangent = translator.tangent
    if closure.emission_layers and hasattr(material, 'emission_layers'):
        material.emission_layers = tuple(closure.emission_layers)
    return material, translator.warning()


def _holdout_weight(translator, holdout):
    """The material's holdout weight as a constant in [0, 1]: a textured Mix
    Shader factor over a Holdout is read as the middle of its range (named
    in the material's warning), a sum above 1 as 1."""
    if nodes.is_expr(holdout):
        lo, hi = nodes.value_range(holdout)
        if lo != hi:   # a textured Mix factor times no Holdout is an expression of range [0, 0]: no warning
            translator.approximated.append(f"'Holdout' (a textured factor read as {0.5 * (lo + hi):g})")
        holdout = 0.5 * (lo + hi)
    holdout = float(holdout)
    return min(max(holdout, 0.0), 1.0) if math.isfinite(holdout) else 0.0


def grid_attribute(name, output):
    """An Attribute node's output for a volume attribute input: 1 where
    the object has no such attribute (Cycles' primitive_density = 1)."""
    renderer = backend.engine()
    call = renderer.NodeCall('ShaderNodeAttribute', {}, {'attribute_name': name, 'attribute_type': 'GEOMETRY',
                                                         '_missing': 1.0})
    return renderer.NodeOutput(call, output)


DEFAULT_VOLUME = 'default_volume'


def default_volume():
    """Cycles' default volume shader (scene/shader.cpp add_default), which a
    Volume object without a material renders with: a Principled Volume of
    Cycles' own defaults (scene/shader_nodes.cpp: Color 0.5, Density 1 times
    the 'density' grid, the Density Attribute its constructor sets, no
    Color Attribute, Anisotropy 0, no emission or blackbody), so scattering
    and absorption are each 0.5 x max(density grid, 0); no surface (a
    pass-through boundary) and the Shader's default Multiple Importance
    sampling."""
    renderer = _scene()
    density = nodes.at_least(grid_attribute('density', 'Fac'), 0.0)
    half = _times((0.5, 0.5, 0.5), density)
    volume = volume_of(VolumeClosure(absorption=half, scattering=half))
    volume.sampling = 'MULTIPLE_IMPORTANCE'
    material = renderer.Material(DEFAULT_VOLUME, (renderer.Lobe('transparent', (1.0, 1.0, 1.0)),))
    material.volume = volume
    return material


def _volume(translator, output):
    """The engine Volume of a Material Output's linked Volume socket (None
    when unlinked)."""
    socket = output.inputs.get('Volume')
    if socket is None or not socket.is_linked:
        return None
    return volume_of(translator.volume(socket))


def volume_sampling(datablock, default):
    """A material's or world's Cycles Volume > Sampling ('DISTANCE',
    'EQUIANGULAR', 'MULTIPLE_IMPORTANCE'; ``default`` where unreadable)."""
    value = getattr(getattr(datablock, 'cycles', None), 'volume_sampling', default)
    return value if value in ('DISTANCE', 'EQUIANGULAR', 'MULTIPLE_IMPORTANCE') else default


def volume_of(v):
    """The engine Volume of a VolumeClosure."""
    volume = _scene().Volume(v.absorption, v.scattering, v.emission, v.anisotropy())
    if v.phase_spec is not None:
        volume.phase, volume.alpha, volume.backscatter, volume.ior, volume.diameter = v.phase_spec
    return volume


def _material_normal(translator, output):
    """The normal map / bump of the first shader node (through Mix and Add
    Shaders) whose Normal input is linked: Ember has one normal per material."""
    found = []
    stack = [output.inputs['Surface']]
    while stack:
        node, _ = translator._linked_node(stack.pop())
        if node is None or node.mute:
            continue
        if node.type in ('MIX_SHADER', 'ADD_SHADER'):
            stack += [s for s in reversed(node.inputs) if s.type == 'SHADER']
        elif 'Normal' in node.inputs and node.inputs['Normal'].is_linked:
            found.append(node)
    if not found:
        return None
    if len(found) > 1:
        translator.reader.warnings.append(
            "one normal per material: the normal input of '" + found[0].name + "' is used for all shaders")
    return translator.reader.normal(found[0].inputs['Normal'])


def _displacement_method(material):
    """'BUMP', 'DISPLACEMENT' or 'BOTH' (the material's in 4.x/5.0, its
    Cycles settings' in 3.x)."""
    method = getattr(material, 'displacement_method', None)
    if method is None:
        method = getattr(getattr(material, 'cycles', None), 'displacement_method', 'BUMP')
    return method


def _displacement_bump(translator, output, inner, method='BUMP'):
    """The Material Output's Displacement as Cycles renders it: "Bump Only"
    is a bump whose height is the displacement along the normal (a
    Displacement node's (Height - Midlevel) * Scale, or a float linked
    directly), over the BSDF's own normal map / bump.  "Displacement Only"
    and "Displacement and Bump" of a Displacement node move the mesh's
    vertices (engine/displacement.py, returned second), "Both" bumps with
    the same height too.  Returns (normal, engine Displacement or None)."""
    socket = output.inputs.get('Displacement')
    if socket is None or not socket.is_linked:
        return inner, None
    node, _ = translator._linked_node(socket)
    if node is None:
        return inner, None
    reader = translator.reader
    true = method in ('DISPLACEMENT', 'BOTH')
    if node.type == 'DISPLACEMENT' and not node.mute:
        height = nodes.math('MULTIPLY', nodes.math('SUBTRACT', reader.value_input(node, 'Height'),
                                                   reader.value_input(node, 'Midlevel')),
                            reader.value_input(node, 'Scale'))
        space = getattr(node, 'space', 'OBJECT')
        if space not in (('OBJECT', 'WORLD') if true else ('OBJECT',)):
            reader.warnings.append(f"'{node.name}' {space.lower()}-space displacement read as object space")
            space = 'OBJECT'
        if true and node.inputs['Normal'].is_linked:
            reader.warnings.append(f"'{node.name}': its Normal input is not read (the vertex normal is used)")
    else:
        if true:
            reader.warnings.append(f"displacement method {method.lower()} of '{node.name}' ({node.bl_idname}) "
                                   "rendered as bump (true displacement reads a Displacement node)")
            true, method = False, 'BUMP'
        value = reader.read(socket)
        if value is None:
            return inner, None
        height = nodes.as_value(value)
        space = 'OBJECT'
    displacement = _scene().Displacement(height, space, method) if true else None
    if method == 'DISPLACEMENT':
        return inner, displacement
    if not nodes.is_expr(height):
        return inner, displacement   # a constant height bends nothing
    bumped = _scene().Bump(height, 1.0, 1.0, False, None)
    if hasattr(bumped, 'sets_normal'):
        bumped.sets_normal = True   # Cycles' SetNormal: sd->N is the displacement's bump
    if method == 'BOTH' and hasattr(bumped, 'undisplaced'):
        bumped.undisplaced = True   # Cycles bumps with the undisplaced surface's derivatives
    if method == 'BOTH' and hasattr(bumped, 'displacement_space'):
        bumped.displacement_space = space   # Cycles' object-space bump of dot(D, N)
    return _over(inner, bumped), displacement


def _over(normal, displaced):
    """The BSDF's normal on top of the displacement's bump: Cycles sets the
    shading normal from the displacement first, so a Bump node's own
    unlinked Normal is the displaced one.  A normal map (whose frame Ember
    takes from the surface) stays under the displacement bump instead."""
    renderer = _scene()
    if normal is None:
        return displaced
    if isinstance(normal, renderer.Bump):
        return dataclasses.replace(normal, normal=_over(normal.normal, displaced))
    return dataclasses.replace(displaced, normal=normal)


class MaterialTable:
    """Scene materials, each Blender material translated once."""

    def __init__(self, override=None):
        self.materials = []
        self.warnings = []
        self.index_of = {}
        self.override = override
        self.slots_cache = {}
        self.default_volume_index = None

    def default_volume(self):
        """Index of Cycles' default volume (default_volume()), added once."""
        if self.default_volume_index is None:
            self.default_volume_index = len(self.materials)
            self.materials.append(default_volume())
        return self.default_volume_index

    def index(self, material):
        if material is None:
            return -1
        key = material.as_pointer()
        if key not in self.index_of:
            translated, warning = translate(material)
            if getattr(material, 'pass_index', 0) and hasattr(translated, 'pass_index'):
                translated.pass_index = int(material.pass_index)  # Material Index pass
            if hasattr(translated, 'aovs'):
                translated.aovs = material_aovs(material)  # Shader AOV passes
            self.index_of[key] = len(self.materials)
            self.materials.append(translated)
            if warning:
                self.warnings.append(warning)
        return self.index_of[key]

    def slots(self, obj):
        """Scene material index per material slot of an evaluated object."""
        if self.override is not None:
            count = max(len(obj.material_slots), 1)
            return [self.index(self.override)] * count
        key = (obj.original.as_pointer(), obj.data.as_pointer() if obj.data else 0)
        if key not in self.slots_cache:
            slots = [slot.material for slot in obj.material_slots]
            if not slots and obj.data is not None and hasattr(obj.data, 'materials'):
                slots = list(obj.data.materials)
            indices = [self.index(m) for m in slots]
            if getattr(obj, 'type', None) == 'VOLUME':
                # Cycles (blender/geometry.cpp sync_geometry): a Volume
                # object's empty slots, or no slots, use the default volume.
                indices = [m if m >= 0 else self.default_volume() for m in indices] or [self.default_volume()]
            self.slots_cache[key] = indices
        return self.slots_cache[key]


def _scene():
    return backend.engine()


def material_aovs(material):
    """{AOV name: ((r, g, b), value)} from a material's AOV Output nodes.
    Constants only: a linked input is read as far as the shader translator
    reads constants, else as the socket's own value."""
    tree = getattr(material, "node_tree", None)
    if tree is None:
        return {}
    translator = NodeTranslator(material.name)
    out = {}
    for node in tree.nodes:
        if node.bl_idname != 'ShaderNodeOutputAOV' or node.mute:
            continue
        name = getattr(node, "aov_name", "") or node.name
        colour = translator.color(node, 'Color', (0.0, 0.0, 0.0))
        value = translator.value(node, 'Value', 0.0)
        if nodes.is_expr(colour):
            colour = tuple(node.inputs['Color'].default_value)[:3]
        if nodes.is_expr(value):
            value = float(node.inputs['Value'].default_value)
        out[name] = (tuple(float(c) for c in colour[:3]), float(value))
    return out
