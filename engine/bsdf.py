"""BSDF lobes evaluated, sampled and weighed on whole batches.

A material is a weighted set of lobes (``scene.Lobe``).  ``MaterialTable``
turns the scene's materials into parameter arrays; ``gather`` picks the
parameters for each ray by material id, so a later texture stage only has to
overwrite those per-ray arrays.  All directions here are in the local shading
frame (+Z = shading normal), with wo pointing away from the surface (wo.z > 0)
and wi.z < 0 for transmitted directions.

Lobes follow Cycles' closures (kernel/closure/*.h): Lambert diffuse and
translucent, GGX reflection (no Fresnel, Schlick, F82-tint metal, or the
Principled BSDF's dielectric Fresnel), GGX glass and refraction (Walter et
al. 2007; smooth ones are delta lobes), Zeltner's LTC sheen, transparent.
Multiscatter GGX is Cycles' energy compensation (1/E(mu) from albedo tables,
darkened by the multiple-bounce Fresnel).  A lobe may lie on top of the
lobes after it (``covers``): they are weighed down by its albedo estimate,
as Cycles layers the Principled BSDF's sheen, coat and specular.

Sampling picks one lobe with probability proportional to its estimated
reflectance (one-sample MIS over lobes): for a non-delta lobe the returned
f and pdf are the sums over all non-delta lobes, so ``eval``/``pdf`` and
``sample`` always agree.  Delta lobes (mirror, smooth glass, transparent)
return their own weight; the Hair BSDF's lobes (OWN_WEIGHT) report their
sample's own value and pdf, which stand in for their eval there.

Each lobe kind is an entry of the registry engine/lobes/ (its parameters,
light class, sample flags, NumPy kernels and test cases): the batch code
here dispatches to the registry's kernels, grouped by kernel, slot by slot.
``weights``, ``selection``, ``eval_pdf`` and ``sample`` run as compiled
per-ray loops over the lobe slots once numba has built them
(engine/bsdf_loops.py); the batch NumPy code here is their twin (JIT off),
equal to float64 rounding.
"""
import math
from dataclasses import field, make_dataclass, replace
from typing import Optional

import numpy as np

from . import bsdf_loops as loops
from . import bump_correction
from . import lobes as registry
from . import microfacet as mf
from . import thinfilm
from .kernels import LoopKernel
# The lobe codes live in lobe_ids (shared with bsdf_loops); bsdf.NONE etc. stay the public names.
from .lobe_ids import GLOSSY_ANISOTROPIC  # noqa: E402
from .lobe_ids import (DIFFUSE, F_CONDUCTOR, F_DIELECTRIC, F_F82, F_NONE, F_SCHLICK, FRESNEL_IDS, GLASS, GLOSSY,  # noqa: F401
                       KIND_IDS, MIN_ALPHA, MIRROR, NONE, RAY_PORTAL, REFRACTION, SHEEN, TRANSLUCENT, TRANSPARENT)
from .lobes.ggx import fresnel as _fresnel, fresnel_of as _fresnel_of, ggx_pdf, schlick  # noqa: F401
from .lobes.ggx import eval_glossy_f as _eval_glossy, ggx_reflect_rows as _ggx_reflect  # noqa: F401
from .lobes.ggx import film_fresnel as _film_fresnel, has_film as _has_film
from .lobes.glass import film_ior_of as _film_ior_of
from .lobes.glass import dielectric as _dielectric, eta_of as _eta, mean3 as _mean3  # noqa: F401
from .lobes.glass import eval_glass_f as _eval_glass, sample_glass_dir as _sample_glass  # noqa: F401
from .lobes.sheen import eval_sheen_f as _eval_sheen, sample_sheen_dir as _sample_sheen  # noqa: F401
from .lobes.sheen import ltc as _ltc, sheen_frame as _sheen_frame, sheen_ltc as _sheen_ltc  # noqa: F401
from .lobes import hair as _hair
from .lobes.hair import HAIR_CHIANG
from .lobes.hair_huang import HAIR_HUANG
from .microfacet import COS_EPS, ggx_d, ggx_lambda, ggx_reflect, ggx_sample_vndf  # noqa: F401
from .sampling import cosine_hemisphere
from .rows import take_arrays
from .textures import MaterialTextures
from .vec import column, contiguous, count, subset


_KIND_TABLES = {}


def kind_in(kind, kinds):
    """np.isin for lobe kinds (int8, NONE = -1): one table lookup instead
    of isin's sort, several times faster on the short lists used here."""
    kind = np.asarray(kind)
    if kind.dtype != np.int8:
        return np.isin(kind, kinds)
    table = _KIND_TABLES.get(kinds)
    if table is None:
        table = np.zeros(256, bool)
        table[np.asarray(kinds, np.int8).view(np.uint8)] = True
        _KIND_TABLES[kinds] = table
    return table.take(kind.view(np.uint8))


def _luminance(rgb):
    """Rec.709 luminance, Blender's default scene-linear space."""
    return 0.2126 * rgb[:, 0] + 0.7152 * rgb[:, 1] + 0.0722 * rgb[:, 2]


def _lobes_post_init(self):
    # Defaults for lobes built from the four original fields (registry.Param.fill).
    for param in registry.EXTRA_PARAMS:
        if getattr(self, param.field) is None:
            setattr(self, param.field, registry.fill_array(param, self))
    if self.back is None:
        self.back = np.zeros(len(self.kind), bool)


_LOBES_DOC = """Per-ray lobe parameters, one array per ``scene.Lobe`` field (N rays,
    K lobe slots; engine/lobes/registry.py PARAMS); a texture stage may
    overwrite any of them after gather:

    kind (N, K) int8, color (N, K, 3), alpha (N, K) = roughness^2,
    schlick (N, K) bool (legacy: fresnel == 'schlick'), then one array per
    further parameter (fresnel int8, ior, f0 (N, K, 3), ...; a parameter left
    out gets its Param.fill); back (N,) bool: the ray arrived on the back face
    (set by the integrator; inverts the IOR of refracting lobes); smooth_n
    (N, 3): where a normal map, bump or Bevel moved the shading normal, the
    smooth normal in the shading frame, and bump_model (N,) int8 which of
    Cycles' bump shadowing terms applies (BUMP_CHIANG, BUMP_GGX); None without.
    diffuse_rot (N, 3, 3), diffuse_split (N,) bool, diffuse_smooth (N, 3):
    Bump Map Correction (engine/bump_correction.py), where the diffuse
    lobes' bent normal differs from the shading frame's corrected one: the
    rotation into its frame, which rows, the smooth normal there; None without.
    """
Lobes = make_dataclass(
    "Lobes", [("kind", np.ndarray), ("color", np.ndarray), ("alpha", np.ndarray), ("schlick", np.ndarray)]
    + [(p.field, Optional[np.ndarray], field(default=None)) for p in registry.EXTRA_PARAMS]
    + [(name, Optional[np.ndarray], field(default=None)) for name in ("back", "smooth_n", "bump_model", "diffuse_rot",
                                                                   "diffuse_split", "diffuse_smooth")],
    namespace={"__post_init__": _lobes_post_init, "__len__": lambda self: len(self.kind), "__doc__": _LOBES_DOC})
