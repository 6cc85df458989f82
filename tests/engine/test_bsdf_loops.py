"""The layered BSDF's compiled per-ray loops (engine/bsdf_loops.py) against
their NumPy reference forms (engine/bsdf.py), within rounding
(tests/engine/rounding.py), on random lobes of every
kind: sheen, coats with absorption, glass and refraction (rough and smooth,
back faces, IORs below 1), multiscatter GGX, every Fresnel mode with and
without a thin film (engine/thinfilm.py; thicknesses under 1 nm too), empty
(NONE) slots, moved normals (bump shadowing), directions on both sides and
grazing ones.
"""
import numpy as np
import pytest

from engine import bsdf, kernels
from engine.bsdf import (DIFFUSE, GLASS, GLOSSY, GLOSSY_ANISOTROPIC, Lobes, MIN_ALPHA, MIRROR, NONE, REFRACTION,
                         SHEEN, TRANSLUCENT, TRANSPARENT)
from engine.lobe_ids import HAIR_CHIANG, HAIR_REFLECTION, HAIR_TRANSMISSION, OREN_NAYAR
from test_kernels import assert_agree, both_ways, compiled_ready

KINDS = np.array([NONE, DIFFUSE, MIRROR, GLOSSY, GLASS, REFRACTION, TRANSLUCENT, TRANSPARENT, SHEEN,
                  GLOSSY_ANISOTROPIC, OREN_NAYAR, HAIR_CHIANG, HAIR_REFLECTION, HAIR_TRANSMISSION], np.int8)


