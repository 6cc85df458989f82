"""Cycles 5.0's volume scattering probability guiding (VSPG) of camera rays
(kernel/integrator/shade_volume.h, volume_scatter_probability_homogeneous
and volume_integrate_homogeneous; film/volume_guiding_denoise.h).

A camera ray's segment through homogeneous media scatters inside it with
probability q[c] for channel c instead of 1 - T(t_end):

    q = 0.25 (1 - T) + 0.75 clamp(L_s / (L_s + L_t) x max(1 - T) / (1 - exp(-tau)))

L_s and L_t: the pixel's light that came by scattering at its camera ray's
volume points and by passing through them, per-pixel means of the samples
so far, Gaussian-filtered (11 taps, sigma 1.5); tau: the mean optical
depth of the pixel's camera rays that passed through; 1/2 where nothing is
known yet.  Given the scattering, the distance follows the channel's
exponential truncated to the segment; the weights divide by the
probabilities actually used (sum over channels, one-sample MIS), so any q
keeps the estimate unbiased: the guide only moves samples between the fog
and what is seen through it.

Bookkeeping as Cycles' path flags: a path whose camera ray enters a
medium (PATH_RAY_VOLUME_PRIMARY_TRANSMIT) sends what it collects from then
on to L_t, except the direct light estimated at its camera ray's volume
points (shadow rays flagged PATH_RAY_VOLUME_SCATTER), which goes to L_s;
a path that scatters there sends all the rest to L_s.  (Cycles stops
counting that rest at the next surface bounce, where PATH_RAY_VOLUME_SCATTER
is cleared; here it is all of it.)  Per path, ``Paths.guide`` holds
COLUMNS values where the film guides, else none.
"""
import numpy as np

RADIUS = 5
# Cycles' gaussian_params: sigma 1.5, each tap the Gaussian's integral over its pixel.
_HALF = [0.0012273699895602, 0.0084674212370284, 0.0379843612914121, 0.1108921888487800, 0.2108379677336155]
WEIGHTS = np.array(_HALF + [0.2611813817992076] + _HALF[::-1])
DEFENSIVE = 0.75           # Cycles' mix(attenuation, guided, 0.75)
# Paths.guide columns: entered a medium as a camera ray, scattered there,
# radiance at the entry (3), direct light at the camera ray's volume points
# (3), the camera ray's optical depth in media.
COLUMNS = 9
FLAG, SCAT, L0, LS, DEPTH = 0, 1, slice(2, 5), slice(5, 8), 8


class Guide:
    """A film's per-pixel guide sums and the filtered view a pass reads."""

    def __init__(self, width, height):
        n = width * height
        self.width, self.height = width, height
        self.scatter = np.zeros((n, 3))
        self.transmit = np.zeros((n, 3))
        self.depth = np.zeros(n)
        self.depth_paths = np.zeros(n)
        self.view = None
        self.update(np.zeros(n))

    def merge(self, lo, sums):
        s = slice(lo, lo + len(sums[0]))
        self.scatter[s] += sums[0]
        self.transmit[s] += sums[1]
        self.depth[s] += sums[2]
        self.depth_paths[s] += sums[3]

    def update(self, count):
        """The view for the next pass from ``count`` samples per pixel:
        (L_s, L_t) blurred per-pixel means, mean optical depth (inf where
        no camera ray passed through a medium)."""
        inv = 1.0 / np.maximum(np.asarray(count, np.float64), 1.0)
        shape = (self.height, self.width, 3)
        s = blur((self.scatter * inv[:, None]).reshape(shape)).reshape(-1, 3)
        t = blur((self.transmit * inv[:, None]).reshape(shape)).reshape(-1, 3)
        known = self.depth_paths > 0
        od = np.where(known, self.depth / np.where(known, self.depth_paths, 1.0), np.inf)
        self.view = (s, t, od)


def blur(image):
    """Separable 11-tap Gaussian over (H, W, 3); pixels past the edges are
    left out without renormalizing, as Cycles' volume_guiding_filter_x/y."""
    out = image
    for axis in (1, 0):
        pad = [(0, 0)] * 3
        pad[axis] = (RADIUS, RADIUS)
        padded = np.pad(out, pad)
        n = out.shape[axis]
        out = sum(w * np.take(padded, np.arange(k, k + n), axis=axis) for k, w in enumerate(WEIGHTS))
    return out


