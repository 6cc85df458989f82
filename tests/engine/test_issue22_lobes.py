"""The lobes of issue 22 beyond what tests/engine/test_lobe_registry.py checks
for every lobe (chi-square of sampling against eval, sample/eval agreement,
reciprocity, energy bounds): Cycles' energy-preserving Oren-Nayar in a white
furnace, the anisotropic lobe's tangent rotation, the material tangent's
frame, and the emission a Principled coat dims seen alike by light samples
and BSDF rays (MIS stays unbiased).  Cycles parity of all of them:
tests/addon/test_lobe_parity.py."""
import numpy as np

from analytic import big_plane, directional_albedo, furnace_plane, ortho_camera
from engine import bsdf
from engine.nodes.context import ShadingContext
from engine.render import render
from engine.scene import Instance, Lobe, Material, NodeCall, NodeOutput, RenderSettings, Scene, World
from engine.testscenes import quad
from engine.textures import MaterialTextures

from ember_stats import detectable, family_level, z_threshold


def test_oren_nayar_white_albedo_is_one_by_quadrature():
    """Truth: the model's energy preservation (Cycles' Oren-Nayar adds the
    OpenPBR multiple-scattering term with E_avg = a pi + (2 pi - 5.6) / 3 b
    in closed form, so a white surface reflects all it receives): the
    directional albedo by midpoint quadrature of eval is 1 at every view
    angle and roughness; roughness 0 is Lambert, 1 / pi exactly; a grey one
    reflects less than its colour would as Lambert plus the lost energy."""
    for sigma in (0.3, 1.0):
        for mu in (0.1, 0.5, 0.95):
            a = directional_albedo(Material("on", (Lobe("oren_nayar", (1.0, 1.0, 1.0), diffuse_roughness=sigma),)),
                                   mu, n_theta=256, n_phi=128)
            assert np.allclose(a, 1.0, atol=2e-4), (sigma, mu, a)
            grey = directional_albedo(Material("on", (Lobe("oren_nayar", (0.5, 0.5, 0.5),
                                                           diffuse_roughness=sigma),)), mu, 128, 64)
            assert np.all((grey > 0.38) & (grey < 0.5)), (sigma, mu, grey)
    lobes = bsdf.MaterialTable([Material("lambert", (Lobe("oren_nayar", (1, 1, 1), diffuse_roughness=0.0),))]
                               ).gather(np.zeros(3, int))
    wi = np.array([[0.3, 0.1, 0.9], [0.0, 0.6, 0.8], [-0.5, 0.0, 0.866]])
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    f, _ = bsdf.eval_pdf(lobes, np.tile([0.6, 0.0, 0.8], (3, 1)), wi)
    assert np.allclose(f, 1.0 / np.pi, rtol=1e-12)


def test_oren_nayar_white_furnace_renders_the_world():
    """A white Oren-Nayar plane (roughness 1) under a unit world renders 1
    (the model's energy preservation), through the integrator's sampling."""
    mat = Material("rough white", (Lobe("oren_nayar", (1.0, 1.0, 1.0), diffuse_roughness=1.0),))
    cases = (0.25, 0.8)
    level = family_level(__name__ + " oren-nayar furnace", len(cases))
    for mu in cases:
        r = furnace_plane(mat, mu, spp=256)
        img = r.image[..., 0].astype(np.float64)
        se = np.sqrt(r.variance[..., 0].astype(np.float64).sum()) / img.size
        z = (img.mean() - 1.0) / se
        print(f"Oren-Nayar furnace mu {mu}: {img.mean():.5f} +- {se:.5f}, z {z:+.2f}; detects "
              f"{detectable(se, level):.3%} with probability 1/2")
        assert abs(z) < z_threshold(level)


def _aniso(rotation):
    table = bsdf.MaterialTable([Material("a", (Lobe("glossy_anisotropic", (0.9, 0.8, 0.7), 0.4, anisotropy=0.8,
                                                    rotation=rotation),))])
    return table.gather(np.zeros(64, int))


def test_anisotropic_rotation_turns_the_tangent():
    """Rotation r turns the tangent by 2 pi r about the normal (Cycles'
    rotate_around_axis): f and pdf at (wo, wi) with rotation r equal those
    at both directions turned by -2 pi r with rotation 0; whole turns and a
    rotation of 1e30 (a whole number of turns in float) change nothing."""
    rng = np.random.default_rng(4)
    wo, wi = rng.normal(size=(64, 3)), rng.normal(size=(64, 3))
    wo[:, 2], wi[:, 2] = np.abs(wo[:, 2]) + 0.2, np.abs(wi[:, 2]) + 0.2
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    r = 0.15
    c, s = np.cos(2 * np.pi * r), np.sin(2 * np.pi * r)

    def turned(w):
        return np.stack([c * w[:, 0] + s * w[:, 1], c * w[:, 1] - s * w[:, 0], w[:, 2]], axis=1)
    f_r, p_r = bsdf.eval_pdf(_aniso(r), wo, wi)
    f_0, p_0 = bsdf.eval_pdf(_aniso(0.0), turned(wo), turned(wi))
    assert np.allclose(f_r, f_0, rtol=1e-9) and np.allclose(p_r, p_0, rtol=1e-9)
    assert not np.allclose(f_r, bsdf.eval_pdf(_aniso(0.0), wo, wi)[0], rtol=1e-3)   # the rotation matters
    for same in (1.15, -0.85, 1e30):
        f, p = bsdf.eval_pdf(_aniso(same), wo, wi)
        expected = f_r if same != 1e30 else bsdf.eval_pdf(_aniso(0.0), wo, wi)[0]
        assert np.allclose(f, expected, rtol=1e-9), same


