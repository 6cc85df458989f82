"""Build engine/data/tables.npz: the albedo tables the materials need.

    .venv/bin/python -m engine.data.build_tables --cycles-tables PATH/src/scene/shader.tables

The GGX tables are the directional albedos Cycles precomputes in
app/cycles_precompute.cpp (same grids, same parametrisation, same meaning),
computed here with the engine's own GGX: instead of Monte Carlo, each value
is a deterministic average of the sample weight over a midpoint grid of the
visible-normal sampler's two uniforms, with both the reflected and the
refracted branch weighed by their Fresnel probabilities.

* ggx_E[mu, rough], ggx_Eavg[rough]: single-scatter GGX reflection albedo
  (Fresnel 1), and its cosine-weighted average 2 int mu E dmu.
* ggx_glass_E[z, mu, rough], ggx_glass_Eavg[z, rough] and the _inv_ pair
  for 1 / IOR: GGX glass (dielectric Fresnel, reflection + refraction) albedo;
  IOR = ior_from_f0(z^4).
* ggx_gen_schlick_ior_s[z, mu, rough]: the Principled BSDF's Fresnel
  estimate: mean over visible normals of the remapped-Fresnel weight s,
  counting samples reflected below the horizon as 0 (as Cycles does).
* ggx_gen_schlick_s[z, mu, rough]: the same for the generalized Schlick
  weight s = (1 - cos_h)^exponent, exponent = 5 (1 - z) / z (Cycles reads
  z = 0.5, exponent 5, for the F82-tint metal's albedo estimate).
* sheen_ltc[3, rough, mu]: the LTC fit of Zeltner et al. 2022 (A, B and
  albedo) that Cycles' Sheen BSDF is defined by; it is data of the model, not
  something to recompute, so it is copied from Cycles' shader.tables.

Takes about a minute on two cores.
"""
import argparse
import os
import re

import numpy as np

from .. import microfacet as mf

HERE = os.path.dirname(os.path.abspath(__file__))
GRID_2D = 256    # uniforms per axis for the 2D tables
GRID_3D = 128    # ... and for the 3D ones
AVG_MU = 32      # Gauss-Legendre nodes for the cosine-weighted averages


def _grid(n):
    u = (np.arange(n) + 0.5) / n
    a, b = np.meshgrid(u, u, indexing="ij")
    return a.ravel(), b.ravel()


def _view(mu, n):
    s = np.sqrt(max(0.0, 1.0 - mu * mu))
    return np.tile([s, 0.0, mu], (n, 1))


def reflection_terms(rough, mu, grid):
    """Per-sample G2/G1 of the reflected direction (0 below the horizon) and
    the microfacet normals, for VNDF samples from the uniform grid."""
    u1, u2 = grid
    n = len(u1)
    wo = _view(mu, n)
    alpha = np.full(n, rough * rough)
    h = mf.ggx_sample_vndf(wo, alpha, u1, u2)
    wi = mf.reflect(wo, h)
    lo = mf.ggx_lambda(wo[:, 2], alpha)
    g = (1.0 + lo) / (1.0 + lo + mf.ggx_lambda(wi[:, 2], alpha))
    return np.where(wi[:, 2] > 0, g, 0.0), wo, h, alpha


def _singular(rough):
    """Cycles treats alpha_x alpha_y <= 2e-10 as a perfect mirror/refractor."""
    return (rough * rough) ** 2 <= 2e-10


def ggx_e(rough, mu, grid):
    if _singular(rough):
        return 1.0
    return reflection_terms(rough, mu, grid)[0].mean()


def glass_e(rough, mu, eta, grid):
    if _singular(rough) or abs(eta - 1.0) < 1e-4:
        return 1.0
    g_r, wo, h, alpha = reflection_terms(rough, mu, grid)
    cos_h = np.einsum("ij,ij->i", wo, h)
    etas = np.full(len(h), eta)
    f, cos_t = mf.fresnel_dielectric(cos_h, etas)
    wi = mf.refract(wo, h, cos_t, etas)
    lo = mf.ggx_lambda(wo[:, 2], alpha)
    g_t = (1.0 + lo) / (1.0 + lo + mf.ggx_lambda(wi[:, 2], alpha))
    g_t = np.where((wi[:, 2] < 0) & (cos_t > 0), g_t, 0.0)
    return (f * g_r + (1.0 - f) * g_t).mean()


