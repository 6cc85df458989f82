"""Emitters: sampling for next-event estimation, and the pdf/radiance that
BSDF-sampled rays need when they hit one.

Units follow Cycles (scene/light.cpp, kernel/light/*.h):
* point/spot: radiance P / (pi * 4 pi r^2); a sphere of radius r, or with
  soft falloff a disk of radius r facing the shading point; r = 0 is a delta
  light of intensity P / (4 pi);
* spot: times smoothstep((cos - cos_half) / ((1 - cos_half) * blend));
* sun: radiance E / (pi sin^2(angle / 2)) over its cone; angle 0 is a delta
  light of irradiance E;
* area: radiance P / (pi A) (normalize on) or P / pi, one-sided along -Z;
* emissive triangles: the material's emission, two-sided.

Every emitter is one entry of a selection distribution (uniform or by power);
emissive triangles are grouped per material, a triangle picked by area.
``select``/``sample`` give NEE samples; ``intersect`` and ``sun_hits`` give
what a BSDF ray sees.  Returned pdfs are solid-angle pdfs *without* the
selection probability; ``selection_pdf`` supplies that.
"""
from dataclasses import dataclass

import numpy as np

from .kernels import helper, kernel, loop_kernel, where
from .sampling import TWO_PI, cone_point
from .sampling import (Distribution1D, concentric_disk, rectangle_frame, rectangle_solid_angle,
                       sin_sq_to_one_minus_cos, spherical_rectangle_warp, spherical_triangle,
                       triangle_solid_angle, uniform_cone, uniform_cone_pdf, uniform_triangle)
from .environment import EnvironmentMap
from .geometry import VIS_ALL, visibility_bits
from .lightproxy import LightProxies
from .lighttree import LightTree, emitter_bounds, triangle_tree
from .scene import AreaLight, PointLight, SpotLight, SunLight
from .vec import column, count, dot, frame, frame_of, rows3, subset, to_world

POINT, SUN, AREA, MESH, ENV = 0, 1, 2, 3, 4

# Solid-angle sampling of rectangles and triangles is used between these
# solid angles (sr); outside, area sampling (pbrt-v4's Triangle thresholds:
# below, the two pdfs are the same up to rounding; near 2 pi, the spherical
# triangle warp degenerates).  Triangles also only from points near their
# plane (_MeshLights._spherical, Cycles' rule).
MIN_SPHERICAL = 3e-4
MAX_SPHERICAL = 6.22
# Emissive triangles of one material up to which the light-tree strategy
# picks them by importance (a tree over them); above, by area.
MAX_TREE_TRIANGLES = 16384
# Light selection 'auto' picks one light by the light tree, except at
# vertices whose BSDF is mostly a narrow glossy lobe (integrator
# _every_light), where it samples every light, in scenes of 2 to this many
# lights none of which is an emissive mesh.  The tree weighs lights by power,
# distance and orientation but not by the BSDF, so over a glossy surface it
# often picks a light outside the lobe.  Every light at every vertex, measured
# with tools/variance_seeds.py (tree / all, 16 spp, 8-12 seeds): Veach's MIS
# scene (4 sphere lights over GGX plates) 5.7x less variance for 1.5x the CPU
# per path, 3.9x less time to equal error; but a diffuse Cornell box with 3
# area lights 10 % less variance for 1.5x the CPU, 3 emissive meshes 10 % for
# 1.4x (each mesh's sample descends its own triangle tree), and 64 lights'
# shadow rays cost far more.
AUTO_ALL_LIGHTS = 4


def resolve_selection(strategy, lights, mesh_emitters):
    """(the selection a LightSet builds for, whether NEE samples every light
    at glossy vertices): 'auto' is the light tree, with every light at glossy
    vertices when there are 2 to AUTO_ALL_LIGHTS emitters, none an emissive
    mesh.  Other selections stand for themselves."""
    if strategy != "auto":
        return strategy, False
    return "tree", mesh_emitters == 0 and 2 <= lights <= AUTO_ALL_LIGHTS


@dataclass
class LightSample:
    wi: np.ndarray        # (N, 3) unit direction towards the light
    dist: np.ndarray      # (N,) distance to the sampled point (inf for suns)
    Le: np.ndarray        # (N, 3) radiance (or intensity/d^2 for delta lights)
    pdf: np.ndarray       # (N,) solid-angle pdf, 0 = no sample
    delta: np.ndarray     # (N,) bool
    on_surface: np.ndarray  # (N,) bool: the point lies on a triangle (shorten the shadow ray)


def selection_power(rgb):
    """The scalar power that light selection (power and tree) weighs an
    emitter by: the mean of its RGB power, as Cycles' light tree
    (``average(strength)``).  Not luminance: the image's error is measured
    per channel, and luminance, dominated by green, gives red and blue
    lights too few samples (Veach's MIS scene: 0.17 instead of about 0.25
    for its red light, 1.5x the variance in that light's highlights)."""
    return np.abs(np.asarray(rgb, float).mean(axis=-1))


def _rows(a, rows):
    return None if a is None else a[rows]


def smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class LightSet:
    """env_compensation: sample an HDRI world by max(L - mean, 0) (only
    unbiased when BSDF sampling is combined by MIS: RenderSettings
    ``mis_compensation`` with strategy 'mis')."""

    def __init__(self, scene, triangles, materials, strategy="power", env_compensation=False):
        self.points = _PointLights([l for l in scene.lights if isinstance(l, PointLight)])
        self.suns = _SunLights([l for l in scene.lights if isinstance(l, SunLight)])
        self.areas = _AreaLights([l for l in scene.lights if isinstance(l, AreaLight)])
        self.env = _EnvironmentLight(scene.world.texture, env_compensation)
        self.meshes = _MeshLights(triangles, materials, by_importance=strategy in ("tree", "auto"))
        analytic = self.points.count + self.suns.count + self.areas.count + self.env.count
        strategy, self.every_at_glossy = resolve_selection(strategy, analytic + self.meshes.count,
                                                           self.meshes.count)
        self.strategy = strategy
        radius = _scene_radius(triangles)
        # Emitter index -> (type, index within type).  Meshes stay last
        # (mesh_emitter below counts from the end).
        kinds, locals_, power = [], [], []
        for group, kind in ((self.points, POINT), (self.suns, SUN), (self.areas, AREA), (self.env, ENV),
                            (self.meshes, MESH)):
            kinds += [kind] * group.count
            locals_ += list(range(group.count))
            power += list(group.power(radius))
        self.kind = np.array(kinds, np.int64)
        self.local = np.array(locals_, np.int64)
        self.count = len(kinds)
        self.mesh_emitter = np.full(max(1, len(materials.emission)), -1, np.int64)
        for j, mat in enumerate(self.meshes.material):
            self.mesh_emitter[mat] = self.count - self.meshes.count + j
        self.env_emitter = self.points.count + self.suns.count + self.areas.count
        if self.count:
            weights = np.ones(self.count) if strategy == "uniform" else np.array(power)
            self.dist = Distribution1D(weights)
        self.visibility = _emitter_visibility(scene, self.kind)
        # Light tree (strategy 'tree'): built over every emitter's bounds and power.
        self.power = np.array(power, float)
        self.tree = LightTree(emitter_bounds(self)) if strategy == "tree" and self.count else None
        self.proxies = LightProxies.for_lights(self.points, self.areas)

    # -- selection ----------------------------------------------------------
    def select(self, u, p=None, n=None):
        """Emitter per uniform u and its probability; the tree needs the
        shading points p and their normals n (zero rows: no normal)."""
        if self.tree is not None:
            return self.tree.select(u, p, _normals(n, len(u)))
        return self.dist.sample(u)

    def selection_pdf(self, emitter, p=None, n=None, every=None):
        """Probability that ``select`` at p (normal n) picks ``emitter``; 1
        where ``every`` (per row: NEE sampled every light there)."""
        if self.strategy == "all":
            return np.ones(len(emitter))
        if every is not None and every.any():
            out = np.ones(len(emitter))
            some = np.flatnonzero(~every)
            if len(some):
                out[some] = self.selection_pdf(emitter[some], _rows(p, some), _rows(n, some))
            return out
        if self.tree is not None:
            return self.tree.pmf(emitter, p, _normals(n, len(emitter)))
        return self.dist.pmf[emitter]

    # -- NEE ----------------------------------------------------------------
    def sample(self, emitter, p, u1, u2, u3, n=None):
        """Sample a point on each ray's emitter as seen from p (normal n: a
        mesh group picks its triangle by importance there, the light tree
        strategy only)."""
        m = len(p)
        out = LightSample(np.zeros((m, 3)), np.full(m, np.inf), np.zeros((m, 3)),
                          np.zeros(m), np.zeros(m, bool), np.zeros(m, bool))
        kind = self.kind[emitter]
        local = self.local[emitter]
        for k, group in ((POINT, self.points), (SUN, self.suns), (AREA, self.areas), (ENV, self.env),
                         (MESH, self.meshes)):
            idx = subset(kind == k)
            if count(idx, len(p)) and k == MESH:
                group.sample(out, idx, local[idx], p[idx], u1[idx], u2[idx], u3[idx],
                             None if n is None else n[idx])
            elif count(idx, len(p)):
                group.sample(out, idx, local[idx], p[idx], u1[idx], u2[idx], u3[idx])
        return out

    # -- what BSDF rays see -------------------------------------------------
    def intersect(self, o, d, tmax, camera=False, ray=None):
        """Closest analytic emitter (point/spot/area) before tmax.

        camera: the rays are camera rays, which see only lights with
        ``visible_camera``; ray: per-ray VIS_* bits (camera, diffuse, glossy,
        transmission), when set, see only lights with a common bit.  Returns
        t (inf = none), emitter index, Le and the solid-angle pdf of sampling
        that point from o.  With several lights only the rays their proxies
        (engine/lightproxy.py) say may meet one are tested exactly."""
        n = len(o)
        if self.proxies is None:
            return self._intersect_exact(o, d, tmax, camera, ray)
        rows = np.flatnonzero(self.proxies.candidates(o, d, tmax))
        out = (np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros((n, 3)), np.zeros(n))
        if len(rows):
            tm = np.broadcast_to(tmax, (n,))[rows]
            found = self._intersect_exact(o[rows], d[rows], tm, camera, None if ray is None else ray[rows])
            for whole, part in zip(out, found):
                whole[rows] = part
        return out

    def _intersect_exact(self, o, d, tmax, camera, ray):
        n = len(o)
        t = np.array(tmax, dtype=np.float64, copy=True)
        hit_t = np.full(n, np.inf)
        emitter = np.full(n, -1, np.int64)
        Le = np.zeros((n, 3))
        pdf = np.zeros(n)
        if self.points.count:   # emitters 0 .. points.count - 1, tested in one compiled loop
            bits = self.visibility[:self.points.count] if ray is not None else np.full(self.points.count, 0xFF)
            if camera:
                bits = np.where(self.points.visible_camera, bits, 0)
            ray_bits = ray if ray is not None else np.full(n, 0xFF, np.uint8)
            hit_t, emitter, Le, pdf = self.points.nearest(o, d, t, ray_bits, bits)
        base = self.points.count + self.suns.count
        areas = self.areas
        for j in range(areas.count):
            if camera and not areas.visible_camera[j]:
                continue
            sees = True if ray is None else (ray & self.visibility[base + j]) != 0
            if not np.any(sees):
                continue
            th, le, pw = areas.intersect(j, o, d)
            closer = (th < t) & sees
            if closer.any():
                t[closer] = th[closer]
                hit_t[closer] = th[closer]
                emitter[closer] = base + j
                Le[closer] = le[closer]
                pdf[closer] = pw[closer]
        return hit_t, emitter, Le, pdf

    def sun_hits(self, d, ray=None):
        """Radiance of sun disks along escaping directions, with MIS pdfs;
        ray: per-ray VIS_* bits, as in ``intersect``.

        Returns a list of (mask, emitter, Le, pdf) per sun with angle > 0."""
        hits = []
        base = self.points.count
        for j in range(self.suns.count):
            res = self.suns.hit(j, d)
            if res is not None:
                mask, Le, pdf = res
                if ray is not None:
                    mask = mask & ((ray & self.visibility[base + j]) != 0)
                hits.append((mask, base + j, Le, pdf))
        return hits

    def environment_hits(self, d):
        """What escaping rays see of an HDRI world: (emitter, Le, pdf), the
        pdf NEE has for these directions; None for a constant world."""
        if not self.env.count:
            return None
        return self.env_emitter, self.env.map.eval(d), self.env.map.pdf(d)

    def triangle_pdf(self, prim, o, p_hit, ng, n=None):
        """Solid-angle pdf of NEE picking this emissive triangle's point from o
        (n: the normal ``sample`` had there, as for ``selection_pdf``)."""
        return self.meshes.pdf(prim, o, p_hit, ng, n)

    def emitter_of_triangle(self, material):
        return self.mesh_emitter[material]


