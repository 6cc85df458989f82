"""Colour-space conversions and blends as Cycles' kernel/svm/color_util.h."""
import numpy as np


def rgb_to_hsv(rgb):
    r, g, b = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    cmax = np.max(rgb, axis=1)
    cmin = np.min(rgb, axis=1)
    delta = cmax - cmin
    s = np.where(cmax != 0, delta / np.where(cmax != 0, cmax, 1.0), 0.0)
    safe = np.where(delta != 0, delta, 1.0)
    c = (cmax[:, None] - rgb) / safe[:, None]
    h = np.where(r == cmax, c[:, 2] - c[:, 1], np.where(g == cmax, 2.0 + c[:, 0] - c[:, 2], 4.0 + c[:, 1] - c[:, 0]))
    h = h / 6.0
    h = np.where(h < 0, h + 1.0, h)
    h = np.where(s != 0, h, 0.0)
    return np.stack([h, s, cmax], axis=1)


def hsv_to_rgb(hsv):
    h, s, v = hsv[:, 0], hsv[:, 1], hsv[:, 2]
    h = np.where(h == 1.0, 0.0, h) * 6.0
    i = np.floor(h)
    f = h - i
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    choices = [np.stack(c, axis=1) for c in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))]
    idx = np.clip(i, 0, 5).astype(np.int64)
    idx = np.where((i >= 0) & (i < 5), idx, 5)
    out = np.choose(idx[:, None], choices)
    return np.where((s != 0)[:, None], out, np.stack([v, v, v], axis=1))


def rgb_to_hsl(rgb):
    r, g, b = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    cmax = np.max(rgb, axis=1)
    cmin = np.min(rgb, axis=1)
    l = np.minimum(1.0, (cmax + cmin) / 2.0)
    d = cmax - cmin
    same = cmax == cmin
    sd = np.where(same, 1.0, d)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(l > 0.5, d / (2.0 - cmax - cmin), d / (cmax + cmin))
    h = np.where(cmax == r, (g - b) / sd + np.where(g < b, 6.0, 0.0),
                 np.where(cmax == g, (b - r) / sd + 2.0, (r - g) / sd + 4.0))
    h = np.where(same, 0.0, h / 6.0)
    s = np.where(same, 0.0, s)
    return np.stack([h, s, l], axis=1)


def hsl_to_rgb(hsl):
    h, s, l = hsl[:, 0], hsl[:, 1], hsl[:, 2]
    nr = np.clip(np.abs(h * 6.0 - 3.0) - 1.0, 0.0, 1.0)
    ng = np.clip(2.0 - np.abs(h * 6.0 - 2.0), 0.0, 1.0)
    nb = np.clip(2.0 - np.abs(h * 6.0 - 4.0), 0.0, 1.0)
    chroma = (1.0 - np.abs(2.0 * l - 1.0)) * s
    return np.stack([(nr - 0.5) * chroma + l, (ng - 0.5) * chroma + l, (nb - 0.5) * chroma + l], axis=1)


def _burn(t, a, b):
    tmp = (1.0 - t) + t * b
    with np.errstate(divide="ignore", invalid="ignore"):
        v = 1.0 - (1.0 - a) / tmp
    return np.where(tmp <= 0, 0.0, np.where(v < 0, 0.0, np.where(v > 1, 1.0, v)))


def _dodge(t, a, b):
    tmp = 1.0 - t * b
    with np.errstate(divide="ignore", invalid="ignore"):
        v = a / tmp
    return np.where(a == 0, a, np.where(tmp <= 0, 1.0, np.where(v > 1, 1.0, v)))


def _hue_like(t, a, b, channels):
    hsv_b = rgb_to_hsv(b)
    hsv = rgb_to_hsv(a)
    hsv[:, channels] = hsv_b[:, channels]
    tmp = hsv_to_rgb(hsv)
    mixed = (1.0 - t) * a + t * tmp
    return np.where((hsv_b[:, 1] != 0)[:, None], mixed, a)


def _saturation(t, a, b):
    hsv = rgb_to_hsv(a)
    hsv_b = rgb_to_hsv(b)
    tt = t[:, 0]
    hsv[:, 1] = (1.0 - tt) * hsv[:, 1] + tt * hsv_b[:, 1]
    return np.where((rgb_to_hsv(a)[:, 1] != 0)[:, None], hsv_to_rgb(hsv), a)


def _value(t, a, b):
    hsv = rgb_to_hsv(a)
    tt = t[:, 0]
    hsv[:, 2] = (1.0 - tt) * hsv[:, 2] + tt * rgb_to_hsv(b)[:, 2]
    return hsv_to_rgb(hsv)


def _soft_light(t, a, b):
    scr = 1.0 - (1.0 - b) * (1.0 - a)
    return (1.0 - t) * a + t * ((1.0 - a) * b * a + a * scr)


EXTRA_BLENDS = {
    "BURN": _burn,
    "DODGE": _dodge,
    "HUE": lambda t, a, b: _hue_like(t, a, b, [0]),
    "COLOR": lambda t, a, b: _hue_like(t, a, b, [0, 1]),
    "SATURATION": _saturation,
    "VALUE": _value,
    "SOFT_LIGHT": _soft_light,
    "LINEAR_LIGHT": lambda t, a, b: a + t * (2.0 * b - 1.0),
    "EXCLUSION": lambda t, a, b: np.maximum((1.0 - t) * a + t * (a + b - 2.0 * a * b), 0.0),
}
