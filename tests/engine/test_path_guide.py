"""Path guiding at surface vertices (engine/integrator/path_guide.py).

* The directional quadtree: Mueller's subdivision rule, its pdf integrates
  to 1 over the sphere, and its sampling matches its pdf (chi-square, power
  printed) on cells that do not line up with its own; the compiled loops
  agree with their NumPy forms.
* Records sum alike in any grouping (fixed point), bad ones dropped; the
  spatial tree refines by its counts within its bounds.
* Renders: guided and unguided agree block by block and over the whole
  image (one family, power printed) in a room lit through a hole and in the
  Cornell box (an area light seen by BSDF rays: NEE/BSDF MIS with the guide
  mixture); a guide really guided there.
* The same seed gives the same guide and image whatever the threads and
  batch size; disjoint sample ranges, each learning its own guide, merge
  into an unbiased image; hostile input stays finite.
"""
import contextlib

import numpy as np
import pytest

from chi2 import chi2_test
from ember_stats import family_z, guided_pair_z as pair_z
from engine import kernels
from engine.film import Film
from engine.integrator import path_guide as pg
from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, SceneError, SunLight, World
from engine.testscenes import cornell_box, look_at, quad


def peaked_energy(rng, leaves):
    """Cell energies with a few bright spots over a dim, uneven background."""
    e = rng.random((leaves, pg.BINS)) * 0.05
    for leaf in range(leaves):
        e[leaf, rng.integers(0, pg.BINS, 3)] += rng.uniform(5.0, 50.0, 3)
    return e


def one_leaf_guide(density):
    return pg.Guide(pg.SpatialTree.root(), density[None], np.array([True]), np.zeros(3), np.ones(3))


def test_quadtree_follows_muellers_rule():
    """All energy in one cell: that cell holds the whole pdf (each level's
    node holding it is split); uniform energy: shares of 1/256 < RHO stop
    the split at level 4, the density stays 1; a quadtree leaf spreads its
    energy evenly over its area."""
    one = np.zeros((1, pg.BINS))
    one[0, 77] = 3.0
    d = pg.densities(one)[0]
    assert d[77] == pytest.approx(pg.BINS) and np.count_nonzero(d) == 1
    np.testing.assert_allclose(pg.densities(np.ones((1, pg.BINS)))[0], 1.0, rtol=1e-12)
    # A spot plus a background: background nodes stop where their share
    # falls below RHO, so their cells share one value per quadtree leaf.
    e = np.full((1, pg.BINS), 1e-4)
    e[0, 0] = 10.0
    d = pg.densities(e)[0].reshape(pg.RES, pg.RES)
    assert d[0, 0] == pytest.approx(10.0 / (10.0 + 1023e-4) * pg.BINS)   # its cell alone
    assert np.ptp(d[16:, 16:]) == 0.0 and np.ptp(d[16:, :16]) == 0.0   # level-1 quadrants without the spot
    assert np.all(pg.densities(np.zeros((2, pg.BINS))) == 0.0)