Lobes.__module__ = __name__

# Per-lobe table arrays beside kind/color/alpha/schlick: (name, trailing shape, dtype).
EXTRA_FIELDS = tuple((p.field, p.tail, p.dtype) for p in registry.EXTRA_PARAMS)


def _lobe_extras(lobe):
    """The extra table values of one scene.Lobe (registry.Param.to_table)."""
    return {p.field: registry.table_value(p, lobe) for p in registry.EXTRA_PARAMS}


class MaterialTable:
    def __init__(self, materials):
        # Texture expressions are compiled apart; the constant tables below
        # are built from the materials with each expression replaced by its
        # mean, and gather overwrites the textured parameters per ray.
        self.textures = MaterialTextures(materials)
        materials = self.textures.constants
        k = max(1, max(len(m.lobes) for m in materials))
        n = len(materials)
        self.kind = np.full((n, k), NONE, np.int8)
        self.color = np.zeros((n, k, 3))
        self.alpha = np.ones((n, k))
        self.schlick = np.zeros((n, k), bool)
        for name, tail, dtype in EXTRA_FIELDS:
            setattr(self, name, np.zeros((n, k) + tail, dtype))
        self.emission = np.zeros((n, 3))
        for i, mat in enumerate(materials):
            self.emission[i] = mat.emission
            for j, lobe in enumerate(mat.lobes):
                alpha = float(np.clip(lobe.roughness, 0.0, 1.0)) ** 2
                kind = KIND_IDS[lobe.kind]
                if kind == GLOSSY and alpha < MIN_ALPHA and not getattr(lobe, "covers", 0):
                    kind = MIRROR
                self.kind[i, j] = kind
                self.color[i, j] = np.maximum(lobe.color, 0.0)
                self.alpha[i, j] = max(alpha, MIN_ALPHA)
                self.schlick[i, j] = lobe.fresnel == "schlick"
                for name, value in _lobe_extras(lobe).items():
                    getattr(self, name)[i, j] = value
        self.emissive = np.any(self.emission > 0, axis=1)
        self._zero_fields = frozenset(j for j, name in enumerate(_GATHERED) if not getattr(self, name).any())
        self.names = [m.name for m in materials]
        # material -> the lobes whose albedo dims its emission (Principled sheen, coat)
        self.emission_layers = {i: tuple(int(k) for k in getattr(m, "emission_layers", ()))
                                for i, m in enumerate(materials) if getattr(m, "emission_layers", ())}

    def dim_emission(self, mat, shading, cos, emission, albedo=True):
        """Emission (N, 3) seen at |cos| to the shading normal, dimmed where
        the material's emission lies under layers: by 1 - each layer's albedo
        estimate and the coat tint along the view, as Cycles' Principled BSDF
        weighs its emission closure (the same terms ``weights`` applies to the
        lobes under the layers).  ``shading``: the points' ShadingContext
        (textured layers), or None."""
        if not self.emission_layers:
            return emission
        out = None
        for i, layers in self.emission_layers.items():
            rows = np.nonzero(mat == i)[0]
            if not len(rows):
                continue
            if out is None:
                out = np.array(emission, dtype=np.float64, copy=True)
            lobes = self.gather(mat[rows], None if shading is None else shading.take(rows))
            out[rows] *= emission_dimming(lobes, np.clip(np.abs(cos[rows]), 0.0, 1.0), layers, albedo)
        return emission if out is None else out

    def gather(self, mat, uv=None):
        """Per-ray lobe parameters for material ids ``mat`` at texture
        coordinates ``uv`` ((N, 2)): constants gathered, then the textured
        parameters of the rays' materials evaluated at their UVs."""
        tables = tuple(getattr(self, name) for name in _GATHERED)
        # A field that is zero in every material (hair, portal, film ... fields
        # of a scene without them, some 60 % of a row's bytes) is not copied:
        # np.zeros of a large array costs nothing until touched, a gather
        # reads and writes every byte.  Its column-less view keeps the
        # kernel's signature.
        zero = self._zero_fields
        out = tuple((np.zeros if j in zero else np.empty)((len(mat),) + a.shape[1:], a.dtype)
                    for j, a in enumerate(tables))
        _gather_kernel(_c(mat, np.int64), *_gather_groups(tables, out, zero))
        lobes = Lobes(*out)
        if self.textures.any:
            self.textures.apply(mat, uv, lobes, MIN_ALPHA)
        return lobes


# ----------------------------------------------------------------------------
# Per-ray weights that depend on the view direction

def _rough(lobes, k):
    return np.sqrt(lobes.alpha[:, k])


def _glossy_fss(lobes, k, rows):
    """Average single-scattering Fresnel of a glossy lobe (Kulla-Conty's
    Fss, as Cycles' setup functions compute it)."""
    code = lobes.fresnel[rows, k]
    f0 = lobes.f0[rows, k]
    fss = lobes.color[rows, k].copy()                      # constant Fresnel: the colour
    ior = np.maximum(lobes.ior[rows, k], 1e-5)
    f0_real = mf.f0_from_ior(ior)
    s = np.clip((mf.dielectric_fss(ior) - f0_real) / np.maximum(1.0 - f0_real, 1e-12), 0.0, 1.0)
    diel = f0 + (1.0 - f0) * s[:, None]
    b = mf.f82_b(f0, lobes.edge_tint[rows, k])
    fss = np.where((code == F_DIELECTRIC)[:, None], diel, fss)
    fss = np.where((code == F_F82)[:, None], mf.f82_fss(f0, b), fss)
    m = np.flatnonzero(code == F_CONDUCTOR)   # n in f0, k in edge_tint
    if len(m):
        fss[m] = mf.conductor_fss(f0[m], lobes.edge_tint[rows, k][m])
    return np.where((code == F_SCHLICK)[:, None], f0 + (1.0 - f0) / 21.0, fss)


def _energy(lobes, k, rows, mu):
    """Multiscatter GGX as Cycles: scale by 1/E(mu) and darken by the
    multiple-bounce Fresnel: returns (1 + Fms (1 - E) / E) per channel and the
    darkening alone (what a layer's albedo estimate includes)."""
    t = mf.tables()
    rough = _rough(lobes, k)[rows]
    if lobes.kind[rows[0] if len(rows) else 0, k] == GLASS:
        eta = _eta(lobes, k)[rows]
        inv = eta < 1.0
        z = mf.ior_z(np.where(inv, 1.0 / eta, eta))
        e = np.where(inv, mf.lookup(t["ggx_glass_inv_E"], rough, mu, z),
                     mf.lookup(t["ggx_glass_E"], rough, mu, z))
        e_avg = np.where(inv, mf.lookup(t["ggx_glass_inv_Eavg"], rough, z),
                         mf.lookup(t["ggx_glass_Eavg"], rough, z))
        fss = lobes.color[rows, k] * lobes.transmission_tint[rows, k]
    else:
        e = mf.lookup(t["ggx_E"], rough, mu)
        e_avg = mf.lookup(t["ggx_Eavg"], rough)
        fss = _glossy_fss(lobes, k, rows)
    e = np.maximum(e, 1e-4)
    missing = ((1.0 - e) / e)[:, None]
    fms = fss * e_avg[:, None] / np.maximum(1.0 - fss * (1.0 - e_avg)[:, None], 1e-12)
    # Cycles' energy_scale and darkening fold together into 1 + Fms (1 - E) / E.
    factor = 1.0 + fms * missing
    return factor, factor / (1.0 + missing)


