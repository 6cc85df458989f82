"""The Ray Portal BSDF's pass (engine/lobes/ray_portal.py), as Cycles'
integrate_surface_ray_portal and path_state_next: a sample that chose a
portal lobe (sampled as a transparent one, wi = -wo) moves the ray to the
portal's Position (the hit point, offset as any ray leaving it, when
Position is not given or within 3e-5 of it) and turns it to its Direction
(the incoming one when not given or zero).  Like a transparent pass it is
no vertex: it counts a transparent bounce and keeps the ray's kind, the
previous vertex's MIS state and bounce counts; it counts a portal bounce
(Portal Depth) and sets Cycles' MIS skip, so emitters the moved ray finds
count whole.  Cycles does both for any transparent pass through a shader
that has a portal closure.  Only scenes with a portal material get here
(Context.portal_mat)."""
import numpy as np

from .. import bsdf
from ..lobes.ray_portal import portal_rows
from ..points import curve_rows

# Cycles: a Position this close (squared distance) to the hit keeps the
# hit's self-intersection offset instead of starting the ray there.
SAME_POINT2 = 1e-9


def chosen(v, u_lobe, through):
    """(rows, slots): the transparent-looking samples that chose a portal
    lobe (bsdf.sample picks slot chosen_lobe(sel, u_lobe))."""
    rows = np.flatnonzero(through)
    if not len(rows):
        return rows, rows
    sel = v.selection[rows]
    slot, _ = bsdf.chosen_lobe(sel, u_lobe[rows])
    is_portal = v.lobes.kind[rows, slot] == bsdf.RAY_PORTAL
    return rows[is_portal], slot[is_portal]


def move(ctx, paths, v, rows, slots, through):
    """Move the portal rays (rows, slots) in place (their o, d, tmax and
    MIS start: Ray Length counts from the portal's Position, as Cycles
    restarts the ray there), and count the portal passes of every
    ``through`` row whose material has a portal."""
    at_portal = through & portal_rows(v.lobes)
    paths.portal = paths.portal + at_portal
    paths.mis_skip = np.where(through, paths.mis_skip | at_portal, False)
    if not len(rows):
        return
    hit = v.hit
    p = hit.p[rows]
    position = v.lobes.portal_position[rows, slots]
    direction = v.lobes.portal_direction[rows, slots]
    d = _directions(direction, paths.d[rows])
    given = np.isfinite(position).all(axis=1)
    moved = given & (np.sum((np.where(given[:, None], position, p) - p) ** 2, axis=1) > SAME_POINT2)
    # Not moved: the ray leaves the hit, offset to the side it goes (as any ray from it).
    o = ctx.accel.offset_origin(p, hit.ng[rows], d, hit.eps[rows])
    o[moved] = position[moved]
    paths.o[rows] = o
    paths.d[rows] = d
    paths.mis_o[rows] = o
    paths.tmax[rows] = np.inf
    if ctx.strands is not None:   # a moved ray may meet the strand it left again (Cycles unsets isect.object)
        left = curve_rows(ctx.strands, hit.prim[rows])
        paths.self_prim[rows] = np.where(moved, -1, left)


def _directions(direction, incoming):
    """Unit directions: the given ones, or the incoming ray's where none is
    given (NaN) or it is zero (Cycles: is_zero(direction) -> -wi)."""
    length = np.linalg.norm(np.nan_to_num(direction, nan=0.0), axis=1)
    ok = np.isfinite(direction).all(axis=1) & (length > 0) & np.isfinite(length)
    out = np.array(incoming, dtype=np.float64, copy=True)
    out[ok] = direction[ok] / length[ok, None]
    return out
