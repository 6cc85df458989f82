"""A light's node tree evaluated per light point, as Cycles'
light_sample_shader_eval (kernel/light/sample.h): the Emission's Color x
Strength at the sampled (or hit) point multiplies the light's radiance.

Cycles sets the shader up with ``shader_setup_from_sample``: P the point on
the light, N = Ng the light's normal there, Incoming = -D (from the light
towards the shading point), no backfacing test, PATH_RAY_EMISSION (no ray
kind).  What the Texture Coordinate and Geometry nodes read there, measured
in bpy 5.0.1 (a camera seeing the light, one sample at each pixel centre):

* area lights: N the emitting normal; UV = Parametric = (x + 0.5, y + 0.5,
  0) with (x, y) the point in the light's axes scaled to [-0.5, 0.5];
* point and spot lights: N = Ng the sphere's normal at the point (soft
  falloff: the disk faces the shading point, N = Incoming); UV =
  Parametric = Cycles' map_to_sphere of the object-space N for point
  lights, spot_light_uv of Incoming in the spot's axes for spots;
* Object = Generated = the point in the light object's space (its inverse
  matrix), Normal = N in object space (transpose of the matrix, normalized).

The pdf never changes, only the radiance, and NEE samples and BSDF rays
that hit a light evaluate the same function of the point, so MIS stays
unbiased.  Light selection weighs a textured light by its power times the
tree's mean over the light (``selection_scale``: noise, not bias).  Values
are made finite and non-negative (a NaN-producing node gives 0, as
everywhere in Ember's textures).
"""
import numpy as np

from ..nodes import ShadingContext
from ..nodes.context import PATH_COLUMNS
from ..vec import dot

# Per-ray values are held to what validation lets constants be.
MAX_VALUE = 1e30
# Cycles' ray length of a sun (ls->t = FLT_MAX), the largest float32.
FLT_MAX = float(np.finfo(np.float32).max)
RAY_LENGTH = PATH_COLUMNS.index("Ray Length")
SINGULAR = PATH_COLUMNS.index("Is Singular Ray")


def emission_path(depth, columns):
    """What a Light Path node in a light's tree reads of the path that
    reaches the light, as Cycles' svm_node_light_path for PATH_RAY_EMISSION:
    Ray Depth is the path's bounce count there + 1 (``depth``: for a light
    sample the vertex's bounce b, reading b + 1; for a ray that hits the
    light the bounces before the ray, b + 1 after vertex b, reading b + 2),
    the per-kind depths and Transparent Depth the path's counts unchanged
    (``columns``: PATH_COLUMNS rows); Ray Length is the light's own."""
    return np.asarray(depth, np.int64) + 1, columns


def path_rows(path, rows):
    """Rows of a (depth, columns) path, or None."""
    return None if path is None else (path[0][rows], path[1][rows])


class LightContext(ShadingContext):
    """Shading points on lights: coordinates in the light object's space
    (``matrix``, ``inverse`` per point), the light's UV, the distance from
    the shading point (Light Path's Ray Length: Cycles' ls->t, FLT_MAX for
    suns), the path that reaches the light (``path``: (depth, PATH_COLUMNS)
    per point, see ``emission_path``; None: every depth reads 0) and the
    scene camera (Camera and Window coordinates of the light point, as on
    surfaces).  No ray kind: Cycles evaluates lights with PATH_RAY_EMISSION,
    so Is Camera Ray and the other kinds read 0."""

    def __init__(self, p, n, wo, uv, matrix, inverse, dist=None, camera=None, path=None):
        depth, columns = (None, np.zeros((len(p), len(PATH_COLUMNS)))) if path is None else path
        columns = np.array(columns, np.float64)
        columns[:, SINGULAR] = 0.0   # PATH_RAY_EMISSION: no singular ray either
        if dist is not None:
            columns[:, RAY_LENGTH] = np.minimum(dist, FLT_MAX)
        super().__init__(len(p), p=p, ng=n, ns=n, wo=wo, ray=np.zeros(len(p), np.uint8), path=columns,
                         depth=None if depth is None else np.asarray(depth, np.int32))
        self.matrix, self.inverse = matrix, inverse
        self._camera = camera
        self._cache[("uv", "")] = uv
        # Geometry > Parametric reads (1 - bu - bv, bu): Cycles' lights give the UV there.
        self.bary = np.stack([uv[:, 1], 1.0 - uv[:, 0] - uv[:, 1]], axis=1)

    def take(self, rows):
        out = super().take(rows)
        out.__class__ = LightContext
        out.matrix, out.inverse, out._camera = self.matrix[rows], self.inverse[rows], self._camera
        return out

    @property
    def camera(self):
        return self._camera

    @property
    def object_coords(self):
        inv = self.inverse
        return np.einsum("nij,nj->ni", inv[:, :3, :3], self.p) + inv[:, :3, 3]

    @property
    def generated(self):
        return self.object_coords   # Cycles: no Generated attribute, object coordinates

    def to_object(self, v):
        out = np.einsum("nji,nj->ni", self.matrix[:, :3, :3], v)
        return _normalize(out)

    def to_world_normal(self, v):
        return _normalize(np.einsum("nji,nj->ni", self.inverse[:, :3, :3], v))


