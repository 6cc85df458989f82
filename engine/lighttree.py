"""A light tree: picks the emitter for next-event estimation by its estimated
contribution at the shading point, not by power alone.

A binary tree over the emitters with a position (points, spots, area lights,
emissive-mesh groups), after Estevez & Kulla 2018 and pbrt-v4's
BVHLightSampler (Cycles' light tree is the same idea).  Every node bounds its
emitters by a box, their total power and an orientation cone (axis w, spread
theta_o of the normals, theta_e of the emission about a normal).  Descending
from the root, a shading point p with normal n picks a child with
probability proportional to the child's importance

    phi * cos(theta') / d^2 * cos(theta_i')

(pbrt-v4 LightBounds::Importance): theta' is the smallest angle between the
cone and the direction to p, widened by the angle the box subtends, and
theta_i' likewise for the receiver's normal.  The bounds are conservative, so
an emitter that can light p never gets probability 0.  Emitters without a
position (suns, the world: their bounds are None) are picked uniformly
with probability n_inf / (n_inf + 1), the tree with the rest (pbrt-v4).

The tree reads only ``lightbounds.Bounds``: each light type computes its own
(engine/lights/*.py ``bounds``), so the tree knows no light type and no
light module imports the tree.

``select`` and ``pmf`` evaluate the same products in the same order, so the
selection probability MIS uses is exactly the one NEE sampled with.

``select_segment`` and ``pmf_segment`` pick for a ray segment in a volume
rather than a point (Cycles' light_tree_sample<true>): a node's importance
is its light integrated along the whole segment (``_segment_importance``),
so a spot whose cone misses the segment's start but crosses the rest of it
keeps its probability.
"""
import numpy as np

from .kernels import helper, kernel, loop_kernel, where
from .lightbounds import Bounds, union  # noqa: F401  (the tree's input type, importable from here)


