"""The compiled media loops (engine/media/table.py ``_stack_media_rows``,
flight.py ``_flight_rows``, equiangular.py ``_lit_rows``) against
their NumPy reference forms: within rounding on random and hostile inputs
(empty stacks, zero and 1e30 coefficients, endless segments), and the
compiled free flight's estimates against the reference's with independent
random numbers by a two-sample z-test (one family)."""
import numpy as np
import pytest

from ember_stats import detectable, family_level, z_threshold
from engine import kernels, media
from engine.media import equiangular
from engine.scene import Volume
from test_kernels import Reference, assert_agree, both_ways, compiled_ready

HOSTILE = (0.0, 1e-300, 1e30, 1e8)


@pytest.fixture
def jit():
    compiled_ready()
    yield
    kernels.configure(True)


def _rays(rng, n, spread):
    o = rng.normal(0.0, spread, (n, 3))
    d = rng.normal(0.0, 1.0, (n, 3))
    return o, d / np.linalg.norm(d, axis=1)[:, None]


def _agree_where(ref, got, same):
    """Compiled against reference within rounding on the rows ``same``
    (infinities read as 0)."""
    plain = Reference(tuple(np.where(np.isfinite(a), a, 0.0)[same] for a in ref))
    plain.spread = [np.asarray(sp)[same] for sp in ref.spread]
    assert_agree(plain, tuple(np.where(np.isfinite(a), a, 0.0)[same] for a in got))


def _table(rng, m=5):
    vols = []
    for i in range(m):
        a, s = rng.random(3) * 3.0, rng.random(3) * 2.0
        if i == 1:
            a, s = np.zeros(3), np.zeros(3)            # an empty medium
        if i == 2:
            a, s = np.array([1e30, 0.0, 1e-300]), np.array([0.0, 1e8, 0.0])
        vols.append(Volume(absorption=tuple(a), scattering=tuple(s), emission=tuple(rng.random(3)),
                           anisotropy=float(rng.uniform(-0.9, 0.9))))
    table = media.MediumTable(vols, [f"m{i}" for i in range(m)])
    table.phase[3:5, 0] += 1     # two media with a non-HG phase function
    return table


def _stacks(rng, n, m):
    stack = rng.integers(-1, m, (n, media.STACK_SIZE)).astype(np.int32)
    stack[: n // 10] = -1                          # paths in no medium
    return stack


def test_stack_media_agrees(jit):
    rng = np.random.default_rng(5)
    table = _table(rng)
    stack = _stacks(rng, 4000, 5)
    n = len(stack)
    het = np.zeros(len(table.has), bool)
    het[4] = True                                  # pretend medium 4 is textured: it wins the phase choice
    plain = table.phase[:, 0] == 0
    outs = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, np.int64))
    args = (stack, table.sigma_a, table.sigma_s, table.emission, table.g, het, plain)
    kernels.configure(False)
    ref = tuple(a.copy() for a in outs)
    from engine.media.table import _stack_media_rows
    _stack_media_rows(*args, *ref)
    kernels.configure(True)
    _stack_media_rows(*args, *outs)
    assert_agree(ref[:4], outs[:4])
    np.testing.assert_array_equal(ref[4], outs[4])
    assert (outs[4][(stack == 4).any(axis=1)] == 4).all()


def _flight_inputs(rng, n):
    sa = rng.random((n, 3)) * 2.0
    ss = rng.random((n, 3)) * 2.0
    pick = rng.random((n, 3)) < 0.1
    sa[pick] = rng.choice(HOSTILE, pick.sum())
    pick = rng.random((n, 3)) < 0.1
    ss[pick] = rng.choice(HOSTILE, pick.sum())
    em = rng.random((n, 3))
    beta = rng.random((n, 3)) * np.where(rng.random((n, 1)) < 0.05, 0.0, 1.0)
    t_end = np.where(rng.random(n) < 0.1, np.inf, rng.random(n) * 4.0)
    may = rng.random(n) < 0.8
    return sa, ss, em, beta, t_end, may


def test_free_flight_agrees(jit):
    """Same random numbers: the same flights within rounding; finite
    everywhere, also for 1e30 coefficients and endless segments."""
    from engine.media.flight import _flight_rows
    rng = np.random.default_rng(11)
    n = 6000
    ins = _flight_inputs(rng, n) + (rng.random(n), rng.random(n))

    def run(*args):
        out = (np.empty(n, bool), np.empty(n), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
               np.empty((n, 3)), np.empty(n, bool))
        _flight_rows(*args, *out)
        return out
    ref, got = both_ways(run, *ins)
    # A channel or scattering choice may flip where u sits within rounding of
    # a threshold: compare the rows where both forms chose alike.
    same = (ref[0] == got[0]) & (ref[6] == got[6])
    assert same.mean() > 0.999
    sub = Reference(ref[1:6])
    sub.spread = ref.spread[1:6]
    _agree_where(sub, got[1:6], same)
    for a in got[2:6]:
        assert np.isfinite(a).all()


