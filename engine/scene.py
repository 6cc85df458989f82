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

The data does not check itself: ``engine.validate.validate_scene(scene)``
reads it and checks shapes, dtypes, finiteness and index ranges, raising
``SceneError`` with a message that names the offending item.
"""
from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields, make_dataclass
from typing import Optional, Sequence, Tuple, Union

import numpy as np

from . import lobes as _lobes

RGB = Tuple[float, float, float]


class SceneError(ValueError):
    """Invalid scene data, with a message meant for the user."""


class Cancelled(Exception):
    """The user stopped the render before its first pass (during export or
    scene preparation): there is no image to keep."""


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
    # Per-corner tangents (T, 3, 3) of the UV map (Blender's MikkTSpace
    # ``calc_tangents``) and bitangent signs (T, 3): bitangent =
    # sign * cross(normal, tangent).  Optional; normal maps need them and
    # fall back to per-triangle UV tangents without.
    tangents: Optional[np.ndarray] = None
    tangent_signs: Optional[np.ndarray] = None
    # For shader nodes (engine.nodes.context): UV maps by name {name: (T, 3, 2)}
    # beside the active one in ``uvs``; colour attributes {name: (T, 3, 4)}
    # linear RGBA per corner ('' = the default colour attribute); the
    # texture space (location, size) of Generated coordinates (None: the
    # bounding box, as Blender's automatic one); undeformed corner positions
    # (T, 3, 3) for Generated when modifiers deform the mesh.
    uv_maps: Optional[dict] = None
    attributes: Optional[dict] = None
    texspace: Optional[tuple] = None
    orco: Optional[np.ndarray] = None
    # Deformation motion blur: vertex positions (S, V, 3) at the shutter's S
    # evenly spaced steps (step k at time k / (S - 1) of the shutter), and
    # optionally per-corner shading normals (S, T, 3, 3) there; None: the
    # mesh does not deform during the shutter.
    motion: Optional[np.ndarray] = None
    motion_normals: Optional[np.ndarray] = None
    # The Vector pass (engine/vector_pass.py): vertex positions (3, V, 3) at
    # frame - 1, frame, frame + 1 when that pass is on and motion blur off.
    vector_motion: Optional[np.ndarray] = None
    # (T,) bool: which faces are shaded smooth (None: every face with corner
    # normals); true displacement gives only smooth faces vertex normals.
    smooth: Optional[np.ndarray] = None
    # (V, 3) vertex positions before true displacement (engine/displacement.py
    # sets it where a material displaces with "Both"); None: not displaced.
    undisplaced: Optional[np.ndarray] = None


@dataclass
class Instance:
    """One placement of a mesh.

    matrix: (4, 4) object-to-world.
    materials: scene material index per material slot of the mesh; a slot past
        the end or holding -1 uses the default grey diffuse material.
    visible_*: Blender's Object > Visibility > Ray Visibility: which rays
        see the object (camera rays, rays leaving a diffuse, glossy or
        transmission bounce); visible_shadow=False: it casts no shadow.
    """
    mesh: int
    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))
    materials: Sequence[int] = ()
    name: str = "object"
    visible_camera: bool = True
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    visible_shadow: bool = True
    # Object Info node: the object's colour and random number (the
    # depsgraph instance's random_id / 0xFFFFFFFF, as Cycles); pass_index
    # is Blender's Object Index (Object Info and passes); the Cryptomatte
    # asset: the name of the topmost parent ("" = the object itself).
    color: tuple = (1.0, 1.0, 1.0)
    pass_index: int = 0
    random: float = 0.0
    asset: str = ""
    # Attribute nodes of type Object, Instancer and View Layer: the RGBA value
    # (4 floats) the exporter resolved for this instance, by
    # engine.nodes.input_nodes.instance_attribute_key(type, name).
    object_attributes: dict = field(default_factory=dict)
    # Object > Visibility > Mask > Holdout (or a holdout collection): camera
    # rays meeting the object end there and leave the film transparent;
    # every other ray sees the object as usual (Cycles' SD_OBJECT_HOLDOUT_MASK).
    holdout: bool = False
    # Object > Visibility > Mask > Shadow Catcher (engine/integrator/catcher.py).
    shadow_catcher: bool = False
    # Transform motion blur: object-to-world (S, 4, 4) at the shutter's S
    # evenly spaced steps (Cycles' motion steps); None: it does not move.
    motion: Optional[np.ndarray] = None
    # The Vector pass: object-to-world (3, 4, 4) at frame - 1, frame, frame + 1.
    vector_motion: Optional[np.ndarray] = None
    # A fluid domain's voxel grids {name: (Z, Y, X) or (Z, Y, X, C)} over
    # its mesh's texture space (engine/media/voxels.py), read by its
    # volume material's attribute lookups; None: no grids.
    voxels: Optional[dict] = None
    # A Volume object's grids are placed: {name: object-to-unit 4x4}
    # (addon/export/volume_object.py); grids without one use Generated.
    voxel_placements: Optional[dict] = None
    # A factor on every coefficient of the object's textured media (Cycles'
    # object_volume_density: a Volume object whose Render > Space is Object
    # has 1 / |M (1, 1, 1) / sqrt 3|, so its density follows its scale).
    volume_density: float = 1.0


def _point_cloud_fields():
    """PointCloud's fields: the points, then Instance's placement fields
    (matrix, materials, name, ray visibility, object info) with their
    defaults, then the per-point attributes."""
    out = [("positions", np.ndarray), ("radii", np.ndarray)]
    for f in fields(Instance):
        if f.name in ("mesh", "asset", "voxels", "voxel_placements", "volume_density"):
            continue
        default = {} if f.default is MISSING else {"default": "points" if f.name == "name" else f.default}
        if f.default_factory is not MISSING:
            default = {"default_factory": f.default_factory}
        out.append((f.name, f.type, field(**default)))
    # Deformation motion blur (Cycles' motion positions attribute): object-space
    # positions (S, N, 3) at the ``motion`` steps' times (S evenly spaced over
    # the shutter), and for points their radii there (S, N) (curves keep their
    # radii, as Cycles' Embree setup); None: no deformation.  The Vector
    # pass (engine/vector_pass.py): ``vector_motion`` (3, 4, 4), Instance's,
    # and ``vector_positions`` (3, N, 3), the points at frame - 1, frame,
    # frame + 1 (None: not deformed).
    return out + [("attributes", Optional[dict], field(default=None)),
                  ("motion_positions", Optional[np.ndarray], field(default=None)),
                  ("motion_radii", Optional[np.ndarray], field(default=None)),
                  ("vector_positions", Optional[np.ndarray], field(default=None))]


PointCloud = make_dataclass("PointCloud", _point_cloud_fields())
PointCloud.__module__ = __name__
PointCloud.__doc__ = """Spheres (Blender's point cloud objects, geometry nodes' Points).

    positions: (N, 3) object-space centres; radii: (N,) radii (the radius
    attribute); matrix: object-to-world (radii scale by cbrt|det|, as
    Cycles); materials: scene material per slot (one slot: the cloud's
    material); attributes: {name: (N, C)} per-point values shader nodes read
    as colour attributes; motion: object-to-world (S, 4, 4) over the shutter
    (transform motion blur); motion_positions (S, N, 3) / motion_radii (S, N):
    the points at the shutter's steps (deformation motion blur);
    vector_motion (3, 4, 4) / vector_positions (3, N, 3): the matrix and
    points at frame - 1, frame, frame + 1 for the Vector pass (motion blur
    off); the other fields as ``Instance``'s.
    """


def _curve_fields():
    """HairCurves' fields: control points, radii and curve offsets, then
    Instance's placement fields."""
    skip = {"positions", "radii", "attributes", "motion_radii"}
    return ([("points", np.ndarray), ("radii", np.ndarray), ("offsets", np.ndarray)]
            + [f for f in _point_cloud_fields() if f[0] not in skip]
            + [("point_attributes", Optional[dict], field(default=None)),
               ("curve_attributes", Optional[dict], field(default=None)),
               ("uv", Optional[str], field(default=None)),
               ("first_curve", int, field(default=0)),
               ("normals", Optional[np.ndarray], field(default=None)),
               ("texspace", Optional[tuple], field(default=None))])