class LightTree:
    """bounds: one ``Bounds`` per emitter (None: no position)."""

    def __init__(self, bounds):
        self.count = len(bounds)
        self.infinite = np.array([e for e, b in enumerate(bounds) if b is None], np.int64)
        finite = [e for e, b in enumerate(bounds) if b is not None]
        self.has_tree = len(finite) > 0
        n_inf = len(self.infinite)
        self.p_infinite = n_inf / (n_inf + (1 if self.has_tree else 0)) if n_inf else 0.0
        nodes = []      # (Bounds, left, right, emitter)
        if finite:
            self._build([(e, bounds[e]) for e in finite], nodes)
        self._pack(nodes)
        self._paths(nodes)
        self._leaves(bounds, nodes)

    # -- construction ---------------------------------------------------------
    def _build(self, items, nodes):
        """Append the subtree of items; returns its node index.  Splits at the
        median centroid along the longest axis of the centroids' box."""
        index = len(nodes)
        nodes.append(None)
        if len(items) == 1:
            e, b = items[0]
            nodes[index] = (b, -1, -1, e)
            return index
        cent = np.array([b.centroid() for _, b in items])
        axis = int(np.argmax(cent.max(axis=0) - cent.min(axis=0)))
        order = np.argsort(cent[:, axis], kind="stable")
        half = len(items) // 2
        left = self._build([items[k] for k in order[:half]], nodes)
        right = self._build([items[k] for k in order[half:]], nodes)
        nodes[index] = (union(nodes[left][0], nodes[right][0]), left, right, -1)
        return index

    def _pack(self, nodes):
        m = len(nodes)
        self.lo = np.array([n[0].lo for n in nodes], float).reshape(m, 3)
        self.hi = np.array([n[0].hi for n in nodes], float).reshape(m, 3)
        self.phi = np.array([n[0].phi for n in nodes], float)
        self.w = np.array([n[0].w for n in nodes], float).reshape(m, 3)
        self.cos_o = np.array([n[0].cos_o for n in nodes], float)
        self.sin_o = np.sqrt(np.maximum(0.0, 1.0 - self.cos_o ** 2))
        self.cos_e = np.array([n[0].cos_e for n in nodes], float)
        self.two_sided = np.array([n[0].two_sided for n in nodes], bool)
        self.two_sided_f = self.two_sided.astype(np.float64)   # kernels take float64
        self.left = np.array([n[1] for n in nodes], np.int64)
        self.right = np.array([n[2] for n in nodes], np.int64)
        self.leaf_emitter = np.array([n[3] for n in nodes], np.int64)
        self.center = 0.5 * (self.lo + self.hi)
        self.radius = 0.5 * np.linalg.norm(self.hi - self.lo, axis=1)

    def _paths(self, nodes):
        """Per emitter: the interior nodes from the root to its leaf and
        whether the path turns left at each, for ``pmf``."""
        steps = {}
        stack = [(0, [])] if nodes else []
        while stack:
            node, path = stack.pop()
            e = self.leaf_emitter[node]
            if e >= 0:
                steps[e] = path
                continue
            stack.append((self.left[node], path + [(node, True)]))
            stack.append((self.right[node], path + [(node, False)]))
        depth = max([len(p) for p in steps.values()] + [0])
        self.depth = depth
        self.path_node = np.zeros((self.count, max(depth, 1)), np.int64)
        self.path_left = np.zeros((self.count, max(depth, 1)), bool)
        self.path_len = np.zeros(self.count, np.int64)
        for e, path in steps.items():
            self.path_len[e] = len(path)
            for k, (node, left) in enumerate(path):
                self.path_node[e, k], self.path_left[e, k] = node, left

    def _leaves(self, bounds, nodes):
        """Per emitter: its leaf node (-1: none) and, for area lights, the
        rectangle Cycles tests for visibility (centre, full edges u and v)."""
        self.leaf_node = np.full(self.count, -1, np.int64)
        for k, node in enumerate(nodes):
            if node[3] >= 0:
                self.leaf_node[node[3]] = k
        self.rect = np.zeros((self.count, 9))
        self.has_rect = np.zeros(self.count, bool)
        for e, b in enumerate(bounds):
            rect = getattr(b, "rect", None)
            if rect is not None:
                self.rect[e] = np.concatenate([np.asarray(x, float) for x in rect])
                self.has_rect[e] = True

    # -- importance -------------------------------------------------------------
    def _tree_arrays(self):
        return (self.center, self.radius, self.w, self.two_sided_f, self.sin_o, self.cos_o, self.cos_e,
                self.phi, self.left, self.right)

    # -- sampling ---------------------------------------------------------------
    def select(self, u, p, n, lobe=None, segment=False):
        """Emitter index and its selection probability for each shading point
        (lobe: (N, LOBE_COLUMNS) glossy-lobe terms, None: none).  segment:
        p and n are ray segments (``select_segment``)."""
        lobe = _lobes(lobe, len(u))
        n = n if segment else _sided(n)
        m = len(u)
        emitter = np.zeros(m, np.int64)
        prob = np.ones(m)
        u = np.asarray(u, float)
        tree = np.ones(m, bool)
        if len(self.infinite):
            pick_inf = (u < self.p_infinite) | (not self.has_tree)
            k = np.minimum((u[pick_inf] / self.p_infinite * len(self.infinite)).astype(np.int64),
                           len(self.infinite) - 1)
            emitter[pick_inf] = self.infinite[k]
            prob[pick_inf] = self.p_infinite / len(self.infinite)
            tree = ~pick_inf
            if self.has_tree:   # else every emitter is infinite and p_infinite is 1
                u = np.where(tree, (u - self.p_infinite) / (1.0 - self.p_infinite), u)
        rows = np.nonzero(tree)[0]
        if len(rows) == m:   # no infinite light picked: the whole arrays, no row copies
            emitter, prob = self._descend_rows(u, p, n, lobe, segment)
        elif len(rows):
            emitter[rows], prob[rows] = self._descend_rows(u[rows], _rows(p, rows), _rows(n, rows), _rows(lobe, rows),
                                                           segment)
        return emitter, prob

    def select_segment(self, u, o, d, t):
        """``select`` for ray segments o + s d, 0 <= s <= t (t may be inf)
        in a volume: each node weighed by its light along the whole
        segment."""
        return self.select(u, o, _segments(d, t), segment=True)

    def pmf_segment(self, emitter, o, d, t):
        """Probability that ``select_segment`` picks ``emitter``."""
        return self.pmf(emitter, o, _segments(d, t), segment=True)

    def _descend_rows(self, u, p, n, lobe, segment=False):
        """``select``'s tree part at every row given: (emitter, probability)."""
        p, n, lobe = (np.ascontiguousarray(a, dtype=np.float64) for a in (p, n, lobe))
        picked = np.empty(len(u), np.int64)
        prob = np.full(len(u), 1.0 - self.p_infinite)
        _descend(np.ascontiguousarray(u, dtype=np.float64), p, n, lobe, *self._tree_arrays(), self.leaf_emitter,
                 segment, picked, prob)
        if not segment:   # no normal at a segment: nothing is culled
            prob *= self._leaf_visible(picked, p, n)
        return picked, prob

    def select_many(self, u, p, n, lobe=None):
        """``select`` for several numbers per shading point, u (N, M), each
        row ascending (stratified candidates): emitters and probabilities
        (N, M), as ``select`` gives them column by column.  The compiled
        descent reuses a node's split where a row's descent repeats the one
        before it (ascending numbers share their first levels)."""
        u = np.asarray(u, float)
        m, k = u.shape
        lobe = _lobes(lobe, m)
        n = _sided(n)
        emitter = np.zeros((m, k), np.int64)
        prob = np.ones((m, k))
        tree = np.ones((m, k), bool)
        uu = u.copy()
        if len(self.infinite):
            pick_inf = (u < self.p_infinite) | (not self.has_tree)
            j = np.minimum((u[pick_inf] / self.p_infinite * len(self.infinite)).astype(np.int64),
                           len(self.infinite) - 1)
            emitter[pick_inf] = self.infinite[j]
            prob[pick_inf] = self.p_infinite / len(self.infinite)
            tree = ~pick_inf
            if self.has_tree:
                uu = np.where(tree, (u - self.p_infinite) / (1.0 - self.p_infinite), u)
        if self.has_tree and tree.any():
            prob[tree] = 1.0 - self.p_infinite
            _descend_many(np.ascontiguousarray(uu), np.ascontiguousarray(tree), _rows(p, np.arange(m)),
                          _rows(n, np.arange(m)), _rows(lobe, np.arange(m)), *self._tree_arrays(), self.leaf_emitter,
                          False, emitter, prob)
            for j in range(k):
                rows = np.flatnonzero(tree[:, j])
                prob[rows, j] *= self._leaf_visible(emitter[rows, j], p[rows], n[rows])
        return emitter, prob

    def pmf(self, emitter, p, n, lobe=None, segment=False):
        """Probability that ``select`` picks ``emitter`` at p (same products)."""
        emitter = np.asarray(emitter, np.int64)
        lobe = _lobes(lobe, len(emitter))
        n = n if segment else _sided(n)
        prob = np.ones(len(emitter))
        inf = np.zeros(len(emitter), bool)
        if len(self.infinite):
            inf = np.isin(emitter, self.infinite)
            prob[inf] = self.p_infinite / len(self.infinite)
        rows = np.nonzero(~inf)[0]
        if len(rows) == len(emitter):   # no infinite light: the whole arrays, no row copies
            return self._pmf_rows(emitter, p, n, lobe, segment)
        if len(rows):
            prob[rows] = self._pmf_rows(emitter[rows], _rows(p, rows), _rows(n, rows), _rows(lobe, rows), segment)
        return prob

    def _pmf_rows(self, emitter, p, n, lobe, segment=False):
        """``pmf`` of tree emitters at every row given."""
        emitter = np.ascontiguousarray(emitter)
        p, n, lobe = (np.ascontiguousarray(a, dtype=np.float64) for a in (p, n, lobe))
        prob = np.full(len(emitter), 1.0 - self.p_infinite)
        _path_pmf(emitter, p, n, lobe, *self._tree_arrays(), self.path_node, self.path_left, self.path_len, segment,
                  prob)
        return prob if segment else prob * self._leaf_visible(emitter, p, n)

    def _leaf_visible(self, emitter, p, n):
        """1, or 0 where the tree's emitter cannot light p from above its
        normal at a point whose closures have no transmission (n[:, 3] 1):
        Cycles' light_tree_emitter_importance is 0 there, so its light
        sampling never picks the emitter at p and a BSDF ray that meets it
        is weighed by MIS as if light sampling could not (weight 1).  Its own
        bounds decide, an area light by Cycles' area_light_tree_parameters."""
        out = np.ones(len(emitter))
        if len(emitter) and self.has_tree:
            _leaf_rows(np.ascontiguousarray(emitter, np.int64), np.ascontiguousarray(p, dtype=np.float64),
                       np.ascontiguousarray(n, dtype=np.float64), self.leaf_node, self.center, self.radius, self.w,
                       self.two_sided_f, self.sin_o, self.cos_o, self.cos_e, self.phi, self.rect, self.has_rect, out)
        return out


