"""The Principled Hair BSDF's Chiang model (Chiang et al. 2016, "A Practical
and Controllable Hair and Fur Model for Production Path Tracing"), as Cycles'
closure/bsdf_principled_hair_chiang.h: the R, TT and TRT lobes (longitudinal
Mp of d'Eon et al. with the cuticle tilt, azimuthal trimmed logistic Np) and
the residual TRRT+, absorption sigma inside the fibre.

The fibre frame comes from the shading frame: the integrator puts the
curve's tangent on x and the round curve's normal (from its centre to the
hit) on z (engine/integrator/stages.shade), so wo's offset across the fibre
is h = -wo.y / |(wo.y, wo.z)| (Cycles' dot(cross(Ng, X), Z)) and no extra
per-ray input is needed.  Cycles' eval returns f |cos| with its own frame;
Ember's eval returns f, so it is divided by |wi.z| here.

Parameters (engine/lobes/registry.py): ``roughness`` (longitudinal, from
the lobe's alpha = roughness^2, so at least sqrt(MIN_ALPHA)), the table's
``radial_roughness``, ``coat``, ``offset`` (radians, the node's Offset) and
``absorption`` (sigma_a RGB, from the node's parametrization:
``sigma_from_melanin`` / ``sigma_from_color`` below, as Cycles' SVM node).
The compiled form is the HAIR_CHIANG branch of engine/bsdf_loops.py."""
import numpy as np

from .registry import REFLECTION, TRANSMISSION, LobeDef, register

HAIR_CHIANG = 12
SQRT_PI_8 = np.sqrt(np.pi / 8.0)
LN_2PI = np.log(2.0 * np.pi)
EUMELANIN = np.array([0.506, 0.841, 1.653])
PHEOMELANIN = np.array([0.343, 0.733, 1.924])


# ----------------------------------------------------------------------------
# Cycles' parametrizations (svm_node_closure_bsdf, CLOSURE_BSDF_HAIR_CHIANG_ID)

def albedo_roughness_scale(radial_roughness):
    x = radial_roughness
    return (((((0.245 * x) + 5.574) * x - 10.73) * x + 2.532) * x - 0.215) * x + 5.969


def sigma_from_color(color, radial_roughness):
    """Direct Coloring: bsdf_principled_hair_sigma_from_reflectance."""
    c = np.maximum(np.asarray(color, np.float64), 1e-30)
    s = np.log(c) / albedo_roughness_scale(radial_roughness)
    return s * s


def sigma_from_melanin(melanin, redness, tint, radial_roughness, random=0.5, random_color=0.0):
    """Melanin Concentration: the perceptual melanin remapped, split into eu-
    and pheomelanin by the redness, plus the tint's sigma."""
    melanin = melanin * (1.0 + 2.0 * (random - 0.5) * np.clip(random_color, 0.0, 1.0))
    melanin = -np.log(max(1.0 - melanin, 1e-4))
    sigma = melanin * (1.0 - redness) * EUMELANIN + melanin * redness * PHEOMELANIN
    return sigma + sigma_from_color(tint, radial_roughness)


def _pow(x, n):
    return x ** n


def variance(roughness):
    """Cycles' roughness -> longitudinal variance v."""
    r = np.clip(roughness, 0.001, 1.0)
    return (0.726 * r + 0.812 * r * r + 3.7 * _pow(r, 20)) ** 2


def logistic_scale(radial_roughness):
    s = np.clip(radial_roughness, 0.001, 1.0)
    return (0.265 * s + 1.194 * s * s + 5.372 * _pow(s, 22)) * SQRT_PI_8


def setup(roughness, radial_roughness, coat):
    """(v, s, m0 variance) as bsdf_hair_chiang_setup."""
    r = np.clip(roughness, 0.001, 1.0)
    m0 = np.clip((1.0 - np.clip(coat, 0.0, 1.0)) * r, 0.001, 1.0)
    return variance(r), logistic_scale(radial_roughness), variance(m0)


def _invert(fn, target, lo=0.001, hi=1.0, steps=60):
    """x in [lo, hi] with fn(x) = target for an increasing fn (bisection,
    vectorized): the roughness whose mapped variance or scale is target."""
    a = np.full(np.shape(target), lo)
    b = np.full(np.shape(target), hi)
    for _ in range(steps):
        m = 0.5 * (a + b)
        below = fn(m) < target
        a = np.where(below, m, a)
        b = np.where(below, b, m)
    return 0.5 * (a + b)