HairCurves = make_dataclass("HairCurves", _curve_fields())
HairCurves.__module__ = __name__
HairCurves.__doc__ = """Strands (Blender's Curves objects): Catmull-Rom curves, Cycles' 3D curves or ribbons, or its linear 3D curves (Scene.curve_shape).

    points: (N, 3) object-space control points; radii: (N,) per point (the
    radius attribute); offsets: (C + 1,) first point of each curve and the
    total (Blender's curve_offset_data); point_attributes {name: (N, C)} per
    control point (mixed linearly along a segment, as Cycles), curve_attributes
    {name: (C, K)} per curve, read by the Attribute, Color Attribute and UV Map
    nodes; uv: the name of the 2-column attribute that is the strands' active
    UV map (None: no UV map); first_curve: the index of the first curve among
    those of its Cycles Hair (an emitter's particle systems are one): the
    Curves Info node's Random hashes it; texspace: (location, size) of the
    emitter's texture space (particle hair: Generated is each strand's root
    mapped through it, as Cycles; None: the object-space position, as
    Cycles' Curves objects); normals: (N, 3) object-space curve normals per
    control point (Blender's, what Cycles' Huang hair aligns an elliptical
    fibre's major axis with; None: none, as Cycles' particle hair); motion:
    object-to-world (S, 4, 4) over the shutter; motion_positions (S, N, 3):
    the control points at the shutter's steps (deformation motion blur;
    radii stay); vector_motion / vector_positions: the Vector pass's steps
    (frame - 1, frame, frame + 1), as PointCloud's; the other fields as
    ``Instance``'s.
    """


