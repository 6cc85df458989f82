"""Every sampling routine of the engine, checked against its own pdf.

Mitsuba's recipe (ChiSquareTest): draw ~1e6 samples with a fixed seed,
histogram them on a grid ((phi, theta) about an axis for directions, a 1D or 2D
grid for points, the indices for discrete choices), integrate the routine's pdf
over every cell numerically, pool cells expecting fewer than 5 samples and
apply Pearson's chi-square test.  Beside the histogram:

* consistency: what ``sample`` returns (pdf, weight, radiance) equals what the
  matching evaluation routine says for the same direction;
* mean(1/pdf) over the samples estimates the measure of the pdf's support
  (2 pi for a hemisphere, the solid angle of a light); it is compared with the
  exact measure in units of its standard error computed from the samples.

All statistical tests of this file form one family: its error rate is
the suite's family level (ember_stats.family_level), split over the tests
with Sidak's correction (docs/testing.md; the seeds here are fixed: the
outcome is deterministic).  Deterministic checks use
tolerances of floating-point rounding, never statistics.
"""
import math
import os
import sys

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
for _path in (ROOT, HERE):
    if _path not in sys.path:
        sys.path.insert(0, _path)

import chi2 as C  # noqa: E402
import ember_stats
from engine import bsdf, camera, lights, sampling  # noqa: E402
from engine import scene as S  # noqa: E402

N = 1_000_000           # samples per histogram
from sampling_lib import (FP_RTOL, RES, TWO_PI, area_matrix, assert_close, assert_unit,  # noqa: E402,F401
                          cone_theta_edges, direction_chi2, emissive_mesh_scene, make_light_set, ray_triangles,
                          uniform_phi_edges, unit)
FZ = C.frame((0.0, 0.0, 1.0))


# Fixed seeds; EMBER_CHI2_SEED shifts them all (to look at other draws).
SEED_OFFSET = int(os.environ.get("EMBER_CHI2_SEED", "0"))


def uniforms(seed, k, n=N):
    return np.random.default_rng(seed + 1000 * SEED_OFFSET).random((k, n))


# ----------------------------------------------------------------------------
# Cases (defined first: the Sidak correction counts them)

CONES = [-0.5, 0.3, 0.95, 1.0 - 1e-5, 1.0 - 1e-9, 1.0 - 1e-13]   # last: a naive sqrt(1 - cos^2) fails

GGX = [(a, c) for a in (0.05, 0.2, 0.5, 1.0) for c in (1.0, 0.75, 0.35, 0.08)]

MATERIALS = {
    "diffuse": S.Material("diffuse", (S.Lobe("diffuse", (0.7, 0.5, 0.3)),)),
    "plastic": S.Material("plastic", (S.Lobe("diffuse", (0.6, 0.3, 0.1)),
                                      S.Lobe("glossy", (0.04, 0.04, 0.04), 0.3, "schlick"))),
    "metal": S.Material("metal", (S.Lobe("glossy", (0.95, 0.64, 0.54), 0.45, "schlick"),)),
    "coated": S.Material("coated", (S.Lobe("diffuse", (0.2, 0.4, 0.6)),
                                    S.Lobe("glossy", (0.3, 0.3, 0.3), 0.7, "none"),
                                    S.Lobe("mirror", (0.05, 0.05, 0.05), 0.0, "schlick"))),
    "glossy_mirror": S.Material("glossy_mirror", (S.Lobe("glossy", (0.9, 0.6, 0.3), 0.15, "schlick"),
                                                  S.Lobe("mirror", (0.2, 0.25, 0.3), 0.0, "none"))),
}
MULTI = [(m, c) for m in MATERIALS for c in (1.0, 0.5, 0.1)]

LIGHTS = ["sphere", "sphere_close", "sphere_far", "soft_disk", "soft_disk_close", "spot_sphere",
          "spot_soft", "sun_real", "sun_wide", "sun_huge", "area_square", "area_square_close",
          "area_rectangle", "area_disk", "area_ellipse", "mesh"]

FILTERS = [(k, w) for k in ("BOX", "GAUSSIAN", "BLACKMAN_HARRIS") for w in (1.0, 1.5)]


def _has_mirror(material):
    return any(l.kind == "mirror" for l in material.lobes)


N_TESTS = (2                      # cosine hemisphere: chi2 + mean(1/pdf)
           + 1                    # uniform sphere
           + len(CONES)           # uniform cone
           + 2                    # concentric disk: polar and cartesian grids
           + 1                    # uniform triangle
           + 3                    # Distribution1D: discrete, continuous, mean(1/pdf)
           + 2 * len(GGX)         # chi2 + mean(1/pdf)
           + sum(2 + _has_mirror(MATERIALS[m]) for m, _ in MULTI)  # + delta frequency
           + 2 * len(LIGHTS)      # chi2 + mean(1/pdf)
           + 2                    # light selection (power, uniform)
           + 2 * len(FILTERS))    # chi2 + mean(1/pdf)
LEVEL = ember_stats.family_level(__name__, N_TESTS)   # the suite budget, Sidak over N_TESTS
Z_MAX = C.z_threshold(LEVEL)


# ----------------------------------------------------------------------------
# Assertions

def assert_chi2(res, what):
    print(f"chi2 {what}: {res.power_line(LEVEL)}")
    assert res.p > LEVEL, f"{what}: chi-square rejects the sampler: {res} (level {LEVEL:.3g})"