def blur(lobes, rows, k, roughness):
    """Cycles' bsdf_hair_chiang_blur (Filter Glossy) on slot k at ``rows``:
    the mapped v, s and m0 (variances and logistic scale, not the node's
    roughnesses) raised to at least ``roughness``.  Ember keeps the node's
    values, so the blurred ones are mapped back: roughness and radial
    roughness whose setup gives max(roughness, v) and max(roughness, s),
    and the coat that gives max(roughness, m0).  In place."""
    r = np.clip(np.sqrt(lobes.alpha[rows, k]), 0.001, 1.0)
    v, s, m0 = setup(r, lobes.radial_roughness[rows, k], lobes.coat[rows, k])
    r0 = np.clip((1.0 - np.clip(lobes.coat[rows, k], 0.0, 1.0)) * r, 0.001, 1.0)
    r_new = np.where(roughness > v, _invert(variance, roughness), r)
    r0_new = np.where(roughness > m0, _invert(variance, roughness), r0)
    lobes.alpha[rows, k] = np.where(roughness > v, r_new * r_new, lobes.alpha[rows, k])
    lobes.radial_roughness[rows, k] = np.where(roughness > s, _invert(logistic_scale, roughness),
                                               lobes.radial_roughness[rows, k])
    lobes.coat[rows, k] = np.where((roughness > v) | (roughness > m0), np.clip(1.0 - r0_new / r_new, 0.0, 1.0),
                                   lobes.coat[rows, k])


# ----------------------------------------------------------------------------
# The model's terms (vectorized)

def _cos_from_sin(s):
    return np.sqrt(np.maximum(1.0 - s * s, 0.0))


# Terms of the I0 series.  Cycles sums ten (its bessel_I0), which falls short
# by up to 2 % for the arguments 8..12 it uses it for (above 12 it takes the
# asymptotic form): its eval then disagrees with its exact sampler, which a
# chi-square of 200k samples detects.  Twenty-four are exact to rounding there.
I0_TERMS = 24


def bessel_i0(x):
    """The I0 series as Cycles' bessel_I0, with I0_TERMS terms."""
    x = x * x
    val = 1.0 + 0.25 * x
    pw = x * x
    fac = 1.0
    p4 = 16.0
    for i in range(2, I0_TERMS):
        fac *= i * i
        val = val + pw / (p4 * fac)
        pw = pw * x
        p4 *= 4.0
    return val


def log_bessel_i0(x):
    """log I0: the series up to 12, then the asymptotic expansion to its
    third term.  (Cycles' log_bessel_I0, as pbrt's, adds 1/(16 x) where the
    expansion has log(1 + 1/(8 x) + ...): 0.5 % low at 12, 0.14 % at 47, so
    its narrow TT lobe's eval is a little below what its sampler draws.)"""
    big = x > 12.0
    xs = np.where(big, x, 1.0)
    inv = 1.0 / xs
    tail = np.log1p(inv * (0.125 + inv * (9.0 / 128.0 + inv * (225.0 / 3072.0))))
    return np.where(big, xs - 0.5 * (LN_2PI + np.log(xs)) + tail, np.log(bessel_i0(np.where(big, 0.0, x))))


def mp(sin_i, cos_i, sin_o, cos_o, v):
    """longitudinal_scattering."""
    inv_v = 1.0 / v
    cos_arg = cos_i * cos_o * inv_v
    sin_arg = sin_i * sin_o * inv_v
    small = v <= 0.1
    with np.errstate(over="ignore", invalid="ignore"):
        a = np.exp(log_bessel_i0(cos_arg) - sin_arg - inv_v + 0.6931 + np.log(0.5 * inv_v))
        vb = np.where(small, 1.0, v)
        b = np.exp(-sin_arg) * bessel_i0(np.where(small, 0.0, cos_arg)) / (np.sinh(1.0 / vb) * 2.0 * vb)
    return np.where(small, a, b)


def logistic_cdf(x, s):
    arg = -x / s
    return np.where(arg > 88.0, 0.0, 1.0 / (1.0 + np.exp(np.minimum(arg, 88.0))))


def trimmed_logistic(x, s):
    e = np.exp(-np.abs(x) / s)
    scale = 1.0 - 2.0 * logistic_cdf(-np.pi, s)
    return np.where(scale > 0, e / (s * (1.0 + e) ** 2) / np.where(scale > 0, scale, 1.0), 0.0)


def sample_trimmed_logistic(u, s):
    c = logistic_cdf(-np.pi, s)
    with np.errstate(divide="ignore"):
        x = -s * np.log(1.0 / (u * (1.0 - 2.0 * c) + c) - 1.0)
    return np.clip(x, -np.pi, np.pi)


def wrap_angle(a):
    return (a + np.pi) - 2.0 * np.pi * np.floor((a + np.pi) / (2.0 * np.pi)) - np.pi


