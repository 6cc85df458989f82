"""The per-hit shading context that shader nodes read.

A ``ShadingContext`` describes N shading points: the triangle and the
barycentrics of each, the world position, normals, the incoming direction,
which side was hit and the ray's depth.  Everything else a node may ask for
(UV maps by name, Generated and Object coordinates, colour attributes,
object info) is interpolated from the triangle on first use and kept, so a
material that only reads UVs costs what it did before.

``SceneShading`` holds the per-scene tables behind it (object matrices and
info per instance, per-mesh corner attributes gathered into per-triangle
arrays on demand).  It hangs off ``geometry.Triangles.shading``.

Bump mapping moves a context along the surface (``shifted``): barycentrics
change with the world offset, so every interpolated attribute, UVs
included, moves consistently with the position.
"""
import numpy as np

from .. import instance_columns

LUMA = np.array([0.2126, 0.7152, 0.0722])
# What the Light Path node reads of the path besides its ray kind and depth
# (ShadingContext.path, filled by the integrator where a material uses it).
# Reserved corner-attribute names of the Geometry node's Pointiness and
# Random Per Island (engine.mesh_attributes computes them; no user attribute
# name holds a NUL).
POINTINESS = "\x00pointiness"
RANDOM_PER_ISLAND = "\x00random_per_island"
# Reserved names of the Curves Info node's per-strand data (engine.curve_attributes
# gives them to curve segments only; elsewhere they read 0, as Cycles' missing
# attribute): intercept and thickness along the strand, its length and random.
CURVE_INTERCEPT = "\x00curve_intercept"
CURVE_THICKNESS = "\x00curve_thickness"
CURVE_LENGTH = "\x00curve_length"
CURVE_RANDOM = "\x00curve_random"
IS_STRAND = "\x00is_strand"
# 1 on ribbon segments (Scene.curve_shape RIBBONS): Cycles' Ng there is the view direction.
IS_RIBBON = "\x00is_ribbon"
# A Mesh.texspace meaning "Generated is the object-space position" (Cycles'
# fallback where a geometry has no generated attribute: Curves objects).
POSITION_TEXSPACE = "object position"

PATH_COLUMNS = ("Diffuse Depth", "Glossy Depth", "Transmission Depth", "Transparent Depth", "Ray Length",
                "Is Singular Ray", "Portal Depth")