def assert_mean(values, target, what):
    """mean(values) == target within Z_MAX standard errors from the samples."""
    values = np.asarray(values, float)
    mean = values.mean()
    se = values.std(ddof=1) / math.sqrt(len(values))
    if se <= FP_RTOL * abs(mean):   # constant up to rounding: an exact identity
        assert mean == pytest.approx(target, rel=FP_RTOL), f"{what}: {mean} != {target}"
        return
    z = (mean - target) / se
    print(f"z {what}: {z:.3f}")
    assert abs(z) < Z_MAX, (f"{what}: mean {mean:.7g} vs exact {target:.7g}, "
                            f"z = {z:.2f} (|z| must be < {Z_MAX:.2f}, se {se:.3g})")


# ----------------------------------------------------------------------------
# sampling.py

def test_chi2_helpers():
    """The chi-square survival function against closed forms."""
    for x in (0.01, 0.7, 3.0, 11.0, 40.0):
        assert C.chi2_sf(x, 1) == pytest.approx(math.erfc(math.sqrt(x / 2)), rel=1e-10)
        for dof in (2, 6, 40):
            k = dof // 2
            exact = math.exp(-x / 2) * sum((x / 2) ** j / math.factorial(j) for j in range(k))
            assert C.chi2_sf(x, dof) == pytest.approx(exact, rel=1e-9, abs=1e-300)
    # The file's N_TESTS tests together spend exactly its share of the suite's budget (Sidak).
    assert 1.0 - (1.0 - LEVEL) ** N_TESTS == pytest.approx(ember_stats.FAMILY_ALPHA, rel=1e-6)
    assert C.normal_two_sided_p(Z_MAX) == pytest.approx(LEVEL, rel=1e-6)


def test_cosine_hemisphere():
    u1, u2 = uniforms(1, 2)
    d, pdf = sampling.cosine_hemisphere(u1, u2)
    assert_unit(d, "cosine_hemisphere")
    assert np.all(d[:, 2] >= 0)
    assert_close(pdf, sampling.cosine_hemisphere_pdf(d[:, 2]), "returned pdf vs cosine_hemisphere_pdf")
    res = direction_chi2(d, lambda v: sampling.cosine_hemisphere_pdf(v[:, 2]), FZ,
                         uniform_phi_edges(), cone_theta_edges(1.0, margin=0.0), N, rest=0)
    assert_chi2(res, "cosine_hemisphere")
    assert_mean(1.0 / pdf, TWO_PI, "cosine_hemisphere mean(1/pdf)")


def test_uniform_sphere():
    u1, u2 = uniforms(2, 2)
    d, pdf = sampling.uniform_sphere(u1, u2)
    assert_unit(d, "uniform_sphere")
    assert_close(pdf, 1.0 / (4 * np.pi), "uniform_sphere pdf")
    res = direction_chi2(d, lambda v: np.full(len(v), 1.0 / (4 * np.pi)), FZ,
                         uniform_phi_edges(), cone_theta_edges(2.0, margin=0.0), N, rest=0)
    assert_chi2(res, "uniform_sphere")


@pytest.mark.parametrize("cos_max", CONES)
def test_uniform_cone(cos_max):
    u1, u2 = uniforms(30 + CONES.index(cos_max), 2)
    omc = 1.0 - cos_max                   # exact in float64 (Sterbenz) for cos_max >= 0.5
    d, pdf = sampling.uniform_cone(u1, u2, omc)
    assert_unit(d, "uniform_cone")
    own_pdf = sampling.uniform_cone_pdf(omc)
    assert_close(np.broadcast_to(pdf, (N,)), own_pdf, "uniform_cone pdf vs uniform_cone_pdf")
    # mean(1/pdf) is exact here: the pdf is constant.
    assert own_pdf * TWO_PI * omc == pytest.approx(1.0, rel=FP_RTOL)

    def pdf_fn(v):
        _, theta = C.to_phi_theta(v, FZ)
        return np.where(C.w_of_theta(theta) <= omc, own_pdf, 0.0)

    res = direction_chi2(d, pdf_fn, FZ, uniform_phi_edges(), cone_theta_edges(omc), N)
    assert_chi2(res, f"uniform_cone(cos_max={cos_max!r})")


def test_concentric_disk():
    u1, u2 = uniforms(4, 2)
    x, y = sampling.concentric_disk(u1, u2)
    r2 = x * x + y * y
    assert np.all(r2 <= 1.0 + 1e-12)
    # Polar grid (phi, r^2): uniform density 1 / (2 pi) per unit phi * r^2.
    phi = np.mod(np.arctan2(y, x), TWO_PI)
    pe, re = uniform_phi_edges(), np.linspace(0.0, 1.0 + 1e-12, RES + 1)
    counts, outside = C.histogram2d(phi, r2, pe, re)
    assert outside == 0
    mass = C.integrate_cells(lambda p, s: np.where(s <= 1.0, 1.0 / TWO_PI, 0.0), pe, re, periodic_x=True)
    assert_chi2(C.chi2_test(counts, N * mass), "concentric_disk (phi, r^2) grid")
    # Cartesian grid: density 1/pi on the disk, cells cut by the circle refined.
    e = np.linspace(-1.0, 1.0, 22)
    counts, outside = C.histogram2d(x, y, e, e)
    assert outside == 0
    mass = C.integrate_cells(lambda a, b: np.where(a * a + b * b <= 1.0, 1.0 / np.pi, 0.0), e, e,
                             refine=128)
    assert_chi2(C.chi2_test(counts, N * mass), "concentric_disk (x, y) grid")