def test_quadtree_pdf_integrates_to_one_and_sampling_matches_it():
    """Exactly sum(density) / BINS = 1 on the square; Monte Carlo over
    uniform directions on the sphere gives 1 within its error; 400k samples
    histogrammed on a 24 x 20 grid of (cos theta, phi) (not the quadtree's)
    against the pdf's integral there (exact: a 960 x 960 midpoint rule of a
    density constant on 32 x 32 cells), chi-square with power printed."""
    rng = np.random.default_rng(11)
    density = pg.densities(peaked_energy(rng, 1))[0]
    assert density.sum() / pg.BINS == pytest.approx(1.0, rel=1e-12)
    guide = one_leaf_guide(density)
    n = 200_000
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    r = np.sqrt(1.0 - z * z)
    w = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    values = guide.pdf(np.zeros(n, np.int32), w) * 4.0 * np.pi
    se = values.std() / np.sqrt(n)
    print(f"sphere integral of the pdf {values.mean():.4f} +- {se:.4f}")
    assert abs(values.mean() - 1.0) < 5.0 * se
    m = 400_000
    wi, pdf = guide.sample(np.zeros(m, np.int32), rng.random(m), rng.random(m))
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(pdf, guide.pdf(np.zeros(m, np.int32), wi), rtol=1e-12)
    nx, ny, fine = 24, 20, 960
    x = (wi[:, 2] + 1.0) / 2.0
    y = np.mod(np.arctan2(wi[:, 1], wi[:, 0]), 2.0 * np.pi) / (2.0 * np.pi)
    observed, _, _ = np.histogram2d(x, y, bins=[nx, ny], range=[[0, 1], [0, 1]])
    grid = density.reshape(pg.RES, pg.RES)
    per = fine // pg.RES
    fine_density = np.repeat(np.repeat(grid, per, axis=0), per, axis=1) / fine ** 2
    expected = fine_density.reshape(nx, fine // nx, ny, fine // ny).sum(axis=(1, 3)) * m
    res = chi2_test(observed, expected)
    level = 0.01
    print(res.power_line(level))
    assert res.p > level


def test_compiled_loops_agree_with_their_numpy_forms():
    """Leaf look-up exactly; sampled directions and pdfs within rounding."""
    kernels.configure(True)
    assert kernels.wait(900)
    rng = np.random.default_rng(3)
    tree = pg.SpatialTree.root().refine(np.array([10_000]), 700.0)
    assert tree.leaves == 16
    p = rng.random((20_000, 3))
    p[:5] = np.array([0.0, 0.5, 1.0 - 1e-12, 0.25, 0.75])[:, None]   # on the split planes and the ends
    a, b = np.empty(len(p), np.int32), np.empty(len(p), np.int32)
    pg._leaf_kernel.compiled(p, tree.child, a)
    pg._leaf_kernel.numpy_fn(p, tree.child, b)
    np.testing.assert_array_equal(a, b)
    assert set(a) == set(range(16))
    density = pg.densities(peaked_energy(rng, 16))
    guide = pg.Guide(tree, density, np.ones(16, bool), np.zeros(3), np.ones(3))
    leaf = a.copy()
    leaf[::7] = -1
    u1, u2 = rng.random(len(p)), rng.random(len(p))
    u1[:3] = [0.0, np.nextafter(1.0, 0.0), 0.5]
    out = [(np.empty((len(p), 3)), np.empty(len(p))) for _ in range(2)]
    pg._sample_kernel.compiled(leaf, u1, u2, guide.cdf, guide.density, *out[0])
    pg._sample_kernel.numpy_fn(leaf, u1, u2, guide.cdf, guide.density, *out[1])
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-12)
    q = [np.empty(len(p)) for _ in range(2)]
    pg._pdf_kernel.compiled(leaf, out[0][0], guide.density, q[0])
    pg._pdf_kernel.numpy_fn(leaf, out[0][0], guide.density, q[1])
    np.testing.assert_allclose(q[0], q[1], rtol=1e-12)
    assert np.all(q[0][leaf < 0] == 0.0) and np.all(q[0][leaf >= 0] > 0.0)


def _mixed_lobes(n, mu):
    """A diffuse + glossy material at n points seen at cos mu: (material,
    lobes, wo, weights, selection)."""
    from engine import bsdf
    material = Material("mix", (Lobe("diffuse", (0.8, 0.6, 0.4), weight=0.6),
                                Lobe("glossy", (0.9, 0.9, 0.9), roughness=0.5, weight=0.4)))
    lobes = bsdf.MaterialTable([material]).gather(np.zeros(n, int))
    wo = np.tile([np.sqrt(1 - mu * mu), 0.0, mu], (n, 1))
    w = bsdf.weights(lobes, wo)
    return material, lobes, wo, w, bsdf.selection(lobes, wo, w)


def test_mixture_keeps_the_bsdf_integral_and_nee_weighs_by_the_same_pdf():
    """At a diffuse + glossy vertex under a peaked guide: E[f cos / p_mix]
    over the one-sample mixture is the BSDF's directional albedo (z-test,
    power printed), and the pdf light samples weigh with in a direction
    (nee_pdf over the BSDF's eval) is the p_mix a BSDF ray carries there."""
    from types import SimpleNamespace
    from engine import bsdf
    rng = np.random.default_rng(17)
    n, mu = 400_000, 0.6
    material, lobes, wo, w, sel = _mixed_lobes(n, mu)
    view = one_leaf_guide(pg.densities(peaked_energy(rng, 1))[0])
    alpha = pg.guide_probability(lobes.kind, lobes.alpha, sel, bsdf.kind_in)
    assert 0.0 < alpha.min() and alpha.max() < pg.ALPHA   # the glossy lobe lowers it
    eye = np.tile(np.eye(3), (n, 1, 1))
    v = SimpleNamespace(guide=pg.GuideAt(view, np.zeros(n, np.int32), alpha, np.ones(n, bool)), lobes=lobes,
                        wo_l=wo, selection=sel, weights=w, tt=eye[:, 0], bb=eye[:, 1], hit=SimpleNamespace(ns=eye[:, 2]))
    chosen, wi, pdf_b, up = _mixture_against_albedo(v, material, mu, rng, n, ".mixture", "")
    assert abs(chosen.mean() - alpha.mean()) < 0.01
    assert np.all(pg.nee_pdf(v, wi, pdf_b)[up] != pdf_b[up])   # the guide's share is in it