def test_compiled_free_flight_is_the_reference_estimator(jit):
    """Independent random numbers: the compiled and the reference free
    flights' mean pass and scattering weights agree per channel (one
    family, 6 two-sample z-tests; power printed)."""
    n = 200_000
    table = media.MediumTable([Volume(absorption=(0.2, 0.5, 1.5), scattering=(1.0, 0.4, 0.1))], ["m"])
    stack = np.full((n, media.STACK_SIZE), -1, np.int32)
    stack[:, 0] = 0
    beta = np.tile([0.2, 1.0, 3.0], (n, 1))
    t_end = np.full(n, 0.8)
    means = []
    for on, seed in ((False, 1), (True, 2)):
        kernels.configure(on)
        rng = np.random.default_rng(seed)
        f = media.free_flight(table, stack, beta, t_end, np.ones(n, bool), rng.random(n), rng.random(n))
        w = np.concatenate([np.where(f.scatter[:, None], 0.0, f.weight), np.where(f.scatter[:, None], f.weight, 0.0)],
                           axis=1)
        means.append((w.mean(axis=0), w.var(axis=0) / n))
    kernels.configure(True)
    level = family_level(f"{__name__}.compiled_flight", 6)
    se = np.sqrt(means[0][1] + means[1][1])
    z = (means[1][0] - means[0][0]) / se
    print(f"|z| {np.abs(z).max():.2f} (limit {z_threshold(level):.2f}), detects "
          f"{detectable(se / np.abs(means[0][0]), level).max():.2%} of a weight")
    assert np.abs(z).max() < z_threshold(level)


def test_cone_segment_agrees(jit):
    rng = np.random.default_rng(3)
    n = 5000
    o, d = _rays(rng, n, 2.0)
    apex = rng.normal(0.0, 1.0, (n, 3))
    axis = rng.normal(0.0, 1.0, (n, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    axis[:50] = -d[:50]                             # rays along the axis
    o[50:100] = apex[50:100]                       # starting at the apex
    cos_half = rng.uniform(0.0, 0.999, n)
    t_end = np.where(rng.random(n) < 0.2, np.inf, rng.random(n) * 6.0)
    ref, got = both_ways(equiangular.cone_segment, o, d, apex, axis, cos_half, t_end)
    # Whether a tangent ray grazes the cone is decided within rounding:
    # compare where both forms agree that the interval is empty or not.
    same = (ref[1] > ref[0]) == (got[1] > got[0])
    assert same.mean() > 0.998 and (ref[1] > ref[0]).mean() > 0.2
    _agree_where(ref, got, same)
    assert not np.isnan(got[0]).any() and not np.isnan(got[1]).any()


def test_direct_points_agree(jit):
    """Equiangular and truncated-distance direct-light points and both
    pdfs: compiled against the reference within rounding (endless and
    empty lit parts, zero and huge extinction, the light on the ray)."""
    from engine.media import direct
    rng = np.random.default_rng(17)
    n = 6000
    o, d = _rays(rng, n, 1.0)
    P = rng.normal(0.0, 2.0, (n, 3))
    P[:40] = o[:40] + d[:40] * 2.0                  # the light point on the ray's line
    t0 = rng.random(n) * 2.0
    t1 = t0 + np.where(rng.random(n) < 0.1, np.inf, rng.random(n) * 3.0)
    t1[40:80] = t0[40:80]                          # empty lit parts
    st = rng.random((n, 3)) * 3.0
    pick = rng.random((n, 3)) < 0.1
    st[pick] = rng.choice(HOSTILE, pick.sum())
    pc = rng.random((n, 3))
    pc /= pc.sum(axis=1)[:, None]
    equi, skip = rng.random(n) < 0.5, rng.random(n) < 0.05
    ref, got = both_ways(direct.sample_points, o, d, P, t0, t1, rng.random(n), rng.random(n), pc, st, equi, skip)
    # Rows whose channel choice sits within rounding of a threshold may differ.
    same = np.isclose(ref[0], got[0], rtol=1e-6, atol=1e-9) | (np.isinf(ref[0]) & np.isinf(got[0]))
    assert same.mean() > 0.999
    _agree_where(ref, got, same)
    assert all(np.isfinite(a).all() for a in got[1:])


def test_majorant_agrees(jit):
    """A textured medium's majorant along rays (engine/media/field.py
    ``_majorant_rows``): compiled against the reference within rounding,
    for rays inside and outside the grid's box, axis-parallel ones (a zero
    direction component) and rays starting on the box's faces."""
    from engine.media.field import GRID, _majorant_rows
    rng = np.random.default_rng(23)
    n = 6000
    lo, hi = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.7, 2.5])
    cell = (hi - lo) / GRID
    grid = np.ascontiguousarray(rng.random((GRID, GRID, GRID)) * np.where(rng.random((GRID, GRID, GRID)) < 0.2,
                                                                          0.0, 5.0))
    q = lo + (hi - lo) * rng.uniform(-0.3, 1.3, (n, 3))
    dq = rng.normal(0.0, 1.0, (n, 3))
    dq[:300, 0] = 0.0                               # axis-parallel in x
    dq[300:400, 1:] = 0.0                           # along x only
    q[400:500, 2] = lo[2]                           # on the bottom face
    q[500:600, 0] = hi[0]                           # on a far face (outside: half-open box)
    dq *= rng.uniform(0.3, 3.0, (n, 1))             # object space: not unit

    def run(q, dq):
        mu, dist = np.empty(n), np.empty(n)
        _majorant_rows(q, dq, lo, hi, cell, grid, mu, dist)
        return mu, dist
    ref, got = both_ways(run, q, dq)
    inside = np.all((q >= lo) & (q < hi), axis=1)
    assert 0.15 < inside.mean() < 0.5 and np.isfinite(ref[1][~inside]).mean() > 0.2
    # A cell index may flip where a segment's end sits within rounding of a
    # cell face: compare the rows where both forms took the same cells.
    same = ref[0] == got[0]
    assert same.mean() > 0.999
    _agree_where(ref, got, same)