def _emitter_visibility(scene, kind):
    """VIS_* bits per emitter: the light objects' ray visibility; the world
    and emissive meshes (whose triangles carry their own bits) see all."""
    vis = np.full(len(kind), VIS_ALL, np.uint8)
    lists = {POINT: [l for l in scene.lights if isinstance(l, PointLight)],
             SUN: [l for l in scene.lights if isinstance(l, SunLight)],
             AREA: [l for l in scene.lights if isinstance(l, AreaLight)]}
    for k, group in lists.items():
        idx = np.nonzero(kind == k)[0]
        vis[idx] = [visibility_bits(l) for l in group]
    return vis


def _normals(n, count):
    return np.zeros((count, 3)) if n is None else n


def _scene_radius(triangles):
    if len(triangles) == 0:
        return 1.0
    lo = triangles.p0.min(axis=0)
    hi = triangles.p0.max(axis=0)
    return max(1.0, 0.5 * float(np.linalg.norm(hi - lo)))


# ----------------------------------------------------------------------------

class _EnvironmentLight:
    """An HDRI world as one emitter (a constant world is not one: Cycles
    only BSDF-samples it)."""

    def __init__(self, texture, compensate):
        self.map = EnvironmentMap(texture, compensate) if texture is not None else None
        self.count = int(texture is not None)

    def power(self, radius):
        # Like a sun from every direction: flux through the scene's disk.
        return [self.map.power() * np.pi * radius ** 2] if self.count else []

    def sample(self, out, idx, j, p, u1, u2, u3):
        wi, pdf = self.map.sample(u1, u2)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, np.inf, self.map.eval(wi)
        out.pdf[idx] = pdf


class _PointLights:
    """Point and spot lights (sphere, soft-falloff disk, or delta)."""

    def __init__(self, lights):
        self.count = len(lights)
        self.pos = np.array([l.position for l in lights], float).reshape(-1, 3)
        self.radius = np.array([max(0.0, l.radius) for l in lights], float)
        self.sphere = np.array([not l.soft_falloff for l in lights], bool)
        self.visible_camera = [l.visible_camera for l in lights]
        pw = np.array([l.power for l in lights], float).reshape(-1, 3)
        area = 4.0 * np.pi * self.radius ** 2
        # Cycles: eval_fac = 1 / (pi * area); area 0 counts as 4 (delta).
        self.L = pw / (np.pi * np.where(area > 0, area, 4.0))[:, None]
        self.power_rgb = pw
        spot = [isinstance(l, SpotLight) for l in lights]
        self.spot = np.array(spot, bool)
        self.dir = np.array([_unit(l.direction) if s else (0, 0, -1) for l, s in zip(lights, spot)],
                            float).reshape(-1, 3)
        half = np.array([0.5 * l.spot_size if s else np.pi for l, s in zip(lights, spot)], float)
        self.cos_half = np.cos(half)
        blend = np.array([l.spot_blend if s else 0.0 for l, s in zip(lights, spot)], float)
        with np.errstate(divide="ignore"):
            self.smooth = 1.0 / ((1.0 - self.cos_half) * blend)

    def power(self, radius):
        return selection_power(self.power_rgb) if self.count else []

    def _spot_factor(self, j, to_p):
        """Spot attenuation for unit directions from the light towards points."""
        cos = to_p @ self.dir[j] if np.ndim(j) == 0 else dot(to_p, self.dir[j])
        with np.errstate(invalid="ignore"):
            x = (cos - self.cos_half[j]) * self.smooth[j]  # inf * 0 at a hard edge
        x = np.where(np.isnan(x), 0.0, x)
        return np.where(self.spot[j], smoothstep(x), 1.0)

    def sample(self, out, idx, j, p, u1, u2, u3):
        n = len(p)
        wi, t, le, pdf, delta = np.empty((n, 3)), np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n, bool)
        _point_sample(column(j, n, np.int64), rows3(p)[0],
                      column(u1, n, np.float64), column(u2, n, np.float64), self.pos, self.radius, self.sphere,
                      self.L, self.spot, self.dir, self.cos_half, self.smooth, wi, t, le, pdf, delta)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, t, le
        out.pdf[idx], out.delta[idx] = pdf, delta

    def nearest(self, o, d, t, ray_bits, light_bits):
        """The nearest of these lights each ray meets before t: t (updated
        in place), the hit distance (inf = none), light index (-1), Le and
        pdf.  A light counts for a ray where ray_bits & light_bits != 0."""
        n = len(o)
        hit_t, index, pdf = np.full(n, np.inf), np.full(n, -1, np.int64), np.zeros(n)
        _nearest_point(np.ascontiguousarray(o, np.float64), np.ascontiguousarray(d, np.float64), t,
                       np.ascontiguousarray(ray_bits, np.uint8), self.pos, self.radius, self.sphere,
                       np.ascontiguousarray(light_bits, np.uint8), hit_t, index, pdf)
        Le = np.zeros((n, 3))
        rows = np.flatnonzero(index >= 0)
        if len(rows):
            j = index[rows]
            Le[rows] = self.L[j] * self._spot_factor(j, -d[rows])[:, None]
        return hit_t, index, Le, pdf