# ----------------------------------------------------------------------------
# Materials

def _lobe_doc():
    kinds = "; ".join(f"'{d.name}' ({d.doc})" for d in _lobes.REGISTRY.values())
    params = "\n".join(f"    {p.name}: {p.doc}" for p in _lobes.PARAMS)
    return (f"One BSDF lobe of a material (Cycles' closures, see engine.bsdf and the\n"
            f"registry engine/lobes/, from which these fields are derived).\n\n"
            f"    kind: {kinds}.\n{params}\n")


Lobe = make_dataclass("Lobe", [("kind", str)] + [(p.name, p.hint, field(default=p.default))
                                                 for p in _lobes.PARAMS])
Lobe.__module__, Lobe.__doc__ = __name__, _lobe_doc()


LOBE_KINDS = _lobes.kinds()
PHASE_FUNCTIONS = ("HENYEY_GREENSTEIN", "RAYLEIGH", "DRAINE", "FOURNIER_FORAND", "MIE")
FRESNEL_MODES = tuple(_lobes.registry.FRESNEL_IDS)   # ("none", "schlick", "f82", "dielectric", "conductor")


@dataclass
class Volume:
    """A homogeneous medium filling a closed mesh (a material's Volume
    output, Cycles' volume closures summed): per-metre coefficients, linear
    RGB.  absorption = sigma_a, scattering = sigma_s (extinction is their
    sum), emission = radiance emitted per metre (Cycles' volume emission:
    integrated along the ray times the transmittance), anisotropy = the
    Henyey-Greenstein g of the scattering, in [-1, 1] (Cycles clamps |g|
    to 1 - 1e-3).  engine/media/ renders it."""
    absorption: RGB = (0.0, 0.0, 0.0)
    scattering: RGB = (0.0, 0.0, 0.0)
    emission: RGB = (0.0, 0.0, 0.0)
    anisotropy: float = 0.0
    # The scattering's phase function (Blender 4.2+'s Volume Scatter, as
    # Cycles): 'HENYEY_GREENSTEIN' (anisotropy), 'RAYLEIGH', 'DRAINE'
    # (anisotropy, alpha), 'FOURNIER_FORAND' (backscatter, ior) or 'MIE'
    # (droplet diameter in micrometres).
    phase: str = "HENYEY_GREENSTEIN"
    alpha: float = 0.5
    backscatter: float = 0.1
    ior: float = 1.33
    diameter: float = 20.0
    # How the point a segment's direct light is sampled at is chosen
    # (Cycles' material / world Volume > Sampling): 'DISTANCE',
    # 'EQUIANGULAR' or 'MULTIPLE_IMPORTANCE' (the two by MIS; Blender's
    # default for materials, its worlds default to 'EQUIANGULAR').
    sampling: str = "MULTIPLE_IMPORTANCE"


@dataclass
class Material:
    """A weighted set of lobes plus emitted radiance (W/(m^2 sr), two-sided).
    ``volume``: the medium inside the mesh (None: none).  Paths enter it
    crossing a front face of the material's triangles and leave it crossing
    a back face, so the mesh should be closed with its normals outward.  A
    material with only a Volume output in Blender has one transparent lobe
    of weight 1: its surface is a pass-through boundary, as in Cycles."""
    name: str = "material"
    lobes: Sequence[Lobe] = (Lobe("diffuse"),)
    emission: RGB = (0.0, 0.0, 0.0)
    # A Bump or NormalMap expression replacing the shading normal, a vector
    # node's NodeOutput (e.g. Bevel; normalized), or None.
    normal: Optional["Texture"] = None
    pass_index: int = 0  # Blender's Material Index
    # Shader AOVs (AOV Output nodes): name -> ((r, g, b), value), constants.
    aovs: dict = field(default_factory=dict)
    volume: Optional[Volume] = None
    # The tangent of its anisotropic lobes: a vector expression (a Tangent
    # node's NodeOutput, Cycles' radial default included), projected onto the
    # plane of the shading normal per hit; None: the shading frame's own.
    tangent: Optional["Texture"] = None
    # The lobes (slot indices: sheen, coat) whose albedo at the view angle
    # dims the emission, as Cycles' Principled BSDF layers its emission.
    emission_layers: tuple = ()
    # Holdout shader weight in [0, 1] (Cycles' holdout closure): camera rays
    # (and their transparent passes) hitting the surface uncover the film's
    # alpha by it, whatever Film > Transparent says; other rays see its part
    # as black.
    holdout: float = 0.0
    # True displacement (engine/displacement.py): a Displacement, or None.
    displacement: Optional["Displacement"] = None


