"""Lobe kind and Fresnel mode codes shared by engine/bsdf.py and its
compiled per-ray form (engine/bsdf_loops.py).  Each kind's id is declared
once, in its module under engine/lobes/ (its registry entry); they are
re-exported here under the names the engine has always used."""
from .lobes import NONE, kind_ids
from .lobes.anisotropic import GLOSSY_ANISOTROPIC  # noqa: F401
from .lobes.diffuse import DIFFUSE, TRANSLUCENT  # noqa: F401
from .lobes.ggx import GLOSSY, MIRROR  # noqa: F401
from .lobes.glass import GLASS, REFRACTION  # noqa: F401
from .lobes.hair import HAIR_CHIANG  # noqa: F401
from .lobes.hair_bsdf import HAIR_REFLECTION, HAIR_TRANSMISSION  # noqa: F401
from .lobes.hair_huang import HAIR_HUANG  # noqa: F401
from .lobes.oren_nayar import OREN_NAYAR  # noqa: F401
from .lobes.registry import F_CONDUCTOR, F_DIELECTRIC, F_F82, F_NONE, F_SCHLICK, FRESNEL_IDS, MIN_ALPHA  # noqa: F401
from .lobes.ray_portal import RAY_PORTAL  # noqa: F401
from .lobes.sheen import SHEEN  # noqa: F401
from .lobes.subsurface import SUBSURFACE_BURLEY, SUBSURFACE_RANDOM_WALK, SUBSURFACE_SKIN  # noqa: F401
from .lobes.transparent import TRANSPARENT  # noqa: F401

assert NONE == -1
KIND_IDS = kind_ids()