def _point_sample_numpy(j, p, u1, u2, pos, radius, sphere, L, spot, sdir, cos_half, smooth,
                        wi_out, t_out, le_out, pdf_out, delta_out):
    c = pos[j]
    r = radius[j]
    dvec = p - c
    d2 = dot(dvec, dvec)
    dist = np.sqrt(d2)
    light_n = dvec / np.maximum(dist, 1e-30)[:, None]
    wi = -light_n
    t = dist.copy()
    pdf = np.ones(len(p))
    delta = r <= 0
    Le = L[j] / np.where(delta, np.maximum(d2, 1e-30), 1.0)[:, None]
    sph = sphere[j] & ~delta
    inside = sph & (d2 <= r * r)
    s = np.nonzero(sph & ~inside)[0]
    if len(s):
        omc = sin_sq_to_one_minus_cos(r[s] ** 2 / d2[s])
        local, pdf[s] = uniform_cone(u1[s], u2[s], omc)
        tt, bb = frame(-light_n[s])
        wi[s] = to_world(local, tt, bb, -light_n[s])
        cos_t = local[:, 2]
        t[s] = dist[s] * cos_t - np.sqrt(np.maximum(0.0, r[s] ** 2 - d2[s] * (1.0 - cos_t ** 2)))
    dsk = np.nonzero(~sphere[j] & ~delta)[0]
    if len(dsk):
        x, y = concentric_disk(u1[dsk], u2[dsk])
        tt, bb = frame(light_n[dsk])
        q = c[dsk] + (x[:, None] * tt + y[:, None] * bb) * r[dsk, None]
        v = q - p[dsk]
        t[dsk] = np.linalg.norm(v, axis=1)
        wi[dsk] = v / np.maximum(t[dsk], 1e-30)[:, None]
        cos_l = np.abs(dot(light_n[dsk], -wi[dsk]))
        pdf[dsk] = t[dsk] ** 2 / (np.pi * r[dsk] ** 2 * np.maximum(cos_l, 1e-30))
    pdf[inside] = 0.0
    # Spot attenuation towards the point (vec.dot's order on unit-stride rows).
    with np.errstate(invalid="ignore"):
        x = (dot(-wi, sdir[j]) - cos_half[j]) * smooth[j]   # inf * 0 at a hard edge
    x = np.where(np.isnan(x), 0.0, x)
    Le *= np.where(spot[j], smoothstep(x), 1.0)[:, None]
    wi_out[:], t_out[:], le_out[:], pdf_out[:], delta_out[:] = wi, t, Le, pdf, delta


@loop_kernel("void(int64[:], float64[:, :], float64[:], float64[:], float64[:, ::1], float64[::1], boolean[::1], "
             "float64[:, ::1], boolean[::1], float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], "
             "float64[::1], float64[:, ::1], float64[::1], boolean[::1])", _point_sample_numpy)
def _point_sample(j, p, u1, u2, pos, radius, sphere, L, spot, sdir, cos_half, smooth,
                  wi_out, t_out, le_out, pdf_out, delta_out):
    """A point on each ray's point or spot light: the cone of a sphere
    light seen from p, the disk facing p (soft falloff), or the centre
    (radius 0: delta), as the NumPy form computes it term by term."""
    for i in range(len(j)):
        k = j[i]
        r = radius[k]
        dx, dy, dz = p[i, 0] - pos[k, 0], p[i, 1] - pos[k, 1], p[i, 2] - pos[k, 2]
        d2 = (dx * dx + dz * dz) + dy * dy
        dist = np.sqrt(d2)
        m = max(dist, 1e-30)
        n0, n1, n2 = dx / m, dy / m, dz / m                  # light_n: from the light to p
        w0, w1, w2 = -n0, -n1, -n2
        t = dist
        pdf = 1.0
        delta = r <= 0
        scale = max(d2, 1e-30) if delta else 1.0
        le0, le1, le2 = L[k, 0] / scale, L[k, 1] / scale, L[k, 2] / scale
        if sphere[k] and not delta:
            if d2 <= r * r:
                pdf = 0.0                                     # inside the sphere
            else:
                x = r * r / d2
                omc = 0.5 * x + 0.125 * x * x if x < 0.0004 else 1.0 - np.sqrt(max(0.0, 1.0 - x))
                lx, ly, cos_t = cone_point(u1[i], u2[i], omc)
                pdf = 1.0 / (TWO_PI * omc)
                a0, a1, a2 = -n0, -n1, -n2                    # the cone's axis: towards the light
                s0, s1, s2, t0, t1, t2 = frame_of(a0, a1, a2)
                w0 = (lx * s0 + ly * t0) + cos_t * a0
                w1 = (lx * s1 + ly * t1) + cos_t * a1
                w2 = (lx * s2 + ly * t2) + cos_t * a2
                t = dist * cos_t - np.sqrt(max(0.0, r * r - d2 * (1.0 - cos_t * cos_t)))
        elif not sphere[k] and not delta:
            a = 2.0 * u1[i] - 1.0
            b = 2.0 * u2[i] - 1.0
            if a == 0 and b == 0:
                rr, phi = b, 0.0
            elif abs(a) > abs(b):
                rr, phi = a, (np.pi / 4) * (b / a)
            else:
                rr, phi = b, np.pi / 2 - (np.pi / 4) * (a / b)
            x, y = rr * np.cos(phi), rr * np.sin(phi)
            s0, s1, s2, t0, t1, t2 = frame_of(n0, n1, n2)
            v0 = (pos[k, 0] + (x * s0 + y * t0) * r) - p[i, 0]
            v1 = (pos[k, 1] + (x * s1 + y * t1) * r) - p[i, 1]
            v2 = (pos[k, 2] + (x * s2 + y * t2) * r) - p[i, 2]
            t = np.sqrt((v0 * v0 + v1 * v1) + v2 * v2)
            mt = max(t, 1e-30)
            w0, w1, w2 = v0 / mt, v1 / mt, v2 / mt
            cos_l = abs((n0 * -w0 + n2 * -w2) + n1 * -w1)
            pdf = t * t / (np.pi * (r * r) * max(cos_l, 1e-30))
        fac = 1.0
        if spot[k]:
            cos = (-w0 * sdir[k, 0] + -w2 * sdir[k, 2]) + -w1 * sdir[k, 1]
            x = (cos - cos_half[k]) * smooth[k]
            if x != x:
                x = 0.0
            x = min(max(x, 0.0), 1.0)
            fac = x * x * (3.0 - 2.0 * x)
        wi_out[i, 0], wi_out[i, 1], wi_out[i, 2] = w0, w1, w2
        t_out[i] = t
        le_out[i, 0], le_out[i, 1], le_out[i, 2] = le0 * fac, le1 * fac, le2 * fac
        pdf_out[i] = pdf
        delta_out[i] = delta


