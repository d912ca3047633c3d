"""Optical halves of the material presets: what the renderer needs to know about a tissue.

The theses give no optical constants (docs/design.md, "Qian §6.2.3: optical constants"); these are
design choices taken from the tissue-optics literature, each cited:

- [Jacques13] S. L. Jacques, "Optical properties of biological tissues: a review", Phys. Med. Biol.
  58 (2013) R37. Reduced scattering mu_s'(lambda) = a (lambda / 500 nm)^-b with, for soft tissue,
  a ~ 1–2.5 /mm, b ~ 1–1.5; absorption dominated by blood (strong at 420 and 540–580 nm, weak
  above 600 nm), so red light penetrates millimetres and green/blue far less.
- [Bashkatov05] A. N. Bashkatov et al., "Optical properties of human skin, subcutaneous and mucous
  tissues in the wavelength range from 400 to 2000 nm", J. Phys. D 38 (2005) 2543 — mucosa and
  fat: mu_a and mu_s' in the visible.
- [Germer98]/[Duck90] tissue refractive index n ~ 1.38–1.41 (F. A. Duck, Physical Properties of
  Tissue, 1990): Fresnel F0 = ((n - 1)/(n + 1))^2 ~ 0.027; a wet mucus film (n ~ 1.33–1.35) gives a
  smooth clear-coat reflection.
- Colours: linear-sRGB diffuse reflectance estimated from published in-vivo laparoscopic and
  ex-vivo reflectance spectra (liver dark red-brown, kidney red-brown, colon mucosa pink, fat
  yellow, fascia and peritoneum whitish pink), cf. Zonios et al., Appl. Opt. 38 (1999) 6628 (colon
  mucosa reflectance) and [Bashkatov05].

``sigma`` is an effective attenuation 1/m per RGB channel, mu_eff = sqrt(3 mu_a (mu_a + mu_s'))
with the [Jacques13] / [Bashkatov05] values at about 620, 550 and 460 nm. It drives the thickness
term C exp(-sigma T) of Qian eq. 6.8.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from materials.textures import bake_layer


@dataclass(frozen=True)
class MucosaLayers:
    """The four layers of a mucosa (Qian §6.2.3, Figs. 6.8–6.9), top to bottom:

    1. epithelium + mucus: a smooth dielectric clear coat (GGX, ``coat_roughness``, ``coat_ior``) of
       thickness ``coat_thickness`` [m] with absorption ``coat_absorption`` [1/m] per RGB channel;
    2. granular layer: a rougher specular lobe (``granular_roughness``) taking ``granular_weight`` of
       the light that reaches it;
    3. connective tissue (lamina propria): diffuse ``connective_colour``, thickness
       ``connective_thickness`` [m] and absorption ``connective_absorption`` [1/m];
    4. submucosa (vessels): diffuse ``submucosa_colour`` under it.

    Layers combine through transmittance (``tissuerender.renderer.bsdf.mucosa``), so
    the stack never reflects more than arrives (white-furnace test).
    """

    coat_roughness: float = 0.06
    coat_ior: float = 1.34
    coat_thickness: float = 150e-6
    coat_absorption: tuple[float, float, float] = (5.0, 8.0, 15.0)
    granular_weight: float = 0.04
    granular_roughness: float = 0.35
    connective_colour: tuple[float, float, float] = (0.70, 0.36, 0.32)
    connective_thickness: float = 400e-6
    connective_absorption: tuple[float, float, float] = (250.0, 900.0, 1300.0)
    submucosa_colour: tuple[float, float, float] = (0.45, 0.10, 0.09)
    texture_seed: int | None = None  # bake a procedural mucosa texture (materials.textures) when set
    texture_period: float = 0.03  # size of one texture tile in UV units (metres on procedural bodies) 
    texture_size: int = 256
    vessel_density: float = 1.2
    bump: float = 0.004  # relief height, in texture widths (0.004 x 3 cm = 0.12 mm)

    def baked_albedo(self):
        """(size, size, 3) base albedo texture: the connective-tissue mottle between the submucosa and
        connective colours, darkened by vessels; its mean stays near ``base_albedo``."""
        return _bake(self)[0]

    def baked_normal(self):
        """(size, size, 3) tangent-space normals of the same bake (the mucosa's fine relief)."""
        return _bake(self)[1]

    def baked_roughness_factor(self):
        """(size, size) roughness map of the same bake as a factor on the preset's roughness (0.7 ... 1.3,
        following the mottle): it scales the tissue's GGX alpha and the granular layer's, not the smooth
        mucus coat."""
        return _bake(self)[2]

    @property
    def base_albedo(self) -> tuple[float, float, float]:
        """Diffuse albedo of layers 3-4: the connective layer reflects ``c3 (1 - e)``, the submucosa
        ``c4 e`` with ``e = exp(-2 sigma_3 d_3)`` the round trip through the connective layer."""
        out = []
        for c3, c4, s3 in zip(self.connective_colour, self.submucosa_colour, self.connective_absorption):
            e = pow(2.718281828459045, -2.0 * s3 * self.connective_thickness)
            out.append(c3 * (1.0 - e) + c4 * e)
        return tuple(out)


@functools.lru_cache(maxsize=8)
def _bake(layers: MucosaLayers):
    base = np.asarray(layers.base_albedo)
    palette = np.stack([np.asarray(layers.submucosa_colour), base, np.asarray(layers.connective_colour)])
    nominal = 0.3
    baked = bake_layer(layers.texture_size, palette, nominal, layers.texture_seed, vessel_density=layers.vessel_density,
                       bump=layers.bump)
    rough = baked.roughness / nominal
    rough.setflags(write=False)
    albedo = baked.albedo * (base / np.maximum(baked.albedo.reshape(-1, 3).mean(axis=0), 1e-6))
    albedo = np.clip(albedo, 0.0, 1.0)
    albedo.setflags(write=False)
    baked.normal.setflags(write=False)
    return albedo, baked.normal, rough


# Colon mucosa layers. Mucus: mostly water, n = 1.33–1.35 (Hale & Querry 1973 for water; mucins add
# little), adherent gel 100–800 um thick in the colon (Atuma et al., Am. J. Physiol. 280 (2001) G922),
# nearly transparent in the visible (water mu_a < 0.01/mm; a little scattering from mucins: a few /m
# here). Connective tissue / lamina propria and submucosa: mu_a, mu_s' from [Bashkatov05] (mucosa) and
# blood-rich submucosa [Jacques13]; layer thickness ~0.3–0.5 mm for the colonic mucosa (histology
# texts, e.g. Ross & Pawlina). The coat roughness and granular weight are design choices (wet, glossy
# highlights; a faint broad sheen from the granular layer).
COLON_LAYERS = MucosaLayers(texture_seed=11)


@dataclass(frozen=True)
class OpticalMaterial:
    """Diffuse albedo (linear RGB), GGX roughness alpha, tissue index of refraction, subsurface weight
    ``k_sss`` (Qian eq. 6.5), effective attenuation ``sigma`` [1/m] per channel and the subsurface
    colour ``sss_colour`` (C of Qian eq. 6.8, as an albedo so C = sss_colour / pi)."""

    albedo: tuple[float, float, float]
    roughness: float
    ior: float = 1.40
    k_sss: float = 0.3
    sigma: tuple[float, float, float] = (400.0, 1500.0, 2500.0)
    sss_colour: tuple[float, float, float] = (0.8, 0.25, 0.2)
    layers: MucosaLayers | None = None
    bsdf: str = "tissue"  # "tissue" (Cook-Torrance + SSS, optional layers) | "roughplastic" (Mitsuba's model)

    @property
    def diffuse_albedo(self) -> tuple[float, float, float]:
        """The Lambert albedo the renderer uses: the layer stack's base for layered materials."""
        return self.layers.base_albedo if self.layers is not None else self.albedo

    @property
    def f0(self) -> float:
        return ((self.ior - 1.0) / (self.ior + 1.0)) ** 2


OPTICS: dict[str, OpticalMaterial] = {
    # Liver: strongly absorbing (blood-rich); mu_a(620) ~ 0.3/mm, mu_s' ~ 0.8/mm -> mu_eff ~ 0.95/mm.
    "liver": OpticalMaterial(albedo=(0.40, 0.09, 0.07), roughness=0.35, ior=1.39, k_sss=0.25,
                             sigma=(950.0, 3500.0, 4500.0), sss_colour=(0.7, 0.12, 0.08)),
    # Kidney: similar perfusion, slightly lighter [Jacques13].
    "kidney": OpticalMaterial(albedo=(0.45, 0.13, 0.10), roughness=0.35, ior=1.39, k_sss=0.3,
                              sigma=(800.0, 3000.0, 4000.0), sss_colour=(0.75, 0.15, 0.1)),
    # Colon mucosa: wet, glossy, pink; mu_s' ~ 1.5/mm, mu_a(620) ~ 0.05/mm [Bashkatov05] -> 0.5/mm red.
    "colon_mucosa": OpticalMaterial(albedo=(0.62, 0.28, 0.24), roughness=0.18, ior=1.35, k_sss=0.4,
                                    sigma=(500.0, 1800.0, 2600.0), sss_colour=(0.85, 0.3, 0.25),
                                    layers=COLON_LAYERS),
    # Fat: weakly absorbing, strongly scattering; mu_a ~ 0.01/mm, mu_s' ~ 1.2/mm [Bashkatov05].
    "fat": OpticalMaterial(albedo=(0.78, 0.65, 0.38), roughness=0.45, ior=1.46, k_sss=0.5,
                           sigma=(190.0, 260.0, 420.0), sss_colour=(0.9, 0.75, 0.45)),
    # Fascia: collagen sheet, high scattering, little blood.
    "fascia": OpticalMaterial(albedo=(0.75, 0.68, 0.63), roughness=0.40, ior=1.41, k_sss=0.35,
                              sigma=(300.0, 450.0, 600.0), sss_colour=(0.85, 0.7, 0.65)),
    # Peritoneum: thin translucent serosa over perfused tissue.
    "peritoneum": OpticalMaterial(albedo=(0.62, 0.40, 0.36), roughness=0.28, ior=1.38, k_sss=0.4,
                                  sigma=(400.0, 1200.0, 1800.0), sss_colour=(0.8, 0.4, 0.35)),
    # The plain reference: Mitsuba 3's roughplastic (GGX coat, polypropylene n = 1.49) over a grey
    # Lambertian base, no subsurface term (tissuerender.renderer.bsdf.plastic).
    "plastic": OpticalMaterial(albedo=(0.55, 0.55, 0.58), roughness=0.25, ior=1.49, k_sss=0.0,
                               sigma=(1.0, 1.0, 1.0), sss_colour=(0.0, 0.0, 0.0), bsdf="roughplastic"),
}


# The optical keys a scene (``[objects.optics]``) or ``tissuerender lookdev --set`` may override.
OVERRIDABLE = ("albedo", "roughness", "ior", "k_sss", "sigma", "sss_colour")


def with_overrides(optics: OpticalMaterial, overrides: dict) -> OpticalMaterial:
    """``optics`` with some of its :data:`OVERRIDABLE` values replaced (tuples for the RGB ones).

    Raises ``ValueError`` naming the key for a value the material does not use: a layered material's
    diffuse colour comes from its layer stack (``albedo`` would be ignored), and the ``roughplastic``
    reference has no subsurface term (``k_sss``, ``sigma``, ``sss_colour``). Ranges are the scene
    schema's business (``tissuerender.scene.schema.OpticsOverride``)."""
    unknown = sorted(set(overrides) - set(OVERRIDABLE))
    if unknown:
        raise ValueError(f"{unknown[0]}: not an optical key; expected one of {', '.join(OVERRIDABLE)}")
    if optics.layers is not None and "albedo" in overrides:
        raise ValueError("albedo: a layered (mucosa) material takes its diffuse colour from its layer stack; "
                         "override roughness, ior or the subsurface keys instead")
    if optics.bsdf == "roughplastic":
        for key in ("k_sss", "sigma", "sss_colour"):
            if key in overrides:
                raise ValueError(f"{key}: the plastic reference (roughplastic) has no subsurface term")
    values = {k: tuple(float(c) for c in v) if isinstance(v, (list, tuple)) else float(v) for k, v in overrides.items()}
    return dataclasses.replace(optics, **values)
