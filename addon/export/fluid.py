"""Smoke and fire: the voxel grids of Blender's gas fluid domains.

A gas domain's evaluated object exposes its simulated grids as flat float
arrays on its Fluid modifier's ``domain_settings`` (density, flame,
temperature, heat, colour: what Cycles' BlenderSmokeLoader reads), x
fastest and z slowest, at the domain's resolution (times the noise upres
when noise is on).  They become the instance's ``voxels`` (engine/media/
voxels.py), read through the texture space of the domain's evaluated mesh.

Blender 3.4's binary simulates and exposes them (a 'REPLAY' cache stepped
by frame_set, or a baked one); the bpy wheels' Mantaflow does not (their
bake aborts and their caches do not load), so there the grids are empty and
the domain renders as its material's constant medium, with a warning.
"""
import numpy as np

# Attribute names (Cycles' standard volume attribute names) -> grid property, channels.
GRIDS = (("density", "density_grid", 1), ("flame", "flame_grid", 1), ("heat", "heat_grid", 1),
         ("temperature", "temperature_grid", 1), ("color", "color_grid", 4))


def gas_domain(obj):
    """The domain settings of an object's gas fluid domain, or None."""
    for mod in getattr(obj, 'modifiers', ()):
        if mod.type == 'FLUID' and mod.fluid_type == 'DOMAIN' and mod.domain_settings.domain_type == 'GAS':
            return mod.domain_settings
    return None


def domain_grids(obj):
    """(grids or None, warning or None) of an evaluated object: its gas
    domain's grids {attribute name: (Z, Y, X[, C]) float32}."""
    settings = gas_domain(obj)
    if settings is None:
        return None, None
    res = tuple(int(r) for r in settings.domain_resolution)
    grids = {}
    for name, prop, channels in GRIDS:
        grid = _read(settings, prop, res, channels)
        if grid is not None:
            grids[name] = grid
    density = grids.get("density")
    if density is None or not density.size:
        return None, (f"fluid domain '{obj.name}' has no simulated data in this Blender (its smoke renders as "
                      "the material's constant medium): simulate or bake it in a Blender whose Mantaflow works "
                      "(Debian's 3.4 binary does; the bpy modules do not)")
    return grids, None


def _read(settings, prop, res, channels):
    """One grid as (Z, Y, X[, C]), or None if empty or of an unknown size."""
    values = getattr(settings, prop, None)
    n = len(values) if values is not None else 0
    cells = int(np.prod(res))
    if n == 0 or cells == 0 or n % channels:
        return None
    scale = round((n // channels / cells) ** (1.0 / 3.0))    # the noise upres (1 without noise)
    shape = tuple(r * scale for r in res[::-1])
    if int(np.prod(shape)) * channels != n:
        return None
    out = np.empty(n, np.float32)
    values.foreach_get(out)
    return out.reshape(shape + ((channels,) if channels > 1 else ()))


def material_on_grids(material_name):
    """Whether a gas fluid domain or a Volume object uses the material (its
    Principled Volume then reads the object's grids by its attribute
    inputs, as Cycles')."""
    import bpy
    for obj in bpy.data.objects:
        if (obj.type == 'VOLUME' or gas_domain(obj) is not None) and any(
                slot.material is not None and slot.material.name == material_name for slot in obj.material_slots):
            return True
    return False
