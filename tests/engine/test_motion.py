"""Motion blur in the engine (engine/motion.py, engine/embree_c.py).

* Embree's C API through ctypes finds the hits embreex finds on the same
  triangles (packets without numba, one-ray calls from numba with it).
* A hit at a ray's time lies on the triangle rebuilt at that time in
  float64 (translation, rotation by slerp, scale and deformation steps):
  Embree's interpolation and ours agree.
* Slerp between quaternion steps of a rotation about one axis is that
  rotation at the interpolated angle (Cycles' and Embree's transform motion).
* Unbiased blur: an emitting strip sliding under an orthographic camera
  (moved as an object, by deformation steps, or seen from a camera moving
  the other way) against the closed-form time average of its coverage.
* The sampler's time is stratified per pixel like its other sets; still
  scenes keep the embreex path and no time column; hostile input (NaN
  steps, one step, a step of scale 0) gives a named error or finite pixels.
"""
import numpy as np
import pytest

from engine import embree_c, kernels, motion
from engine.accel import Accel, _import_embreex
from engine.geometry import flatten
from engine.render import prepare, render
from engine.sampler import TIME, Sampler
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, SceneError, World
from engine.testscenes import box, quad, translate_rotate_z, uv_sphere

from analytic import check_against
import ember_stats

pytestmark = pytest.mark.skipif(not embree_c.available(), reason="libembree4 (embreex) not loaded")


def _rays(n, seed, centre=(0.0, 0.0, 0.0)):
    rng = np.random.default_rng(seed)
    o = rng.normal(0, 0.4, (n, 3)) + np.asarray(centre) + [0.0, 0.0, 5.0]
    d = rng.normal(0, 0.2, (n, 3)) + [0.0, 0.0, -1.0]
    return o, d / np.linalg.norm(d, axis=1)[:, None], rng.uniform(0, 1, n)


def test_c_api_finds_what_embreex_finds():
    rng = np.random.default_rng(3)
    t_count = 3000
    corners = (rng.uniform(-1, 1, (t_count, 1, 3)) + rng.normal(0, 0.05, (t_count, 3, 3))).astype(np.float32)
    vertices, indices = corners.reshape(-1, 3), np.arange(3 * t_count).reshape(-1, 3)
    scene = embree_c.TriangleScene([(vertices[None], indices, np.arange(t_count))])
    mc, rs = _import_embreex()
    from embreex import rtcore
    reference = rs.EmbreeScene(rtcore.EmbreeDevice())
    mc.TriangleMesh(reference, vertices, indices.astype(np.int32))
    o = rng.uniform(-2, 2, (20000, 3))
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tmax = np.full(len(o), 1e30)
    res = reference.run(o.astype(np.float32), d.astype(np.float32), dists=tmax.astype(np.float32),
                        query="INTERSECT", output=1)
    blocked_ref = reference.run(o.astype(np.float32), d.astype(np.float32), dists=tmax.astype(np.float32),
                                query="OCCLUDED") == 0
    for loops in (False, None):     # NumPy packets; whatever the JIT setting gives
        t, prim, u, v = scene.intersect(o, d, tmax, 0.0, loops=loops)
        hit = prim >= 0
        assert hit.mean() > 0.1
        assert np.array_equal(prim, res["primID"].astype(np.int64))
        assert np.allclose(t[hit], res["tfar"][hit], rtol=1e-5, atol=1e-5)
        assert np.allclose(u[hit], res["u"][hit], atol=1e-4)
        assert np.array_equal(scene.occluded(o, d, tmax, 0.0, loops=loops), blocked_ref)


