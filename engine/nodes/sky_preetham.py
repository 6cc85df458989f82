"""The Sky Texture's 'PREETHAM' model as Cycles evaluates it.

Preetham, Shirley and Smits, "A Practical Analytic Model for Daylight"
(SIGGRAPH 1999): zenith luminance and chromaticity from the turbidity and
the sun's zenith angle, each scaled by the Perez distribution

    F(theta, gamma) = (1 + A exp(B / cos theta)) (1 + C exp(D gamma) + E cos^2 gamma)

normalised at the zenith (F(0, theta_sun)), theta the view's zenith angle
(clamped just above the horizon), gamma its angle to the sun.  The result is
CIE xyY, converted to linear Rec.709 and clamped at zero.  The coefficient
fits are the paper's (Appendix A.2).  There is no sun disc.  Computed in
float32 like Cycles' host precompute (scene/shader_nodes.cpp) and kernel
(svm/sky.h); all supported Blenders agree.
"""
import numpy as np

F = np.float32
HALF_PI = F(np.pi / 2)
# Perez coefficients (A..E) as linear functions of the turbidity: (slope, offset).
PEREZ_Y = ((0.1787, -1.4630), (-0.3554, 0.4275), (-0.0227, 5.3251), (0.1206, -2.5771), (-0.0670, 0.3703))
PEREZ_X = ((-0.0193, -0.2592), (-0.0665, 0.0008), (-0.0004, 0.2125), (-0.0641, -0.8989), (-0.0033, 0.0452))
PEREZ_Z = ((-0.0167, -0.2608), (-0.0950, 0.0092), (-0.0079, 0.2102), (-0.0441, -1.6537), (-0.0109, 0.0529))
# Zenith chromaticity: rows T^2, T, 1; columns theta^3, theta^2, theta, 1.
ZENITH_X = ((0.00166, -0.00375, 0.00209, 0.0), (-0.02903, 0.06377, -0.03202, 0.00394),
            (0.11693, -0.21196, 0.06052, 0.25886))
ZENITH_Y = ((0.00275, -0.00610, 0.00317, 0.0), (-0.04214, 0.08970, -0.04153, 0.00516),
            (0.15346, -0.26756, 0.06670, 0.26688))


def perez(lam, theta, gamma):
    cg = np.cos(gamma)
    return (F(1.0) + lam[0] * np.exp(lam[1] / np.cos(theta))) * (
        F(1.0) + lam[2] * np.exp(lam[3] * gamma) + lam[4] * cg * cg)


def _zenith_chromaticity(rows, theta, t):
    theta = F(theta)
    powers = (theta * theta * theta, theta * theta, theta, F(1.0))
    def poly(row):
        return sum(F(c) * p for c, p in zip(row, powers) if c != 0.0)
    return poly(rows[0]) * (t * t) + poly(rows[1]) * t + poly(rows[2])


def precompute(sun_direction, turbidity):
    """(sun theta, sun phi, zenith values (Y, x, y), Perez coefficients
    (3, 5)) as Cycles' sky_texture_precompute_preetham."""
    d = np.asarray(sun_direction, np.float64)
    n = np.linalg.norm(d)
    d = (d / n if n > 0 else np.array([0.0, 0.0, 1.0])).astype(F)
    theta = np.arccos(np.clip(d[2], F(-1.0), F(1.0)))
    phi = np.arctan2(d[0], d[1])
    t = F(turbidity)
    chi = (F(4.0 / 9.0) - t / F(120.0)) * (F(np.pi) - F(2.0) * theta)
    zenith_Y = ((F(4.0453) * t - F(4.9710)) * np.tan(chi) - F(0.2155) * t + F(2.4192)) * F(0.06)
    zenith = np.array([zenith_Y, _zenith_chromaticity(ZENITH_X, theta, t),
                       _zenith_chromaticity(ZENITH_Y, theta, t)], F)
    coeffs = np.array([[F(a) * t + F(b) for a, b in table] for table in (PEREZ_Y, PEREZ_X, PEREZ_Z)], F)
    zenith = zenith / np.array([perez(c, F(0.0), theta) for c in coeffs], F)
    return F(theta), F(phi), zenith, coeffs


def evaluate(d, props, xyz_to_rgb):
    """Linear RGB (N, 3) for lookup vectors d (N, 3)."""
    d = np.asarray(d, F)
    sun_theta, sun_phi, zenith, coeffs = precompute(props.get("sun_direction", (0.0, 0.0, 1.0)),
                                                    props.get("turbidity", 2.2))
    with np.errstate(all="ignore"):
        theta = np.arccos(np.clip(d[:, 2], F(-1.0), F(1.0)))
        phi = np.arctan2(d[:, 0], d[:, 1])
        cos_psi = (np.sin(theta) * np.sin(sun_theta) * np.cos(sun_phi - phi)
                   + np.cos(theta) * np.cos(sun_theta))
        gamma = np.arccos(np.clip(cos_psi, F(-1.0), F(1.0)))
        theta = np.minimum(theta, HALF_PI - F(0.001))
        Y = zenith[0] * perez(coeffs[0], theta, gamma)
        x = zenith[1] * perez(coeffs[1], theta, gamma)
        y = zenith[2] * perez(coeffs[2], theta, gamma)
        X = np.where(y != 0, x / y * Y, F(0.0))
        Z = np.where((y != 0) & (Y != 0), (F(1.0) - x - y) / y * Y, F(0.0))
        rgb = np.stack([X, Y, Z], axis=1) @ xyz_to_rgb.T
    return np.maximum(np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0), F(0.0))