def test_uniform_triangle():
    u1, u2 = uniforms(5, 2)
    b1, b2 = sampling.uniform_triangle(u1, u2)
    assert np.all((b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1.0 + 1e-12))
    a, b, c = np.array([0.1, 0.2]), np.array([0.9, 0.35]), np.array([0.3, 0.95])
    p = a + b1[:, None] * (b - a) + b2[:, None] * (c - a)
    xe, ye = np.linspace(0.1, 0.9, 22), np.linspace(0.2, 0.95, 22)
    counts, outside = C.histogram2d(p[:, 0], p[:, 1], xe, ye)
    assert outside == 0
    # Exact expected counts: area of each cell inside the triangle.
    area = C.clip_polygon_area([a, b, c], -1, 2, -1, 2)
    mass = np.array([[C.clip_polygon_area([a, b, c], xe[i], xe[i + 1], ye[j], ye[j + 1])
                      for j in range(len(ye) - 1)] for i in range(len(xe) - 1)]) / area
    assert mass.sum() == pytest.approx(1.0, rel=1e-12)
    assert_chi2(C.chi2_test(counts, N * mass), "uniform_triangle")


def test_distribution1d():
    w = np.array([0.0, 2.0, 0.5, 0.0, 7.0, 1e-3, 3.0, 0.0, 0.25, 0.0])
    pmf = w / w.sum()
    dist = sampling.Distribution1D(w)
    assert_close(dist.pmf, pmf, "Distribution1D pmf")
    (u,) = uniforms(6, 1)
    idx, p = dist.sample(u)
    assert_close(p, pmf[idx], "Distribution1D returned probability")
    counts = np.bincount(idx, minlength=len(w))
    assert_chi2(C.chi2_test(counts, N * pmf), "Distribution1D.sample")
    assert_mean(1.0 / p, np.count_nonzero(w), "Distribution1D mean(1/p)")
    # sample_continuous: the same index, and u remapped uniformly inside it.
    idx2, p2, du = dist.sample_continuous(u)
    assert np.array_equal(idx2, idx) and np.array_equal(p2, p)
    assert np.all((du >= 0) & (du < 1))
    bins = 10
    joint = np.bincount(idx2 * bins + np.minimum((du * bins).astype(int), bins - 1),
                        minlength=len(w) * bins)
    assert_chi2(C.chi2_test(joint, np.repeat(N * pmf / bins, bins)), "Distribution1D.sample_continuous")


@pytest.mark.parametrize("weights", [[0.1] * 10 + [0.0, 0.0], [0.0, 0.3, 0.3, 0.3, 0.1, 0.0],
                                     [1.0, 0.0, 1e-300, 2.0, 0.0]])
def test_distribution1d_never_returns_zero_probability(weights):
    """Bins of zero weight are never chosen, for any u in [0, 1): including u
    on CDF steps and the largest double below 1 (rng.random() can return it)."""
    dist = sampling.Distribution1D(weights)
    c = dist.cdf
    u = np.concatenate([[0.0, np.nextafter(1.0, 0.0)], c[c < 1.0],
                        np.nextafter(c[c < 1.0], 0.0), np.nextafter(c[c < 1.0], 1.0)])
    u = u[(u >= 0) & (u < 1)]
    idx, p = dist.sample(u)
    bad = p <= 0
    assert not bad.any(), (f"weights {weights}: u = {u[bad].tolist()} picks zero-probability "
                           f"bins {idx[bad].tolist()} (cdf {c.tolist()})")
    _, p2, du = dist.sample_continuous(u)
    assert np.all(p2 > 0) and np.all((du >= 0) & (du < 1))


# ----------------------------------------------------------------------------
# bsdf.py

def lobes_for(material, n):
    table = bsdf.MaterialTable([material])
    return table, table.gather(np.zeros(n, int))


def wo_for(cos_o, phi_o=0.7):
    s = math.sqrt(max(0.0, 1.0 - cos_o * cos_o))
    return np.array([s * math.cos(phi_o), s * math.sin(phi_o), cos_o])


def lobe_grid(wo, alpha):
    """(phi, theta) edges about the normal, dense around the mirror
    direction with a width following the lobe (alpha None: uniform)."""
    if alpha is None:
        return uniform_phi_edges(), cone_theta_edges(1.0, margin=0.0)
    r = np.array([[-wo[0], -wo[1], wo[2]]])
    phi_r, theta_r = (float(v[0]) for v in C.to_phi_theta(r, FZ))
    s_theta = 2.0 * alpha
    s_phi = min(100.0, s_theta / max(math.sin(theta_r), 1e-6))
    pe = C.mixture_edges(phi_r - np.pi, phi_r + np.pi, phi_r, s_phi, RES)
    te = C.mixture_edges(0.0, 0.5 * np.pi, theta_r, s_theta, RES)
    return pe, te