def _moving_scene():
    """A smooth sphere spinning, growing and sliding; a box deforming
    (its top rises) while it turns; a still floor."""
    sphere = uv_sphere(0.6, segments=16, rings=8)
    steps = np.array([translate_rotate_z((0.4 * k - 0.4, 0.0, 0.8), 50.0 * k, 1.0 + 0.15 * k) for k in range(3)])
    cube = box((0.8, 0.8, 0.8))
    rise = np.array([cube.positions + [0.0, 0.0, 0.5 * k] * (cube.positions[:, 2:] > 0) for k in range(4)])
    cube.motion = rise
    cube.positions = 0.5 * (rise[1] + rise[2])   # the centre of 4 steps, where the scene itself is
    floor = quad([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]])
    turn = np.array([translate_rotate_z((1.5, 0.5, 0.4), -20.0 * k) for k in range(2)])
    instances = [Instance(0, steps[1], motion=steps),
                 Instance(1, motion.matrix_at(motion.decompose(turn), motion.CENTRE), motion=turn), Instance(2)]
    return Scene(meshes=[sphere, cube, floor], instances=instances)


def test_hits_lie_on_the_triangle_at_their_time():
    scene = _moving_scene()
    tris = flatten(scene)
    geometry = motion.MotionGeometry(scene, tris)
    accel = motion.MotionAccel(tris, geometry)
    o, d, time = _rays(40000, 1, centre=(0.5, 0.2, 0.0))
    t, prim, bu, bv = accel.intersect(o, d, np.full(len(o), np.inf), time)
    hit = prim >= 0
    moving = hit & (geometry.part[np.maximum(prim, 0)] >= 0)
    assert moving.sum() > 5000 and (hit & ~moving).sum() > 1000
    p0, ng, ns = geometry.at(tris, prim[hit], time[hit])
    cos = np.einsum("ij,ij->i", d[hit], ng)
    t_plane = np.einsum("ij,ij->i", p0 - o[hit], ng) / cos
    grazing = np.abs(cos) < 0.05
    err = np.abs(t_plane - t[hit])[~grazing]
    print(f"moving hits {moving.sum()}, |t_embree - t_plane| max {err.max():.2e}, 99.9% {np.quantile(err, 0.999):.2e}")
    assert err.max() < 20 * motion.MotionAccel.OFFSET * 6.0
    # At the centre time the rebuilt triangles are the scene's own (to
    # float32, the precision Embree keeps the steps in).
    c0, cn, _ = geometry.at(tris, np.arange(len(tris)), np.full(len(tris), motion.CENTRE))
    assert np.allclose(c0, tris.p0, atol=1e-6) and np.allclose(cn, tris.ng, atol=1e-6)
    assert np.array_equal(accel.occluded(o, d, np.full(len(o), np.inf), time), hit)
    # Packets and the compiled loop (when on) agree.
    t2, prim2, _, _ = accel.scene.intersect(o, d, np.full(len(o), np.inf), time, loops=False)
    assert np.array_equal(prim2, prim)


def test_slerp_of_a_turn_is_the_turn_at_the_interpolated_angle():
    angles = np.radians([10.0, 70.0, 150.0])
    steps = np.array([translate_rotate_z((k, 2.0 * k, 0.0), np.degrees(a), 1.5) for k, a in enumerate(angles)])
    time = np.linspace(0.0, 1.0, 41)
    L, T = motion.transform_at(motion.decompose(steps), time)
    f = time * 2
    angle = np.where(f < 1, angles[0] + f * (angles[1] - angles[0]), angles[1] + (f - 1) * (angles[2] - angles[1]))
    want = np.array([translate_rotate_z((0, 0, 0), np.degrees(a), 1.5)[:3, :3] for a in angle])
    assert np.allclose(L, want, atol=1e-12)
    assert np.allclose(T[:, :2], np.stack([f, 2 * f], axis=1), atol=1e-12)


WIDTH, HEIGHT, SPAN = 48, 8, 4.0      # orthographic frame: 4 m wide
STRIP, TRAVEL = 0.7, 1.5              # the strip's width and its travel over the shutter


