"""Writing images through OpenImageIO: scene-linear EXR, display-referred PNG."""
import numpy as np


def write_image(path, rgba):
    """Write (H, W, C) float pixels, row 0 at the top.  ``.exr`` stays linear
    float; other formats (PNG) are converted linear -> sRGB and quantised."""
    import OpenImageIO as oiio
    from OpenImageIO import ImageBuf, ImageBufAlgo, ImageSpec

    pixels = np.ascontiguousarray(np.nan_to_num(rgba, nan=0.0, posinf=0.0, neginf=0.0), dtype=np.float32)
    h, w, c = pixels.shape
    buf = ImageBuf(ImageSpec(w, h, c, oiio.FLOAT))
    buf.set_pixels(oiio.ROI(), pixels)
    if str(path).lower().endswith(".exr"):
        ok = buf.write(str(path), "float")
    else:
        if c == 4:
            buf.specmod().alpha_channel = 3
        srgb = ImageBufAlgo.colorconvert(buf, "linear", "sRGB")
        ok = srgb.write(str(path), "uint8")
    if not ok:
        raise OSError(f"could not write {path}: {oiio.geterror()}")


def read_image(path):
    """(H, W, C) float32 pixels as stored (no colour conversion)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    pixels = buf.get_pixels(oiio.FLOAT)
    if pixels is None or buf.has_error:
        raise OSError(f"could not read {path}: {buf.geterror()}")
    return pixels