def _layer_albedo(lobes, k, rows, mu):
    """Cycles' albedo estimate of a layer lobe (relative to the weight of
    what it covers): colour times the Fresnel estimate (tables; under a thin
    film its reflectance at the view angle) for a glossy layer, colour times
    the LTC albedo for sheen."""
    col = lobes.color[rows, k]
    kind = lobes.kind[rows, k]
    rough = _rough(lobes, k)[rows]
    out = col.copy()
    sheen = kind == SHEEN
    if sheen.any():
        out[sheen] = col[sheen] * _sheen_ltc(rough[sheen], mu[sheen])[2][:, None]
    gl = ~sheen
    if gl.any():
        ior = np.maximum(lobes.ior[rows[gl], k], 1e-5)
        s = mf.lookup(mf.tables()["ggx_gen_schlick_ior_s"], rough[gl], mu[gl], mf.ior_z(ior))
        f0 = lobes.f0[rows[gl], k]
        est = f0 + (1.0 - f0) * s[:, None]
        # Under a thin film Cycles has no table: the film's reflectance at the view angle.
        film = np.flatnonzero(_has_film(lobes, rows[gl], k) & (lobes.fresnel[rows[gl], k] == F_DIELECTRIC))
        if len(film):
            est[film] = _film_fresnel(F_DIELECTRIC, lobes, rows[gl][film], k, mu[gl][film])
        ms = lobes.multiscatter[rows[gl], k]
        if ms.any():
            g = rows[gl][ms]
            est[ms] *= _energy(lobes, k, g, mu[gl][ms])[1]
        out[gl] = col[gl] * est
    return out


def _coat_absorption(lobes, k, rows, mu):
    """Coat tint seen along the refracted view ray: tint^(1 / cos_t), mixed
    in by the coat weight (Cycles' Beer-Lambert approximation)."""
    absorb = lobes.absorb[rows, k]
    ior = np.maximum(lobes.ior[rows, k], 1.0)
    cos_t = np.sqrt(np.maximum(1.0 - (1.0 - mu * mu) / (ior * ior), 1e-12))
    tinted = np.power(np.maximum(absorb, 0.0), (1.0 / cos_t)[:, None])
    w = _mean3(lobes.color[rows, k])[:, None]
    return 1.0 + w * (tinted - 1.0)


def weights(lobes, wo):
    """(N, K, 3) effective lobe colours for view direction wo: weight x
    colour, energy compensation (Multiscatter GGX), and the attenuation of
    lobes lying under a layer (coat, sheen, Principled specular) by that
    layer's albedo, as Cycles' Principled BSDF."""
    out = np.empty(lobes.kind.shape + (3,))
    _weights_kernel(_lobe_arrays(lobes), _table_arrays(), _c(wo), out)
    return out


def closure_weights(lobes, wo):
    """(N, K, 3) the lobes' weights as Cycles keeps them in a closure's
    weight (what its Roughness bake averages with): ``weights`` without the
    multiscatter GGX energy scale 1 / E(mu), which Cycles applies in eval
    (bsdf->energy_scale); the multiple-bounce Fresnel darkening stays."""
    w = weights(lobes, wo)
    mu = np.clip(wo[:, 2], 0.0, 1.0)
    for k in range(lobes.kind.shape[1]):
        ms = np.nonzero(lobes.multiscatter[:, k] & kind_in(lobes.kind[:, k], (GLOSSY, GLOSSY_ANISOTROPIC, GLASS)))[0]
        glass = lobes.kind[ms, k] == GLASS
        for part in (ms[glass], ms[~glass]):
            if len(part):
                factor, darkening = _energy(lobes, k, part, mu[part])
                w[part, k] *= np.where(factor > 0, darkening / np.where(factor > 0, factor, 1.0), 1.0)
    return w


def _weights_numpy(lobes, wo):
    n, kk = lobes.kind.shape
    mu = np.clip(wo[:, 2], 0.0, 1.0)
    w = lobes.color * lobes.weight[:, :, None]
    w = np.where((lobes.fresnel == F_SCHLICK)[:, :, None], lobes.weight[:, :, None], w)
    for k in range(kk):
        sheen = np.nonzero(lobes.kind[:, k] == SHEEN)[0]
        if len(sheen):
            # Cycles folds the sheen's directional albedo into its weight.
            w[sheen, k] *= _sheen_ltc(_rough(lobes, k)[sheen], mu[sheen])[2][:, None]
        ms = np.nonzero(lobes.multiscatter[:, k] & kind_in(lobes.kind[:, k], (GLOSSY, GLOSSY_ANISOTROPIC, GLASS)))[0]
        if len(ms):
            glass = lobes.kind[ms, k] == GLASS
            for part in (ms[glass], ms[~glass]):
                if len(part):
                    w[part, k] *= _energy(lobes, k, part, mu[part])[0]
        layer = np.nonzero(lobes.covers[:, k] > 0)[0]
        if len(layer) == 0:
            continue
        below = 1.0 - np.clip(_layer_albedo(lobes, k, layer, mu[layer]).max(axis=1), 0.0, 1.0)
        tint = _coat_absorption(lobes, k, layer, mu[layer])
        for j in range(k + 1, kk):
            under = lobes.covers[layer, k] >= j - k
            w[layer, j] *= np.where(under, below, 1.0)[:, None]
            w[layer, j] *= np.where(under[:, None], tint, 1.0)
    return np.maximum(w, 0.0)


def emission_dimming(lobes, mu, layers, albedo=True):
    """(N, 3) factor of an emission under the layer lobes ``layers`` (slot
    indices) seen at cos mu: the product of 1 - max(layer albedo) and the
    coat tint (_layer_albedo, _coat_absorption, as ``weights``); without
    ``albedo`` the coat tint alone."""
    n = len(mu)
    factor = np.ones((n, 3))
    rows = np.arange(n)
    for k in layers:
        present = lobes.kind[:, k] != NONE
        below = 1.0 - np.clip(_layer_albedo(lobes, k, rows, mu).max(axis=1), 0.0, 1.0) if albedo else np.ones(n)
        step = below[:, None] * _coat_absorption(lobes, k, rows, mu)
        factor *= np.where(present[:, None], np.maximum(step, 0.0), 1.0)
    return factor


