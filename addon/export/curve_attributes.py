"""A Curves object's generic attributes for shading (Cycles' blender/curves.cpp
attr_create_generic): point-domain attributes become per-key values mixed
along a segment, curve-domain ones per-curve values; the first 2D vector
attribute on the curve domain is the strands' UV map (Cycles' "weak" rule:
hair made on a surface carries ``surface_uv_coordinate`` there).  Byte
colours are read linear (``color``, Blender's scene-linear view of them, as
Cycles' converter).  NaN or infinite values read as 0, named once per
object.  bpy only; no engine import."""
import numpy as np

# data_type -> (foreach_get property, columns)
_TYPES = {'FLOAT': ('value', 1), 'INT': ('value', 1), 'INT8': ('value', 1), 'BOOLEAN': ('value', 1),
          'FLOAT_VECTOR': ('vector', 3), 'FLOAT2': ('vector', 2), 'FLOAT_COLOR': ('color', 4),
          'BYTE_COLOR': ('color', 4)}
# What the strands themselves are made of, not shading data.
_GEOMETRY = {'position', 'radius'}


_DTYPES = {'BOOLEAN': bool, 'INT': np.int32, 'INT8': np.int32}


def _read(attr, count):
    """(count, columns) float32 values of a bpy attribute."""
    prop, width = _TYPES[attr.data_type]
    values = np.empty(count * width, _DTYPES.get(attr.data_type, np.float32))
    attr.data.foreach_get(prop, values)
    return values.reshape(count, width).astype(np.float32)


def curve_attributes(data, keep_points, keep_curves, warn):
    """(point attributes, curve attributes, UV map name or None) of the
    Curves data-block ``data``; ``keep_points`` / ``keep_curves``: the
    points and curves exported (bool masks, or None for all); warn(text)
    names a non-finite attribute."""
    points, curves, uv = {}, {}, None
    sizes = {'POINT': len(data.points), 'CURVE': len(data.curves)}
    for attr in data.attributes:
        name = attr.name
        if name in _GEOMETRY or name.startswith('.') or attr.data_type not in _TYPES or attr.domain not in sizes:
            continue
        values = _read(attr, sizes[attr.domain])
        keep = keep_points if attr.domain == 'POINT' else keep_curves
        if keep is not None:
            values = values[keep]
        bad = ~np.isfinite(values)
        if bad.any():
            warn(f"attribute '{name}': {int(bad.any(axis=1).sum())} NaN or infinite values read as 0")
            values = np.where(bad, 0.0, values).astype(np.float32)
        if attr.domain == 'POINT':
            points[name] = values
        else:
            curves[name] = values
            if uv is None and attr.data_type == 'FLOAT2':
                uv = name
    return points, curves, uv
