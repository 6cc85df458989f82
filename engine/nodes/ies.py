"""The IES Texture node: a luminaire's measured intensity by direction, as
Cycles reads and evaluates it (util/ies.cpp: parse, then process the
photometric type B or C table to vertical angles from 0 and horizontal
angles over the full 0-360 degrees; kernel/svm/ies.h: Catmull-Rom cubic
interpolation in both angles).  The table is parsed at export (the node's
``translate``: its internal text or external file) and carried as the
call's ``ies_table`` property; a node without a readable file gives 100, as
Cycles' missing slot.  The unlinked Vector is Incoming in object space (on
a light: the direction from the light towards the lit point), Cycles'
LINK_TEXTURE_INCOMING (measured in bpy 5.0.1: over a camera-seen area light
the IES varies with the view direction, not with the light's normal)."""
import os
import sys

import numpy as np

from .registry import node

# Cycles converts candela to its watt units by 4 pi / 177.83 (D65's luminous efficacy).
CANDELA_TO_WATT = 0.0706650768394
TYPE_A, TYPE_B, TYPE_C = 3, 2, 1   # LM-63's photometric types (Cycles' IESType)
MISSING = 100.0


def parse(text):
    """(h_angles, v_angles, intensity[h][v]) in degrees as the file gives
    them (times the candela multiplier, ballast factors and the watt
    conversion), or None where Cycles' parser fails."""
    start = text.find("\nTILT=")
    if start < 0:
        return None
    data = text[start:].replace(",", " ")
    if data.startswith("\nTILT=INCLUDE"):
        tokens = data[len("\nTILT=INCLUDE"):].split()
        tokens = tokens[1:]
        count = int(float(tokens[0]))
        tokens = tokens[1 + 2 * count:]
    else:
        newline = data.find("\n", 1)
        if newline < 0:
            return None
        tokens = data[newline + 1:].split()
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        values = _leading_numbers(tokens)
    if len(values) < 13:
        return None
    factor = values[2]
    v_num, h_num, kind = int(values[3]), int(values[4]), int(values[5])
    if kind not in (TYPE_A, TYPE_B, TYPE_C) or v_num < 1 or h_num < 1:
        return None
    factor *= values[10] * values[11] * CANDELA_TO_WATT   # ballast and ballast-lamp factors
    body = values[13:]
    if len(body) < v_num + h_num + v_num * h_num:
        return None
    v = np.array(body[:v_num], np.float32)
    h = np.array(body[v_num:v_num + h_num], np.float32)
    intensity = (np.array(body[v_num + h_num:v_num + h_num + v_num * h_num], np.float64) * factor).astype(
        np.float32).reshape(h_num, v_num)
    return kind, h, v, intensity


def _leading_numbers(tokens):
    out = []
    for t in tokens:
        try:
            out.append(float(t))
        except ValueError:
            break
    return out


def process(parsed):
    """Cycles' IESFile::process (type A and B turned into type C's frame,
    symmetric tables mirrored to the full turn): (h radians, v radians,
    intensity[h][v]) as float32, or None without angles."""
    if parsed is None:
        return None
    kind, h, v, intensity = parsed
    h, v, rows = [float(x) for x in h], [float(x) for x in v], [list(r) for r in intensity]
    if not h or not v:
        return None
    if kind == TYPE_A:
        h, v, rows = _type_a(h, v, rows)
    elif kind == TYPE_B:
        h, v, rows = _type_b(h, v, rows)
    else:
        h, v, rows = _type_c(h, v, rows)
    rad = np.float32(np.pi) / np.float32(180.0)
    return (np.array(h, np.float32) * rad, np.array(v, np.float32) * rad, np.array(rows, np.float32))


def _close(a, b):
    return abs(a - b) < 1e-4


def _type_c(h, v, rows):
    if _close(h[0], 90.0):
        h = [a - 90.0 for a in h]      # stored from 90 to 270 degrees
    if len(h) == 1:
        h = [0.0, 360.0]
        rows = rows + [rows[0]]
    if _close(h[-1], 90.0):            # one quadrant: mirror to two
        for i in range(len(h) - 2, -1, -1):
            h.append(180.0 - h[i])
            rows.append(rows[i])
    if _close(h[-1], 180.0):           # one half: mirror to the full turn
        for i in range(len(h) - 2, -1, -1):
            h.append(360.0 - h[i])
            rows.append(rows[i])
    if _close(h[0], 0.0) and not _close(h[-1], 360.0):
        last, first, gap = h[-1] - h[-2], h[1] - h[0], 360.0 - h[-1]
        if _close(last, gap) or _close(first, gap):   # a file that skips the 360 degree entry
            h.append(360.0)
            rows.append(rows[0])
    return h, v, rows


def _mirror_90(angles):
    """Angles over 0-90 degrees mirrored to -90-90 and shifted to 0-180."""
    n = len(angles)
    return [90.0 - angles[i] for i in range(n - 1, 0, -1)] + [90.0 + angles[i] for i in range(n)]


