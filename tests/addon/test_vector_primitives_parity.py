"""The Vector pass of curves and points against live Cycles (issue 24):
test_curve_motion_parity's sliding strands (object motion), swaying
strands (geometry-nodes deformation: control points at frame 1 and 3),
sliding points and sliding particle hair (on its sliding sphere), without
their floor, on a transparent film, rendered at frame 2 with motion blur
off (Cycles writes the pass only then), SCENES[name] seeds of SPP samples
per renderer at the scenes' 48 x 32 (hair 64 x 48).

The pass is a ratio over the samples that hit, so each seed's alpha says
which pixels it is defined in:

* background (no seed of either renderer hit): both write exactly 0;
* covered (every seed of both hit): away from the silhouettes, Welch's t
  per pixel and channel over the seeds, a float32 rounding floor
  (``_floor``) added to its variance, all within the family level;
* edges (some seeds hit, others not: the silhouette the seeds saw): the
  seeds that hit are compared alike; a pixel every seed of one renderer
  hits and no seed of the other is a geometry mismatch and must not occur;
  failing edge pixels are bounded by EDGE_SHARE of the edge pixels (their
  ratio estimates are far from normal), and printed;
* the image mean of each moving channel over covered pixels (Welch over
  the seeds), which resolves a scale error of the whole pass.

The same check is run on Ember's vectors scaled by 1.01 and with the steps
swapped (frame - 1 for frame + 1), and must fail on both: printed as what
the test detects.
"""
import os

import bpy
import numpy as np
import pytest

from ember_testlib import empty_factory_scene, multilayer_output, read_multilayer_exr, setup_cycles, setup_ember
import ember_stats as stats
import test_curve_motion_parity as motion_scenes

SPP = 32
# Cycles projects in float32: a raster position of up to the image's width
# in pixels is rounded to 2^-24 width; FLOOR_ULPS such roundings along the
# projection and the difference (measured gaps on pixels both renderers see
# alike: <= 5e-7 px at 48 wide).
FLOOR_ULPS = 8
EDGE_SHARE = 0.02
MOVING = 0.1                   # channels whose image mean is at least this many pixels
# Seeds per renderer: the swaying strands' vectors vary most within a pixel;
# 16 seeds let their image mean resolve a 1 % scale with room (t 8.6).
SCENES = {'sliding_curves': 8, 'swaying_curves': 16, 'sliding_points': 8, 'sliding_hair': 8}


def _scene(name):
    scene = empty_factory_scene()
    getattr(motion_scenes, name)(scene, blur=False)
    bpy.data.objects.remove(bpy.data.objects['floor'])
    scene.render.film_transparent = True
    bpy.context.view_layer.use_pass_vector = True
    multilayer_output(scene)
    return scene


def _render(scene, folder, engine, seed):
    (setup_ember if engine == 'EMBER' else setup_cycles)(scene, SPP, 100 + seed, 0)
    scene.render.filepath = os.path.join(str(folder), f"{engine}_{seed}.exr")
    bpy.ops.render.render(write_still=True)
    layers = read_multilayer_exr(scene.render.filepath)
    return layers['Vector'], layers['Combined'][..., 3] > 0


@pytest.fixture(scope="module")
def renders(registered_addon, tmp_path_factory):
    from addon import engine as ember_engine
    out = {}
    for name, seeds in SCENES.items():
        folder = tmp_path_factory.mktemp(name)
        scene = _scene(name)
        for engine in ('EMBER', 'CYCLES'):
            runs = [_render(scene, folder, engine, seed) for seed in range(seeds)]
            out[name, engine] = (np.array([r[0] for r in runs]), np.array([r[1] for r in runs]))
            if engine == 'EMBER':
                assert all(entry['error'] is None for entry in ember_engine.RENDER_LOG[-seeds:])
    return out


def _conditional(vectors, hit):
    """Per pixel: the mean of the seeds that hit, the variance of that mean, and their count."""
    n = hit.sum(axis=0)[..., None]
    w = hit[..., None]
    mean = (vectors * w).sum(axis=0) / np.maximum(n, 1)
    var = ((vectors - mean) ** 2 * w).sum(axis=0) / np.maximum(n - 1, 1) / np.maximum(n, 1)
    return mean, var, n


def _floor(vectors):
    return FLOOR_ULPS * 2.0 ** -24 * vectors.shape[2]


