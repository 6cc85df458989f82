"""Solid-angle sampling of rectangle lights and emissive triangles, and the
light tree.

As tests/engine/test_sampling_chi2.py (whose helpers this file reuses):
chi-square of the sampled directions against the pdf a BSDF ray sees for the
same direction (``intersect`` / ``triangle_pdf``), exact agreement of the two
pdfs, mean(1/pdf) = solid angle, plus the variance the new strategies save.
All statistical tests here form one family of the suite budget (ember_stats.family_level, Sidak).
"""
import math

import numpy as np
import pytest

import chi2 as C
import ember_stats
from engine import lights
from engine import scene as S
from sampling_lib import (area_matrix, assert_close, assert_unit, cone_theta_edges, direction_chi2,
                          make_light_set, ray_triangles, uniform_phi_edges)

N = 400_000


RECTS = {
    # name: (shape, size_x, size_y, centre, emit direction, scale, roll, shading point)
    "square_close": ("SQUARE", 2.0, 2.0, (0.0, 0.0, 0.3), (0, 0, -1), (1, 1), 0.0, (0.0, 0.0, 0.0)),
    "square_off_centre": ("SQUARE", 3.0, 3.0, (1.2, -0.4, 0.5), (0.2, 0.1, -1), (1, 1), 0.4,
                          (0.0, 0.0, 0.0)),
    "rectangle_scaled": ("RECTANGLE", 2.0, 0.5, (-0.3, 0.2, 0.6), (0.5, -0.2, -1.0), (1.5, 2.0), 0.7,
                         (0.1, 0.0, 0.0)),
}
TRIS = {
    # name: triangle corners, shading point
    "triangle_close": ([(-1.0, -1.0, 0.4), (1.5, -0.8, 0.5), (0.0, 1.2, 0.3)], (0.0, 0.0, 0.0)),
    "triangle_wide": ([(-3.0, -2.0, 0.2), (3.0, -2.5, 0.25), (0.5, 3.0, 0.1)], (0.1, 0.1, 0.0)),
}
N_TESTS = 2 * len(RECTS) + 2 * len(TRIS) + 1 + 2 + 1 + 2
LEVEL = ember_stats.family_level(__name__, N_TESTS)   # the suite budget, Sidak over N_TESTS
Z_MAX = C.z_threshold(LEVEL)


def uniforms(seed, k, n=N):
    return np.random.default_rng(seed).random((k, n))


def assert_chi2(res, what):
    print(f"chi2 {what}: {res.power_line(LEVEL)}")
    assert res.p > LEVEL, f"{what}: chi-square rejects the sampler: {res} (level {LEVEL:.3g})"


def assert_z(values, target, what):
    values = np.asarray(values, float)
    mean = values.mean()
    se = values.std(ddof=1) / math.sqrt(len(values))
    z = (mean - target) / se
    print(f"z {what}: {z:.3f} (mean {mean:.6g}, exact {target:.6g}); detects "
          f"{Z_MAX * se / max(abs(target), 1e-300):.3%} (relative) with probability 1/2")
    assert abs(z) < Z_MAX, f"{what}: mean {mean} vs {target}, z = {z:.2f}"


def rect_light(name):
    shape, sx, sy, center, emit, scale, roll, p = RECTS[name]
    m = area_matrix(np.array(center, float), emit, scale, roll)
    light = S.AreaLight(m, (40.0, 30.0, 20.0), shape, sx, sy)
    u = m[:3, 0] * sx
    v = m[:3, 1] * (sx if shape == "SQUARE" else sy)
    c = np.array(center, float)
    corners = c + 0.5 * np.array([u + v, -u + v, -u - v, u - v])
    return light, corners, np.array(p, float)


def bounding_cone(p, points):
    axis = points.mean(axis=0) - p
    axis /= np.linalg.norm(axis)
    rays = points - p
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    _, theta = C.to_phi_theta(rays, C.frame(axis))
    if theta.max() > 0.45 * np.pi:
        # A cap wider than a hemisphere is not convex: corners inside it do
        # not keep the whole shape inside.  Histogram the whole sphere.
        return axis, 2.0
    return axis, float(C.w_of_theta(1.01 * theta.max()))


# ----------------------------------------------------------------------------
# Rectangles