def _type_b(h, v, rows):
    # Type B's polar axis is horizontal: Cycles transposes the table.
    rows = [[rows[j][i] for j in range(len(h))] for i in range(len(v))]
    h, v = v, h
    if _close(h[0], 0.0):
        n = len(h)
        rows = [rows[i] for i in range(n - 1, 0, -1)] + [rows[i] for i in range(n)]
        h = _mirror_90(h)
    else:
        h = [a + 90.0 for a in h]
    if _close(v[0], 0.0):
        n = len(v)
        rows = [[r[j] for j in range(n - 1, 0, -1)] + list(r) for r in rows]
        v = _mirror_90(v)
    else:
        v = [a + 90.0 for a in v]
    return h, v, rows


def _type_a(h, v, rows):
    v = [a + 90.0 for a in v]
    new_h = [180.0 - h[i] for i in range(len(h) - 1, -1, -1)]
    new_rows = [rows[i] for i in range(len(h) - 1, -1, -1)]
    if _close(h[0], 0.0):
        new_h += [180.0 + h[i] for i in range(1, len(h))]
        new_rows += [rows[i] for i in range(1, len(h))]
    return new_h, v, new_rows


def read_table(node_data):
    """The processed table of a Blender IES Texture node (internal text or
    external file), as plain lists for the call's properties; None."""
    text = None
    if getattr(node_data, "mode", "INTERNAL") == "INTERNAL":
        block = getattr(node_data, "ies", None)
        text = block.as_string() if block is not None else None
    else:
        path = getattr(node_data, "filepath", "") or ""
        # Blender's '//' prefix: relative to the .blend (bpy is already loaded
        # where a bpy node is translated; the engine never imports it).
        bpy = sys.modules.get("bpy")
        if path.startswith("//") and bpy is not None:
            path = bpy.path.abspath(path)
        if path and os.path.isfile(path):
            with open(path, "r", errors="replace") as f:
                text = f.read()
    table = process(parse(text)) if text else None
    if table is None:
        return {"ies_table": None}
    h, v, rows = table
    return {"ies_table": (h.tolist(), v.tolist(), rows.tolist())}


def _cubic(a, b, c, d, x):
    """Cycles' cubic_interp (Catmull-Rom), float32."""
    return np.float32(0.5) * (((d + np.float32(3.0) * (b - c) - a) * x + (np.float32(2.0) * a - np.float32(5.0) * b
                                                                            + np.float32(4.0) * c - d)) * x
                              + (c - a)) * x + b


def interpolate(table, h_angle, v_angle):
    """Cycles' kernel_ies_interp for float32 angle arrays: 0 at and beyond
    the last vertical angle, cubic (Catmull-Rom) in v then h; the vertical
    neighbours mirror at the first angle (symmetry about the pole) and clamp
    at the last, the horizontal ones wrap around the full turn (measured
    against bpy 5.0.1: its kernel clamps, where later Cycles reads 0)."""
    h, v, rows = (np.asarray(t, np.float32) for t in table)
    h_num, v_num = len(h), len(v)
    if h_num < 2 or v_num < 2:
        return np.zeros(len(h_angle), np.float32)
    h_i = np.clip(np.searchsorted(h[1:], h_angle, side="left"), 0, h_num - 2)
    v_i = np.clip(np.searchsorted(v[1:], v_angle, side="left"), 0, v_num - 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        h_frac = ((h_angle - h[h_i]) / (h[h_i + 1] - h[h_i])).astype(np.float32)
        v_frac = ((v_angle - v[v_i]) / (v[v_i + 1] - v[v_i])).astype(np.float32)

    def vertical(col):
        a = rows[col, np.where(v_i == 0, 1, v_i - 1)]
        d = rows[col, np.minimum(v_i + 2, v_num - 1)]
        return _cubic(a, rows[col, v_i], rows[col, v_i + 1], d, v_frac)
    a = vertical(np.maximum(h_i - 1, 0))
    d = vertical(np.where(h_i + 2 < h_num, np.minimum(h_i + 2, h_num - 1), max(h_num - 2, 0)))
    out = np.maximum(_cubic(a, vertical(h_i), vertical(h_i + 1), d, h_frac), np.float32(0.0))
    outside = (v_angle < v[0]) | (v_angle >= v[-1]) | (h_angle < h[0]) | (h_angle >= h[-1])
    return np.where(outside, np.float32(0.0), out)


def _translate(node_data):
    return read_table(node_data)


@node("ShaderNodeTexIES", inputs=(("Vector", "vector"), ("Strength", "float")), outputs=(("Fac", "float"),),
      props=(("ies_table", None),), translate=_translate, coords="incoming", tolerance=1e-4,
      input_defaults={"Strength": 1.0}, cases=[{"Strength": 0.01}])
def ies(ctx, i, p):
    strength = np.asarray(i["Strength"], np.float32)
    table = p.get("ies_table")
    if table is None:
        return {"Fac": (strength * np.float32(MISSING)).astype(np.float64)}
    vec = np.asarray(i["Vector"], np.float32)
    length = np.sqrt((vec * vec).sum(axis=1))
    vec = vec / np.where(length > 0, length, np.float32(1.0))[:, None]
    v_angle = np.arccos(np.clip(-vec[:, 2], -1.0, 1.0)).astype(np.float32)
    h_angle = (np.arctan2(vec[:, 0], vec[:, 1]) + np.float32(np.pi)).astype(np.float32)
    return {"Fac": (strength * interpolate(table, h_angle, v_angle)).astype(np.float64)}

