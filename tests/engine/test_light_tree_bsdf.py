"""Light selection 'tree_bsdf': the light tree with a glossy-lobe factor in
its node importance (engine/lighttree.py LOBE_COLUMNS).

The selection must stay a distribution whose probability of the picked
light is exactly what MIS computes for any (vertex, light) pair, so:
the pmf sums to 1 with every light above 0, ``select`` returns the pmf of
its pick, the picks follow the pmf (chi-square), mix 0 is the plain tree;
and a render agrees with the every-light estimator.  Two statistical
families: the chi-square and the render comparison.
"""
import numpy as np

import chi2 as C
import ember_stats
from engine import scene as S
from sampling_lib import assert_close, make_light_set

from test_light_sampling import glossy_plates_over_floor, many_lights

N = 200_000


def lobe_rows(rng, m):
    r = rng.normal(size=(m, 3))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    out = np.empty((m, 5))
    out[:, :3], out[:, 3], out[:, 4] = r, rng.uniform(0.02, 1.0, m), rng.uniform(0.0, 0.9, m)
    return out


def test_lobe_tree_pmf():
    ls = make_light_set(many_lights(120) + [S.SunLight((0.2, 0.1, -1.0), (0.5, 0.5, 0.5), 0.05)],
                        strategy="tree_bsdf")[0]
    assert ls.lobe_term and ls.strategy == "tree"
    rng = np.random.default_rng(7)
    m = 30
    P = rng.uniform(-5, 5, (m, 3)) * (1, 1, 0.3)
    nrm = rng.normal(size=(m, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    lobe = lobe_rows(rng, m)
    em = np.arange(ls.count)
    for i in range(m):
        tile = (np.tile(P[i], (ls.count, 1)), np.tile(nrm[i], (ls.count, 1)))
        pmf = ls.selection_pdf(em, *tile, lobe=np.tile(lobe[i], (ls.count, 1)))
        plain = ls.selection_pdf(em, *tile)
        assert abs(pmf.sum() - 1.0) < 1e-12, pmf.sum()
        # The floor: no light loses more than the lobe's mix can take away.
        assert np.all(pmf[plain > 0] > 0)
        zero = lobe[i].copy()
        zero[4] = 0.0
        assert_close(ls.selection_pdf(em, *tile, lobe=np.tile(zero, (ls.count, 1))), plain, "mix 0 = plain tree")
    # A sharp lobe toward one light moves probability to it.
    i = 3
    u = np.random.default_rng(11).random(N)
    p, nn = np.tile(P[i], (N, 1)), np.tile(nrm[i], (N, 1))
    sharp = np.tile(lobe[i], (N, 1))
    sharp[:, 3], sharp[:, 4] = 0.05, 0.9
    e, prob = ls.select(u, p, nn, sharp)
    assert_close(prob, ls.selection_pdf(e, p, nn, lobe=sharp), "select probability vs selection_pdf")
    pmf = ls.selection_pdf(em, p[:ls.count], nn[:ls.count], lobe=sharp[:ls.count])
    counts = np.bincount(e, minlength=ls.count)
    res = C.chi2_test(counts, N * pmf)
    level = ember_stats.family_level(__name__ + ".chi2", 1)
    print(f"\nchi2 tree_bsdf selection: {res.power_line(level)}")
    assert res.p > level, f"chi-square rejects the selection: {res}"


def test_lobe_tree_render_agrees_with_all():
    """Veach's plates over a floor: 'tree_bsdf' against 'all' (selection
    probability 1), block by block and in the image mean, the power printed;
    and less noise than the plain tree."""
    from engine.render import render
    from ember_stats import block_means_var, detectable, family_level, family_z, z_scores
    out = {sel: render(*glossy_plates_over_floor(sel, seed)) for sel, seed in
           (("tree_bsdf", 21), ("all", 22), ("tree", 23))}
    a, b = out["tree_bsdf"], out["all"]
    ma, va = block_means_var(a.image[..., :3].astype(float), a.variance.astype(float), 6)
    mb, vb = block_means_var(b.image[..., :3].astype(float), b.variance.astype(float), 6)
    z = z_scores(ma, va, mb, vb)
    limit = family_z(__name__ + ".render", z.size + 1)
    se = np.sqrt(va.sum() + vb.sum()) / ma.size
    zm = (ma.mean() - mb.mean()) / se
    level = family_level(__name__ + ".render", z.size + 1)
    print(f"\ntree_bsdf vs all: max |z| {np.abs(z).max():.2f} (limit {limit:.2f}); mean z {zm:.2f}, detects "
          f"{detectable(se / mb.mean(), level):.2%} of the mean; variance tree_bsdf {a.variance.mean():.4g} "
          f"tree {out['tree'].variance.mean():.4g} all {b.variance.mean():.4g}")
    assert np.abs(z).max() < limit
    assert abs(zm) < limit
    assert detectable(se / mb.mean(), level) < 0.01
    assert a.variance.mean() < 0.8 * out["tree"].variance.mean()
