"""Equirectangular environment maps (HDRI worlds): lookups as Cycles does
them, and importance sampling by a piecewise-constant 2D distribution.

Coordinates follow Cycles (kernel/camera/projection.h,
direction_to_equirectangular): for a lookup vector e,

    u = (pi - atan2(e_y, e_x)) / (2 pi),   v = 1 - acos(e_z / |e|) / pi,

so +X is the middle of the image, +Y a quarter from its left edge, and v = 1
(the image's top row) is +Z.  Cycles' v counts rows from the bottom (Blender's
image convention); ``EnvironmentTexture.pixels`` has row 0 at the top, so the
map flips it once.  Lookups (kernel/device/cpu/image.h) put pixel centres at
(i + 0.5) / W and wrap periodically in both axes (EXTENSION_REPEAT, which the
Environment Texture node always uses): bilinear ('Linear') or nearest
('Closest').

The world direction d becomes the lookup vector e = M d (``matrix``, the
Mapping node).  Sampling picks (u, v) from a table of luminance x sin(theta)
over the texture's pixels (pbrt's Distribution2D, Cycles' background map), so

    pdf(d) = pdf_uv / (2 pi^2 sin(theta)) * |det M| / |M d|^3,

the last factor being the Jacobian of d -> M d / |M d| (1 for rotations).

Baked procedural worlds (``texture.shader``) are evaluated exactly per
direction, as Cycles shades its background; the baked pixels only build the
table.  A sun disc too small for the table (``texture.sun``, the Sky
Texture's) is sampled as Cycles' background light does with sun guiding
(kernel/light/background.h): the disc's cone with weight 4, the table with
weight 1, one-sample MIS over the two (the pdf is their mixture).
"""
import numpy as np

from . import kernels
from .nodes.context import ShadingContext
from .projection import direction_to_equirect, direction_to_mirrorball, to_uv
from .sampling import Distribution2D, uniform_cone
from .textures import Compiler
from .vec import column, frame, luminance, to_world

TWO_PI_SQ = 2.0 * np.pi * np.pi
# Wider textures are summed into blocks for the sampling table (Cycles'
# background map resolution plays the same role): the pdf stays exact, the
# table small.
MAX_TABLE_WIDTH = 2048
# Cycles' background strategy weights with sun guiding: map 1, sun 4.
SUN_SHARE = 0.8


def equirect_to_direction(u, v):
    """Unit directions for (u, v): phi = pi - 2 pi u, theta = pi (1 - v)."""
    phi = np.pi - 2.0 * np.pi * u
    theta = np.pi * (1.0 - v)
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=1)


def bake(expression, width, height, importance_bake=False):
    """A world colour expression as (height, width, 3) float32 equirectangular
    pixels (row 0 = +Z), each texel centre's direction shaded as a camera ray
    of Cycles' background (P = Generated = d, N = incoming = -d), negative
    values clamped.  importance_bake: Cycles' PATH_RAY_IMPORTANCE_BAKE (a
    guided sky's sun disc stays out of the table)."""
    u = (np.arange(width) + 0.5) / width
    v = 1.0 - (np.arange(height) + 0.5) / height      # row 0 is the top (+Z)
    uu, vv = np.meshgrid(u, v)
    d = equirect_to_direction(uu.reshape(-1), vv.reshape(-1))
    ctx = ShadingContext(len(d), p=d, ng=-d, ns=-d, wo=-d)
    ctx.importance_bake = importance_bake
    rgb = Compiler().color(expression)(ctx)
    return np.ascontiguousarray(np.maximum(rgb, 0.0).reshape(height, width, 3), dtype=np.float32)


def lookup(image, u, v, closest=False):
    """Cycles' image lookup at (u, v) of an (H, W, C) image whose row 0 is
    the bottom (v = 0); periodic wrap in both axes."""
    h, w = image.shape[:2]
    if closest:
        ix = np.floor(np.asarray(u, np.float64) * w).astype(np.int64) % w
        iy = np.floor(np.asarray(v, np.float64) * h).astype(np.int64) % h
        return image[iy, ix].astype(np.float64)
    u, v = (column(a, len(a), np.float64) for a in (np.atleast_1d(u), np.atleast_1d(v)))
    out = np.empty((len(u), image.shape[2]))
    if image.dtype == np.float32 and image.flags.c_contiguous:
        _bilinear(image, u, v, out)
    else:
        _bilinear_numpy(image, u, v, out)
    return out


