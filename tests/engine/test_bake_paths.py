"""engine/integrator/bake_paths.py and engine.bake.light_filter: the pass
filter as Cycles' closure filter, and the texels' sample positions
(exact checks, no statistics)."""
import numpy as np
import pytest

from engine.bake import light_filter
from engine.integrator.bake_paths import BakeFilter, _mirror
from engine.lobe_ids import (DIFFUSE, GLASS, GLOSSY, OREN_NAYAR, RAY_PORTAL, REFRACTION, SUBSURFACE_RANDOM_WALK,
                             TRANSLUCENT, TRANSPARENT)
from engine.lobes import kinds_of_class


def test_class_bakes_keep_their_lobes_as_cycles():
    diffuse = set(BakeFilter(("diffuse",), subsurface=True).dropped_kinds())
    assert {GLOSSY, GLASS, REFRACTION, TRANSPARENT} <= diffuse
    assert not diffuse & {DIFFUSE, OREN_NAYAR, TRANSLUCENT, SUBSURFACE_RANDOM_WALK}
    glossy = set(BakeFilter(("glossy",), subsurface=False).dropped_kinds())
    assert {DIFFUSE, REFRACTION, TRANSPARENT, SUBSURFACE_RANDOM_WALK} <= glossy
    assert GLOSSY not in glossy and GLASS not in glossy        # glass stays while glossy does
    transmission = set(BakeFilter(("transmission",), subsurface=False).dropped_kinds())
    assert GLASS not in transmission and REFRACTION not in transmission and GLOSSY in transmission
    everything = set(BakeFilter().dropped_kinds())
    # a bake sees the object itself: the lobes rays pass straight through
    # (Transparent, Ray Portal) are dropped at the texel, nothing else
    assert everything == set(kinds_of_class("transparent")) and {TRANSPARENT, RAY_PORTAL} <= everything


@pytest.mark.parametrize("kind,names,expect", [
    ('DIFFUSE', {'DIRECT', 'INDIRECT', 'COLOR'}, ("combined", True, True)),
    ('DIFFUSE', {'DIRECT'}, ("light", True, False)),
    ('GLOSSY', {'INDIRECT'}, ("light", False, True)),
    ('DIFFUSE', {'COLOR'}, ("color", False, False)),
    ('COMBINED', {'INDIRECT', 'DIFFUSE'}, ("combined", False, True)),
])
def test_light_filter_as_blenders_bake_setup(kind, names, expect):
    bake_filter, indirect, value = light_filter(kind, names)
    assert (value, bake_filter.direct, indirect) == expect
    if kind == 'COMBINED':
        assert bake_filter.classes == ("diffuse",) and not bake_filter.emission
    else:
        # A class bake leaves out the texel's own emission, not the others'.
        assert bake_filter.emission and not bake_filter.emits(0) and bake_filter.emits(1)


def test_light_filter_refuses_unknown_names():
    with pytest.raises(ValueError, match="AO"):
        light_filter('DIFFUSE', {'DIRECT', 'AO'})
    with pytest.raises(ValueError, match="SHADOW"):
        light_filter('SHADOW', {'DIRECT'})


def test_mirror_repeat_stays_in_range_and_is_cycles():
    x = np.linspace(-2.5, 2.5, 101)
    for top in (1.0, 0.3):
        m = _mirror(x, np.full_like(x, top))
        assert np.all((m >= 0) & (m <= top + 1e-12))
        inside = (x >= 0) & (x < top)
        assert np.allclose(m[inside], x[inside])
    assert np.isclose(_mirror(np.array([1.2]), 1.0)[0], 0.8)      # mirrored back, not wrapped
    assert np.isclose(_mirror(np.array([-0.1]), 1.0)[0], 0.1)


def test_jitter_stays_inside_the_triangle_as_cycles():
    """Cycles 3.5+'s bake_jitter_barycentric: a jitter outside the triangle
    is retried with hashed numbers, the centre kept after 10 misses; sample
    0 (not jittered) stays at the centre."""
    from engine.integrator.bake_paths import _jitter_inside
    rng = np.random.default_rng(3)
    n = 2000
    u, v = np.full(n, 0.05), np.full(n, 0.05)           # near a corner: most jitters leave the triangle
    d = np.tile([0.4, 0.0, 0.0, 0.4], (n, 1))
    jitter = np.arange(n) > 0
    ju, jv = _jitter_inside(u, v, d, jitter, rng.random(n), rng.random(n))
    moved = (ju != u) | (jv != v)
    assert ju[0] == u[0] and jv[0] == v[0]
    inside = (ju > 0) & (jv > 0) & (ju + jv < 1)
    assert inside.all()
    assert moved[1:].mean() > 0.9                      # the retries find the triangle's part of the texel
    assert np.all(np.abs(ju - u) <= 0.2 + 1e-12) and np.all(np.abs(jv - v) <= 0.2 + 1e-12)
    # Inside the texel's part of the triangle the positions are uniform: as many left as right of its middle.
    part = moved & (ju > 0.0) & (ju < 0.25)
    assert abs((ju[part] < 0.125).mean() - 0.5) < 0.05
    # A texel on a sliver of a triangle: every try misses, the centre is kept.
    su, sv = _jitter_inside(np.array([0.5]), np.array([1e-9]), np.array([[0.0, 0.0, 0.0, 1e3]]),
                            np.array([True]), np.array([0.9]), np.array([0.9]))
    assert (su[0], sv[0]) == (0.5, 1e-9)


def test_glossy_and_transmission_bakes_count_one_side_of_glass():
    assert light_filter('GLOSSY', {'DIRECT', 'INDIRECT', 'COLOR'})[0].glass_side == 1
    assert light_filter('TRANSMISSION', {'DIRECT'})[0].glass_side == -1
    assert light_filter('DIFFUSE', {'DIRECT'})[0].glass_side == 0
    assert light_filter('COMBINED', {'DIRECT', 'GLOSSY'})[0].glass_side == 0   # Cycles keeps glass whole there
