"""Flattening instances into one world-space triangle soup.

embreex has no instancing, so every instance's triangles are transformed into
world space.  Per-mesh work (corner gathering, slot lookup, validity) is done
once per mesh; per instance only the matrix multiply remains.
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .scene import DEFAULT_MATERIAL


@dataclass
class Triangles:
    """World-space triangles; index = Embree primID.

    p0, e1, e2: (T, 3) float64 vertex 0 and the two edges (p1 - p0, p2 - p0)
    ng: (T, 3) unit geometric normals (right-handed winding)
    ns: (T, 3, 3) per-corner unit shading normals, or None (all flat)
    smooth: (T,) bool, whether ns is meaningful for this triangle
    uv: (T, 3, 2) or None
    material: (T,) int32 index into the compiled material table
    area: (T,)
    """
    p0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    ng: np.ndarray
    ns: Optional[np.ndarray]
    smooth: np.ndarray
    uv: Optional[np.ndarray]
    material: np.ndarray
    area: np.ndarray
    dropped: int = 0

    def __len__(self):
        return len(self.p0)

    def corners_float32(self):
        """(T, 3, 3) float32 vertex positions for Embree."""
        v = np.empty((len(self.p0), 3, 3), dtype=np.float32)
        v[:, 0] = self.p0
        v[:, 1] = self.p0 + self.e1
        v[:, 2] = self.p0 + self.e2
        return v


def _mesh_corners(mesh):
    pos = np.asarray(mesh.positions, dtype=np.float64)
    tris = np.asarray(mesh.triangles, dtype=np.int64)
    return pos[tris]  # (T, 3, 3)


def _slot_table(inst, n_materials):
    """Map material slot -> compiled material id; the last id is the default."""
    default = n_materials  # compiled table appends DEFAULT_MATERIAL
    ids = [m if 0 <= m < n_materials else default for m in inst.materials]
    return np.array(ids + [default], dtype=np.int32)


def flatten(scene):
    """Build Triangles for every instance; degenerate triangles are dropped."""
    n_mat = len(scene.materials)
    mesh_cache = {}
    parts = []
    for inst in scene.instances:
        mesh = scene.meshes[inst.mesh]
        if len(mesh.triangles) == 0:
            continue
        if inst.mesh not in mesh_cache:
            mesh_cache[inst.mesh] = _mesh_corners(mesh)
        corners = mesh_cache[inst.mesh]
        parts.append(_instance_part(mesh, corners, inst, n_mat))
    return _concat(parts)


def _instance_part(mesh, corners, inst, n_mat):
    m = np.asarray(inst.matrix, dtype=np.float64)
    lin, off = m[:3, :3], m[:3, 3]
    world = corners @ lin.T + off
    slots = (np.zeros(len(corners), np.int64) if mesh.material_slots is None
             else np.asarray(mesh.material_slots, dtype=np.int64))
    table = _slot_table(inst, n_mat)
    material = table[np.minimum(slots, len(table) - 1)]
    ns = None
    if mesh.normals is not None:
        # Normals transform with the inverse transpose; a mirroring matrix
        # flips the winding, which the cross product in _concat sees too.
        nmat = np.linalg.inv(lin).T if abs(np.linalg.det(lin)) > 0 else lin
        ns = np.asarray(mesh.normals, dtype=np.float64) @ nmat.T
    uv = None if mesh.uvs is None else np.asarray(mesh.uvs, dtype=np.float64)
    return world, ns, uv, material


def _concat(parts):
    if not parts:
        empty3 = np.zeros((0, 3))
        return Triangles(empty3, empty3, empty3, empty3, None, np.zeros(0, bool), None,
                         np.zeros(0, np.int32), np.zeros(0))
    world = np.concatenate([p[0] for p in parts])
    any_ns = any(p[1] is not None for p in parts)
    any_uv = any(p[2] is not None for p in parts)
    n_each = [len(p[0]) for p in parts]
    smooth = np.concatenate([np.full(n, p[1] is not None) for n, p in zip(n_each, parts)])
    ns = _stack_optional([p[1] for p in parts], n_each, (3, 3)) if any_ns else None
    uv = _stack_optional([p[2] for p in parts], n_each, (3, 2)) if any_uv else None
    material = np.concatenate([p[3] for p in parts]).astype(np.int32)

    p0 = world[:, 0]
    e1 = world[:, 1] - p0
    e2 = world[:, 2] - p0
    c = np.cross(e1, e2)
    clen = np.linalg.norm(c, axis=1)
    keep = np.isfinite(clen) & (clen > 1e-12 * (1.0 + np.abs(p0).max(axis=1)) ** 2)
    dropped = int(len(keep) - keep.sum())
    ng = c[keep] / clen[keep, None]
    if ns is not None:
        ns = _fix_normals(ns[keep], ng, smooth[keep])
    return Triangles(p0[keep], e1[keep], e2[keep], ng, ns, smooth[keep],
                     None if uv is None else uv[keep], material[keep],
                     0.5 * clen[keep], dropped)


def _stack_optional(arrays, counts, tail):
    out = np.zeros((sum(counts),) + tail)
    start = 0
    for a, n in zip(arrays, counts):
        if a is not None:
            out[start:start + n] = a
        start += n
    return out


def _fix_normals(ns, ng, smooth):
    """Unit shading normals; zero or NaN ones fall back to the face normal."""
    length = np.linalg.norm(ns, axis=2)
    bad = ~np.isfinite(length) | (length < 1e-12)
    ns = np.where(bad[..., None], ng[:, None, :], ns / np.where(bad, 1.0, length)[..., None])
    # Flat triangles in a partly smooth scene carry the face normal.
    ns[~smooth] = ng[~smooth, None, :]
    return ns


def material_table(scene):
    """The scene's materials plus the default material at the end."""
    return list(scene.materials) + [DEFAULT_MATERIAL]
