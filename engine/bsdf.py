"""BSDF lobes evaluated, sampled and weighed on whole batches.

A material is a weighted set of lobes (``scene.Lobe``).  ``MaterialTable``
turns the scene's materials into parameter arrays; ``gather`` picks the
parameters for each ray by material id, so a later texture stage only has to
overwrite those per-ray arrays.  All directions here are in the local shading
frame (+Z = shading normal), with wo pointing away from the surface.

Sampling picks one lobe with probability proportional to its estimated
reflectance (one-sample MIS over lobes): for a non-delta lobe the returned
f and pdf are the sums over all non-delta lobes, so ``eval``/``pdf`` and
``sample`` always agree.  Delta lobes (mirror) return their own weight.
"""
from dataclasses import dataclass

import numpy as np

from .sampling import cosine_hemisphere, INV_PI
from .vec import count, luminance, subset

NONE, DIFFUSE, MIRROR, GLOSSY = -1, 0, 1, 2
KIND_IDS = {"diffuse": DIFFUSE, "mirror": MIRROR, "glossy": GLOSSY}
# Below this alpha, GGX is numerically a mirror; Cycles switches to a
# singular reflection at alpha^2 <= 1e-7 too.
MIN_ALPHA = 1e-3
COS_EPS = 1e-9


@dataclass
class Lobes:
    """Per-ray lobe parameters: (N, K) kinds, (N, K, 3) colours, (N, K) alpha,
    (N, K) bool schlick Fresnel (colour is F0)."""
    kind: np.ndarray
    color: np.ndarray
    alpha: np.ndarray
    schlick: np.ndarray

    def __len__(self):
        return len(self.kind)


class MaterialTable:
    def __init__(self, materials):
        k = max(1, max(len(m.lobes) for m in materials))
        n = len(materials)
        self.kind = np.full((n, k), NONE, np.int8)
        self.color = np.zeros((n, k, 3))
        self.alpha = np.ones((n, k))
        self.schlick = np.zeros((n, k), bool)
        self.emission = np.zeros((n, 3))
        for i, mat in enumerate(materials):
            self.emission[i] = mat.emission
            for j, lobe in enumerate(mat.lobes):
                alpha = float(np.clip(lobe.roughness, 0.0, 1.0)) ** 2
                kind = KIND_IDS[lobe.kind]
                if kind == GLOSSY and alpha < MIN_ALPHA:
                    kind = MIRROR
                self.kind[i, j] = kind
                self.color[i, j] = np.maximum(lobe.color, 0.0)
                self.alpha[i, j] = max(alpha, MIN_ALPHA)
                self.schlick[i, j] = lobe.fresnel == "schlick"
        self.emissive = np.any(self.emission > 0, axis=1)
        self.names = [m.name for m in materials]

    def gather(self, mat, uv=None):
        """Per-ray lobe parameters for material ids ``mat`` at texture
        coordinates ``uv`` ((N, 2); unused until materials carry textures)."""
        return Lobes(self.kind[mat], self.color[mat], self.alpha[mat], self.schlick[mat])


# ----------------------------------------------------------------------------
# GGX with visible-normal sampling (Heitz 2018) and height-correlated Smith G2

def ggx_d(h_z, alpha):
    a2 = alpha * alpha
    t = h_z * h_z * (a2 - 1.0) + 1.0
    return a2 / (np.pi * t * t)


def ggx_lambda(w_z, alpha):
    z2 = np.maximum(w_z * w_z, COS_EPS)
    tan2 = np.maximum(1.0 - z2, 0.0) / z2
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


def ggx_sample_vndf(wo, alpha, u1, u2):
    """Visible microfacet normal for wo (wo.z > 0)."""
    vh = np.stack([alpha * wo[:, 0], alpha * wo[:, 1], wo[:, 2]], axis=1)
    vh /= np.linalg.norm(vh, axis=1, keepdims=True)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = np.where(lensq > 0, 1.0 / np.sqrt(np.where(lensq > 0, lensq, 1.0)), 0.0)
    t1 = np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, np.zeros(len(vh))], axis=1)
    t1[lensq <= 0] = (1.0, 0.0, 0.0)
    t2 = np.cross(vh, t1)
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
    p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    ne = np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(nh[:, 2], 1e-12)], axis=1)
    return ne / np.linalg.norm(ne, axis=1, keepdims=True)