class SceneShading:
    """Per-instance and per-mesh data the shading context interpolates."""

    def __init__(self, scene, instance_of_triangle, local_triangle):
        self.scene = scene
        self.instance = np.asarray(instance_of_triangle, np.int32)   # (T,) index into scene.instances
        self.local = np.asarray(local_triangle, np.int32)            # (T,) triangle index in its mesh
        cols = instance_columns.columns(scene.instances)
        mats = cols.matrix.reshape(-1, 4, 4)
        self.matrix = mats
        self.inverse = safe_inverses(mats)
        self.location = mats[:, :3, 3] if len(mats) else np.zeros((0, 3))
        self.color = cols.color
        self.pass_index = cols.pass_index
        self.random = cols.random
        self.mesh_of_instance = cols.mesh
        self._instance_attributes = {}
        self._corners = {}

    def instance_attribute(self, key):
        """(I, 4) RGBA per instance of an Object / Instancer / View Layer
        attribute (zeros where the exporter found none, as Cycles)."""
        if key not in self._instance_attributes:
            inst = self.scene.instances
            table = np.zeros((len(inst), 4))
            for k, i in enumerate(inst):
                value = (getattr(i, "object_attributes", None) or {}).get(key)
                if value is not None:
                    table[k] = value
            self._instance_attributes[key] = table
        return self._instance_attributes[key]

    def position_generated(self):
        """(T,) whether each triangle's Generated coordinates are its
        object-space position (a mesh whose texspace is POSITION_TEXSPACE)."""
        if "position_generated" not in self._corners:
            per_mesh = np.array([_is_position_texspace(mesh) for mesh in self.scene.meshes] + [False])
            mesh = self.mesh_of_instance[self.instance] if len(self.mesh_of_instance) else \
                np.full(len(self.instance), -1)
            self._corners["position_generated"] = per_mesh[mesh]
        return self._corners["position_generated"]

    def has_uv(self):
        """(T,) whether each triangle's mesh has a UV map (Cycles' UV pass is
        0 on meshes without one, (u, v, 1) on the others)."""
        if "has_uv" not in self._corners:
            per_mesh = np.array([mesh.uvs is not None for mesh in self.scene.meshes] + [False])
            mesh = self.mesh_of_instance[self.instance] if len(self.mesh_of_instance) else \
                np.full(len(self.instance), -1)
            self._corners["has_uv"] = per_mesh[mesh]
        return self._corners["has_uv"]

    def undisplaced_edges(self, prim):
        """World-space edges (e1, e2) of triangles prim before true
        displacement (meshes displaced with "Both" keep their undisplaced
        positions), or None when no mesh has them."""
        meshes = self.scene.meshes
        if not any(getattr(m, "undisplaced", None) is not None for m in meshes):
            return None
        inst, local = self.instance[prim], self.local[prim]
        mesh = self.mesh_of_instance[inst]
        e1, e2 = np.zeros((len(prim), 3)), np.zeros((len(prim), 3))
        for m in np.unique(mesh):
            rows = np.flatnonzero(mesh == m)
            data = meshes[m]
            pos = data.undisplaced if getattr(data, "undisplaced", None) is not None else data.positions
            p = np.asarray(pos, np.float64)[np.asarray(data.triangles, np.int64)[local[rows]]]
            mats = self.matrix[inst[rows]][:, :3, :3]
            e1[rows] = np.einsum("nij,nj->ni", mats, p[:, 1] - p[:, 0])
            e2[rows] = np.einsum("nij,nj->ni", mats, p[:, 2] - p[:, 0])
        return e1, e2

    def corners(self, key):
        """(T, 3, C) per-corner data of every triangle, or None when no mesh
        has it.  key: ('uv', name), ('attr', name) or ('generated',)."""
        if key not in self._corners:
            self._corners[key] = self._gather(key)
        return self._corners[key]

    def _gather(self, key):
        meshes = self.scene.meshes
        per_mesh = [_mesh_corner_data(mesh, key) for mesh in meshes]
        if all(d is None for d in per_mesh):
            return None
        width = next(d.shape[2] for d in per_mesh if d is not None)
        fill = _fill_value(key, width)
        out = np.empty((len(self.instance), 3, width))
        out[:] = fill
        mesh_of_tri = self.mesh_of_instance[self.instance]
        for m, data in enumerate(per_mesh):
            if data is None:
                continue
            rows = np.nonzero(mesh_of_tri == m)[0]
            if len(rows):
                out[rows] = data[self.local[rows], :, :width]
        return out


def _safe_inverse(m):
    try:
        return np.linalg.inv(m)
    except np.linalg.LinAlgError:
        return np.eye(4)


def safe_inverses(mats):
    """(N, 4, 4) inverses of ``mats``, the identity for a singular one: one
    batched inversion (10^6 instances: 0.3 s, not 8 s one by one), and one
    by one only when the batch has a singular matrix."""
    mats = np.asarray(mats, np.float64).reshape(-1, 4, 4)
    try:
        return np.linalg.inv(mats)
    except np.linalg.LinAlgError:
        return np.array([_safe_inverse(m) for m in mats]).reshape(-1, 4, 4)


def _fill_value(key, width):
    if key[0] == "attr":
        return np.zeros(width) if width != 4 else np.array([0.0, 0.0, 0.0, 1.0])
    return np.zeros(width)


def _mesh_corner_data(mesh, key):
    """A mesh's (T, 3, C) corner data for key, or None."""
    if key[0] == "uv":
        name = key[1]
        maps = getattr(mesh, "uv_maps", None) or {}
        if name and name in maps:
            return np.asarray(maps[name], dtype=np.float64)
        return None if mesh.uvs is None or name else np.asarray(mesh.uvs, dtype=np.float64)
    if key[0] == "attr":
        attrs = getattr(mesh, "attributes", None) or {}
        data = attrs.get(key[1])
        if data is None:
            return None
        data = np.asarray(data, dtype=np.float64)
        return data[..., None] if data.ndim == 2 else data
    if key[0] == "generated":
        return None if _is_position_texspace(mesh) else generated_corners(mesh)
    if key[0] == "tangent":
        tangents = getattr(mesh, "tangents", None)
        return None if tangents is None else np.asarray(tangents, dtype=np.float64)
    raise KeyError(key)


def _is_position_texspace(mesh):
    space = getattr(mesh, "texspace", None)
    return isinstance(space, str) and space == POSITION_TEXSPACE