def _mixture_against_albedo(v, material, mu, rng, n, family, label):
    """Sample the mixture at vertices ``v`` and hold E[f cos / p_mix] to the
    BSDF's albedo (a z-test, power printed) and NEE's pdf to the p_mix a BSDF
    ray carries; returns (chosen, wi, the BSDF's own pdf, rows above)."""
    from analytic import directional_albedo
    from engine import bsdf
    lobes, wo, sel, w = v.lobes, v.wo_l, v.selection, v.weights
    u = rng.random((n, 3))
    chosen, u_lobe = pg.split_choice(v.guide, u[:, 0])
    wi, weight, pdf, delta = bsdf.sample(lobes, wo, u_lobe, u[:, 1], u[:, 2], sel, w)
    pg.mix(v, chosen, u[:, 1], u[:, 2], wi, weight, pdf, delta, bsdf.eval_pdf)
    want = directional_albedo(material, mu)
    mean = weight.mean(axis=0)
    se = weight.std(axis=0) / np.sqrt(n)
    zc = family_z(__name__ + family, 3)
    print(f"{label}E[f cos / p_mix] {mean} vs albedo {want}: |z| {np.abs((mean - want) / se).max():.2f} "
          f"(limit {zc:.2f}), detects {(zc * se / want).max():.2%}")
    assert np.all(np.abs(mean - want) < zc * se)
    up = wi[:, 2] > 1e-3
    _, pdf_b = bsdf.eval_pdf(lobes, wo, wi, sel, w)
    np.testing.assert_allclose(pg.nee_pdf(v, wi, pdf_b)[up], pdf[up], rtol=1e-9)
    return chosen, wi, pdf_b, up


def test_records_sum_alike_in_any_grouping_and_drop_bad_ones():
    """Fixed-point sums: the same integers however records are grouped
    into tiles and in whatever order the tiles merge; NaN, inf and
    negative records are dropped."""
    rng = np.random.default_rng(5)
    n = 30_000
    cell = rng.integers(0, 3 * pg.BINS, n)   # the three leaves below
    value = rng.lognormal(0.0, 3.0, n)
    value[::97] = np.nan
    value[::89] = np.inf
    value[::83] = -1.0
    results = []
    for groups in (1, 7):
        guide = pg.PathGuide(np.zeros(3), np.ones(3), 128)
        guide.tree = pg.SpatialTree([1, 3, -3, -1, -2], [0, 1, 1, 2, 2])
        guide._reset()
        parts = np.array_split(rng.permutation(n), groups)
        for part in parts[::-1]:
            rec = pg.Records(guide.tree, guide.lo, guide.inv_size)
            rec.add(cell[part], value[part])
            guide.merge(rec.summed())
        results.append((guide.sums.copy(), guide.counts.copy()))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])
    good = np.isfinite(value) & (value >= 0)
    assert results[0][1].sum() == good.sum()


def test_spatial_tree_refines_by_counts_within_its_bounds():
    """A leaf with k thresholds' worth of records becomes about k leaves;
    MAX_DEPTH and MAX_LEAVES bound the tree; points outside the bounds (or
    NaN) land in the border leaves; flat, point-like and empty bounds get a
    size."""
    tree = pg.SpatialTree.root().refine(np.array([1000]), 100.0)
    assert tree.leaves == 16 and tree.depth.max() == 4
    assert pg.SpatialTree.root().refine(np.array([1e30]), 1.0).leaves <= pg.MAX_LEAVES
    deep = pg.SpatialTree.root()
    for _ in range(3):
        deep = deep.refine(np.full(deep.leaves, 1e30), 1.0)
    assert deep.depth.max() <= pg.MAX_DEPTH and deep.leaves <= pg.MAX_LEAVES
    lo, inv = np.zeros(3), np.ones(3)
    unit = pg.unit_cube(np.array([[-5.0, 0.5, 0.5], [5.0, 0.5, 0.5], [np.nan, np.inf, -np.inf]]), lo, inv)
    assert np.all((unit >= 0) & (unit < 1))

    class Flat:
        p0 = np.array([[1.0, 2.0, 3.0]])
        e1 = np.zeros((1, 3))
        e2 = np.zeros((1, 3))
    lo, inv = pg.bounds_of(Flat)
    assert np.all(np.isfinite(inv)) and np.all(inv > 0)
    assert np.all(pg.unit_cube(Flat.p0, lo, inv) >= 0)
    lo, inv = pg.bounds_of(None)
    assert np.all(inv == 1.0)