def closure_albedos(lobes, wo):
    """Each lobe's albedo as Cycles' ``bsdf_albedo`` estimates it for the
    Diffuse / Glossy / Transmission Color passes and the denoising albedo:
    (reflection, transmission), each (N, K, 3).  The closure weight (colour,
    layering, the multiscatter darkening but not its 1/E energy scale) times
    the Fresnel estimate of ``bsdf_microfacet_estimate_albedo``: F82 metals
    mix(F0, 1, s) with s from ``ggx_gen_schlick_s`` at exponent 5 (the B
    term left out, as Cycles does), the Principled dielectric and coat
    mix(F0, 1, s) from ``ggx_gen_schlick_ior_s``; glass splits into that
    reflection estimate and the refracted rest at the view angle,
    (1 - F(mu)) x transmission tint; under a thin film (no table) the
    film's reflectance at the view angle F(mu) instead; other lobes carry
    their weight whole (sheen's weight holds its albedo)."""
    mu = np.clip(wo[:, 2], 0.0, 1.0)
    w = weights(lobes, wo)
    refl = w.copy()
    trans = np.zeros_like(w)
    t = mf.tables()
    for k in range(lobes.kind.shape[1]):
        kind = lobes.kind[:, k]
        glossy = kind_in(kind, (GLOSSY, GLASS, MIRROR, GLOSSY_ANISOTROPIC))
        ms = np.nonzero(lobes.multiscatter[:, k] & kind_in(kind, (GLOSSY, GLASS)))[0]
        if len(ms):
            glass = kind[ms] == GLASS
            for part in (ms[glass], ms[~glass]):
                if len(part):
                    factor, darkening = _energy(lobes, k, part, mu[part])
                    refl[part, k] *= darkening / np.maximum(factor, 1e-12)
        rough = _rough(lobes, k)
        code = lobes.fresnel[:, k]
        f0 = lobes.f0[:, k]
        est = np.ones_like(f0)
        metal = np.nonzero(glossy & (code == F_F82) & (kind != GLASS))[0]
        if len(metal):
            s = mf.lookup(t["ggx_gen_schlick_s"], rough[metal], mu[metal], np.full(len(metal), 0.5))
            est[metal] = f0[metal] + (1.0 - f0[metal]) * s[:, None]
        # A physical conductor has no table in Cycles: its Fresnel at the view angle.
        cond = np.nonzero(glossy & (code == F_CONDUCTOR) & (kind != GLASS))[0]
        if len(cond):
            est[cond] = mf.conductor(mu[cond], f0[cond], lobes.edge_tint[cond, k])
        eta = _eta(lobes, k)
        diel = np.nonzero(glossy & ((code == F_DIELECTRIC) | (kind == GLASS)))[0]
        if len(diel):
            e = eta[diel]
            s = mf.lookup(t["ggx_gen_schlick_ior_s"], rough[diel], mu[diel], mf.ior_z(e))
            exact = mf.schlick_s(mu[diel], e)[0]
            # Cycles' real-Fresnel branch reads the table only above IOR 1.
            s = np.where(e > 1.0, s, exact)
            est[diel] = f0[diel] + (1.0 - f0[diel]) * s[:, None]
        # Thin films: no table either, the film's reflectance at the view angle.
        film = np.flatnonzero(glossy & _has_film(lobes, slice(None), k))
        glass_film = film[kind[film] == GLASS]
        other = film[kind[film] != GLASS]
        for c in (F_F82, F_DIELECTRIC, F_CONDUCTOR):
            m = other[code[other] == c]
            if len(m):
                est[m] = _film_fresnel(c, lobes, m, k, mu[m])
        if len(glass_film):
            est[glass_film] = _film_fresnel(F_DIELECTRIC, lobes, glass_film, k, mu[glass_film], eta[glass_film],
                                            _film_ior_of(lobes, glass_film, k))
        through = np.nonzero(kind_in(kind, (GLASS, REFRACTION)))[0]
        if len(through):
            e = eta[through]
            cos_t = mf.fresnel_dielectric(mu[through], e)[1]
            ft = f0[through]
            f = ft + (1.0 - ft) * mf.schlick_s(mu[through], e)[0][:, None]
            f = np.where(np.isin(through, glass_film)[:, None], est[through], f)
            glass = (kind[through] == GLASS)[:, None]
            tint = np.where(glass, lobes.transmission_tint[through, k], 1.0)
            passes = np.where(glass, 1.0 - f, (cos_t > 0)[:, None] * 1.0)
            trans[through, k] = refl[through, k] * tint * np.maximum(passes, 0.0)
            refl[through, k] = np.where(glass, refl[through, k], 0.0)
        refl[:, k] *= est
    return np.maximum(refl, 0.0), np.maximum(trans, 0.0)


def transparency(lobes):
    """(N, 3) light a surface lets straight through: the summed weight x
    colour of its transparent lobes (Cycles' closure_transparent_extinction),
    what a shadow ray keeps crossing it.  The exporter never puts a
    transparent lobe under a layer, so this is also its entry in ``weights``."""
    # A Ray Portal's weight counts too (Cycles' bsdf_ray_portal_setup): what
    # a path past its last vertex crosses; shadow rays stop at portals
    # (integrator/transparency.transmittance).
    t = lobes.color * (lobes.weight * ((lobes.kind == TRANSPARENT) | (lobes.kind == RAY_PORTAL)))[:, :, None]
    return np.maximum(t.sum(axis=1), 0.0)


def _albedo_guess(lobes, k, mu):
    """Cheap estimate of a lobe's albedo for choosing lobes (any positive
    guess is unbiased: it only moves variance): the registry's albedo_guess,
    else 1; 0 for an empty slot."""
    kind = lobes.kind[:, k]
    guess = np.ones(len(kind))
    for fn, ids in _groups("albedo_guess"):
        guess = np.where(kind_in(kind, ids), fn(lobes, k, mu), guess)
    return np.where(kind == NONE, 0.0, guess)


_GROUPS = {}


def _groups(kernel):
    """[(the kernel, the ids of the lobes sharing it)] for one kernel kind of
    the registry ('eval', 'sample', 'albedo_guess'); eval groups also by side
    and ``evaluates``.  Lobes sharing a kernel (glass and refraction) run as
    one batch."""
    key = (kernel, len(registry.REGISTRY))
    if key not in _GROUPS:
        groups = {}
        for d in registry.BY_ID.values():
            fn = getattr(d, kernel)
            if fn is not None:
                extra = (d.side, d.evaluates) if kernel == "eval" else ()
                groups.setdefault((fn,) + extra, []).append(d.id)
        _GROUPS[key] = [k + (tuple(sorted(ids)),) if kernel == "eval" else (k[0], tuple(sorted(ids)))
                        for k, ids in groups.items()]
    return _GROUPS[key]


def selection(lobes, wo, w=None):
    """(N, K) probability of sampling each lobe."""
    if w is None:
        w = weights(lobes, wo)
    out = np.empty(lobes.kind.shape)
    _selection_kernel(_lobe_arrays(lobes), _table_arrays(), _c(wo), _c(w), out)
    return out


