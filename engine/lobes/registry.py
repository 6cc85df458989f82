"""The lobe registry: one entry per BSDF lobe kind Ember renders.

As engine/nodes/registry.py is for shader nodes.  A ``LobeDef`` declares the
lobe's id (the int8 code in the per-ray ``kind`` arrays), its name (what
``scene.Lobe.kind`` holds), the parameters it reads, its light class for
ray visibility and render passes, the flags its samples may carry (as
pbrt-v4's ``BSDFSample.flags``), its NumPy kernels (eval / sample / albedo
guess, called by engine/bsdf.py) and the cases its tests render.  The
parameters of every lobe are one table, ``PARAMS``: ``scene.Lobe``,
``bsdf.Lobes``, ``bsdf.EXTRA_FIELDS`` and ``bsdf_loops.LOBE_FIELDS`` are
derived from it.  The kinds validation accepts (``scene.LOBE_KINDS``), the
diffuse class of ray visibility and the passes (``kinds_of_class``), bsdf's
NumPy dispatch and tests/engine/test_lobe_registry.py read ``REGISTRY``.

Kernel conventions (directions in the shading frame, wo.z > 0):

* ``eval(lobes, rows, k, wo, wi, w, sel, term, sampled) -> (f, pdf)``: what
  lobe slot ``k`` of ``rows`` adds to the material's f (N, 3) and pdf (N,),
  its weight ``w`` (N, 3) and selection probability ``sel`` (N,) already
  applied; ``term`` is Cycles' bump shadowing factor for diffuse lobes (or
  None), ``sampled`` whether wi came from ``sample``.  ``side`` says which
  wi reach it: 'upper' (reflection), 'lower' (transmission) or 'both'.
* ``sample(lobes, rows, batch)``: directions for the ``rows`` that chose
  this lobe, written into the ``SampleBatch``; delta lobes also write their
  weight (f |cos| / pdf) and pdf and set ``delta``; OWN_WEIGHT lobes write
  their own f (w applied, without |cos|) into weight and p_lobe x their pdf
  into pdf; a sample the lobe rejects sets ``kind`` to NONE (absorbed).
* ``albedo_guess(lobes, k, mu) -> (N,)``: a cheap estimate of the lobe's
  albedo for choosing lobes (any positive guess is unbiased); None: 1.

The compiled per-ray forms of these kernels are the branches of the loops
in engine/bsdf_loops.py, one per lobe kind.
"""
from dataclasses import dataclass, field
from typing import Callable, Optional, Tuple

import numpy as np

from .. import microfacet as mf

NONE = -1                 # kind of an empty lobe slot
PASS_CLASSES = ("diffuse", "glossy", "transmission", "transparent")
# Flags a lobe's samples may carry (pbrt-v4 BxDFFlags / BSDFSample.flags).
REFLECTION = 1            # wi on the side of wo
TRANSMISSION = 2          # wi through the surface (wi.z < 0)
DELTA = 4                 # always a singular direction (no eval, no pdf)
DELTA_WHEN_SMOOTH = 8     # singular at alpha <= MIN_ALPHA (smooth glass)
STRAIGHT = 16             # wi = -wo: the path continues as if no surface were there
SUBSURFACE = 32           # a BSSRDF: no BSDF value; the integrator's subsurface stage walks it
# Its sample reports the value and pdf of the direction it drew (Cycles'
# bsdf_sample's eval and pdf), which bsdf.sample uses in place of its eval
# there (the Hair BSDF: its sampler and eval disagree, engine/lobes/hair_bsdf.py).
OWN_WEIGHT = 64
# Below this alpha, GGX is numerically a mirror (glass: a smooth refractor);
# Cycles switches to a singular lobe at alpha^2 <= 2e-10.
MIN_ALPHA = 1e-3

RGB = Tuple[float, float, float]
F_NONE, F_SCHLICK, F_F82, F_DIELECTRIC, F_CONDUCTOR = range(5)
FRESNEL_IDS = {"none": F_NONE, "schlick": F_SCHLICK, "f82": F_F82, "dielectric": F_DIELECTRIC,
               "conductor": F_CONDUCTOR}


# ----------------------------------------------------------------------------
# Parameters: one table for the scene dataclass and the per-ray arrays

