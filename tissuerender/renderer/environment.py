"""Light from the environment: the wet mucus coat's reflection of a spherical-harmonics gradient
environment (Qian §7.2.2), and a uniform ambient environment, optionally times the ambient occlusion.
"""
from __future__ import annotations

import numpy as np

from tissuerender.renderer import sh
from tissuerender.renderer.bsdf.microfacet import dielectric_F
from tissuerender.renderer.light import radical_inverse


def tangent_frames(n: np.ndarray):
    """Two unit tangents (t, b) per unit normal, a right-handed frame (t, b, n) (Duff et al. 2017)."""
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    bt = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, bt


def ambient_occlusion(bvh, pos: np.ndarray, n: np.ndarray, samples: int, distance: float, eps: float,
                      seed: int) -> np.ndarray:
    """Cosine-weighted visibility of the hemisphere within ``distance``: the fraction of a uniform
    environment's irradiance that reaches each point (1 in the open, 1/2 in a right-angled corner).
    Directions are a stratified Hammersley set on the cosine-weighted hemisphere, rotated per point
    (Cranley-Patterson) with a seeded generator."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xA0]))
    rotation = rng.random((pos.shape[0], 2))
    t, b = tangent_frames(n)
    visible = np.zeros(pos.shape[0])
    origin = pos + eps * n
    for s in range(samples):
        u1 = np.mod((s + 0.5) / samples + rotation[:, 0], 1.0)
        u2 = np.mod(radical_inverse(np.full(pos.shape[0], s)) + rotation[:, 1], 1.0)
        r, phi = np.sqrt(u1), 2.0 * np.pi * u2
        local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u1, 0.0))], axis=1)
        d = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:] * n
        visible += ~bvh.occluded(origin, origin + distance * d)
    return visible / samples


def mucus_reflection(points, settings, radiance) -> None:
    """Add the mucus coat's reflection of the gradient environment to the layered points' ``radiance``:
    coat Fresnel times the environment in the mirror direction, blurred by the coat's roughness."""
    layers = points.layers
    idx = np.flatnonzero(layers["mask"])
    n, wo = points.normal[idx], points.wo[idx]
    env = sh.gradient_environment(settings.environment_up, settings.environment_down, settings.environment_axis)
    nv = np.clip(np.einsum("ij,ij->i", n, wo), 0.0, 1.0)
    mirror = 2.0 * nv[:, None] * n - wo
    reflected = sh.evaluate(env, mirror, layers["coat_alpha"][idx])
    fresnel = dielectric_F(nv, layers["coat_ior"][idx])
    radiance[idx] += fresnel[:, None] * np.maximum(reflected, 0.0)


def ambient_light(points, ambient, visibility, radiance) -> None:
    """A uniform environment L_a on a Lambertian surface: int (albedo / pi) L_a cos dw = albedo L_a, times
    the cosine-weighted ``visibility`` (1 without ambient occlusion), added to ``radiance``."""
    radiance += points.albedo * ambient[None, :] * visibility[:, None]
