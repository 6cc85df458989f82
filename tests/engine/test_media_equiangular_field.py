"""Equiangular and MIS direct-light points in heterogeneous media
(engine/integrator/volume.py ``_tracked_points``: the point sampled before
the free flight, the tracker's running weight there as the transmittance,
sigma_s evaluated at the point; Cycles 5.0's shade_volume.h).

Truths from outside the new code: a fog whose coefficients are a constant
texture (so the trackers and the field evaluation render it) against the
same fog as a homogeneous medium (closed-form transmittance, its
equiangular points tested in test_media_equiangular.py); and on a noise
fog in a world haze, lit by a point light inside it and a sun, Volume > Sampling
'EQUIANGULAR' and 'MULTIPLE_IMPORTANCE' against 'DISTANCE' (light sampling
at the trackers' scattering points, tested in test_media_field.py).  Two
statistical families; power printed; the variance gain printed.
"""
import numpy as np

from ember_stats import block_means_var, family_z
from test_media_equiangular import worst_pair_z
from engine.render import render
from engine.scene import (Camera, Instance, Lobe, Material, Math, NodeCall, NodeOutput, PointLight,
                          RenderSettings, Scene, SunLight, Volume, World)
from engine.testscenes import box, look_at

PASS = (Lobe("transparent", (1.0, 1.0, 1.0)),)
SCATTER, ABSORB = (1.0, 0.9, 0.8), (0.1, 0.1, 0.2)


def _noise():
    return NodeOutput(NodeCall("ShaderNodeTexNoise", {"Scale": 3.0, "Detail": 1.0, "Roughness": 0.5,
                                                      "Lacunarity": 2.0, "Distortion": 0.0},
                               {"noise_dimensions": "3D", "noise_type": "FBM", "normalize": True}), "Fac")


def _tinted(rgb, density):
    from engine.scene import MixColor
    return MixColor("MULTIPLY", 1.0, tuple(rgb), density, clamp_factor=False)


def fog(volume, sun=False, size=(16, 12), world=None):
    """A 2 m fog cube, a small point light inside it off the centre, seen
    from outside (and a sun from above; ``world``: the world's volume)."""
    lights = [PointLight((0.2, 0.0, 0.1), (20.0, 20.0, 20.0), radius=0.05)]
    if sun:
        lights.append(SunLight((0.3, 0.2, -0.9), (0.6, 0.6, 0.6), angle=0.05))
    cam = Camera(look_at((0, -5, 0.3), (0, 0, 0)), lens=45, resolution=size)
    return Scene([box((2.0, 2.0, 2.0))], [Instance(0, materials=[0], name="fog")],
                 [Material("fog", PASS, volume=volume)], lights, World((0.0, 0.0, 0.0), volume=world), cam)


def constant_fog(sampling, textured):
    if not textured:
        return fog(Volume(scattering=SCATTER, absorption=ABSORB, anisotropy=0.2, sampling=sampling))
    one = Math("ADD", Math("MULTIPLY", _noise(), 0.0), 1.0)   # a texture of value 1: tracked
    return fog(Volume(scattering=_tinted(SCATTER, one), absorption=_tinted(ABSORB, one), anisotropy=0.2,
                      sampling=sampling))


def noise_fog(sampling):
    dens = Math("MULTIPLY", Math("MAXIMUM", Math("SUBTRACT", _noise(), 0.3), 0.0), 4.0)
    haze = Volume(scattering=(0.08, 0.08, 0.08), absorption=(0.01, 0.02, 0.03), sampling=sampling)
    return fog(Volume(scattering=_tinted(SCATTER, dens), absorption=_tinted(ABSORB, dens), anisotropy=0.2,
                      sampling=sampling), sun=True, world=haze)


def _render(scene, seed, spp=1024):
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, seed=seed, max_bounces=4))
    assert np.isfinite(r.image).all()
    return r


def _agree(results, pairs, family, block=2):
    """Block means and whole-image means of each pair agree (one family)."""
    blocks = {k: block_means_var(r.image[..., :3].astype(np.float64), r.variance.astype(np.float64), block)
              for k, r in results.items()}
    ref = blocks[pairs[0][1]][0]
    keep = ref > 0.02 * ref.max()
    zc = family_z(__name__ + "." + family, (int(keep.sum()) + 3) * len(pairs))
    worst = worst_pair_z(results, blocks, pairs, keep, zc)
    assert keep.sum() >= 20
    assert worst < zc


def _variance(results):
    lit = results["DISTANCE"].image[..., :3].mean(axis=2)
    lit = lit > 0.05 * lit.max()
    var = {k: r.variance[..., :3].astype(np.float64).sum(axis=2)[lit] for k, r in results.items()}
    gain = {k: float(np.median(var["DISTANCE"] / np.maximum(v, 1e-30))) for k, v in var.items()}
    print(f"{lit.sum()} lit pixels; median variance gain over distance:", {k: f"{g:.2f}x" for k, g in gain.items()},
          "; total variance", {k: f"{v.sum():.3g}" for k, v in var.items()})
    return {k: float(v.sum()) for k, v in var.items()}


def test_constant_texture_fog_matches_homogeneous_fog():
    """The heterogeneous code's equiangular, MIS and distance points on a
    fog of constant textured density against the homogeneous fog (closed-
    form transmittance, MIS points), block by block and over the image."""
    results = {"homogeneous": _render(constant_fog("MULTIPLE_IMPORTANCE", False), 71)}
    for seed, s in enumerate(("DISTANCE", "EQUIANGULAR", "MULTIPLE_IMPORTANCE"), start=72):
        results[s] = _render(constant_fog(s, True), seed)
    _agree(results, [(s, "homogeneous") for s in ("DISTANCE", "EQUIANGULAR", "MULTIPLE_IMPORTANCE")], "constant")
    total = _variance(results)
    assert total["EQUIANGULAR"] < total["DISTANCE"] and total["MULTIPLE_IMPORTANCE"] < total["DISTANCE"], total


def test_noise_fog_sampling_methods_agree():
    """A noise fog (empty patches, dense cores) around a point light, and
    a sun, in a homogeneous world haze (both in the stack inside the cube,
    the haze's transmittance in closed form): equiangular and MIS points (the sun's a distance point from the
    media's mean majorant) against light sampling at the trackers'
    scattering points ('DISTANCE')."""
    results = {s: _render(noise_fog(s), seed)
               for seed, s in enumerate(("DISTANCE", "EQUIANGULAR", "MULTIPLE_IMPORTANCE"), start=81)}
    _agree(results, [("EQUIANGULAR", "DISTANCE"), ("MULTIPLE_IMPORTANCE", "DISTANCE"),
                     ("EQUIANGULAR", "MULTIPLE_IMPORTANCE")], "noise")
    _variance(results)