def _point_hit(o, d, c, r, sphere):
    """Distance (inf = miss) and solid-angle pdf of rays (o, d) meeting a
    point light of radius r > 0 at c: its sphere (sampled by its cone), or
    with soft falloff its disk facing the ray's origin."""
    n = len(o)
    t = np.full(n, np.inf)
    pdf = np.zeros(n)
    oc = o - c
    d2 = dot(oc, oc)
    if sphere:
        b = dot(oc, d)
        disc = b * b - (d2 - r * r)
        ok = (disc >= 0) & (d2 > r * r)
        th = -b - np.sqrt(np.maximum(disc, 0.0))
        ok &= th > 0
        t[ok] = th[ok]
        pdf[ok] = uniform_cone_pdf(sin_sq_to_one_minus_cos(r * r / d2[ok]))
    else:
        light_n = oc / np.sqrt(np.maximum(d2, 1e-30))[:, None]
        denom = dot(d, light_n)
        with np.errstate(divide="ignore", invalid="ignore"):
            th = -dot(oc, light_n) / denom
        q = o + d * th[:, None]
        ok = (denom < 0) & (th > 0) & (np.sum((q - c) ** 2, axis=1) <= r * r)
        t[ok] = th[ok]
        pdf[ok] = th[ok] ** 2 / (np.pi * r * r * np.abs(denom[ok]))
    return t, pdf


def _nearest_point_numpy(o, d, t, ray_bits, pos, radius, sphere, light_bits, hit_t, index, pdf):
    for j in range(len(radius)):
        sees = (ray_bits & light_bits[j]) != 0
        if radius[j] <= 0 or not sees.any():
            continue
        th, pw = _point_hit(o, d, pos[j], radius[j], sphere[j])
        closer = (th < t) & sees
        t[closer] = hit_t[closer] = th[closer]
        index[closer] = j
        pdf[closer] = pw[closer]


@helper
def _dot3(ax, ay, az, bx, by, bz):
    """A row of vec.dot (einsum adds the middle term last)."""
    return (ax * bx + az * bz) + ay * by


@loop_kernel("void(float64[:, ::1], float64[:, ::1], float64[::1], uint8[::1], float64[:, ::1], float64[::1], "
             "boolean[::1], uint8[::1], float64[::1], int64[::1], float64[::1])", _nearest_point_numpy)
def _nearest_point(o, d, t, ray_bits, pos, radius, sphere, light_bits, hit_t, index, pdf):
    for i in range(len(t)):
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        for j in range(len(radius)):
            r = radius[j]
            if r <= 0 or (ray_bits[i] & light_bits[j]) == 0:
                continue
            ox, oy, oz = o[i, 0] - pos[j, 0], o[i, 1] - pos[j, 1], o[i, 2] - pos[j, 2]
            d2 = _dot3(ox, oy, oz, ox, oy, oz)
            if sphere[j]:
                b = _dot3(ox, oy, oz, dx, dy, dz)
                disc = b * b - (d2 - r * r)
                th = -b - np.sqrt(np.maximum(disc, 0.0))
                if not (disc >= 0 and d2 > r * r and th > 0 and th < t[i]):
                    continue
                x = r * r / d2
                omc = 0.5 * x + 0.125 * x * x if x < 0.0004 else 1.0 - np.sqrt(np.maximum(0.0, 1.0 - x))
                pw = 1.0 / (2.0 * np.pi * omc)
            else:
                inv = np.sqrt(np.maximum(d2, 1e-30))
                nx, ny, nz = ox / inv, oy / inv, oz / inv
                denom = _dot3(dx, dy, dz, nx, ny, nz)
                th = -_dot3(ox, oy, oz, nx, ny, nz) / denom
                qx = (o[i, 0] + dx * th) - pos[j, 0]
                qy = (o[i, 1] + dy * th) - pos[j, 1]
                qz = (o[i, 2] + dz * th) - pos[j, 2]
                if not (denom < 0 and th > 0 and (qx * qx + qy * qy) + qz * qz <= r * r and th < t[i]):
                    continue
                pw = th * th / (np.pi * r * r * np.abs(denom))
            t[i] = th
            hit_t[i] = th
            index[i] = j
            pdf[i] = pw