def generated_corners(mesh):
    """Cycles' Generated coordinates at each corner: the undeformed position
    (``mesh.orco`` when the exporter gave it, else the positions) mapped
    through the texture space, (orco - location) / (2 size) + 0.5.  Without
    an exported texture space Blender's automatic one is used: the bounding
    box, with a zero extent replaced by 1 as Blender does."""
    orco = getattr(mesh, "orco", None)
    pos = np.asarray(mesh.positions, dtype=np.float64)
    tris = np.asarray(mesh.triangles, dtype=np.int64)
    corners = np.asarray(orco, dtype=np.float64) if orco is not None else pos[tris]
    loc, factor = texture_space(mesh)
    return (corners - loc) * factor + 0.5


def texture_space(mesh):
    """(location, factor) of a mesh's texture space: Generated = (orco -
    location) * factor + 0.5 (Cycles' generated transform; inside a volume
    it maps the object-space point)."""
    pos = np.asarray(mesh.positions, dtype=np.float64)
    space = getattr(mesh, "texspace", None)
    if space is None or _is_position_texspace(mesh):
        lo, hi = (pos.min(axis=0), pos.max(axis=0)) if len(pos) else (np.zeros(3), np.zeros(3))
        loc, size = 0.5 * (lo + hi), 0.5 * (hi - lo)
        size = np.where(size == 0.0, 1.0, np.where(size < 1e-5, 1e-5, size))
    else:
        loc, size = (np.asarray(v, dtype=np.float64) for v in space)
    # Cycles: a zero size maps that axis to 0.5.
    factor = np.where(size != 0.0, 0.5 / np.where(size != 0.0, size, 1.0), 0.0)
    return loc, factor