@dataclass(eq=False)
class Displacement:
    """A material's true displacement (Cycles' Displacement Only / Both): the
    vertices move by height along their normal in ``space`` ('OBJECT' or
    'WORLD', the Displacement node's); ``method`` 'DISPLACEMENT' recomputes
    the normals, 'BOTH' keeps them (the material's bump bends them)."""
    height: object
    space: str = "OBJECT"
    method: str = "DISPLACEMENT"


DISPLACEMENT_SPACES = ("OBJECT", "WORLD")
DISPLACEMENT_METHODS = ("DISPLACEMENT", "BOTH")


DEFAULT_MATERIAL = Material("default", (Lobe("diffuse", (0.8, 0.8, 0.8)),))


# ----------------------------------------------------------------------------
# Textures: expressions a Lobe parameter, a Material's emission or its normal
# may hold instead of a constant (evaluated per ray by engine.textures).
# Colours evaluate to RGB, everything else to a float; a colour used as a float
# is its Rec.709 luminance and a float used as a colour is grey, as Cycles.
# Every Lobe field but kind, fresnel, multiscatter and covers may be one (so a
# lobe's weight and IOR may vary per ray, e.g. a textured Principled Metallic,
# Alpha or Mix Shader factor); engine.textures.value_range bounds their values.

INTERPOLATIONS = ("Closest", "Linear")
EXTENSIONS = ("REPEAT", "EXTEND", "CLIP", "MIRROR")
ALPHA_MODES = ("STRAIGHT", "PREMUL", "CHANNEL_PACKED", "NONE")


@dataclass(eq=False)
class TextureImage:
    """Pixels of an image: (H, W, C) float, C in 1..4, row 0 at the TOP,
    linear values (or data for Non-Color images).

    srgb_filter: filter in sRGB encoding and decode after (Cycles keeps 8-bit
        sRGB images encoded and decodes after interpolation).
    alpha_mode: Blender's image alpha mode; STRAIGHT colours are associated
        with alpha before filtering (Cycles does); NONE ignores alpha.
    data: Non-Color (no alpha association).
    tiles: a UDIM image's tiles, ((number, TextureImage), ...) with 1001 +
        u + 10 v the tile of UVs in [u, u + 1) x [v, v + 1) (Cycles' lookup,
        engine.textures); pixels are then the first tile's.  Empty for an
        ordinary image.
    """
    pixels: np.ndarray
    name: str = "image"
    srgb_filter: bool = False
    alpha_mode: str = "STRAIGHT"
    data: bool = False
    tiles: tuple = ()


@dataclass(eq=False)
class ImageTexture:
    """Image Texture node.  uv: None = the hit's UV map.  output 'Color' or
    'Alpha'.  unassociate: divide colour by alpha (Cycles does when the
    node's Alpha output is linked).

    projection 'EQUIRECTANGULAR' or 'MIRROR_BALL' (ENV_PROJECTIONS): the
    Environment Texture node on a surface (Cycles' svm_node_tex_environment):
    uv is then its Vector, None = the world position (the node's socket is
    LINK_POSITION), normalized and projected as a world direction; the
    extension is REPEAT and tiles are not read, as Cycles' node does."""
    image: TextureImage
    interpolation: str = "Linear"
    extension: str = "REPEAT"
    output: str = "Color"
    unassociate: bool = False
    uv: Optional[object] = None
    projection: str = "FLAT"


MIX_BLENDS = ("MIX", "ADD", "MULTIPLY", "SUBTRACT", "SCREEN", "OVERLAY", "DIVIDE",
              "DIFFERENCE", "DARKEN", "LIGHTEN", "BURN", "DODGE", "HUE", "SATURATION", "VALUE",
              "COLOR", "SOFT_LIGHT", "LINEAR_LIGHT", "EXCLUSION")


@dataclass(eq=False)
class MixColor:
    """Mix node in colour mode (and the legacy MixRGB): a colour."""
    blend: str
    fac: object
    a: object
    b: object
    clamp_factor: bool = True
    clamp_result: bool = False


MATH_OPERATIONS = ("ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "POWER", "LOGARITHM",
                   "SQRT", "INVERSE_SQRT", "ABSOLUTE", "EXPONENT", "MINIMUM", "MAXIMUM",
                   "LESS_THAN", "GREATER_THAN", "SIGN", "ROUND", "FLOOR", "CEIL", "TRUNC",
                   "FRACT", "MODULO", "SINE", "COSINE", "TANGENT", "SNAP", "COMPARE", "SMOOTH_MIN",
                   "SMOOTH_MAX", "WRAP", "PINGPONG", "ARCSINE", "ARCCOSINE", "ARCTANGENT", "ARCTAN2",
                   "SINH", "COSH", "TANH", "RADIANS", "DEGREES", "FLOORED_MODULO")


