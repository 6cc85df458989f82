"""Cycles' Hair BSDF node (kernel/closure/bsdf_hair.h, from OSL): the
Reflection and Transmission components, each one lobe.

The fibre's axis T is the shading frame's x (the curve's tangent, as for
engine/lobes/hair.py); the normal N (z) only decides the side: reflection
sees light above N, transmission below.  Angles as Cycles: theta_r =
asin(wo.x) of the view, theta_i of the light; the azimuth is measured from
``locy``, the view made perpendicular to T.  Parameters: ``roughness``
(RoughnessU, longitudinal, from alpha so at least sqrt(MIN_ALPHA)),
``radial_roughness`` (RoughnessV, azimuthal), both clamped to [0.001, 1] as
Cycles' setup, and ``offset`` (the node's Offset in radians, negated as
Cycles' svm node does).

Cycles' eval returns its pdf as f |cos| (every sample weighs 1) but its
samplers are not consistent with it: the reflection sampler draws the
azimuth over |phi| <= pi RoughnessV with density cos(phi / (2 RoughnessV)) /
(4 RoughnessV) while its pdf and eval take cos(phi / 2) / (4 RoughnessV) and
eval is 0 beyond |phi| = pi / 2; the transmission sampler draws into the
half-space behind the view, eval only below N.  Cycles' bsdf_sample uses the
sampler's own eval and pdf, so these lobes carry OWN_WEIGHT: their sample
writes f (the weight applied, |cos| divided out) into the batch's weight
and sel x pdf into its pdf, and bsdf.sample adds the other lobes' eval to
them (Cycles' _surface_shader_bsdf_eval_mis).  ``sampler_pdf`` is the
density the sampler really draws from (the tests' chi-square).
The compiled form is the HAIR_REFLECTION / HAIR_TRANSMISSION branches of
engine/bsdf_loops.py."""
import numpy as np

from .registry import OWN_WEIGHT, REFLECTION, TRANSMISSION, LobeDef, register

HAIR_REFLECTION = 13
HAIR_TRANSMISSION = 14
HALF_PI = 0.5 * np.pi
# Cycles rejects lights and samples within this of the fibre's axis.
POLE = 1e-3


def roughnesses(lobes, rows, k):
    """(RoughnessU, RoughnessV) clamped as bsdf_hair_*_setup (NaN, negative: 0.001)."""
    alpha, r2 = lobes.alpha[rows, k], lobes.radial_roughness[rows, k]
    r1 = np.sqrt(np.where(alpha > 0, alpha, 0.0))
    return np.clip(r1, 0.001, 1.0), np.clip(np.where(r2 > 0, r2, 0.0), 0.001, 1.0)


class View:
    """What eval and sample share: theta_r, locy (the view perpendicular
    to T, in the frame's (y, z)), the longitudinal range a - b, offset."""

    def __init__(self, lobes, rows, k, wo):
        self.r1, self.r2 = roughnesses(lobes, rows, k)
        offset = lobes.offset[rows, k]
        self.offset = -np.where(np.isfinite(offset), offset, 0.0)
        self.theta_r = np.arcsin(np.clip(wo[:, 0], -1.0, 1.0))
        yz = np.hypot(wo[:, 1], wo[:, 2])
        self.ok = yz > 1e-12
        safe = np.where(self.ok, yz, 1.0)
        self.ly, self.lz = wo[:, 1] / safe, wo[:, 2] / safe
        self.b = np.arctan(((-HALF_PI + self.theta_r) * 0.5 - self.offset) / self.r1)
        self.a = np.arctan(((HALF_PI + self.theta_r) * 0.5 - self.offset) / self.r1)

    def theta_pdf(self, theta_i):
        t = (theta_i + self.theta_r) * 0.5 - self.offset
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.r1 / (2.0 * (t * t + self.r1 * self.r1) * (self.a - self.b) * np.cos(theta_i))

    def reflection_phi_pdf(self, phi):
        """The pdf Cycles reports (not the sampler's density)."""
        return np.cos(phi * 0.5) * 0.25 / self.r2

    def transmission_phi_pdf(self, p):
        c = 2.0 * np.arctan(HALF_PI / self.r2)
        return self.r2 / (c * (p * p + self.r2 * self.r2))

    def light(self, wi):
        """(theta_i, cos phi) of light directions wi (phi from locy)."""
        theta_i = np.arcsin(np.clip(wi[:, 0], -1.0, 1.0))
        yz = np.hypot(wi[:, 1], wi[:, 2])
        safe = np.where(yz > 0, yz, 1.0)
        cos_phi = np.clip((wi[:, 1] * self.ly + wi[:, 2] * self.lz) / safe, -1.0, 1.0)
        return theta_i, cos_phi, self.ok & (yz > 0) & (HALF_PI - np.abs(theta_i) >= POLE)

    def direction(self, theta_i, phi):
        """Cycles' wo = cos(phi) cos(theta) locy - sin(phi) cos(theta) locx + sin(theta) T,
        locx = locy x T = (0, lz, -ly)."""
        c = np.cos(theta_i)
        cp, sp = np.cos(phi) * c, np.sin(phi) * c
        return np.stack([np.sin(theta_i), cp * self.ly - sp * self.lz, cp * self.lz + sp * self.ly], axis=1)


def _finite(f, pdf, ok):
    good = ok & np.isfinite(f) & np.isfinite(pdf) & (pdf > 0)
    return np.where(good, f, 0.0), np.where(good, pdf, 0.0)