def ggx_pdf(wo, wi, alpha):
    """Solid-angle pdf of wi under VNDF sampling of the reflection."""
    h = wo + wi
    hl = np.linalg.norm(h, axis=1)
    h = h / np.where(hl > 0, hl, 1.0)[:, None]
    ok = (wo[:, 2] > COS_EPS) & (wi[:, 2] > COS_EPS) & (hl > 0)
    g1 = 1.0 / (1.0 + ggx_lambda(wo[:, 2], alpha))
    pdf = ggx_d(h[:, 2], alpha) * g1 / (4.0 * np.maximum(wo[:, 2], COS_EPS))
    return np.where(ok, pdf, 0.0), h


def schlick(f0, cos):
    c = np.clip(1.0 - cos, 0.0, 1.0)
    return f0 + (1.0 - f0) * (c ** 5)[:, None]


def _fresnel(color, schlick_on, cos):
    return np.where(schlick_on[:, None], schlick(color, cos), color)


def ggx_eval(wo, wi, color, alpha, schlick_on):
    pdf, h = ggx_pdf(wo, wi, alpha)
    ok = pdf > 0
    g2 = 1.0 / (1.0 + ggx_lambda(wo[:, 2], alpha) + ggx_lambda(wi[:, 2], alpha))
    denom = 4.0 * np.maximum(wo[:, 2], COS_EPS) * np.maximum(wi[:, 2], COS_EPS)
    spec = ggx_d(h[:, 2], alpha) * g2 / denom
    f = _fresnel(color, schlick_on, np.einsum("ij,ij->i", wo, h)) * np.where(ok, spec, 0.0)[:, None]
    return f, pdf


# ----------------------------------------------------------------------------
# The material as a whole

def selection(lobes, wo):
    """(N, K) probability of sampling each lobe."""
    cos_o = np.clip(wo[:, 2], 0.0, 1.0)
    w = np.zeros(lobes.kind.shape)
    for k in range(lobes.kind.shape[1]):
        col = _fresnel(lobes.color[:, k], lobes.schlick[:, k], cos_o)
        w[:, k] = np.where(lobes.kind[:, k] == NONE, 0.0, luminance(col))
    total = w.sum(axis=1, keepdims=True)
    return np.where(total > 0, w / np.where(total > 0, total, 1.0), 0.0)


def eval_pdf(lobes, wo, wi, sel=None):
    """f (N, 3) and pdf (N,) summed over the non-delta lobes."""
    n = len(wo)
    if sel is None:
        sel = selection(lobes, wo)
    f = np.zeros((n, 3))
    pdf = np.zeros(n)
    upper = (wo[:, 2] > COS_EPS) & (wi[:, 2] > COS_EPS)
    for k in range(lobes.kind.shape[1]):
        kind = lobes.kind[:, k]
        d = subset((kind == DIFFUSE) & upper)
        if count(d, n):
            f[d] += lobes.color[d, k] * INV_PI
            pdf[d] += sel[d, k] * wi[d, 2] * INV_PI
        g = subset((kind == GLOSSY) & upper)
        if count(g, n):
            fg, pg = ggx_eval(wo[g], wi[g], lobes.color[g, k], lobes.alpha[g, k], lobes.schlick[g, k])
            f[g] += fg
            pdf[g] += sel[g, k] * pg
    return f, pdf