def lit_room(size=(20, 20), k=0.6):
    """A closed white room (floor, walls, a ceiling with a square hole) lit
    by a sun through the hole onto the floor: the camera looks at a wall,
    lit by light that bounced (guiding's case)."""
    c, h = 1.0, 2.0
    meshes = [
        quad([[-c, -c, 0], [c, -c, 0], [c, c, 0], [-c, c, 0]]),
        quad([[-c, c, 0], [c, c, 0], [c, c, h], [-c, c, h]]),
        quad([[-c, -c, 0], [-c, c, 0], [-c, c, h], [-c, -c, h]]),
        quad([[c, -c, 0], [c, -c, h], [c, c, h], [c, c, 0]]),
        quad([[-c, -c, 0], [-c, -c, h], [c, -c, h], [c, -c, 0]]),
        quad([[-c, -c, h], [-c, c, h], [-k, c, h], [-k, -c, h]]),
        quad([[k, -c, h], [k, c, h], [c, c, h], [c, -c, h]]),
        quad([[-k, -c, h], [-k, -k, h], [k, -k, h], [k, -c, h]]),
        quad([[-k, k, h], [-k, c, h], [k, c, h], [k, k, h]]),
    ]
    white = Material("white", (Lobe("diffuse", (0.75, 0.75, 0.75)),))
    glossy = Material("floor", (Lobe("diffuse", (0.5, 0.4, 0.3), weight=0.7), Lobe("glossy", (0.3, 0.3, 0.3),
                                                                                  roughness=0.4, weight=0.3)))
    instances = [Instance(0, materials=[1], name="floor")] + [Instance(i, materials=[0], name=f"wall {i}")
                                                             for i in range(1, len(meshes))]
    sun = SunLight((0.15, 0.1, -1.0), (8.0, 8.0, 8.0))
    cam = Camera(look_at((0.0, -0.9, 1.0), (0.0, 1.0, 1.2)), lens=20.0, resolution=size, clip_start=0.01)
    return Scene(meshes, instances, [white, glossy], [sun], World((0.0, 0.0, 0.0)), cam)


@contextlib.contextmanager
def guiding_throughout(fixed=False):
    """No early stop (STOP_SHARE 0): these small renders' guides would
    stop after 8 samples, and the tests below check the mixture over all
    of a render's samples; ``fixed``: every leaf's fraction ALPHA (the
    Cornell box learns 0 everywhere, which would leave its light's MIS
    against the mixture untested)."""
    saved = pg.STOP_SHARE, pg.PathGuide.fractions
    pg.STOP_SHARE = 0.0
    if fixed:
        pg.PathGuide.fractions = lambda self: np.full(self.tree.leaves, pg.ALPHA)
    try:
        yield
    finally:
        pg.STOP_SHARE, pg.PathGuide.fractions = saved


def guided_pair(scene, seed, fixed=False, **settings):
    out = {}
    for guide in (False, True):
        with guiding_throughout(fixed):
            out[guide] = render(scene, RenderSettings(seed=seed + guide, path_guiding=guide, **settings))
        assert np.isfinite(out[guide].image).all()
        assert not guide or not out[guide].film.path_guide.stopped
    assert out[True].film.path_guide is not None and out[False].film.path_guide is None
    view = out[True].film.path_guide.view
    assert view is not None and view.guided.any()
    print(f"guided leaves' fractions {sorted(set(view.fraction[view.guided].round(2)))}")
    return out


@pytest.fixture(scope="module")
def room():
    # Two diffuse bounces of four: a guided sample's kind (drawn by the BSDF's own pdf) sets the limit.
    return guided_pair(lit_room(), 41, samples=256, max_bounces=4, diffuse_bounces=2,
                       path_guiding_training_samples=64)


def test_guided_and_unguided_agree(room):
    """The guide changes the variance only: the room (light that bounced,
    a diffuse + glossy floor, two diffuse bounces: the guided samples'
    kinds count) and the Cornell box (its area light met by BSDF rays,
    weighed by MIS against the guide-BSDF mixture) agree guided and
    unguided block by block and over the whole image (one family)."""
    box = guided_pair(cornell_box(16, 16), 51, fixed=True, samples=192, max_bounces=4)
    tests = {name: pair_z(r, block) for name, r, block in (("room", room, 4), ("cornell", box, 2))}
    zc = family_z(__name__ + ".agree", sum(len(t[0]) + 3 for t in tests.values()))
    for name, (z, zm, block_rel, image_rel) in tests.items():
        print(f"{name}: guided vs unguided, {len(z)} block-channels, max |z| {z.max():.2f} (limit {zc:.2f}), "
              f"median block detects {zc * block_rel:.1%}; image |z| {zm.max():.2f}, detects {zc * image_rel:.2%}")
        assert len(z) >= 50
        assert z.max() < zc and zm.max() < zc


def test_same_seed_same_guide_and_image_whatever_the_batching():
    """Threads and batch sizes regroup the same samples: the guide's
    integer sums, hence the guide, are the same bit for bit, the image the
    same up to the film's float merging."""
    scene = lit_room((12, 12))
    runs = [render(scene, RenderSettings(samples=16, max_bounces=3, seed=9, path_guiding=True, **kw))
            for kw in (dict(threads=1), dict(threads=2, max_paths=1024))]
    a, b = (r.film.path_guide for r in runs)
    np.testing.assert_array_equal(a.view.density, b.view.density)
    np.testing.assert_array_equal(a.view.tree.child, b.view.tree.child)
    np.testing.assert_array_equal(a.view.fraction, b.view.fraction)   # learned from integer sums
    np.testing.assert_array_equal(a.moments, b.moments)
    np.testing.assert_allclose(runs[0].image, runs[1].image, rtol=2e-6, atol=1e-7)


