"""How far two correct float64 code paths may drift apart, from rounding.

The compiled kernels (numba, which calls libm) and their NumPy reference
forms (whose transcendental ufuncs dispatch to SIMD code on CPUs with
AVX-512, rounding differently from libm in the last bits) compute the same
maths but do not round alike.  Where a result is ill-conditioned (asin near
1, a difference of nearly equal numbers) those last bits grow, so a fixed
tolerance would be either too loose for well-conditioned values or too
tight for the others.

``rounding_spread`` measures the conditioning element by element: it runs
the NumPy form again with every transcendental ufunc's result perturbed by a
random relative error of up to ``ULPS`` units in the last place (the
difference a different libm or SIMD implementation makes), a few times, and
takes the largest change of each output element.  ``assert_rounding_close``
requires the compiled result to lie within a small multiple of that spread
(plus a few ulps of the value itself): a real bug moves results by many
orders of magnitude more, on well-conditioned elements, which is where it
fails.
"""
import contextlib
import copy
import dataclasses

import numpy as np

# The largest difference in units of the last place between two float64
# implementations of a transcendental that the model allows.  libm (glibc)
# is correctly rounded or within 1 ulp; NumPy's SIMD float64 functions are
# within 4 ulp.
ULPS = 4.0
TRIALS = 8
# Margin on the measured spread: TRIALS random perturbations (four antithetic
# pairs) do not hit the worst combination of signs, and a different
# implementation's errors are not uniform.
MARGIN = 8.0
_EPS = np.finfo(np.float64).eps
# Elements that may step past the measured spread (see assert_rounding_close).
STEP_SHARE = 1e-3
# Ufuncs whose float64 results differ between libm and NumPy's SIMD loops
# (add, multiply, divide and sqrt are IEEE correctly rounded everywhere).
TRANSCENDENTALS = ("sin", "cos", "tan", "arcsin", "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh",
                   "arcsinh", "arccosh", "arctanh", "exp", "exp2", "expm1", "log", "log2", "log10",
                   "log1p", "power", "float_power", "cbrt", "hypot")


class _Jittered:
    """A ufunc whose floating-point results carry a random relative error
    (``sign`` -1: the opposite of the error drawn, for antithetic pairs)."""

    def __init__(self, ufunc, rng, ulps, sign=1.0):
        self.ufunc, self.rng, self.ulps, self.sign = ufunc, rng, ulps, sign

    def __call__(self, *args, **kwargs):
        out = self.ufunc(*args, **kwargs)
        if isinstance(out, tuple):
            return tuple(self._jitter(o) for o in out)
        return self._jitter(out)

    def _jitter(self, out):
        arr = np.asarray(out)
        if arr.dtype != np.float64:
            return out
        noise = 1.0 + self.sign * self.rng.uniform(-1.0, 1.0, arr.shape) * self.ulps * _EPS
        with np.errstate(all="ignore"):
            if isinstance(out, np.ndarray):      # also a caller's out= array, in place
                np.multiply(out, noise, out=out)
                return out
            return np.float64(arr * noise)

    def __getattr__(self, name):
        return getattr(self.ufunc, name)


@contextlib.contextmanager
def jittered_numpy(rng, ulps=ULPS, sign=1.0):
    """Within the block, ``np.sin`` & co. return results perturbed by up to
    ``ulps`` ulp.  Code that calls them through the numpy module (the NumPy
    reference forms) sees the perturbation; compiled code does not."""
    saved = {name: getattr(np, name) for name in TRANSCENDENTALS}
    try:
        for name, ufunc in saved.items():
            setattr(np, name, _Jittered(ufunc, rng, ulps, sign))
        yield
    finally:
        for name, ufunc in saved.items():
            setattr(np, name, ufunc)


def _outputs(result):
    return [np.asarray(r) for r in (result if isinstance(result, tuple) else (result,))]


