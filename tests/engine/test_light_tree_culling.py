"""The light tree at points whose closures have no transmission (Cycles'
SD_BSDF_HAS_TRANSMISSION unset; engine/lighttree.py, the fourth column of
its normals): lights wholly behind the normal get probability 0, in
``select`` and ``pmf`` alike, an area light by Cycles' own test; lights with
any point above the normal keep a positive probability; with the column 0
(transmission) nothing changes.  No statistics: exact properties of the
selection (the renders that check unbiasedness are
tests/engine/test_light_tree_bsdf.py's and the hair parity tests)."""
import numpy as np

from engine import scene as S
from engine.lighttree import _rect_visible
from sampling_lib import area_matrix, make_light_set

from test_light_sampling import many_lights


def one_area_light(z=2.0, size=1.0, facing=(0.0, 0.0, -1.0)):
    return make_light_set([S.AreaLight(area_matrix(np.array((0.0, 0.0, z)), facing), (50.0, 50.0, 50.0),
                                       size_x=size)], strategy="tree")[0]


def sided(nrm, one_sided):
    out = np.empty((len(nrm), 4))
    out[:, :3], out[:, 3] = nrm, one_sided
    return out


def test_single_area_light_culled_behind_the_normal():
    """One area light 2 m above the origin facing down: a point at the
    origin facing up picks it with probability 1, facing down with 0
    (without transmission) or 1 (with), and pmf says the same."""
    ls = one_area_light()
    m = 4
    p = np.zeros((m, 3))
    nrm = np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, -1.0], [1.0, 0, 0]])
    flag = np.array([1.0, 1.0, 0.0, 1.0])
    e, prob = ls.select(np.full(m, 0.3), p, sided(nrm, flag))
    np.testing.assert_array_equal(prob, [1.0, 0.0, 1.0, 1.0])   # edge-on: half the light is above
    np.testing.assert_array_equal(ls.selection_pdf(e, p, sided(nrm, flag)), prob)
    # Three columns (no flag) are both sides: as before.
    np.testing.assert_array_equal(ls.selection_pdf(e, p, nrm), np.ones(m))


def test_area_light_test_is_conservative():
    """Random area lights and points: wherever some point of the rectangle
    lies above the point's tangent plane (and the point is in front of the
    light), the test keeps the light; where the whole rectangle, doubled,
    lies below the plane, it culls it (Cycles' plane test uses the full
    edges where the corners are half)."""
    rng = np.random.default_rng(4)
    n = 20000
    p = rng.normal(size=(n, 3))
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    c = rng.normal(size=(n, 3)) * 2.0
    u, v = rng.normal(size=(n, 3)) * 0.5, rng.normal(size=(n, 3)) * 0.5
    a = np.cross(u, v)
    a /= np.linalg.norm(a, axis=1)[:, None]
    a = np.where((np.einsum("ij,ij->i", a, p - c) > 0)[:, None], a, -a)   # p in front of the light
    vis = _rect_visible(*p.T, *nrm.T, *c.T, *u.T, *v.T, *a.T)
    heights = np.stack([np.einsum("ij,ij->i", nrm, c + su * u + sv * v - p)
                        for su in (-0.5, 0.5) for sv in (-0.5, 0.5)])
    above = heights.max(axis=0) > 1e-9
    assert np.all(vis[above] == 1.0), "a light partly above the plane was culled"
    doubled = np.einsum("ij,ij->i", nrm, c - p) + np.abs(np.einsum("ij,ij->i", nrm, u)) + \
        np.abs(np.einsum("ij,ij->i", nrm, v))
    assert np.all(vis[doubled < 0] == 0.0), "a light wholly behind was kept"
    assert 0.2 < vis.mean() < 0.8, vis.mean()


def test_tree_select_and_pmf_agree_when_culling():
    """Hundreds of lights (points, spots, areas, a sun, an emissive mesh)
    and points with random normals, half without transmission: select's
    probability is pmf's of its pick; per point, the pmf over all lights
    sums to at most 1, to 1 with transmission; no light with a point above
    the plane loses its probability (the area lights checked exactly)."""
    ls = make_light_set(many_lights(150), strategy="tree")[0]
    rng = np.random.default_rng(12)
    m = 40
    p = rng.uniform(-4, 4, (m, 3)) * (1, 1, 0.2)
    nrm = rng.normal(size=(m, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    flag = (np.arange(m) % 2).astype(float)
    n4 = sided(nrm, flag)
    u = rng.random(m)
    e, prob = ls.select(u, p, n4)
    np.testing.assert_allclose(ls.selection_pdf(e, p, n4), prob, rtol=1e-12)
    em = np.arange(ls.count)
    kept = culled = 0
    for i in range(m):
        pmf = ls.selection_pdf(em, np.tile(p[i], (ls.count, 1)), np.tile(n4[i], (ls.count, 1)))
        total = pmf.sum()
        if not flag[i]:
            assert abs(total - 1.0) < 1e-12, total
            continue
        assert total <= 1.0 + 1e-12, total
        # Area lights with a corner above the plane, p in front: kept.
        tree = ls.tree
        r = np.flatnonzero(tree.has_rect)
        c, eu, ev = tree.rect[r, :3], tree.rect[r, 3:6], tree.rect[r, 6:9]
        height = np.max([(c + su * eu + sv * ev - p[i]) @ nrm[i] for su in (-0.5, 0.5) for sv in (-0.5, 0.5)],
                        axis=0)
        front = np.einsum("ij,ij->i", tree.w[tree.leaf_node[r]], p[i] - c) > 0
        keep = (height > 1e-9) & front
        doubled = (c - p[i]) @ nrm[i] + np.abs(eu @ nrm[i]) + np.abs(ev @ nrm[i])
        cull = ~front | (doubled < 0)
        kept += keep.sum()
        culled += cull.sum()
        assert np.all(pmf[r[keep]] > 0), "a light partly above the plane lost its probability"
        assert np.all(pmf[r[cull]] == 0), "a light behind the plane kept its probability"
    assert kept > 100 and culled > 100, (kept, culled)   # both cases met
