"""Helpers of the sampling chi-square tests (a helper module: test modules
do not import each other): direction histograms against a pdf, float
agreement, light sets and area-light matrices."""
import math

import numpy as np

import chi2 as C
from engine import bsdf, geometry, lights
from engine import scene as S

RES = 31                # cells per axis (odd, as Mitsuba)
FP_RTOL = 1e-9          # agreement of two float64 computations of one quantity
TWO_PI = 2.0 * np.pi


def assert_close(a, b, what, rtol=FP_RTOL, atol=0.0):
    a, b = np.asarray(a, float), np.asarray(b, float)
    bad = ~np.isclose(a, b, rtol=rtol, atol=atol)
    if bad.any():
        i = np.argwhere(bad)[0]
        raise AssertionError(f"{what}: {int(bad.sum())} mismatches, first at {tuple(i)}: "
                             f"{a[tuple(i)]!r} vs {b[tuple(i)]!r}")


def assert_unit(d, what):
    assert_close(np.linalg.norm(d, axis=1), 1.0, f"{what}: |d| != 1", rtol=0, atol=1e-12)


def direction_chi2(dirs, pdf_fn, fr, phi_edges, theta_edges, n_total, rest=None):
    """Chi-square of directions against a solid-angle pdf on a (phi, theta)
    grid about the axis of ``fr``.

    ``dirs`` are the valid samples out of ``n_total`` drawn.  With
    ``rest=None`` every sample must fall inside the grid; otherwise ``rest``
    samples (invalid or delta) plus those outside the grid form one more cell
    whose expected count is the pdf mass the grid misses."""
    phi, theta = C.to_phi_theta(dirs, fr, phi_edges[0])
    counts, outside = C.histogram2d(phi, theta, phi_edges, theta_edges)

    def density(ph, th):
        return pdf_fn(C.from_phi_theta(ph, th, fr)) * np.sin(th)

    mass = C.integrate_cells(density, phi_edges, theta_edges, periodic_x=True)
    # A sliver of the support (the tip of a light's corner) can slip between
    # all the nodes of a cell: integrate cells that got samples but no mass
    # again, much finer.  Still no mass there = samples where the pdf is 0.
    mass = C.refine_cells(density, phi_edges, theta_edges, mass, (mass == 0) & (counts > 0), 512)
    expected = n_total * mass
    obs, exp = counts.ravel(), expected.ravel()
    if rest is None:
        assert outside == 0, f"{outside} samples outside the support of the pdf"
    else:
        obs = np.append(obs, rest + outside)
        exp = np.append(exp, max(n_total - exp.sum(), 0.0))
    return C.chi2_test(obs, exp)


def uniform_phi_edges(k=RES):
    return np.linspace(0.0, TWO_PI, k + 1)


def cone_theta_edges(one_minus_cos_max, k=RES, margin=1e-7):
    """Edges of equal solid angle up to the cone (slightly widened so that
    samples exactly on the boundary stay inside after rounding)."""
    return C.theta_of_w(np.linspace(0.0, one_minus_cos_max * (1.0 + margin), k + 1))


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def area_matrix(center, emit_dir, scale=(1.0, 1.0), roll=0.0):
    """Light-to-world matrix of an area light at ``center`` emitting along
    ``emit_dir`` (its local -Z), local X/Y scaled by ``scale``."""
    z = -unit(emit_dir)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = unit(np.cross(helper, z))
    y = np.cross(z, x)
    x, y = math.cos(roll) * x + math.sin(roll) * y, -math.sin(roll) * x + math.cos(roll) * y
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x * scale[0], y * scale[1], z, center
    return m


def make_light_set(light_list=(), meshes=(), instances=(), materials=(), strategy="power"):
    sc = S.Scene(meshes=list(meshes), instances=list(instances), materials=list(materials),
                 lights=list(light_list))
    tris = geometry.flatten(sc)
    mats = bsdf.MaterialTable(geometry.material_table(sc))
    return lights.LightSet(sc, tris, mats, strategy), tris, mats


def ray_triangles(o, d, tris):
    """Closest hit of rays (o, d) with a few triangles: t and prim (-1 = miss)."""
    n = len(d)
    best = np.full(n, np.inf)
    prim = np.full(n, -1)
    for k in range(len(tris)):
        e1, e2 = tris.e1[k], tris.e2[k]
        pvec = np.cross(d, e2)
        det = pvec @ e1
        inv = 1.0 / np.where(np.abs(det) > 1e-300, det, 1.0)
        tvec = o - tris.p0[k]
        u = (pvec @ tvec) * inv
        qvec = np.cross(tvec, e1)
        v = (d @ qvec) * inv
        t = (qvec @ e2) * inv
        hit = (np.abs(det) > 1e-300) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < best)
        best[hit] = t[hit]
        prim[hit] = k
    return best, prim


def emissive_mesh_scene():
    """A quad (two triangles, facing the origin) and a triangle facing away
    from it in one emissive material, and a triangle in another."""
    pos = np.array([[-0.4, 0.2, 1.5], [0.6, 0.2, 1.5], [0.6, 1.0, 1.7], [-0.4, 1.0, 1.7],
                    [0.8, -0.5, 1.2], [1.4, -0.3, 1.3], [0.9, 0.1, 0.8],
                    [-2.0, -2.0, 1.0], [-1.5, -2.0, 1.0], [-2.0, -1.5, 1.0]])
    # Winding of triangle 2 makes its normal point away from the origin (two-sided emitter).
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [7, 8, 9]])
    mesh = S.Mesh(pos, tris, material_slots=np.array([0, 0, 0, 1]))
    mats = [S.Material("emit_a", (S.Lobe("diffuse"),), emission=(2.0, 1.0, 0.5)),
            S.Material("emit_b", (S.Lobe("diffuse"),), emission=(0.3, 0.3, 0.3))]
    return [mesh], [S.Instance(0, np.eye(4), [0, 1])], mats
