"""Shading evaluated at pixel centres, without sampling.

``emission_at_pixel_centres`` traces one camera ray through the centre of
every pixel and returns the emission of the surface it hits (world colour
where it misses): for an emission-shaded scene this is exactly what Cycles
renders with one sample (its first sample sits at the pixel centre), so
shader nodes can be compared with Cycles per pixel, to float32 precision.
"""
from types import SimpleNamespace

import numpy as np

from ..integrator import _interaction
from ..render import prepare
from ..scene import RenderSettings
from .context import ShadingContext


def emission_at_pixel_centres(scene, offset=(0.0, 0.0)):
    """(H, W, 3) emitted radiance seen through each pixel centre (row 0 at
    the top), and the (H, W) material index hit (-1 for none).  offset:
    a shift of every sample in pixels (x right, y up), e.g. where Cycles'
    filter table puts its first sample."""
    ctx = prepare(scene, RenderSettings(samples=1, filter_type="BOX", filter_width=1.0, max_bounces=0))
    cam = ctx.camera
    npix = cam.width * cam.height
    pix = np.arange(npix)
    half = np.full(npix, 0.5)
    o, d, tmax = cam.generate(pix, half, half, half, half)
    if offset != (0.0, 0.0):
        shift = cam.rot @ np.array([offset[0] * cam.pw, offset[1] * cam.ph, 0.0])
        o = o + shift   # orthographic cameras only: the ray moves parallel
    t, prim, bu, bv = ctx.accel.intersect(o, d, tmax)
    out = np.broadcast_to(ctx.world, (npix, 3)).copy()
    material = np.full(npix, -1)
    hit = np.nonzero(prim >= 0)[0]
    if len(hit):
        paths = SimpleNamespace(o=o[hit], d=d[hit])
        h = _interaction(ctx, paths, t[hit], prim[hit], bu[hit], bv[hit])
        emission = ctx.materials.emission[h.mat]
        if ctx.materials.textures.emission:
            emission = ctx.materials.textures.emission_at(h.mat, ShadingContext.of_hit(ctx.triangles, h), emission)
        out[hit] = emission
        material[hit] = h.mat
    return out.reshape(cam.height, cam.width, 3), material.reshape(cam.height, cam.width)