def test_sample_ranges_learning_their_own_guides_merge(room):
    """A farm's split: [0, 96) and [96, 256), each guided by what its own
    passes learnt, merge into the counts of one render and an image that
    agrees with the unguided one (block and image z-tests)."""
    scene = lit_room()
    settings = dict(max_bounces=4, diffuse_bounces=2, path_guiding=True, path_guiding_training_samples=64, seed=43)
    with guiding_throughout():
        first = render(scene, RenderSettings(samples=96, **settings))
        rest = render(scene, RenderSettings(samples=160, sample_start=96, **settings))
    merged = Film.from_state(first.film.state())
    merged.merge_state(rest.film.state())
    np.testing.assert_array_equal(merged.count, np.full(merged.count.shape, 256))

    class Merged:
        image, variance = merged.image(), merged.variance()
    z, zm, block_rel, image_rel = pair_z({True: Merged, False: room[False]}, 4)
    zc = family_z(__name__ + ".ranges", len(z) + 3)
    print(f"merged ranges vs unguided: max |z| {z.max():.2f} (limit {zc:.2f}), median block detects "
          f"{zc * block_rel:.1%}; image |z| {zm.max():.2f}, detects {zc * image_rel:.2%}")
    assert z.max() < zc and zm.max() < zc


def test_hostile_input_stays_finite():
    """No triangles at all, one degenerate triangle (zero-area bounds), one
    sample, and records that were NaN, inf or negative (dropped) or of no
    light (counted): finite pixels; a guide that learnt no light guides nothing."""
    guide = pg.PathGuide(np.zeros(3), np.ones(3), 8)
    rec = pg.Records(guide.tree, guide.lo, guide.inv_size)
    rec.add(np.arange(10), np.array([np.nan, np.inf, -np.inf, -1.0, 0.0] * 2))
    cells, sums, counts = rec.summed()
    assert list(cells) == [4, 9] and not sums.any() and list(counts) == [1, 1]   # the zeros count, no light
    guide.merge((cells, sums, counts))
    guide.update(4)
    assert guide.view is not None and not guide.view.guided.any()
    assert np.all(guide.view.leaf_of(np.zeros((3, 3))) == -1)
    room = lit_room((6, 6))
    empty = Scene([], [], [], room.lights, World((0.2, 0.2, 0.2)), room.camera)
    point = Scene([quad([[0, 1, 1]] * 4)], [Instance(0, materials=[0], name="dot")], room.materials[:1],
                  room.lights, World((0.2, 0.2, 0.2)), room.camera)
    with pytest.raises(SceneError, match="path_guiding_training_samples"):
        render(room, RenderSettings(samples=1, path_guiding=True, path_guiding_training_samples=-1))
    for scene in (empty, point, room):
        for samples in (1, 8):
            r = render(scene, RenderSettings(samples=samples, max_bounces=3, seed=2, path_guiding=True))
            assert np.isfinite(r.image).all()


def random_vertices(rng, n):
    """Lobe kinds (eligible, none, and a transmitting one), roughnesses and
    selections of n vertices of up to three lobes."""
    from engine.lobes import registry
    eligible = list(pg.eligible_kinds())
    bad = sorted(registry.transmitting())[0]
    kinds = np.array(eligible + [-1, bad], np.int8)
    kind = kinds[rng.choice(len(kinds), (n, 3), p=[0.8 / len(eligible)] * len(eligible) + [0.15, 0.05])]
    lobe_alpha = rng.choice([0.0, 1e-4, 0.04, 0.25, 1.0], (n, 3))
    selection = rng.random((n, 3)) * (kind != -1)
    selection[rng.random(n) < 0.05] = 0.0
    return kind, lobe_alpha, selection