@pytest.mark.parametrize("mode", [0, 1, 2])
def test_tracker_collisions_agree(jit, mode):
    """One batch of a tracker's tentative collisions (engine/media/tracking.py
    ``_resolve_rows``: free flight, ratio and delta tracking) resolved by
    the compiled loop and by the reference, same random numbers: the same
    weights, stops, scatterings and light weights within rounding, for
    rows whose collisions leave the cell early, a light on the ray, null
    weights below zero (sigma_t above the majorant) and Russian roulette."""
    from engine.media.tracking import _resolve_rows
    rng = np.random.default_rng(29 + mode)
    n, K = 3000, 8
    live = np.sort(rng.choice(n + 500, n, replace=False)).astype(np.int64)
    N = n + 500
    mu = rng.uniform(0.5, 4.0, n)
    tk = np.cumsum(rng.exponential(1.0, (n, K)) / mu[:, None], axis=1)
    step_end = tk[:, -1] * rng.uniform(0.2, 1.2, n)
    valid = tk < step_end[:, None]
    t_end = np.full(N, np.inf)
    t_end[live] = step_end * rng.uniform(0.9, 3.0, n)
    sa = rng.random((n, K, 3)) * mu[:, None, None] * 0.5
    ss = rng.random((n, K, 3)) * mu[:, None, None] * 0.6      # sigma_t may pass mu: negative null weight
    em = rng.random((n, K, 3))
    gw = rng.random((n, K)) * ss.mean(axis=2)
    u = rng.random((n, K, 4))
    beta = rng.random((N, 3))
    may = rng.random(N) < 0.8
    x_light = np.where(rng.random(N) < 0.5, rng.random(N) * 2.0, np.inf)

    def run(t, w):
        t, w = t.copy(), w.copy()
        light_w, emitted = np.zeros((N, 3)), np.zeros((N, 3))
        scatter, t_out, g, done = np.zeros(N, bool), np.full(N, np.inf), np.zeros(N), np.zeros(n, bool)
        _resolve_rows(live, t, w, tk, valid, step_end, t_end, mu, sa, ss, em, gw, u, mode, beta, may,
                      x_light, light_w, emitted, scatter, t_out, g, done)
        return t, w, light_w, emitted, t_out, g, scatter.astype(float), done.astype(float)
    t0 = np.zeros(N)
    w0 = rng.uniform(0.01, 1.0, (N, 3))
    ref, got = both_ways(run, t0, w0)
    # A scattering or roulette choice may flip where u sits within rounding of its threshold.
    same = np.ones(N, bool)
    same[live] = ref[7] == got[7]
    same &= (ref[6] == got[6]) & np.all(np.sign(ref[1]) == np.sign(got[1]), axis=1)
    assert same.mean() > 0.999
    assert ref[7].mean() > 0.2 and (mode != 0 or ref[6].mean() > 0.05)
    sub = Reference(ref[:6])
    sub.spread = ref.spread[:6]
    _agree_where(sub, got[:6], same)