def _strip_scene(how):
    emit = Material("strip", lobes=(Lobe("diffuse", color=(0.0, 0.0, 0.0)),), emission=(1.0, 1.0, 1.0))
    strip = quad([[-STRIP / 2, -2, 0], [STRIP / 2, -2, 0], [STRIP / 2, 2, 0], [-STRIP / 2, 2, 0]])
    cam = Camera(matrix=translate_rotate_z((0.0, 0.0, 3.0)), kind="ORTHO", ortho_scale=SPAN,
                 resolution=(WIDTH, HEIGHT))
    offsets = np.array([-0.5, 0.0, 0.5]) * TRAVEL
    inst = Instance(0, materials=[0], visible_camera=True)
    if how == "transform":
        inst.motion = np.array([translate_rotate_z((x, 0.0, 0.0)) for x in offsets])
    elif how == "deform":
        strip.motion = np.array([strip.positions + [x, 0.0, 0.0] for x in offsets])
    else:   # the camera moves the other way
        cam.motion = np.array([translate_rotate_z((-x, 0.0, 3.0)) for x in offsets])
    return Scene(meshes=[strip], instances=[inst], materials=[emit], camera=cam, world=World(color=(0.0, 0.0, 0.0)))


def _strip_expected(settings):
    """Each pixel's expectation: the filter-weighted share of the shutter
    during which the strip covers the pixel's ray (closed form in time,
    quadrature over the filter)."""
    from engine.camera import PixelFilter
    pf = PixelFilter(settings.filter_type, settings.filter_width)
    pw = SPAN / WIDTH
    dx = np.linspace(-settings.filter_width, settings.filter_width, 4001)
    w = pf.pdf(dx)
    w /= w.sum()
    x = -SPAN / 2 + (np.arange(WIDTH)[:, None] + 0.5 + dx[None, :]) * pw       # ray x per pixel, offset
    # covered while |x - c(t)| < STRIP / 2 with c(t) = TRAVEL (t - 1/2): the overlap of two intervals
    lo = np.clip((x - STRIP / 2) / TRAVEL + 0.5, 0.0, 1.0)
    hi = np.clip((x + STRIP / 2) / TRAVEL + 0.5, 0.0, 1.0)
    row = ((hi - lo) * w).sum(axis=1)
    return np.repeat(row[None, :], HEIGHT, axis=0)


def test_sliding_strip_blur_is_the_time_average():
    settings = RenderSettings(samples=256, samples_per_pass=256, max_bounces=0, seed=5)
    expected = _strip_expected(settings)
    images, variances = [], []
    for how in ("transform", "deform", "camera"):
        result = render(_strip_scene(how), settings)
        assert np.isfinite(result.image).all()
        images.append(result.image)
        variances.append(result.variance)

    class Joined:   # the three renders side by side: one family of blocks
        image = np.concatenate(images, axis=1)
        variance = np.concatenate(variances, axis=1)

    expect = np.concatenate([expected] * 3, axis=1)
    # Blocks where the strip passes (elsewhere both are exactly 0).
    check_against(Joined, expect, expect > 0.02, "sliding strip (object, deformation, camera)", block=4)


def test_time_is_a_stratified_dimension_of_its_own():
    sampler = Sampler(7, "sobol")
    pseed = sampler.pixel_seeds(np.full(64, 11))
    t = sampler.get(pseed, np.arange(64, dtype=np.uint32), TIME)[:, 0]
    assert np.array_equal(np.sort(np.floor(t * 64).astype(int)), np.arange(64))
    camera = sampler.get(pseed, np.arange(64, dtype=np.uint32), 0)[:, 0]
    assert abs(np.corrcoef(t, camera)[0, 1]) < 0.5


def test_still_scenes_keep_embreex_and_no_time():
    scene = _strip_scene("transform")
    scene.instances[0].motion = None
    ctx = prepare(scene, RenderSettings(samples=1))
    assert ctx.motion is None and type(ctx.accel) is Accel
    moving = prepare(_strip_scene("transform"), RenderSettings(samples=1))
    assert isinstance(moving.accel, motion.MotionAccel) and moving.motion.moving
    camera_only = prepare(_strip_scene("camera"), RenderSettings(samples=1))
    assert type(camera_only.accel) is Accel and camera_only.motion is not None


