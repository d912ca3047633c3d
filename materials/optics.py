"""Optical halves of the material presets: what the renderer needs to know about a tissue.

The theses give no optical constants (DESIGN.md); these are design choices taken from the tissue-
optics literature, each cited:

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

from dataclasses import dataclass


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
                                    sigma=(500.0, 1800.0, 2600.0), sss_colour=(0.85, 0.3, 0.25)),
    # Fat: weakly absorbing, strongly scattering; mu_a ~ 0.01/mm, mu_s' ~ 1.2/mm [Bashkatov05].
    "fat": OpticalMaterial(albedo=(0.78, 0.65, 0.38), roughness=0.45, ior=1.46, k_sss=0.5,
                           sigma=(190.0, 260.0, 420.0), sss_colour=(0.9, 0.75, 0.45)),
    # Fascia: collagen sheet, high scattering, little blood.
    "fascia": OpticalMaterial(albedo=(0.75, 0.68, 0.63), roughness=0.40, ior=1.41, k_sss=0.35,
                              sigma=(300.0, 450.0, 600.0), sss_colour=(0.85, 0.7, 0.65)),
    # Peritoneum: thin translucent serosa over perfused tissue.
    "peritoneum": OpticalMaterial(albedo=(0.62, 0.40, 0.36), roughness=0.28, ior=1.38, k_sss=0.4,
                                  sigma=(400.0, 1200.0, 1800.0), sss_colour=(0.8, 0.4, 0.35)),
    # The plain reference: a grey dielectric (n = 1.5), no subsurface term.
    "plastic": OpticalMaterial(albedo=(0.55, 0.55, 0.58), roughness=0.25, ior=1.5, k_sss=0.0,
                               sigma=(1.0, 1.0, 1.0), sss_colour=(0.0, 0.0, 0.0)),
}