def _bilinear_numpy(image, u, v, out):
    h, w = image.shape[:2]
    x, y = u * w, v * h
    # Pixel centres at i + 0.5: interpolate between the two nearest.
    fx, fy = np.floor(x - 0.5), np.floor(y - 0.5)
    tx, ty = (x - 0.5 - fx)[:, None], (y - 0.5 - fy)[:, None]
    ix, iy = fx.astype(np.int64) % w, fy.astype(np.int64) % h
    nix, niy = (ix + 1) % w, (iy + 1) % h
    bottom = (1.0 - tx) * image[iy, ix] + tx * image[iy, nix]
    top = (1.0 - tx) * image[niy, ix] + tx * image[niy, nix]
    out[:] = (1.0 - ty) * bottom + ty * top


@kernels.loop_kernel("void(float32[:, :, ::1], float64[:], float64[:], float64[:, ::1])", _bilinear_numpy)
def _bilinear(image, u, v, out):
    h, w = image.shape[0], image.shape[1]
    for i in range(len(u)):
        x, y = u[i] * w, v[i] * h
        fx, fy = np.floor(x - 0.5), np.floor(y - 0.5)
        tx, ty = x - 0.5 - fx, y - 0.5 - fy
        ix, iy = np.int64(fx) % w, np.int64(fy) % h
        nix, niy = (ix + 1) % w, (iy + 1) % h
        for c in range(image.shape[2]):
            bottom = (1.0 - tx) * np.float64(image[iy, ix, c]) + tx * np.float64(image[iy, nix, c])
            top = (1.0 - tx) * np.float64(image[niy, ix, c]) + tx * np.float64(image[niy, nix, c])
            out[i, c] = (1.0 - ty) * bottom + ty * top