@pytest.mark.parametrize("mutate, message", [
    (lambda s: setattr(s.instances[0], "motion", np.full((3, 4, 4), np.nan)), "instance 0 ('object') motion"),
    (lambda s: setattr(s.instances[0], "motion", np.eye(4)[None]), "at least 2 steps"),
    (lambda s: setattr(s.meshes[0], "motion", np.zeros((3, 5, 3))), "mesh 0 ('quad') motion"),
    (lambda s: setattr(s.camera, "motion", np.zeros((2, 3, 4))), "camera motion"),
])
def test_bad_motion_is_a_named_error(mutate, message):
    scene = _strip_scene("transform")
    mutate(scene)
    with pytest.raises(SceneError, match=message.replace("(", r"\(").replace(")", r"\)")):
        render(scene, RenderSettings(samples=1))


def test_a_step_of_scale_zero_renders_finite():
    scene = _strip_scene("transform")
    scene.instances[0].motion[0, :3, :3] = 0.0   # the strip appears from a point
    scene.meshes[0].normals = np.tile(np.array([0.0, 0.0, 1.0]), (2, 3, 1))
    result = render(scene, RenderSettings(samples=4, max_bounces=1))
    assert np.isfinite(result.image).all() and result.image.max() > 0


def _lit_floor_scene():
    """The sliding strip, invisible to the camera, lighting a floor under it."""
    scene = _strip_scene("transform")
    floor = quad([[-3, -3, -0.5], [3, -3, -0.5], [3, 3, -0.5], [-3, 3, -0.5]])
    scene.meshes.append(floor)
    scene.materials.append(Material("floor"))
    scene.instances.append(Instance(1, translate_rotate_z((0.0, 0.0, 0.0)), materials=[1]))
    scene.instances[0].visible_camera = False
    return scene


def test_moving_emitters_are_sampled_where_they_are_at_the_path_time():
    """A moving emissive triangle is a light (as Cycles' light/triangle.h):
    its points are drawn on the triangle where it is at each path's time."""
    ctx = prepare(_lit_floor_scene(), RenderSettings(samples=1))
    assert ctx.unlit is None and ctx.lights.emitter_of_triangle(np.array([0]))[0] >= 0
    rng = np.random.default_rng(4)
    n = 4000
    p = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), np.full(n, -0.5)])
    time = rng.uniform(0, 1, n)
    e = np.full(n, ctx.lights.emitter_of_triangle(np.array([0]))[0])
    ls = ctx.lights.sample(e, p, rng.uniform(size=n), rng.uniform(size=n), rng.uniform(size=n), time=time)
    q = p + ls.wi * ls.dist[:, None]
    centre = TRAVEL * (time - 0.5)
    assert np.abs(q[:, 2]).max() < 1e-9
    assert (np.abs(q[:, 0] - centre) <= STRIP / 2 + 1e-9).all() and (ls.pdf > 0).all()
    # the pdf a BSDF ray meeting that point has (MIS) is the sample's own, on either triangle of the strip
    prim = np.where(np.isclose(ctx.lights.triangle_pdf(np.zeros(n, np.int64), p, q, np.tile([0.0, 0.0, 1.0], (n, 1)),
                                                       time=time), ls.pdf, rtol=1e-6), 0, 1)
    pdf = ctx.lights.triangle_pdf(prim, p, q, np.tile([0.0, 0.0, 1.0], (n, 1)), time=time)
    assert np.allclose(pdf, ls.pdf, rtol=1e-6)


