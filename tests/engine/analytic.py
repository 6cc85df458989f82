"""Small analytic scenes shared by the engine tests (a helper module: test
modules do not import each other)."""
import numpy as np

from engine import bsdf
from engine.render import render
from engine.scene import Camera, Instance, Lobe, Material, RenderSettings, Scene, World
from engine.testscenes import look_at, quad

from ember_stats import block_means_var, family_z, z_scores


def ortho_camera(eye, target, size, scale, up=(0.0, 1.0, 0.0)):
    return Camera(look_at(eye, target, up), kind="ORTHO", ortho_scale=scale,
                  resolution=size, clip_start=0.01, clip_end=100.0)


def big_plane(material=0, half=50.0):
    return quad([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]]), \
        Instance(0, materials=[material])


def analytic_scene(light):
    mesh, inst = big_plane()
    cam = ortho_camera((0, 0, 5), (0, 0, 0), (40, 40), 4.0)
    rho = 0.5
    mat = Material("grey", (Lobe("diffuse", (rho, rho, rho)),))
    return Scene([mesh], [inst], [mat], [light], World((0.0, 0.0, 0.0)), cam), rho


def pixel_centres(n, scale):
    c = (np.arange(n) + 0.5) / n * scale - 0.5 * scale
    x, y = np.meshgrid(c, -c)   # row 0 at the top = +y
    return x, y


def directional_albedo(material, mu, n_theta=1024, n_phi=512):
    """Hemispherical reflectance of ``material`` for cos(theta_o) = mu by
    midpoint quadrature of eval() -- independent of the sampling code."""
    table = bsdf.MaterialTable([material])
    wo = np.array([np.sqrt(1 - mu * mu), 0.0, mu])
    ct = (np.arange(n_theta) + 0.5) / n_theta       # cos(theta_i), uniform in [0, 1]
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    c, p = np.meshgrid(ct, ph, indexing="ij")
    st = np.sqrt(1 - c * c)
    wi = np.stack([st * np.cos(p), st * np.sin(p), c], axis=-1).reshape(-1, 3)
    lobes = table.gather(np.zeros(len(wi), int))
    f, _ = bsdf.eval_pdf(lobes, np.tile(wo, (len(wi), 1)), wi)
    # d omega = d(cos theta) d phi
    return (f * wi[:, 2:3]).sum(axis=0) * (1.0 / n_theta) * (2 * np.pi / n_phi)


def furnace_plane(material, mu, spp=64):
    mesh, inst = big_plane()
    s = np.sqrt(1 - mu * mu)
    cam = ortho_camera((3 * s, 0, 3 * mu), (0, 0, 0), (24, 24), 0.5, up=(0, 0, 1) if mu < 0.99 else (0, 1, 0))
    scene = Scene([mesh], [inst], [material], [], World((1.0, 1.0, 1.0)), cam)
    return render(scene, RenderSettings(samples=spp, samples_per_pass=spp, max_bounces=8, seed=3))


def disk_irradiance(L, R, h, x):
    """Irradiance at radial offset x in a plane parallel to a disk (radius R,
    radiance L) at height h."""
    a = h * h + x * x - R * R
    return 0.5 * np.pi * L * (1.0 - a / np.sqrt((h * h + x * x + R * R) ** 2 - 4 * R * R * x * x))


def check_against(result, expected, mask, label, block=4):
    """z-test of block means (block x block pixels) against the analytic value.

    Blocks rather than pixels: with BSDF sampling a far pixel may see no light
    hit at all, and its sample variance (0) would be no estimate of the error."""
    img = np.where(mask, result.image[..., 0], np.nan).astype(np.float64)
    var = result.variance[..., 0].astype(np.float64)
    m, v = block_means_var(img[..., None], var[..., None], block)
    e, _ = block_means_var(expected[..., None], np.zeros_like(var)[..., None], block)
    ok = np.isfinite(m)
    z = z_scores(m[ok], v[ok], e[ok], 0.0)
    zc = family_z(__name__, ok.sum() + 1)      # the blocks and the mean of them all
    rel = (m[ok].mean() - e[ok].mean()) / e[ok].mean()
    rel_se = np.sqrt(v[ok].sum()) / ok.sum() / e[ok].mean()
    print(f"{label}: {ok.sum()} blocks, max |z| {np.abs(z).max():.2f} (limit {zc:.2f}), "
          f"relative mean error {rel:+.4f} +- {rel_se:.4f}; detects {zc * rel_se:.2%} over the image, "
          f"{zc * np.median(np.sqrt(v[ok]) / e[ok]):.1%} in a median block, with probability 1/2")
    assert abs(rel) < zc * rel_se, f"{label}: the image mean is off by {rel:+.3%} +- {rel_se:.3%}"
    assert np.abs(z).max() < zc, f"{label}: blocks off by up to {np.abs(z).max():.1f} standard errors"