def test_tangent_frame_is_the_radial_tangent_projected():
    """A material's tangent (Cycles' default radial tangent about Z) sets the
    shading frame: x perpendicular to the normal, in the plane of the normal
    and the radial tangent (-y, x, 0) of the Generated coordinates, y = n x
    x; rows of other materials keep their frame."""
    mesh = quad([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    tangent = NodeOutput(NodeCall("ShaderNodeTangent", {}, {"direction_type": "RADIAL", "axis": "Z",
                                                            "uv_map": ""}), "Tangent")
    mats = [Material("plain"), Material("brushed", (Lobe("glossy_anisotropic", anisotropy=0.5),), tangent=tangent)]
    textures = MaterialTextures(mats)
    n = 6
    p = np.column_stack([np.linspace(-0.9, 0.9, n), np.linspace(0.7, -0.4, n), np.zeros(n)])
    ns = np.tile([0.0, 0.0, 1.0], (n, 1))
    ctx = ShadingContext(n, p=p, ng=ns, ns=ns, wo=ns)
    tt, bb = np.tile([1.0, 0.0, 0.0], (n, 1)), np.tile([0.0, 1.0, 0.0], (n, 1))
    mat = np.array([1, 1, 0, 1, 1, 1])
    textures.tangent_frames(mat, ctx, ns, tt, bb)
    g = p   # no mesh: Generated is object space P (the node's fallback); radial about its centre 0.5
    radial = np.column_stack([-(g[:, 1] - 0.5), g[:, 0] - 0.5, np.zeros(n)])
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    rows = mat == 1
    assert np.allclose(tt[rows], radial[rows], atol=1e-12)
    assert np.allclose(bb[rows], np.cross(ns, tt)[rows], atol=1e-12)
    assert np.allclose(tt[~rows], [1.0, 0.0, 0.0]) and np.allclose(bb[~rows], [0.0, 1.0, 0.0])
    del mesh


def _strategy_means(scene, runs):
    out = {}
    for strategy, spp, seed in runs:
        r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, max_bounces=0, seed=seed,
                                         strategy=strategy, sum_variance=True))
        img = r.image[..., :3].astype(np.float64)
        # A mean over channels: the variance of each pixel's R + G + B (correlated channels).
        out[strategy] = img.mean(), np.sqrt(r.sum_variance.astype(np.float64).sum()) / img.size
    return out


def test_coat_dimmed_emission_in_light_samples_and_bsdf_rays(monkeypatch):
    """An emissive plane under a tinted coat lights a diffuse floor.  With
    the albedo dimming in both estimators, NEE alone and BSDF sampling alone
    agree (the dimming is the same function of the emitter's view angle in
    both: MIS is unbiased).  As Cycles (engine/lights/mesh.py
    LIGHT_SAMPLES_DIM_BY_ALBEDO), light samples keep only the coat tint, so
    NEE sees more light than BSDF rays; the coat dims the emission either way."""
    from engine.lights import mesh
    floor, floor_inst = big_plane(0, 3.0)
    lamp = quad([[-0.5, -0.5, 1.0], [-0.5, 0.5, 1.0], [0.5, 0.5, 1.0], [0.5, -0.5, 1.0]])
    coat = Lobe("glossy", (1.0, 1.0, 1.0), 0.2, "dielectric", ior=1.5, covers=1, absorb=(0.6, 0.8, 1.0))
    lamp_mat = Material("coated lamp", (coat, Lobe("diffuse", (0.0, 0.0, 0.0))), (4.0, 4.0, 4.0),
                        emission_layers=(0,))
    grey = Material("floor", (Lobe("diffuse", (0.5, 0.5, 0.5)),))
    cam = ortho_camera((0, 0, 0.9), (0, 0, 0), (16, 16), 2.0)
    scene = Scene([floor, lamp], [floor_inst, Instance(1, materials=[1])], [grey, lamp_mat], [],
                  World((0.0, 0.0, 0.0)), cam)
    runs = (("light", 64, 11), ("bsdf", 1024, 12))
    level = family_level(__name__ + " dimmed emission", 2)
    monkeypatch.setattr(mesh, "LIGHT_SAMPLES_DIM_BY_ALBEDO", True)
    consistent = _strategy_means(scene, runs)
    (a, sa), (b, sb) = consistent["light"], consistent["bsdf"]
    se = np.hypot(sa, sb)
    z = (a - b) / se
    print(f"coat-dimmed emitter, dimmed alike: NEE {a:.5f} +- {sa:.5f}, BSDF {b:.5f} +- {sb:.5f}, z {z:+.2f}; "
          f"detects {detectable(se, level) / a:.2%} with probability 1/2")
    assert abs(z) < z_threshold(level)
    monkeypatch.setattr(mesh, "LIGHT_SAMPLES_DIM_BY_ALBEDO", False)
    light, _ = _strategy_means(scene, runs[:1])["light"]
    z_cycles = (light - b) / np.hypot(consistent["light"][1], sb)
    print(f"as Cycles: NEE {light:.5f} against BSDF {b:.5f}: z {z_cycles:+.1f}")
    assert z_cycles > z_threshold(level), "light samples are dimmed by the coat's albedo (Cycles' are not)"
    plain = Scene([floor, lamp], [floor_inst, Instance(1, materials=[1])],
                  [grey, Material("lamp", (Lobe("diffuse", (0.0, 0.0, 0.0)),), (4.0, 4.0, 4.0))], [],
                  World((0.0, 0.0, 0.0)), cam)
    r = render(plain, RenderSettings(samples=16, samples_per_pass=16, max_bounces=0, seed=13, strategy="light"))
    assert r.image[..., :3].mean() > 1.2 * light, "the coat does not dim the emission"