class LightShaders:
    """The node trees of one light table's lights (None where constant).

    lights: the scene lights; matrices: (count, 4, 4) light-to-world;
    camera: the scene's engine.scene.Camera (or None)."""

    def __init__(self, lights, matrices, camera=None):
        from ..textures import Compiler
        compiler = Compiler()
        self.fns = {j: compiler.color(l.shader) for j, l in enumerate(lights) if l.shader is not None}
        # A Light Path node reads the path's depths: the integrator then
        # tracks them (integrator Context.light_path).
        self.light_path = any(call.idname == "ShaderNodeLightPath" for call, _ in compiler.calls.values())
        self.matrix = np.asarray(matrices, np.float64).reshape(-1, 4, 4)
        self.inverse = np.array([_safe_inverse(m) for m in self.matrix]).reshape(-1, 4, 4)
        self.camera = camera

    @classmethod
    def of(cls, lights, matrices, camera=None):
        """The table's shaders, or None when every light is constant."""
        if any(getattr(l, "shader", None) is not None for l in lights):
            return cls(lights, matrices, camera)
        return None

    def factor(self, j, q, n, wo, uv, dist=None, path=None):
        """(N, 3) emission of light j (per row, or one int) at points q with
        light normals n, Incoming wo, UVs uv (N, 2), distances dist from
        the shading points (N,) or None (0) and the paths' (depth, columns)
        there (``emission_path``; None: 0); 1 for constant lights."""
        m = len(q)
        out = np.ones((m, 3))
        j = np.broadcast_to(np.asarray(j, np.int64), (m,))
        for k, fn in self.fns.items():
            rows = np.flatnonzero(j == k)
            if not len(rows):
                continue
            ctx = LightContext(q[rows], n[rows], wo[rows], uv[rows], self.matrix[j[rows]], self.inverse[j[rows]],
                               None if dist is None else np.broadcast_to(dist, (m,))[rows], self.camera,
                               path_rows(path, rows))
            with np.errstate(all="ignore"):
                value = np.asarray(fn(ctx), np.float64)
            value = np.nan_to_num(value, nan=0.0, posinf=MAX_VALUE, neginf=0.0)
            out[rows] = np.clip(value, 0.0, MAX_VALUE)
        return out

    def selection_scale(self, j, q, n, wo, uv):
        """What light selection weighs light j's power by: the mean of its
        tree over the given points and directions (a spread over the light
        and the directions it emits to), so that an IES light of Fac 50
        is picked as often as its light deserves.  Only noise depends on
        it; a tree that reads 0 everywhere sampled keeps the plain power
        (a light must stay selectable wherever it may emit)."""
        if j not in self.fns:
            return 1.0
        mean = float(self.factor(np.full(len(q), j), q, n, wo, uv).mean())
        return mean if np.isfinite(mean) and mean > 0 else 1.0

    def sphere_uv(self, j, n):
        """Cycles' map_to_sphere of the object-space normal n of light j."""
        m = len(n)
        j = np.broadcast_to(np.asarray(j, np.int64), (m,))
        local = _normalize(np.einsum("nji,nj->ni", self.matrix[j][:, :3, :3], n))
        return map_to_sphere(local)


def map_to_sphere(co):
    """Cycles' map_to_sphere (util/math): u from atan2(x, y), v from acos(z)."""
    length = np.sqrt(dot(co, co))
    x, y, z = co[:, 0], co[:, 1], co[:, 2]
    u = np.where((x == 0) & (y == 0), 0.0, 0.5 - np.arctan2(x, y) / (2.0 * np.pi))
    with np.errstate(invalid="ignore", divide="ignore"):
        v = 1.0 - np.arccos(np.clip(z / length, -1.0, 1.0)) / np.pi
    ok = length > 0
    return np.stack([np.where(ok, u, 0.0), np.where(ok, v, 0.0)], axis=1)


def checker_of(idname, output, scale):
    """A Checker Texture on one output of an input node: the registry's
    examples of lights whose node tree varies over them."""
    from ..scene import NodeCall, NodeOutput
    vector = NodeOutput(NodeCall(idname, {}), output)
    call = NodeCall("ShaderNodeTexChecker", {"Vector": vector, "Color1": (1.0, 0.5, 0.2),
                                             "Color2": (0.1, 0.2, 0.3), "Scale": scale})
    return NodeOutput(call, "Color")


def _safe_inverse(m):
    try:
        return np.linalg.inv(m)
    except np.linalg.LinAlgError:
        return np.eye(4)


def _normalize(v):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), 0.0)


def spread_directions(count, seed=0):
    """(count, 3) fixed unit directions spread over the sphere (a Fibonacci
    lattice): where selection_scale evaluates a tree."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = k * np.pi * (3.0 - np.sqrt(5.0)) + seed
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