def check_bsdf(material, cos_o, seed, alpha_grid):
    table, lob = lobes_for(material, N)
    wo1 = wo_for(cos_o)
    wo = np.tile(wo1, (N, 1))
    ul, u1, u2 = uniforms(seed, 3)
    wi, weight, pdf, delta = bsdf.sample(lob, wo, ul, u1, u2)
    name = f"{material.name} cos_o={cos_o}"
    assert np.all(np.isfinite(weight)) and np.all(np.isfinite(pdf)) and np.all(weight >= 0)
    assert_unit(wi, name)

    # Consistency of the non-delta samples with eval_pdf.
    smooth = ~delta
    f, p_eval = bsdf.eval_pdf(lob, wo, wi)
    assert_close(pdf[smooth], p_eval[smooth], f"{name}: sample pdf vs eval_pdf")
    valid = smooth & (pdf > 0)
    assert_close(weight[valid], f[valid] * (wi[valid, 2] / pdf[valid])[:, None],
                 f"{name}: weight vs f cos / pdf")
    assert np.all(weight[smooth & (pdf == 0)] == 0), f"{name}: zero-pdf samples must be absorbed"

    # Delta (mirror) samples: exact reflection, weight = colour / selection probability.
    sel = bsdf.selection(_first(lob), wo[:1])[0]
    mirror_k = [k for k in range(lob.kind.shape[1]) if lob.kind[0, k] == bsdf.MIRROR]
    if mirror_k:
        k = mirror_k[0]
        refl = wo1 * np.array([-1.0, -1.0, 1.0])
        assert np.all(wi[delta] == refl), f"{name}: mirror direction is not the exact reflection"
        col = table.color[0, k]
        if table.schlick[0, k]:
            col = col + (1.0 - col) * (1.0 - cos_o) ** 5
        assert_close(weight[delta], np.broadcast_to(col / sel[k], (int(delta.sum()), 3)),
                     f"{name}: mirror weight vs colour / selection")
        assert_close(pdf[delta], sel[k], f"{name}: mirror pdf (selection probability)")
        assert_mean(delta.astype(float), sel[k], f"{name}: frequency of the mirror lobe")
    else:
        assert not delta.any()

    pe, te = lobe_grid(wo1, alpha_grid)

    def pdf_fn(v):
        return bsdf.eval_pdf(_first(lob, len(v)), np.tile(wo1, (len(v), 1)), v)[1]

    res = direction_chi2(wi[valid], pdf_fn, FZ, pe, te, N, rest=int((~valid).sum()))
    assert_chi2(res, name)
    inv = np.where(valid, 1.0 / np.where(valid, pdf, 1.0), 0.0)
    assert_mean(inv, TWO_PI * (1.0 - bsdf.COS_EPS), f"{name}: mean(1/pdf) over the hemisphere")


def _first(lob, n=1):
    return bsdf.Lobes(np.repeat(lob.kind[:1], n, 0), np.repeat(lob.color[:1], n, 0),
                      np.repeat(lob.alpha[:1], n, 0), np.repeat(lob.schlick[:1], n, 0))


@pytest.mark.parametrize("alpha,cos_o", GGX)
def test_bsdf_ggx_vndf(alpha, cos_o):
    mat = S.Material(f"ggx a={alpha}", (S.Lobe("glossy", (0.9, 0.6, 0.3), math.sqrt(alpha), "none"),))
    table, _ = lobes_for(mat, 1)
    assert table.alpha[0, 0] == pytest.approx(alpha, rel=1e-12)
    check_bsdf(mat, cos_o, seed=100 + GGX.index((alpha, cos_o)), alpha_grid=alpha)


@pytest.mark.parametrize("name,cos_o", MULTI)
def test_bsdf_material(name, cos_o):
    mat = MATERIALS[name]
    alphas = [l.roughness ** 2 for l in mat.lobes if l.kind == "glossy"]
    check_bsdf(mat, cos_o, seed=200 + MULTI.index((name, cos_o)),
               alpha_grid=min(alphas) if alphas else None)


def test_bsdf_pure_mirror_and_below_horizon():
    n = 1000
    rng = np.random.default_rng(7)
    cos_o = rng.uniform(0.01, 1.0, n)
    phi = rng.uniform(0, TWO_PI, n)
    s = np.sqrt(1 - cos_o ** 2)
    wo = np.stack([s * np.cos(phi), s * np.sin(phi), cos_o], axis=1)
    for fresnel in ("none", "schlick"):
        mat = S.Material("m", (S.Lobe("mirror", (0.8, 0.5, 0.2), 0.0, fresnel),))
        _, lob = lobes_for(mat, n)
        wi, weight, pdf, delta = bsdf.sample(lob, wo, *rng.random((3, n)))
        assert np.all(delta) and np.all(pdf == 1.0)
        assert np.array_equal(wi, wo * np.array([-1.0, -1.0, 1.0]))
        col = np.array([0.8, 0.5, 0.2])[None, :]
        if fresnel == "schlick":
            col = col + (1 - col) * ((1 - cos_o) ** 5)[:, None]
        assert_close(weight, np.broadcast_to(col, weight.shape), f"mirror weight ({fresnel})")
    # A glossy lobe below MIN_ALPHA is a mirror.
    table, _ = lobes_for(S.Material("g", (S.Lobe("glossy", (1, 1, 1), 0.01),)), 1)
    assert table.kind[0, 0] == bsdf.MIRROR
    # wo below the surface: every sample is absorbed.
    for name, mat in MATERIALS.items():
        _, lob = lobes_for(mat, n)
        wi, weight, pdf, delta = bsdf.sample(lob, wo * np.array([1, 1, -1]), *rng.random((3, n)))
        assert np.all(weight == 0), name