def _selection_numpy(lobes, wo, w):
    cos_o = np.clip(wo[:, 2], 0.0, 1.0)
    sel = np.zeros(lobes.kind.shape)
    for k in range(lobes.kind.shape[1]):
        col = w[:, k]
        legacy = lobes.fresnel[:, k] == F_SCHLICK
        if legacy.any():
            col = np.where(legacy[:, None], schlick(lobes.color[:, k], cos_o) * w[:, k], col)
        # Cycles' closure sample weight: the mean of the weight's channels
        # (bsdf_alloc: fabsf(average(weight))), not its luminance: the lobe
        # choice sets the BSDF pdf that MIS weighs, and a bake without Emit keeps
        # only the light-sampled share (+0.7 % with luminance on a checker mix).
        sel[:, k] = col.mean(axis=1) * _albedo_guess(lobes, k, cos_o)
    sel = np.maximum(sel, 0.0)
    total = sel[:, 0]
    for k in range(1, sel.shape[1]):
        total = total + sel[:, k]
    total = total[:, None]
    return np.where(total > 0, sel / np.where(total > 0, total, 1.0), 0.0)


# ----------------------------------------------------------------------------
# The material as a whole

# Cycles' bump shadowing terms (closure/bsdf.h), by Blender version.
BUMP_CHIANG = 0   # up to 4.4: Chiang, Li and Burley 2019, "Taming the Shadow Terminator"
BUMP_GGX = 1      # 4.5 on: Conty Estevez et al., "A Microfacet-Based Shadowing Function ..."


def bump_model(version):
    """Which bump shadowing term Cycles of Blender ``version`` applies."""
    return BUMP_GGX if tuple(version) >= (4, 5) else BUMP_CHIANG


def bump_shadowing(smooth_n, model, wi):
    """Cycles' bump_shadowing_term for light arriving along wi (shading
    frame) where the shading normal N (z) left the smooth normal Ns:
    (factor for diffuse lobes, rows every lobe rejects when evaluated) or
    (None, None) where no normal was moved.  The 4.5+ term rejects light and
    normal on opposite sides of Ns for every closure evaluated and for
    diffuse ones sampled; its softening, and all of the older term, scale
    diffuse lobes only."""
    if smooth_n is None:
        return None, None
    n = len(smooth_n)
    term, keep = np.empty(n), np.empty(n, np.bool_)
    _bump_shadowing_kernel(_c(smooth_n), _c(column(model, n, np.int8), np.int8), _c(wi), term, keep)
    return term, keep


