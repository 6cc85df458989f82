"""Tests that grow with the light registry (engine/lights/registry.py): every
registered light type's examples (``LightDef.examples``) and hostile inputs
(``LightDef.hostile``) run here, so a new type is tested the day it lands.

For each example: what NEE samples and what a BSDF ray towards the same
direction sees (intersect / sun_hits / environment_hits / triangle_pdf, by
the type's ``hit``) agree in pdf, radiance and distance to float rounding;
mean(1/pdf) is the light's solid angle and mean(Le cos / pdf) its irradiance
where the example knows them in closed form; the light's bounds hold every
sampled point and the directions it emits them along.  All mean tests form
one family of the suite budget (ember_stats.family_level, Sidak).
"""
import math

import numpy as np
import pytest

import ember_stats
from engine import bsdf, geometry, lights
from engine import scene as S
from engine.lights import registry
from engine.validate import validate_scene
from sampling_lib import FP_RTOL, assert_close, ray_triangles

N = 200_000
EXAMPLES = [(d, ex) for d in registry.ordered() for ex in d.examples()]
IDS = [f"{d.name}-{ex.label}" for d, ex in EXAMPLES]
HOSTILE = [(d, h) for d in registry.ordered() for h in d.hostile]
HOSTILE_IDS = [f"{d.name}-{h[0]}" for d, h in HOSTILE]
N_TESTS = sum(ex.solid_angle is not None for _, ex in EXAMPLES) + \
    3 * sum(ex.irradiance is not None for _, ex in EXAMPLES)
LEVEL = ember_stats.family_level(__name__, N_TESTS)
Z_MAX = ember_stats.z_threshold(LEVEL)


def light_set(example, strategy="power"):
    scene = example.scene()
    tris = geometry.flatten(scene)
    mats = bsdf.MaterialTable(geometry.material_table(scene))
    return lights.LightSet(scene, tris, mats, strategy), tris, mats


def nee(example, seed, n=N):
    ls, tris, mats = light_set(example)
    assert ls.count >= 1
    u = np.random.default_rng(seed).random((3, n))
    p = np.tile(np.asarray(example.p, float), (n, 1))
    return ls, tris, mats, p, ls.sample(np.zeros(n, np.int64), p, *u)


def seen_by_rays(definition, ls, tris, mats, p, wi):
    """(pdf, Le, t) a BSDF ray from p along wi finds of emitter 0, by the
    way the type's ``hit`` says rays find it."""
    n = len(p)
    pdf, Le, t = np.zeros(n), np.zeros((n, 3)), np.full(n, np.inf)
    if definition.hit == registry.RAY:
        th, emitter, le, pw = ls.intersect(p, wi, np.full(n, np.inf))
        mine = emitter == 0
        pdf[mine], Le[mine], t[mine] = pw[mine], le[mine], th[mine]
    elif definition.hit == registry.ESCAPE:
        for mask, emitter, le, pw in ls.sun_hits(wi):
            mine = np.broadcast_to(mask, (n,)) & (emitter == 0)
            pdf[mine], Le[mine] = pw, le
    elif definition.hit == registry.WORLD:
        emitter, le, pw = ls.environment_hits(wi)
        assert emitter == 0
        pdf, Le = pw, le
    else:
        th, prim = ray_triangles(p[0], wi, tris)
        mine = prim >= 0
        pr = prim[mine]
        pdf[mine] = ls.triangle_pdf(pr, p[mine], p[mine] + wi[mine] * th[mine, None], tris.ng[pr])
        Le[mine], t[mine] = mats.emission[tris.material[pr]], th[mine]
    return pdf, Le, t


def assert_z(values, target, what):
    values = np.asarray(values, float)
    mean = values.mean()
    se = values.std(ddof=1) / math.sqrt(len(values))
    if se <= FP_RTOL * abs(target):   # constant up to rounding: an identity
        assert mean == pytest.approx(target, rel=1e-9), f"{what}: {mean} != {target}"
        return
    z = (mean - target) / se
    print(f"z {what}: {z:.3f} (mean {mean:.6g}, exact {target:.6g}; detects "
          f"{ember_stats.detectable(se / abs(target), LEVEL):.3%} with probability 1/2)")
    assert abs(z) < Z_MAX, f"{what}: mean {mean:.7g} vs {target:.7g}, z = {z:.2f} (limit {Z_MAX:.2f})"


def test_registry_is_consistent():
    """Every scene light class is one registered type; kinds, orders and
    LightSet attributes are unique; exactly one type each is hit by the
    world and by surfaces (LightSet relies on it)."""
    defs = registry.ordered()
    for cls in (S.PointLight, S.SpotLight, S.SunLight, S.AreaLight):
        assert registry.definition_of(cls.__new__(cls)) is not None, cls
    for field in ("kind", "order", "attr", "name"):
        values = [getattr(d, field) for d in defs]
        assert len(set(values)) == len(values), field
    assert all(d.hit in registry.HITS for d in defs)
    assert sum(d.hit == registry.WORLD for d in defs) == 1
    assert sum(d.hit == registry.SURFACE for d in defs) == 1
    assert all(d.examples() for d in defs), "every type brings examples for these tests"