def _sided(n):
    """Normals as the tree reads them, (N, 4): a fourth column 1 where the
    point's closures have no transmission (0 when not given: both sides)."""
    n = np.asarray(n, float)
    if n.shape[1] == 4:
        return n
    return np.concatenate([n, np.zeros((len(n), 1))], axis=1)


def _segments(d, t):
    """Ray segments as the tree reads them in place of normals, (N, 4): the
    unit direction and the length (inf: no end)."""
    out = np.empty((len(d), 4))
    out[:, :3], out[:, 3] = d, t
    return out


def _lobes(lobe, m):
    return np.zeros((m, LOBE_COLUMNS)) if lobe is None else lobe


def _rows(a, rows):
    return np.ascontiguousarray(a[rows] if len(rows) < len(a) else a, dtype=np.float64)


def _p_left_numpy(node, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, segment):
    """Probability of descending into the left child of each ``node``
    (segment: p and n are ray segments, ``_segments``)."""
    il = _node_importance(left[node], p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, segment)
    ir = _node_importance(right[node], p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, segment)
    il = il * _node_lobe(left[node], p, lobe, center, radius)
    ir = ir * _node_lobe(right[node], p, lobe, center, radius)
    total = il + ir
    # Both zero: neither child can light p; any choice is unbiased.
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, il / total, 0.5)


