"""The rounding tolerance of tests/engine/rounding.py can fail: it accepts
what another libm's last bits do and rejects a real (if tiny) error."""
import numpy as np
import pytest

from engine.sampling import spherical_rectangle_warp
from rounding import assert_rounding_close, jittered_numpy, rounding_spread


def _warp_args(rng, n=20000):
    xc, yc = rng.normal(size=n), rng.normal(size=n)
    z0 = -np.abs(rng.normal(size=n)) - 1e-3
    return (xc, yc, z0, 0.5, np.abs(rng.normal(size=n)) + 0.01, rng.random(n), rng.random(n))


def _warp(*args):
    return spherical_rectangle_warp.fn(*args)   # the NumPy form


def test_another_libm_passes():
    """The same NumPy form with its transcendentals off by up to 4 ulp (a
    stand-in for AVX-512 SIMD against libm, a seed the spread never saw)."""
    args = _warp_args(np.random.default_rng(1))
    base, spread = rounding_spread(_warp, args, seed=2)
    with jittered_numpy(np.random.default_rng(99)):
        other = _warp(*args)
    assert_rounding_close(base, other, spread)


@pytest.mark.parametrize("error", [1e-9, 1e-11])
def test_a_small_real_error_fails(error):
    args = _warp_args(np.random.default_rng(3))
    base, spread = rounding_spread(_warp, args)
    wrong = [b * (1.0 + error) for b in base]
    with pytest.raises(AssertionError, match="beyond rounding"):
        assert_rounding_close(base, wrong, spread)


def test_a_flipped_index_fails():
    def pick(u):
        return (np.floor(u * 7.0).astype(np.int64),)
    u = np.random.default_rng(4).random(1000)
    base, spread = rounding_spread(pick, (u,))
    flipped = base[0].copy()
    flipped[10] = (flipped[10] + 1) % 7
    with pytest.raises(AssertionError, match="values differ"):
        assert_rounding_close(base, [flipped], spread)
