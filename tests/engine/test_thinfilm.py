"""engine/thinfilm.py (Cycles' fresnel_iridescence_channel, float32) against
a direct scalar transcription of Cycles' bsdf_util.h evaluated in double,
and against the Fresnel terms it must reduce to (film of thickness 0, film
of the substrate's IOR, F82 metal under no film)."""
import cmath
import math

import numpy as np
import pytest

from engine import microfacet as mf
from engine import thinfilm as tf

TABLE = tf.sensitivity_table(np.float64)


def _lookup(row, x):
    x = min(max(x, 0.0), 1.0) * (tf.TABLE_SIZE - 1)
    i = min(int(x), tf.TABLE_SIZE - 1)
    t = x - i
    return (1.0 - t) * row[i] + t * row[min(i + 1, tf.TABLE_SIZE - 1)]


def _dielectric(cos_i, eta):
    t2 = eta * eta - (1.0 - cos_i * cos_i)
    if t2 <= 0:
        return (1.0, 1.0), 0.0, (1.0, 1.0)
    c = abs(cos_i)
    cos_t = -math.sqrt(t2) / eta
    r_s = (c + eta * cos_t) / (c - eta * cos_t)
    r_p = (cos_t + eta * c) / (eta * c - cos_t)
    return (r_s * r_s, r_p * r_p), cos_t, (1.0 if r_s >= 0 else -1.0, 1.0 if r_p >= 0 else -1.0)


def _conductor(cosi, eta1, eta2, k2):
    """Born and Wolf 14.4.1 with n + ik, as Cycles (reflectances and unit phasors)."""
    t1 = eta2 ** 2 - k2 ** 2 - eta1 ** 2 * (1.0 - cosi ** 2)
    t2 = math.sqrt(t1 ** 2 + (2 * eta2 * k2) ** 2)
    u2, v2 = max(0.5 * (t2 + t1), 0.0), max(0.5 * (t2 - t1), 0.0)
    u, v = math.sqrt(u2), math.sqrt(v2)
    r_s = ((eta1 * cosi - u) ** 2 + v2) / ((eta1 * cosi + u) ** 2 + v2)
    t3, t4 = (eta2 ** 2 - k2 ** 2) * cosi, 2 * eta2 * k2 * cosi
    r_p = ((t3 - eta1 * u) ** 2 + (t4 - eta1 * v) ** 2) / ((t3 + eta1 * u) ** 2 + (t4 + eta1 * v) ** 2)
    ps = complex(-u2 - v2 + (eta1 * cosi) ** 2, -2 * eta1 * cosi * v)
    pp = complex(((eta2 ** 2 + k2 ** 2) * cosi) ** 2 - eta1 ** 2 * (u2 + v2),
                 2 * eta1 * cosi * (2 * eta2 * k2 * u - (eta2 ** 2 - k2 ** 2) * v))
    return (r_s, r_p), (ps / abs(ps) if abs(ps) else 1.0, pp / abs(pp) if abs(pp) else 1.0)


def _airy(channel, r12, r23, opd, phasor):
    t121 = 1.0 - r12
    r123 = r12 * r23
    rs = t121 * t121 * r23 / (1.0 - r123)
    out, cm, acc = rs + r12, rs - t121, phasor
    for m in range(1, 4):
        cm *= math.sqrt(r123)
        x = 2 * math.pi * m * opd / 60000.0
        s = complex(_lookup(TABLE[channel], x), _lookup(TABLE[channel + 3], x))
        out += cm * 2.0 * (acc.real * s.real + acc.imag * s.imag)
        acc *= phasor
    return out


def reference(channel, thickness, film_ior, n, k, cos1, conductive=False):
    if thickness < 1.0:
        t = min(max(thickness, 0.0), 1.0)
        film_ior = 1.0 + (film_ior - 1.0) * t * t * (3.0 - 2.0 * t)
    r12, cos2, c12 = _dielectric(cos1, film_ior)
    if r12 == (1.0, 1.0):
        return 1.0
    if conductive:
        r23, ph23 = _conductor(-cos2, film_ior, n, k)
    else:
        r23, _, c23 = _dielectric(-cos2, n / film_ior)
        if r23 == (1.0, 1.0):
            return 1.0
        ph23 = (complex(c23[0], 0.0), complex(c23[1], 0.0))
    opd = -2.0 * film_ior * thickness * cos2
    r_s = _airy(channel, r12[0], r23[0], opd, ph23[0] * -c12[0])
    r_p = _airy(channel, r12[1], r23[1], opd, ph23[1] * -c12[1])
    return min(max(0.5 * (r_s + r_p), 0.0), 1.0)