@pytest.mark.parametrize("name", sorted(RECTS))
def test_spherical_rectangle(name):
    light, corners, p = rect_light(name)
    ls, _, _ = make_light_set([light])
    n = N
    P = np.tile(p, (n, 1))
    s = ls.sample(np.zeros(n, int), P, *uniforms(20 + sorted(RECTS).index(name), 3))
    solid_angle = C.convex_polygon_solid_angle(p, corners)
    assert np.all(s.pdf > 0)
    assert_unit(s.wi, name)
    # Solid-angle sampling: the pdf is 1 / solid angle everywhere.
    assert_close(s.pdf, 1.0 / solid_angle, f"{name}: pdf vs 1 / solid angle", rtol=1e-9)
    t, emitter, Le, pdf = ls.intersect(P, s.wi, np.full(n, np.inf))
    assert np.all(emitter == 0)
    assert_close(pdf, s.pdf, f"{name}: intersect pdf vs sample pdf")
    assert_close(t, s.dist, f"{name}: hit distance", rtol=1e-7)

    def pdf_of(d):
        m = len(d)
        return np.where(ls.intersect(np.tile(p, (m, 1)), d, np.full(m, np.inf))[1] == 0,
                        ls.intersect(np.tile(p, (m, 1)), d, np.full(m, np.inf))[3], 0.0)
    axis, omc = bounding_cone(p, corners)
    res = direction_chi2(s.wi, pdf_of, C.frame(axis), uniform_phi_edges(), cone_theta_edges(omc), n)
    assert_chi2(res, f"spherical rectangle {name}")
    # Area sampling's 1/pdf has the solid angle as its mean too: compare the
    # two strategies' estimates of it (independent of the engine's formula).
    area_inv = area_sampled_inverse_pdf(light, p, 30 + sorted(RECTS).index(name))
    assert_z(area_inv, solid_angle, f"{name}: mean(1/pdf) of area sampling")


def area_sampled_inverse_pdf(light, p, seed, n=N):
    ls, _, _ = make_light_set([light])
    saved = lights.common.MIN_SPHERICAL
    lights.common.MIN_SPHERICAL = np.inf
    try:
        s = ls.sample(np.zeros(n, int), np.tile(p, (n, 1)), *uniforms(seed, 3, n))
    finally:
        lights.common.MIN_SPHERICAL = saved
    return np.where(s.pdf > 0, 1.0 / np.where(s.pdf > 0, s.pdf, 1.0), 0.0)


def test_rectangle_fallbacks_to_area_sampling():
    """Tiny (far) rectangles and points almost in the light's plane use area
    sampling, with the same pdf from sample and intersect."""
    far = S.AreaLight(area_matrix(np.array([0.0, 0.0, 100.0]), (0, 0, -1)), (1.0, 1.0, 1.0), "SQUARE", 0.5)
    graze = S.AreaLight(area_matrix(np.array([3.0, 0.0, 1e-9]), (0, 0, -1)), (1.0, 1.0, 1.0),
                        "RECTANGLE", 2.0, 1.0)
    for light in (far, graze):
        ls, _, _ = make_light_set([light])
        n = 2000
        P = np.zeros((n, 3))
        s = ls.sample(np.zeros(n, int), P, *uniforms(5, 3, n))
        ok = s.pdf > 0
        assert ok.any()
        v = s.wi[ok] * s.dist[ok, None]
        area_pdf = s.dist[ok] ** 2 / (np.abs(s.wi[ok] @ ls.areas.n[0]) * ls.areas.area[0])
        assert_close(s.pdf[ok], area_pdf, "fallback pdf is the area pdf")
        q = v - ls.areas.c[0]
        assert np.all(np.abs(q @ ls.areas.du[0]) <= 0.5 + 1e-9)
        pdf = ls.intersect(P[ok], s.wi[ok], np.full(ok.sum(), np.inf))[3]
        assert_close(pdf, s.pdf[ok], "fallback: intersect pdf vs sample pdf", rtol=1e-6)


