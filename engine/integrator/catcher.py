"""Shadow catchers (Object > Visibility > Mask > Shadow Catcher), as Cycles
(kernel/integrator/shadow_catcher.h, kernel/film/read.h).

A camera path (through transparent passes too) that meets a catcher
splits: the main path goes on treating the catcher as an ordinary object
and adds to Combined only; a copy, the catcher path, sees catchers alone
(its rays and shadow rays pass every other object) and adds to the
catcher's own light; it draws the main path's random numbers.  Paths that never meet a catcher are the matte
(Combined and matte alike); a split uncovers the matte by the path's
throughput.  The film (engine/film.py, ``catcher_image``) turns these into
Cycles' Combined with the approximate shadow: the shadow is
(Combined - matte) / catcher light, alpha-overed on white by Combined's
alpha; the matte is laid over it, with the alpha of the shadow on a
transparent film, or over the background the camera sees otherwise.
"""
import numpy as np

from .. import instance_columns


def catcher_triangles(scene, tris):
    """(T,) whether each triangle belongs to a shadow catcher (not a holdout
    object: Cycles never splits at those), or None without catchers."""
    cols = instance_columns.columns(scene.instances)
    per_instance = np.append(cols.shadow_catcher & ~cols.holdout, False)
    owner = getattr(tris.shading, "instance", None)
    if not per_instance.any() or owner is None or len(tris.material) == 0:
        return None
    return per_instance[np.asarray(owner, np.int64)]


def background(ctx, d):
    """The world the camera sees along d (for the opaque film's shadow)."""
    env = ctx.lights.environment_hits(d)
    if env is not None:
        return env[1]
    return np.broadcast_to(ctx.world, d.shape)


def split(ctx, paths, hit, tile):
    """Split the camera paths at their first catcher: returns the paths and
    hits with the catcher paths appended (copies of the main paths at the
    same hit, with the same sample address, so both draw the same random
    numbers, as Cycles' split copies the path state: in the open, away from
    every shadow, the two agree sample by sample)."""
    at = (paths.bounce == 0) & (paths.catcher == 0) & ctx.catcher[hit.prim]
    rows = np.flatnonzero(at)
    if len(rows) == 0:
        return paths, hit
    pix = paths.pix[rows]
    beta = paths.beta[rows]
    # What the matte path brought before the split stays the matte's.
    tile.add_catcher(pix, paths.L[rows], np.zeros(len(rows), np.int8))
    bg = None if ctx.settings.transparent else background(ctx, paths.d[rows]) * beta
    tile.add_split(pix, beta.mean(axis=1), bg)
    paths.catcher[rows] = 1
    both = np.concatenate([np.arange(len(paths.pix)), rows])
    paths, hit = paths.take(both), hit.take(both)
    n = len(both) - len(rows)
    paths.catcher[n:] = 2
    paths.L[n:] = 0.0
    return paths, hit


def camera_background(ctx, paths, i, tile):
    """Camera paths ``i`` escaped: the background the opaque film's shadow
    is laid over (Cycles' Background pass)."""
    if ctx.catcher is None or ctx.settings.transparent or len(i) == 0:
        return
    i = i[paths.bounce[i] == 0]
    if len(i):
        tile.add_background(paths.pix[i], background(ctx, paths.d[i]) * paths.beta[i])