def test_bsdf_lobe_choice_at_u_near_one():
    """u_lobe in [1 - 1e-9, 1) picks the last lobe that has a selection
    probability, also where the rounded selection CDF ends an ulp below 1 and
    the material table has unused lobe slots after it (a shared table)."""
    names = list(MATERIALS)
    table = bsdf.MaterialTable([MATERIALS[m] for m in names])
    cos_o = np.linspace(0.02, 1.0, 50)
    n = len(cos_o)
    wo = np.array([wo_for(c) for c in cos_o])
    rng = np.random.default_rng(12)
    u1, u2 = rng.random((2, n))
    for i, name in enumerate(names):
        lob = table.gather(np.full(n, i))
        safe = bsdf.sample(lob, wo, np.full(n, 1.0 - 1e-9), u1, u2)
        edge = bsdf.sample(lob, wo, np.full(n, np.nextafter(1.0, 0.0)), u1, u2)
        for a, b, what in zip(safe, edge, ("wi", "weight", "pdf", "delta")):
            bad = np.nonzero(np.any(np.atleast_2d((a != b).T).T.reshape(n, -1), axis=1))[0]
            assert len(bad) == 0, (f"{name}, cos_o = {cos_o[bad[0]]:.4f}: u_lobe = 1 - 2^-53 gives "
                                   f"{what} {b[bad[0]]} instead of {a[bad[0]]} (selection CDF "
                                   f"{np.cumsum(bsdf.selection(lob, wo), axis=1)[bad[0]].tolist()})")


def test_bsdf_reciprocity():
    """f(wo, wi) == f(wi, wo) for the non-delta lobes (same Fresnel angle wo.h = wi.h)."""
    n = 20000
    rng = np.random.default_rng(8)
    d = sampling.cosine_hemisphere(*rng.random((2, 2 * n)))[0]
    wo, wi = d[:n], d[n:]
    for name, mat in MATERIALS.items():
        _, lob = lobes_for(mat, n)
        assert_close(bsdf.eval_pdf(lob, wo, wi)[0], bsdf.eval_pdf(lob, wi, wo)[0],
                     f"{name}: reciprocity", rtol=1e-9, atol=1e-15)


# ----------------------------------------------------------------------------
# lights.py

class LightCase:
    """A single emitter seen from p: its LightSet, the pdf of a direction,
    a cone (axis, theta_max) containing it and its exact solid angle."""

    def __init__(self, name):
        self.name = name
        self.p = np.array([0.0, 0.0, 0.0])
        meshes, instances, materials = (), (), ()
        light = None
        kind, rest = name.split("_", 1) if "_" in name else (name, "")
        if kind in ("sphere", "soft", "spot"):
            soft = rest.startswith("soft") or kind == "soft"
            pos, r = {"sphere": ((0.3, -0.2, 2.0), 0.5), "sphere_close": ((0.5, 0.4, 1.1), 1.0),
                      "sphere_far": ((3.0, -4.0, 8.0), 0.05), "soft_disk": ((0.2, 1.4, 0.5), 0.5),
                      "soft_disk_close": ((0.0, 0.1, 0.3), 0.25), "spot_sphere": ((1.0, 0.5, 1.5), 0.4),
                      "spot_soft": ((-1.0, 0.5, 1.5), 0.4)}[name]
            if kind == "spot":
                light = S.SpotLight(pos, (30.0, 20.0, 10.0), r, soft, direction=(-pos[0], 0.3, -1.0),
                                    spot_size=1.2, spot_blend=0.5)
            else:
                light = S.PointLight(pos, (30.0, 20.0, 10.0), r, soft)
            d = np.linalg.norm(pos)
            if soft:   # disk of radius r facing p: cone of tan = r / d
                omc = (r * r / (d * d + r * r)) / (1.0 + d / math.hypot(d, r))
            else:      # sphere: sin = r / d
                omc = (r * r / (d * d)) / (1.0 + math.sqrt(1.0 - r * r / (d * d)))
            self.axis, self.omc = unit(pos), omc
            self.solid_angle = TWO_PI * omc
        elif kind == "sun":
            angle = {"sun_real": 0.00918, "sun_wide": 0.3, "sun_huge": 2.5}[name]
            direction = unit((0.3, -0.2, -1.0))
            light = S.SunLight(direction, (3.0, 2.5, 2.0), angle)
            self.axis, self.omc = -direction, 2.0 * math.sin(angle / 4) ** 2
            self.solid_angle = TWO_PI * self.omc
        elif kind == "area":
            shape, sx, sy, center, emit, scale, roll = {
                "area_square": ("SQUARE", 1.0, 1.0, (0.5, 0.3, 2.0), (-0.3, 0.0, -1.0), (1, 1), 0.3),
                "area_square_close": ("SQUARE", 2.0, 2.0, (0.0, 0.0, 0.3), (0, 0, -1), (1, 1), 0.0),
                "area_rectangle": ("RECTANGLE", 2.0, 0.5, (-1.0, 1.0, 1.5), (0.8, -0.2, -1.0),
                                   (1.5, 0.7), 0.5),
                "area_disk": ("DISK", 1.2, 1.2, (1.0, 0.0, 1.0), (-1.0, 0.3, -0.6), (1, 1), 0.0),
                "area_ellipse": ("ELLIPSE", 1.5, 0.6, (0.0, -1.5, 1.0), (0.2, 1.0, -0.5),
                                 (1.2, 0.8), 1.0)}[name]
            m = area_matrix(np.array(center, float), emit, scale, roll)
            light = S.AreaLight(m, (40.0, 30.0, 20.0), shape, sx, sy)
            u, v = m[:3, 0] * sx, m[:3, 1] * (sx if shape in ("SQUARE", "DISK") else sy)
            c = np.array(center, float)
            if shape in ("DISK", "ELLIPSE"):
                t = np.linspace(0.0, TWO_PI, 20000, endpoint=False)
                boundary = c + 0.5 * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
            else:
                boundary = c + 0.5 * np.array([u + v, -u + v, -u - v, u - v])
            self.solid_angle = C.convex_polygon_solid_angle(self.p, boundary)
            self._bound(c, boundary)
        elif kind == "mesh":
            meshes, instances, materials = emissive_mesh_scene()
        else:
            raise ValueError(name)
        self.ls, self.tris, self.mats = make_light_set([light] if light else [], meshes, instances,
                                                       materials)
        self.emitter = 0
        if kind == "mesh":
            group = np.nonzero(self.tris.material == 0)[0]
            corners = np.concatenate([self.tris.p0[group], self.tris.p0[group] + self.tris.e1[group],
                                      self.tris.p0[group] + self.tris.e2[group]])
            self._bound(corners.mean(axis=0), corners)
            self.solid_angle = float(triangle_solid_angle_of(self.tris, group, self.p).sum())
            self.emitter = int(self.ls.emitter_of_triangle(0))
        self.kind = kind

    def _bound(self, center, boundary):
        """Axis to the centre; a cone 1% wider than the farthest boundary point."""
        self.axis = unit(center - self.p)
        rays = np.asarray(boundary, float) - self.p
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        _, theta = C.to_phi_theta(rays, C.frame(self.axis))
        self.omc = float(C.w_of_theta(min(np.pi, 1.01 * theta.max())))

    def sample(self, n, seed):
        u1, u2, u3 = uniforms(seed, 3, n)
        return self.ls.sample(np.full(n, self.emitter), np.tile(self.p, (n, 1)), u1, u2, u3)

    def pdf(self, d):
        """Solid-angle pdf (and radiance) of direction(s) d from p, by what a
        BSDF ray sees: intersect, sun_hits, or the emissive triangle hit."""
        n = len(d)
        o = np.tile(self.p, (n, 1))
        if self.kind == "sun":
            ((mask, emitter, Le, pdf),) = self.ls.sun_hits(d)
            assert emitter == self.emitter
            mask = np.broadcast_to(mask, (n,))
            return np.where(mask, pdf, 0.0), np.broadcast_to(Le, (n, 3)), np.full(n, np.inf)
        if self.kind == "mesh":
            t, prim = ray_triangles(self.p, d, self.tris)
            hit = prim >= 0
            mine = hit & (self.ls.emitter_of_triangle(self.tris.material[np.maximum(prim, 0)])
                          == self.emitter)
            pdf = np.zeros(n)
            Le = np.zeros((n, 3))
            if mine.any():
                pr = prim[mine]
                p_hit = o[mine] + d[mine] * t[mine, None]
                pdf[mine] = self.ls.triangle_pdf(pr, o[mine], p_hit, self.tris.ng[pr])
                Le[mine] = self.mats.emission[self.tris.material[pr]]
            return pdf, Le, np.where(mine, t, np.inf)
        t, emitter, Le, pdf = self.ls.intersect(o, d, np.full(n, np.inf))
        mine = emitter == self.emitter
        return np.where(mine, pdf, 0.0), Le, np.where(mine, t, np.inf)


