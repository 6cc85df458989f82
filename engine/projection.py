"""World directions -> image (u, v) as Cycles' Environment Texture reads
them (kernel/camera/projection.h, after the node's safe_normalize): the
equirectangular and mirror-ball projections.  engine.environment (worlds)
and engine.textures (the node on surfaces) share them.
"""
import numpy as np


def direction_to_equirect(e):
    """(u, v) in [0, 1] of lookup vectors e (N, 3), any length > 0."""
    u = (np.pi - np.arctan2(e[:, 1], e[:, 0])) / (2.0 * np.pi)
    length = np.sqrt(np.einsum("ij,ij->i", e, e))
    with np.errstate(divide="ignore", invalid="ignore"):
        cos_t = np.clip(e[:, 2] / length, -1.0, 1.0)
    v = 1.0 - np.arccos(np.where(length > 0, cos_t, 1.0)) / np.pi
    return u, v


def direction_to_mirrorball(e):
    """(u, v) in [0, 1] of lookup vectors e (N, 3) on the image of a mirror
    ball photographed from -Y (Cycles' direction_to_mirrorball after
    safe_normalize): the centre reflects -Y, the rim +Y; a zero vector
    reads the centre, as in Cycles."""
    length = np.sqrt(np.einsum("ij,ij->i", e, e))
    d = e / np.where(length > 0, length, 1.0)[:, None]
    y = d[:, 1] - 1.0
    div = 2.0 * np.sqrt(np.maximum(-0.5 * y, 0.0))
    scale = np.where(div > 0, 1.0 / np.where(div > 0, div, 1.0), 1.0)
    return 0.5 * (d[:, 0] * scale + 1.0), 0.5 * (d[:, 2] * scale + 1.0)


def to_uv(e, projection):
    """Image (u, v) of lookup vectors for the node's projection."""
    if projection == "MIRROR_BALL":
        return direction_to_mirrorball(e)
    return direction_to_equirect(e)