def _cross_inputs(rng, n, m):
    """Stacks with full, empty and duplicate entries; crossings in and out
    of media present, absent and without a medium (``has`` False)."""
    stack = _stacks(rng, n, m)
    stack[n // 10: n // 5] = rng.integers(0, m, (n // 5 - n // 10, media.STACK_SIZE))   # full stacks
    rows = rng.permutation(n)[: n // 2].astype(np.int64)
    mat = rng.integers(0, m + 1, len(rows)).astype(np.int64)
    back = rng.random(len(rows)) < 0.5
    has = np.ones(m + 2, bool)
    has[[1, m + 1]] = False
    return stack, rows, mat, back, has


def test_cross_agrees(jit):
    """MediumTable.cross's compiled loop against its NumPy form: the same
    stacks exactly (integers), for entering, leaving, full stacks and
    materials without a medium."""
    from engine.media.table import _cross_numpy, _cross_rows
    rng = np.random.default_rng(21)
    stack, rows, mat, back, has = _cross_inputs(rng, 5000, 6)
    ref, got = stack.copy(), stack.copy()
    _cross_numpy(ref, rows, mat, back, has)
    _cross_rows(got, rows, mat, back, has)
    np.testing.assert_array_equal(ref, got)
    assert (ref[rows] != stack[rows]).any(axis=1).mean() > 0.25   # many crossings changed their stack
    entered = rows[~back & has[mat]]
    m_in = mat[~back & has[mat]]
    not_full = (stack[entered] < 0).any(axis=1)
    assert (got[entered[not_full]] == m_in[not_full, None]).any(axis=1).all()
    left = rows[back & has[mat]]
    assert not (got[left] == mat[back & has[mat]][:, None]).any(axis=1).any()


def test_cross_on_a_strided_stack_writes_back():
    """A stack that is not a C-contiguous int32 array (a column slice's
    copy target, an int64 stack) is still updated in place."""
    table = _table(np.random.default_rng(3))
    stack = np.full((4, media.STACK_SIZE), -1, np.int64)
    stack[1, 0] = 2
    table.cross(stack, np.array([0, 1]), np.array([3, 2]), np.array([False, True]))
    assert stack[0, 0] == 3 and (stack[1] == -1).all()


def test_lit_segments_are_each_spots_cone():
    """volume._lit_segment (the per-emitter cone table, built once per
    light set) against each row's spot cone computed from the light's own
    fields: spots' tangent cones (one nearly 180 degrees wide, one of
    radius 0), the whole segment for a point light and a sun."""
    from engine.integrator import volume
    from engine.render import prepare
    from engine.scene import PointLight, SpotLight, SunLight
    from engine.testscenes import box
    from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
    from engine.testscenes import look_at
    lights = [PointLight((0.3, 0.0, 0.5), (5.0, 5.0, 5.0), radius=0.1),
              SpotLight((0.0, 0.0, 1.2), (60.0, 60.0, 60.0), radius=0.1, direction=(0.0, 0.2, -1.0),
                        spot_size=1.1, spot_blend=0.2),
              SunLight((0.0, 0.3, -1.0), (1.0, 1.0, 1.0)),
              SpotLight((0.5, 0.5, 0.5), (9.0, 9.0, 9.0), radius=0.05, direction=(1.0, 0.0, 0.0),
                        spot_size=3.1, spot_blend=0.1),
              SpotLight((-0.4, 0.2, 0.9), (9.0, 9.0, 9.0), radius=0.0, direction=(0.3, 0.0, -1.0),
                        spot_size=0.6, spot_blend=0.1)]
    fog = Material("fog", (Lobe("transparent", (1.0, 1.0, 1.0)),), volume=Volume(scattering=(0.5, 0.5, 0.5)))
    scene = Scene([box((3.0, 3.0, 3.0))], [Instance(0, materials=[0])], [fog], lights, World((0.0, 0.0, 0.0)),
                  Camera(look_at((0, -6, 0.3), (0, 0, 0.1)), lens=40, resolution=(8, 8)))
    ctx = prepare(scene, RenderSettings(samples=1, seed=1))
    rng = np.random.default_rng(4)
    n = 3000
    o, d = _rays(rng, n, 1.0)
    e = rng.integers(0, ctx.lights.count, n)
    t_end = np.where(rng.random(n) < 0.2, np.inf, rng.uniform(0.1, 5.0, n))
    rows = rng.permutation(n)
    t0, t1 = volume._lit_segment(ctx, o, d, rows, e[rows], t_end[rows])
    t0[rows], t1[rows] = t0.copy(), t1.copy()   # back in the rays' order
    want0, want1 = np.zeros(n), t_end.copy()
    cones = 0
    for g in ctx.lights.groups:
        table = g.table
        for j in range(table.count):
            rows = np.flatnonzero(e == g.base + j)
            if not getattr(table, "spot", np.zeros(table.count, bool))[j] or table.cos_half[j] < 0 or not len(rows):
                continue
            cones += 1
            sin_half = np.sqrt(1.0 - table.cos_half[j] ** 2)
            apex = table.pos[j] - table.dir[j] * table.radius[j] / sin_half
            want0[rows], want1[rows] = equiangular.cone_segment(
                o[rows], d[rows], np.tile(apex, (len(rows), 1)), np.tile(table.dir[j], (len(rows), 1)),
                np.full(len(rows), table.cos_half[j]), t_end[rows])
    assert cones == 3
    np.testing.assert_array_equal(t0, want0)
    np.testing.assert_array_equal(t1, want1)
    assert (t1 < t_end).mean() > 0.1   # the cones cut many segments


def test_point_weights_agree(jit):
    """direct.point_weights' compiled loop against its NumPy form within
    rounding, with zero, infinite and NaN pdfs, endless and empty lit parts."""
    from engine.media.direct import _weights_rows
    rng = np.random.default_rng(31)
    n = 6000
    t = rng.uniform(0.0, 5.0, n)
    t[rng.random(n) < 0.03] = np.inf
    p_e, p_d = rng.random(n) * 3.0, rng.random(n) * 3.0
    for p in (p_e, p_d):
        pick = rng.random(n) < 0.1
        p[pick] = rng.choice((0.0, np.inf, np.nan, 1e-300, 1e300), pick.sum())
    equi, mis = rng.random(n) < 0.5, rng.random(n) < 0.6
    t0 = rng.uniform(0.0, 1.0, n)
    t1 = t0 + np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.0, 4.0, n))
    st, ss = rng.random((n, 3)) * 2.0, rng.random((n, 3))
    st[rng.random((n, 3)) < 0.05] = 0.0

    def run(*args):
        good, factor = np.empty(n, bool), np.empty((n, 3))
        _weights_rows(*args, good, factor)
        return good.astype(float), factor
    ref, got = both_ways(run, t, p_e, p_d, equi, mis, t0, t1, st, ss)
    np.testing.assert_array_equal(ref[0], got[0])
    assert 0.5 < got[0].mean() < 0.95
    assert np.isfinite(got[1]).all()
    _agree_where(ref, got, np.ones(n, bool))