# (thickness nm, film IOR, substrate n, k, cos): soap film in air and on
# glass, oil on water, a film denser than its substrate, grazing, under
# 1 nm, a thick film; metals (gold-like, aluminium-like) under oil.
DIELECTRIC = [(500.0, 1.33, 1.0, 0.9), (380.0, 1.33, 1.5, 0.5), (250.0, 1.45, 1.33, 0.2), (120.0, 2.0, 1.5, 0.7),
              (0.5, 1.3, 1.5, 1.0), (900.0, 1.6, 1.5, 0.05), (1500.0, 1.33, 1.5, 0.999), (300.0, 1.2, 1.0, 0.6)]
CONDUCTOR = [(300.0, 1.5, 0.2, 3.0, 0.8), (450.0, 1.4, 1.1, 6.5, 0.3), (200.0, 1.8, 0.5, 2.4, 0.95)]


@pytest.mark.parametrize("case", DIELECTRIC)
def test_dielectric_matches_double_transcription(case):
    thickness, film, n, cos = case
    got = [float(tf.fresnel_iridescence(c, 1.0, thickness, film, n, 0.0, cos)[0]) for c in range(3)]
    want = [reference(c, thickness, film, n, 0.0, cos) for c in range(3)]
    print(case, got, want)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)   # float32 phases and lookups


@pytest.mark.parametrize("case", CONDUCTOR)
def test_conductor_matches_double_transcription(case):
    thickness, film, n, k, cos = case
    got = [float(tf.fresnel_iridescence(c, 1.0, thickness, film, n, k, cos, conductive=True)[0]) for c in range(3)]
    want = [reference(c, thickness, film, n, k, cos, conductive=True) for c in range(3)]
    print(case, got, want)
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-4)


def test_vectorised_rows_equal_scalar_calls():
    arr = np.array(DIELECTRIC).T
    got = tf.fresnel_iridescence(1, 1.0, arr[0], arr[1], arr[2], 0.0, arr[3])[0]
    np.testing.assert_allclose(got, [reference(1, *c[:3], 0.0, c[3]) for c in DIELECTRIC], atol=2e-4)


def test_no_film_is_plain_fresnel():
    """Thickness 0: the film takes the ambient IOR, F is the substrate's
    dielectric Fresnel in every channel (the table's DC terms are 1)."""
    cos = np.linspace(0.02, 1.0, 25)
    for eta in (1.33, 1.5, 2.4):
        f, _ = mf.fresnel_dielectric(cos, eta)
        for c in range(3):
            got, _ = tf.fresnel_iridescence(c, 1.0, 0.0, 1.4, eta, 0.0, cos, dtype=np.float64)
            np.testing.assert_allclose(got, f, atol=1e-9)


def test_film_of_substrate_ior_is_plain_fresnel():
    """A film as dense as its substrate has no bottom interface: R = R12."""
    cos = np.linspace(0.02, 1.0, 25)
    f, _ = mf.fresnel_dielectric(cos, 1.5)
    for c in range(3):
        got, _ = tf.fresnel_iridescence(c, 1.0, 400.0, 1.5, 1.5, 0.0, cos, dtype=np.float64)
        np.testing.assert_allclose(got, f, atol=1e-9)


def test_conductor_without_film_is_its_fresnel():
    """Thickness 0 over a conductor: the complex-IOR Fresnel (checked with
    Python's complex arithmetic), and for the F82 metal its F82 curve."""
    cos = np.linspace(0.05, 1.0, 20)
    n, k = 0.2, 3.0
    got, _ = tf.fresnel_iridescence(0, 1.0, 0.0, 1.5, n, k, cos, conductive=True, dtype=np.float64)
    eta = complex(n, k)
    want = []
    for c in cos:
        ct = cmath.sqrt(1 - (1 - c * c) / eta ** 2)
        rs = (c - eta * ct) / (c + eta * ct)
        rp = (eta * c - ct) / (eta * c + ct)
        want.append(0.5 * (abs(rs) ** 2 + abs(rp) ** 2))
    np.testing.assert_allclose(got, want, atol=1e-9)
    f0 = np.array([[0.9, 0.6, 0.3]])
    b = mf.f82_b(f0, np.array([[0.9, 0.9, 0.5]]))
    got = tf.f82_conductor(cos, f0, b, 0.0, 1.5, dtype=np.float64)
    np.testing.assert_allclose(got, mf.f82(cos, f0, b), atol=1e-6)


