"""The render's read-only Context: every field declared, built once by
``Context.build`` (engine.render.prepare calls it), frozen for the render.

Besides the scene's compiled parts it holds what the bounce decides once per
render: which emitters light sampling visits in each strategy, whether
paths track their ray kind (visibility), whether shadow rays cross
transparent surfaces, and the extra passes' per-render tables.  The one
thing that changes while batches run is inside ``centres``, the extra
passes' record of which pixels' centre rays are traced (behind its lock).
"""
from dataclasses import dataclass

import numpy as np

from .. import bsdf, kernels, pass_events
from ..geometry import VIS_SHADOW
from ..lobes.hair_huang import HAIR_HUANG
from ..sampler import Sampler
from . import subsurface
from .visibility import VIS_INDIRECT


@dataclass(frozen=True)
class Context:
    """Everything a batch needs, shared read-only between threads."""
    accel: object
    triangles: object
    materials: object
    lights: object
    camera: object
    world: np.ndarray
    settings: object
    sampler: Sampler
    # Cycles' bump shadowing term of the Blender version the scene comes from.
    bump_model: int
    jit: bool                    # compiled kernels on for this render
    # LightSet indices of the delta lights (BSDF sampling cannot find them)
    # and of every emitter.
    delta_emitters: np.ndarray
    all_emitters: np.ndarray
    # Visibility: some light is invisible to some bounce kind; some light
    # casts no shadow; paths track their VIS_* ray kind; some object casts
    # no shadow.  All False in the common scene, which pays nothing.
    light_excludes: bool
    light_no_shadow: bool
    track_rays: bool
    shadow_skips: bool
    # Transparency: which materials have a transparent lobe; whether any
    # does (shadow rays then cross them); the transparent passes after
    # which the next surface ends a path (Cycles lets a path cross one
    # even when transparent_max_bounces is 0).
    transparent_mat: np.ndarray
    transparent_shadows: bool
    transparent_limit: int
    # Cycles' per-kind bounce limits (diffuse, glossy, transmission): paths
    # count their bounces by kind only when some limit is below max_bounces.
    count_kinds: bool
    kind_limits: np.ndarray
    # Some material or light reads a Light Path node: paths track their ray
    # kind and count their bounces by kind, and hits carry the node's path
    # columns.
    light_path: bool
    # Extra passes: their PassConfig, the light group of each emitter (None
    # without light groups) and the centre-ray record.
    pass_config: object
    emitter_groups: object
    centres: object
    # Volumes: the scene's media.MediumTable, None without a volume (the
    # bounce's volume stages are then skipped: no cost).
    media: object = None
    # Some material has a subsurface lobe (integrator/subsurface.py).
    subsurface: bool = False
    subsurface_warnings: tuple = ()
    # Holdouts: (T,) each triangle's holdout weight for camera rays (1 on a
    # holdout object, the material's Holdout shader weight elsewhere); None
    # in a scene without holdouts (the stage is skipped).
    holdout: object = None
    # Light and shadow linking: linking.LightLinks, None without links.
    links: object = None
    # Shadow catchers: (T,) whether each triangle is a catcher's, None
    # without one (catcher.py).
    catcher: object = None
    # Motion blur (engine.motion.MotionGeometry), None in a still scene.
    motion: object = None
    # A light bake (bake_paths.BakeTarget, also the camera): paths start at its
    # texels under its closure filter; None in a render.
    bake: object = None
    # Point clouds (engine.points.Spheres: which triangle rows are spheres), None without.
    spheres: object = None
    # Rows no light samples (engine.points.unlit_rows: points, moving triangles), None when none.
    unlit: object = None
    # Hair curves (engine.points.Strands: which rows are curve segments), None without.
    strands: object = None
    # Ray Portal BSDF (integrator/portal.py): (M,) which materials have a
    # portal lobe, None without one (the stage is skipped).
    portal_mat: object = None

    @classmethod
    def build(cls, accel, triangles, materials, lights, camera, world, settings, sampler=None,
              bump_model=bsdf.BUMP_GGX, pass_config=None, media=None, holdout=None, links=None, catcher=None,
              motion=None, spheres=None, unlit=None, strands=None):
        """The Context of a render; ``sampler`` defaults to the settings'
        seed and pattern, ``pass_config`` to no extra passes."""
        if sampler is None:
            sampler = Sampler(settings.seed, settings.sampling_pattern)
        if pass_config is None:
            pass_config = pass_events.PassConfig()
        # Elliptical Huang hair is transparent outside its projected width (Cycles).
        portal_mat = np.any(materials.kind == bsdf.RAY_PORTAL, axis=1)
        transparent_mat = np.any((materials.kind == bsdf.TRANSPARENT)
                                 | ((materials.kind == HAIR_HUANG) & (materials.aspect_ratio != 1.0)), axis=1) | portal_mat
        # A light's node tree may read it too (LightSet.light_path).
        light_path = bool(getattr(materials.textures, "light_path", False) or getattr(lights, "light_path", False))
        return cls(accel, triangles, materials, lights, camera, world, settings, sampler, bump_model,
                   kernels.enabled(), _delta_emitters(lights), np.arange(lights.count),
                   **_visibility(lights, triangles, light_path),
                   transparent_mat=transparent_mat, transparent_shadows=bool(transparent_mat.any()),
                   portal_mat=portal_mat if portal_mat.any() else None,
                   transparent_limit=max(int(settings.transparent_max_bounces), 1),
                   **_kind_limits(settings, light_path), light_path=light_path,
                   pass_config=pass_config, emitter_groups=pass_events.emitter_groups(pass_config, lights),
                   centres=pass_events.CentreRecord(camera.width * camera.height), media=media,
                   subsurface=subsurface.in_scene(materials), holdout=holdout, links=links, catcher=catcher,
                   motion=motion, spheres=spheres, unlit=unlit, strands=strands)


def _delta_emitters(lights):
    """LightSet indices of the lights only light sampling can find (each
    light type says which of its lights are delta)."""
    return np.nonzero(lights.delta)[0]


def _kind_limits(settings, light_path=False):
    """The diffuse, glossy and transmission limits; counting them costs a
    ray-kind draw per bounce, so only when one of them can end a path first."""
    limits = np.array([settings.diffuse_bounces, settings.glossy_bounces, settings.transmission_bounces])
    return dict(count_kinds=light_path or bool(np.any(limits < settings.max_bounces)), kind_limits=limits)


def _visibility(lights, triangles, light_path=False):
    """The visibility flags of a scene (Blender's Ray Visibility); a Light
    Path node needs the ray kinds too."""
    vis = lights.visibility
    light_excludes = bool(np.any((vis & VIS_INDIRECT) != VIS_INDIRECT))
    tv = triangles.visibility
    return dict(light_excludes=light_excludes, light_no_shadow=bool(np.any((vis & VIS_SHADOW) == 0)),
                track_rays=light_excludes or light_path or (tv is not None and bool(np.any((tv & VIS_INDIRECT) != VIS_INDIRECT))),
                shadow_skips=tv is not None and bool(np.any((tv & VIS_SHADOW) == 0)))