def scatter_probability(attenuation, scattered, transmitted, depth):
    """(n, 3) q of camera-ray segments from their attenuation 1 - T(t_end),
    their pixels' filtered L_s and L_t and mean optical depth (inf: unknown)."""
    total = scattered + transmitted
    unknown = ~np.any(total != 0, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(total != 0, scattered / np.where(total != 0, total, 1.0), 0.0)
        whole = -np.expm1(-depth)   # 1 - exp(-tau): 1 where unknown (Cycles' FLT_MAX)
        scale = np.where(whole > 0, attenuation.max(axis=1) / np.where(whole > 0, whole, 1.0), 1.0)
    guided = np.clip(ratio * scale[:, None], 0.0, 1.0)
    guided = np.where(unknown[:, None], np.where(attenuation > 0, 0.5, 0.0), guided)
    return (1.0 - DEFENSIVE) * attenuation + DEFENSIVE * guided


def enter(guide, rows, L, sigma_t, t_end):
    """Camera rays (``rows`` of Paths.guide) flying through media: the first
    time, flagged with their radiance so far; their optical depth grows by
    max(sigma_t) t_end (Cycles' path optical_depth, finite segments only)."""
    new = rows[guide[rows, FLAG] == 0]
    guide[new, FLAG] = 1.0
    guide[new, L0] = L[new]
    finite = np.isfinite(t_end)
    guide[rows, DEPTH] += np.where(finite, sigma_t.max(axis=1) * np.where(finite, t_end, 0.0), 0.0)


def guided_flight(flight, k, q, sigma_s, u_channel, u_distance):
    """Redo the homogeneous free flight of rows ``k`` of ``flight`` with
    scattering probabilities q (n, 3) (flight.py's reference form with
    1 - T(t_end) replaced by q): scatter, t and weight in place."""
    pc, st, te = flight.channel_pdf[k], flight.sigma_t[k], flight.t_end[k]
    ss = sigma_s
    n = len(k)
    with np.errstate(invalid="ignore", over="ignore"):
        T_end = np.where(st > 0, np.exp(-st * np.where(st > 0, te[:, None], 0.0)), 1.0)
    mass = 1.0 - T_end
    q = np.where(st > 0, np.clip(q, 0.0, 1.0), 0.0)
    c = np.minimum((u_channel[:, None] >= np.cumsum(pc, axis=1)).sum(axis=1), 2)   # as the kernel's
    i = np.arange(n)
    sig, q_c, m_c = st[i, c], q[i, c], mass[i, c]
    u = np.minimum(u_distance, 1.0 - 2 ** -53)
    sc = (u < q_c) & (sig > 0) & (m_c > 0)
    t = np.full(n, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        # u / q_c is uniform given the scattering: the channel's exponential truncated to t_end
        ts = -np.log1p(-np.minimum(u / q_c, 1.0) * m_c) / np.where(sig > 0, sig, 1.0)
    t[sc] = np.minimum(ts[sc], te[sc])
    weight = T_end.copy()
    s = np.flatnonzero(sc)
    if len(s):
        T_t = np.exp(-st[s] * t[s, None])
        with np.errstate(divide="ignore", invalid="ignore"):
            density = np.where(mass[s] > 0, q[s] * st[s] * T_t / np.where(mass[s] > 0, mass[s], 1.0), 0.0)
        pdf = (pc[s] * density).sum(axis=1)
        weight[s] = ss[s] * T_t / np.maximum(pdf, 1e-300)[:, None]
    p = np.flatnonzero(~sc)
    if len(p):
        P = (pc[p] * (1.0 - q[p])).sum(axis=1)
        weight[p] = np.where(P[:, None] > 0, T_end[p] / np.where(P > 0, P, 1.0)[:, None], 0.0)
    flight.scatter[k], flight.t[k], flight.weight[k] = sc, t, weight
    flight.guided = (k, q)


def light_factor(flight, k, x, factor):
    """media.light_factor's ``factor`` for rows k (lights met at distance x)
    redone where the flight was guided: T(x) / P(no scattering before x),
    P = sum_c pc q_c (1 - T_c(x)) / (1 - T_c(t_end)) taken from 1."""
    g = getattr(flight, "guided", None)
    if g is None:
        return factor
    pos = np.full(len(flight.t_end), -1)
    pos[g[0]] = np.arange(len(g[0]))
    j = pos[k]
    m = np.flatnonzero(j >= 0)
    if len(m) == 0:
        return factor
    rows, q = k[m], g[1][j[m]]
    st, te, xm = flight.sigma_t[rows], flight.t_end[rows], x[m]
    T = np.exp(-st * xm[:, None])
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        mass = 1.0 - np.where(st > 0, np.exp(-st * np.where(st > 0, te[:, None], 0.0)), 1.0)
        before = np.where(mass > 0, q * (1.0 - T) / np.where(mass > 0, mass, 1.0), 0.0)
    P = (flight.channel_pdf[rows] * (1.0 - before)).sum(axis=1)
    ok = (flight.t[rows] > xm) & (P > 0)
    out = factor.copy()
    out[m] = np.where(ok[:, None], T / np.where(P > 0, P, 1.0)[:, None], 0.0)
    return out


def sums(lo, hi, pix, guide, L):
    """A tile's guide sums [L_s, L_t, optical depth, paths counted in it]
    from finished paths (pix, Paths.guide rows, radiance)."""
    n = hi - lo
    inside = guide[:, FLAG] > 0
    p = pix[inside] - lo
    g = guide[inside]
    after = L[inside] - g[:, L0]
    scat = g[:, SCAT] > 0
    scattered = np.where(scat[:, None], after, g[:, LS])
    transmitted = np.where(scat[:, None], 0.0, after - g[:, LS])
    out = [np.zeros((n, 3)), np.zeros((n, 3))]
    for c in range(3):
        out[0][:, c] = np.bincount(p, scattered[:, c], n)
        out[1][:, c] = np.bincount(p, transmitted[:, c], n)
    passed = ~scat   # Cycles writes the optical depth of paths still flagged transmitted
    out.append(np.bincount(p[passed], g[passed, DEPTH], n).astype(np.float64))
    out.append(np.bincount(p[passed], minlength=n).astype(np.float64))
    return out