def test_lit_rows_agree(jit):
    """equiangular._lit_rows (each row's cone read through its emitter, the
    ray through its row index) against its NumPy form within rounding:
    cones of 0-90 degrees, endless segments, rays from inside and along
    the axis, emitters without a cone."""
    from engine.media.equiangular import _lit_rows
    rng = np.random.default_rng(41)
    n, m = 4000, 6
    o, d = _rays(rng, n, 1.5)
    d[:50] = [0.0, 0.0, -1.0]                            # along the axis
    rows = rng.integers(0, n, 3000)
    e = rng.integers(0, m, len(rows))
    lit = np.array([True, True, False, True, True, False])
    apex = rng.normal(0.0, 1.0, (m, 3))
    axis = np.tile([0.0, 0.0, -1.0], (m, 1))
    cos_half = np.array([0.95, 0.6, 0.5, 0.0, 0.999, 0.3])
    t_end = np.where(rng.random(len(rows)) < 0.2, np.inf, rng.uniform(0.1, 6.0, len(rows)))

    def run(*args):
        t0, t1 = np.empty(len(rows)), np.empty(len(rows))
        _lit_rows(*args, t0, t1)
        return t0, t1
    ref, got = both_ways(run, o, d, rows, e, lit, apex, axis, cos_half, t_end)
    _agree_where(ref, got, np.ones(len(rows), bool))
    assert (got[1][~lit[e]] == t_end[~lit[e]]).all()
    assert ((got[1] > got[0]) & lit[e]).mean() > 0.1