def test_moving_emitters_light_sampling_agrees_with_bsdf_rays():
    """The floor lit by the moving strip: light sampling with MIS (the
    strip sampled at the path's time) against BSDF rays alone, the two
    unbiased estimators by the block test (power printed); MIS is less noisy."""
    scene = _lit_floor_scene()
    images = {}
    for strategy in ("mis", "bsdf"):
        r = render(scene, RenderSettings(samples=512, samples_per_pass=512, max_bounces=0, seed=3,
                                         strategy=strategy, sum_variance=True))
        assert np.isfinite(r.image).all()
        images[strategy] = (r.image[..., :3].astype(np.float64), r.variance_with_sum.astype(np.float64))
    (a, va), (b, vb) = images["mis"], images["bsdf"]
    fails, details = ember_stats.failing_blocks_var(a, va, 511, b, vb, 511, 4, name=__name__ + ".moving_emitter")
    print(f"moving emitter, MIS against BSDF rays: max |t| {details['max_abs_t']:.2f}, median block detects "
          f"{details['median_block_detects']:.2%}; noise ratio {np.sqrt(va[..., 3].sum() / vb[..., 3].sum()):.2f}")
    assert len(fails) == 0, fails
    tests, level = ember_stats.region_mean_tests_var(a, va, 511, b, vb, 511, name=__name__ + ".moving_emitter_means")
    assert not ember_stats.report_mean_tests("moving emitter, MIS against BSDF rays", tests, level)
    assert va[..., 3].sum() < 0.8 * vb[..., 3].sum()


def test_motion_with_transparency_volumes_and_passes_renders_finite():
    """A moving transparent box, a moving volume box and the AO, Depth and
    Vector passes together: finite pixels (their shadow rays and AO rays at
    the centre's geometry where they carry no time, docs/design.md)."""
    from engine.scene import PointLight, Volume
    scene = _strip_scene("transform")
    scene.world = World(color=(0.2, 0.2, 0.2))
    scene.meshes.append(box((0.6, 0.6, 0.6)))
    scene.materials += [Material("veil", lobes=(Lobe("transparent", color=(0.6, 0.6, 0.6)),
                                                Lobe("diffuse", color=(0.5, 0.5, 0.5)))),
                        Material("fog", lobes=(Lobe("transparent", color=(1.0, 1.0, 1.0)),),
                                 volume=Volume(scattering=(2.0, 2.0, 2.0)))]
    steps = np.array([translate_rotate_z((x, 0.0, -0.6), 30 * x) for x in (-0.5, 0.0, 0.5)])
    scene.instances += [Instance(1, steps[1], materials=[1], motion=steps),
                        Instance(1, translate_rotate_z((0.8, 0.0, -0.6)), materials=[2], motion=steps[::-1] + 0)]
    scene.instances[2].matrix = steps[1]
    scene.lights = [PointLight((0.0, -1.0, 2.0), (100.0, 100.0, 100.0))]
    result = render(scene, RenderSettings(samples=4, samples_per_pass=4, max_bounces=3, volume_bounces=1,
                                          passes=("Ambient Occlusion", "Depth", "Vector")))
    assert np.isfinite(result.image).all() and result.image.max() > 0
    for name in ("Ambient Occlusion", "Depth", "Vector"):
        assert np.isfinite(result.passes[name]).all()
    assert not result.passes["Vector"].any()   # Cycles' rule with motion blur on


def test_query_loops_are_cached_kernels():
    """A moving scene's first query compiles nothing: the per-ray loops are
    kernels numba caches on disk (they were closures over ctypes function
    pointers, compiled again in every process: 1.8-2.2 s, docs/benchmarks.md)."""
    before = kernels.enabled()
    if not kernels.configure(True):
        pytest.skip(str(kernels.UNAVAILABLE))
    try:
        assert kernels.wait(900)
        loops = embree_c._compiled_loops()
        assert loops is not None
        for loop, kernel in zip(loops, (embree_c._intersect_rays, embree_c._occluded_rays)):
            assert kernel in kernels.KERNELS and loop is kernel.compiled
            assert type(loop._cache).__name__ == "FunctionCache"
    finally:
        kernels.configure(before)
