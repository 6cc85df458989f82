"""The Principled Hair BSDF's Chiang lobe (engine/lobes/hair.py) beyond what
tests/engine/test_lobe_registry.py checks for every lobe (sample vs eval,
chi-square, energy z-test; tests/engine/test_bsdf_loops.py: the compiled
branch against NumPy):

* white furnace: with no absorption the lobe conserves energy, its f |cos|
  integrates to 1 over the sphere for every view angle, offset h across the
  fibre and roughness (a deterministic quadrature in (sin theta, phi), where
  the solid angle is d sin theta d phi), and every sample's weight is 1;
* absorption only takes energy away;
* Cycles' parametrizations (svm_node_closure_bsdf): melanin and colour;
* rays leaving a strand pass all of it (Accel.intersect_skipping, Cycles' rule);
* a hair ball in a white world with no absorption renders white.
"""
import math

import numpy as np
import pytest

from engine import bsdf, embree_c
from engine import scene as S
from engine.lobes import hair
from engine.points import curve_hits, curve_rows

ROUGH = (0.15, 0.3, 0.7)
CELLS = 400   # per unit of sin theta (2 CELLS in phi): 1e-5 of the albedo at roughness 0.15


def lobes_for(n, **kw):
    table = bsdf.MaterialTable([S.Material("hair", (S.Lobe("hair_chiang", (1, 1, 1), **kw),))])
    return table.gather(np.zeros(n, np.int64))


def view(sin_o, h):
    """wo with longitudinal sine sin_o and offset h across the fibre (x the
    tangent, z the curve normal: h = -wo.y / |(wo.y, wo.z)|)."""
    c = math.sqrt(1.0 - sin_o * sin_o)
    return np.array([sin_o, -h * c, math.sqrt(1.0 - h * h) * c])


def albedo(roughness, sin_o, h, absorption=(0.0, 0.0, 0.0), cells=CELLS):
    """f |cos| integrated over the sphere by the midpoint rule in (sin theta_i, phi_i)."""
    s = (np.arange(cells) + 0.5) / cells * 2.0 - 1.0
    p = (np.arange(2 * cells) + 0.5) / (2 * cells) * 2.0 * np.pi - np.pi
    ss, pp = np.meshgrid(s, p, indexing="ij")
    c = np.sqrt(1.0 - ss * ss)
    wi = np.stack([ss.ravel(), (c * np.cos(pp)).ravel(), (c * np.sin(pp)).ravel()], axis=1)
    n = len(wi)
    lob = lobes_for(n, roughness=roughness, radial_roughness=roughness, ior=1.55, offset=math.radians(2.0),
                    absorption=absorption)
    f, _ = hair.eval_hair_f(lob, np.arange(n), 0, np.tile(view(sin_o, h), (n, 1)), wi)
    return (f * np.abs(wi[:, 2:3])).sum(axis=0) * (2.0 / cells) * (np.pi / cells)


@pytest.mark.parametrize("roughness", ROUGH)
def test_white_furnace(roughness):
    for sin_o, h in ((0.0, 0.0), (0.5, 0.6), (-0.8, -0.3)):
        a = albedo(roughness, sin_o, h)
        print(f"roughness {roughness} sin_o {sin_o} h {h}: albedo {a[0]:.5f}")
        # Cycles' Mp takes log 2 as 0.6931: 5e-5 short of 1
        assert np.allclose(a, 1.0, atol=1.5e-4), (roughness, sin_o, h, a)


def test_samples_weigh_one_without_absorption():
    rng = np.random.default_rng(5)
    n = 20000
    lob = lobes_for(n, roughness=0.3, radial_roughness=0.4, ior=1.55, offset=math.radians(2.0))
    wo = np.tile(view(0.3, 0.4), (n, 1))
    wi, weight, pdf, delta = bsdf.sample(lob, wo, rng.random(n), rng.random(n), rng.random(n))
    ok = pdf > 0
    assert ok.mean() > 0.99 and not delta.any()
    assert np.allclose(weight[ok], 1.0, rtol=1e-9)
    assert (wi[ok, 2] < 0).mean() > 0.3     # TT and TRT leave through the fibre


def test_absorption_takes_energy():
    clear = albedo(0.3, 0.2, 0.5, cells=200)
    dark = albedo(0.3, 0.2, 0.5, absorption=tuple(hair.sigma_from_melanin(0.6, 0.3, (1, 1, 1), 0.3)), cells=200)
    assert np.all(dark < clear) and np.all(dark > 0.03)
    assert dark[2] < dark[1] < dark[0]      # melanin absorbs blue most: brown


def test_parametrizations_are_cycles():
    m = -math.log(1.0 - 0.6)
    expect = m * 0.7 * hair.EUMELANIN + m * 0.3 * hair.PHEOMELANIN
    assert np.allclose(hair.sigma_from_melanin(0.6, 0.3, (1, 1, 1), 0.3), expect, rtol=1e-12)
    # Direct Coloring: Cycles' albedo estimate exp(-sqrt(sigma) scale) gives back the colour
    colour = np.array([0.6, 0.3, 0.1])
    sigma = hair.sigma_from_color(colour, 0.4)
    assert np.allclose(np.exp(-np.sqrt(sigma) * hair.albedo_roughness_scale(0.4)), colour, rtol=1e-12)
    # the remap saturates at melanin 1 (Cycles' 1e-4 floor)
    assert np.all(np.isfinite(hair.sigma_from_melanin(1.0, 0.5, (1, 1, 1), 0.3)))


@pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")
def test_rays_leaving_a_strand_pass_all_of_it():
    """Cycles' self-intersection rule for curves (kernel/device/cpu/bvh.h:
    a hair hit maps to its curve, and a ray leaving a curve skips it): rays
    from points on a curly strand A, into it or away from it, never meet A
    again; aimed at a straight strand B beside it they meet B; shadow rays
    stop at B and pass A.  Without the rule every ray into A meets
    A again (its far wall, or the curl)."""
    import importlib
    prepare = importlib.import_module("engine.render").prepare
    turns = np.linspace(0.0, 6.0 * np.pi, 40)
    curly = np.c_[0.05 * np.cos(turns), 0.05 * np.sin(turns), np.linspace(-0.6, 0.6, 40)]
    straight = np.c_[np.full(8, 0.4), np.zeros(8), np.linspace(-0.8, 0.8, 8)]
    points = np.concatenate([curly, straight])
    radii = np.r_[np.full(40, 0.03), np.full(8, 0.05)]
    curves = S.HairCurves(points, radii, np.array([0, 40, 48]), materials=[0])
    mat = S.Material("hair", (S.Lobe("diffuse", (0.5, 0.5, 0.5)),))
    scene = S.Scene(meshes=[], instances=[], materials=[mat], world=S.World(color=(0.0, 0.0, 0.0)),
                    camera=S.Camera(matrix=np.eye(4), resolution=(4, 4)), curves=[curves])
    ctx = prepare(scene, S.RenderSettings(samples=1))
    acc, strands = ctx.accel, ctx.strands
    rng = np.random.default_rng(11)
    n = 20000
    o = np.c_[np.full(n, -2.0), rng.uniform(-0.08, 0.08, n), rng.uniform(-0.5, 0.5, n)]
    t, prim, u, _ = acc.intersect(o, np.tile([1.0, 0.0, 0.0], (n, 1)), np.full(n, np.inf))
    on_a = np.flatnonzero((prim >= 0) & (points_curve(strands, prim) == 0))
    assert len(on_a) > 0.3 * n
    o, prim, u = o[on_a], prim[on_a], u[on_a]
    p, ng, _, _ = curve_hits(strands, o, np.tile([1.0, 0.0, 0.0], (len(o), 1)), t[on_a], prim, u)
    m = len(p)
    eps = np.full(m, 1e-5)
    skip = curve_rows(strands, prim)
    assert np.all(skip == 0)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    start = acc.offset_origin(p, ng, d, eps)
    into = np.einsum("ij,ij->i", d, ng) < 0
    _, plain, _, _ = acc.intersect(start, d, np.full(m, np.inf))
    again = (plain >= 0) & (points_curve(strands, plain) == 0)
    print(f"rays into the strand meeting it again without the rule: {again[into].mean():.1%}")
    assert again[into].mean() > 0.2
    _, passed, _, _ = acc.intersect_skipping(start, d, np.full(m, np.inf), skip)
    assert not np.any((passed >= 0) & (points_curve(strands, passed) == 0))
    # aimed at B's axis (straight through A when A is in the way): B, every time
    target = np.c_[np.full(m, 0.4), np.zeros(m), np.clip(p[:, 2], -0.5, 0.5)]
    d = target - p
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    start = acc.offset_origin(p, ng, d, eps)
    _, hit_b, _, _ = acc.intersect_skipping(start, d, np.full(m, np.inf), skip)
    assert np.all(points_curve(strands, hit_b) == 1)
    assert acc.occluded_skipping(start, d, dist, skip).all()              # B blocks its own axis
    assert not acc.occluded_skipping(start, d, dist - 0.06, skip).any()    # A does not block


def points_curve(strands, prim):
    return np.where(prim >= 0, strands.curve[np.maximum(prim, 0)], -1)


@pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")
def test_hair_ball_in_a_white_world_is_white():
    from engine.render import render
    from engine.testscenes import look_at
    rng = np.random.default_rng(3)
    roots = rng.normal(size=(300, 3))
    roots /= np.linalg.norm(roots, axis=1)[:, None]
    s = np.linspace(0.0, 1.0, 6)
    points = (roots[:, None, :] * (0.5 + 0.4 * s)[None, :, None]).reshape(-1, 3)
    curves = S.HairCurves(points, np.full(len(points), 0.012), np.arange(0, 6 * 300 + 1, 6), materials=[0])
    mat = S.Material("hair", (S.Lobe("hair_chiang", (1, 1, 1), 0.3, ior=1.55, radial_roughness=0.3,
                                     offset=math.radians(2.0)),))
    scene = S.Scene(meshes=[], instances=[], materials=[mat], world=S.World(color=(1.0, 1.0, 1.0)),
                    camera=S.Camera(matrix=look_at((0, -4, 1), (0, 0, 0)), resolution=(24, 18)), curves=[curves])
    img = render(scene, S.RenderSettings(samples=8, samples_per_pass=8, max_bounces=64, rr_depth=64)).image[..., :3]
    print("white world: mean", img.mean(), "min", img.min(), "max", img.max())
    assert np.isfinite(img).all()
    assert abs(img.mean() - 1.0) < 2e-3 and img.min() > 0.9