def delta_phi(p, gamma_o, gamma_t):
    return 2.0 * p * gamma_t - 2.0 * gamma_o + p * np.pi


def fresnel_dielectric_cos(cos, eta):
    """Cycles' fresnel_dielectric_cos (unpolarized, 1 under total reflection)."""
    c = np.abs(cos)
    g = eta * eta - 1.0 + c * c
    ok = g > 0
    g = np.sqrt(np.maximum(g, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        return np.where(ok, 0.5 * a * a * (1.0 + b * b), 1.0)


def _luminance(rgb):
    return 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]


def tilts(sin_o, cos_o, alpha):
    """hair_alpha_angles: (sin, cos) of theta_o tilted for R, TT, TRT."""
    s1 = np.sin(alpha)
    c1 = _cos_from_sin(s1)
    s2 = 2.0 * s1 * c1
    c2 = c1 * c1 - s1 * s1
    s4 = 2.0 * s2 * c2
    c4 = c2 * c2 - s2 * s2
    return ((sin_o * c2 - cos_o * s2, np.abs(cos_o * c2 + sin_o * s2)),
            (sin_o * c1 + cos_o * s1, np.abs(cos_o * c1 - sin_o * s1)),
            (sin_o * c4 + cos_o * s4, np.abs(cos_o * c4 - sin_o * s4)))


# Cycles' frame is X = tangent, Y = normalize(X x wo) (its bsdf->N), Z = X x Y;
# its azimuth about the fibre is atan2(d.Z, d.Y).  In Ember's shading frame
# (x the tangent, z the curve normal) (d.Y, d.Z) is (d.y, d.z) turned by a
# proper rotation about x (fixed by wo), so only a constant separates the
# two azimuths and their differences, all the model reads, are equal.

def _phi(d):
    return np.arctan2(d[:, 2], d[:, 1])



class Fibre:
    """What eval and sample share for one batch of rows: the view angles,
    the Ap attenuations (N, 4, 3) and their normalized energies (N, 4)."""

    def __init__(self, lobes, rows, k, wo):
        self.v, self.s, self.m0 = setup(np.sqrt(lobes.alpha[rows, k]), lobes.radial_roughness[rows, k],
                                        lobes.coat[rows, k])
        # Cycles negates the node's offset in setup.
        self.alpha = -lobes.offset[rows, k]
        eta = np.maximum(lobes.ior[rows, k], 1e-5)
        sigma = np.maximum(lobes.absorption[rows, k], 0.0)
        self.sin_o = np.clip(wo[:, 0], -1.0, 1.0)
        self.cos_o = _cos_from_sin(self.sin_o)
        self.phi_o = _phi(wo)
        yz = np.sqrt(wo[:, 1] ** 2 + wo[:, 2] ** 2)
        h = np.clip(np.where(yz > 0, -wo[:, 1] / np.where(yz > 0, yz, 1.0), 0.0), -1.0, 1.0)
        self.gamma_o = np.arcsin(h)
        cos_gamma_o = _cos_from_sin(h)
        sin_t = self.sin_o / eta
        cos_t = _cos_from_sin(sin_t)
        sin_gt = h * self.cos_o / np.sqrt(np.maximum(eta * eta - self.sin_o ** 2, 1e-30))
        self.gamma_t = np.arcsin(np.clip(sin_gt, -1.0, 1.0))
        cos_gt = _cos_from_sin(sin_gt)
        with np.errstate(over="ignore"):
            t = np.exp(-sigma * (2.0 * cos_gt / np.maximum(cos_t, 1e-30))[:, None])
        f = fresnel_dielectric_cos(self.cos_o * cos_gamma_o, eta)[:, None]
        ap = np.empty((len(wo), 4, 3))
        ap[:, 0] = f
        col = (1.0 - f) ** 2 * t
        ap[:, 1] = col
        col = col * t * f
        ap[:, 2] = col
        tf = t * f
        col = col * np.where(tf < 1.0, tf / np.where(tf < 1.0, 1.0 - tf, 1.0), 0.0)
        ap[:, 3] = col
        energy = _luminance(ap)
        total = energy.sum(axis=1)
        self.ap = ap
        self.energy = np.where(total[:, None] > 0, energy / np.where(total > 0, total, 1.0)[:, None], 0.0)
        self.tilted = tilts(self.sin_o, self.cos_o, self.alpha)

    def terms(self, sin_i, cos_i, phi):
        """(F (N, 3), F_energy (N,)): Cycles' eval and pdf, f |cos| in its frame."""
        f = np.zeros((len(sin_i), 3))
        e = np.zeros(len(sin_i))
        vs = (self.m0, 0.25 * self.v, 4.0 * self.v)
        for p in range(3):
            so, co = self.tilted[p]
            m = mp(sin_i, cos_i, so, co, vs[p])
            n = trimmed_logistic(wrap_angle(phi - delta_phi(p, self.gamma_o, self.gamma_t)), self.s)
            f += self.ap[:, p] * (m * n)[:, None]
            e += self.energy[:, p] * m * n
        m = mp(sin_i, cos_i, self.sin_o, self.cos_o, 4.0 * self.v) / (2.0 * np.pi)
        f += self.ap[:, 3] * m[:, None]
        e += self.energy[:, 3] * m
        return f, e


def eval_hair_f(lobes, rows, k, wo, wi):
    """f (without the weight) and pdf per solid angle."""
    fib = Fibre(lobes, rows, k, wo)
    sin_i = np.clip(wi[:, 0], -1.0, 1.0)
    f, e = fib.terms(sin_i, _cos_from_sin(sin_i), _phi(wi) - fib.phi_o)
    cos = np.abs(wi[:, 2])
    ok = cos > 1e-12
    f = np.where(ok[:, None], f / np.where(ok, cos, 1.0)[:, None], 0.0)
    good = np.isfinite(f).all(axis=1) & np.isfinite(e)
    return np.where(good[:, None], f, 0.0), np.where(good & ok, e, 0.0)


def eval_hair(lobes, rows, k, wo, wi, w, sel, term, sampled):
    f, pdf = eval_hair_f(lobes, rows, k, wo, wi)
    return w * f, sel * pdf


def sample_hair_dir(lobes, rows, k, wo, u_lobe, u1, u2):
    """bsdf_hair_chiang_sample's direction: rand = (u1, u2, u_lobe)."""
    fib = Fibre(lobes, rows, k, wo)
    n = len(wo)
    z = np.array(u_lobe, dtype=np.float64)
    p = np.full(n, 3)
    chosen = np.zeros(n, bool)
    for q in range(3):
        take = ~chosen & (z < fib.energy[:, q])
        p[take] = q
        chosen |= take
        z = np.where(chosen, z, z - fib.energy[:, q])
    ep = fib.energy[np.arange(n), p]
    z = np.where(ep > 0, z / np.where(ep > 0, ep, 1.0), z)
    v = np.where(p == 1, 0.25 * fib.v, np.where(p >= 2, 4.0 * fib.v, fib.v))
    so = np.choose(np.minimum(p, 2), [fib.tilted[q][0] for q in range(3)])
    co = np.choose(np.minimum(p, 2), [fib.tilted[q][1] for q in range(3)])
    so = np.where(p < 3, so, fib.sin_o)
    co = np.where(p < 3, co, fib.cos_o)
    z = np.maximum(z, 1e-5)
    fac = 1.0 + v * np.log(z + (1.0 - z) * np.exp(-2.0 / v))
    sin_i = -fac * so + _cos_from_sin(fac) * np.cos(2.0 * np.pi * u2) * co
    cos_i = _cos_from_sin(sin_i)
    phi = np.where(p < 3, delta_phi(np.minimum(p, 2), fib.gamma_o, fib.gamma_t)
                   + sample_trimmed_logistic(u1, fib.s), 2.0 * np.pi * u1)
    phi_i = fib.phi_o + phi
    return np.stack([sin_i, cos_i * np.cos(phi_i), cos_i * np.sin(phi_i)], axis=1)


def sample_hair(lobes, rows, s):
    for k in np.unique(s.chosen[rows]):
        r = rows[s.chosen[rows] == k]
        s.wi[r] = sample_hair_dir(lobes, r, k, s.wo[r], s.u_sub[r], s.u1[r], s.u2[r])


register(LobeDef(HAIR_CHIANG, "hair_chiang", "glossy", REFLECTION | TRANSMISSION, sample_hair, eval_hair, "both",
                 params=("roughness", "ior", "absorption", "radial_roughness", "coat", "offset"),
                 reciprocal=False, has_transmission=True,
                 doc="Principled Hair BSDF, Chiang model (Cycles' bsdf_principled_hair_chiang.h) on curves: x "
                     "the fibre's tangent, z its normal",
                 cases=[dict(color=(1, 1, 1), roughness=0.3, radial_roughness=0.3, ior=1.55, offset=0.0349,
                             absorption=tuple(sigma_from_melanin(0.6, 0.0, (1, 1, 1), 0.3))),
                        dict(color=(1, 1, 1), roughness=0.5, radial_roughness=0.6, ior=1.55, offset=0.0349,
                             absorption=(0.0, 0.0, 0.0))]))