def _node_importance(node, p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, segment=False):
    c, wn = center[node], w[node]
    if segment:
        return _segment_importance(p[:, 0], p[:, 1], p[:, 2], n[:, 0], n[:, 1], n[:, 2], n[:, 3],
                                   c[:, 0], c[:, 1], c[:, 2], radius[node], wn[:, 0], wn[:, 1], wn[:, 2],
                                   two_sided[node], sin_o[node], cos_o[node], cos_e[node], phi[node])
    return _importance(p[:, 0], p[:, 1], p[:, 2], n[:, 0], n[:, 1], n[:, 2], n[:, 3],
                       c[:, 0], c[:, 1], c[:, 2], radius[node], wn[:, 0], wn[:, 1], wn[:, 2],
                       two_sided[node], sin_o[node], cos_o[node], cos_e[node], phi[node])


_U_MAX = np.nextafter(1.0, 0.0)


def _descend_numpy(u, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, leaf,
                   segment, emitter, prob):
    """From the root to a leaf per row, picking a child by importance; the
    product of the choices' probabilities multiplies ``prob``."""
    arrays = (center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right)
    rows = np.arange(len(u))
    node = np.zeros(len(u), np.int64)
    uu = u
    while len(rows):
        interior = leaf[node] < 0
        emitter[rows[~interior]] = leaf[node[~interior]]
        rows, node, uu = rows[interior], node[interior], uu[interior]
        if len(rows) == 0:
            break
        pl = _p_left_numpy(node, p[rows], n[rows], lobe[rows], *arrays, segment)
        go_left = uu < pl
        prob[rows] *= np.where(go_left, pl, 1.0 - pl)
        with np.errstate(divide="ignore", invalid="ignore"):
            uu = np.where(go_left, uu / pl, (uu - pl) / (1.0 - pl))
        uu = np.clip(np.nan_to_num(uu), 0.0, _U_MAX)
        node = np.where(go_left, left[node], right[node])


def _path_pmf_numpy(emitter, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right,
                    path_node, path_left, path_len, segment, prob):
    """The product ``_descend`` forms for each row's emitter, along its path."""
    arrays = (center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right)
    rows = np.arange(len(emitter))
    for k in range(path_node.shape[1]):
        rows = rows[path_len[emitter[rows]] > k]
        if len(rows) == 0:
            break
        e = emitter[rows]
        pl = _p_left_numpy(path_node[e, k], p[rows], n[rows], lobe[rows], *arrays, segment)
        prob[rows] *= np.where(path_left[e, k], pl, 1.0 - pl)


@kernel(19)
def _importance(px, py, pz, nx, ny, nz, one_sided, cx, cy, cz, r, wx, wy, wz, two_sided, sin_o, cos_o, cos_e, phi):
    """pbrt-v4 LightBounds::Importance of one node for one shading point (normal
    (0, 0, 0): none), as ``_descend`` and ``_path_pmf`` weigh the children.
    one_sided 1: the point's closures have no transmission (Cycles'
    light_tree_importance without SD_BSDF_HAS_TRANSMISSION): the incidence
    cosine is signed, so a node wholly behind n gets 0."""
    tx, ty, tz = px - cx, py - cy, pz - cz
    d2_true = tx * tx + ty * ty + tz * tz
    d2 = np.maximum(d2_true, r * r)
    inv = 1.0 / np.sqrt(np.maximum(d2_true, 1e-300))
    ix, iy, iz = tx * inv, ty * inv, tz * inv
    cos_w = wx * ix + wy * iy + wz * iz
    cos_w = where(two_sided > 0.0, np.abs(cos_w), cos_w)
    sin_w = _sin(cos_w)
    # Angle the node's bounding sphere subtends at p.
    inside = d2_true <= r * r
    sin2_b = where(inside, 1.0, r * r / np.maximum(d2_true, 1e-300))
    cos_b = where(inside, -1.0, np.sqrt(np.maximum(0.0, 1.0 - sin2_b)))
    sin_b = _sin(cos_b)
    cos_x = _cos_sub(sin_w, cos_w, sin_o, cos_o)
    sin_x = _sin_sub(sin_w, cos_w, sin_o, cos_o)
    cos_p = _cos_sub(sin_x, cos_x, sin_b, cos_b)
    imp = where(cos_p > cos_e, phi * cos_p / d2, 0.0)
    # i points from the node to p: cos_i is the cosine at p towards the node.
    cos_n = ix * nx + iy * ny + iz * nz
    cos_i = where(one_sided > 0.0, -cos_n, np.abs(cos_n))
    has_n = nx * nx + ny * ny + nz * nz > 0.0
    # cos(max(0, theta_i - theta_b)); negative (the node wholly behind n,
    # one-sided) makes the importance 0 below.
    cos_pi = _cos_sub(_sin(cos_i), cos_i, sin_b, cos_b)
    imp = imp * where(has_n, cos_pi, 1.0)
    return np.maximum(imp, 0.0)