def _bump_shadowing_numpy(s, model, wi, term_out, keep_out):
    cos_si = s[:, 0] * wi[:, 0] + s[:, 1] * wi[:, 1] + s[:, 2] * wi[:, 2]
    cos_sn, cos_ni = s[:, 2], wi[:, 2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        den = cos_ni * cos_sn
        g = np.where(den != 0, cos_si / np.where(den != 0, den, 1.0), 0.0)
        chiang = np.where(g >= 1.0, 1.0, np.where(g < 0.0, 0.0, -g * g * g + g * g + g))
        wrong = cos_si * cos_sn * cos_ni < 0.0
        ci, cd = np.abs(cos_si), np.abs(cos_sn)
        alpha2 = np.clip(0.125 * (1.0 / (cd * cd) - 1.0), 0.0, 1.0)
        tan2_i = np.maximum(1.0 / (ci * ci) - 1.0, 0.0)
        g1 = 1.0 / (1.0 + 0.5 * (np.sqrt(1.0 + alpha2 * tan2_i) - 1.0))
    ggx = np.where((cd >= 1.0) | (ci >= 1.0), 1.0, np.where(ci < 1e-6, 0.0, g1))
    ggx = np.where(wrong, 0.0, ggx)
    use_ggx = model == BUMP_GGX
    term_out[:], keep_out[:] = np.where(use_ggx, ggx, chiang), ~(use_ggx & wrong)


def _bump_shadowing_rows(s, model, wi, term, keep):
    """bump_shadowing per row (its NumPy form: _bump_shadowing_numpy)."""
    for i in range(len(s)):
        cos_sn, cos_ni = s[i, 2], wi[i, 2]
        cos_si = (s[i, 0] * wi[i, 0] + s[i, 1] * wi[i, 1]) + s[i, 2] * wi[i, 2]
        wrong = cos_si * cos_sn * cos_ni < 0.0
        if model[i] == BUMP_GGX:
            ci, cd = abs(cos_si), abs(cos_sn)
            if wrong:
                g1 = 0.0
            elif cd >= 1.0 or ci >= 1.0:
                g1 = 1.0
            elif ci < 1e-6:
                g1 = 0.0
            else:
                alpha2 = min(max(0.125 * (1.0 / (cd * cd) - 1.0), 0.0), 1.0)
                tan2_i = max(1.0 / (ci * ci) - 1.0, 0.0)
                g1 = 1.0 / (1.0 + 0.5 * (np.sqrt(1.0 + alpha2 * tan2_i) - 1.0))
            term[i], keep[i] = g1, not wrong
        else:
            den = cos_ni * cos_sn
            g = cos_si / den if den != 0 else 0.0
            term[i] = 1.0 if g >= 1.0 else (0.0 if g < 0.0 else -g * g * g + g * g + g)
            keep[i] = True


def eval_pdf(lobes, wo, wi, sel=None, w=None, sampled=False):
    """f (N, 3) and pdf (N,) summed over the non-delta lobes; wi below the
    surface (wi.z < 0) reaches the transmitting lobes only.  sampled: wi
    came from ``sample`` (Cycles then softens only a reflecting diffuse
    lobe's bump shadowing and rejects no other lobe).  Rows with a bent
    normal of their own (Lobes.diffuse_split) evaluate their diffuse lobes
    in its frame, f scaled so that f |wi.z| is Cycles' f cos(bent, wi)."""
    if w is None:
        w = weights(lobes, wo)
    if sel is None:
        sel = selection(lobes, wo, w)
    split = lobes.diffuse_split
    if split is None or not split.any():
        return _eval_pdf_frame(lobes, wo, wi, sel, w, sampled)
    bent = kind_in(lobes.kind, bump_correction.BENT_KINDS) & split[:, None]
    main = replace(lobes, kind=np.where(bent, NONE, lobes.kind).astype(lobes.kind.dtype))
    f, pdf = _eval_pdf_frame(main, wo, wi, sel, w, sampled)
    rows = np.flatnonzero(split & bent.any(axis=1))
    if len(rows):
        sub = take_arrays(lobes, rows, len(lobes))
        keep = kind_in(sub.kind, bump_correction.BENT_KINDS)
        rot = sub.diffuse_rot
        sub = replace(sub, kind=np.where(keep, sub.kind, NONE).astype(sub.kind.dtype),
                                  smooth_n=sub.diffuse_smooth)
        wo_d = bump_correction.view_above(bump_correction.apply(rot, wo[rows]))
        wi_d = bump_correction.apply(rot, wi[rows])
        fd, pd = _eval_pdf_frame(sub, wo_d, wi_d, sel[rows], w[rows], sampled)
        cos = np.abs(wi[rows, 2])
        scale = np.where(cos > 1e-12, np.abs(wi_d[:, 2]) / np.where(cos > 1e-12, cos, 1.0), 0.0)
        f[rows] += fd * scale[:, None]
        pdf[rows] += pd
    return f, pdf


def _eval_pdf_frame(lobes, wo, wi, sel, w, sampled):
    """eval_pdf in the shading frame alone."""
    n = len(wo)
    diffuse_term, keep = bump_shadowing(lobes.smooth_n, lobes.bump_model, wi)
    f, pdf = np.empty((n, 3)), np.empty(n)
    _eval_pdf_kernel(_lobe_arrays(lobes), _table_arrays(), _c(wo), _c(wi), _c(sel), _c(w),
                     _NO_TERM if diffuse_term is None else _c(diffuse_term),
                     _NO_KEEP if keep is None else _c(keep, bool), bool(sampled), f, pdf)
    return f, pdf


def _eval_pdf_numpy(lobes, wo, wi, sel, w, diffuse_term, keep, sampled):
    n = len(wo)
    f = np.zeros((n, 3))
    pdf = np.zeros(n)
    front = wo[:, 2] > COS_EPS
    upper = front & (wi[:, 2] > COS_EPS)
    lower = front & (wi[:, 2] < -COS_EPS)
    sides = {"upper": upper, "lower": lower, "both": front}
    for k in range(lobes.kind.shape[1]):
        kind = lobes.kind[:, k]
        for fn, side, evaluates, ids in _groups("eval"):
            mask = kind_in(kind, ids) & sides[side]
            if evaluates is not None:
                mask &= evaluates(lobes, k)
            d = subset(mask)
            if count(d, n):
                term = None if diffuse_term is None else diffuse_term[d]
                fd, pd = fn(lobes, d, k, wo[d], wi[d], w[d, k], sel[d, k], term, sampled)
                f[d] += fd
                pdf[d] += pd
    if keep is not None and not sampled:
        f = np.where(keep[:, None], f, 0.0)
        pdf = np.where(keep, pdf, 0.0)
    return f, pdf


# ----------------------------------------------------------------------------
# The compiled per-ray forms (engine/bsdf_loops.py) and their NumPy twins

_NO_TERM, _NO_KEEP = np.empty(0), np.empty(0, bool)


_c = contiguous   # the loops' array arguments


def _lobe_arrays(lobes):
    return tuple(_c(getattr(lobes, name), dtype) for name, _, dtype in loops.LOBE_FIELDS)


def _table_arrays():
    t = mf.tables()
    if "thin_film_cmf" not in t:
        t["thin_film_cmf"] = np.ascontiguousarray(thinfilm.sensitivity_table(np.float64))
    return tuple(t[name] for name, _ in loops.TABLES)


registry.hair_huang.bind(_table_arrays, loops)


def _lobes_of(arrays):
    kind, color, alpha, fresnel, *rest = arrays
    return Lobes(kind, color, alpha, fresnel == F_SCHLICK, fresnel, *rest)


def _weights_twin(lobes, tables, wo, out):
    out[:] = _weights_numpy(_lobes_of(lobes), wo)


def _selection_twin(lobes, tables, wo, w, out):
    out[:] = _selection_numpy(_lobes_of(lobes), wo, w)


def _eval_pdf_twin(lobes, tables, wo, wi, sel, w, diffuse_term, keep, sampled, f, pdf):
    bump = len(diffuse_term) > 0
    f[:], pdf[:] = _eval_pdf_numpy(_lobes_of(lobes), wo, wi, sel, w, diffuse_term if bump else None,
                                   keep if bump else None, sampled)


def _gather_numpy(mat, *groups):
    # np.take: rows copied several times faster than by fancy indexing.
    for tables, out in zip(groups[::2], groups[1::2]):
        for a, o in zip(tables, out):
            np.take(a, mat, axis=0, out=o)


def _gather_groups(tables, out, skip=frozenset()):
    """gather_loop's arguments: (tables, outputs) of each dtype of
    loops.GATHER_DTYPES, as 2D views; those of the fields ``skip`` (indices)
    without columns, so the loop copies nothing of them."""
    groups = []
    for dtype in loops.GATHER_DTYPES:
        pick = [j for j, a in enumerate(tables) if a.dtype == dtype]
        groups += [tuple(_flat2d(tables[j], j in skip) for j in pick), tuple(_flat2d(out[j], j in skip) for j in pick)]
    return groups


def _flat2d(a, empty=False):
    # math.prod, not np.prod: this runs some 50 times a bounce, and np.prod
    # of a shape tuple costs several microseconds of interpreter each time.
    flat = a.reshape(a.shape[0], math.prod(a.shape[1:]))
    return flat[:, :0] if empty else flat


class _Loop(LoopKernel):
    def build(self, numba):
        loops.register(numba)
        return super().build(numba)


def _sample_twin(lobes, tables, wo, u_lobe, u1, u2, sel, w, wi, weight, pdf, delta, smooth):
    wi[:], weight[:], pdf[:], delta[:], smooth[:] = _sample_numpy(_lobes_of(lobes), wo, u_lobe, u1, u2, sel, w)


_LOBES, _TABLES = loops.LOBES_SIGNATURE, loops.TABLES_SIGNATURE
# MaterialTable's per-lobe arrays in Lobes' field order, and their types.
_GATHERED = ("kind", "color", "alpha", "schlick") + tuple(name for name, _, _ in EXTRA_FIELDS)
_gather_kernel = _Loop(loops.gather_loop, loops.GATHER_SIGNATURE, _gather_numpy)
_bump_shadowing_kernel = LoopKernel(_bump_shadowing_rows, "void(float64[:, ::1], int8[::1], float64[:, ::1], "
                                    "float64[::1], bool_[::1])", _bump_shadowing_numpy)
_weights_kernel = _Loop(loops.weights_loop, f"void({_LOBES}, {_TABLES}, float64[:, ::1], float64[:, :, ::1])",
                        _weights_twin)
_selection_kernel = _Loop(loops.selection_loop,
                          f"void({_LOBES}, {_TABLES}, float64[:, ::1], float64[:, :, ::1], float64[:, ::1])",
                          _selection_twin)
_eval_pdf_kernel = _Loop(loops.eval_pdf_loop,
                         f"void({_LOBES}, {_TABLES}, float64[:, ::1], float64[:, ::1], float64[:, ::1], "
                         "float64[:, :, ::1], float64[::1], boolean[::1], boolean, float64[:, ::1], float64[::1])",
                         _eval_pdf_twin)
_sample_kernel = _Loop(loops.sample_loop,
                       f"void({_LOBES}, {_TABLES}, float64[:, ::1], float64[::1], float64[::1], float64[::1], "
                       "float64[:, ::1], float64[:, :, ::1], float64[:, ::1], float64[:, ::1], float64[::1], "
                       "boolean[::1], boolean[::1])", _sample_twin)


def sample(lobes, wo, u_lobe, u1, u2, sel=None, w=None, bent=None, labels=None):
    """Sample wi.  Returns wi, weight (= f cos / pdf), pdf, delta (bool).

    A sample with weight 0 is an absorbed path.  For delta samples pdf is the
    probability of that discrete choice (only its being > 0 matters downstream).
    A lobe flagged OWN_WEIGHT that drew the sample counts with the value and
    pdf its sample reported, the other lobes with their eval (as Cycles).
    Transmitted samples have wi.z < 0.  ``w``/``sel`` (weights, selection for
    this wo) may be passed when the caller has them already.  ``bent``, an
    (N,) bool array, receives which samples a bent-normal lobe drew on rows
    with a second normal (bump_correction.sided).  ``labels``, an (N,) int8
    array, receives the kind of the OWN_WEIGHT lobe that drew each sample
    (NONE elsewhere): Cycles labels those samples by their closure, not by
    the side they leave to.
    """
    if bent is not None:
        bent[:] = False
    if labels is not None:
        labels[:] = NONE
    if lobes.kind.shape[1] == 1 and _simple(lobes) and lobes.diffuse_split is None:
        return _sample_single(lobes, wo, u1, u2)
    n = len(wo)
    if w is None:
        w = weights(lobes, wo)
    if sel is None:
        sel = selection(lobes, wo, w)
    wi, weight, pdf = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    delta, smooth = np.empty(n, bool), np.empty(n, bool)
    wo, sel, w = _c(wo), _c(sel), _c(w)
    _sample_kernel(_lobe_arrays(lobes), _table_arrays(), wo, _c(u_lobe), _c(u1), _c(u2), sel, w,
                   wi, weight, pdf, delta, smooth)
    if lobes.diffuse_split is not None:
        drawn = _resample_bent(lobes, wo, u_lobe, u1, u2, sel, w, wi)
        if bent is not None:
            bent[:] = drawn
    # Every row evaluated (rarely not needed; no copies of the lobes), the
    # smooth ones' weight and pdf taken from it.
    own = _own_weight_rows(lobes, u_lobe, sel, delta)
    if own is None:
        fs, ps = eval_pdf(lobes, wo, wi, sel, w, sampled=True)
    else:
        fs, ps = _eval_with_own(lobes, wo, wi, sel, w, own, weight, pdf)
        if labels is not None:
            labels[own[0]] = lobes.kind[own]
    _finish_kernel(wo, wi, smooth, fs, ps, weight, pdf)
    return wi, weight, pdf, delta


def _own_weight_rows(lobes, u_lobe, sel, delta):
    """(rows, slots) whose chosen lobe reported its own value and pdf
    (registry.OWN_WEIGHT), or None."""
    ids = _own_weight_ids()
    if not ids or not kind_in(lobes.kind, ids).any():
        return None
    chosen, any_lobe = chosen_lobe(sel, u_lobe)
    kind = lobes.kind[np.arange(len(chosen)), chosen]
    rows = np.flatnonzero(any_lobe & ~delta & kind_in(kind, ids))
    return (rows, chosen[rows]) if len(rows) else None


def _own_weight_ids():
    key = len(registry.REGISTRY)
    if _OWN_IDS.get("key") != key:
        _OWN_IDS.update(key=key, ids=registry.with_flag(registry.OWN_WEIGHT))
    return _OWN_IDS["ids"]


_OWN_IDS = {}


def _eval_with_own(lobes, wo, wi, sel, w, own, weight, pdf):
    """eval_pdf with the chosen OWN_WEIGHT lobe's eval replaced by what its
    sample reported (Cycles: the sampled closure's eval and pdf from
    bsdf_sample, every other closure's from bsdf_eval)."""
    rows, slots = own
    kind = lobes.kind.copy()
    kind[rows, slots] = NONE
    fs, ps = eval_pdf(replace(lobes, kind=kind), wo, wi, sel, w, sampled=True)
    fs[rows] += weight[rows]
    ps[rows] += pdf[rows]
    return fs, ps


def chosen_lobe(sel, u_lobe):
    """The slot ``sample`` picks for u_lobe (as _sample_numpy) and its kind."""
    cdf = np.cumsum(sel, axis=1)
    last = sel.shape[1] - 1 - np.argmax(sel[:, ::-1] > 0, axis=1)
    return np.minimum((u_lobe[:, None] >= cdf).sum(axis=1), last), cdf[:, -1] > 0


def bent_samples(lobes, u_lobe, sel):
    """Which samples chose a lobe that keeps the bent normal on a row with
    a second normal (bump_correction; all False without)."""
    split = lobes.diffuse_split
    if split is None:
        return np.zeros(len(u_lobe), bool)
    chosen, any_lobe = chosen_lobe(sel, u_lobe)
    kind = lobes.kind[np.arange(len(chosen)), chosen]
    return split & any_lobe & kind_in(kind, bump_correction.BENT_KINDS)


def _resample_bent(lobes, wo, u_lobe, u1, u2, sel, w, wi):
    """Directions of the bent-normal lobes chosen on split rows, drawn in
    the bent normal's frame (the same lobe, the same numbers) and turned
    back into the shading frame.  In place."""
    drawn = bent_samples(lobes, u_lobe, sel)
    rows = np.flatnonzero(drawn)
    if not len(rows):
        return drawn
    sub = take_arrays(lobes, rows, len(lobes))
    rot = sub.diffuse_rot
    wo_d = _c(bump_correction.view_above(bump_correction.apply(rot, wo[rows])))
    m = len(rows)
    wi_d, weight, pdf = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    delta, smooth = np.empty(m, bool), np.empty(m, bool)
    _sample_kernel(_lobe_arrays(sub), _table_arrays(), wo_d, _c(u_lobe[rows]), _c(u1[rows]), _c(u2[rows]),
                   _c(sel[rows]), _c(w[rows]), wi_d, weight, pdf, delta, smooth)
    wi[rows] = bump_correction.apply_t(rot, wi_d)
    return drawn


def _finish_numpy(wo, wi, smooth, fs, ps, weight, pdf):
    """A smooth sample's weight f |cos| / pdf and pdf; no weight where wo
    lies below the surface."""
    ok = ps > 0
    value = np.where(ok[:, None], fs * (np.abs(wi[:, 2]) / np.where(ok, ps, 1.0))[:, None], 0.0)
    weight[:] = np.where(smooth[:, None], value, weight)
    pdf[:] = np.where(smooth, ps, pdf)
    weight[~(wo[:, 2] > COS_EPS)] = 0.0


_finish_kernel = LoopKernel(loops.finish_sample_loop,
                            "void(float64[:, ::1], float64[:, ::1], boolean[::1], float64[:, ::1], float64[::1], "
                            "float64[:, ::1], float64[::1])", _finish_numpy)


def _sample_numpy(lobes, wo, u_lobe, u1, u2, sel, w):
    """The chosen lobe's direction for each ray; the weight and pdf of delta
    samples (0 for the others), which samples are delta and which need
    eval_pdf (smooth)."""
    n = len(wo)
    cdf = np.cumsum(sel, axis=1)
    # u_lobe past a rounded CDF that ends an ulp below 1 belongs to the last
    # lobe with a selection probability, not to an unused slot after it.
    last = sel.shape[1] - 1 - np.argmax(sel[:, ::-1] > 0, axis=1)
    chosen = np.minimum((u_lobe[:, None] >= cdf).sum(axis=1), last)
    rows = np.arange(n)
    kind = np.where(cdf[:, -1] > 0, lobes.kind[rows, chosen], NONE)
    p_lobe = sel[rows, chosen]
    # The part of u_lobe inside the chosen lobe's interval, reused for the
    # reflect/refract choice of glass.
    lo = cdf[rows, chosen] - p_lobe
    u_sub = np.clip((u_lobe - lo) / np.where(p_lobe > 0, p_lobe, 1.0), 0.0, 1.0 - 1e-12)
    wi = np.zeros((n, 3))
    wi[:, 2] = 1.0
    batch = registry.SampleBatch(wo, chosen, p_lobe, u_sub, u1, u2, w, wi, np.zeros((n, 3)), np.zeros(n),
                                 np.zeros(n, bool), kind)
    for fn, ids in _groups("sample"):
        rows = np.nonzero(kind_in(kind, ids))[0]
        if len(rows):
            fn(lobes, rows, batch)
    weight, pdf, delta = batch.weight, batch.pdf, batch.delta
    return wi, weight, pdf, delta, ~delta & (kind != NONE)


def _simple(lobes):
    """One-lobe materials with a closed-form sample weight."""
    return (np.all(kind_in(lobes.kind[:, 0], (NONE, DIFFUSE, GLOSSY, MIRROR)))
            and not lobes.multiscatter.any() and np.all(lobes.weight == 1.0)
            and not np.any(lobes.thin_film_thickness > registry.FILM_CUTOFF))   # the loop has no film


def _sample_single(lobes, wo, u1, u2):
    """``sample`` for one-lobe materials: the weight in closed form, without
    evaluating the BSDF again (diffuse: colour; GGX: F G2 / G1(wo)); a row
    loop where no normal was moved (bump shadowing stays NumPy)."""
    if lobes.smooth_n is not None:
        return _sample_single_numpy(lobes, wo, u1, u2)
    n = len(wo)
    wi, weight, pdf, delta = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, bool)
    _single_kernel(_lobe_arrays(lobes), _c(wo), _c(u1), _c(u2), wi, weight, pdf, delta)
    return wi, weight, pdf, delta