class _SunLights:
    def __init__(self, lights):
        self.count = len(lights)
        self.dir = np.array([_unit(l.direction) for l in lights], float).reshape(-1, 3)
        self.E = np.array([l.strength for l in lights], float).reshape(-1, 3)
        half = np.array([0.5 * l.angle for l in lights], float)
        self.one_minus_cos = 2.0 * np.sin(0.5 * half) ** 2
        self.delta = half <= 0
        sin2 = np.sin(half) ** 2
        self.L = self.E / np.where(self.delta, 1.0, np.pi * sin2)[:, None]

    def power(self, radius):
        return selection_power(self.E) * np.pi * radius ** 2 if self.count else []

    def sample(self, out, idx, j, p, u1, u2, u3):
        n = len(p)
        wi, pdf = np.empty((n, 3)), np.empty(n)
        _sun_sample(column(j, n, np.int64), column(u1, n, np.float64), column(u2, n, np.float64),
                    -self.dir, self.one_minus_cos, self.delta, wi, pdf)
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, np.inf, self.L[j]
        out.pdf[idx], out.delta[idx] = pdf, self.delta[j]

    def hit(self, j, d):
        if self.delta[j]:
            return None
        omc = self.one_minus_cos[j]
        # 1 - cos(angle to the axis) as |d - axis|^2 / 2: no cancellation for tiny suns.
        diff = d + self.dir[j]
        mask = 0.5 * np.einsum("ij,ij->i", diff, diff) <= omc
        return mask, self.L[j], uniform_cone_pdf(omc)


def _sun_sample_numpy(j, u1, u2, axes, one_minus_cos, delta, wi, pdf):
    axis = axes[j]
    wi[:] = axis
    pdf[:] = 1.0
    s = np.nonzero(~delta[j])[0]
    if len(s):
        local, pdf[s] = uniform_cone(u1[s], u2[s], one_minus_cos[j[s]])
        tt, bb = frame(axis[s])
        wi[s] = to_world(local, tt, bb, axis[s])


@loop_kernel("void(int64[:], float64[:], float64[:], float64[:, ::1], float64[::1], boolean[::1], "
             "float64[:, ::1], float64[::1])", _sun_sample_numpy)
def _sun_sample(j, u1, u2, axes, one_minus_cos, delta, wi, pdf):
    """Directions uniform in each sun's cone about its axis (delta suns: the
    axis), as uniform_cone, vec.frame and vec.to_world compute them."""
    for i in range(len(j)):
        k = j[i]
        n0, n1, n2 = axes[k, 0], axes[k, 1], axes[k, 2]
        if delta[k]:
            wi[i, 0], wi[i, 1], wi[i, 2] = n0, n1, n2
            pdf[i] = 1.0
            continue
        x, y, cos_t = cone_point(u1[i], u2[i], one_minus_cos[k])
        s0, s1, s2, t0, t1, t2 = frame_of(n0, n1, n2)
        wi[i, 0] = (x * s0 + y * t0) + cos_t * n0
        wi[i, 1] = (x * s1 + y * t1) + cos_t * n1
        wi[i, 2] = (x * s2 + y * t2) + cos_t * n2
        pdf[i] = 1.0 / (TWO_PI * one_minus_cos[k])


class _AreaLights:
    def __init__(self, lights):
        self.count = len(lights)
        u, v, c, n, area, ell = [], [], [], [], [], []
        for l in lights:
            m = np.asarray(l.matrix, float)
            sy = l.size_x if l.shape in ("SQUARE", "DISK") else l.size_y
            u.append(m[:3, 0] * l.size_x)
            v.append(m[:3, 1] * sy)
            c.append(m[:3, 3])
            n.append(_unit(-m[:3, 2]))
            ellipse = l.shape in ("DISK", "ELLIPSE")
            a = np.linalg.norm(u[-1]) * np.linalg.norm(v[-1]) * (np.pi / 4 if ellipse else 1.0)
            area.append(a)
            ell.append(ellipse)
        self.u = np.array(u, float).reshape(-1, 3)
        self.v = np.array(v, float).reshape(-1, 3)
        self.c = np.array(c, float).reshape(-1, 3)
        self.n = np.array(n, float).reshape(-1, 3)
        self.area = np.array(area, float)
        self.ellipse = np.array(ell, bool)
        self.visible_camera = [l.visible_camera for l in lights]
        pw = np.array([l.power for l in lights], float).reshape(-1, 3)
        norm = np.array([l.normalize for l in lights], bool)
        self.power_rgb = pw
        inv_area = np.where(norm & (self.area > 0), 1.0 / np.maximum(self.area, 1e-300), 1.0)
        self.L = pw * (inv_area / np.pi)[:, None]
        # Projections onto the light's axes: local coords in [-0.5, 0.5].
        self.du = self.u / np.maximum(np.sum(self.u ** 2, axis=1), 1e-300)[:, None]
        self.dv = self.v / np.maximum(np.sum(self.v ** 2, axis=1), 1e-300)[:, None]
        # Rectangles (not sheared by the matrix) are sampled by solid angle.
        self.len_u = np.linalg.norm(self.u, axis=1)
        self.len_v = np.linalg.norm(self.v, axis=1)
        self.ex = self.u / np.maximum(self.len_u, 1e-300)[:, None]
        self.ey = self.v / np.maximum(self.len_v, 1e-300)[:, None]
        skew = np.abs(np.sum(self.ex * self.ey, axis=1))
        self.rect = ~self.ellipse & (self.area > 0) & (skew < 1e-9)

    def power(self, radius):
        return selection_power(self.L) * np.pi * self.area if self.count else []

    def sample(self, out, idx, j, p, u1, u2, u3):
        j = _uniform_index(j)
        x, y = u1 - 0.5, u2 - 0.5
        e = self.ellipse[j]
        if np.any(e):
            e = np.broadcast_to(e, x.shape)
            dx, dy = concentric_disk(u1[e], u2[e])
            x[e], y[e] = 0.5 * dx, 0.5 * dy
        c, ex, ey, n = self.c[j], self.ex[j], self.ey[j], self.n[j]
        wx, wy, wz, t, pdf = _area_light_sample(
            p[:, 0], p[:, 1], p[:, 2], c[..., 0], c[..., 1], c[..., 2], ex[..., 0], ex[..., 1], ex[..., 2],
            ey[..., 0], ey[..., 1], ey[..., 2], self.len_u[j], self.len_v[j], n[..., 0], n[..., 1], n[..., 2],
            self.area[j], self.rect[j].astype(np.float64), x, y, u1, u2, MIN_SPHERICAL)
        out.wi[idx], out.dist[idx], out.Le[idx] = np.stack([wx, wy, wz], axis=1), t, self.L[j]
        out.pdf[idx] = pdf

    def _solid_angle_pdf(self, j, o):
        """Which rays from o NEE samples by solid angle, and that pdf."""
        c, ex, ey = self.c[j], self.ex[j], self.ey[j]
        s, min_nz2 = rectangle_solid_angle(o[:, 0], o[:, 1], o[:, 2], *c, *ex, *ey, self.len_u[j], self.len_v[j])
        use = (s >= MIN_SPHERICAL) & (min_nz2 < 1.0 - 1e-8)
        return use, 1.0 / np.maximum(s, 1e-300)

    def intersect(self, j, o, d):
        n = len(o)
        t = np.full(n, np.inf)
        pdf = np.zeros(n)
        normal = self.n[j]
        denom = d @ normal
        front = denom < -1e-12  # emits along its normal: seen from the front only
        with np.errstate(divide="ignore", invalid="ignore"):
            th = ((self.c[j] - o) @ normal) / denom
        q = o + d * th[:, None] - self.c[j]
        a = q @ self.du[j]
        b = q @ self.dv[j]
        if self.ellipse[j]:
            inside = 4.0 * (a * a + b * b) <= 1.0
        else:
            inside = (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5)
        ok = front & (th > 0) & inside & (self.area[j] > 0)
        t[ok] = th[ok]
        pdf[ok] = th[ok] ** 2 / (-denom[ok] * self.area[j])
        if self.rect[j] and ok.any():
            # The pdf NEE has for this point: the same choice of strategy.
            sph, solid_angle_pdf = self._solid_angle_pdf(j, o[ok])
            pdf[ok] = np.where(sph, solid_angle_pdf, pdf[ok])
        return t, np.tile(self.L[j], (n, 1)), pdf


