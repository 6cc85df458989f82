"""Per-mesh attributes Cycles derives from the topology at sync, for the
Geometry node: Pointiness and Random Per Island (Cycles blender/mesh.cpp,
attr_create_pointiness and attr_create_random_per_island).

Both take the evaluated mesh's vertex positions, vertex normals and edge
list (Blender's edges, not the triangles' sides: a quad's diagonal is no
edge) and compute in float32 in Cycles' order, so the values agree with
Cycles' to float32 rounding.

The mesh stores them as corner attributes under reserved names (no user
attribute can be named with a NUL), so every per-triangle filter of the
exporter and the engine's interpolation treat them like colour attributes.
"""
import numpy as np

from .nodes.context import POINTINESS, RANDOM_PER_ISLAND  # noqa: F401  (the reserved names)
from .nodes.hashing import hash_uint, to_float

F32 = np.float32
FLT_EPSILON = F32(1.1920929e-07)


def _weld(positions):
    """Cycles' STEP 1: each vertex's 'original' (a coincident vertex found
    by sorting on x + y + z), followed to the end of the chain."""
    n = len(positions)
    p = positions.astype(F32)
    key = (p[:, 0] + p[:, 1]) + p[:, 2]
    # Equal vertices order by descending index (Cycles' comparator).
    order = np.lexsort((-np.arange(n), key))
    sorted_key = key[order]
    orig = np.arange(n)
    pending = np.ones(n, bool)   # in sorted order: no duplicate found yet, still in the window
    k = 1
    while pending.any() and k < n:
        i = np.nonzero(pending[:n - k])[0]
        if len(i) == 0:
            break
        far = (sorted_key[i + k] - sorted_key[i]) > 3 * FLT_EPSILON
        pending[i[far]] = False
        i = i[~far]
        d = p[order[i + k]] - p[order[i]]
        dup = ((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2]) < FLT_EPSILON
        orig[order[i[dup]]] = order[i[dup] + k]
        pending[i[dup]] = False
        pending[n - k:] = False
        k += 1
    for _ in range(n):   # follow chains to their end
        nxt = orig[orig]
        if np.array_equal(nxt, orig):
            break
        orig = nxt
    return orig


def _unique_edges(edges, orig):
    """Edges on original vertices, each unordered pair once (first kept)."""
    e = orig[np.asarray(edges, dtype=np.int64).reshape(-1, 2)]
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    _, first = np.unique(lo * (int(hi.max(initial=0)) + 1) + hi, return_index=True)
    return e[np.sort(first)]


def pointiness(positions, vertex_normals, edges):
    """(V,) float32 Pointiness per vertex, as Cycles' attr_create_pointiness."""
    positions = np.asarray(positions, dtype=F32).reshape(-1, 3)
    n = len(positions)
    if n == 0:
        return np.zeros(0, F32)
    orig = _weld(positions)
    normal = np.zeros((n, 3), F32)
    np.add.at(normal, orig, np.asarray(vertex_normals, dtype=F32).reshape(-1, 3))
    normal = np.nan_to_num(normal[orig], nan=0.0, posinf=0.0, neginf=0.0)
    length = np.sqrt((normal * normal).sum(axis=1, dtype=F32))
    normal = np.where(length[:, None] > 0, normal / np.where(length > 0, length, F32(1))[:, None], normal)
    e = _unique_edges(edges, orig)
    # Edges touching a NaN or infinite vertex are left out (the exporter
    # drops those triangles): the values stay finite around them.
    finite = np.isfinite(positions).all(axis=1)
    e = e[finite[e[:, 0]] & finite[e[:, 1]]]
    v0, v1 = e[:, 0], e[:, 1]
    d = positions[v1] - positions[v0]
    dl = np.sqrt((d * d).sum(axis=1, dtype=F32))
    d = np.where(dl[:, None] > 0, d / np.where(dl > 0, dl, F32(1))[:, None], F32(0))
    accum = np.zeros((n, 3), F32)
    # Interleaved as Cycles adds them (v0 += edge, v1 -= edge, edge by edge).
    np.add.at(accum, np.stack([v0, v1], axis=1).ravel(), np.stack([d, -d], axis=1).reshape(-1, 3))
    counter = np.bincount(np.concatenate([v0, v1]), minlength=n)
    raw = np.zeros(n, F32)
    ok = (counter > 0) & (orig == np.arange(n))
    mean = accum[ok] / counter[ok].astype(F32)[:, None]
    cos = (normal[ok] * mean).sum(axis=1, dtype=F32)
    raw[ok] = np.arccos(np.clip(cos, F32(-1), F32(1))) * F32(1.0 / np.pi)
    data = raw.copy()
    np.add.at(data, np.stack([v0, v1], axis=1).ravel(), np.stack([raw[v1], raw[v0]], axis=1).ravel())
    data = data / (counter + 1).astype(F32)
    return np.nan_to_num(data[orig], nan=0.0).astype(F32)


def island_roots(num_vertices, edges):
    """The root of each vertex in Cycles' DisjointSet after joining every
    edge in order (union by rank, path compression): which vertex names an
    island decides its random value."""
    parent = list(range(num_vertices))
    rank = [0] * num_vertices

    def find(x):
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for a, b in np.asarray(edges, dtype=np.int64).reshape(-1, 2).tolist():
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        if rank[ra] < rank[rb]:
            ra, rb = rb, ra
        parent[rb] = ra
        if rank[ra] == rank[rb]:
            rank[ra] += 1
    return np.array([find(v) for v in range(num_vertices)], dtype=np.int64)


def random_per_island(num_vertices, edges, triangles):
    """(T,) float32: hash_uint_to_float of the island root of each
    triangle's first vertex (Cycles' face attribute)."""
    roots = island_roots(num_vertices, edges)
    tris = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    return to_float(hash_uint(roots[tris[:, 0]].astype(np.uint32)))