def test_spherical_rectangle_lowers_variance():
    """Irradiance at a point 0.3 below a 2 x 2 light: both strategies agree
    with the analytic value; solid-angle sampling has far lower variance."""
    light, _, p = rect_light("square_close")
    ls, _, _ = make_light_set([light])
    # Cycles' units from the light's definition, not from the light set: a
    # normalized area light of power P and area A has radiance P / (pi A).
    L = light.power[0] / (math.pi * 2.0 * 2.0)
    n = N
    P = np.tile(p, (n, 1))
    u = uniforms(40, 3)
    s = ls.sample(np.zeros(n, int), P, *u)
    e_sph = s.Le[:, 0] * s.wi[:, 2] / s.pdf
    saved = lights.common.MIN_SPHERICAL
    lights.common.MIN_SPHERICAL = np.inf
    try:
        s = ls.sample(np.zeros(n, int), P, *u)
    finally:
        lights.common.MIN_SPHERICAL = saved
    ok = s.pdf > 0
    e_area = np.where(ok, s.Le[:, 0] * s.wi[:, 2] / np.where(ok, s.pdf, 1.0), 0.0)
    # Four corner rectangles 1 x 1 at height h: the differential form factor.
    a = 1.0 / 0.3
    f = (a / math.sqrt(1 + a * a) * math.atan(a / math.sqrt(1 + a * a))) / math.pi
    exact = math.pi * L * 4 * f
    var_sph, var_area = e_sph.var(), e_area.var()
    print(f"\nclose 2x2 rectangle: per-sample variance spherical {var_sph:.4g}, area {var_area:.4g} "
          f"(ratio {var_area / var_sph:.1f})")
    assert_z(e_sph, exact, "irradiance, spherical rectangle")
    assert var_sph < 0.5 * var_area


# ----------------------------------------------------------------------------
# Triangles

def triangle_scene(corners, extra=()):
    pos = np.array(list(corners) + list(extra), float)
    tris = np.arange(len(pos)).reshape(-1, 3)
    mesh = S.Mesh(pos, tris)
    mat = S.Material("emit", (S.Lobe("diffuse"),), emission=(2.0, 1.0, 0.5))
    return make_light_set([], [mesh], [S.Instance(0, np.eye(4), [0])], [mat])


def triangle_pdf_of(ls, tris, p):
    def pdf(d):
        t, prim = ray_triangles(p, d, tris)
        out = np.zeros(len(d))
        hit = prim >= 0
        o = np.tile(p, (hit.sum(), 1))
        out[hit] = ls.triangle_pdf(prim[hit], o, o + d[hit] * t[hit, None], tris.ng[prim[hit]])
        return out
    return pdf


@pytest.mark.parametrize("name", sorted(TRIS))
def test_spherical_triangle(name):
    corners, p = TRIS[name]
    p = np.array(p, float)
    ls, tris, _ = triangle_scene(corners)
    n = N
    P = np.tile(p, (n, 1))
    s = ls.sample(np.zeros(n, int), P, *uniforms(50 + sorted(TRIS).index(name), 3))
    c = np.array(corners, float)
    solid_angle = float(C.triangle_solid_angle(c[:1] - p, c[1:2] - p, c[2:] - p)[0])
    assert lights.MIN_SPHERICAL < solid_angle < lights.MAX_SPHERICAL
    assert np.all(s.pdf > 0)
    assert_close(s.pdf, 1.0 / solid_angle, f"{name}: pdf vs 1 / solid angle", rtol=1e-9)
    pdf_fn = triangle_pdf_of(ls, tris, p)
    assert_close(pdf_fn(s.wi), s.pdf, f"{name}: triangle_pdf vs sample pdf", rtol=1e-9)
    t, prim = ray_triangles(p, s.wi, tris)
    assert np.all(prim == 0)
    assert_close(t, s.dist, f"{name}: distance to the sampled point", rtol=1e-9)
    axis, omc = bounding_cone(p, c)
    res = direction_chi2(s.wi, pdf_fn, C.frame(axis), uniform_phi_edges(), cone_theta_edges(omc), n)
    assert_chi2(res, f"spherical triangle {name}")
    assert_z(area_sampled_triangle_inverse_pdf(ls, p, 60 + sorted(TRIS).index(name)), solid_angle,
             f"{name}: mean(1/pdf) of area sampling")


def area_sampled_triangle_inverse_pdf(ls, p, seed, n=N):
    saved = lights.common.MIN_SPHERICAL
    lights.common.MIN_SPHERICAL = np.inf
    try:
        s = ls.sample(np.zeros(n, int), np.tile(p, (n, 1)), *uniforms(seed, 3, n))
    finally:
        lights.common.MIN_SPHERICAL = saved
    return 1.0 / s.pdf


