"""Blender images -> float32 pixel arrays for the renderer.

``load_image(bpy_image)`` returns ``(pixels, warnings)``: pixels (H, W, C)
float32, row 0 at the TOP, colour channels linear (Non-Color images keep
their data values), alpha straight as stored.  External files are read with
OpenImageIO (without its automatic alpha association, as Cycles loads them);
packed and generated images, or any image when OpenImageIO is missing, come
from Blender's own pixel buffer.  A file that cannot be read gives Cycles'
missing-texture magenta (1, 0, 1) and a warning, never an error.

``load_texture`` is the same for an Image Texture node, with straight
alpha associated as Cycles associates it at load; ``load_tiles`` reads a
tiled (UDIM) image's tiles, each a texture of its own.
"""
import os
import tempfile

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
    pixels, _, warnings = _load(bpy_image, texture=False)
    pixels, more = _checked(pixels, bpy_image)
    return pixels, warnings + more


def load_texture(bpy_image):
    """(pixels, alpha mode, warnings) for an Image Texture node's
    engine.scene.TextureImage: as ``load_image``, with straight alpha
    associated as Cycles' image manager does at load (``_associate``)."""
    pixels, mode, warnings = _load(bpy_image, texture=True)
    pixels, more = _checked(pixels, bpy_image)
    return pixels, mode, warnings + more


def _load(bpy_image, texture):
    name = bpy_image.name
    path = _external_path(bpy_image)
    try:
        if path is not None:
            if not os.path.isfile(path):
                raise OSError(f"file {path!r} not found")
            pixels = _read_oiio(path)
            if pixels is not None:
                return _decoded(pixels, bpy_image, _file_info(path), texture)
        pixels = _read_blender(bpy_image)
        # Blender's byte buffers hold straight alpha, its float buffers associated.
        byte = not bool(bpy_image.is_float)
        return _decoded(pixels, bpy_image, FileInfo(not byte, byte, byte), texture)
    except (OSError, RuntimeError, ValueError) as err:
        return MAGENTA.copy(), 'STRAIGHT', [f"Image '{name}' could not be loaded ({err}): rendered magenta"]


def _decoded(pixels, bpy_image, info, texture):
    """Raw pixels -> (linear pixels, alpha mode, []): associated first when
    for a texture (Cycles associates in the file's own encoding), then
    decoded from sRGB."""
    mode = alpha_mode(bpy_image)
    if texture:
        pixels, mode = _associate(pixels, bpy_image, info)
    return _linearize(pixels, bpy_image, info.is_float), mode, []


class FileInfo:
    """What Cycles' loader reads from a file besides its pixels."""

    def __init__(self, is_float, byte, straight):
        self.is_float, self.byte, self.straight = is_float, byte, straight


def alpha_mode(bpy_image):
    mode = getattr(bpy_image, 'alpha_mode', 'STRAIGHT')
    return mode if mode in ('STRAIGHT', 'PREMUL', 'CHANNEL_PACKED', 'NONE') else 'STRAIGHT'


