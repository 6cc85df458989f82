"""Rough glass against a truth from outside Ember: Cycles' own precomputed
directional albedo of single-scatter GGX glass (issue 27).

``table_ggx_glass_E`` in intern/cycles/scene/shader.tables (blender/blender,
commit 09cf4924) is computed by intern/cycles/app/cycles_precompute.cpp with
Cycles' bsdf_microfacet_ggx_sample of a GGX glass closure (reflection and
refraction, dielectric Fresnel): 2^23 Sobol samples per entry (Monte Carlo
error below 1e-5), printed to 6 decimals.  The table is 16 x 16 x 16:
slice z (IOR = ior_from_F0(z^4), z = k / 15), row mu = y / 15, column
roughness = x / 15 (alpha = roughness^2), clamped to 1e-4.  The entries
below are at grid nodes, so no interpolation enters.

Ember computes its own tables (engine/data/build_tables.py), so a plane of
its single-scatter glass in a white furnace is checked against Cycles'
numbers, not against its own quadrature; its Multiscatter glass (Cycles 4+:
the single-scatter lobe scaled by 1 / E) must then render 1 at the nodes, as
Cycles' does up to its own table's error."""
import math
import os
import sys

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import ember_stats  # noqa: E402
from engine import scene as S  # noqa: E402
from engine.scene import Material  # noqa: E402
from analytic import furnace_plane  # noqa: E402

Z_SLICE = 7                                   # IOR = (1 + z^2) / (1 - z^2), z = 7 / 15
IOR = (1 + (Z_SLICE / 15) ** 2) / (1 - (Z_SLICE / 15) ** 2)   # 1.556818
# table_ggx_glass_E[z = 7][y][x] at these nodes: {(y, x): E}
CYCLES_GLASS_E = {(4, 5): 0.964266, (4, 10): 0.867724, (4, 15): 0.702937,
                  (9, 5): 0.993744, (9, 10): 0.925582, (9, 15): 0.765094,
                  (15, 5): 0.998420, (15, 10): 0.972038, (15, 15): 0.884305}
CYCLES_TABLE_ERROR = 1e-5 + 5e-7              # its Monte Carlo error and its rounding, as a bound
MULTISCATTER_NODES = [(4, 15), (9, 10), (15, 15)]
N_TESTS = len(CYCLES_GLASS_E) + len(MULTISCATTER_NODES)
LEVEL = ember_stats.family_level(__name__, N_TESTS)
Z_MAX = ember_stats.z_threshold(LEVEL)
SPP = 96


def furnace(lobe, mu):
    """A white glass plane (one interface: what it reflects and refracts
    meets the unit world) seen at cos(theta) = mu: image mean and its
    standard error."""
    r = furnace_plane(Material("glass", (lobe,)), mu, spp=SPP)
    img = r.image[..., 0].astype(np.float64)
    return img.mean(), math.sqrt(r.variance[..., 0].astype(np.float64).sum()) / img.size


def check(label, mean, se, expected):
    total_se = math.hypot(se, CYCLES_TABLE_ERROR)
    z = (mean - expected) / total_se
    print(f"{label}: rendered {mean:.5f} +- {se:.5f}, Cycles {expected:.6f}, z {z:+.2f} (limit {Z_MAX:.2f}); "
          f"detects {ember_stats.detectable(total_se, LEVEL) / expected:.3%} with probability 1/2")
    assert abs(z) < Z_MAX


@pytest.mark.parametrize("y,x", sorted(CYCLES_GLASS_E))
def test_single_scatter_glass_albedo_is_cycles_table(y, x):
    """Single-scatter GGX glass (IOR 1.5568) reflects and transmits Cycles'
    E(mu, roughness, IOR) of the whole lobe."""
    lobe = S.Lobe("glass", (1, 1, 1), x / 15, ior=IOR)
    mean, se = furnace(lobe, max(y / 15, 1e-4))
    check(f"glass roughness {x}/15 mu {y}/15", mean, se, CYCLES_GLASS_E[(y, x)])


@pytest.mark.parametrize("y,x", MULTISCATTER_NODES)
def test_multiscatter_glass_keeps_energy_at_cycles_nodes(y, x):
    """Multiscatter GGX glass divides the single-scatter lobe by E: where
    Cycles' table is exact (its nodes), the plane renders 1 to within the
    table's error (Cycles' E is the true albedo there)."""
    lobe = S.Lobe("glass", (1, 1, 1), x / 15, ior=IOR, multiscatter=True)
    mean, se = furnace(lobe, max(y / 15, 1e-4))
    check(f"multiscatter glass roughness {x}/15 mu {y}/15", mean, se, 1.0)