def _per_cos(pdf, wi):
    """Cycles' eval (= its pdf) is f |cos|: f = pdf / |wi.z|."""
    cos = np.abs(wi[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(cos > 1e-12, pdf / np.where(cos > 1e-12, cos, 1.0), np.inf)


def eval_hair_bsdf_f(lobes, rows, k, wo, wi, transmission):
    """(f (N,), pdf (N,)) of bsdf_hair_reflection_eval / _transmission_eval."""
    view = View(lobes, rows, k, wo)
    theta_i, cos_phi, ok = view.light(wi)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if transmission:
            ok &= wi[:, 2] < 0.0
            phi_pdf = view.transmission_phi_pdf(np.pi - np.arccos(cos_phi))
        else:
            ok &= (wi[:, 2] >= 0.0) & (cos_phi >= 0.0)
            phi = np.minimum(np.arccos(cos_phi) / view.r2, np.pi)
            phi_pdf = view.reflection_phi_pdf(phi)
        pdf = phi_pdf * view.theta_pdf(theta_i)
        return _finite(_per_cos(pdf, wi), pdf, ok)


def eval_reflection(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_hair_bsdf_f(lobes, rows, k, wo, wi, False)
    return w * f[:, None], sel * pdf


def eval_transmission(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_hair_bsdf_f(lobes, rows, k, wo, wi, True)
    return w * f[:, None], sel * pdf


def sample_hair_bsdf_dir(lobes, rows, k, wo, u1, u2, transmission):
    """bsdf_hair_*_sample: (wi, f (N,), pdf (N,)), the sampler's own value
    and pdf (0 where Cycles' pdf is 0)."""
    view = View(lobes, rows, k, wo)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = view.r1 * np.tan(u1 * (view.a - view.b) + view.b)
        theta_i = 2.0 * (t + view.offset) - view.theta_r
        if transmission:
            c = 2.0 * np.arctan(HALF_PI / view.r2)
            p = view.r2 * np.tan(c * (u2 - 0.5))
            phi = p + np.pi
            phi_pdf = view.transmission_phi_pdf(p)
        else:
            phi = 2.0 * np.arcsin(1.0 - 2.0 * u2) * view.r2
            phi_pdf = view.reflection_phi_pdf(phi)
        wi = view.direction(theta_i, phi)
        pdf = np.abs(phi_pdf * view.theta_pdf(theta_i))
        ok = view.ok & (HALF_PI - np.abs(theta_i) >= POLE) & np.isfinite(wi).all(axis=1)
        f, pdf = _finite(_per_cos(pdf, wi), pdf, ok)
    wi = np.where(ok[:, None], wi, np.array([0.0, 0.0, 1.0]))
    return wi, f, pdf


def sampler_pdf(lobes, rows, k, wo, wi, transmission):
    """The density (per solid angle) the sampler draws wi from: the
    reported pdf for transmission (whichever side of N), for reflection
    cos(phi / (2 RoughnessV)) / (4 RoughnessV) over |phi| <= pi RoughnessV
    (equal to the reported one at RoughnessV 1 only)."""
    view = View(lobes, rows, k, wo)
    theta_i, cos_phi, ok = view.light(wi)
    phi = np.arccos(cos_phi)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if transmission:
            ok &= phi >= HALF_PI
            phi_pdf = view.transmission_phi_pdf(np.pi - phi)
        else:
            ok &= phi <= np.pi * view.r2
            phi_pdf = np.cos(phi / (2.0 * view.r2)) * 0.25 / view.r2
        pdf = phi_pdf * view.theta_pdf(theta_i)
    return np.where(ok & np.isfinite(pdf), pdf, 0.0)


def _sampler(transmission):
    def sample(lobes, rows, s):
        for k in np.unique(s.chosen[rows]):
            r = rows[s.chosen[rows] == k]
            wi, f, pdf = sample_hair_bsdf_dir(lobes, r, k, s.wo[r], s.u1[r], s.u2[r], transmission)
            s.wi[r] = wi
            s.weight[r] = s.w[r, k] * f[:, None]
            s.pdf[r] = s.p_lobe[r] * pdf
            s.kind[r] = np.where(pdf > 0, s.kind[r], -1)
    return sample


_CASES = [dict(color=(1, 1, 1), roughness=0.1, radial_roughness=1.0, offset=0.0349),
          dict(color=(0.8, 0.6, 0.4), roughness=0.4, radial_roughness=0.3, offset=-0.2)]
_PARAMS = ("roughness", "radial_roughness", "offset")
register(LobeDef(HAIR_REFLECTION, "hair_reflection", "glossy", REFLECTION | TRANSMISSION | OWN_WEIGHT,
                 _sampler(False), eval_reflection, "upper", params=_PARAMS, reciprocal=False,
                 doc="Hair BSDF node, Reflection (Cycles' bsdf_hair_reflection) on curves: x the fibre's tangent",
                 cases=_CASES))
register(LobeDef(HAIR_TRANSMISSION, "hair_transmission", "transmission", REFLECTION | TRANSMISSION | OWN_WEIGHT,
                 _sampler(True), eval_transmission, "lower", params=_PARAMS, reciprocal=False, has_transmission=True,
                 doc="Hair BSDF node, Transmission (Cycles' bsdf_hair_transmission) on curves",
                 cases=_CASES))
