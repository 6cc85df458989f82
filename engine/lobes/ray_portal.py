"""The Ray Portal BSDF (Blender 4.2+; Cycles' bsdf_ray_portal.h and
shade_surface.h integrate_surface_ray_portal): the path goes on from the
portal's Position along its Direction, weighted by its colour.

The lobe samples as the transparent one (wi = -wo, weight colour /
p_lobe, a delta sample with no eval and no pdf), and the integrator
(engine/integrator/portal.py) then moves the ray: as Cycles, a pass through
a portal is a transparent bounce (it counts towards transparent_max_bounces
and Transparent Depth, keeps the ray's kind) that also counts a portal
bounce (Portal Depth) and skips MIS for the emitters the moved ray finds.
Shadow rays are blocked by a material with a portal, even where it mixes
in a transparent lobe (Cycles' integrate_transparent_surface_shadow: "Disable
transparent shadows for ray portals"), so light met through a portal is
found by BSDF rays alone, counted whole.  A path past its last vertex (which
Cycles shades without closures) crosses it as a transparent surface of its
colour (Cycles adds the portal's weight to closure_transparent_extinction).

Position and Direction are per-lobe parameters, textures allowed.  Their
defaults (and any non-finite value) are NaN: NaN Position is the hit point,
as Blender's unlinked Position socket; a NaN or zero Direction is the
incoming ray's, as Cycles' bsdf_ray_portal_setup (is_zero -> -sd->wi).
"""
import numpy as np

from .registry import DELTA, STRAIGHT, LobeDef, register
from .transparent import sample_transparent

RAY_PORTAL = 10
# Cycles' CLOSURE_WEIGHT_CUTOFF: a lighter portal allocates no closure.
CUTOFF = 1e-5


def portal_rows(lobes):
    """(N,) which rows hold a portal lobe of some weight (Cycles' SD_RAY_PORTAL)."""
    weight = np.abs(lobes.color.mean(axis=2)) * lobes.weight
    return np.any((lobes.kind == RAY_PORTAL) & (weight >= CUTOFF), axis=1)

register(LobeDef(RAY_PORTAL, "ray_portal", "transparent", DELTA | STRAIGHT, sample_transparent,
                 params=("portal_position", "portal_direction"),
                 doc="the Ray Portal BSDF: the path goes on from portal_position along portal_direction; "
                     "shadow rays are blocked by its material",
                 cases=[dict(color=(0.9, 0.7, 1.0))]))