@helper
def _sin(cos):
    return np.sqrt(np.maximum(0.0, 1.0 - cos * cos))


@helper
def _cos_sub(sin_a, cos_a, sin_b, cos_b):
    """cos(max(0, a - b))."""
    return where(cos_a > cos_b, 1.0, cos_a * cos_b + sin_a * sin_b)


@helper
def _sin_sub(sin_a, cos_a, sin_b, cos_b):
    """sin(max(0, a - b))."""
    return where(cos_a > cos_b, 0.0, sin_a * cos_b - cos_a * sin_b)


# -- importance along a ray segment in a volume (select_segment) -------------

@kernel(19)
def _segment_importance(ox, oy, oz, dx, dy, dz, t, cx, cy, cz, r, wx, wy, wz, two_sided, sin_o, cos_o, cos_e, phi):
    """A node's importance for the ray segment o + s d, 0 <= s <= t, as
    Cycles' light_tree_node_importance<in_volume_segment>: phi cos(theta')
    (theta_b - theta_a) / h, the integral of 1 / distance^2 along the
    segment (h the line's distance from the node's centre, theta_b -
    theta_a the angle the segment subtends there).  theta' is taken
    conservatively for the whole segment: the segment's direction from the
    centre nearest the emission axis (Cycles' compute_v), widened by the
    angle the bounding sphere subtends at the segment's point closest to
    the centre (the largest along it), so a node that lights any point of
    the segment gets importance > 0.  No incidence cosine (a phase
    function has no normal)."""
    tx, ty, tz = cx - ox, cy - oy, cz - oz
    tc = tx * dx + ty * dy + tz * dz   # the line's closest approach to the centre
    hx, hy, hz = tx - dx * tc, ty - dy * tc, tz - dz * tc
    h = np.maximum(np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 0.5 * r), 1e-12)
    theta_d = np.arctan2(t - tc, h) + np.arctan2(tc, h)
    # The sphere's angle at the segment's point closest to the centre.
    s = np.minimum(np.maximum(tc, 0.0), t)
    qx, qy, qz = tx - dx * s, ty - dy * s, tz - dz * s
    q2 = qx * qx + qy * qy + qz * qz
    inside = q2 <= r * r
    cos_b = where(inside, -1.0, np.sqrt(np.maximum(0.0, 1.0 - r * r / np.maximum(q2, 1e-300))))
    sin_b = _sin(cos_b)
    # From the centre to the segment's ends (a far end stands in for inf).
    te = np.minimum(t, 1e12)
    ax, ay, az = -tx, -ty, -tz
    bx, by, bz = dx * te - tx, dy * te - ty, dz * te - tz
    cos_w = _nearest_cos(ax, ay, az, bx, by, bz, wx, wy, wz)
    cos_w = where(two_sided > 0.0, np.maximum(cos_w, _nearest_cos(ax, ay, az, bx, by, bz, -wx, -wy, -wz)), cos_w)
    sin_w = _sin(cos_w)
    cos_x = _cos_sub(sin_w, cos_w, sin_o, cos_o)
    sin_x = _sin_sub(sin_w, cos_w, sin_o, cos_o)
    cos_p = _cos_sub(sin_x, cos_x, sin_b, cos_b)
    imp = where(cos_p > cos_e, phi * cos_p * theta_d / h, 0.0)
    return np.maximum(imp, 0.0)