@dataclass(frozen=True)
class Param:
    """One ``scene.Lobe`` field.  ``array`` names its per-ray array in
    ``bsdf.Lobes`` (None: kept under the field's name), ``dtype``/``tail`` that
    array's element type and trailing shape; ``to_table(lobe)`` converts the
    field to its table value (None: stored as given); ``fill(lobes)`` is the
    array a ``bsdf.Lobes`` built without it gets (None: the default, broadcast)."""
    name: str
    hint: object
    default: object
    dtype: type
    tail: tuple = ()
    doc: str = ""
    array: Optional[str] = None
    to_table: Optional[Callable] = None
    fill: Optional[Callable] = None

    @property
    def field(self):
        return self.array or self.name


def _f0_table(lobe):
    """f0 defaults: the real dielectric F0 of the IOR for 'dielectric' and
    glass, else the colour."""
    f0 = getattr(lobe, "f0", None)
    if f0 is None:
        dielectric = getattr(lobe, "fresnel", "none") == "dielectric" or lobe.kind in ("glass", "refraction")
        f0 = (float(mf.f0_from_ior(_ior(lobe))),) * 3 if dielectric else lobe.color
    return np.maximum(f0, 0.0)


def _ior(lobe):
    return float(getattr(lobe, "ior", 1.5))


NAN = float("nan")   # the portal vectors' "not given"


