"""The transparent lobe (Transparent BSDF, Principled Alpha): straight on."""
from .registry import DELTA, STRAIGHT, LobeDef, register

TRANSPARENT = 6


def sample_transparent(lobes, rows, s):
    """wi = -wo with weight colour / p_lobe: a delta lobe that keeps the
    path's direction (the integrator counts it as a transparent bounce)."""
    s.wi[rows] = -s.wo[rows]
    s.weight[rows] = s.w[rows, s.chosen[rows]] / s.p_lobe[rows, None]
    s.delta[rows] = True
    s.pdf[rows] = s.p_lobe[rows]


register(LobeDef(TRANSPARENT, "transparent", "transparent", DELTA | STRAIGHT, sample_transparent,
                 doc="straight through; a shadow ray keeps crossing it (bsdf.transparency)",
                 cases=[dict(color=(0.9, 0.7, 1.0))]))
