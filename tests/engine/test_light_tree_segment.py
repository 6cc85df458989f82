"""The light tree's selection for a ray segment in a volume (Cycles'
light_tree_sample<true>; engine/lighttree.py ``select_segment``,
``pmf_segment``): a light whose bounds miss the segment's start but light
the rest of it keeps a probability > 0 (the point selection at the start
gives it 0, which lost a spot's in-scattered light, docs/real_scenes.md
world_volume); the probability ``select_segment`` returns is the
``pmf_segment`` MIS takes; the picks follow it (chi-square); and a light
that lights any point of a segment (by the tree's point importance) keeps
a positive probability.  One statistical family: the chi-square."""
import numpy as np

import chi2 as C
import ember_stats
from engine import scene as S
from engine.lighttree import _importance
from sampling_lib import make_light_set

from test_light_sampling import many_lights

N = 100_000


def spot_and_point():
    """A point light and a narrow spot pointing down at x = 3: a camera
    ray from the origin along +x starts outside the spot's cone and
    crosses it near x = 3."""
    return [S.PointLight((0.0, 2.0, 1.0), (100.0, 100.0, 100.0), 0.05, True),
            S.SpotLight((3.0, 0.0, 2.0), (400.0, 400.0, 400.0), 0.05, direction=(0.0, 0.0, -1.0),
                        spot_size=0.5, spot_blend=0.1)]


def test_spot_missing_the_start_keeps_its_probability():
    ls = make_light_set(spot_and_point(), strategy="tree")[0]
    e = np.array([0, 1])
    spot = int(np.flatnonzero(ls.points.spot[ls.local[e]])[0])
    o = np.zeros((2, 3))
    d = np.tile((1.0, 0.0, 0.0), (2, 1))
    at_start = ls.selection_pdf(e, o, np.zeros((2, 3)))
    along = ls.selection_pdf(e, o, d, segment=np.array([6.0, 6.0]))
    print(f"\nat the start {at_start}, along the segment {along}")
    assert at_start[spot] == 0.0, "the spot's cone should miss the segment's start"
    assert along[spot] > 0.05, along
    assert abs(along.sum() - 1.0) < 1e-12
    # A segment that ends before the cone: the spot's probability is 0 again.
    short = ls.selection_pdf(e, o, d, segment=np.array([1.0, 1.0]))
    assert short[spot] == 0.0 and abs(short.sum() - 1.0) < 1e-12


def segments(rng, m):
    o = rng.uniform(-4, 4, (m, 3)) * (1, 1, 0.3)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0.0, 6.0, m)
    t[::5] = np.inf   # world volumes: no end
    return o, d, t


def test_segment_pmf_sums_to_one_and_keeps_every_light_that_lights_the_segment():
    """Hundreds of lights (points, spots, areas, a sun, an emissive mesh):
    per segment the pmf sums to 1, and every light whose point importance
    is positive somewhere along the segment (sampled at 200 points) has
    probability > 0."""
    ls = make_light_set(many_lights(150) + [S.SunLight((0.2, 0.1, -1.0), (0.5, 0.5, 0.5), 0.05)],
                        strategy="tree")[0]
    tree = ls.tree
    rng = np.random.default_rng(5)
    o, d, t = segments(rng, 30)
    em = np.arange(ls.count)
    leaf = tree.leaf_node
    bounded = np.flatnonzero(leaf >= 0)
    k = leaf[bounded]
    checked = 0
    for i in range(len(o)):
        pmf = ls.selection_pdf(em, np.tile(o[i], (ls.count, 1)), np.tile(d[i], (ls.count, 1)),
                               segment=np.full(ls.count, t[i]))
        assert abs(pmf.sum() - 1.0) < 1e-12, pmf.sum()
        lit = np.zeros(len(bounded), bool)
        for s in np.linspace(0.0, min(t[i], 40.0), 200):
            p = np.tile(o[i] + d[i] * s, (len(bounded), 1))
            zero = np.zeros(len(bounded))
            c, w = tree.center[k], tree.w[k]
            imp = _importance(p[:, 0], p[:, 1], p[:, 2], zero, zero, zero, zero, c[:, 0], c[:, 1], c[:, 2],
                              tree.radius[k], w[:, 0], w[:, 1], w[:, 2], tree.two_sided_f[k], tree.sin_o[k],
                              tree.cos_o[k], tree.cos_e[k], tree.phi[k])
            lit |= imp > 0
        assert np.all(pmf[bounded[lit]] > 0), "a light that lights the segment lost its probability"
        checked += lit.sum()
    assert checked > 1000, checked


def test_segment_selection_follows_its_pmf():
    """select_segment's probability is pmf_segment's of its pick, and its
    picks follow pmf_segment (chi-square, power printed)."""
    ls = make_light_set(many_lights(120) + spot_and_point() + [S.SunLight((0.2, 0.1, -1.0), (1, 1, 1), 0.05)],
                        strategy="tree")[0]
    rng = np.random.default_rng(3)
    o, d, t = segments(rng, 5)
    level = ember_stats.family_level(__name__ + ".chi2", len(o))
    em = np.arange(ls.count)
    for i in range(len(o)):
        u = rng.random(N)
        oo, dd, tt = np.tile(o[i], (N, 1)), np.tile(d[i], (N, 1)), np.full(N, t[i])
        e, prob = ls.select_segment(u, oo, dd, tt)
        np.testing.assert_allclose(prob, ls.selection_pdf(e, oo, dd, segment=tt), rtol=1e-12, atol=0)
        pmf = ls.selection_pdf(em, oo[:ls.count], dd[:ls.count], segment=tt[:ls.count])
        res = C.chi2_test(np.bincount(e, minlength=ls.count), N * pmf)
        print(f"\nchi2 segment {i} (t {t[i]:.2f}): {res.power_line(level)}")
        assert res.p > level, f"chi-square rejects the segment selection: {res}"


def test_other_selections_ignore_the_segment():
    """Power and uniform selection: the segment's pmf is the plain one."""
    for strategy in ("power", "uniform"):
        ls = make_light_set(spot_and_point(), strategy=strategy)[0]
        e = np.array([0, 1])
        o, d = np.zeros((2, 3)), np.tile((1.0, 0.0, 0.0), (2, 1))
        np.testing.assert_array_equal(ls.selection_pdf(e, o, d, segment=np.array([6.0, 6.0])), ls.dist.pmf[e])
        picked, prob = ls.select_segment(np.array([0.1, 0.9]), o, d, np.array([6.0, 6.0]))
        np.testing.assert_array_equal(prob, ls.dist.pmf[picked])