def test_vertex_kernel_agrees_with_its_numpy_form_and_the_guide_probability():
    """The one-pass vertex look-up (eligibility, roughness, leaf, guide
    probability): compiled = NumPy within rounding (leaves exactly), its
    probability ALPHA x roughness = guide_probability at unlearned leaves,
    a learned fraction scales it, a fraction of 0 stays guided only while
    training, unlearned leaves (-1) never."""
    from engine import bsdf
    kernels.configure(True)
    assert kernels.wait(900)
    rng = np.random.default_rng(23)
    n = 20_000
    kind, lobe_alpha, selection = random_vertices(rng, n)
    split = (rng.random(n) < 0.03).astype(np.uint8)
    p = rng.normal(0.0, 0.6, (n, 3))
    p[:3] = [np.nan, np.inf, -np.inf]
    tree = pg.SpatialTree.root().refine(np.array([10_000]), 700.0)
    fraction = rng.choice(pg.FRACTIONS, tree.leaves)
    fraction[[0, 5]] = [-1.0, 0.0]
    fraction[1] = pg.ALPHA
    table = pg.kind_table(bsdf.NONE)
    lo, inv = np.full(3, -1.0), np.full(3, 0.5)
    for training in (0, 1):
        out = [(np.empty(n, np.int32), np.empty(n), np.empty(n)) for _ in range(2)]
        for fn, o in zip((pg._vertex_kernel.compiled, pg._vertex_kernel.numpy_fn), out):
            fn(kind, lobe_alpha, selection, split, table, p, lo, inv, tree.child, fraction, training, *o)
        np.testing.assert_array_equal(out[0][0], out[1][0])
        np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-12, atol=0)
        np.testing.assert_allclose(out[0][2], out[1][2], rtol=1e-12, atol=0)
        leaf, alpha, rough = out[0]
        ok = rough >= 0
        want = bsdf.kind_in(kind, pg.eligible_kinds() + (bsdf.NONE,)).all(axis=1) & (selection > 0).any(axis=1)
        np.testing.assert_array_equal(ok, want & (split == 0))
        np.testing.assert_allclose(pg.ALPHA * rough[ok], pg.guide_probability(kind[ok], lobe_alpha[ok], selection[ok],
                                                                              bsdf.kind_in), rtol=1e-12)
        lf = tree.leaf_of(pg.unit_cube(p, lo, inv))
        on = leaf >= 0
        np.testing.assert_array_equal(leaf[on], lf[on])
        np.testing.assert_allclose(alpha[on], fraction[lf[on]] * rough[on], rtol=1e-12)
        assert not on[lf == 0].any()                          # a leaf that learned no light
        assert on[lf == 5].any() == bool(training)            # a fraction of 0: only while training
        assert on[(lf == 1) & ok & (pg.ALPHA * rough >= pg.MIN_ALPHA)].all()
        assert not on[ok & (pg.ALPHA * rough < pg.MIN_ALPHA)].any()   # narrow lobes: the BSDF alone


@pytest.mark.parametrize("fraction", [0.0, 0.05, 0.8])
def test_mixture_is_unbiased_whatever_the_learned_fraction(fraction):
    """E[f cos / p_mix] = the BSDF's albedo with the guide probability a
    leaf may learn (0, a small and the largest of FRACTIONS, times the
    vertex's roughness), and NEE weighs by the same p_mix."""
    from types import SimpleNamespace
    from engine import bsdf
    rng = np.random.default_rng(29)
    n, mu = 200_000, 0.5
    material, lobes, wo, w, sel = _mixed_lobes(n, mu)
    density = pg.densities(peaked_energy(rng, 1))[0]
    view = pg.Guide(pg.SpatialTree.root(), density[None], np.array([True]), np.zeros(3), np.ones(3),
                    np.array([fraction]))
    eye = np.tile(np.eye(3), (n, 1, 1))
    hit = SimpleNamespace(ns=eye[:, 2], p=np.full((n, 3), 0.5))
    class Vertices(SimpleNamespace):
        def __len__(self):
            return len(self.wo_l)
    v = Vertices(lobes=lobes, wo_l=wo, selection=sel, weights=w, tt=eye[:, 0], bb=eye[:, 1], hit=hit)
    v.guide = pg.at_vertices(view, True, v, bsdf.kind_in, bsdf.NONE)
    assert np.all(v.guide.leaf == 0)
    np.testing.assert_allclose(v.guide.alpha, fraction * v.guide.rough, rtol=1e-12)
    _mixture_against_albedo(v, material, mu, rng, n, f".fraction{fraction}", f"fraction {fraction}: ")
    assert np.all(np.isfinite(v.guide.x))   # what the records learn from


def moment_samples(rng, n, old, target):
    """One-dimensional stand-in of a guided bounce on [0, 1): BSDF pdf 1,
    guide pdf 2u, F = target(u); samples of the mixture of fraction ``old``:
    (y = F / q_old, x = (p_g - p_b) / q_old)."""
    u = np.where(rng.random(n) < old, np.sqrt(rng.random(n)), rng.random(n))
    pg_, pb = 2.0 * u, np.ones(n)
    q = old * pg_ + (1.0 - old) * pb
    return target(u) / q, (pg_ - pb) / q


def test_second_moments_estimate_each_fraction_and_pick_the_least():
    """From samples of one fraction, second_moments estimates the integral
    of F^2 / q_k for every fraction of FRACTIONS (z-test against a 100k-point
    midpoint rule, power printed); PathGuide.fractions picks the fraction of
    least moment: 0 where F follows the BSDF (the guide only adds variance,
    NEE's case), a large one where F follows the guide."""
    rng = np.random.default_rng(31)
    n = 400_000
    grid = (np.arange(100_000) + 0.5) / 100_000
    cases = {"follows the guide": lambda u: 3.0 * u * u, "follows the BSDF": lambda u: np.ones_like(u)}
    zc = family_z(__name__ + ".moments", len(cases) * pg.K)
    for name, target in cases.items():
        y, x = moment_samples(rng, n, 0.3, target)
        m = pg.second_moments(y, x, np.full(n, 0.3)) / pg.FIXED
        exact = np.array([(target(grid) ** 2 / (a * 2.0 * grid + 1.0 - a)).mean() for a in pg.FRACTIONS])
        mean, se = m.mean(axis=0), m.std(axis=0) / np.sqrt(n)
        z = np.abs(mean - exact) / se
        print(f"F {name}: max |z| {z.max():.2f} (limit {zc:.2f}), detects {(zc * se / exact).max():.2%}; "
              f"least at fraction {pg.FRACTIONS[np.argmin(exact)]}")
        assert z.max() < zc
        guide = pg.PathGuide(np.zeros(3), np.ones(3), 16)
        rec = pg.Records(guide.tree, guide.lo, guide.inv_size)
        rec.add(np.zeros(n, np.int64), y, y, x, np.full(n, 0.3))
        guide.merge(rec.summed())
        picked = guide.fractions()[0]
        if name == "follows the BSDF":
            assert picked == 0.0
        else:
            assert picked >= 0.5   # within the estimate's error of the exact least moment, a guided one
            assert exact[list(pg.FRACTIONS).index(picked)] <= 1.02 * exact.min()