# color and roughness are converted by bsdf.MaterialTable itself (roughness
# to alpha, with the glossy -> mirror switch); the others by to_table.
PARAMS = (
    Param("color", RGB, (0.8, 0.8, 0.8), np.float64, (3,),
          "RGB colour of the lobe (for glass it tints reflection and refraction; for a layer, see covers)."),
    Param("roughness", float, 0.5, np.float64, (), "Blender roughness in [0, 1] (glossy, glass, refraction, "
          "sheen); the per-ray array is alpha = roughness^2.", array="alpha"),
    Param("fresnel", str, "none", np.int8, (),
          "glossy and mirror: 'none' (Glossy BSDF: colour times the microfacet term), 'schlick' (legacy: colour "
          "is F0), 'f82' (Principled metal: F82-tint with F0 = f0 and edge_tint), 'dielectric' (the Principled "
          "BSDF's Fresnel: mix(f0, 1, s) with s the real Fresnel curve of ior remapped to [0, 1]; f0 None = F0 "
          "of ior), 'conductor' (the Metallic BSDF's Physical Conductor: the exact Fresnel of n + i k, with n in "
          "f0 and k in edge_tint).  Glass and refraction always use the dielectric Fresnel of ior.",
          to_table=lambda lobe: FRESNEL_IDS.get(getattr(lobe, "fresnel", "none"), F_NONE),
          fill=lambda lobes: np.where(lobes.schlick, F_SCHLICK, F_NONE).astype(np.int8)),
    Param("ior", float, 1.5, np.float64, (), "index of refraction (relative to the outside; inverted "
          "automatically when a ray arrives from the back face of a glass or refraction lobe).", to_table=_ior),
    Param("f0", Optional[RGB], None, np.float64, (3,), "RGB reflectance at normal incidence ('f82', "
          "'dielectric', glass); the conductor's n ('conductor').", to_table=_f0_table, fill=lambda lobes: np.array(lobes.color, dtype=np.float64)),
    Param("edge_tint", RGB, (1.0, 1.0, 1.0), np.float64, (3,), "RGB F82 tint ('f82'); the conductor's "
          "extinction k ('conductor')."),
    Param("transmission_tint", RGB, (1.0, 1.0, 1.0), np.float64, (3,),
          "RGB factor on the refracted part only (glass).",
          to_table=lambda lobe: np.maximum(getattr(lobe, "transmission_tint", (1.0, 1.0, 1.0)), 0.0)),
    Param("multiscatter", bool, False, np.bool_, (), "Multiscatter GGX energy compensation (glossy, glass).",
          to_table=lambda lobe: bool(getattr(lobe, "multiscatter", False))),
    Param("covers", int, 0, np.int8, (), "this lobe is a layer over the next covers lobes of the material, "
          "which are weighed down by (1 - its albedo estimate), as Cycles layers the Principled BSDF; colour "
          "is then the layer's weight relative to what it covers (coat weight, sheen weight x tint).",
          to_table=lambda lobe: int(getattr(lobe, "covers", 0))),
    Param("absorb", RGB, (1.0, 1.0, 1.0), np.float64, (3,), "RGB coat tint applied to the covered lobes "
          "(Beer-Lambert along the refracted view ray, mixed in by the colour)."),
    Param("weight", float, 1.0, np.float64, (), "scalar factor from Mix/Add shaders and Principled mixing; "
          "unlike colour it does not enter Fresnel, energy or layering estimates.",
          to_table=lambda lobe: max(float(getattr(lobe, "weight", 1.0)), 0.0)),
    Param("anisotropy", float, 0.0, np.float64, (), "Anisotropy in [0, 1] (glossy_anisotropic): alpha_x = "
          "alpha / aspect, alpha_y = alpha aspect with aspect = sqrt(1 - 0.9 anisotropy), as Cycles' Principled "
          "(values up to 1/0.9 express the Glossy BSDF's stronger anisotropy).",
          to_table=lambda lobe: _finite_or(getattr(lobe, "anisotropy", 0.0), 0.0)),
    Param("diffuse_roughness", float, 0.0, np.float64, (), "Oren-Nayar sigma in [0, 1] (oren_nayar: Cycles' "
          "Diffuse BSDF Roughness, the Principled Diffuse Roughness)."),
    Param("rotation", float, 0.0, np.float64, (), "tangent rotation about the normal in turns (glossy_anisotropic: "
          "Anisotropic Rotation), applied as Cycles' rotate_around_axis(T, N, 2 pi rotation).",
          to_table=lambda lobe: _turns(getattr(lobe, "rotation", 0.0))),
    Param("radius", RGB, (1.0, 1.0, 1.0), np.float64, (3,), "subsurface: RGB scattering radius in metres "
          "(Blender's Radius x Scale; Cycles' bssrdf radius before its per-method remap)",
          to_table=lambda lobe: np.nan_to_num(np.maximum(getattr(lobe, "radius", (1.0, 1.0, 1.0)), 0.0),
                                              nan=0.0, posinf=1e30)),
    Param("phase_g", float, 0.0, np.float64, (), "subsurface: Henyey-Greenstein anisotropy of the walk "
          "(Blender's Subsurface Anisotropy; clamped to [0, 0.9] as Cycles 5.0)."),
    Param("absorption", RGB, (0.0, 0.0, 0.0), np.float64, (3,), "hair_chiang: the fibre's absorption "
          "coefficient sigma_a per unit of its radius (Cycles' bsdf->sigma; engine/lobes/hair.py converts "
          "melanin and colour).",
          to_table=lambda lobe: np.nan_to_num(np.maximum(getattr(lobe, "absorption", (0.0, 0.0, 0.0)), 0.0),
                                              nan=0.0, posinf=1e30)),
    Param("radial_roughness", float, 0.3, np.float64, (), "hair_chiang: azimuthal roughness in [0, 1] "
          "(hair_reflection / _transmission: RoughnessV).",
          to_table=lambda lobe: _finite_or(getattr(lobe, "radial_roughness", 0.3), 0.3)),
    Param("coat", float, 0.0, np.float64, (), "hair_chiang: Coat in [0, 1] (the R lobe's roughness is "
          "(1 - coat) roughness).", to_table=lambda lobe: _finite_or(getattr(lobe, "coat", 0.0), 0.0)),
    Param("offset", float, 0.0, np.float64, (), "hair_chiang, hair_reflection / _transmission: the "
          "cuticle tilt in radians (the node's Offset).",
          to_table=lambda lobe: _finite_or(getattr(lobe, "offset", 0.0), 0.0)),
    Param("aspect_ratio", float, 1.0, np.float64, (), "hair_huang: the fibre's Aspect Ratio (minor over major "
          "axis; above 1 inverted as Cycles; NaN 1, at least 1e-3).",
          to_table=lambda lobe: max(_finite_or(getattr(lobe, "aspect_ratio", 1.0), 1.0), 1e-3)),
    Param("hair_gains", RGB, (1.0, 1.0, 1.0), np.float64, (3,), "hair_huang: the Reflection, Transmission and "
          "Secondary Reflection gains of its R, TT and TRT lobes (negative and NaN 0).",
          to_table=lambda lobe: np.nan_to_num(np.maximum(getattr(lobe, "hair_gains", (1.0, 1.0, 1.0)), 0.0),
                                              nan=0.0, posinf=1e30)),
    Param("fibre_axis", Tuple[float, float], (0.0, 1.0), np.float64, (2,), "hair_huang: the ellipse's major axis "
          "in the shading frame's (y, z), set per ray by the integrator from the curve's normal "
          "(engine/lobes/hair_huang.py)."),
    Param("pixel_coverage", float, 1.0, np.float64, (), "hair_huang: half a pixel's width over the fibre's "
          "radius; the near field model where the fibre is wider (set per camera ray by the integrator; 1: far "
          "field)."),
    Param("thin_film_thickness", float, 0.0, np.float64, (), "thin-film iridescence over the lobe's Fresnel "
          "(glossy 'dielectric', 'f82' and 'conductor', mirror, glass): the film's thickness in nm; at most 0.1 (Cycles' "
          "THINFILM_THICKNESS_CUTOFF) is no film (engine/thinfilm.py).",
          to_table=lambda lobe: film_thickness(getattr(lobe, "thin_film_thickness", 0.0))),
    Param("portal_position", RGB, (NAN,) * 3, np.float64, (3,), "ray_portal: the world position the path goes "
          "on from (NaN, the default: the hit point, as Blender's unlinked Position).",
          to_table=lambda lobe: _portal_vector(getattr(lobe, "portal_position", (NAN,) * 3))),
    Param("portal_direction", RGB, (NAN,) * 3, np.float64, (3,), "ray_portal: the direction it goes on in "
          "(normalized; NaN, the default, or zero: the incoming ray's, as Cycles).",
          to_table=lambda lobe: _portal_vector(getattr(lobe, "portal_direction", (NAN,) * 3))),
    Param("thin_film_ior", float, 1.33, np.float64, (), "the thin film's IOR (at least 1e-5, as Cycles; divided "
          "by the glass IOR on back faces of glass lobes).",
          to_table=lambda lobe: film_ior(getattr(lobe, "thin_film_ior", 1.33))),
)
# Cycles' THINFILM_THICKNESS_CUTOFF (nm): a thinner film is no film.
FILM_CUTOFF = 0.1
# Thickness and film IOR are held below this (a 1e30 nm film is finite maths).
FILM_MAX = 1e30


