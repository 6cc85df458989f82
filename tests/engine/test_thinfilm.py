"""engine/thinfilm.py (Cycles' fresnel_iridescence, float32) against a
direct scalar transcription of Cycles 4.2's bsdf_util.h in double, and
against the plain Fresnel it must reduce to (film of thickness 0, film of
the substrate's IOR)."""
import math

import numpy as np
import pytest

from engine import microfacet as mf
from engine import thinfilm as tf


def _polarized(cos_i, eta):
    t2 = eta * eta - (1.0 - cos_i * cos_i)
    if t2 <= 0:
        return (1.0, 1.0), 0.0, (0.0, 0.0)
    c = abs(cos_i)
    cos_t = -math.sqrt(t2) / eta
    r_s = (c + eta * cos_t) / (c - eta * cos_t)
    r_p = (cos_t + eta * c) / (eta * c - cos_t)
    return (r_s * r_s, r_p * r_p), cos_t, (math.pi * (r_s < 0), math.pi * (r_p < 0))


def _sensitivity(opd, shift):
    phase = 2.0 * math.pi * opd * 1e-9
    val = (5.4856e-13, 4.4201e-13, 5.2481e-13)
    pos = (1.6810e+06, 1.7953e+06, 2.2084e+06)
    var = (4.3278e+09, 9.3046e+09, 6.6121e+09)
    xyz = [val[i] * math.sqrt(2.0 * math.pi * var[i]) * math.cos(pos[i] * phase + shift)
           * math.exp(-phase * phase * var[i]) for i in range(3)]
    xyz[0] += 1.64408e-8 * math.cos(2.2399e+06 * phase + shift) * math.exp(-4.5282e+09 * phase * phase)
    return [x / 1.0685e-7 for x in xyz]


def _airy(t121, r12, r23, opd, phi):
    if r23 == 1.0:
        return [1.0, 1.0, 1.0]
    r123 = r12 * r23
    rs = t121 * t121 * r23 / (1.0 - r123)
    out = [r12 + rs] * 3
    cm = rs - t121
    for m in range(1, 4):
        cm *= math.sqrt(r123)
        s = _sensitivity(m * opd, m * phi)
        out = [o + cm * 2.0 * si for o, si in zip(out, s)]
    return out


def reference(eta1, eta2, eta3, cos1, thickness):
    if thickness < 30.0:
        t = min(max(thickness / 30.0, 0.0), 1.0)
        eta2 = eta1 + (eta2 - eta1) * t * t * (3.0 - 2.0 * t)
    r12, cos2, phi12 = _polarized(cos1, eta2 / eta1)
    if r12 == (1.0, 1.0):
        return [1.0, 1.0, 1.0]
    opd = -2.0 * eta2 * thickness * cos2
    r23, _, phi23 = _polarized(-cos2, eta3 / eta2)
    if r23 == (1.0, 1.0):
        return [1.0, 1.0, 1.0]
    rs = _airy(1.0 - r12[0], r12[0], r23[0], opd, math.pi - phi12[0] + phi23[0])
    rp = _airy(1.0 - r12[1], r12[1], r23[1], opd, math.pi - phi12[1] + phi23[1])
    xyz = [(a + b) * 0.5 * w for a, b, w in zip(rs, rp, tf.WHITE_XYZ)]
    return [min(max(sum(tf.XYZ_TO_RGB[i, j] * xyz[j] for j in range(3)), 0.0), 1.0) for i in range(3)]


# (ambient, film, substrate IOR, cos, thickness nm): soap film on air and
# on glass, oil on water, a film denser than its substrate, TIR from inside.
CASES = [(1.0, 1.33, 1.0, 0.9, 500.0), (1.0, 1.33, 1.5, 0.5, 380.0), (1.0, 1.45, 1.33, 0.2, 250.0),
         (1.0, 2.0, 1.5, 0.7, 120.0), (1.0, 1.3, 1.5, 1.0, 15.0), (1.0, 1.6, 1.5, 0.05, 900.0),
         (1.5, 1.33, 1.0, 0.3, 400.0), (1.0, 1.33, 1.5, 0.999, 1500.0)]


@pytest.mark.parametrize("case", CASES)
def test_matches_double_transcription(case):
    got, _ = tf.fresnel_iridescence(*case)
    want = reference(*case)
    print(case, got, want)
    # float32 phases reach ~60 rad: ~1e-5 absolute at worst.
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)


def test_vectorised_equals_scalar_cases():
    arr = np.array(CASES).T
    got, _ = tf.fresnel_iridescence(*arr)
    np.testing.assert_allclose(got, [reference(*c) for c in CASES], rtol=0, atol=2e-4)


def test_no_film_is_plain_fresnel():
    """Thickness 0: the film takes the ambient IOR, so F is the substrate's
    dielectric Fresnel, equal in R, G and B (white maps to white)."""
    cos = np.linspace(0.02, 1.0, 25)
    for eta3 in (1.33, 1.5, 2.4):
        got, _ = tf.fresnel_iridescence(1.0, 1.4, eta3, cos, 0.0, dtype=np.float64)
        f, _ = mf.fresnel_dielectric(cos, eta3)
        np.testing.assert_allclose(got, np.repeat(f[:, None], 3, axis=1), atol=1e-6)


def test_film_of_substrate_ior_is_plain_fresnel():
    """A film as dense as its substrate has no bottom interface: R = R12."""
    cos = np.linspace(0.02, 1.0, 25)
    got, _ = tf.fresnel_iridescence(1.0, 1.5, 1.5, cos, 400.0, dtype=np.float64)
    f, _ = mf.fresnel_dielectric(cos, 1.5)
    np.testing.assert_allclose(got, np.repeat(f[:, None], 3, axis=1), atol=1e-6)


def test_soap_film_is_coloured_and_bounded():
    """A 400 nm soap film in air reflects visibly coloured light (channels
    differ by far more than rounding) and stays within [0, 1]."""
    cos = np.linspace(0.05, 1.0, 64)
    rgb, _ = tf.fresnel_iridescence(1.0, 1.33, 1.0, cos, 400.0)
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0.0 and rgb.max() <= 1.0
    assert np.ptp(rgb, axis=1).max() > 0.05
    assert rgb.dtype == np.float32