def test_second_moment_sums_are_the_same_in_any_grouping():
    """The moments' fixed-point sums, and the fractions chosen from them,
    are the same integers however records are grouped into tiles and in
    whatever order the tiles merge; bad ones (NaN, inf, negative, no
    moment) are dropped."""
    rng = np.random.default_rng(37)
    n = 30_000
    cell = rng.integers(0, 3 * pg.BINS, n)
    y, x = moment_samples(rng, n, 0.2, lambda u: 3.0 * u * u)
    f = rng.uniform(0.1, 2.0, n)
    value = y / f
    f[::53] = -1.0
    value[::97] = np.nan
    x[::89] = np.inf
    results = []
    for groups in (1, 7):
        guide = pg.PathGuide(np.zeros(3), np.ones(3), 128)
        guide.tree = pg.SpatialTree([1, 3, -3, -1, -2], [0, 1, 1, 2, 2])
        guide._reset()
        for part in np.array_split(rng.permutation(n), groups)[::-1]:
            rec = pg.Records(guide.tree, guide.lo, guide.inv_size)
            rec.add(cell[part], value[part], np.where(f[part] >= 0, y[part], -1.0), x[part], np.full(len(part), 0.2))
            guide.merge(rec.summed())
        results.append((guide.moments.copy(), guide.moment_counts.copy(), guide.fractions()))
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)
    good = np.isfinite(value) & (f >= 0) & np.isfinite(x)
    assert results[0][1].sum() == good.sum()


def test_mixture_loops_agree_with_their_numpy_forms():
    """The mixture's compiled passes (guide choice, directions and pdfs,
    weights, NEE's pdf) against their NumPy forms, within rounding; rows of
    no leaf untouched."""
    kernels.configure(True)
    assert kernels.wait(900)
    rng = np.random.default_rng(41)
    n, leaves = 20_000, 4
    density = pg.densities(peaked_energy(rng, leaves))
    guide = pg.Guide(pg.SpatialTree.root().refine(np.array([1000]), 300.0), density, np.ones(leaves, bool),
                     np.zeros(3), np.ones(3))
    leaf = rng.integers(-1, leaves, n).astype(np.int32)
    alpha = rng.uniform(0.0, 0.8, n)
    u0, u1, u2 = rng.random(n), rng.random(n), rng.random(n)
    q, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    tt, bb, ns = (np.ascontiguousarray(q[:, :, k]) for k in range(3))
    wl0 = rng.normal(size=(n, 3))
    wl0 /= np.linalg.norm(wl0, axis=1)[:, None]
    runs = []
    for fn in ("compiled", "numpy_fn"):
        split, dirs = getattr(pg._split_kernel, fn), getattr(pg._directions_kernel, fn)
        weights, nee = getattr(pg._weights_kernel, fn), getattr(pg._nee_kernel, fn)
        chosen, u = np.empty(n, np.uint8), np.empty(n)
        split(leaf, alpha, u0, chosen, u)
        wl, p_guide = wl0.copy(), np.empty(n)
        dirs(leaf, chosen, u1, u2, tt, bb, ns, guide.cdf, guide.density, wl, p_guide)
        bsdf_pdf, f = rng.random(n) if not runs else runs[0][-1], np.full((n, 3), 0.3)
        weight, pdf, x = np.full((n, 3), 0.7), bsdf_pdf.copy(), np.empty(n)
        weights(leaf, chosen, alpha, np.full(n, 0.9), wl[:, 2].copy(), p_guide, bsdf_pdf, f, wl, 1e-7, 1,
                weight, pdf, x)
        out = np.empty(n)
        nee(leaf, alpha, np.ascontiguousarray(wl0), guide.density, bsdf_pdf, out)
        runs.append((chosen, u, wl, p_guide, weight, pdf, x, out, bsdf_pdf))
    a, b = runs
    np.testing.assert_array_equal(a[0], b[0])
    assert a[0][leaf < 0].sum() == 0 and 0.2 < a[0][leaf >= 0].mean() < 0.6
    for got, want in zip(a[1:8], b[1:8]):
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    off = leaf < 0
    np.testing.assert_array_equal(a[2][off], wl0[off])
    assert np.all(a[4][off] == 0.7) and np.all(a[7][off] == a[8][off])