def _single_twin(lobes, wo, u1, u2, wi, weight, pdf, delta):
    wi[:], weight[:], pdf[:], delta[:] = _sample_single_numpy(_lobes_of(lobes), wo, u1, u2)


_single_kernel = _Loop(loops.single_sample_loop,
                       f"void({_LOBES}, float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], "
                       "float64[:, ::1], float64[::1], boolean[::1])", _single_twin)


def _sample_single_numpy(lobes, wo, u1, u2):
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
        if lobes.smooth_n is not None:
            weight[d] *= bump_shadowing(lobes.smooth_n[d], lobes.bump_model[d], wi[d])[0][:, None]
    g = np.nonzero((kind == GLOSSY) & up)[0]
    if len(g):
        wo_g, alpha = np.take(wo, g, axis=0), np.take(lobes.alpha[:, 0], g)
        h = ggx_sample_vndf(wo_g, alpha, u1[g], u2[g])
        cos_oh = np.einsum("ij,ij->i", wo_g, h)
        wi_g = 2.0 * cos_oh[:, None] * h - wo_g
        ok = wi_g[:, 2] > COS_EPS
        lam_o = ggx_lambda(wo_g[:, 2], alpha)
        g1 = 1.0 / (1.0 + lam_o)
        g2 = 1.0 / (1.0 + lam_o + ggx_lambda(wi_g[:, 2], alpha))
        wi[g] = wi_g
        pdf[g] = np.where(ok, ggx_d(h[:, 2], alpha) * g1 / (4.0 * wo_g[:, 2]), 0.0)
        col = np.where((lobes.fresnel[g, 0] == F_SCHLICK)[:, None], 1.0, color[g])
        weight[g] = col * _fresnel(lobes, g, 0, cos_oh) * np.where(ok, g2 / g1, 0.0)[:, None]
    m = np.nonzero((kind == MIRROR) & up)[0]
    if len(m):
        wi[m] = wo[m] * np.array([-1.0, -1.0, 1.0])
        col = np.where((lobes.fresnel[m, 0] == F_SCHLICK)[:, None], 1.0, color[m])
        weight[m] = col * _fresnel(lobes, m, 0, wo[m, 2])
        pdf[m] = 1.0
    return wi, weight, pdf, (kind == MIRROR) & up