def triangle_solid_angle_of(tris, idx, p):
    a = tris.p0[idx] - p
    return C.triangle_solid_angle(a, a + tris.e1[idx], a + tris.e2[idx])


@pytest.mark.parametrize("name", LIGHTS)
def test_light_sampling(name):
    case = LightCase(name)
    s = case.sample(N, seed=300 + LIGHTS.index(name))
    assert np.all(np.isfinite(s.pdf)) and np.all(s.pdf > 0), f"{name}: samples without pdf"
    assert not s.delta.any()
    assert_unit(s.wi, name)

    # What a BSDF ray towards each sample sees: same emitter, distance, radiance, pdf.
    pdf, Le, t = case.pdf(s.wi)
    assert_close(pdf, s.pdf, f"{name}: pdf of intersect/sun_hits/triangle_pdf vs LightSet.sample")
    # (absolute tolerance: a spot's smoothstep near its edge amplifies rounding)
    assert_close(Le, s.Le, f"{name}: radiance seen by a ray vs LightSet.sample",
                 atol=FP_RTOL * np.abs(s.Le).max())
    assert_close(t, s.dist, f"{name}: hit distance vs sampled distance")

    fr = C.frame(case.axis)
    res = direction_chi2(s.wi, lambda v: case.pdf(v)[0], fr, uniform_phi_edges(),
                         cone_theta_edges(case.omc), N)
    assert_chi2(res, f"light {name}")
    assert_mean(1.0 / s.pdf, case.solid_angle, f"{name}: mean(1/pdf) vs solid angle")


def test_delta_lights():
    p = np.array([[0.2, -0.1, 0.3], [1.0, 2.0, -1.0]])
    pos = np.array([0.5, 0.5, 2.0])
    sun_dir = unit((0.3, -0.2, -1.0))
    spot = S.SpotLight(tuple(pos), (8.0, 4.0, 2.0), 0.0, direction=(0.0, 0.0, -1.0),
                       spot_size=2.0, spot_blend=1.0)
    ls, _, _ = make_light_set([S.PointLight(tuple(pos), (8.0, 4.0, 2.0), 0.0), spot,
                               S.SunLight(sun_dir, (3.0, 2.0, 1.0), 0.0)])
    n = len(p)
    for e in range(3):
        s = ls.sample(np.full(n, e), p, *uniforms(9, 3, n))
        assert np.all(s.delta) and np.all(s.pdf == 1.0)
        if e < 2:
            d = pos - p
            dist = np.linalg.norm(d, axis=1)
            assert_close(s.wi, d / dist[:, None], "point light direction")
            assert_close(s.dist, dist, "point light distance")
            le = np.array([8.0, 4.0, 2.0]) / (4 * np.pi) / dist[:, None] ** 2
            if e == 1:
                cos = d[:, 2] / dist          # light axis (0, 0, -1) . (p - pos) / dist
                half = 1.0
                x = np.clip((cos - math.cos(half)) / ((1 - math.cos(half)) * 1.0), 0, 1)
                le = le * (x * x * (3 - 2 * x))[:, None]
            assert_close(s.Le, le, "delta point/spot intensity / d^2")
        else:
            assert_close(s.wi, np.tile(-sun_dir, (n, 1)), "delta sun direction")
            assert_close(s.Le, np.tile([3.0, 2.0, 1.0], (n, 1)), "delta sun irradiance")
    t, emitter, _, _ = ls.intersect(p, np.tile(unit(pos), (n, 1)), np.full(n, np.inf))
    assert np.all(np.isinf(t)) and np.all(emitter == -1)
    assert ls.sun_hits(np.tile(-sun_dir, (n, 1))) == []