def test_record_loops_agree_with_their_numpy_forms():
    """The records' compiled passes (a vertex taking its path's next slot,
    ending paths giving every slot's record) against their NumPy forms:
    the same records in the same order and the same slots, within rounding."""
    kernels.configure(True)
    assert kernels.wait(900)
    rng = np.random.default_rng(43)
    n = 5000
    tree = pg.SpatialTree.root().refine(np.array([1000]), 300.0)
    table = np.full((n, pg.COLUMNS), -1.0)
    table[:, 0] = rng.integers(0, 7, n)
    used = rng.random((n, pg.SLOTS)) < 0.6
    for s in range(pg.SLOTS):
        c = 1 + pg.SLOT * s
        k = np.flatnonzero(used[:, s])
        table[k, c] = rng.integers(0, tree.leaves * pg.BINS, len(k))
        table[k, c + 1] = rng.random(len(k))
        table[k, c + 2] = rng.uniform(0.1, 2.0, len(k))
        table[k, c + 3] = np.where(rng.random(len(k)) < 0.3, -1.0, rng.uniform(0.5, 2.0, len(k)))
        table[k, c + 4] = rng.normal(0.0, 1.0, len(k))
        table[k, c + 5] = rng.choice(pg.FRACTIONS, len(k))
    rows = np.sort(rng.choice(n, 3000, replace=False)).astype(np.int64)
    L, beta = rng.random((n, 3)) * 3.0, rng.random((n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    ns = rng.normal(size=(n, 3))
    ns /= np.linalg.norm(ns, axis=1)[:, None]
    p = rng.random((n, 3))
    leaf = rng.integers(-1, 4, n).astype(np.int32)
    x, prev_pdf = rng.normal(0.0, 1.0, n), rng.uniform(0.1, 1.0, n)
    norm, fraction = rng.uniform(0.5, 2.0, 4), rng.choice(pg.FRACTIONS, 4)
    runs = []
    for fn in ("compiled", "numpy_fn"):
        t, out = table.copy(), np.empty((len(rows), 5))
        m = getattr(pg._slots_kernel, fn)(rows, t, L, d, ns, beta, prev_pdf, p, tree.child, np.zeros(3), np.ones(3),
                                          leaf, x, norm, fraction, out)
        done = np.empty((n * pg.SLOTS, 5))
        k = getattr(pg._finish_kernel, fn)(t, L.mean(axis=1), done)
        runs.append((m, out[:m], t, k, done[:k]))
    a, b = runs
    assert a[0] == b[0] == used[rows, table[rows, 0].astype(int) % pg.SLOTS].sum() and a[3] == b[3]
    for got, want in ((a[1], b[1]), (a[2], b[2]), (a[4], b[4])):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert np.all(a[2][rows, 0] == table[rows, 0] + 1)


def test_training_stops_early_where_most_records_learn_no_guiding():
    """Two leaves, one whose records do best with the BSDF alone (F = 1),
    one with the guide (F = 3u^2): training goes on while the guided
    leaf holds most records and stops (no more records, the guide kept as
    learned, for inspection, but no longer sampled) once STOP_AFTER
    samples trained and it holds fewer than STOP_SHARE; not before
    STOP_AFTER samples."""
    rng = np.random.default_rng(47)

    def guide_after(shares, samples):
        guide = pg.PathGuide(np.zeros(3), np.ones(3), 64)
        for spp in samples:
            guide.tree = pg.SpatialTree([1, -1, -2], [0, 1, 1])   # two leaves (no refinement)
            guide._reset()
            rec = pg.Records(guide.tree, guide.lo, guide.inv_size)
            for leaf, (target, n) in enumerate(zip((lambda u: np.ones_like(u), lambda u: 3.0 * u * u), shares)):
                y, x = moment_samples(rng, n, 0.3, target)
                rec.add(leaf * pg.BINS + rng.integers(0, pg.BINS, n), y, y, x, np.full(n, 0.3))
            guide.merge(rec.summed())
            guide.update(spp)
        return guide

    going = guide_after((20_000, 30_000), (1, 1, 2, 4))
    assert not going.stopped and going.records_for(8) is not None
    stopped = guide_after((40_000, 10_000), (1, 1, 2, 4))
    assert stopped.stopped and stopped.training == 8 and stopped.records_for(8) is None
    assert stopped.view is not None and list(stopped.view.fraction) == [0.0, pg.FRACTIONS[-1]]
    assert stopped.sampled is None and going.sampled is going.view   # stopped: the BSDF alone samples
    early = guide_after((40_000, 10_000), (1, 1))
    assert not early.stopped and early.trained == 2 < pg.STOP_AFTER