@helper
def _nearest_cos(ax, ay, az, bx, by, bz, wx, wy, wz):
    """The largest cosine between w and a direction from the origin to a
    point of the segment from a to b: on the arc of directions from a to b,
    the projection of w onto the arc's plane where it falls inside the arc,
    else the nearer end (Cycles' compute_v)."""
    la = np.sqrt(ax * ax + ay * ay + az * az)
    lb = np.sqrt(bx * bx + by * by + bz * bz)
    ia = where(la > 0.0, 1.0 / np.maximum(la, 1e-300), 0.0)
    ib = where(lb > 0.0, 1.0 / np.maximum(lb, 1e-300), 0.0)
    v0x, v0y, v0z = ax * ia, ay * ia, az * ia
    v1x, v1y, v1z = bx * ib, by * ib, bz * ib
    c01 = v0x * v1x + v0y * v1y + v0z * v1z
    ux, uy, uz = v1x - c01 * v0x, v1y - c01 * v0y, v1z - c01 * v0z   # the arc's tangent at v0
    lu = np.sqrt(ux * ux + uy * uy + uz * uz)
    iu = where(lu > 1e-12, 1.0 / np.maximum(lu, 1e-300), 0.0)
    a0 = wx * v0x + wy * v0y + wz * v0z
    a1 = (wx * ux + wy * uy + wz * uz) * iu
    length = np.sqrt(a0 * a0 + a1 * a1)
    cos_phi = where(length > 0.0, a0 / np.maximum(length, 1e-300), 1.0)
    on_arc = (lu > 1e-12) & (a1 >= 0.0) & (cos_phi >= c01)
    ends = np.maximum(a0, wx * v1x + wy * v1y + wz * v1z)
    # An end at the centre itself: every direction is as near.
    return where((la > 0.0) & (lb > 0.0), where(on_arc, length, ends), 1.0)


@kernel(18)
def _rect_visible(px, py, pz, nx, ny, nz, cx, cy, cz, ux, uy, uz, vx, vy, vz, ax, ay, az):
    """1 where an area light (centre c, full edges u and v, facing a) may
    light p above its normal n, else 0: Cycles' area_light_tree_parameters
    (p in front of the light and the plane test with the full edges, as
    Cycles writes it) and light_tree_importance's incidence test (the cone
    from p through the four corners wholly behind n: 0)."""
    dx, dy, dz = cx - px, cy - py, cz - pz
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    inv = where(dist > 0.0, 1.0 / np.maximum(dist, 1e-300), 0.0)   # safe_normalize
    tx, ty, tz = dx * inv, dy * inv, dz * inv
    cos_u = np.minimum(np.minimum(_corner_cos(dx, dy, dz, tx, ty, tz, ux, uy, uz, vx, vy, vz, -0.5, -0.5),
                                  _corner_cos(dx, dy, dz, tx, ty, tz, ux, uy, uz, vx, vy, vz, 0.5, -0.5)),
                       np.minimum(_corner_cos(dx, dy, dz, tx, ty, tz, ux, uy, uz, vx, vy, vz, -0.5, 0.5),
                                  _corner_cos(dx, dy, dz, tx, ty, tz, ux, uy, uz, vx, vy, vz, 0.5, 0.5)))
    front = ax * tx + ay * ty + az * tz < 0.0
    above = (nx * dx + ny * dy + nz * dz) + np.abs(nx * ux + ny * uy + nz * uz) + np.abs(nx * vx + ny * vy + nz * vz) > 0.0
    cos_i = tx * nx + ty * ny + tz * nz
    cos_min = where(cos_i >= cos_u, 1.0, cos_i * cos_u + _sin(cos_i) * _sin(cos_u))
    return where(front, where(above, where(cos_min > 0.0, 1.0, 0.0), 0.0), 0.0)


@helper
def _corner_cos(dx, dy, dz, tx, ty, tz, ux, uy, uz, vx, vy, vz, su, sv):
    """Cosine between the direction to the centre (t) and to the corner
    c + su u + sv v (d = c - p), as Cycles' safe_normalize_len."""
    qx, qy, qz = dx + su * ux + sv * vx, dy + su * uy + sv * vy, dz + su * uz + sv * vz
    length = np.sqrt(qx * qx + qy * qy + qz * qz)
    inv = where(length > 0.0, 1.0 / np.maximum(length, 1e-300), 0.0)
    return (tx * qx + ty * qy + tz * qz) * inv


# -- the glossy lobe's term (light selection 'tree_bsdf') --------------------
# A vertex whose BSDF is mostly a glossy lobe passes LOBE_COLUMNS numbers:
# the lobe's mirror direction (world), its angular width sigma (radians) and
# the share ``mix`` of the importance the lobe weighs.  A node's importance is
# multiplied by (1 - mix) + mix * exp(-(x / sigma)^2), x the angle between the
# mirror direction and the nearest direction into the node's bounding sphere
# (0 inside it), after Conty Estevez & Kulla 2018's BSDF bound.  mix < 1, so
# every light keeps a nonzero probability; mix 0 multiplies by exactly 1
# (the plain tree).  ``select`` and ``pmf`` use the same factor.
LOBE_COLUMNS = 5