def film_thickness(value):
    """A film thickness for the tables: NaN and negative ones are no film."""
    value = _finite_or(value, 0.0)
    return float(min(max(value, 0.0), FILM_MAX))


def film_ior(value):
    """A film IOR for the tables: at least 1e-5 (Cycles' fmaxf), NaN the default."""
    return float(min(max(_finite_or(value, 1.33), 1e-5), FILM_MAX))


def _portal_vector(value):
    """A portal position or direction for the tables: non-finite (or infinite,
    out of reach of a ray) components make it NaN, its default."""
    v = np.asarray(value, np.float64).reshape(3)
    return v if np.all(np.isfinite(v)) and np.all(np.abs(v) < 1e30) else np.full(3, np.nan)


def _finite_or(value, fallback):
    value = float(value)
    return value if np.isfinite(value) else fallback


def _turns(value):
    """A rotation in turns reduced to [0, 1) (a huge one keeps its float
    fraction: 1e30 turns is a whole number of turns, 0)."""
    value = _finite_or(value, 0.0)
    return float(value - np.floor(value))
PARAM = {p.name: p for p in PARAMS}
# The per-lobe table arrays beside kind / color / alpha / schlick, in order.
EXTRA_PARAMS = tuple(p for p in PARAMS if p.name not in ("color", "roughness"))


def table_value(param, lobe):
    """The table value of ``param`` for one scene lobe."""
    if param.to_table is not None:
        return param.to_table(lobe)
    return getattr(lobe, param.name, param.default)


def fill_array(param, lobes):
    """The per-ray array of ``param`` for a ``bsdf.Lobes`` built without it."""
    if param.fill is not None:
        return param.fill(lobes)
    return np.full(lobes.kind.shape + param.tail, param.default, param.dtype)


# ----------------------------------------------------------------------------
# Lobe definitions