def test_triangle_group_mixes_strategies():
    """One emissive material, a near triangle (solid angle sampling) and a far
    one (area sampling): the pdf of every sample equals what triangle_pdf
    says, the group's solid angle is mean(1/pdf), and the histogram fits."""
    near = [(-1.0, -1.0, 0.4), (1.5, -0.8, 0.5), (0.0, 1.2, 0.3)]
    far = [(-30.0, -0.2, -0.1), (-30.0, 0.2, -0.1), (-30.0, 0.0, 0.2)]   # not behind the near one
    ls, tris, _ = triangle_scene(near, far)
    p = np.zeros(3)
    n = N
    s = ls.sample(np.zeros(n, int), np.tile(p, (n, 1)), *uniforms(70, 3))
    pdf_fn = triangle_pdf_of(ls, tris, p)
    assert_close(pdf_fn(s.wi), s.pdf, "mixed group: triangle_pdf vs sample pdf", rtol=1e-9)
    t, prim = ray_triangles(p, s.wi, tris)
    assert set(np.unique(prim)) == {0, 1}
    total = sum(float(C.triangle_solid_angle(tris.p0[k:k + 1] - p, tris.p0[k:k + 1] + tris.e1[k:k + 1] - p,
                                             tris.p0[k:k + 1] + tris.e2[k:k + 1] - p)[0]) for k in (0, 1))
    assert_z(1.0 / s.pdf, total, "mixed group: mean(1/pdf)")
    corners = np.array(near)
    axis, omc = bounding_cone(p, corners)
    near_dirs = s.wi[prim == 0]
    res = direction_chi2(near_dirs, pdf_fn, C.frame(axis), uniform_phi_edges(), cone_theta_edges(omc), n,
                         rest=int((prim == 1).sum()))
    assert_chi2(res, "mixed group, near triangle")


# ----------------------------------------------------------------------------
# Emissive triangles picked by a light tree over their group

def spread_group(strategy="tree"):
    """One emissive material on a small cube near the origin and a big quad
    far away: by area nearly every sample would go to the far quad."""
    from engine.testscenes import box, quad
    cube = box((0.2, 0.2, 0.2))
    tilt = np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])   # no face edge-on to p
    near = S.Mesh(cube.positions @ tilt.T + (0.4, 0.5, 0.9), cube.triangles)
    far = quad([[-2.0, 5.0, 1.0], [2.0, 5.0, 1.0], [2.0, 5.0, 5.0], [-2.0, 5.0, 5.0]])
    mat = S.Material("emit", (S.Lobe("diffuse"),), emission=(2.0, 1.0, 0.5))
    return make_light_set([], [near, far], [S.Instance(0, np.eye(4), [0]), S.Instance(1, np.eye(4), [0])],
                          [mat], strategy)


def test_triangle_tree_picks_by_importance():
    """With the tree strategy a group's triangle is picked by importance at
    the shading point: the picks follow the pmf ``triangle_pdf`` uses
    (chi-square), the pmf sums to 1, the sampled pdf equals triangle_pdf
    exactly (with and without a normal), mean(1/pdf) is the triangles' total
    solid angle, and the near cube gets over ten times its share by area (1.5 %)."""
    ls, tris, _ = spread_group()
    meshes = ls.meshes
    assert meshes.trees[0] is not None
    p = np.array([0.0, 0.0, 0.0])
    n = N
    P = np.tile(p, (n, 1))
    members = meshes.members[0]
    for normal in (np.array([0.0, 0.3, 1.0]) / math.hypot(0.3, 1.0), None):
        nn = None if normal is None else np.tile(normal, (n, 1))
        pmf = meshes._pick_pmf(members, P[:len(members)], None if nn is None else nn[:len(members)])
        assert abs(pmf.sum() - 1.0) < 1e-12, pmf.sum()
        near = pmf[:12].sum()
        area_share = tris.area[members[:12]].sum() / tris.area[members].sum()
        assert area_share < 0.02 and near > 10 * area_share, (near, area_share)
        s = ls.sample(np.zeros(n, int), P, *uniforms(70 if normal is None else 71, 3), n=nn)
        assert np.all(s.pdf > 0)
        tri, prob = meshes._pick(np.zeros(n, int), P, uniforms(70 if normal is None else 71, 3)[2], nn)
        hit = s.wi * s.dist[:, None]
        assert_close(ls.triangle_pdf(tri, P, hit, tris.ng[tri], nn), s.pdf, "tree group: triangle_pdf vs sample",
                     rtol=1e-9)
        assert_close(prob, meshes._pick_pmf(tri, P, nn), "tree group: pick probability vs pmf", rtol=0)
    res = C.chi2_test(np.bincount(meshes.rank[tri], minlength=len(members)), n * pmf)
    assert_chi2(res, "triangle picks of a group's light tree")
    a = tris.p0[members] - p
    total = float(C.triangle_solid_angle(a, a + tris.e1[members], a + tris.e2[members]).sum())
    assert_z(1.0 / s.pdf, total, "tree group: mean(1/pdf) vs solid angle")


