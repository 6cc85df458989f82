"""The renderer's input: plain data, no Blender.

Everything the add-on exports (and everything a test builds by hand) is one of
these dataclasses.  Units and conventions follow Blender/Cycles so that the
exporter only copies numbers:

* world space is Blender's (right-handed, Z up), metres;
* object matrices are 4x4 object-to-world, row-major (``matrix_world`` as NumPy);
* a camera looks down its local -Z with +Y up;
* lights use Cycles' units (see ``engine.lights``): point/spot/area ``power`` is
  in watts times colour, sun ``strength`` is irradiance in W/m^2 times colour;
* colours are linear scene-referred RGB.

``Scene.validate()`` checks shapes, dtypes, finiteness and index ranges and
raises ``SceneError`` with a message that names the offending item.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence, Tuple, Union

import numpy as np

RGB = Tuple[float, float, float]


class SceneError(ValueError):
    """Invalid scene data, with a message meant for the user."""


# ----------------------------------------------------------------------------
# Geometry

@dataclass
class Mesh:
    """A triangle mesh in object space, shared by every instance that uses it.

    positions: (V, 3) float  vertex positions
    triangles: (T, 3) int    vertex indices per triangle
    normals:   (T, 3, 3) float per-corner shading normals, or None for flat shading
    uvs:       (T, 3, 2) float per-corner UVs, or None
    material_slots: (T,) int material slot per triangle, or None (all slot 0)
    """
    positions: np.ndarray
    triangles: np.ndarray
    normals: Optional[np.ndarray] = None
    uvs: Optional[np.ndarray] = None
    material_slots: Optional[np.ndarray] = None
    name: str = "mesh"


@dataclass
class Instance:
    """One placement of a mesh.

    matrix: (4, 4) object-to-world.
    materials: scene material index per material slot of the mesh; a slot past
        the end or holding -1 uses the default grey diffuse material.
    """
    mesh: int
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    materials: Sequence[int] = ()
    name: str = "object"


# ----------------------------------------------------------------------------
# Materials

@dataclass
class Lobe:
    """One BSDF lobe of a material.

    kind: 'diffuse' (Lambert), 'mirror' (perfect specular reflection) or
          'glossy' (GGX microfacet reflection, alpha = roughness^2).
    color: RGB weight of the lobe.
    roughness: Blender roughness in [0, 1] (glossy only).
    fresnel: 'none' (Blender's Glossy BSDF: colour times the microfacet term) or
             'schlick' (colour is F0, the reflectance at normal incidence;
             used for the Principled BSDF's specular layer).
    """
    kind: str
    color: RGB = (0.8, 0.8, 0.8)
    roughness: float = 0.5
    fresnel: str = "none"


LOBE_KINDS = ("diffuse", "mirror", "glossy")


@dataclass
class Material:
    """A weighted set of lobes plus emitted radiance (W/(m^2 sr), two-sided)."""
    name: str = "material"
    lobes: Sequence[Lobe] = (Lobe("diffuse"),)
    emission: RGB = (0.0, 0.0, 0.0)


DEFAULT_MATERIAL = Material("default", (Lobe("diffuse", (0.8, 0.8, 0.8)),))


# ----------------------------------------------------------------------------
# Lights (Cycles units)

@dataclass
class PointLight:
    """Blender point light.  ``power`` = colour * watts.

    Every light has ``visible_camera`` (Blender's Object > Visibility > Camera
    ray, False by default for lights): whether camera rays see its shape.

    soft_falloff=False: a sphere of radius ``radius`` with radiance
    P / (4 pi^2 r^2).  soft_falloff=True (Blender 4.0+ default): Cycles' disk of
    radius ``radius`` that always faces the shading point, same radiance.
    """
    position: Sequence[float]
    power: RGB
    radius: float = 0.1
    soft_falloff: bool = False
    name: str = "point"
    visible_camera: bool = False


@dataclass
class SpotLight(PointLight):
    """A point light with a cone: ``direction`` is where it shines (object -Z),
    ``spot_size`` the full cone angle in radians, ``spot_blend`` in [0, 1]."""
    direction: Sequence[float] = (0.0, 0.0, -1.0)
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    name: str = "spot"


@dataclass
class SunLight:
    """A distant light.  ``direction`` is where the light travels (object -Z);
    ``strength`` = colour * irradiance (W/m^2) on a surface facing the sun;
    ``angle`` is the full angular diameter in radians."""
    direction: Sequence[float]
    strength: RGB
    angle: float = 0.0
    name: str = "sun"
    visible_camera: bool = False


AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")


@dataclass
class AreaLight:
    """A one-sided area light emitting along its local -Z.

    matrix: (4, 4) light-to-world (may include scale).  The emitter spans
    size_x by size_y in local X/Y (SQUARE and DISK use size_x for both;
    DISK/ELLIPSE sizes are diameters).  ``power`` = colour * watts; with
    ``normalize`` (Cycles' default) radiance = power / (pi * area).
    """
    matrix: np.ndarray
    power: RGB
    shape: str = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    normalize: bool = True
    name: str = "area"
    visible_camera: bool = False


Light = Union[PointLight, SpotLight, SunLight, AreaLight]


@dataclass
class World:
    """A constant-colour background: radiance = colour * strength."""
    color: RGB = (0.05, 0.05, 0.05)


# ----------------------------------------------------------------------------
# Camera

@dataclass
class Camera:
    """A Blender camera plus the render resolution that frames it.

    matrix: (4, 4) camera-to-world; the camera looks down local -Z, +Y up.
    kind: 'PERSP' or 'ORTHO'.  lens in mm, sensor sizes in mm,
    sensor_fit 'AUTO' | 'HORIZONTAL' | 'VERTICAL', shift in units of the
    fitted sensor size, ortho_scale in metres.
    Depth of field is on when ``aperture_radius > 0`` (metres) or
    ``fstop > 0`` (radius = lens / (2 fstop), as Cycles computes it).
    border = (xmin, xmax, ymin, ymax) in [0, 1] of the full frame, Blender's
    render border (y measured from the bottom).  The rendered image covers only
    the border window.
    """
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: str = "PERSP"
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    shift_x: float = 0.0
    shift_y: float = 0.0
    ortho_scale: float = 6.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    focus_distance: float = 10.0
    fstop: float = 0.0
    aperture_radius: float = 0.0
    resolution: Tuple[int, int] = (640, 480)
    pixel_aspect: Tuple[float, float] = (1.0, 1.0)
    border: Optional[Tuple[float, float, float, float]] = None


# ----------------------------------------------------------------------------
# Settings

@dataclass
class RenderSettings:
    """How to render.

    samples: samples per pixel in total; samples_per_pass: how many are
    added between two progress callbacks.  max_bounces follows Cycles: the
    number of indirect bounces, so 0 is direct lighting only (light sampling
    at the first hit, emission found by its BSDF sample).  light_selection: 'uniform',
    'power' or 'all'.  strategy: 'mis', 'light' (NEE only) or 'bsdf'.
    clamp: 0 disables clamping of a sample's radiance.  max_paths bounds the
    number of paths in flight (memory); threads 0 = every core.
    time_limit: seconds (0 = none); stops after the pass that crosses it.
    """
    samples: int = 16
    samples_per_pass: int = 1
    max_bounces: int = 8
    rr_depth: int = 3
    seed: int = 0
    light_selection: str = "power"
    strategy: str = "mis"
    clamp: float = 0.0
    filter_type: str = "BLACKMAN_HARRIS"
    filter_width: float = 1.5
    transparent: bool = False
    max_paths: int = 1 << 18
    threads: int = 0
    time_limit: float = 0.0


@dataclass
class Scene:
    meshes: Sequence[Mesh] = ()
    instances: Sequence[Instance] = ()
    materials: Sequence[Material] = ()
    lights: Sequence[Light] = ()
    world: World = field(default_factory=World)
    camera: Camera = field(default_factory=Camera)

    def validate(self) -> None:
        from .validate import validate_scene
        validate_scene(self)
