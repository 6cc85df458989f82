"""The IES Texture node's file reading (engine/nodes/ies.py, as Cycles'
util/ies.cpp): the LM-63 numbers, Cycles' candela-to-watt factor, the
symmetric tables mirrored to the full turn, the 100 of a missing or
unreadable file; and the interpolation reproducing the table at its own
angles.  Against Cycles' pixels: tests/addon/test_ies_parity.py."""
import numpy as np

from engine.nodes import ies
from engine.nodes.context import ShadingContext
from engine.nodes.registry import REGISTRY


def lm63(kind, v, h, rows, multiplier=2.0, ballast=0.5):
    lines = ["IESNA:LM-63-2002", "TILT=NONE", f"1 1000 {multiplier} {len(v)} {len(h)} {kind} 2 0 0 0",
             f"{ballast} 1.0 60", " ".join(map(str, v)), " ".join(map(str, h))]
    return "\n".join(lines + [" ".join(map(str, r)) for r in rows]) + "\n"


def test_type_c_quadrant_is_mirrored_to_the_full_turn():
    rows = [[100, 50, 10], [80, 40, 8], [60, 30, 6]]
    h, v, table = ies.process(ies.parse(lm63(1, [0, 45, 90], [0, 45, 90], rows)))
    np.testing.assert_allclose(np.degrees(h), [0, 45, 90, 135, 180, 225, 270, 315, 360], atol=1e-4)
    np.testing.assert_allclose(np.degrees(v), [0, 45, 90], atol=1e-4)
    factor = 2.0 * 0.5 * 1.0 * ies.CANDELA_TO_WATT       # multiplier x ballast x ballast-lamp x 4 pi / 177.83
    order = [0, 1, 2, 1, 0, 1, 2, 1, 0]                   # 0-90 mirrored about 90, then about 180
    np.testing.assert_allclose(table, np.array(rows, float)[order] * factor, rtol=1e-6)


def test_interpolation_returns_the_table_at_its_angles():
    rows = [[100, 50, 10, 5], [80, 40, 8, 4], [60, 35, 6, 3]]
    table = ies.process(ies.parse(lm63(1, [0, 30, 60, 80], [0, 45, 90], rows)))
    h, v, values = table
    hh, vv = np.meshgrid(h[:-1], v[:-1], indexing="ij")
    got = ies.interpolate(table, hh.ravel().astype(np.float32), vv.ravel().astype(np.float32))
    np.testing.assert_allclose(got, values[:-1, :-1].ravel(), rtol=1e-5)
    # At and beyond the last vertical angle: no light.
    assert (ies.interpolate(table, np.float32([0.3, 1.0]), np.float32([v[-1], 3.0])) == 0).all()


def test_unreadable_files_give_cycles_missing_value():
    for text in ("", "garbage\n", lm63(1, [0, 45], [0], [[1, 2]])[:-8], lm63(5, [0, 45], [0], [[1, 2]])):
        assert ies.process(ies.parse(text)) is None
    entry = REGISTRY["ShaderNodeTexIES"]
    ctx = ShadingContext(3)
    out = entry.evaluate(ctx, {"Vector": np.tile([0.0, 0.0, -1.0], (3, 1)), "Strength": np.full(3, 0.5)},
                         {"ies_table": None})
    np.testing.assert_allclose(out["Fac"], 50.0)


def test_straight_down_reads_the_first_vertical_angle():
    """Cycles: v = acos(-z) of the normalized vector, so the light's -Z is v 0."""
    rows = [[100, 50, 10]]
    table = ies.process(ies.parse(lm63(1, [0, 45, 90], [0], rows)))
    entry = REGISTRY["ShaderNodeTexIES"]
    out = entry.evaluate(ShadingContext(1), {"Vector": np.array([[0.0, 0.0, -3.0]]), "Strength": np.ones(1)},
                         {"ies_table": tuple(np.asarray(t).tolist() for t in table)})
    np.testing.assert_allclose(out["Fac"], 100 * 2.0 * 0.5 * ies.CANDELA_TO_WATT, rtol=1e-6)