def random_lobes(rng, n, k=4, bump=False):
    kind = rng.choice(KINDS, (n, k))
    kind[: n // 4, 0] = GLOSSY       # a Principled-like stack on a quarter of the rays
    kind[: n // 4, 1] = SHEEN
    kind[: n // 4, 2] = DIFFUSE
    layer = (kind == GLOSSY) | (kind == SHEEN)
    covers = np.where(layer, rng.integers(0, k, (n, k)), 0).astype(np.int8)
    covers = np.minimum(covers, k - 1 - np.arange(k)).astype(np.int8)
    alpha = rng.random((n, k)) ** 2
    alpha[rng.random((n, k)) < 0.1] = MIN_ALPHA
    alpha = np.maximum(alpha, MIN_ALPHA)
    multiscatter = rng.random((n, k)) < 0.4
    lobes = Lobes(kind, rng.random((n, k, 3)) * 1.2, alpha, np.zeros((n, k), bool),
                  fresnel=rng.integers(0, 4, (n, k)).astype(np.int8),
                  ior=rng.uniform(0.4, 3.0, (n, k)), f0=rng.random((n, k, 3)),
                  edge_tint=rng.random((n, k, 3)), transmission_tint=rng.random((n, k, 3)),
                  multiscatter=multiscatter, covers=covers, absorb=rng.random((n, k, 3)),
                  weight=rng.uniform(0.0, 1.2, (n, k)), back=rng.random(n) < 0.3,
                  anisotropy=rng.uniform(-0.1, 1.15, (n, k)), rotation=rng.uniform(-2.0, 2.0, (n, k)),
                  diffuse_roughness=rng.uniform(-0.1, 1.1, (n, k)),
                  absorption=rng.random((n, k, 3)) * 3.0, radial_roughness=rng.uniform(-0.1, 1.1, (n, k)),
                  coat=rng.uniform(-0.1, 1.1, (n, k)), offset=rng.uniform(-0.2, 0.2, (n, k)),
                  # thin films on half the slots (some under the 0.1 nm cutoff or 1 nm), film IORs below 1 too
                  thin_film_thickness=np.where(rng.random((n, k)) < 0.5, rng.uniform(0.0, 1200.0, (n, k))
                                               * np.where(rng.random((n, k)) < 0.1, 1e-3, 1.0), 0.0),
                  thin_film_ior=rng.uniform(0.7, 2.2, (n, k)))
    if bump:
        s = rng.normal(size=(n, 3)) + np.array([0.0, 0.0, 2.0])
        lobes.smooth_n = s / np.linalg.norm(s, axis=1)[:, None]
        lobes.bump_model = rng.integers(0, 2, n).astype(np.int8)
    return lobes


def directions(rng, n):
    wo = rng.normal(size=(n, 3))
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    wo[: n // 2, 2] = np.abs(wo[: n // 2, 2])         # mostly above the surface
    wo[n // 2: n // 2 + 50] = (1.0, 0.0, 0.0)          # grazing
    wo[n // 2 + 50: n // 2 + 60] = (0.0, 0.0, 1.0)     # normal incidence (flat sheen frame)
    wi = rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    mirror = rng.random(n) < 0.2                     # near the specular direction
    wi[mirror] = wo[mirror] * (-1.0, -1.0, 1.0) + rng.normal(size=(mirror.sum(), 3)) * 0.05
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    return wo, wi


@pytest.fixture(scope="module")
def jit():
    compiled_ready()
    loops = (bsdf._weights_kernel, bsdf._selection_kernel, bsdf._eval_pdf_kernel, bsdf._sample_kernel,
             bsdf._finish_kernel)
    assert all(k.compiled is not None for k in loops)   # the compiled forms are what is compared
    yield
    kernels.configure(True)


@pytest.mark.parametrize("bump", [False, True])
def test_weights_selection_eval_agree(jit, bump):
    rng = np.random.default_rng(7 + bump)
    n = 20000
    lobes = random_lobes(rng, n, bump=bump)
    wo, wi = directions(rng, n)
    plain_w, compiled_w = both_ways(bsdf.weights, lobes, wo)
    assert_agree(plain_w, compiled_w)
    w = plain_w[0]
    assert np.isfinite(w).all() and (w >= 0).all()
    assert_agree(*both_ways(bsdf.selection, lobes, wo, w))
    sel = bsdf.selection(lobes, wo, w)
    for sampled in (False, True):
        plain, compiled = both_ways(lambda *a: bsdf.eval_pdf(*a, sampled=sampled), lobes, wo, wi, sel, w)
        assert_agree(plain, compiled)
        assert (plain[1] > 0).sum() > n // 4   # the lobes were evaluated, not skipped


@pytest.mark.parametrize("bump", [False, True])
def test_sample_agrees(jit, bump):
    """The lobe choice, the sampled direction of every lobe kind (smooth
    glass: delta samples), the weights and pdfs."""
    rng = np.random.default_rng(17 + bump)
    n = 20000
    lobes = random_lobes(rng, n, bump=bump)
    wo, _ = directions(rng, n)
    u = rng.random((n, 3))
    u[:100, 0] = 1.0 - 1e-16     # past a CDF rounded below 1
    plain, compiled = both_ways(bsdf.sample, lobes, wo, u[:, 0], u[:, 1], u[:, 2])
    assert_agree(plain, compiled)
    wi, weight, pdf, delta = plain
    assert delta.sum() > n // 20 and (~delta & (pdf > 0)).sum() > n // 4
    assert np.isfinite(weight).all() and np.isfinite(wi).all()


@pytest.mark.parametrize("kind", [DIFFUSE, MIRROR, GLOSSY, GLASS, REFRACTION, TRANSLUCENT, TRANSPARENT, SHEEN,
                                  HAIR_REFLECTION, HAIR_TRANSMISSION])
def test_each_lobe_kind_agrees(jit, kind):
    """One lobe kind at a time (the others emptied to NONE), so every branch
    of the loops is reached: evaluated with a nonzero pdf, or sampled."""
    rng = np.random.default_rng(30 + int(kind))
    n = 5000
    lobes = random_lobes(rng, n)
    lobes.kind = np.where(lobes.kind == kind, kind, NONE).astype(np.int8)
    lobes.kind[:, 0] = kind
    wo, wi = directions(rng, n)
    u = rng.random((n, 3))
    w = bsdf.weights(lobes, wo)
    sel = bsdf.selection(lobes, wo, w)
    plain, compiled = both_ways(bsdf.eval_pdf, lobes, wo, wi, sel, w)
    assert_agree(plain, compiled)
    sampled = both_ways(bsdf.sample, lobes, wo, u[:, 0], u[:, 1], u[:, 2], sel, w)
    assert_agree(*sampled)
    wi_s, weight, pdf, delta = sampled[0]
    if kind in (MIRROR, TRANSPARENT):
        assert delta[wo[:, 2] > 0].all()
    else:
        assert (plain[1] > 0).sum() > n // 20 and (~delta & (pdf > 0)).sum() > n // 20
    if kind in (GLASS, REFRACTION, TRANSLUCENT, TRANSPARENT, HAIR_TRANSMISSION):
        assert (wi_s[:, 2] < 0).sum() > n // 20     # transmitted samples


def test_read_only_and_strided_inputs(jit):
    """Read-only lobe arrays and strided directions (a texture stage's or a
    caller's views) are copied for the loops, not refused."""
    rng = np.random.default_rng(40)
    n = 2000
    lobes = random_lobes(rng, n)
    for name in ("kind", "color", "alpha", "f0", "back"):
        getattr(lobes, name).setflags(write=False)
    wo, wi = directions(rng, n)
    wo6 = np.repeat(wo, 2, axis=1)[:, ::2]      # rows with a stride of 6 values
    wo.setflags(write=False)
    u = rng.random((n, 3))
    assert_agree(*both_ways(bsdf.weights, lobes, wo6))
    np.testing.assert_array_equal(bsdf.weights(lobes, wo6), bsdf.weights(lobes, wo))
    assert_agree(*both_ways(bsdf.eval_pdf, lobes, wo, wi))
    assert_agree(*both_ways(bsdf.sample, lobes, wo, u[:, 0], u[:, 1], u[:, 2]))


def test_gather_agrees(jit):
    """MaterialTable.gather's compiled copy gives np.take's lobes."""
    from engine.scene import Lobe, Material
    materials = [Material("a", [Lobe("glossy", (0.8, 0.5, 0.2), 0.3, fresnel="f82", covers=1),
                                Lobe("diffuse", (0.1, 0.2, 0.3), 0.0)]),
                 Material("b", [Lobe("glass", (1.0, 1.0, 1.0), 0.1, ior=1.45, multiscatter=True)]),
                 Material("c", [Lobe("sheen", (0.5, 0.5, 0.5), 0.5, covers=2), Lobe("glossy", (1, 1, 1), 0.2),
                                Lobe("translucent", (0.3, 0.6, 0.9), 0.0, weight=0.5)])]
    table = bsdf.MaterialTable(materials)
    mat = np.random.default_rng(3).integers(0, 3, 5000)
    kernels.configure(False)
    plain = table.gather(mat)
    kernels.configure(True)
    compiled = table.gather(mat)
    for name in plain.__dataclass_fields__:     # copies: equal on any CPU
        a, b = getattr(plain, name), getattr(compiled, name)
        if a is None:
            assert b is None
        else:
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(compiled.covers[mat == 2, 0], 2)