def _pixel_t(e, c):
    """Welch's t and dof per pixel-channel of the seeds that hit, the floor
    added to the variance as a deterministic allowance (no degrees of
    freedom of its own: where both renderers' seeds agree exactly, the test
    is |gap| against the normal threshold times the floor)."""
    (me, ve, ne), (mc, vc, nc) = _conditional(*e), _conditional(*c)
    se2 = ve + vc + _floor(e[0]) ** 2
    with np.errstate(divide='ignore', invalid='ignore'):
        dof = se2 ** 2 / (ve ** 2 / np.maximum(ne - 1, 1) + vc ** 2 / np.maximum(nc - 1, 1))
    dof = np.minimum(np.where(np.isfinite(dof), np.maximum(dof, np.minimum(ne, nc) - 1.0), 1e6), 1e6)
    return (me - mc) / np.sqrt(se2), dof, me, mc


class Levels:
    """One scene's family levels, handed out once (mutants reuse them)."""

    def __init__(self, name, covered, edges, channels):
        self.covered = stats.family_level(f"vector primitives {name}: covered pixels", max(4 * covered, 1))
        self.edges = stats.family_level(f"vector primitives {name}: edge pixels", max(4 * edges, 1))
        self.mean = stats.family_level(f"vector primitives {name}: image means", max(channels, 1))


def _classes(e_hit, c_hit):
    every = e_hit.all(axis=0) & c_hit.all(axis=0)
    none = ~e_hit.any(axis=0) & ~c_hit.any(axis=0)
    tested = ~every & ~none & (e_hit.sum(axis=0) >= 2) & (c_hit.sum(axis=0) >= 2)
    mismatch = (e_hit.all(axis=0) & ~c_hit.any(axis=0)) | (c_hit.all(axis=0) & ~e_hit.any(axis=0))
    return every, none, ~every & ~none, tested, mismatch


def check(name, e, c, levels=None):
    """The verdict on Ember's (vectors, hit) seeds ``e`` against Cycles'
    ``c``: (ok, levels, lines to print)."""
    every, none, edge, tested, mismatch = _classes(e[1], c[1])
    t, dof, me, mc = _pixel_t(e, c)
    cm = c[0][:, every].mean(axis=1)                      # (seeds, 4) image means over covered pixels
    channels = np.flatnonzero(np.abs(cm.mean(axis=0)) >= MOVING)
    levels = levels or Levels(name, int(every.sum()), int(tested.sum()), len(channels))
    p = stats.t_p_values(t, dof)
    bad_covered = (p < levels.covered)[every].any(axis=-1)
    bad_edges = (p < levels.edges)[tested].any(axis=-1)
    background = np.abs(e[0][:, none]).max(initial=0.0) + np.abs(c[0][:, none]).max(initial=0.0)
    em = e[0][:, every].mean(axis=1)
    sign = np.sign(cm.mean(axis=0))      # (a relative difference > 0: Ember's vectors longer)
    means = [stats.MeanTest(f"channel {k}", sign[k] * em[:, k].mean(), em[:, k].var(ddof=1) / len(em), len(em) - 1,
                            sign[k] * cm[:, k].mean(), cm[:, k].var(ddof=1) / len(cm), len(cm) - 1)
             for k in channels]
    gap = np.abs(me - mc)[every]
    lines = [f"{name}: {int(every.sum())} covered pixels (median |vector| {np.median(np.abs(mc[every])):.2f} px): "
             f"{int(bad_covered.sum())} differ, median gap {np.median(gap):.1e} px, max {gap.max():.1e}, "
             f"max |t| {np.abs(t[every]).max():.1f} (median dof {np.median(dof[every]):.0f}, limit "
             f"{stats.t_threshold(levels.covered, float(np.median(dof[every]))):.1f})",
             f"  {int(edge.sum())} edge pixels ({int(tested.sum())} tested): {int(bad_edges.sum())} differ; "
             f"{int(mismatch.sum())} hit by every seed of one renderer and none of the other; "
             f"{int(none.sum())} background, max |vector| {background:.1e}"]
    lines += [f"  image mean {m}; detects {stats.detectable(m.relative_se, levels.mean, m.dof):.3%}" for m in means]
    ok = (not bad_covered.any() and bad_edges.sum() <= EDGE_SHARE * max(edge.sum(), 1) and not mismatch.any()
          and background == 0.0 and all(m.p >= levels.mean for m in means) and len(channels) > 0)
    return ok, levels, lines


