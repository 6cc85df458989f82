"""Hair particle systems -> strands, as Cycles exports them (its
blender/curves.cpp ObtainCacheParticleData and ExportCurveSegments).

For each particle system modifier enabled for the render (the viewport: for
the viewport) whose settings are Hair rendered as Path: the strands of the
path cache, children in place of their parents when there are children, each
with (1 << Steps) + 1 keys (Render Steps for the render, Display Steps for
the viewport; a Spiral kink adds its extra steps).  A key's radius is
Cycles' ``shaperadius`` of its arc-length position t along the strand:
(1 - t) shaped by Hair Shape, from radius_scale / 2 x Diameter Root to
radius_scale / 2 x Tip, 0 at the last key with Close Tip.  The material is
the settings' material slot.  bpy only; no engine import (the collector
makes the scene objects).

Per strand, as Cycles' ObtainCacheParticleUV / ObtainCacheParticleVcol: the
emitter's UV maps and byte colour attributes at the strand's root
(``ParticleSystem.uv_on_emitter`` / ``mcol_on_emitter``; colours sRGB there,
linearized as Cycles), read only when the system's material reads surface
data.  Each strand's number among the emitter's (its systems in order) is
``first_curve``: Cycles hashes it for the Curves Info node's Random."""
import numpy as np

from .mesh import node_trees

# Shader nodes through which a material reads UV maps or colour attributes.
_SURFACE_READERS = {'UVMAP', 'TEX_COORD', 'TEX_IMAGE', 'ATTRIBUTE', 'VERTEX_COLOR', 'NORMAL_MAP', 'TANGENT'}


class ParticleStrands:
    """One particle system's strands: ``points`` (N, 3) in the emitter's
    object space, ``radii`` (N,), ``offsets`` (C + 1,), ``slot`` the
    emitter's material slot (0-based), ``name``, ``skipped`` strands with a
    NaN or infinite key or radius (left out)."""

    def __init__(self, points, radii, offsets, slot, name, skipped):
        self.points, self.radii, self.offsets = points, radii, offsets
        self.slot, self.name, self.skipped = slot, name, skipped
        self.curve_attributes, self.uv, self.first_curve = {}, None, 0
        self.coincident = 0   # strands lying exactly on another of the system (coincident_strands)


def coincident_strands(co):
    """How many of the strands (S, K, 3) repeat another's keys exactly.
    Blender's Jittered distribution can place two hairs at one point of a
    face (about 1 in 6 of 1,500 on a 512-face sphere), and the twins grow
    along the same normal: one tube traced twice.  Cycles renders such
    strands much darker than a single one (each one's light is blocked by
    its twin: measured 0.62 of the image with every strand doubled), Ember
    as one strand (0.95), so a file with them differs (docs/real_scenes.md
    hair)."""
    if len(co) < 2:
        return 0
    rows = np.ascontiguousarray(co.reshape(len(co), -1))
    return int(len(rows) - len(np.unique(rows, axis=0)))


def shape_radius(shape, root, tip, t):
    """Cycles' shaperadius: the radius at arc-length fraction t (0 root, 1 tip)."""
    r = 1.0 - np.asarray(t, np.float64)
    if shape < 0.0:
        r = r ** (1.0 + shape)
    elif shape > 0.0:
        r = r ** (1.0 / (1.0 - shape))
    return r * (root - tip) + tip


def _systems(obj, render):
    """(particle system, settings) of the emitter's enabled hair systems."""
    for mod in obj.modifiers:
        if mod.type != 'PARTICLE_SYSTEM' or not (mod.show_render if render else mod.show_viewport):
            continue
        psys = mod.particle_system
        settings = psys.settings
        if settings.type == 'HAIR' and settings.render_type == 'PATH':
            yield mod, psys, settings


def _strand_indices(psys, settings, render):
    """The path cache's strand numbers Cycles exports: the children when the
    system has some (the viewport shows Display Amount of them), else the
    parents."""
    parents = len(psys.particles)
    children = len(psys.child_particles)
    if not render:
        children = int(children * settings.display_percentage / 100.0)
    if settings.child_type != 'NONE' and children:
        return range(parents, parents + children)
    return range(parents + children)


def _keys(psys, obj, strands, steps):
    """(S, steps, 3) world-space keys of the path cache (ParticleSystem.co_hair)."""
    co = np.empty((len(strands), steps, 3))
    for i, number in enumerate(strands):
        for step in range(steps):
            co[i, step] = psys.co_hair(obj, particle_no=number, step=step)
    return co