def _associate(pixels, bpy_image, info):
    """Cycles' load-time alpha (ImageManager::file_load_image, OIIO loader):
    RGBA pixels (4 channels only) that the file stores straight - as OIIO
    reports it (PNG, TGA, ...; not EXR), whatever the image's Alpha Mode
    says unless Channel Packed or None, and never for data - are multiplied
    by alpha in the file's encoding; 8-bit ones in integers, truncated
    (a * b / 255), as Cycles' byte textures hold them.  Returns (pixels,
    mode for the engine): PREMUL once associated (or never to be), the
    engine associates STRAIGHT ones itself (float files)."""
    mode = alpha_mode(bpy_image)
    if mode in ('CHANNEL_PACKED', 'NONE'):
        return pixels, mode
    if is_data(bpy_image) or pixels.shape[2] != 4 or not info.straight:
        return pixels, 'PREMUL'
    if not info.byte:
        return pixels, 'STRAIGHT'
    out = pixels if pixels.flags.writeable else pixels.copy()
    for lo in range(0, len(out), 512):
        band = out[lo:lo + 512]
        raw = np.round(band * 255.0).astype(np.uint32)
        band[..., :3] = (raw[..., :3] * raw[..., 3:] // 255).astype(np.float32) / np.float32(255.0)
    return out, 'PREMUL'


def tile_path(bpy_image, number):
    """The file of UDIM tile ``number``: Blender's ``<UDIM>`` (1001) and
    ``<UVTILE>`` (u1_v1) markers in the image's path replaced."""
    path = bpy.path.abspath(bpy_image.filepath, library=bpy_image.library)
    u, v = (number - 1001) % 10, (number - 1001) // 10
    return path.replace('<UDIM>', str(number)).replace('<UVTILE>', f'u{u + 1}_v{v + 1}')


def is_tiled(bpy_image):
    return getattr(bpy_image, 'source', 'FILE') == 'TILED'


def load_tiles(bpy_image):
    """[(tile number, pixels, srgb_filtered, alpha mode, warnings)] of a tiled (UDIM)
    image, each tile's file read as ``load_image`` reads one (its own bit
    depth decides sRGB filtering and its own channels the alpha, as Cycles
    loads each tile as an image of its own); a tile without a readable file
    is the missing-texture magenta with a warning."""
    packed = {int(p.tile_number): p for p in getattr(bpy_image, 'packed_files', ())}
    tiles = []
    with tempfile.TemporaryDirectory(prefix='ember-udim-') as folder:
        for tile in bpy_image.tiles:
            number = int(tile.number)
            try:
                path = _tile_file(bpy_image, number, packed.get(number), folder)
                tiles.append(_read_tile(bpy_image, number, path))
            except (OSError, RuntimeError, ValueError) as err:
                tiles.append((number, MAGENTA.copy(), False, 'STRAIGHT', [
                    f"Image '{bpy_image.name}' tile {number} could not be loaded ({err}): rendered magenta"]))
    return tiles


def _tile_file(bpy_image, number, packed, folder):
    """The tile's file on disk; a packed tile is written to ``folder``."""
    if packed is None:
        path = tile_path(bpy_image, number)
        if not os.path.isfile(path):
            raise OSError(f"file {path!r} not found")
        return path
    path = os.path.join(folder, f'{number}{os.path.splitext(packed.filepath)[1]}')
    with open(path, 'wb') as f:
        f.write(packed.packed_file.data)
    return path


def _read_tile(bpy_image, number, path):
    pixels = _read_oiio(path)
    if pixels is None:
        raise OSError("OpenImageIO is needed to read UDIM tiles")
    info = _file_info(path)
    pixels, mode, _ = _decoded(pixels, bpy_image, info, texture=True)
    pixels, warnings = _checked(pixels, bpy_image, f" tile {number}")
    return number, pixels, is_srgb(bpy_image) and not info.is_float, mode, warnings


def _checked(pixels, bpy_image, where=""):
    """NaN and infinite texels (a damaged EXR) become 0, with a warning."""
    finite = np.isfinite(pixels)
    if finite.all():
        return pixels, []
    bad = int(finite.size - np.count_nonzero(finite))
    return (np.where(finite, pixels, np.float32(0.0)),
            [f"Image '{bpy_image.name}'{where}: {bad} NaN or infinite values were replaced by 0"])


def is_missing(pixels, warnings):
    """True if load_image gave the missing-texture colour."""
    return bool(warnings) and pixels.shape[:2] == (1, 1)


def _file_is_float(path):
    return _file_info(path).is_float


def _file_info(path):
    """FileInfo of a file as OpenImageIO opens it for Cycles (without its
    automatic alpha association; Cycles' workarounds for TGA, DDS, PSD)."""
    try:
        import OpenImageIO as oiio  # lazy: optional (and slow to load); Blender's pixels without it
    except ImportError:
        return FileInfo(False, True, True)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(path, config)
    if inp is None:
        return FileInfo(False, True, True)
    try:
        spec, name = inp.spec(), inp.format_name()
        straight = bool(spec.get_int_attribute("oiio:UnassociatedAlpha", 0))
        if not straight and spec.alpha_channel != -1:
            straight = (spec.get_int_attribute("targa:alpha_type", -1) != 4 if name == 'targa'
                        else name in ('dds', 'psd'))
        basetype = spec.format.basetype
        return FileInfo(basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE), basetype == oiio.UINT8, straight)
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