def sample(lobes, wo, u_lobe, u1, u2):
    """Sample wi.  Returns wi, weight (= f cos / pdf), pdf, delta (bool).

    A sample with weight 0 is an absorbed path.  For delta samples pdf is the
    lobe's selection probability (only its being > 0 matters downstream).
    """
    if lobes.kind.shape[1] == 1:
        return _sample_single(lobes, wo, u1, u2)
    n = len(wo)
    sel = selection(lobes, wo)
    cdf = np.cumsum(sel, axis=1)
    # u_lobe past a rounded CDF that ends an ulp below 1 belongs to the last
    # lobe with a selection probability, not to an unused slot after it.
    last = sel.shape[1] - 1 - np.argmax(sel[:, ::-1] > 0, axis=1)
    chosen = np.minimum((u_lobe[:, None] >= cdf).sum(axis=1), last)
    rows = np.arange(n)
    kind = np.where(cdf[:, -1] > 0, lobes.kind[rows, chosen], NONE)
    wi = np.zeros((n, 3))
    wi[:, 2] = 1.0

    d = subset(kind == DIFFUSE)
    if count(d, n):
        wi[d] = cosine_hemisphere(u1[d], u2[d])[0]
    g = subset(kind == GLOSSY)
    if count(g, n):
        h = ggx_sample_vndf(wo[g], lobes.alpha[rows[g], chosen[g]], u1[g], u2[g])
        wi[g] = 2.0 * np.einsum("ij,ij->i", wo[g], h)[:, None] * h - wo[g]
    m = kind == MIRROR
    if m.any():
        wi[m] = wo[m] * np.array([-1.0, -1.0, 1.0])

    f, pdf = eval_pdf(lobes, wo, wi, sel)
    weight = np.zeros((n, 3))
    smooth = (pdf > 0) & ~m
    weight[smooth] = f[smooth] * (wi[smooth, 2] / pdf[smooth])[:, None]
    if m.any():
        ps = sel[rows[m], chosen[m]]
        col = _fresnel(lobes.color[rows[m], chosen[m]], lobes.schlick[rows[m], chosen[m]], wo[m, 2])
        ok = (wo[m, 2] > COS_EPS) & (ps > 0)
        weight[m] = np.where(ok[:, None], col / np.where(ps > 0, ps, 1.0)[:, None], 0.0)
        pdf[m] = ps
    return wi, weight, pdf, m


def _sample_single(lobes, wo, u1, u2):
    """``sample`` for one-lobe materials: the weight in closed form, without
    evaluating the BSDF again (diffuse: colour; GGX: F G2 / G1(wo))."""
    n = len(wo)
    kind, color = lobes.kind[:, 0], lobes.color[:, 0]
    wi = np.zeros((n, 3))
    wi[:, 2] = 1.0
    weight = np.zeros((n, 3))
    pdf = np.zeros(n)
    up = wo[:, 2] > COS_EPS
    d = subset((kind == DIFFUSE) & up)
    if count(d, n):
        wi[d], pdf[d] = cosine_hemisphere(u1[d], u2[d])
        weight[d] = np.where((pdf[d] > 0)[:, None], color[d], 0.0)
    g = subset((kind == GLOSSY) & up)
    if count(g, n):
        wo_g, alpha = wo[g], lobes.alpha[g, 0]
        h = ggx_sample_vndf(wo_g, alpha, u1[g], u2[g])
        cos_oh = np.einsum("ij,ij->i", wo_g, h)
        wi_g = 2.0 * cos_oh[:, None] * h - wo_g
        ok = wi_g[:, 2] > COS_EPS
        lam_o = ggx_lambda(wo_g[:, 2], alpha)
        g1 = 1.0 / (1.0 + lam_o)
        g2 = 1.0 / (1.0 + lam_o + ggx_lambda(wi_g[:, 2], alpha))
        wi[g] = wi_g
        pdf[g] = np.where(ok, ggx_d(h[:, 2], alpha) * g1 / (4.0 * wo_g[:, 2]), 0.0)
        weight[g] = _fresnel(color[g], lobes.schlick[g, 0], cos_oh) * np.where(ok, g2 / g1, 0.0)[:, None]
    m = (kind == MIRROR) & up
    if m.any():
        wi[m] = wo[m] * np.array([-1.0, -1.0, 1.0])
        weight[m] = _fresnel(color[m], lobes.schlick[m, 0], wo[m, 2])
        pdf[m] = 1.0
    return wi, weight, pdf, m