@kernel(24, 5)
def _area_light_sample(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz, len_u, len_v, nx, ny, nz,
                       area, rect, x, y, u1, u2, min_spherical):
    """Direction (x, y, z), distance and solid-angle pdf towards a point of
    an area light: the point (x, y) of the shape in its axes (area
    sampling), or for rectangles seen under at least ``min_spherical`` sr a
    point uniform in their solid angle (Urena et al.; tiny or grazing ones,
    where the warp loses precision, keep area sampling as Cycles' area.h)."""
    ax, ay = x * len_u, y * len_v
    qx = cx + ax * exx + ay * eyx
    qy = cy + ax * exy + ay * eyy
    qz = cz + ax * exz + ay * eyz
    xc, yc, z0, zx, zy, zz = rectangle_frame(px, py, pz, cx, cy, cz, exx, exy, exz, eyx, eyy, eyz)
    xu, yv, solid_angle, min_nz2 = _rectangle_warp(xc, yc, where(z0 > 0, -z0, z0), len_u, len_v, u1, u2)
    use = (rect > 0.0) & (solid_angle >= min_spherical) & (min_nz2 < 1.0 - 1e-8)
    qx = where(use, px + xu * exx + yv * eyx + z0 * zx, qx)
    qy = where(use, py + xu * exy + yv * eyy + z0 * zy, qy)
    qz = where(use, pz + xu * exz + yv * eyz + z0 * zz, qz)
    vx, vy, vz = qx - px, qy - py, qz - pz
    t = np.sqrt(vx * vx + vy * vy + vz * vz)
    inv = 1.0 / np.maximum(t, 1e-30)
    wx, wy, wz = vx * inv, vy * inv, vz * inv
    cos_l = -(wx * nx + wy * ny + wz * nz)
    ok = (cos_l > 1e-12) & (t > 0.0) & (area > 0.0)
    pdf = where(ok, t * t / (np.maximum(cos_l, 1e-12) * np.maximum(area, 1e-300)), 0.0)
    pdf = where(ok & use, 1.0 / np.maximum(solid_angle, 1e-300), pdf)
    return wx, wy, wz, t, pdf


_rectangle_warp = helper(spherical_rectangle_warp.fn)