@dataclass(eq=False)
class Math:
    """Math node on floats (a, b, c as its three inputs): a float."""
    operation: str
    a: object
    b: object = 0.0
    c: object = 0.0
    clamp: bool = False


@dataclass(eq=False)
class NormalMap:
    """Normal Map node: colour (in [0, 1]), strength and space ('TANGENT',
    'OBJECT', 'WORLD', 'BLENDER_OBJECT', 'BLENDER_WORLD')."""
    color: object
    strength: object = 1.0
    space: str = "TANGENT"


NORMAL_MAP_SPACES = ("TANGENT", "OBJECT", "WORLD", "BLENDER_OBJECT", "BLENDER_WORLD")


@dataclass(eq=False)
class Bump:
    """Bump node: height (a float), strength, distance, invert, and an
    optional NormalMap (or vector NodeOutput) feeding its Normal input."""
    height: object
    strength: object = 1.0
    distance: object = 1.0
    invert: bool = False
    normal: Optional[NormalMap] = None
    # A "Displacement and Bump" material's bump: differentiated on the
    # surface before true displacement, as Cycles' NODE_ENTER_BUMP_EVAL
    # (the undisplaced position's derivatives).
    undisplaced: bool = False
    # The Material Output's displacement as bump: Cycles' SetNormal makes it
    # the smooth normal (sd->N), so the bump shadowing term leaves it alone.
    sets_normal: bool = False
    # The Material Output's "Both" bump (Cycles' bump_from_displacement):
    # computed in object space (the BumpNode's use_object_space) on the
    # height dot(displacement vector in world space, N), which for an
    # Object-space Displacement node is the height times |M^T N|.  None:
    # an ordinary world-space bump; else the Displacement node's space.
    displacement_space: Optional[str] = None
    # The Bump node's Filter Width (Blender 4.3+): Cycles evaluates the
    # height at P + width dPdx and P + width dPdy (engine.textures.footprint_bump).
    filter_width: object = 0.1


@dataclass(eq=False)
class NodeCall:
    """One shader node of engine.nodes.REGISTRY: its Blender id, its inputs
    (identifier -> constant or expression) and its properties."""
    idname: str
    inputs: dict
    props: dict = field(default_factory=dict)


@dataclass(eq=False)
class NodeOutput:
    """One output socket of a NodeCall (outputs of one call evaluate once)."""
    call: NodeCall
    output: str


Texture = Union[ImageTexture, MixColor, Math, NormalMap, Bump, NodeOutput]
TEXTURE_TYPES = (ImageTexture, MixColor, Math, NormalMap, Bump, NodeOutput)
# What a Lobe parameter or a Material's emission may hold.
Color = Union[RGB, Texture]
Scalar = Union[float, Texture]


# ----------------------------------------------------------------------------
# Lights (Cycles units).  Each class is one light type's scene data; the type
# itself (validation, sampling, bounds, ...) is its entry in
# engine/lights/registry.py.

# Cycles' Light Falloff node outputs, in the power of the distance they
# multiply the emission by (engine/lights/common.py Falloff).
FALLOFFS = ("QUADRATIC", "LINEAR", "CONSTANT")