@pytest.mark.parametrize("definition, example", EXAMPLES, ids=IDS)
def test_sample_agrees_with_what_rays_see(definition, example):
    """The pdf, radiance and distance NEE reports for a sample equal what
    a BSDF ray towards it finds, to float rounding (MIS needs both sides of
    one direction to agree); delta samples are found by no ray."""
    ls, tris, mats, p, s = nee(example, seed=11 + IDS.index(f"{definition.name}-{example.label}"), n=20_000)
    assert np.all(np.isfinite(s.pdf)) and np.all(np.isfinite(s.Le)) and np.all(s.pdf >= 0)
    ok = s.pdf > 0
    assert ok.mean() > 0.5, "the example should face its shading point"
    assert_close(np.linalg.norm(s.wi[ok], axis=1), 1.0, "unit directions", rtol=0, atol=1e-12)
    pdf, Le, t = seen_by_rays(definition, ls, tris, mats, p, s.wi)
    if s.delta.any():
        assert s.delta.all() and np.all(s.pdf == 1.0)
        assert np.all(pdf == 0), "no BSDF ray may hit a delta light"
        return
    assert_close(pdf[ok], s.pdf[ok], f"{definition.name}: pdf of the ray vs the sample's")
    assert_close(Le[ok], s.Le[ok], f"{definition.name}: radiance", atol=FP_RTOL * np.abs(s.Le).max())
    if definition.hit in (registry.RAY, registry.SURFACE):
        assert_close(t[ok], s.dist[ok], f"{definition.name}: distance")
    else:
        assert np.all(np.isinf(s.dist))


SOLID = [(d, ex) for d, ex in EXAMPLES if ex.solid_angle is not None]


@pytest.mark.parametrize("definition, example", SOLID, ids=[f"{d.name}-{ex.label}" for d, ex in SOLID])
def test_mean_inverse_pdf_is_the_solid_angle(definition, example):
    *_, s = nee(example, seed=101 + SOLID.index((definition, example)))
    inv = np.where(s.pdf > 0, 1.0 / np.where(s.pdf > 0, s.pdf, 1.0), 0.0)
    assert_z(inv, example.solid_angle, f"{definition.name} {example.label}: mean(1/pdf)")


LIT = [(d, ex) for d, ex in EXAMPLES if ex.irradiance is not None]


@pytest.mark.parametrize("definition, example", LIT, ids=[f"{d.name}-{ex.label}" for d, ex in LIT])
def test_irradiance(definition, example):
    """mean(Le cos / pdf) of NEE samples is the light's irradiance (delta
    lights: Le cos, their intensity over d^2, exactly)."""
    *_, s = nee(example, seed=201 + LIT.index((definition, example)))
    cos = np.maximum(s.wi @ np.asarray(example.normal, float), 0.0)
    est = np.where((s.pdf > 0)[:, None], s.Le * (cos / np.where(s.pdf > 0, s.pdf, 1.0))[:, None], 0.0)
    for c in range(3):
        assert_z(est[:, c], example.irradiance[c], f"{definition.name} {example.label}: irradiance[{c}]")


@pytest.mark.parametrize("definition, example", EXAMPLES, ids=IDS)
def test_bounds_contain_the_light(definition, example):
    """The light tree's bounds of the emitter hold every point NEE samples
    on it, and its orientation cone the direction it emits each towards p;
    lights without a position (suns, the world) have none."""
    ls, _, _, p, s = nee(example, seed=301, n=20_000)
    (b,) = ls.emitter_bounds()[:1]
    if definition.hit in (registry.ESCAPE, registry.WORLD):
        assert b is None
        return
    assert b is not None and b.phi > 0
    ok = (s.pdf > 0) & np.isfinite(s.dist)
    q = p[ok] + s.wi[ok] * s.dist[ok, None]
    slack = 1e-9 * (1.0 + np.abs(q).max())
    assert np.all(q >= b.lo - slack) and np.all(q <= b.hi + slack), "a sampled point outside the box"
    lit = ok & (np.abs(s.Le).max(axis=1) > 0)
    out = -s.wi[lit]                                   # from the light towards p
    cos = out @ b.w
    if b.two_sided:
        cos = np.abs(cos)
    spread = math.acos(min(1.0, b.cos_o)) + math.acos(max(-1.0, min(1.0, b.cos_e)))
    assert np.all(cos >= math.cos(min(math.pi, spread)) - 1e-9), "light emitted outside the bounds' cone"


@pytest.mark.parametrize("definition, hostile", HOSTILE, ids=HOSTILE_IDS)
def test_hostile_input_is_a_clear_error(definition, hostile):
    """Each type's hostile inputs (NaN, negative, zero or unknown values)
    are a ValueError (SceneError) naming what is wrong, raised by the scene
    validation before anything renders."""
    label, mutate, message = hostile
    scene = definition.examples()[0].scene()
    validate_scene(scene)                              # the example itself is valid
    mutate(scene)
    with pytest.raises(ValueError, match=message):
        validate_scene(scene)