@kernel(12)
def _lobe_weight(px, py, pz, cx, cy, cz, r, rx, ry, rz, sigma, mix):
    """The lobe factor of one node for one shading point."""
    dx, dy, dz = cx - px, cy - py, cz - pz
    d2 = dx * dx + dy * dy + dz * dz
    inv = 1.0 / np.sqrt(np.maximum(d2, 1e-300))
    cos_r = np.minimum(np.maximum((rx * dx + ry * dy + rz * dz) * inv, -1.0), 1.0)
    inside = d2 <= r * r
    cos_b = where(inside, -1.0, np.sqrt(np.maximum(0.0, 1.0 - r * r / np.maximum(d2, 1e-300))))
    cos_x = _cos_sub(_sin(cos_r), cos_r, _sin(cos_b), cos_b)
    x = np.arccos(np.minimum(np.maximum(cos_x, -1.0), 1.0)) / np.maximum(sigma, 1e-6)
    return (1.0 - mix) + mix * np.exp(-x * x)


def _node_lobe(node, p, lobe, center, radius):
    c = center[node]
    return _lobe_weight(p[:, 0], p[:, 1], p[:, 2], c[:, 0], c[:, 1], c[:, 2], radius[node],
                        lobe[:, 0], lobe[:, 1], lobe[:, 2], lobe[:, 3], lobe[:, 4])


# -- the descent, compiled: one loop per row instead of a dozen array
# operations per tree level (the NumPy forms above define the results).

_importance_one = helper(_importance.fn)


_segment_one = helper(_segment_importance.fn)


@helper
def _importance_at(i, k, p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, segment):
    if segment:
        return _segment_one(p[i, 0], p[i, 1], p[i, 2], n[i, 0], n[i, 1], n[i, 2], n[i, 3],
                            center[k, 0], center[k, 1], center[k, 2], radius[k], w[k, 0], w[k, 1], w[k, 2],
                            two_sided[k], sin_o[k], cos_o[k], cos_e[k], phi[k])
    return _importance_one(p[i, 0], p[i, 1], p[i, 2], n[i, 0], n[i, 1], n[i, 2], n[i, 3],
                           center[k, 0], center[k, 1], center[k, 2], radius[k], w[k, 0], w[k, 1], w[k, 2],
                           two_sided[k], sin_o[k], cos_o[k], cos_e[k], phi[k])


_lobe_one = helper(_lobe_weight.fn)


@helper
def _lobe_at(i, k, p, lobe, center, radius):
    if lobe[i, 4] == 0.0:   # no lobe: the factor is exactly 1; skip its arccos and exp
        return 1.0
    return _lobe_one(p[i, 0], p[i, 1], p[i, 2], center[k, 0], center[k, 1], center[k, 2], radius[k],
                     lobe[i, 0], lobe[i, 1], lobe[i, 2], lobe[i, 3], lobe[i, 4])


@helper
def _p_left_one(i, node, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, segment):
    # One call site for both children: numba inlines the importance once
    # (two sites cost ~10 s more compile time).  0 + il + ir == il + ir exactly.
    il, total = 0.0, 0.0
    for side in range(2):
        child = left[node] if side == 0 else right[node]
        imp = _importance_at(i, child, p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, segment)
        imp *= _lobe_at(i, child, p, lobe, center, radius)
        if side == 0:
            il = imp
        total += imp
    if total > 0:
        return il / total
    return 0.5


_TREE_SIGNATURE = ("float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[:, ::1], "
                   "float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], int64[::1], int64[::1]")


@loop_kernel(f"void(float64[::1], {_TREE_SIGNATURE}, int64[::1], boolean, int64[::1], float64[::1])", _descend_numpy)
def _descend(u, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, leaf, segment, emitter,
             prob):
    for i in range(len(u)):
        node = 0
        uu = u[i]
        while leaf[node] < 0:
            pl = _p_left_one(i, node, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right,
                             segment)
            if uu < pl:
                prob[i] *= pl
                v = uu / pl
                node = left[node]
            else:
                prob[i] *= 1.0 - pl
                v = (uu - pl) / (1.0 - pl)
                node = right[node]
            if v != v:
                v = 0.0
            uu = min(max(v, 0.0), _U_MAX)
        emitter[i] = leaf[node]


@loop_kernel(f"void(int64[::1], {_TREE_SIGNATURE}, int64[:, ::1], boolean[:, ::1], int64[::1], boolean, "
             "float64[::1])", _path_pmf_numpy)
