"""UDIM tile culling as Cycles' final renders do it (ImageTextureNode::
cull_tiles, Attribute::get_uv_tiles): an Image Texture reading the UV map
(unlinked, a Texture Coordinate UV or a UV Map node) keeps only the tiles
that hold a UV corner of some mesh using its material; a UV inside a tile
without such a corner samples Cycles' missing-tile magenta there.  Other
vectors keep every tile, as in Cycles.

Works on the exported engine scene (no bpy): walks each material's
expressions for tiled ImageTextures and replaces their image by one
holding the used tiles (the tiles' pixels are shared, not copied).
"""
import dataclasses

import numpy as np

from .. import backend


def corner_tiles(uv):
    """Tile numbers of (..., 2) UV corners as Attribute::get_uv_tiles:
    truncated toward zero, corners on a right or upper edge kept in the
    lower tile, u outside [0, 10) and negative v skipped."""
    uv = np.asarray(uv, dtype=np.float32).reshape(-1, 2)
    if not len(uv):
        return set()
    u, v = uv[:, 0], uv[:, 1]
    x, y = np.trunc(u).astype(np.int64), np.trunc(v).astype(np.int64)
    ok = (x >= 0) & (y >= 0) & (x < 10)
    x = np.where((x > 0) & (u < x.astype(np.float32) + np.float32(1e-6)), x - 1, x)
    y = np.where((y > 0) & (v < y.astype(np.float32) + np.float32(1e-6)), y - 1, y)
    return set((1001 + 10 * y[ok] + x[ok]).tolist())


def _uv_of(mesh, name):
    maps = getattr(mesh, 'uv_maps', None) or {}
    if name and name in maps:
        return maps[name]
    if name and maps:
        return None    # a map this mesh lacks: no corners
    return mesh.uvs


def _image_textures(value, seen, out):
    """Every ImageTexture reachable from an engine value (dataclasses,
    sequences, dicts), each once."""
    if value is None or isinstance(value, (str, bytes, int, float, bool, np.ndarray, np.generic)):
        return
    if id(value) in seen:
        return
    seen.add(id(value))
    if type(value).__name__ == 'ImageTexture':
        out.append(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            if f.name == 'image' and type(value).__name__ == 'ImageTexture':
                continue
            _image_textures(getattr(value, f.name, None), seen, out)
    elif isinstance(value, (list, tuple)):
        for item in value:
            _image_textures(item, seen, out)
    elif isinstance(value, dict):
        for item in value.values():
            _image_textures(item, seen, out)


def _uv_map_name(node):
    """'' for the active UV map, the UV Map node's map, or None: a vector
    Cycles does not cull for."""
    if getattr(node, 'projection', 'FLAT') != 'FLAT':
        return None   # an Environment Texture: no UVs, and its tiles are not read
    if node.uv is None:
        return ''
    call = getattr(node.uv, 'call', None)
    if call is not None and call.idname == 'ShaderNodeUVMap' and getattr(node.uv, 'output', '') == 'UV':
        return call.props.get('uv_map', '') or ''
    return None


def cull_tiles(scene):
    """Drop the tiles no mesh of the material has a UV corner in (in place)."""
    users = {}
    for inst in backend.engine().distinct_instances(scene.instances):
        for m in inst.materials:
            users.setdefault(m, set()).add(inst.mesh)
    for index, material in enumerate(scene.materials):
        nodes = []
        _image_textures(material, set(), nodes)
        for node in nodes:
            tiles = getattr(node.image, 'tiles', ())
            name = _uv_map_name(node)
            if len(tiles) < 2 or name is None:
                continue
            used = set()
            for mesh_index in users.get(index, ()):
                uv = _uv_of(scene.meshes[mesh_index], name)
                if uv is not None:
                    used |= corner_tiles(uv)
            kept = tuple((n, tile) for n, tile in tiles if int(n) in used)
            if kept and len(kept) < len(tiles):
                first = kept[0][1]
                node.image = dataclasses.replace(node.image, pixels=first.pixels, tiles=kept)