def _jitter_argument(a, rng, ulps, sign=1.0):
    """``a`` with a relative error of up to ``ulps`` ulp; values in [0, 1)
    (random numbers, CDFs) stay inside it."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        moved = copy.copy(a)
        for field in dataclasses.fields(a):
            setattr(moved, field.name, _jitter_argument(getattr(a, field.name), rng, ulps, sign))
        return moved
    if isinstance(a, float):
        a = np.float64(a)
    elif not (isinstance(a, np.ndarray) and a.dtype == np.float64):
        return a
    with np.errstate(all="ignore"):
        moved = a * (1.0 + sign * rng.uniform(-1.0, 1.0, np.shape(a)) * ulps * _EPS)
        unit = (a >= 0.0) & (a < 1.0)
        return np.where(unit, np.clip(moved, 0.0, np.nextafter(1.0, 0.0)), moved)


def rounding_spread(reference, args=(), seed=0, trials=TRIALS):
    """Per output, the largest change of each element over ``trials`` runs
    of ``reference(*args)`` (a NumPy form) with its transcendentals' results
    and its float arguments perturbed (the arguments stand for rounding in
    arithmetic, which a compiler may contract or reorder); also the
    unperturbed outputs."""
    base = _outputs(reference(*args))
    spread = [np.zeros(b.shape) for b in base]
    for trial in range(trials):
        # Antithetic pairs: the second run of a pair draws the same errors
        # with the opposite sign, so a kink (a clamp, a branch) is seen from
        # both sides.
        rng = np.random.default_rng((seed, trial // 2))
        sign = 1.0 if trial % 2 == 0 else -1.0
        jittered = [_jitter_argument(a, rng, ULPS, sign) for a in args]
        with jittered_numpy(rng, sign=sign):
            again = _outputs(reference(*jittered))
        for s, b, a in zip(spread, base, again):
            if b.dtype.kind != "f":
                s[a != b] = np.inf           # an index or flag that flipped
                continue
            with np.errstate(all="ignore"):
                d = np.abs(a - b)
            d[~np.isfinite(d)] = np.inf     # moved to or from inf / NaN: anything goes there
            np.maximum(s, d, out=s)
    return base, spread


def assert_rounding_close(reference, compiled, spread, what=""):
    """Compiled outputs against the reference's.

    * Indices and flags: equal, except where perturbed rounding flipped
      them too.
    * Floats: NaN where the reference has NaN, and within MARGIN x the
      rounding spread plus ULPS ulp of the value, except on at most
      ``STEP_SHARE`` of the elements: where a result hangs on the last bit
      of one intermediate (a clamp, a branch, 1 - cu^2 with cu near 1) it
      moves in steps, and TRIALS perturbations can all miss the step.  Those
      few must still lie within sqrt(eps) of the value (or of 1, for
      values near 0 from cancellation).  A real error moves far more than
      STEP_SHARE of the elements, or moves one by far more than sqrt(eps).
    """
    for k, (a, b, s) in enumerate(zip(reference, compiled, spread)):
        a, b = np.asarray(a), np.asarray(b)
        label = f"{what} output {k}"
        assert a.shape == b.shape, f"{label}: shapes {a.shape} and {b.shape}"
        if a.dtype.kind != "f":
            bad = (a != b) & ~np.isinf(s)
            assert not bad.any(), f"{label}: {np.sum(bad)} of {a.size} values differ"
            continue
        with np.errstate(all="ignore"):
            allowed = MARGIN * s + ULPS * np.spacing(np.abs(a))
            d = np.abs(a - b)
            coarse = np.sqrt(_EPS) * np.maximum(np.maximum(np.abs(a), np.abs(b)), 1.0)
        same = (a == b) | (np.isnan(a) & np.isnan(b))
        moved = np.isinf(s)
        ok = same | (d <= allowed) | moved
        steps = ~ok & (d <= coarse)
        wrong = ~ok & ~steps
        assert not wrong.any(), (f"{label}: {np.sum(wrong)} of {a.size} values differ beyond rounding "
                                 f"(worst {np.max(np.where(wrong, d / coarse, 0)):.3g}x sqrt(eps))")
        assert steps.sum() <= STEP_SHARE * a.size, (
            f"{label}: {np.sum(steps)} of {a.size} values differ beyond rounding (allowed "
            f"{int(STEP_SHARE * a.size)}; worst {np.max(np.where(steps, d / np.maximum(allowed, 1e-300), 0)):.3g}x "
            "the allowance)")


def assert_agree_within_rounding(reference, compiled, what="", seed=0):
    """Run ``reference()`` (the NumPy form) and ``compiled()`` and require
    them to agree within rounding (``assert_rounding_close``)."""
    base, spread = rounding_spread(reference, seed=seed)
    assert_rounding_close(base, _outputs(compiled()), spread, what)