class _MeshLights:
    """Emissive triangles, one emitter per emissive material.

    Within its group a triangle is picked by area, or (by_importance, the
    light-tree strategy) by a light tree over the group's triangles that
    weighs each by its importance at the shading point, as Cycles' light tree
    holds every emissive triangle: a group's triangles can lie far apart
    (objects sharing a material), and area alone sends most samples to the
    ones far from the shading point.  Groups larger than MAX_TREE_TRIANGLES
    keep area selection: the tree is built in Python (about 60 us per
    triangle)."""

    def __init__(self, triangles, materials, by_importance=False):
        emissive = materials.emissive
        self.tris = triangles
        mats = np.unique(triangles.material[emissive[triangles.material]]) if len(triangles) else []
        self.material = np.array(mats, np.int64)
        self.count = len(self.material)
        self.L = materials.emission[self.material].reshape(-1, 3)
        self.textures = materials.textures
        self.members, self.dists, self.total_area, self.trees = [], [], [], []
        # Index of each triangle within its group (for the group's tree pmf).
        self.rank = np.zeros(len(triangles), np.int64)
        for m in self.material:
            members = np.nonzero(triangles.material == m)[0]
            self.members.append(members)
            self.rank[members] = np.arange(len(members))
            self.dists.append(Distribution1D(triangles.area[members]))
            self.total_area.append(triangles.area[members].sum())
            tree = by_importance and 1 < len(members) <= MAX_TREE_TRIANGLES
            self.trees.append(triangle_tree(triangles, members) if tree else None)
        self.total_area = np.array(self.total_area, float)
        self.group_of_material = np.full(max(1, len(materials.emission)), -1, np.int64)
        self.group_of_material[self.material] = np.arange(self.count)

    def power(self, radius):
        # Two-sided Lambertian emitter: flux = pi * L * A per side.
        return selection_power(self.L) * 2.0 * np.pi * self.total_area if self.count else []

    def sample(self, out, idx, j, p, u1, u2, u3, n=None):
        tri, p_tri = self._pick(j, p, u3, n)
        b1, b2 = uniform_triangle(u1, u2)
        tr = self.tris
        q = tr.p0[tri] + b1[:, None] * tr.e1[tri] + b2[:, None] * tr.e2[tri]
        sph, solid_angle = self._spherical(tri, p)
        s = np.nonzero(sph)[0]
        if len(s):
            ts = tri[s]
            d, _ = spherical_triangle(p[s], tr.p0[ts], tr.p0[ts] + tr.e1[ts], tr.p0[ts] + tr.e2[ts],
                                      u1[s], u2[s])
            # The point where the sampled direction meets the triangle's plane.
            ng = tr.ng[ts]
            with np.errstate(divide="ignore", invalid="ignore"):
                th = dot(tr.p0[ts] - p[s], ng) / dot(d, ng)
            q[s] = p[s] + d * np.nan_to_num(th)[:, None]
        v = q - p
        t = np.linalg.norm(v, axis=1)
        wi = v / np.maximum(t, 1e-30)[:, None]
        cos_l = np.abs(dot(wi, tr.ng[tri]))
        out.wi[idx], out.dist[idx], out.Le[idx] = wi, t, self._radiance(tri, q, self.L[j])
        out.pdf[idx] = self._pdf(tri, p_tri, t * t, cos_l, sph, solid_angle)
        out.on_surface[idx] = True

    def _pick(self, j, p, u, n):
        """A triangle of each ray's group j and its probability within the group."""
        tri = np.empty(len(p), np.int64)
        prob = np.empty(len(p))
        for g in np.unique(j):
            sel = np.nonzero(j == g)[0]
            if self.trees[g] is not None:
                k, prob[sel] = self.trees[g].select(u[sel], p[sel], _normals(n, len(p))[sel])
            else:
                k, _ = self.dists[g].sample(u[sel])
                prob[sel] = self.dists[g].pmf[k]
            tri[sel] = self.members[g][k]
        return tri, prob

    def _pick_pmf(self, tri, o, n):
        """Probability that ``_pick`` at o (normal n) picks triangle tri."""
        group = self.group_of_material[self.tris.material[tri]]
        prob = np.zeros(len(tri))
        for g in np.unique(group):
            if g < 0:
                continue
            sel = np.nonzero(group == g)[0]
            k = self.rank[tri[sel]]
            if self.trees[g] is not None:
                prob[sel] = self.trees[g].pmf(k, o[sel], _normals(n, len(tri))[sel])
            else:
                prob[sel] = self.dists[g].pmf[k]
        return prob

    def _pdf(self, tri, p_tri, t2, cos_l, sph, solid_angle):
        """Solid-angle pdf of a point on triangle tri: p_tri times the
        triangle's own (area or solid-angle) pdf."""
        area = self.tris.area[tri]
        ok = (cos_l > 1e-12) & (t2 > 0) & (area > 0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            pdf = np.where(ok, p_tri * t2 / (np.maximum(cos_l, 1e-12) * np.maximum(area, 1e-300)), 0.0)
            pdf = np.where(ok & sph, p_tri / solid_angle, pdf)
        return np.where(np.isfinite(pdf), pdf, 0.0)

    def _radiance(self, tri, q, L):
        """Emission at points q on triangles tri: the constant, or the
        material's emission texture evaluated at q's UVs."""
        if not self.textures.emission:
            return L
        tr = self.tris
        d = q - tr.p0[tri]
        e1, e2 = tr.e1[tri], tr.e2[tri]
        d00, d01, d11 = dot(e1, e1), dot(e1, e2), dot(e2, e2)
        d20, d21 = dot(d, e1), dot(d, e2)
        denom = np.where(d00 * d11 - d01 * d01 > 0, d00 * d11 - d01 * d01, 1.0)
        b1 = (d11 * d20 - d01 * d21) / denom
        b2 = (d00 * d21 - d01 * d20) / denom
        from .nodes import ShadingContext
        shading = ShadingContext.at(tr, tri, b1, b2)
        return self.textures.emission_at(tr.material[tri], shading, np.broadcast_to(L, q.shape))

    def _spherical(self, tri, p):
        """Which shading points sample their triangle by solid angle (Arvo),
        and that solid angle: as Cycles (light/triangle.h), those nearer to
        the triangle's plane than its longest edge, where area sampling's
        pdf varies much over the triangle; farther, area sampling is about
        as good and far cheaper.  The solid-angle limits guard the warp."""
        tr = self.tris
        e1, e2 = tr.e1[tri], tr.e2[tri]
        e3 = e2 - e1
        longest2 = np.maximum(np.maximum(dot(e1, e1), dot(e2, e2)), dot(e3, e3))
        plane = dot(tr.p0[tri] - p, tr.ng[tri])
        close = np.nonzero(longest2 > plane * plane)[0]
        solid_angle = np.zeros(len(tri))
        if len(close):
            tc = tri[close]
            solid_angle[close] = triangle_solid_angle(p[close], tr.p0[tc], tr.p0[tc] + tr.e1[tc],
                                                      tr.p0[tc] + tr.e2[tc])[0]
        return (solid_angle >= MIN_SPHERICAL) & (solid_angle <= MAX_SPHERICAL), solid_angle

    def pdf(self, prim, o, p_hit, ng, n=None):
        """Solid-angle pdf of ``sample`` from o (normal n) giving p_hit on prim."""
        v = p_hit - o
        t2 = dot(v, v)
        cos_l = np.abs(dot(v, ng)) / np.sqrt(np.maximum(t2, 1e-300))
        sph, solid_angle = self._spherical(prim, o)
        return self._pdf(prim, self._pick_pmf(prim, o, n), t2, cos_l, sph, solid_angle)


def _uniform_index(j):
    """j itself, or its single value when every ray picked the same light, so
    per-light parameters broadcast instead of being gathered per ray."""
    if len(j) and j[0] == j[-1] and (j == j[0]).all():
        return int(j[0])
    return j


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)