class ShadingContext:
    """N shading points.  Arrays: p (N, 3) world position, ng (N, 3)
    geometric normal and ns (N, 3) shading normal facing the incoming ray,
    wo (N, 3) unit direction back along the ray, back (N,) hit the back
    face, depth (N,) bounces before this hit (0: camera ray), ray (N,)
    VIS_* bit of the ray (camera, diffuse, glossy, transmission, shadow;
    0 where Cycles evaluates with PATH_RAY_EMISSION: a light sample's
    emission), path (N, 7) or None: the Light Path node's PATH_COLUMNS.
    prim/bary locate the point on the scene's triangles (None for a context
    made from UVs alone).  rays: the renderer's handle for nodes that cast
    rays from the points (engine.nodes.rays.NodeRays: AO, Bevel), or None
    where Cycles does not ray-trace in shaders (light samples, shadow rays,
    worlds): those nodes then return their no-ray value.  voxels: the
    engine.media.voxels.Voxels of the object a medium point lies in (a
    fluid domain's grids, read by name as attributes), or None.  fibre
    (N, 3) or None: on curve segments the strand's dC/du (Cycles' dPdu), 0
    elsewhere.  dp (N,) or None: the ray footprint's radius at the points
    (Cycles' compact sd->dP, the camera ray's differentials carried along
    the path: integrator.stages.footprint), the bump's step."""

    voxels = None

    def __init__(self, n, tris=None, prim=None, bary=None, p=None, ng=None, ns=None, wo=None,
                 back=None, depth=None, ray=None, uv=None, path=None, fibre=None, dp=None):
        self.n = n
        self.tris = tris
        self.prim = prim
        self.bary = bary
        self.p = _or_zeros(p, (n, 3))
        self.ng = _or_default(ng, n, (0.0, 0.0, 1.0))
        self.ns = self.ng if ns is None else ns
        self.wo = _or_default(wo, n, (0.0, 0.0, 1.0))
        self.back = np.zeros(n, bool) if back is None else back
        self.depth = np.zeros(n, np.int32) if depth is None else depth
        self.ray = np.ones(n, np.uint8) if ray is None else ray
        self.path = path
        self.fibre = fibre
        self.dp = dp
        self.rays = None
        self._cache = {}
        if uv is not None:
            self._cache[("uv", "")] = uv

    def __len__(self):
        return self.n

    # -- construction ---------------------------------------------------------

    @classmethod
    def from_uv(cls, uv):
        """A context knowing only UVs (tests and callers without geometry)."""
        uv = np.asarray(uv, dtype=np.float64)
        return cls(len(uv), uv=uv)

    @classmethod
    def of_hit(cls, tris, hit):
        ctx = getattr(hit, "shading", None)
        if ctx is None:
            bary = getattr(hit, "bary", None)
            ctx = cls(len(hit.p), tris, hit.prim, bary, hit.p, hit.ng, hit.ns, hit.wo,
                      getattr(hit, "back", None), getattr(hit, "depth", None), getattr(hit, "ray", None),
                      uv=None if bary is not None else hit.uv, path=getattr(hit, "path", None),
                      fibre=getattr(hit, "fibre", None), dp=getattr(hit, "dp", None))
            hit.shading = ctx
        return ctx

    @classmethod
    def at(cls, tris, prim, bu, bv, wo=None, depth=None, ray=None):
        """Points on triangles prim at barycentrics (bu, bv), normals facing wo."""
        p = tris.p0[prim] + bu[:, None] * tris.e1[prim] + bv[:, None] * tris.e2[prim]
        ng = tris.ng[prim]
        back = np.zeros(len(prim), bool)
        if wo is not None:
            back = np.einsum("ij,ij->i", ng, wo) < 0
            ng = np.where(back[:, None], -ng, ng)
        ns = ng
        if tris.ns is not None:
            c = tris.ns[prim]
            ns = (1 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
            ns /= np.maximum(np.linalg.norm(ns, axis=1), 1e-30)[:, None]
            ns = np.where((np.einsum("ij,ij->i", ns, ng) < 0)[:, None], -ns, ns)
        return cls(len(prim), tris, prim, np.stack([bu, bv], axis=1), p, ng, ns,
                   ng if wo is None else wo, back, depth, ray)

    def take(self, rows):
        """The context of a subset of the points (cached values carried).
        Its arrays are picked from this context's on first read: a material's
        nodes read a few of them (a texture of Object coordinates: p and
        prim), so the others are never copied."""
        out = ShadingContext.__new__(ShadingContext)
        out.n = len(rows)
        out.tris = self.tris
        out._lazy = {name: _pick(self._deferred(name), rows) for name in _ROW_FIELDS}
        out.rays = None if self.rays is None else self.rays.take(rows)
        out._cache = _LazyCache(_deferred_cache(self._cache, rows))
        return out

    def _deferred(self, name):
        """A row field as it stands: its array, or its pending _Rows."""
        if name in self.__dict__:
            return self.__dict__[name]
        return self.__dict__["_lazy"][name]

    def __getattr__(self, name):
        # Only called for what the instance lacks: a field take() deferred.
        lazy = self.__dict__.get("_lazy")
        if lazy is None or name not in lazy:
            raise AttributeError(name)
        entry = lazy[name]
        value = None if entry is None else entry.get()
        self.__dict__[name] = value
        return value

    def shifted_pairs(self, steps):
        """The points moved by +s and by -s for each world offset s (N, 3)
        of ``steps``, as one context of 2 len(steps) N points, a point's
        copies consecutive (+s0, -s0, +s1, ... of point 0, then of point 1:
        neighbours in memory share their noise cells, engine/nodes/noise.py):
        the bump's central differences evaluate the height once (one pass
        through its nodes, not four).  Each copy holds what ``shifted``
        gives; a -s copy's barycentric change is the +s one's negated
        (exactly: the map is linear).  The fields the move keeps (normals,
        direction, ray kind, ...) are picked on first read."""
        return self.shifted_copies([x for step in steps for x in (step, -step)], negated_pairs=True)

    def shifted_copies(self, offsets, negated_pairs=False, moves=None):
        """The points moved by each world offset (N, 3) of ``offsets`` (None:
        not moved), as one context of len(offsets) N points, a point's copies
        consecutive; Cycles' bump evaluates its height at P, P + dPdx and
        P + dPdy in one pass this way.  ``negated_pairs``: offsets come as
        (s, -s) pairs, whose barycentric moves are computed once each.
        ``moves``: the offsets' barycentric moves (N, 2) when the caller
        has them already (textures.bump_steps)."""
        n, k = self.n, len(offsets)
        rows = np.repeat(np.arange(n), k)
        zero = np.zeros((n, 3))
        offsets = [zero if o is None else o for o in offsets]
        dp = np.stack(offsets, axis=1).reshape(k * n, 3)
        out = ShadingContext.__new__(ShadingContext)
        out.n = k * n
        out.tris = self.tris
        out._lazy = {name: _pick(self._deferred(name), rows) for name in _ROW_FIELDS if name not in ("p", "bary")}
        out.p = self.p[rows] + dp
        out.bary = None
        out.rays = None if self.rays is None else self.rays.take(rows)
        out._cache = {}
        if self.bary is not None and self.tris is not None:
            if moves is None and negated_pairs:
                moves = _bary_of_offsets(self.tris, self.prim, offsets[::2])
                moves = [x for d in moves for x in (d, -d)]
            elif moves is None:
                moves = _bary_of_offsets(self.tris, self.prim, offsets)
            out.bary = self.bary[rows] + np.stack(moves, axis=1).reshape(k * n, 2)
        else:
            out._cache[("uv", "")] = self.uv[rows] + dp[:, :2]
        return out

    def shifted(self, dp):
        """The same points moved by world offsets dp (N, 3) within their
        triangles' planes; interpolated attributes move with them."""
        out = ShadingContext(self.n, self.tris, self.prim, None, self.p + dp, self.ng, self.ns, self.wo,
                             self.back, self.depth, self.ray, path=self.path, fibre=self.fibre, dp=self.dp)
        out.rays = self.rays
        if self.bary is not None and self.tris is not None:
            d = _bary_of_offset(self.tris, self.prim, dp)
            out.bary = self.bary + d
        else:
            # Without triangles, only the UV map can follow: along x and y.
            uv = self.uv
            out._cache[("uv", "")] = uv + dp[:, :2]
        return out

    # -- interpolated data -----------------------------------------------------

    def _interpolate(self, key):
        if key in self._cache:
            return self._cache[key]
        value = None
        shading = getattr(self.tris, "shading", None) if self.tris is not None else None
        if shading is not None and self.bary is not None:
            corners = shading.corners(key)
            if corners is not None:
                c = corners[self.prim]
                bu, bv = self.bary[:, 0], self.bary[:, 1]
                value = (1 - bu - bv)[:, None] * c[:, 0] + bu[:, None] * c[:, 1] + bv[:, None] * c[:, 2]
        self._cache[key] = value
        return value

    @property
    def uv(self):
        """(N, 2) active UV map (zeros without one)."""
        return self.uv_map("")

    def uv_map(self, name):
        """(N, 2) UV map by name ('' = the active map); zeros if missing."""
        value = self._interpolate(("uv", name or ""))
        if value is None and name:
            value = self.uv_map("")
        return np.zeros((self.n, 2)) if value is None else value

    def attribute(self, name):
        """(N, 4) RGBA of a colour attribute (or (N, C) padded), None if absent;
        inside a fluid domain's medium its voxel grids of that name."""
        if self.voxels is not None and name in self.voxels:
            return self.voxels.read(name, self)
        value = self._interpolate(("attr", name))
        if value is None:
            return None
        if value.shape[1] < 4:
            pad = np.zeros((self.n, 4))
            pad[:, 3] = 1.0
            pad[:, :value.shape[1]] = value
            if value.shape[1] == 1:
                pad[:, 1:3] = value
            value = pad
        return value

    @property
    def camera(self):
        """The scene's engine.scene.Camera (Camera and Window coordinates), or None."""
        shading = getattr(self.tris, "shading", None) if self.tris is not None else None
        return getattr(getattr(shading, "scene", None), "camera", None)

    @property
    def instance(self):
        shading = getattr(self.tris, "shading", None) if self.tris is not None else None
        if shading is None or self.prim is None:
            return None, None
        return shading, shading.instance[self.prim]

    @property
    def object_coords(self):
        """Object-space position (Cycles' Object texture coordinate)."""
        if "object" not in self._cache:
            shading, inst = self.instance
            if shading is None:
                self._cache["object"] = self.p
            elif len(inst) and (inst == inst[0]).all():
                # One object (a material's points usually are): one matrix
                # product, not a gathered (N, 4, 4) stack.
                inv = shading.inverse[inst[0]]
                self._cache["object"] = self.p @ inv[:3, :3].T + inv[:3, 3]
            else:
                inv = shading.inverse[inst]
                self._cache["object"] = np.einsum("nij,nj->ni", inv[:, :3, :3], self.p) + inv[:, :3, 3]
        return self._cache["object"]

    def to_object(self, v):
        """A world direction in object space (normalized), as Cycles'
        object_inverse_normal_transform for normals."""
        shading, inst = self.instance
        if shading is None:
            return v
        m = shading.matrix[inst][:, :3, :3]
        out = np.einsum("nji,nj->ni", m, v)   # transpose(M) v: inverse-transpose of the inverse
        return _normalize(out)

    def to_world_normal(self, v):
        """An object-space normal in world space (Cycles'
        object_normal_transform: the inverse transpose), normalized."""
        shading, inst = self.instance
        if shading is None:
            return _normalize(v)
        inv = shading.inverse[inst][:, :3, :3]
        return _normalize(np.einsum("nji,nj->ni", inv, v))

    @property
    def uv_tangent(self):
        """(N, 3) object-space MikkTSpace tangent of the active UV map
        (interpolated, unnormalized, as Cycles' tangent attribute), or None
        where the meshes have none."""
        return self._interpolate(("tangent",))

    @property
    def generated(self):
        """(N, 3) Generated coordinates (object-space P without a mesh, and
        on geometry whose Generated is its position)."""
        value = self._interpolate(("generated",))
        if value is None:
            return self.object_coords
        shading, _ = self.instance
        if shading is not None:
            at_p = shading.position_generated()[self.prim]
            if at_p.any():
                value = np.where(at_p[:, None], self.object_coords, value)
        return value

    def instance_attribute(self, key):
        """(N, 4) RGBA of an Object / Instancer / View Layer attribute."""
        shading, inst = self.instance
        if shading is None:
            return np.zeros((self.n, 4))
        return shading.instance_attribute(key)[inst]

    def object_info(self, what):
        shading, inst = self.instance
        if shading is None:
            defaults = {"location": np.zeros((self.n, 3)), "color": np.ones((self.n, 3)),
                        "pass_index": np.zeros(self.n), "random": np.zeros(self.n)}
            return defaults[what]
        table = {"location": shading.location, "color": shading.color,
                 "pass_index": shading.pass_index, "random": shading.random}[what]
        return table[inst]


def _bary_of_offset(tris, prim, dp):
    """Barycentric change (dbu, dbv) of a world offset dp projected onto the
    plane of each triangle."""
    return _bary_of_offsets(tris, prim, (dp,))[0]


def _bary_of_offsets(tris, prim, offsets):
    """_bary_of_offset of each (N, 3) offset, the triangles' Gram matrix
    gathered and inverted once for all of them."""
    e1, e2 = tris.e1[prim], tris.e2[prim]
    d00 = np.einsum("ij,ij->i", e1, e1)
    d01 = np.einsum("ij,ij->i", e1, e2)
    d11 = np.einsum("ij,ij->i", e2, e2)
    det = d00 * d11 - d01 * d01
    inv = np.where(np.abs(det) > 1e-300, 1.0 / np.where(det != 0, det, 1.0), 0.0)
    out = []
    for dp in offsets:
        d20 = np.einsum("ij,ij->i", dp, e1)
        d21 = np.einsum("ij,ij->i", dp, e2)
        move = np.empty((len(dp), 2))
        move[:, 0] = (d11 * d20 - d01 * d21) * inv
        move[:, 1] = (d00 * d21 - d01 * d20) * inv
        out.append(move)
    return out


_ROW_FIELDS = ("prim", "bary", "p", "ng", "ns", "wo", "back", "depth", "ray", "path", "fibre", "dp")


class _Rows:
    """Rows of an array, picked when read (ShadingContext.take)."""
    __slots__ = ("array", "rows")

    def __init__(self, array, rows):
        self.array, self.rows = array, rows

    def get(self):
        return self.array[self.rows]

    def sub(self, rows):
        return _Rows(self.array, self.rows[rows])


def _pick(value, rows):
    """value's rows, deferred (value: an array, a _Rows or None)."""
    if value is None:
        return None
    return value.sub(rows) if isinstance(value, _Rows) else _Rows(value, rows)


def _deferred_cache(cache, rows):
    """A cache's entries for a row subset, each a deferred pick (or None)."""
    pending = getattr(cache, "pending", {})
    out = {k: _pick(v, rows) for k, v in cache.items()}   # a _LazyCache: its read entries
    for k, v in pending.items():
        if k not in out:
            out[k] = _pick(v, rows)
    return out


class _LazyCache(dict):
    """A subset context's cache: the parent's values, their rows picked on
    first read."""

    def __init__(self, pending):
        super().__init__()
        self.pending = pending   # key -> _Rows or None

    def __contains__(self, key):
        return dict.__contains__(self, key) or key in self.pending

    def __getitem__(self, key):
        if not dict.__contains__(self, key):
            entry = self.pending[key]
            dict.__setitem__(self, key, None if entry is None else entry.get())
        return dict.__getitem__(self, key)


def _normalize(v):
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0, v / np.where(length > 0, length, 1.0), 0.0)


def _or_zeros(value, shape):
    return np.zeros(shape) if value is None else value


def _or_default(value, n, default):
    return np.broadcast_to(np.asarray(default, dtype=np.float64), (n, 3)).copy() if value is None else value


def as_context(value):
    """A ShadingContext from a context or from (N, 2) UVs."""
    if isinstance(value, ShadingContext):
        return value
    return ShadingContext.from_uv(value)