@pytest.mark.parametrize("name", list(SCENES))
def test_vector_pass_of_curves_and_points_matches_cycles(name, renders):
    e, c = renders[name, 'EMBER'], renders[name, 'CYCLES']
    ok, levels, lines = check(name, e, c)
    print("\n" + "\n".join(lines))
    # what it detects: the pass 1 % too long, and the two steps swapped
    scaled, _, scaled_lines = check(name, (1.01 * e[0], e[1]), c, levels)
    swapped, _, swapped_lines = check(name, (-e[0][..., [2, 3, 0, 1]], e[1]), c, levels)
    print("  x 1.01: " + scaled_lines[0].split(": ", 1)[1] + "; " + "; ".join(s.strip() for s in scaled_lines[2:]))
    print("  steps swapped: " + swapped_lines[0].split(": ", 1)[1])
    assert ok, lines
    assert not scaled, ("the check cannot tell a pass 1 % too long", scaled_lines)
    assert not swapped, ("the check cannot tell the steps swapped", swapped_lines)


def test_vector_steps_reach_the_engine_scene(registered_addon, tmp_path, monkeypatch):
    """The export hands the engine the steps at frame 1 and 3 and a still
    render: the sliding strands', points' and particle hair's
    object-to-world 1 unit apart in x, the swaying strands' keys (their
    tips either side), no motion blur steps."""
    from ember_testlib import record_engine_scenes
    seen = record_engine_scenes(monkeypatch)
    for name in ('sliding_curves', 'swaying_curves', 'sliding_points', 'sliding_hair'):
        _render(_scene(name), tmp_path, 'EMBER', 0)
    sliding, swaying, points, hair = seen[0].curves[0], seen[1].curves[0], seen[2].points[0], seen[3].curves[0]
    for item in (sliding, swaying, points, hair):
        assert item.motion is None and getattr(item, 'motion_positions', None) is None
    assert np.allclose(np.asarray(sliding.vector_motion)[:, 0, 3], [-1.0, 0.0, 1.0], atol=1e-4)
    assert sliding.vector_positions is None and swaying.vector_motion is None
    steps = np.asarray(swaying.vector_positions)
    dx = steps[:, :, 0] - np.asarray(swaying.points)[None, :, 0]
    assert np.allclose(dx, np.array([-1.0, 0.0, 1.0])[:, None] * np.asarray(swaying.points)[None, :, 2], atol=1e-4)
    assert np.allclose(np.asarray(points.vector_motion)[:, 0, 3], [-1.0, 0.0, 1.0], atol=1e-4)
    assert np.allclose(np.asarray(hair.vector_motion)[:, 0, 3], [-1.0, 0.0, 1.0], atol=1e-4)


def test_infinite_steps_give_a_finite_pass_and_a_named_warning(registered_addon, tmp_path):
    """The sway blown up to infinity at frames 1 and 3 only (1e38 x 1e38 x
    (frame - 2)): the strands' deformation is dropped with a warning naming
    them, the pass is finite."""
    from addon import engine as ember_engine
    scene = _scene('swaying_curves')
    motion_scenes.infinite_sway()
    vector, hit = _render(scene, tmp_path, 'EMBER', 0)
    warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
    assert np.isfinite(vector).all() and hit.any()
    assert np.all(vector == 0.0)            # the strands taken as still, the camera is
    assert any("'strands'" in w and "Vector" in w for w in warnings), warnings


def test_the_objects_motion_blur_switches_do_not_change_the_pass(registered_addon, tmp_path):
    """Cycles' MOTION_PASS gives every object 3 steps and its deformation
    whatever Object > Motion Blur (and its Deformation) says: the swaying
    strands' pass is the same with both off, in both renderers (same seed:
    equal to float rounding), and it moves."""
    scene = _scene('swaying_curves')
    obj = bpy.data.objects['strands']
    for engine in ('EMBER', 'CYCLES'):
        obj.cycles.use_motion_blur = obj.cycles.use_deform_motion = True
        on, _ = _render(scene, tmp_path, engine, 0)
        obj.cycles.use_motion_blur = obj.cycles.use_deform_motion = False
        off, _ = _render(scene, tmp_path, engine, 0)
        assert np.abs(on).max() > 5.0, engine
        assert np.allclose(on, off, rtol=0.0, atol=1e-5), (engine, np.abs(on - off).max())