class EnvironmentMap:
    """An ``EnvironmentTexture`` ready to evaluate and sample.

    compensate: sample max(L - mean, 0) (MIS compensation, Karlik et al.
    2019) instead of L.  Directions darker than the mean then have pdf 0, so
    this is only unbiased when BSDF sampling covers them (strategy 'mis').
    """

    def __init__(self, texture, compensate=False):
        pixels = np.asarray(texture.pixels, dtype=np.float32)[..., :3]
        # Row 0 = bottom from here on, as Cycles' v.
        self.image = np.ascontiguousarray(pixels[::-1] * np.float32(texture.strength))
        self.strength = float(texture.strength)
        self.closest = texture.interpolation == "Closest"
        self.matrix = np.asarray(texture.matrix, dtype=np.float64)
        self.inverse = np.linalg.inv(self.matrix)
        self.det = abs(float(np.linalg.det(self.matrix)))
        self.projection = getattr(texture, "projection", "EQUIRECTANGULAR")
        lum = np.maximum(luminance(self._equirect_pixels()), 0.0)
        sin_rows = np.sin(np.pi * (np.arange(lum.shape[0]) + 0.5) / lum.shape[0])[:, None]
        # Mean luminance over the sphere (solid-angle weighted).
        self.mean_luminance = float((lum * sin_rows).sum() / (sin_rows.sum() * lum.shape[1]))
        self.dist = Distribution2D(self._table(lum, compensate))
        self.shader = compile_world(texture.shader) if getattr(texture, "shader", None) is not None else None
        self.sun = _Sun(texture.sun) if getattr(texture, "sun", None) is not None else None

    def _equirect_pixels(self):
        """The map over equirectangular (u, v) of the lookup vector, which the
        sampling table covers.  A mirror ball is looked up at the texel
        centres of a 2N x N grid (as Cycles' background map evaluates the
        world's shader on its own equirectangular grid): the pdf stays exact
        (the table is sampled in equirect (u, v)), only its fit is approximate."""
        image = self.image.astype(np.float64)
        if self.projection != "MIRROR_BALL":
            return image
        n = min(max(image.shape[:2]), MAX_TABLE_WIDTH // 2)
        u = (np.arange(2 * n) + 0.5) / (2 * n)
        v = (np.arange(n) + 0.5) / n                        # row 0 = bottom, as self.image
        uu, vv = np.meshgrid(u, v)
        e = equirect_to_direction(uu.reshape(-1), vv.reshape(-1))
        mu, mv = direction_to_mirrorball(e)
        return lookup(self.image, mu, mv, self.closest).reshape(n, 2 * n, 3)

    def _table(self, lum, compensate):
        # Closest lookups of an equirect map are constant per cell; a
        # resampled mirror ball is not, so its cells see their neighbours too.
        exact_cells = self.closest and self.projection != "MIRROR_BALL"
        cells = lum if exact_cells else _cover_neighbours(lum)
        cells = _downsample(cells)
        h = cells.shape[0]
        sin_rows = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
        if compensate:
            mean = (cells * sin_rows).sum() / (sin_rows.sum() * cells.shape[1])
            weights = np.maximum(cells - mean, 0.0) * sin_rows
            if weights.sum() > 0:  # a constant map has nothing above its mean
                return weights
        return cells * sin_rows

    def power(self):
        """Integral of luminance over the sphere (W / m^2 per unit area seen)."""
        sun = self.sun.power * float(self.strength) if self.sun is not None else 0.0
        return 4.0 * np.pi * self.mean_luminance + sun

    def eval(self, d):
        """Radiance (N, 3) arriving from world directions d (N, 3)."""
        if self.shader is not None:
            return self.shader(d) * self.strength
        u, v = to_uv(d @ self.matrix.T, self.projection)
        return lookup(self.image, u, v, self.closest)

    def sample(self, u1, u2):
        """World directions (N, 3) and their solid-angle pdf."""
        if self.sun is None:
            return self._sample_map(u1, u2)
        to_sun = u1 < SUN_SHARE
        d = np.empty((len(u1), 3))
        s, m = np.nonzero(to_sun)[0], np.nonzero(~to_sun)[0]
        d[s] = self.sun.sample(u1[s] / SUN_SHARE, u2[s])
        d[m] = self._sample_map((u1[m] - SUN_SHARE) / (1.0 - SUN_SHARE), u2[m])[0]
        return d, self.pdf(d)

    def _sample_map(self, u1, u2):
        x, y, pdf_uv = self.dist.sample(u1, u2)
        e = equirect_to_direction(x, y)
        d = e @ self.inverse.T
        inv_len = np.sqrt(np.einsum("ij,ij->i", d, d))  # = 1 / |M d| for unit d
        d /= inv_len[:, None]
        return d, self._solid_angle_pdf(pdf_uv, np.sin(np.pi * y), inv_len ** 3)

    def pdf(self, d):
        """Solid-angle pdf of ``sample`` returning world directions d."""
        if self.sun is None:
            return self._map_pdf(d)
        return (1.0 - SUN_SHARE) * self._map_pdf(d) + SUN_SHARE * self.sun.pdf(d)

    def _map_pdf(self, d):
        e = d @ self.matrix.T
        u, v = direction_to_equirect(e)
        length = np.sqrt(np.einsum("ij,ij->i", e, e))
        sin_t = np.hypot(e[:, 0], e[:, 1]) / length
        return self._solid_angle_pdf(self.dist.pdf(u, v), sin_t, 1.0 / length ** 3)

    def _solid_angle_pdf(self, pdf_uv, sin_t, inv_len_cubed):
        ok = sin_t > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            pdf = pdf_uv / (TWO_PI_SQ * sin_t) * self.det * inv_len_cubed
        return np.where(ok, pdf, 0.0)


def _cover_neighbours(lum):
    """Weights positive wherever bilinear lookups are: a texel's cell also
    sees its 8 neighbours (periodic), so mix in their mean.  NEE alone then
    reaches every direction with radiance, and bright texels still dominate."""
    acc = np.zeros_like(lum)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            acc += np.roll(np.roll(lum, dy, axis=0), dx, axis=1)
    return 0.5 * lum + 0.5 * acc / 9.0


def _downsample(cells):
    """Sum k x k blocks when the table would be wider than MAX_TABLE_WIDTH
    (k divides both sizes, so blocks line up with texels)."""
    h, w = cells.shape
    k = -(-w // MAX_TABLE_WIDTH)
    while k > 1 and (w % k or h % k):
        k += 1
        if k > w or k > h:
            return cells
    if k <= 1:
        return cells
    return cells.reshape(h // k, k, w // k, k).sum(axis=(1, 3))


def compile_world(expression):
    """A world colour expression as a function of directions (N, 3): the
    shading context Cycles gives the background (P = Generated = the
    direction, N = incoming = -direction, a camera ray)."""
    color = Compiler().color(expression)

    def shade(d):
        d = np.asarray(d, np.float64)
        rgb = np.asarray(color(ShadingContext(len(d), p=d, ng=-d, ns=-d, wo=-d)), np.float64)
        return np.maximum(np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0), 0.0)
    return shade


class _Sun:
    """Uniform sampling of a sun disc's cone (Cycles' background_sun_sample)."""

    def __init__(self, guide):
        axis = np.asarray(guide.direction, np.float64)
        self.axis = axis / np.linalg.norm(axis)
        half = float(guide.half_angle)
        self.one_minus_cos = 2.0 * np.sin(0.5 * half) ** 2     # 1 - cos without cancellation
        self.cos_max = 1.0 - self.one_minus_cos
        self.power = float(guide.power)

    def sample(self, u1, u2):
        local, _ = uniform_cone(u1, u2, self.one_minus_cos)
        n = np.broadcast_to(self.axis, (len(u1), 3))
        s, t = frame(n)
        return to_world(local, s, t, n)

    def pdf(self, d):
        inside = d @ self.axis >= self.cos_max
        return np.where(inside, 1.0 / (2.0 * np.pi * self.one_minus_cos), 0.0)