# Cycles' Filter Glossy: the lobes bsdf_blur widens (microfacet ones; a
# mirror becomes a glossy lobe; the Principled Hair closures: _blur_hair).
BLURRED_KINDS = (GLOSSY, GLOSSY_ANISOTROPIC, GLASS, REFRACTION)


def blur(lobes, rows, roughness):
    """Cycles' bsdf_blur with Filter Glossy's blur_roughness at ``rows``:
    every microfacet lobe's alpha raised to at least ``roughness`` (as
    Cycles compares them: alpha, not roughness^2), a mirror turned into a
    glossy lobe that rough.  In place.

    Cycles keeps the multiscatter energy scale of the closure's own alpha,
    which is 1 for a smooth one: a smooth lobe blurred loses its
    multiscatter compensation (exact); a rough one keeps Ember's, computed
    at the blurred alpha (slightly brighter than Cycles' where the blur
    exceeds the lobe's own roughness)."""
    kind = lobes.kind[rows]
    r = roughness[:, None]
    mirror = kind == MIRROR
    widen = np.isin(kind, BLURRED_KINDS) | mirror
    alpha = lobes.alpha[rows]
    lobes.alpha[rows] = np.where(widen, np.maximum(alpha, np.where(mirror, np.maximum(r, MIN_ALPHA), r)), alpha)
    lobes.kind[rows] = np.where(mirror & (r > MIN_ALPHA), GLOSSY, kind).astype(lobes.kind.dtype)
    if lobes.multiscatter is not None:
        smooth = widen & (alpha <= MIN_ALPHA) & (r > alpha)
        lobes.multiscatter[rows] = lobes.multiscatter[rows] & ~smooth
    _blur_hair(lobes, rows, roughness)


def _blur_hair(lobes, rows, roughness):
    """Cycles blurs the Principled Hair closures too: Chiang's mapped
    variances and scale (hair.blur), Huang's roughness (bsdf_hair_huang_blur:
    max(blur, roughness), here on alpha = roughness^2)."""
    kind = lobes.kind[rows]
    for k in range(kind.shape[1]):
        chiang = np.flatnonzero(kind[:, k] == HAIR_CHIANG)
        if len(chiang):
            _hair.blur(lobes, rows[chiang], k, roughness[chiang])
        huang = np.flatnonzero(kind[:, k] == HAIR_HUANG)
        if len(huang):
            a = lobes.alpha[rows[huang], k]
            lobes.alpha[rows[huang], k] = np.maximum(a, np.minimum(roughness[huang], 1.0) ** 2)