def test_triangle_tree_render_agrees_with_area_picks_and_strategies():
    """Direct light from the spread group on a floor: light-only, BSDF-only
    and MIS with the tree, and MIS with area picks (power selection), agree
    block by block; the tree's MIS image has lower variance than area picks'."""
    from engine.render import render
    from engine.testscenes import box, look_at, quad
    from ember_stats import block_means_var, family_z, median_block_detects, z_scores
    cube = box((0.4, 0.4, 0.4))
    floor = quad([[-3, -3, 0], [3, -3, 0], [3, 6, 0], [-3, 6, 0]])
    bar = quad([[-2.0, 5.0, 1.0], [2.0, 5.0, 1.0], [2.0, 5.0, 3.0], [-2.0, 5.0, 3.0]])
    near = S.Mesh(cube.positions + (0.0, 0.0, 0.5), cube.triangles)
    mats = [S.Material("floor", (S.Lobe("diffuse", (0.8, 0.8, 0.8)),)),
            S.Material("emit", (S.Lobe("diffuse", (0.0, 0.0, 0.0)),), emission=(4.0, 3.0, 2.0))]
    cam = S.Camera(look_at((0, 0, 8), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=5.0,
                   resolution=(32, 32), clip_start=0.1, clip_end=100.0)
    scene = S.Scene([floor, near, bar], [S.Instance(0, materials=[0]), S.Instance(1, materials=[1]),
                                         S.Instance(2, materials=[1])], mats, [], S.World((0.0, 0.0, 0.0)), cam)
    runs = {"tree light": ("tree", "light"), "tree bsdf": ("tree", "bsdf"), "tree mis": ("tree", "mis"),
            "area mis": ("power", "mis")}
    out = {}
    for seed, (name, (selection, strategy)) in enumerate(runs.items(), start=21):
        r = render(scene, S.RenderSettings(samples=64, samples_per_pass=64, max_bounces=1, seed=seed,
                                           light_selection=selection, strategy=strategy))
        assert np.isfinite(r.image).all()
        out[name] = block_means_var(r.image[..., :3].astype(float), r.variance.astype(float), 4)
        out[name + " var"] = float(r.variance[..., :3].astype(float).mean())
    pairs = [(a, "tree mis") for a in ("tree light", "tree bsdf", "area mis")]
    ref = out["tree mis"][0]
    keep = ref > 0.01 * ref.max()
    limit = family_z(__name__, keep.sum() * len(pairs))
    for a, b in pairs:
        z = z_scores(*out[a], *out[b])[keep]
        print(f"{a} vs {b}: max |z| {np.abs(z).max():.2f} (limit {limit:.2f}), means "
              f"{out[a][0][keep].mean():.4f} / {out[b][0][keep].mean():.4f}; the median block detects "
              f"{median_block_detects(limit, out[b][0][keep], out[a][1][keep], out[b][1][keep]):.1%}")
        assert np.abs(z).max() < limit
    print({k: f"{v:.4g}" for k, v in out.items() if k.endswith("var")})
    assert keep.sum() > 100
    assert out["tree mis var"] < out["area mis var"]


# ----------------------------------------------------------------------------
# Light tree

def many_lights(count=300, seed=7):
    """Small point, spot and area lights of varied power scattered above a
    floor, a sun, and an emissive mesh (two materials)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        pos = (rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(0.05, 1.0))
        power = tuple(rng.uniform(0.5, 3.0) * np.array([1.0, 0.8, 0.6]))
        r = rng.random()
        if r < 0.4:
            out.append(S.PointLight(pos, power, 0.03, rng.random() < 0.5))
        elif r < 0.6:
            out.append(S.SpotLight(pos, power, 0.02, direction=tuple(rng.normal(size=3) + (0, 0, -1.5)),
                                   spot_size=1.2, spot_blend=0.3))
        else:
            out.append(S.AreaLight(area_matrix(np.array(pos), (rng.normal(), rng.normal(), -1.0)),
                                   power, "RECTANGLE", 0.1, 0.05))
    return out


def tree_set(count=300):
    from sampling_lib import emissive_mesh_scene
    meshes, instances, materials = emissive_mesh_scene()
    lts = many_lights(count) + [S.SunLight((0.2, 0.1, -1.0), (0.5, 0.5, 0.5), 0.05)]
    return make_light_set(lts, meshes, instances, materials, "tree")[0]


def test_auto_selection_samples_every_light_only_when_few_and_no_mesh():
    """'auto' is the light tree, which samples every light at glossy
    vertices with 2-4 lights and no emissive mesh; prepare() hands the
    integrator 'auto' only then."""
    from engine.render import prepare
    from engine.testscenes import look_at, quad
    def point(k):
        return S.PointLight((k, 0.0, 3.0), (10.0, 10.0, 10.0), radius=0.1)
    for n, every in ((1, False), (2, True), (4, True), (5, False), (64, False)):
        ls, _, _ = make_light_set([point(k) for k in range(n)], strategy="auto")
        assert (ls.strategy, ls.every_at_glossy) == ("tree", every), n
    assert lights.resolve_selection("power", 3, 0) == ("power", False)
    mats = [S.Material("floor"), S.Material("emit", emission=(2.0, 2.0, 2.0))]
    cam = S.Camera(look_at((0, 0, 5), (0, 0, 0), (0, 1, 0)), resolution=(8, 8))
    for emit, expected in ((1, "tree"), (0, "auto")):
        floor = quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
        scene = S.Scene([floor], [S.Instance(0, materials=[emit])], mats, [point(0), point(1)],
                        S.World((0.0, 0.0, 0.0)), cam)
        ctx = prepare(scene, S.RenderSettings(light_selection="auto"))
        assert ctx.settings.light_selection == expected, emit


def test_every_light_only_at_narrow_glossy_vertices():
    from engine import bsdf
    from engine.integrator import _every_light
    kinds = np.array([[bsdf.GLOSSY, bsdf.DIFFUSE]] * 4, np.int8)
    alpha = np.array([[0.01, 0.0], [0.01, 0.0], [0.5, 0.0], [0.25, 0.0]])
    sel = np.array([[0.9, 0.1], [0.4, 0.6], [0.9, 0.1], [0.6, 0.4]])
    lobes = bsdf.Lobes(kinds, np.zeros((4, 2, 3)), alpha, np.zeros((4, 2), bool))
    assert _every_light(lobes, sel).tolist() == [True, False, False, True]


def glossy_plates_over_floor(selection, seed):
    """Veach's four plates (the rougher ones reflect by the tree's pick, the
    sharper by every light: 'auto' splits the image) over a diffuse floor
    they bounce light onto, so MIS meets lights sampled both ways."""
    from engine.testscenes import quad, veach_four
    scene = veach_four((96, 72), power=20.0)
    scene.meshes.append(quad([[-6, -4, -0.6], [6, -4, -0.6], [6, 6, -0.6], [-6, 6, -0.6]]))
    scene.materials.append(S.Material("floor", (S.Lobe("diffuse", (0.6, 0.6, 0.6)),)))
    scene.instances.append(S.Instance(len(scene.meshes) - 1, materials=[len(scene.materials) - 1]))
    return scene, S.RenderSettings(samples=512, samples_per_pass=256, max_bounces=2, seed=seed,
                                   light_selection=selection)


def test_auto_selection_render_agrees_with_tree_and_all():
    """'auto' (every light at the three sharper plates, the tree at the
    roughest plate and the floor) against 'all' and 'tree', block by block
    and in the image mean: the MIS weight of a light that a BSDF ray meets
    uses the selection probability of the way its vertex sampled lights.
    With the tree's probability where every light was sampled, a block is
    off by |z| 53 against 'all' (checked by hand, limit 5.5)."""
    from engine.render import render
    from ember_stats import block_means_var, detectable, family_level, family_z, z_scores
    out = {sel: render(*glossy_plates_over_floor(sel, seed)) for sel, seed in
           (("auto", 11), ("all", 12), ("tree", 13))}
    level = family_level(__name__ + ".auto_vs", 4)
    limit = family_z(__name__ + ".auto_blocks", 2 * 12 * 16 * 3)
    a = out["auto"]
    ma, va = block_means_var(a.image[..., :3].astype(float), a.variance.astype(float), 6)
    for other in ("all", "tree"):
        b = out[other]
        mb, vb = block_means_var(b.image[..., :3].astype(float), b.variance.astype(float), 6)
        assert np.abs(z_scores(ma, va, mb, vb)).max() < limit, other
        mean_a, mean_b = ma.mean(), mb.mean()
        se = np.sqrt(va.sum() + vb.sum()) / ma.size
        if other == "all":
            se_all, mean_all = se, mean_b
        z = (mean_a - mean_b) / se
        print(f"\nauto vs {other}: image mean {mean_a:.5f} vs {mean_b:.5f}, z {z:.2f}; detects "
              f"{detectable(se / mean_b, level):.2%} of the mean")
        assert abs(z) < family_z(__name__ + ".auto_vs", 4)
    # Against 'all' (every selection probability 1, nothing to get wrong),
    # the image mean resolves a 1 % bias.
    assert detectable(se_all / mean_all, level) < 0.01
    # Every light at the sharp plates: clearly less noise than the tree alone.
    assert a.variance.mean() < 0.7 * out["tree"].variance.mean()


def test_light_tree_pmf():
    """At random shading points (with and without a normal) the selection
    pmf sums to 1, ``select`` returns exactly ``selection_pdf`` of its pick,
    the picks follow the pmf (chi-square), and an emitter the tree never
    picks at a point contributes nothing there."""
    ls = tree_set()
    rng = np.random.default_rng(3)
    m = 40
    P = rng.uniform(-5, 5, (m, 3)) * (1, 1, 0.3)
    nrm = rng.normal(size=(m, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm[::4] = 0.0        # no normal
    emitters = np.arange(ls.count)
    for i in range(m):
        pmf = ls.selection_pdf(emitters, np.tile(P[i], (ls.count, 1)), np.tile(nrm[i], (ls.count, 1)))
        assert abs(pmf.sum() - 1.0) < 1e-12, pmf.sum()
        for e in np.nonzero(pmf == 0)[0]:
            s = ls.sample(np.full(64, e), np.tile(P[i], (64, 1)), *uniforms(i, 3, 64))
            assert not np.any((s.pdf > 0) & (s.Le.max(axis=1) > 0)), f"emitter {e} lights a point it skips"
    (u,) = uniforms(80, 1)
    p = np.tile(P[1], (N, 1))
    nn = np.tile(nrm[1], (N, 1))
    e, prob = ls.select(u, p, nn)
    assert_close(prob, ls.selection_pdf(e, p, nn), "tree: select probability vs selection_pdf")
    pmf = ls.selection_pdf(emitters, p[:ls.count], nn[:ls.count])
    assert_chi2(C.chi2_test(np.bincount(e, minlength=ls.count), N * pmf), "light tree selection")


def test_selection_weighs_the_mean_rgb_power_not_the_hue():
    """Two sphere lights of one mean RGB power, red and green, placed
    symmetrically about a shading point: power selection and the tree pick
    each with probability 1/2 (Cycles' light tree weighs average(strength)).
    By luminance the green light would get 0.77 (0.7152 vs 0.2126 for the
    red one), starving the red light's highlights of samples."""
    red = S.PointLight(position=(-2.0, 0.0, 3.0), power=(60.0, 0.0, 0.0), radius=0.03, soft_falloff=True)
    green = S.PointLight(position=(2.0, 0.0, 3.0), power=(0.0, 60.0, 0.0), radius=0.03, soft_falloff=True)
    p = np.zeros((2, 3))
    n = np.tile([0.0, 0.0, 1.0], (2, 1))
    for strategy in ("power", "tree"):
        ls, _, _ = make_light_set([red, green], strategy=strategy)
        pmf = ls.selection_pdf(np.arange(2), p, n)
        assert np.allclose(pmf, 0.5, rtol=0, atol=1e-12), (strategy, pmf)


def floor_scene(selection, count=300, size=(24, 24)):
    from engine.testscenes import look_at, quad
    floor = quad([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]])
    mats = [S.Material("floor", (S.Lobe("diffuse", (0.8, 0.8, 0.8)),))]
    cam = S.Camera(look_at((0, 0, 10), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=9.0,
                   resolution=size, clip_start=0.1, clip_end=100.0)
    scene = S.Scene([floor], [S.Instance(0, materials=[0])], mats, many_lights(count),
                    S.World((0.0, 0.0, 0.0)), cam)
    # A seed per selection: renders compared by z-tests must be independent.
    return scene, S.RenderSettings(samples=32, samples_per_pass=32, max_bounces=0,
                                   seed=5 + ("power", "tree", "uniform", "all").index(selection),
                                   light_selection=selection)


def test_light_tree_render_agrees_and_lowers_variance():
    """300 small lights over a floor, direct light: the tree's image agrees
    with power selection block by block, with clearly lower variance."""
    import time
    from engine.render import render
    from ember_stats import block_means_var, family_z, median_block_detects, z_scores
    out = {}
    for sel in ("power", "tree"):
        scene, settings = floor_scene(sel)
        t0 = time.perf_counter()
        out[sel] = render(scene, settings)
        out[sel + "_s"] = time.perf_counter() - t0
    a, b = out["power"], out["tree"]
    ma, va = block_means_var(a.image[..., :3].astype(float), a.variance.astype(float), 4)
    mb, vb = block_means_var(b.image[..., :3].astype(float), b.variance.astype(float), 4)
    z = z_scores(ma, va, mb, vb)
    limit = family_z(__name__, z.size)
    var_power, var_tree = float(a.variance.mean()), float(b.variance.mean())
    rel = abs(mb.sum() - ma.sum()) / ma.sum()
    print(f"\nmany lights: mean pixel variance power {var_power:.4g}, tree {var_tree:.4g} "
          f"(ratio {var_power / var_tree:.2f}); relative mean difference {rel:.4f}; max |z| "
          f"{np.abs(z).max():.2f} (limit {limit:.2f}), the median block detects "
          f"{median_block_detects(limit, ma, va, vb):.1%}; seconds power {out['power_s']:.1f}, "
          f"tree {out['tree_s']:.1f}")
    assert np.abs(z).max() < limit
    assert var_tree < 0.5 * var_power


# ----------------------------------------------------------------------------
# Ray visibility

def test_shadow_and_camera_invisible_object_is_absent():
    """A box invisible to camera and shadow rays, direct light only: the
    image equals the scene without the box (block z-test); with default
    flags the triangles carry no visibility array (nothing to pay)."""
    from engine import geometry
    from engine.render import render
    from engine.testscenes import box, look_at, quad
    from ember_stats import block_means_var, family_z, median_block_detects, z_scores
    floor = quad([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]])
    cube = box((0.8, 0.8, 0.8))
    mats = [S.Material("floor", (S.Lobe("diffuse", (0.8, 0.8, 0.8)),))]
    cam = S.Camera(look_at((0, 0, 6), (0, 0, 0), (0, 1, 0)), kind="ORTHO", ortho_scale=5.0,
                   resolution=(24, 24), clip_start=0.1, clip_end=100.0)
    light = [S.PointLight((0.3, 0.2, 2.5), (300.0, 300.0, 300.0), 0.1)]
    m = np.eye(4)
    m[:3, 3] = (0.0, 0.0, 1.0)
    ghost = S.Instance(1, m, [0], visible_camera=False, visible_shadow=False)
    settings = S.RenderSettings(samples=64, samples_per_pass=64, max_bounces=0, seed=9)
    with_ghost = S.Scene([floor, cube], [S.Instance(0, materials=[0]), ghost], mats, light, S.World((0, 0, 0)), cam)
    without = S.Scene([floor], [S.Instance(0, materials=[0])], mats, light, S.World((0, 0, 0)), cam)
    assert geometry.flatten(without).visibility is None
    assert set(np.unique(geometry.flatten(with_ghost).visibility)) == {geometry.VIS_ALL, geometry.VIS_DIFFUSE
                                                                       | geometry.VIS_GLOSSY
                                                                       | geometry.VIS_TRANSMISSION}
    # Independent seeds: the z-test assumes independent renders.
    a, b = render(with_ghost, settings), render(without, S.RenderSettings(**{**vars(settings), "seed": 10}))
    ma, va = block_means_var(a.image[..., :3].astype(float), a.variance.astype(float), 4)
    mb, vb = block_means_var(b.image[..., :3].astype(float), b.variance.astype(float), 4)
    z = z_scores(ma, va, mb, vb)
    limit = family_z(__name__, z.size)
    print(f"\ninvisible box: max |z| {np.abs(z).max():.2f} (limit {limit:.2f}), relative mean difference "
          f"{abs(ma.sum() - mb.sum()) / mb.sum():.4f}; the median block detects "
          f"{median_block_detects(limit, mb, va, vb):.1%}")
    assert np.abs(z).max() < limit
    visible = S.Scene([floor, cube], [S.Instance(0, materials=[0]), S.Instance(1, m, [0])], mats, light,
                      S.World((0, 0, 0)), cam)
    c = render(visible, settings)
    diff = np.abs(c.image[..., :3] - b.image[..., :3]).mean()
    assert diff > 0.1 * b.image[..., :3].mean(), "the same box with default flags must show"
