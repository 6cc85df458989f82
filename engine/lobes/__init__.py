"""BSDF lobes: the registry (registry.py) and one module per lobe family.

Importing the package registers every lobe; ``REGISTRY`` maps names to
``LobeDef`` entries.  See docs/design.md, "Adding a lobe"."""
from . import (anisotropic, diffuse, ggx, glass, hair, hair_bsdf, hair_huang, oren_nayar, sheen,  # noqa: F401
               subsurface, transparent, ray_portal)                                           # (each registers its lobes)                                           # its lobes)
from .registry import (BY_ID, DELTA, DELTA_WHEN_SMOOTH, EXTRA_PARAMS, FILM_CUTOFF, NONE, OWN_WEIGHT,  # noqa: F401
                       PARAM, PARAMS, PASS_CLASSES, REFLECTION, REGISTRY, STRAIGHT, SUBSURFACE, TRANSMISSION,
                       LobeDef, Param, SampleBatch, fill_array, kind_ids, kinds, kinds_of_class, register, table_value,
                       with_flag)
