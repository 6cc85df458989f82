"""Blender images -> float32 pixel arrays for the renderer.

``load_image(bpy_image)`` returns ``(pixels, warnings)``: pixels (H, W, C)
float32, row 0 at the TOP, colour channels linear (Non-Color images keep
their data values), alpha straight as stored.  External files are read with
OpenImageIO (without its automatic alpha association, as Cycles loads them);
packed and generated images, or any image when OpenImageIO is missing, come
from Blender's own pixel buffer.  A file that cannot be read gives Cycles'
missing-texture magenta (1, 0, 1) and a warning, never an error.
"""
import os

import bpy
import numpy as np

MAGENTA = np.array([[[1.0, 0.0, 1.0, 1.0]]], np.float32)
# Colour spaces whose values are used as they are (3.4 and 4.x/5.0 names).
DATA_SPACES = ('Non-Color', 'Raw')


def colorspace(bpy_image):
    return getattr(bpy_image.colorspace_settings, 'name', 'sRGB')


def is_data(bpy_image):
    return colorspace(bpy_image) in DATA_SPACES or bool(getattr(bpy_image.colorspace_settings,
                                                                 'is_data', False))


def is_srgb(bpy_image):
    return colorspace(bpy_image) == 'sRGB' and not is_data(bpy_image)


def srgb_to_linear(c):
    c = np.asarray(c, dtype=np.float32)
    return np.where(c < 0.04045, np.maximum(c, 0.0) / 12.92,
                    np.power(np.maximum(c + 0.055, 0.0) / 1.055, 2.4)).astype(np.float32)


def _external_path(bpy_image):
    if bpy_image.source != 'FILE' or bpy_image.packed_file is not None:
        return None
    return bpy.path.abspath(bpy_image.filepath, library=bpy_image.library)


def _read_oiio(path):
    """(H, W, C) float32 straight-alpha pixels, or None without OpenImageIO."""
    try:
        import OpenImageIO as oiio  # lazy: optional (and slow to load); Blender's pixels without it
    except ImportError:
        return None
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    buf = oiio.ImageBuf(path, 0, 0, config)
    if buf.has_error:
        raise OSError(buf.geterror())
    pixels = buf.get_pixels(oiio.FLOAT)
    if pixels is None or pixels.size == 0:
        raise OSError(buf.geterror() or "no pixels")
    return np.asarray(pixels, np.float32).reshape(buf.spec().height, buf.spec().width, -1)


def _read_blender(bpy_image):
    """Blender's pixel buffer: RGBA float, row 0 at the bottom."""
    width, height = bpy_image.size
    channels = bpy_image.channels
    if width * height == 0 or channels == 0:
        raise OSError("the image has no pixels")
    flat = np.empty(width * height * channels, np.float32)
    bpy_image.pixels.foreach_get(flat)
    return flat.reshape(height, width, channels)[::-1]


def _linearize(pixels, bpy_image, is_float):
    """sRGB-encoded colour channels to linear (8-bit sRGB files and Blender's
    byte buffers are encoded; float data is already linear)."""
    if is_float or not is_srgb(bpy_image):
        return pixels
    # The pixels are this module's own fresh array: convert in place, a band
    # of rows at a time (no second full-size copy of a 16k texture).
    out = pixels if pixels.dtype == np.float32 and pixels.flags.writeable else pixels.astype(np.float32)
    colour = min(3, out.shape[2]) if out.shape[2] != 2 else 1
    for lo in range(0, len(out), 512):
        band = out[lo:lo + 512]
        band[..., :colour] = srgb_to_linear(band[..., :colour])
    return out


def load_image(bpy_image):
    """(pixels float32 (H, W, C) linear, row 0 = top, warnings).  NaN and
    infinite texels (a damaged EXR) become 0, with a warning."""
    pixels, warnings = _load_image(bpy_image)
    finite = np.isfinite(pixels)
    if not finite.all():
        bad = int(finite.size - np.count_nonzero(finite))
        pixels = np.where(finite, pixels, np.float32(0.0))
        warnings = warnings + [f"Image '{bpy_image.name}': {bad} NaN or infinite values were replaced by 0"]
    return pixels, warnings


def _load_image(bpy_image):
    name = bpy_image.name
    path = _external_path(bpy_image)
    try:
        if path is not None:
            if not os.path.isfile(path):
                raise OSError(f"file {path!r} not found")
            pixels = _read_oiio(path)
            if pixels is not None:
                return _linearize(pixels, bpy_image, _file_is_float(path)), []
        pixels = _read_blender(bpy_image)
        return _linearize(pixels, bpy_image, bool(bpy_image.is_float)), []
    except (OSError, RuntimeError, ValueError) as err:
        return MAGENTA.copy(), [f"Image '{name}' could not be loaded ({err}): rendered magenta"]


def is_missing(pixels, warnings):
    """True if load_image gave the missing-texture colour."""
    return bool(warnings) and pixels.shape[:2] == (1, 1)


def _file_is_float(path):
    try:
        import OpenImageIO as oiio  # lazy: optional (and slow to load); Blender's pixels without it
    except ImportError:
        return False
    inp = oiio.ImageInput.open(path)
    if inp is None:
        return False
    try:
        return inp.spec().format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    finally:
        inp.close()


def srgb_filtered(bpy_image, path_is_float=None):
    """Whether Cycles filters this image in sRGB encoding: 8-bit sRGB data."""
    if not is_srgb(bpy_image):
        return False
    path = _external_path(bpy_image)
    if path is not None and os.path.isfile(path):
        return not _file_is_float(path)
    return not bool(bpy_image.is_float)