@dataclass
class SampleBatch:
    """The inputs and outputs of the sample kernels for one batch (N rows):
    wo (N, 3), the chosen slot ``chosen``, its selection probability
    ``p_lobe`` and the rest of u_lobe inside it ``u_sub`` (reused for the
    reflect / refract choice), u1, u2, the lobe weights w (N, K, 3); written:
    wi, weight, pdf, delta, kind."""
    wo: np.ndarray
    chosen: np.ndarray
    p_lobe: np.ndarray
    u_sub: np.ndarray
    u1: np.ndarray
    u2: np.ndarray
    w: np.ndarray
    wi: np.ndarray
    weight: np.ndarray
    pdf: np.ndarray
    delta: np.ndarray
    kind: np.ndarray


@dataclass
class LobeDef:
    id: int
    name: str
    pass_class: str                # 'diffuse', 'glossy', 'transmission' or 'transparent'
    flags: int                     # REFLECTION | TRANSMISSION | DELTA | DELTA_WHEN_SMOOTH | STRAIGHT | OWN_WEIGHT
    sample: Callable               # (lobes, rows, SampleBatch) -> None
    eval: Optional[Callable] = None        # None: a delta lobe
    side: str = "upper"            # which wi eval sees: 'upper', 'lower', 'both'
    albedo_guess: Optional[Callable] = None
    # (lobes, k) -> (N,) bool: rows whose slot k eval may see (None: all)
    evaluates: Optional[Callable] = None
    params: tuple = ()             # the scene.Lobe fields it reads besides color and weight
    reciprocal: bool = True        # f(wo, wi) = f(wi, wo) (tested where true)
    # (lobes, k, wo, wi) -> (N,) bool: pairs eval scores that sample never
    # draws (Cycles' rough refraction); the registry tests leave them out
    unjoined: Optional[Callable] = None
    doc: str = ""
    # scene.Lobe keyword sets the registry tests render (each one lobe)
    cases: list = field(default_factory=list)
    # Cycles' setup of the closure sets SD_BSDF_HAS_TRANSMISSION: its light
    # tree then keeps lights behind the normal (|cos|); without it, at a
    # point none of whose closures has it, they get importance 0
    # (engine/lighttree.py).  Not the sample flags: the Hair BSDF's
    # Reflection samples below the normal, yet Cycles does not set it.
    has_transmission: bool = False

    def has(self, flag):
        return bool(self.flags & flag)


REGISTRY = {}      # name -> LobeDef, in registration order
BY_ID = {}         # id -> LobeDef


def register(lobe):
    """Add a lobe definition (ids and names unique, parameters known)."""
    assert lobe.name not in REGISTRY and lobe.id not in BY_ID and 0 <= lobe.id < 127, lobe
    assert lobe.pass_class in PASS_CLASSES, lobe.pass_class
    assert lobe.side in ("upper", "lower", "both") and (lobe.eval is not None or lobe.has(DELTA)), lobe.name
    for name in lobe.params:
        assert name in PARAM, (lobe.name, name)
    REGISTRY[lobe.name] = lobe
    BY_ID[lobe.id] = lobe
    return lobe


def kinds():
    """Lobe names in id order (what scene.Lobe.kind may be)."""
    return tuple(BY_ID[i].name for i in sorted(BY_ID))


def kind_ids():
    return {d.name: d.id for d in REGISTRY.values()}


_CLASS_IDS = {}


def kinds_of_class(pass_class):
    """The ids of the lobes of one light class, e.g. ``kinds_of_class('diffuse')``
    (memoized per registry size: the integrator asks every bounce)."""
    key = (pass_class, len(REGISTRY))
    if key not in _CLASS_IDS:
        assert pass_class in PASS_CLASSES, pass_class
        _CLASS_IDS[key] = tuple(sorted(d.id for d in REGISTRY.values() if d.pass_class == pass_class))
    return _CLASS_IDS[key]


def with_flag(flag):
    return tuple(sorted(d.id for d in REGISTRY.values() if d.has(flag)))


def transmitting():
    """The ids of the lobes whose Cycles closure has SD_BSDF_HAS_TRANSMISSION."""
    return tuple(sorted(d.id for d in REGISTRY.values() if d.has_transmission))
