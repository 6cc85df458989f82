"""The Light Falloff node's effect on lights (engine/lights/common.py
Falloff, Cycles' svm_node_light_falloff): the emission of a sample at
distance t is scaled by t (Linear) or t^2 (Constant), and by t^2 / (smooth +
t^2) where smooth > 0, in NEE and in what BSDF rays hit alike.

A delta point light over a plane gives its irradiance exactly (samples at
pixel centres); a sphere light, whose samples lie at varying distances,
is checked for every strategy (NEE, BSDF, MIS) against a quadrature of the
falloff over its visible cone, independent of the sampling code."""
import numpy as np
import pytest

from analytic import analytic_scene, check_against, pixel_centres
from engine.render import render
from engine.scene import AreaLight, PointLight, RenderSettings

FALLOFF_POWER = {"QUADRATIC": 0, "LINEAR": 1, "CONSTANT": 2}


def factor(t, kind, smooth):
    """Cycles' Light Falloff node at ray length t."""
    f = t ** FALLOFF_POWER[kind]
    return f * t * t / (smooth + t * t) if smooth > 0 else f


@pytest.mark.parametrize("kind, smooth", [("LINEAR", 0.0), ("CONSTANT", 0.0), ("QUADRATIC", 0.5),
                                          ("LINEAR", 2.0)])
def test_point_light_falloff_on_a_plane(kind, smooth):
    """A radius-0 point light of power P at height h: irradiance
    P / (4 pi) cos / D^2 times the falloff at D, e.g. P h / (4 pi D^2) with
    Linear falloff (strength * d / d^2, with d / D the cosine)."""
    P, h = 40.0, 1.0
    light = PointLight((0, 0, h), (P, P, P), radius=0.0, falloff=kind, falloff_smooth=smooth)
    scene, rho = analytic_scene(light)
    r = render(scene, RenderSettings(samples=2, samples_per_pass=2, filter_type="BOX", filter_width=1e-6))
    x, y = pixel_centres(40, 4.0)
    D = np.sqrt(x * x + y * y + h * h)
    expected = rho / np.pi * P / (4 * np.pi) * (h / D) / D ** 2 * factor(D, kind, smooth)
    np.testing.assert_allclose(r.image[..., 0], expected, rtol=2e-5, atol=1e-7)


def sphere_irradiance(rho_xy, h, r, L, kind, smooth, n_u=2048, n_phi=96):
    """Irradiance on the plane z = 0 at radial offsets rho_xy from a sphere
    light (centre height h, radius r, radiance L) with falloff, by midpoint
    quadrature over its visible cone (u = cos of the angle to the axis)."""
    out = np.empty(len(rho_xy))
    k = (np.arange(n_u) + 0.5) / n_u
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    for i, s in enumerate(rho_xy):
        c = np.array([-s, 0.0, h])                     # light centre seen from the point (s, 0, 0)
        D = np.linalg.norm(c)
        a = c / D
        e1 = np.array([a[2], 0.0, -a[0]])              # perpendicular to a, in the xz plane
        e2 = np.array([0.0, 1.0, 0.0])
        cos_max = np.sqrt(1.0 - r * r / (D * D))
        u = cos_max + (1.0 - cos_max) * k
        sin = np.sqrt(1.0 - u * u)
        t = D * u - np.sqrt(np.maximum(0.0, r * r - D * D * (1.0 - u * u)))
        wz = sin[:, None] * (np.cos(phi)[None, :] * e1[2]) + u[:, None] * a[2]
        du, dphi = (1.0 - cos_max) / n_u, 2 * np.pi / n_phi
        out[i] = L * (factor(t, kind, smooth)[:, None] * np.maximum(wz, 0.0)).sum() * du * dphi
    return out


@pytest.mark.parametrize("strategy", ["mis", "light", "bsdf"])
def test_sphere_light_falloff_every_strategy(strategy):
    """Linear falloff with Smooth on a sphere light close to the plane: NEE
    alone, BSDF sampling alone and MIS render the quadrature's image, so
    both sides of MIS see the same falloff."""
    r_light, h, P, kind, smooth = 0.4, 1.0, 30.0, "LINEAR", 0.3
    light = PointLight((0, 0, h), (P, P, P), radius=r_light, falloff=kind, falloff_smooth=smooth)
    scene, rho = analytic_scene(light)
    r, radial, unique, back = render_plane(scene, strategy, seed=13)
    L = P / (4 * np.pi ** 2 * r_light ** 2)
    expected = rho / np.pi * sphere_irradiance(unique, h, r_light, L, kind, smooth)[back].reshape(radial.shape)
    check_against(r, expected, radial > r_light + 0.15, f"sphere light, {kind} falloff ({strategy})")


def render_plane(scene, strategy, seed):
    """The plane under the light (box filter at pixel centres), each
    pixel's distance from the point below the light, and those distances
    once each (``unique[back]`` is ``radial``)."""
    spp = 1024 if strategy == "bsdf" else 64
    r = render(scene, RenderSettings(samples=spp, samples_per_pass=spp, seed=seed, strategy=strategy,
                                     filter_type="BOX", filter_width=1e-3))
    x, y = pixel_centres(40, 4.0)
    radial = np.hypot(x, y)
    unique, back = np.unique(np.round(radial, 12), return_inverse=True)
    return r, radial, unique, back


def test_quadrature_is_the_sphere_formula():
    """The quadrature itself: without falloff it gives a sphere light's
    closed form P / (4 pi) h / D^3 (the cone above the horizon)."""
    r_light, h, P = 0.3, 1.0, 30.0
    s = np.array([0.0, 0.5, 1.0])
    L = P / (4 * np.pi ** 2 * r_light ** 2)
    D = np.hypot(s, h)
    np.testing.assert_allclose(sphere_irradiance(s, h, r_light, L, "QUADRATIC", 0.0),
                               P / (4 * np.pi) * h / D ** 3, rtol=2e-4)


@pytest.mark.parametrize("strategy", ["light", "bsdf"])
def test_area_light_constant_falloff(strategy):
    """A disk light with Constant falloff over the plane: its radiance
    times t^2 cancels the 1/t^2 of the solid angle, so the irradiance is
    L times the integral of cos_l cos_r over the disk's area, by quadrature
    in polar coordinates about the point below its centre."""
    R, h, P = 0.5, 1.0, 20.0
    m = np.eye(4)
    m[:3, 3] = (0, 0, h)
    scene, rho = analytic_scene(AreaLight(m, (P, P, P), "DISK", 2 * R, falloff="CONSTANT"))
    r, radial, unique, back = render_plane(scene, strategy, seed=17)
    L = P / (np.pi * np.pi * R * R)
    k = (np.arange(512) + 0.5) / 512
    rr, ph = R * np.sqrt(k)[:, None], (k * 2 * np.pi)[None, :]   # uniform in area: dA = pi R^2 / n^2
    E = []
    for s in unique:
        qx, qy = rr * np.cos(ph) - s, rr * np.sin(ph)
        t2 = qx * qx + qy * qy + h * h
        E.append(L * (h * h / t2).sum() * np.pi * R * R / k.size ** 2)   # cos_l cos_r / t^2 * t^2
    expected = rho / np.pi * np.array(E)[back].reshape(radial.shape)
    check_against(r, expected, np.ones_like(expected, bool), f"disk light, Constant falloff ({strategy})")