def test_principled_scaling_is_identity_at_real_f0():
    cos = np.linspace(0.05, 1.0, 20)
    f0 = np.full((20, 3), ((1.5 - 1) / 2.5) ** 2)
    got = tf.principled_dielectric(cos, 1.5, f0, 380.0, 1.33)
    want = np.stack([tf.fresnel_iridescence(c, 1.0, 380.0, 1.33, 1.5, 0.0, cos)[0] for c in range(3)], axis=-1)
    np.testing.assert_allclose(got, want, atol=1e-6)
    dimmer = tf.principled_dielectric(cos, 1.5, f0 * 0.5, 380.0, 1.33)
    assert np.all(dimmer <= got + 1e-7) and np.any(dimmer < got - 1e-3)


def test_soap_film_is_coloured_and_bounded():
    """A 400 nm soap film in air reflects visibly coloured light (channels
    differ by far more than rounding), within [0, 1], in float32."""
    cos = np.linspace(0.05, 1.0, 64)
    rgb = np.stack([tf.fresnel_iridescence(c, 1.0, 400.0, 1.33, 1.0, 0.0, cos)[0] for c in range(3)], axis=-1)
    assert np.all(np.isfinite(rgb)) and rgb.min() >= 0.0 and rgb.max() <= 1.0
    assert np.ptp(rgb, axis=1).max() > 0.05
    assert rgb.dtype == np.float32


def _complex_fresnel(n, k, cos):
    """Unpolarized Fresnel of n + ik from air by Python's complex arithmetic."""
    eta = complex(n, k)
    ct = cmath.sqrt(1 - (1 - cos * cos) / eta ** 2)
    rs = (cos - eta * ct) / (cos + eta * ct)
    rp = (eta * cos - ct) / (eta * cos + ct)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


METALS = [((0.18, 0.42, 1.37), (3.42, 2.35, 1.77)),    # gold
          ((1.5, 1.5, 1.5), (0.0, 0.0, 0.0)),          # k 0: a dielectric seen as a conductor
          ((2.9, 0.05, 0.0), (3.0, 4.0, 2.0))]         # n 0.05 and 0: near the edges


@pytest.mark.parametrize("n, k", METALS)
def test_conductor_fresnel_is_the_complex_fresnel(n, k):
    """microfacet.conductor (pbrt's a, b form, the lobe's Fresnel of a
    Physical Conductor) against complex arithmetic, and its compiled form
    (bsdf_loops._conductor) against it."""
    from engine import bsdf_loops
    cos = np.linspace(0.0, 1.0, 41)
    got = mf.conductor(cos, np.array(n)[None], np.array(k)[None])
    want = np.array([[_complex_fresnel(nc, kc, c) if c > 0 else 1.0 for nc, kc in zip(n, k)] for c in cos])
    np.testing.assert_allclose(got, want, atol=1e-12)
    compiled = bsdf_loops._conductor.py_func if hasattr(bsdf_loops._conductor, "py_func") else bsdf_loops._conductor
    rows = np.array([[compiled(c, nc, kc) for nc, kc in zip(n, k)] for c in cos])
    np.testing.assert_allclose(rows, got, atol=1e-12)


def test_conductor_fss_is_cycles_f82_fit():
    """Cycles' fresnel_conductor_Fss: the F82 model through the Fresnel at
    cos 1 and 1/7, its closed-form average; checked against the fitted
    model's average by quadrature (the fit is not the exact average)."""
    n, k = np.array([[0.18, 0.42, 1.37]]), np.array([[3.42, 2.35, 1.77]])
    f0 = mf.conductor(np.ones(1), n, k)
    f82 = mf.conductor(np.full(1, 1 / 7), n, k)
    b = (7.0 / ((6 / 7) ** 6)) * ((f0 + (1 - f0) * (6 / 7) ** 5) - f82)
    mu = (np.arange(20000) + 0.5) / 20000
    quad = (mf.f82(mu, f0, b) * 2 * mu[:, None]).mean(axis=0)
    np.testing.assert_allclose(mf.conductor_fss(n, k)[0], quad, atol=1e-6)


def test_conductor_under_a_vanishing_film_is_its_fresnel():
    """A film of thickness 0 takes the ambient IOR: the physical conductor
    under it reflects its own complex Fresnel through the polarized Airy
    sum (and not the F82 fit's, which differs by up to 5 % in gold's blue)."""
    cos = np.linspace(0.05, 1.0, 20)
    n, k = np.array([0.18, 0.42, 1.37]), np.array([3.42, 2.35, 1.77])
    got = tf.conductor(cos, np.tile(n, (20, 1)), np.tile(k, (20, 1)), 0.0, 1.5, dtype=np.float64)
    want = np.array([[_complex_fresnel(nc, kc, c) for nc, kc in zip(n, k)] for c in cos])
    np.testing.assert_allclose(got, want, atol=1e-9)
