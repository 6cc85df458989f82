"""Lobe kind and Fresnel mode codes shared by engine/bsdf.py and its
compiled per-ray form (engine/bsdf_loops.py)."""

NONE, DIFFUSE, MIRROR, GLOSSY, GLASS, REFRACTION, TRANSLUCENT, TRANSPARENT, SHEEN = range(-1, 8)
KIND_IDS = {"diffuse": DIFFUSE, "mirror": MIRROR, "glossy": GLOSSY, "glass": GLASS,
            "refraction": REFRACTION, "translucent": TRANSLUCENT, "transparent": TRANSPARENT,
            "sheen": SHEEN}
F_NONE, F_SCHLICK, F_F82, F_DIELECTRIC = range(4)
FRESNEL_IDS = {"none": F_NONE, "schlick": F_SCHLICK, "f82": F_F82, "dielectric": F_DIELECTRIC}
# Below this alpha, GGX is numerically a mirror (glass: a smooth refractor);
# Cycles switches to a singular lobe at alpha^2 <= 2e-10.
MIN_ALPHA = 1e-3