@dataclass
class PointLight:
    """Blender point light.  ``power`` = colour * watts.

    Every light has ``visible_camera`` (Blender's Object > Visibility > Camera
    ray, False by default for lights): whether camera rays see its shape;
    ``visible_diffuse`` / ``visible_glossy`` / ``visible_transmission``:
    whether it lights (by NEE) and is seen (by BSDF rays) through those
    bounces, as Cycles' light visibility; ``visible_shadow=False``: objects
    do not block its light (Cycles' light "Cast Shadow" off).

    soft_falloff=False: a sphere of radius ``radius`` with radiance
    P / (4 pi^2 r^2).  soft_falloff=True (Blender 4.0+ default): Cycles' disk of
    radius ``radius`` that always faces the shading point, same radiance.

    falloff / falloff_smooth: the light's node tree feeds its Emission
    Strength through a Light Falloff node ('QUADRATIC' = none, 'LINEAR',
    'CONSTANT') with that Smooth; ``power`` then holds the node's Strength.
    """
    position: Sequence[float]
    power: RGB
    radius: float = 0.1
    soft_falloff: bool = False
    name: str = "point"
    visible_camera: bool = False
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    visible_shadow: bool = True
    falloff: str = "QUADRATIC"
    falloff_smooth: float = 0.0
    # The light's node tree where it varies over the light: a colour
    # expression (as Material.emission) multiplying the radiance per light
    # point (engine/lights/shader.py); None: constant.  matrix: the light
    # object's (4, 4) light-to-world, which its Object and Normal
    # coordinates read (None: a translation to ``position``).
    shader: object = None
    matrix: Optional[np.ndarray] = None


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
    ``angle`` is the full angular diameter in radians.  No falloff: Cycles
    ignores a Light Falloff node on distant lights (its ray_length is
    FLT_MAX)."""
    direction: Sequence[float]
    strength: RGB
    angle: float = 0.0
    name: str = "sun"
    visible_camera: bool = False
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    visible_shadow: bool = True
    # The light's node tree where it varies over the sun's disk (a colour
    # expression, engine/lights/sun.py); None: constant.  matrix: the sun
    # object's (4, 4) light-to-world (its UV axes and Object coordinates;
    # None: a frame at the origin whose -Z is ``direction``).
    shader: object = None
    matrix: Optional[np.ndarray] = None


AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")


@dataclass
class AreaLight:
    """A one-sided area light emitting along its local -Z.

    matrix: (4, 4) light-to-world (may include scale).  The emitter spans
    size_x by size_y in local X/Y (SQUARE and DISK use size_x for both;
    DISK/ELLIPSE sizes are diameters).  ``power`` = colour * watts; with
    ``normalize`` (Cycles' default) radiance = power / (pi * area).
    falloff / falloff_smooth as for PointLight.
    """
    matrix: np.ndarray
    power: RGB
    shape: str = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    normalize: bool = True
    name: str = "area"
    visible_camera: bool = False
    visible_diffuse: bool = True
    visible_glossy: bool = True
    visible_transmission: bool = True
    visible_shadow: bool = True
    falloff: str = "QUADRATIC"
    falloff_smooth: float = 0.0
    shader: object = None   # as PointLight.shader


Light = Union[PointLight, SpotLight, SunLight, AreaLight]


ENV_INTERPOLATIONS = ("Linear", "Closest")
ENV_PROJECTIONS = ("EQUIRECTANGULAR", "MIRROR_BALL")


@dataclass
class EnvironmentTexture:
    """An equirectangular HDRI (Blender's Environment Texture node).

    pixels: (H, W, 3) float32 linear RGB, row 0 = the top of the image (+Z).
    strength: the Background node's strength (radiance = pixels * strength).
    matrix: (3, 3) world direction -> texture lookup vector (the Mapping
        node's linear part, e.g. its rotation); any invertible matrix.
    interpolation: 'Linear' (bilinear, Cycles' default) or 'Closest'.
    Lookups follow Cycles exactly: direction_to_equirectangular, pixel
    centres at (i + 0.5) / W, periodic wrap in both axes.
    """
    pixels: np.ndarray
    strength: float = 1.0
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    interpolation: str = "Linear"
    name: str = "environment"
    # A baked procedural world: ``shader`` (a texture expression of the
    # direction, e.g. a Sky Texture) gives the radiance of every direction
    # exactly, as Cycles shades the background; ``pixels`` then only build
    # the sampling table.  ``sun``: a disc the table cannot resolve, sampled
    # by its cone as Cycles' sun guiding does (``SunGuide``).
    shader: Optional[object] = None
    sun: Optional["SunGuide"] = None
    # The procedural world's expression even where renders read the baked
    # pixels: an Environment bake shades it exactly per direction (engine/bake.py).
    expression: Optional[object] = None
    # The node's projection: 'EQUIRECTANGULAR' or 'MIRROR_BALL' (Cycles'
    # direction_to_mirrorball; the sampling table is then resampled onto
    # an equirectangular grid, engine/environment.py).
    projection: str = "EQUIRECTANGULAR"


@dataclass
class SunGuide:
    """A small bright disc of a procedural world (the Sky Texture's sun):
    unit world ``direction``, ``half_angle`` (radians) and ``power``, its
    luminance integrated over its solid angle (for light selection)."""
    direction: Tuple[float, float, float]
    half_angle: float
    power: float = 0.0


@dataclass
class World:
    """The background.  Without ``texture``: a constant radiance ``color``
    (Background colour * strength), which is only BSDF sampled, as Cycles.
    With ``texture``: the HDRI replaces ``color`` and is importance sampled
    (next-event estimation combined with BSDF sampling by MIS)."""
    color: RGB = (0.05, 0.05, 0.05)
    texture: Optional[EnvironmentTexture] = None
    # The world's Volume output: a homogeneous medium filling all space,
    # at the bottom of every path's volume stack (Cycles adds the background
    # volume first and keeps it inside objects: their media add to it).
    # Constant coefficients only.  Light from infinitely far (the world,
    # suns) is extinguished by it entirely, as in Cycles.
    volume: Optional[Volume] = None


# ----------------------------------------------------------------------------
# Camera

@dataclass
class Camera:
    """A Blender camera plus the render resolution that frames it.

    matrix: (4, 4) camera-to-world; the camera looks down local -Z, +Y up.
    kind: 'PERSP', 'ORTHO' or 'PANO' (panoramic).  lens in mm, sensor sizes in mm,
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
    # Camera motion blur: camera-to-world (S, 4, 4) at the shutter's S evenly
    # spaced steps; None: a still camera.  Rays take their time over the
    # shutter from the sampler's time dimension (by the shutter curve and
    # rolling shutter below) and the camera at that time (rotation by
    # quaternion, translation linearly, as Cycles).
    motion: Optional[np.ndarray] = None
    # The shutter (engine/shutter.py), read only when something moves: the
    # shutter curve's 256 values over the shutter (None: flat), the rolling
    # shutter ('NONE' or 'TOP': Cycles' Top-Bottom) and its duration in [0, 1].
    shutter_curve: Optional[np.ndarray] = None
    rolling_shutter: str = "NONE"
    rolling_duration: float = 0.1
    # Focal-length animation (perspective): the lens in mm at the shutter's
    # start and end, None: constant (Cycles' fov_pre / fov_post).
    lens_motion: Optional[Tuple[float, float]] = None
    # The Vector pass: camera-to-world (3, 4, 4) at frame - 1, frame, frame + 1.
    vector_motion: Optional[np.ndarray] = None
    # Panoramic cameras (kind 'PANO', engine/panorama.py): Blender's
    # panorama_type and its settings (angles in radians, lengths in mm but
    # the cylinder's, which are in its radius' units).
    panorama_type: str = "FISHEYE_EQUISOLID"
    fisheye_fov: float = np.pi
    fisheye_lens: float = 10.5
    latitude: Tuple[float, float] = (-0.5 * np.pi, 0.5 * np.pi)
    longitude: Tuple[float, float] = (-np.pi, np.pi)
    # k0..k4 of the polynomial fisheye: theta = -(k0 + k1 r + ... + k4 r^4)
    fisheye_polynomial: Tuple[float, ...] = (-1.17351e-05, -0.0199887, -3.3525e-06, 3.0993e-06, -2.61e-08)
    # The central cylinder: longitude min, max, height min, max, radius.
    cylinder: Tuple[float, ...] = (-np.pi, np.pi, -1.0, 1.0, 1.0)
    # Spherical stereo (engine/stereo.py): the eye's signed half interocular
    # distance (0: none), the convergence distance (inf: parallel) and the
    # pole merge's altitudes (radians; (0, 0): none).
    stereo_offset: float = 0.0
    stereo_convergence: float = np.inf
    stereo_pole_merge: Tuple[float, float] = (0.0, 0.0)


# ----------------------------------------------------------------------------
# Settings

@dataclass
class RenderSettings:
    """How to render.

    samples: samples per pixel in total; samples_per_pass: how many are
    added between two progress callbacks (0: automatic, one sample first,
    then passes of about a second; engine/render.py).  max_bounces follows Cycles: the
    number of indirect bounces, so 0 is direct lighting only (light sampling
    at the first hit, emission found by its BSDF sample).  light_selection: 'uniform',
    'power', 'all', 'tree' (a light tree: by each light's estimated
    contribution at the shading point; for scenes with many lights) or 'auto'
    (the tree, and every light at glossy vertices with 2-4 lights and no
    emissive mesh: engine/lights/lightset.py resolve_selection) or 'ris' (4 light-tree
    candidates per vertex, one kept by its unshadowed contribution with the BSDF: engine/nee.py resample).  strategy: 'mis', 'light' (NEE only) or 'bsdf'.
    clamp: 0 disables clamping of a sample's radiance.  max_paths bounds the
    number of paths in flight (memory); threads 0 = every core.
    time_limit: seconds (0 = none); stops after the pass that crosses it.
    transparent_max_bounces: passes straight through transparent surfaces
    (Transparent BSDF, Principled Alpha), counted apart from max_bounces as
    Cycles does (its default is 8): a path may cross this many, after which
    the next surface only adds its emission; a shadow ray crosses at most
    this many minus those its path has crossed, else it is blocked.
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
    transparent_max_bounces: int = 8
    # Cycles' Light Paths > Max Bounces by kind: after more than this many
    # bounces of a kind the next vertex only adds its emission (as after
    # max_bounces).  The engine's defaults leave max_bounces alone; the
    # add-on's are Cycles' (4, 4, 12).
    diffuse_bounces: int = 1024
    # Cycles' Filter Glossy (its blur_glossy; 0 = off, the engine's default;
    # the add-on's is Cycles' 1.0): engine/integrator/stages.filter_glossy.
    filter_glossy: float = 0.0
    glossy_bounces: int = 1024
    transmission_bounces: int = 1024
    # Sample an HDRI world by max(L - mean, 0) instead of L (MIS compensation,
    # Karlik et al. 2019): BSDF sampling covers the dim parts, NEE spends its
    # samples on what stands out.  Only with strategy 'mis' (NEE alone would
    # miss the dim parts).
    mis_compensation: bool = True
    # Samples traced are the indices [sample_start, sample_start + samples):
    # every random number is addressed by (seed, pixel, sample index,
    # dimension), so disjoint ranges merge into the render of their union.
    sample_start: int = 0
    # Cycles 5.0's volume scattering probability guiding of camera rays in
    # homogeneous media (integrator/volume_guide.py): the scattering choice
    # follows what earlier passes saw.  Unbiased either way; a guided render
    # of disjoint sample ranges merges to the same estimate statistically,
    # not to the float of one render (each range builds its own guide).
    volume_guiding: bool = True
    # Path guiding of the BSDF sample at surface vertices (Mueller et al.
    # 2017, integrator/path_guide.py), learned from the render's own passes
    # over its first path_guiding_training_samples samples (Cycles'
    # Training Samples, 0: all); unbiased, deterministic per seed, each sample range
    # of a farm learning its own.  Off by default (docs/benchmarks.md, "Path
    # guiding that learns its fraction": gain 0.99 in an interior lit
    # indirectly, 0.97-0.98 in direct light, where it stops after 8 samples).
    path_guiding: bool = False
    path_guiding_training_samples: int = 128
    # 'sobol' (shuffled Owen-scrambled Sobol, Cycles' default) or 'random'.
    sampling_pattern: str = "sobol"
    # Adaptive sampling as Cycles: a pixel stops once its error estimate
    # falls below adaptive_threshold (Cycles' Noise Threshold; 0 = off),
    # checked every 16 samples after adaptive_min_samples (0 = automatic).
    adaptive_threshold: float = 0.0
    adaptive_min_samples: int = 0
    # First-hit AOVs the film keeps (memory: only what is asked for).
    aovs: tuple = ("depth", "normal", "albedo")
    # Keep the M2 of each pixel's R + G + B too (RenderResult.sum_variance:
    # the variance of sums over channels, which are correlated; tests ask
    # for it, 4 bytes a pixel).  Images and passes are the same either way.
    sum_variance: bool = False
    # Extra passes by name (engine/passes.py ALL_PASSES; none by default, and
    # none costs nothing) and their settings (a passes.PassConfig or None).
    passes: tuple = ()
    pass_config: object = None
    # Compiled kernels (engine/kernels.py, numba) instead of plain NumPy for
    # the same elementwise maths; off, or without numba, or with EMBER_JIT=0,
    # the NumPy code runs.  Images are the same bit for bit.
    use_jit: bool = True
    # Scattering events a path may have in volumes (Cycles' volume_bounces,
    # default 0: single scattering).  A path past it (or past max_bounces)
    # is still attenuated and lit by volume emission, as in Cycles.
    volume_bounces: int = 0
    # Blender's Persistent Data (Render > Performance): keep the last
    # render's BVH and reuse it when the next one traces the same triangles
    # (engine/accel.py BuiltScenes).  Off, nothing outlives a render.
    persistent: bool = False


@dataclass(frozen=True)
class LinkSet:
    """A light's receiver or blocker collection (Blender 4.0+ Light Linking
    and Shadow Linking) as object names: objects excluded never take part;
    with any object included only the included ones do, else every object
    not excluded does (Blender's rule)."""
    include: frozenset = frozenset()
    exclude: frozenset = frozenset()

    def admits(self, name):
        if name in self.exclude:
            return False
        return name in self.include if self.include else True


@dataclass
class Scene:
    meshes: Sequence[Mesh] = ()
    instances: Sequence[Instance] = ()
    materials: Sequence[Material] = ()
    lights: Sequence[Light] = ()
    world: World = field(default_factory=World)
    camera: Camera = field(default_factory=Camera)
    # The Blender version the scene comes from: where Cycles changed between
    # versions (its bump shadowing term), Ember renders as that version's.
    cycles_version: tuple = (5, 0, 0)
    # Light and shadow linking: scene light index -> (receivers, blockers),
    # each a LinkSet or None (every object).  Lights not listed are linked
    # to everything.
    light_links: dict = field(default_factory=dict)
    # Point clouds (spheres), after the fields above (scenes are built positionally too).
    points: Sequence[PointCloud] = ()
    # Hair curves (Catmull-Rom strands).
    curves: Sequence[HairCurves] = ()
    # Render > Curves > Shape, for every curve set (Cycles' scene-wide
    # curve_shape): 'THICK' (3D curves, round), 'RIBBONS' (flat strands
    # facing each ray, no end caps: engine/points.py ribbon_hits) or
    # 'THICK_LINEAR' (linear 3D curves: round cones between the keys as they
    # are, with spheres at the joints and ends).
    curve_shape: str = "THICK"
    # Render > Curves > Curve Subdivisions (Embree cuts each segment into
    # 2^s + 1 pieces: engine/points.py curve_rate).
    curve_subdivisions: int = 2