def test_area_light_seen_from_behind():
    """One-sided area lights: no NEE sample and no ray hit from behind."""
    for shape in ("SQUARE", "DISK"):
        ls, _, _ = make_light_set([S.AreaLight(area_matrix(np.array([0.0, 0.0, 2.0]), (0, 0, 1)),
                                               (5.0, 5.0, 5.0), shape, 1.0)])
        n = 1000
        p = np.zeros((n, 3))
        s = ls.sample(np.zeros(n, int), p, *uniforms(13, 3, n))
        assert np.all(s.pdf == 0), shape
        t, emitter, _, pdf = ls.intersect(p, s.wi, np.full(n, np.inf))
        assert np.all(np.isinf(t)) and np.all(emitter == -1) and np.all(pdf == 0), shape


def test_light_ray_consistency_in_a_shared_set():
    """Several emitters in one LightSet, in separate directions from p: a ray
    towards each NEE sample hits the sampled emitter (global index) with the
    same pdf and radiance."""
    meshes, instances, materials = emissive_mesh_scene()
    sun_dir = unit((1.0, 1.0, -1.0))
    lts = [S.PointLight((0.0, 0.0, 5.0), (10.0, 10.0, 10.0), 0.5),
           S.PointLight((5.0, 0.0, 0.0), (10.0, 5.0, 1.0), 0.7, soft_falloff=True),
           S.SpotLight((0.0, -5.0, 0.0), (20.0, 20.0, 20.0), 0.3, direction=(0, 1, 0.1)),
           S.SunLight(sun_dir, (2.0, 2.0, 2.0), 0.1),
           S.AreaLight(area_matrix(np.array([0.0, 5.0, 0.0]), (0, -1, 0)), (5.0, 5.0, 5.0), "SQUARE", 2.0),
           S.AreaLight(area_matrix(np.array([-5.0, 0.0, 0.5]), (1, 0, 0)), (5.0, 5.0, 5.0), "DISK", 1.0)]
    ls, tris, mats = make_light_set(lts, meshes, instances, materials)
    p = np.array([0.0, 0.0, 0.0])
    n = 20000
    for e in range(ls.count):
        s = ls.sample(np.full(n, e), np.tile(p, (n, 1)), *uniforms(10 + e, 3, n))
        assert np.all(s.pdf > 0)
        kind = ls.kind[e]
        if kind == lights.SUN:
            hits = [h for h in ls.sun_hits(s.wi) if h[1] == e]
            assert len(hits) == 1 and np.all(hits[0][0])
            assert_close(np.broadcast_to(hits[0][3], (n,)), s.pdf, "sun pdf in a shared set")
            continue
        if kind == lights.MESH:
            t, prim = ray_triangles(p, s.wi, tris)
            assert np.all(prim >= 0)
            assert np.all(ls.emitter_of_triangle(tris.material[prim]) == e)
            pdf = ls.triangle_pdf(prim, np.tile(p, (n, 1)), p + s.wi * t[:, None], tris.ng[prim])
            assert_close(pdf, s.pdf, "triangle pdf in a shared set")
            assert_close(mats.emission[tris.material[prim]], s.Le, "triangle radiance")
            continue
        t, emitter, Le, pdf = ls.intersect(np.tile(p, (n, 1)), s.wi, np.full(n, np.inf))
        assert np.all(emitter == e), f"emitter {e}: rays hit {np.unique(emitter)}"
        assert_close(pdf, s.pdf, f"emitter {e}: intersect pdf vs sample pdf")
        assert_close(Le, s.Le, f"emitter {e}: intersect Le vs sample Le", atol=FP_RTOL * np.abs(s.Le).max())
        assert_close(t, s.dist, f"emitter {e}: distance")


def _selection_scene():
    meshes, instances, materials = emissive_mesh_scene()
    lts = [S.PointLight((1.0, 2.0, 3.0), (10.0, 10.0, 10.0), 0.1),
           S.SpotLight((0.0, 0.0, 4.0), (30.0, 5.0, 1.0), 0.2),
           S.SunLight((0.0, 0.0, -1.0), (3.0, 3.0, 2.0), 0.01),
           S.AreaLight(area_matrix(np.array([0.0, 0.0, 3.0]), (0, 0, -1)), (100.0, 80.0, 60.0), "SQUARE", 0.5),
           S.AreaLight(area_matrix(np.array([2.0, 0.0, 3.0]), (0, 0, -1), (1.0, 2.0)), (5.0, 5.0, 5.0),
                       "ELLIPSE", 2.0, 1.0, normalize=False)]
    return lts, meshes, instances, materials