def _path_pmf(emitter, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right,
              path_node, path_left, path_len, segment, prob):
    for i in range(len(emitter)):
        e = emitter[i]
        for k in range(path_len[e]):
            pl = _p_left_one(i, path_node[e, k], p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi,
                             left, right, segment)
            prob[i] *= pl if path_left[e, k] else 1.0 - pl


def _descend_many_numpy(u, use, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, leaf,
                        segment, emitter, prob):
    """``_descend`` of each column of u (N, M) where ``use``."""
    for k in range(u.shape[1]):
        rows = np.flatnonzero(use[:, k])
        if len(rows) == 0:
            continue
        e, pr = np.empty(len(rows), np.int64), prob[rows, k].copy()
        _descend_numpy(u[rows, k], p[rows], n[rows], lobe[rows], center, radius, w, two_sided, sin_o, cos_o, cos_e, phi,
                       left, right, leaf, segment, e, pr)
        emitter[rows, k], prob[rows, k] = e, pr


_CACHED_LEVELS = 64


@loop_kernel(f"void(float64[:, ::1], boolean[:, ::1], {_TREE_SIGNATURE}, int64[::1], boolean, int64[:, ::1], "
             "float64[:, ::1])", _descend_many_numpy)
def _descend_many(u, use, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, left, right, leaf,
                  segment, emitter, prob):
    cache_node = np.empty(_CACHED_LEVELS, np.int64)
    cache_pl = np.empty(_CACHED_LEVELS)
    for i in range(u.shape[0]):
        valid = 0   # levels of the row's previous descent kept in the cache
        for k in range(u.shape[1]):
            if not use[i, k]:
                continue
            node = 0
            uu = u[i, k]
            level = 0
            same = True
            while leaf[node] < 0:
                if same and level < valid and cache_node[level] == node:
                    pl = cache_pl[level]
                else:
                    same = False
                    pl = _p_left_one(i, node, p, n, lobe, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi,
                                     left, right, segment)
                    if level < _CACHED_LEVELS:
                        cache_node[level], cache_pl[level] = node, pl
                if uu < pl:
                    prob[i, k] *= pl
                    v = uu / pl
                    node = left[node]
                else:
                    prob[i, k] *= 1.0 - pl
                    v = (uu - pl) / (1.0 - pl)
                    node = right[node]
                if v != v:
                    v = 0.0
                uu = min(max(v, 0.0), _U_MAX)
                level += 1
            valid = min(level, _CACHED_LEVELS)
            emitter[i, k] = leaf[node]


# -- the leaf test at points without transmission (LightTree._leaf_visible)

def _leaf_rows_numpy(emitter, p, n, leaf_node, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, rect, has_rect,
                     out):
    k = leaf_node[emitter]
    rows = np.flatnonzero((n[:, 3] > 0) & np.any(n[:, :3] != 0.0, axis=1) & (k >= 0))
    if len(rows) == 0:
        return
    e, kr, pr, nr = emitter[rows], k[rows], p[rows], n[rows]
    vis = _node_importance(kr, pr, nr, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi) > 0.0
    sq = np.flatnonzero(has_rect[e])
    if len(sq):
        rc, wn, ps, ns = rect[e[sq]], w[kr[sq]], pr[sq], nr[sq]
        vis[sq] = _rect_visible(ps[:, 0], ps[:, 1], ps[:, 2], ns[:, 0], ns[:, 1], ns[:, 2],
                                *(rc[:, j] for j in range(9)), wn[:, 0], wn[:, 1], wn[:, 2]) > 0.0
    out[rows] = vis


_rect_one = helper(_rect_visible.fn)


@loop_kernel("void(int64[::1], float64[:, ::1], float64[:, ::1], int64[::1], float64[:, ::1], float64[::1], "
             "float64[:, ::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[:, ::1], "
             "boolean[::1], float64[::1])", _leaf_rows_numpy)
def _leaf_rows(emitter, p, n, leaf_node, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, rect, has_rect, out):
    for i in range(len(emitter)):
        e = emitter[i]
        k = leaf_node[e]
        if n[i, 3] <= 0.0 or k < 0 or (n[i, 0] == 0.0 and n[i, 1] == 0.0 and n[i, 2] == 0.0):
            continue
        if has_rect[e]:
            v = _rect_one(p[i, 0], p[i, 1], p[i, 2], n[i, 0], n[i, 1], n[i, 2], rect[e, 0], rect[e, 1], rect[e, 2],
                          rect[e, 3], rect[e, 4], rect[e, 5], rect[e, 6], rect[e, 7], rect[e, 8], w[k, 0], w[k, 1],
                          w[k, 2])
        else:
            v = _importance_at(i, k, p, n, center, radius, w, two_sided, sin_o, cos_o, cos_e, phi, False)
        out[i] = 1.0 if v > 0.0 else 0.0