def _radii(settings, co):
    """(S, K) key radii: shape_radius at each key's arc-length fraction (as
    Cycles' curvekey_time / curve_length; 0 along a zero-length strand)."""
    with np.errstate(invalid="ignore"):
        seg = np.linalg.norm(np.diff(co, axis=1), axis=2)
        length = np.concatenate([np.zeros((len(co), 1)), np.cumsum(seg, axis=1)], axis=1)
        total = length[:, -1:]
        t = np.where(total > 0, length / np.where(total > 0, total, 1.0), 0.0)
        half = 0.5 * float(settings.radius_scale)
        radii = shape_radius(float(settings.shape), half * float(settings.root_radius),
                             half * float(settings.tip_radius), t)
    if settings.use_close_tip:
        radii[:, -1] = 0.0
    return radii


def particle_strands(obj, render=True, check=lambda: None):
    """The hair particle systems of the (evaluated) mesh object ``obj`` as
    ParticleStrands, one per system with strands."""
    out = []
    world_to_object = None
    first_curve = 0
    for mod, psys, settings in _systems(obj, render):
        steps = (1 << int(settings.render_step if render else settings.display_step)) + 1
        if settings.kink == 'SPIRAL':
            steps += int(settings.kink_extra_steps)
        strands = _strand_indices(psys, settings, render)
        if len(strands) == 0:
            continue
        check()
        if world_to_object is None:
            m = np.array(obj.matrix_world, np.float64)
            if not np.isfinite(m).all() or abs(np.linalg.det(m[:3, :3])) < 1e-30:
                return out   # a collapsed emitter: its hair has no extent either
            world_to_object = np.linalg.inv(m)
        co = _keys(psys, obj, strands, steps)
        co = co @ world_to_object[:3, :3].T + world_to_object[:3, 3]
        radii = _radii(settings, co)
        good = np.isfinite(co).all(axis=(1, 2)) & np.isfinite(radii).all(axis=1)
        co, radii = co[good], radii[good]
        slot = max(int(settings.material) - 1, 0)
        made = ParticleStrands(co.reshape(-1, 3), np.maximum(radii, 0.0).reshape(-1),
                               np.arange(len(co) + 1, dtype=np.int64) * steps, slot, psys.name,
                               int((~good).sum()))
        made.first_curve = first_curve
        made.coincident = coincident_strands(co)
        first_curve += len(strands)
        if _reads_surface(obj, slot):
            made.curve_attributes, made.uv = _root_data(obj, mod, psys, strands, check)
            made.curve_attributes = {k: v[good] for k, v in made.curve_attributes.items()}
        out.append(made)
    return out


def _reads_surface(obj, slot):
    """Whether the material in the emitter's ``slot`` reads UV maps or
    colour attributes (node groups included)."""
    slots = getattr(obj, 'material_slots', ())
    material = slots[min(slot, len(slots) - 1)].material if len(slots) else None
    tree = getattr(material, 'node_tree', None) if material else None
    return any(n.type in _SURFACE_READERS for t in node_trees(tree, set()) for n in t.nodes)


def _srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c < 0.04045, np.where(c < 0.0, 0.0, c / 12.92), ((c + 0.055) / 1.055) ** 2.4)


def _root_data(obj, mod, psys, strands, check):
    """({name: (S, 2) UV or (S, 4) RGBA per strand}, the active render UV
    map's name or None) from the emitter at each strand's root, as Cycles:
    a child strand passes the first particle (Cycles' particle iterator
    stops at the parents)."""
    mesh = obj.data
    out, active = {}, None
    particles = psys.particles
    first = particles[0] if len(particles) else None

    def particle(number):
        return particles[number] if number < len(particles) else first

    layers = list(getattr(mesh, 'uv_layers', ()))
    for k, layer in enumerate(layers):
        check()
        out[layer.name] = np.array([psys.uv_on_emitter(mod, particle(i), particle_no=i, uv_no=k)
                                    for i in strands], np.float64).reshape(-1, 2)
        if layer.active_render:
            active = layer.name
    colours = [a for a in getattr(mesh, 'attributes', ())
               if a.data_type == 'BYTE_COLOR' and a.domain == 'CORNER']
    for k, attr in enumerate(colours):
        check()
        rgb = np.array([psys.mcol_on_emitter(mod, particle(i), particle_no=i, vcol_no=k) for i in strands],
                       np.float64).reshape(-1, 3)
        out.setdefault(attr.name, np.c_[_srgb_to_linear(rgb), np.ones(len(rgb))])
    out = {k: np.where(np.isfinite(v), v, 0.0).astype(np.float32) for k, v in out.items()}
    return out, active
