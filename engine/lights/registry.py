"""One definition per light type, as engine/nodes/registry.py is for shader
nodes.  ``LightSet`` (lightset.py), validation, the light tree's bounds, the
ray proxies, the light-group passes and the tests (tests/engine/
test_light_registry.py) iterate over ``ordered()`` instead of naming types.

A type's module (point.py, sun.py, area.py, world.py, mesh.py) defines a
``LightTable`` subclass, the table of every light of that type in a scene,
and registers a ``LightDef`` saying how to build it, how BSDF rays find it
(``hit``), which scene classes it stands for, how to validate one, and the
cases the registry's tests render.
"""
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from ..geometry import VIS_ALL
from ..scene import SceneError

# How a BSDF-sampled ray finds a light of the type:
RAY = "ray"          # LightSet.intersect: the table's nearest(o, d, t, ray, bits, camera, path, tmin)
ESCAPE = "escape"    # LightSet.sun_hits: rays that leave the scene, escape_hits(d)
WORLD = "world"      # LightSet.environment_hits: the HDRI world, eval(d) and pdf(d)
SURFACE = "surface"  # emissive triangles, found by the scene's own ray casts
HITS = (RAY, ESCAPE, WORLD, SURFACE)


@dataclass
class BuildInputs:
    """What a type's ``build`` may read.  make_tree(bounds) returns a
    selection tree over bounds (lighttree.LightTree), handed in so that no
    light module imports the tree."""
    lights: list          # the scene lights of this type, in scene order
    scene: object
    triangles: object
    materials: object
    strategy: str
    env_compensation: bool
    make_tree: Callable
    motion: object = None   # engine.motion.MotionGeometry of a scene with moving triangles, else None


class LightTable:
    """Every light of one type in a scene.  Subclasses set ``count`` and
    implement ``sample`` and ``power``; the rest has defaults for a type
    without it."""
    count = 0
    falloff = None   # common.Falloff: Light Falloff node per light, or None

    def power(self, radius):
        """Per light: the power light selection weighs it by (radius: the
        scene's, for lights without a position)."""
        raise NotImplementedError

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        """NEE: fill rows idx of ``out`` (a common.LightSample) with a sample
        of light j (per row) seen from p (normal n, or None)."""
        raise NotImplementedError

    def is_delta(self):
        """(count,) bool: lights no BSDF ray can hit (sampled by NEE only)."""
        return np.zeros(self.count, bool)

    def visibility(self):
        """(count,) uint8 VIS_* bits: which rays see and are lit by each."""
        return np.full(self.count, VIS_ALL, np.uint8)

    def bounds(self, j, phi):
        """lightbounds.Bounds of light j with power phi, or None (no position)."""
        return None

    def proxy_boxes(self):
        """(8, 3) corner boxes around the lights BSDF rays can hit
        (lightproxy.LightProxies); empty: no proxies."""
        return []


@dataclass
class LightExample:
    """A scene for the registry's tests: one light of the type (the first
    emitter of the set), seen from p with receiver normal ``normal``;
    solid_angle: the light's solid angle from p (mean of 1/pdf), irradiance:
    the RGB irradiance at p on that normal, where known in closed form."""
    label: str
    scene: Callable                  # () -> engine.scene.Scene
    p: tuple
    normal: tuple = (0.0, 0.0, 1.0)
    solid_angle: Optional[float] = None
    irradiance: Optional[tuple] = None


@dataclass
class LightDef:
    name: str
    kind: int                 # stable id (POINT, SUN, ...): LightSet.kind holds it per emitter
    order: int                # place in the emitter order: a seed's image depends on it
    build: Callable           # BuildInputs -> LightTable
    hit: str                  # one of HITS
    attr: str                 # LightSet attribute of the table (points, suns, ...)
    scene_types: tuple = ()   # engine.scene classes that are lights of this type
    validate: Optional[Callable] = None   # (light, what) -> None; raises SceneError
    source: str = "lights"    # what a light group keys it by: 'lights', 'world' or 'material'
    examples: Callable = lambda: []       # () -> [LightExample]
    # (label, mutate(scene) -> None, message): input validation must reject.
    hostile: tuple = field(default_factory=tuple)


REGISTRY = {}


def register(definition):
    if definition.hit not in HITS:
        raise ValueError(f"light type {definition.name}: unknown hit {definition.hit!r}")
    if any(d.kind == definition.kind or d.order == definition.order for d in REGISTRY.values()):
        raise ValueError(f"light type {definition.name}: kind or order taken")
    REGISTRY[definition.name] = definition
    return definition


def ordered():
    """Every registered type in emitter order."""
    return sorted(REGISTRY.values(), key=lambda d: d.order)


def definition_of(light):
    """The type a scene light belongs to (its class or the nearest base)."""
    for cls in type(light).__mro__:
        for d in REGISTRY.values():
            if cls in d.scene_types:
                return d
    return None


def lights_of(definition, lights):
    """The scene lights of one type, in scene order."""
    return [l for l in lights if definition_of(l) is definition]


def scene_lights_in_order(lights):
    """The scene's lights in the order their emitters have in a LightSet."""
    return [l for d in ordered() for l in lights_of(d, lights)]


def validate_light(light, index):
    what = f"light {index} ({getattr(light, 'name', '?')!r})"
    d = definition_of(light)
    if d is None or d.validate is None:
        raise SceneError(f"{what}: unknown light type {type(light).__name__}")
    d.validate(light, what)
