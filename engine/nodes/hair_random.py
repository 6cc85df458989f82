"""The Principled Hair BSDF's per-strand randomization (Cycles'
svm_node_closure_bsdf, CLOSURE_BSDF_HAIR_CHIANG_ID), as an expression the
hair lobe's fields read: from the node's Random (the Curves Info node's
Random when unlinked, as Cycles' attr_random), Random Roughness scales
Roughness and Radial Roughness by 1 + 2 (random - 0.5) random_roughness,
and Random Color scales the melanin by 1 + 2 (random - 0.5) random_color
(clamped to [0, 1]) before Cycles' remapping; the absorption follows
(engine/lobes/hair.py's parametrizations).

It is no Blender node (its id is Ember's): the exporter builds it for a
Principled Hair BSDF whose Random Roughness or Random Color is not 0."""
import numpy as np

from ..lobes import hair
from .registry import node

PARAMETRIZATIONS = ("MELANIN", "COLOR", "ABSORPTION")


def _factor(random, amount):
    return 1.0 + 2.0 * (random - 0.5) * amount


def _sigma(p, random, radial):
    """(N, 3) absorption of the parametrization at per-point radial roughness."""
    n = len(random)
    kind = p.get("parametrization", "MELANIN")
    if kind == "ABSORPTION":
        return np.tile(np.asarray(p["absorption"], np.float64), (n, 1))
    if kind == "COLOR":
        return hair.sigma_from_color(np.tile(np.asarray(p["color"], np.float64), (n, 1)), radial[:, None])
    melanin = p["melanin"] * _factor(random, np.clip(p["random_color"], 0.0, 1.0))
    melanin = -np.log(np.maximum(1.0 - melanin, 1e-4))
    redness = p["redness"]
    sigma = (melanin * (1.0 - redness))[:, None] * hair.EUMELANIN + (melanin * redness)[:, None] * hair.PHEOMELANIN
    return sigma + hair.sigma_from_color(np.tile(np.asarray(p["tint"], np.float64), (n, 1)), radial[:, None])


@node("EmberPrincipledHairRandom", inputs=(("Random", "float"), ("Is Strand", "float")),
      outputs=(("Roughness", "float"), ("Radial Roughness", "float"), ("Absorption", "color")),
      props=(("parametrization", "MELANIN"), ("melanin", 0.8), ("redness", 1.0), ("tint", (1.0, 1.0, 1.0)),
             ("color", (0.017513, 0.005763, 0.002059)), ("absorption", (0.245531, 0.52, 1.365)),
             ("roughness", 0.3), ("radial_roughness", 0.3), ("random_roughness", 0.0), ("random_color", 0.0),
             ("random_default", 0.0)),
      bounds=lambda p: {"Absorption": (0.0, np.inf)},
      cases=[{"random_roughness": 0.5, "random_color": 0.4, "melanin": 0.6, "redness": 0.3},
             {"parametrization": "COLOR", "random_roughness": 1.0},
             {"parametrization": "ABSORPTION", "random_roughness": 0.2}])
def principled_hair_random(ctx, i, p):
    """Off strands (Is Strand 0) the unlinked Random is the socket's value
    (``random_default``), as Cycles' fallback where no curve attribute is found."""
    random = np.broadcast_to(np.asarray(i["Random"], np.float64), (len(ctx),))
    strand = np.broadcast_to(np.asarray(i.get("Is Strand", 1.0), np.float64), (len(ctx),))
    random = np.where(strand > 0.5, random, p.get("random_default", 0.0))
    factor = _factor(random, p["random_roughness"])
    radial = p["radial_roughness"] * factor
    sigma = np.nan_to_num(np.maximum(_sigma(p, random, radial), 0.0), nan=0.0, posinf=1e30)
    return {"Roughness": p["roughness"] * factor, "Radial Roughness": radial, "Absorption": sigma}