def gen_schlick_s(rough, mu, eta, grid):
    if _singular(rough):
        return float(mf.schlick_s(np.array([mu]), np.array([eta]))[0][0])
    g_r, wo, h, _ = reflection_terms(rough, mu, grid)
    s, _ = mf.schlick_s(np.einsum("ij,ij->i", wo, h), np.full(len(h), eta))
    return np.where(g_r > 0, s, 0.0).mean()


def gen_schlick_exp_s(rough, mu, exponent, grid):
    if _singular(rough):
        return float((1.0 - mu) ** exponent)
    g_r, wo, h, _ = reflection_terms(rough, mu, grid)
    cos_h = np.clip(np.einsum("ij,ij->i", wo, h), 0.0, 1.0)
    return np.where(g_r > 0, (1.0 - cos_h) ** exponent, 0.0).mean()


def build_gen_schlick_s(grid=None):
    grid = _grid(GRID_3D) if grid is None else grid
    rough, mus, zs = axis(16), axis(16), axis(16, hi=0.99)
    return np.clip(np.array([[[gen_schlick_exp_s(r, m, 5.0 * (1.0 - z) / z, grid) for r in rough] for m in mus]
                             for z in zs]), 0.0, 1.0)


def axis(n, lo=1e-4, hi=1.0):
    return np.clip(np.arange(n) / (n - 1), lo, hi)


def cos_average(fn):
    x, w = np.polynomial.legendre.leggauss(AVG_MU)
    mu = 0.5 * (x + 1.0)
    return sum(0.5 * wk * 2.0 * m * fn(m) for m, wk in zip(mu, w))


def build_ggx():
    g2, g3 = _grid(GRID_2D), _grid(GRID_3D)
    rough, mus = axis(32), axis(32)
    out = {"ggx_E": np.array([[ggx_e(r, m, g2) for r in rough] for m in mus]),
           "ggx_Eavg": np.array([cos_average(lambda m: ggx_e(r, m, g3)) for r in rough])}
    rough, mus = axis(16), axis(16)
    iors = mf.ior_from_f0(axis(16, hi=0.99) ** 4)
    for name, etas in (("ggx_glass", iors), ("ggx_glass_inv", 1.0 / iors)):
        out[name + "_E"] = np.array([[[glass_e(r, m, e, g3) for r in rough] for m in mus] for e in etas])
        out[name + "_Eavg"] = np.array([[cos_average(lambda m: glass_e(r, m, e, g3)) for r in rough]
                                        for e in etas])
    out["ggx_gen_schlick_ior_s"] = np.array([[[gen_schlick_s(r, m, e, g3) for r in rough] for m in mus]
                                             for e in iors])
    out["ggx_gen_schlick_s"] = build_gen_schlick_s(g3)
    return {k: np.clip(v, 0.0, 1.0) for k, v in out.items()}


def read_cycles_table(path, name):
    with open(path, encoding="utf-8") as handle:
        text = handle.read()
    m = re.search(r"table_" + name + r"\[(\d+)\]\s*=\s*\{(.*?)\};", text, re.S)
    if m is None:
        raise SystemExit(f"{path} has no table_{name}")
    values = np.array([float(v) for v in re.findall(r"[-+0-9.eE]+(?=f)", m.group(2))])
    if len(values) != int(m.group(1)):
        raise SystemExit(f"table_{name}: {len(values)} values, expected {m.group(1)}")
    return values


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles-tables", required=True,
                        help="Cycles' src/scene/shader.tables (for the sheen LTC fit)")
    parser.add_argument("-o", "--output", default=os.path.join(HERE, "tables.npz"))
    args = parser.parse_args()
    out = build_ggx()
    out["sheen_ltc"] = read_cycles_table(args.cycles_tables, "sheen_ltc").reshape(3, 32, 32)
    np.savez_compressed(args.output, **{k: v.astype(np.float32) for k, v in out.items()})
    print("wrote", args.output, {k: v.shape for k, v in out.items()})


if __name__ == "__main__":
    main()