def test_light_selection():
    lts, meshes, instances, materials = _selection_scene()
    # Selection weighs the mean of the RGB power (Cycles' light tree: average(strength)).
    lum = lambda c: float(np.mean(c))  # noqa: E731
    (u,) = uniforms(11, 1)
    for strategy in ("power", "uniform"):
        ls, tris, mats = make_light_set(lts, meshes, instances, materials, strategy)
        assert ls.count == 7
        if strategy == "power":
            # Emitted flux (Cycles units), independently of the engine's code.
            lo = tris.p0.min(axis=0)
            hi = tris.p0.max(axis=0)
            radius = max(1.0, 0.5 * float(np.linalg.norm(hi - lo)))
            area_ell = 2.0 * 2.0 * 1.0 * np.pi / 4          # scaled ELLIPSE, diameters 2x2 by 1
            groups = [tris.area[tris.material == m].sum() for m in (0, 1)]
            power = np.array([lum((10, 10, 10)), lum((30, 5, 1)), lum((3, 3, 2)) * np.pi * radius ** 2,
                              lum((100, 80, 60)), lum((5, 5, 5)) * area_ell,
                              lum((2.0, 1.0, 0.5)) * 2 * np.pi * groups[0],
                              lum((0.3, 0.3, 0.3)) * 2 * np.pi * groups[1]])
            pmf = power / power.sum()
        else:
            pmf = np.full(7, 1.0 / 7)
        assert_close(ls.dist.pmf, pmf, f"{strategy}: selection pmf")
        idx, p = ls.select(u)
        assert_close(p, pmf[idx], f"{strategy}: returned selection probability")
        assert_close(ls.selection_pdf(idx), p, f"{strategy}: selection_pdf")
        assert_chi2(C.chi2_test(np.bincount(idx, minlength=7), N * pmf), f"light selection {strategy}")
    ls, _, _ = make_light_set(lts, meshes, instances, materials, "all")
    assert np.all(ls.selection_pdf(np.arange(7)) == 1.0)


# ----------------------------------------------------------------------------
# camera.py

def cycles_filter(kind, width, x):
    """Cycles' filter functions (kernel film filter table), unnormalized."""
    if kind == "BOX":
        return np.ones_like(x)
    if kind == "GAUSSIAN":
        return np.exp(-2.0 * (x * 6.0 / (3.0 * width)) ** 2)
    v = TWO_PI * (x / (2.0 * width) + 0.5)
    return 0.35875 - 0.48829 * np.cos(v) + 0.14128 * np.cos(2 * v) - 0.01168 * np.cos(3 * v)


@pytest.mark.parametrize("kind,width", FILTERS)
def test_pixel_filter_guide_table_is_the_inverse_cdf(kind, width):
    """The guide-table lookup returns np.interp's inverse CDF bit for bit,
    tails and bin edges included."""
    f = camera.PixelFilter(kind, width)
    u = np.concatenate([np.random.default_rng(7).random(200000), np.linspace(0.0, 1.0, 20001)[:-1],
                        0.5 * f.cdf, 0.5 + 0.5 * f.cdf[:-1], [np.nextafter(0.5, 0.0), np.nextafter(1.0, 0.0)]])
    v = np.where(u < 0.5, 2.0 * u, 2.0 * u - 1.0)
    expected = np.where(u < 0.5, -1.0, 1.0) * np.interp(v, f.cdf, f.edges)
    np.testing.assert_array_equal(f.sample(u), expected)


@pytest.mark.parametrize("kind,width", FILTERS)
def test_pixel_filter(kind, width):
    f = camera.PixelFilter(kind, width)
    # Cycles' filter supports: box width / 2, Gaussian 1.5 width, Blackman-Harris width.
    radius = {"BOX": 0.5 * width, "GAUSSIAN": 1.5 * width, "BLACKMAN_HARRIS": width}[kind]
    assert f.radius == pytest.approx(radius, rel=1e-15)
    # The density follows Cycles' filter function (on the table's midpoints).
    x = 0.5 * (f.edges[:-1] + f.edges[1:])
    ratio = f.pdf(x) / cycles_filter(kind, width, x)
    assert_close(ratio, ratio[0], f"{kind}: pdf shape vs Cycles' filter")
    assert np.all(f.pdf(np.array([-radius * 1.001, radius * 1.001])) == 0)

    (u,) = uniforms(400 + FILTERS.index((kind, width)), 1)
    xs = f.sample(u)
    assert np.all(np.abs(xs) <= radius)
    edges = np.linspace(-radius, radius, 102)
    counts = np.histogram(xs, edges)[0]
    expected = N * C.integrate_1d(f.pdf, edges)
    assert_chi2(C.chi2_test(counts, expected), f"pixel filter {kind} {width}")
    # E[1_A / pdf] = |A| for any A inside the support.  A = the full support
    # would put the Gaussian's and Blackman-Harris' 1e-8 tails into the mean:
    # a variance the samples cannot estimate.  Take A = {filter >= 1% of its
    # peak} = [-a, a] (the filters decrease in |x|).
    lo, hi = 0.0, radius
    if kind != "BOX":
        peak = cycles_filter(kind, width, np.array([0.0]))[0]
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if cycles_filter(kind, width, np.array([mid]))[0] >= 0.01 * peak else (lo, mid)
    inside = np.abs(xs) <= lo
    assert_mean(np.where(inside, 1.0 / f.pdf(xs), 0.0), 2 * lo, f"{kind} {width}: mean(1_A/pdf) vs |A|")
