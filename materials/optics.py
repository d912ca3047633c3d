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

from materials.patterns import PATTERNS, pattern
from materials.textures import normal_map


@dataclass(frozen=True)
class TissueLayers:
    """The layers of a wet tissue, after the four of a mucosa (Qian §6.2.3, Figs. 6.8–6.9), top to bottom:

    1. epithelium + mucus: a smooth dielectric clear coat (GGX, ``coat_roughness``, ``coat_ior``) of
       thickness ``coat_thickness`` [m] with absorption ``coat_absorption`` [1/m] per RGB channel;
    2. granular layer: a rougher specular lobe (``granular_roughness``) taking ``granular_weight`` of
       the light that reaches it;
    3. connective tissue (lamina propria): diffuse ``connective_colour``, thickness
       ``connective_thickness`` [m] and absorption ``connective_absorption`` [1/m];
    4. submucosa (vessels): diffuse ``submucosa_colour`` under it.

    Layers 3 and 4 each have their own subsurface colour (``connective_sss_colour``, ``submucosa_sss_colour``,
    linear RGB) and thickness-term attenuation (``connective_sigma``, ``submucosa_sigma`` [1/m] per channel); None
    (the default) takes the material's ``sss_colour`` / ``sigma``, so a preset that sets none renders exactly as a
    single-layer subsurface term. How they combine: :meth:`OpticalMaterial.subsurface_colour` and
    :meth:`OpticalMaterial.subsurface_attenuation` (docs/renderer.md, "Per-layer subsurface colour").

    Layers combine through the coat's albedo (``tissuerender.renderer.bsdf.mucosa``, derivation there), so
    the stack returns what arrives in a white furnace and less with absorption. ``pattern`` names the
    procedural texture (``materials.patterns``: lobules, folds, fibres, vessel trees) baked once per material.
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
    connective_sss_colour: tuple[float, float, float] | None = None  # None: the material's sss_colour
    connective_sigma: tuple[float, float, float] | None = None  # None: the material's sigma [1/m]
    submucosa_sss_colour: tuple[float, float, float] | None = None
    submucosa_sigma: tuple[float, float, float] | None = None
    texture_seed: int | None = None  # bake a procedural mucosa texture (materials.textures) when set
    texture_period: float = 0.03  # size of one texture tile in UV units (metres on procedural bodies) 
    texture_size: int = 256
    vessel_density: float = 1.2
    bump: float = 0.004  # relief height, in texture widths (0.004 x 3 cm = 0.12 mm)
    pattern: str = "colon_folds"  # materials.patterns.PATTERNS

    def __post_init__(self):
        if self.pattern not in PATTERNS:
            raise ValueError(f"pattern: expected one of {', '.join(PATTERNS)}, found {self.pattern!r}")

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


@functools.lru_cache(maxsize=16)
def _bake(layers: TissueLayers):
    """(albedo, normal, roughness factor) of the layer stack's pattern: the value field through the palette
    (deep colour, base, connective colour), vessels tinting towards the deep colour at half its value
    (haemoglobin absorbs), the mean rescaled to ``base_albedo``; roughness 0.7 ... 1.3 x following the value."""
    base = np.asarray(layers.base_albedo)
    deep = np.asarray(layers.submucosa_colour)
    palette = np.stack([deep, base, np.asarray(layers.connective_colour)])
    pat = pattern(layers.pattern, layers.texture_size, layers.texture_seed, layers.vessel_density)
    stops = np.linspace(0.0, 1.0, palette.shape[0])
    albedo = np.stack([np.interp(pat.value, stops, palette[:, c]) for c in range(3)], axis=-1)
    albedo = albedo * (1.0 - 0.7 * pat.vessels[..., None]) + 0.7 * pat.vessels[..., None] * 0.5 * deep
    albedo = np.clip(albedo * (base / np.maximum(albedo.reshape(-1, 3).mean(axis=0), 1e-6)), 0.0, 1.0)
    rough = np.clip(0.7 + 0.6 * pat.value, 0.7, 1.3)
    normal = normal_map(pat.height, layers.bump)
    for a in (albedo, rough, normal):
        a.setflags(write=False)
    return albedo, normal, rough


MucosaLayers = TissueLayers  # the colon's stack came first; every tissue has one now


# Colon mucosa layers. Mucus: mostly water, n = 1.33–1.35 (Hale & Querry 1973 for water; mucins add
# little), adherent gel 100–800 um thick in the colon (Atuma et al., Am. J. Physiol. 280 (2001) G922),
# nearly transparent in the visible (water mu_a < 0.01/mm; a little scattering from mucins: a few /m
# here). Connective tissue / lamina propria and submucosa: mu_a, mu_s' from [Bashkatov05] (mucosa) and
# blood-rich submucosa [Jacques13]; layer thickness ~0.3–0.5 mm for the colonic mucosa (histology
# texts, e.g. Ross & Pawlina). The coat roughness and granular weight are design choices (wet, glossy
# highlights; a faint broad sheen from the granular layer).
COLON_LAYERS = TissueLayers(texture_seed=11, pattern="colon_folds")


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
    metal_f0: float | None = None  # a metal's Schlick F0 (instead of the dielectric's from ior)

    @property
    def diffuse_albedo(self) -> tuple[float, float, float]:
        """The Lambert albedo the renderer uses: the layer stack's base for layered materials."""
        return self.layers.base_albedo if self.layers is not None else self.albedo

    @property
    def subsurface_colour(self) -> tuple[float, float, float]:
        """The subsurface colour C (as an albedo, C / pi in Qian eq. 6.8) the thickness term uses.

        Unlayered, or with no layer colour set: ``sss_colour``. Layered: the two tissue layers' colours weighted
        like their diffuse colours in ``TissueLayers.base_albedo``, ``c3 (1 - e) + c4 e`` with
        ``e = exp(-2 connective_absorption connective_thickness)`` per channel: the share of the light scattered
        back from below that comes from under the connective layer (a layer of zero thickness: e = 1, its colour
        has no weight)."""
        st = self.layers
        if st is None or (st.connective_sss_colour is None and st.submucosa_sss_colour is None):
            return self.sss_colour
        c3 = st.connective_sss_colour if st.connective_sss_colour is not None else self.sss_colour
        c4 = st.submucosa_sss_colour if st.submucosa_sss_colour is not None else self.sss_colour
        out = []
        for a, b, s3 in zip(c3, c4, st.connective_absorption):
            e = float(np.exp(-2.0 * s3 * st.connective_thickness))
            out.append(a * (1.0 - e) + b * e)
        return tuple(out)

    def subsurface_attenuation(self) -> tuple[tuple[float, float, float], tuple[float, float, float], float]:
        """``(sigma_upper, sigma_deep, depth)`` of the thickness term: along the inward path of length T the
        light crosses the connective layer (``depth`` = its thickness, attenuation ``sigma_upper``) and then the
        deep layer (``sigma_deep``): ``exp(-sigma_upper min(T, depth) - sigma_deep max(T - depth, 0))``
        (:func:`layered_transmittance`). Unlayered, or with neither layer sigma set: ``(sigma, sigma, 0)``,
        which is ``exp(-sigma T)`` to the bit (``min(T, 0) = 0`` and ``sigma_upper 0 = 0`` exactly)."""
        st = self.layers
        if st is None or (st.connective_sigma is None and st.submucosa_sigma is None):
            return self.sigma, self.sigma, 0.0
        upper = st.connective_sigma if st.connective_sigma is not None else self.sigma
        deep = st.submucosa_sigma if st.submucosa_sigma is not None else self.sigma
        return upper, deep, float(st.connective_thickness)

    @property
    def f0(self) -> float:
        if self.metal_f0 is not None:
            return self.metal_f0
        return ((self.ior - 1.0) / (self.ior + 1.0)) ** 2


def layered_transmittance(sigma_upper, sigma_deep, depth, T):
    """``exp(-sigma_upper min(T, depth) - sigma_deep max(T - depth, 0))`` (k, 3) for paths T (k,) [m] through a
    layer of thickness ``depth`` (k,) over a deep one, attenuations (k, 3) [1/m]; an infinite T transmits nothing
    (the thickness rays found no back face: ``tissuerender.renderer.thickness``)."""
    T = np.asarray(T, float)
    finite = np.isfinite(T)
    Tf = np.where(finite, T, 0.0)[:, None]
    d = np.asarray(depth, float)[:, None]
    tau = sigma_upper * np.minimum(Tf, d) + sigma_deep * np.maximum(Tf - d, 0.0)
    return np.where(finite[:, None], np.exp(-tau), 0.0)


def stack_for(albedo, absorption, thickness, pattern, seed, contrast=0.4, **coat) -> TissueLayers:
    """A layer stack whose mean diffuse albedo is ``albedo``: the deep layer ``(1 - y)`` times it, the
    connective layer ``(1 + y e / (1 - e))`` times it (``e = exp(-2 absorption thickness)`` per channel), so
    ``base_albedo = c3 (1 - e) + c4 e = albedo``; ``y = contrast``, less in a channel where the connective
    colour would pass 1."""
    e = np.exp(-2.0 * np.asarray(absorption, float) * thickness)
    a = np.asarray(albedo, float)
    y = np.minimum(contrast, (1.0 / a - 1.0) * (1.0 - e) / e)
    connective = a * (1.0 + y * e / (1.0 - e))
    deep = a * (1.0 - y)
    return TissueLayers(connective_colour=tuple(float(c) for c in connective), connective_thickness=thickness,
                        connective_absorption=tuple(float(c) for c in absorption),
                        submucosa_colour=tuple(float(c) for c in deep), pattern=pattern, texture_seed=seed, **coat)


# Wet coats. Serosa (liver, kidney, gallbladder, bowel outside, peritoneum): a film of serous fluid a few
# to tens of micrometres thick (peritoneal fluid, n ~ 1.335, water-like), smooth: coat_roughness 0.04-0.1
# (design: laparoscopic images show small sharp highlights). Connective absorption: blood-rich parenchyma
# absorbs green and blue within a fraction of a millimetre [Jacques13]; fat and fascia little [Bashkatov05].
SEROUS = dict(coat_ior=1.335, coat_thickness=20e-6, coat_absorption=(2.0, 3.0, 5.0))

OPTICS: dict[str, OpticalMaterial] = {
    # Liver: strongly absorbing (blood-rich); mu_a(620) ~ 0.3/mm, mu_s' ~ 0.8/mm -> mu_eff ~ 0.95/mm.
    # Lobules (1-2 mm, hexagonal) under Glisson's capsule: 16 across a 3 cm tile.
    "liver": OpticalMaterial(albedo=(0.40, 0.09, 0.07), roughness=0.35, ior=1.39, k_sss=0.25,
                             sigma=(950.0, 3500.0, 4500.0), sss_colour=(0.7, 0.12, 0.08),
                             layers=stack_for((0.40, 0.09, 0.07), (1500.0, 4000.0, 5000.0), 300e-6, "liver_lobules", 21,
                                              coat_roughness=0.07, granular_weight=0.03, granular_roughness=0.3,
                                              vessel_density=0.6, **SEROUS)),
    # Kidney: similar perfusion, slightly lighter [Jacques13]; a smooth fibrous capsule with stellate veins.
    "kidney": OpticalMaterial(albedo=(0.45, 0.13, 0.10), roughness=0.35, ior=1.39, k_sss=0.3,
                              sigma=(800.0, 3000.0, 4000.0), sss_colour=(0.75, 0.15, 0.1),
                              layers=stack_for((0.45, 0.13, 0.10), (1200.0, 3500.0, 4500.0), 300e-6, "capsule", 23,
                                               coat_roughness=0.06, granular_weight=0.03, granular_roughness=0.3,
                                               vessel_density=0.8, **SEROUS)),
    # Gallbladder: a thin wall (1-3 mm) over green bile; bile absorbs red and blue (bilirubin/biliverdin),
    # so the wall reads olive green; vessels of the cystic artery on the serosa. Design values.
    "gallbladder": OpticalMaterial(albedo=(0.30, 0.38, 0.20), roughness=0.25, ior=1.38, k_sss=0.45,
                                   sigma=(900.0, 500.0, 1500.0), sss_colour=(0.40, 0.55, 0.25),
                                   layers=stack_for((0.30, 0.38, 0.20), (1200.0, 600.0, 2000.0), 250e-6, "serosa",
                                                    25, coat_roughness=0.04, granular_weight=0.03,
                                                    granular_roughness=0.25, vessel_density=1.0, **SEROUS)),
    # Colon mucosa: wet, glossy, pink; mu_s' ~ 1.5/mm, mu_a(620) ~ 0.05/mm [Bashkatov05] -> 0.5/mm red.
    "colon_mucosa": OpticalMaterial(albedo=COLON_LAYERS.base_albedo, roughness=0.18, ior=1.35, k_sss=0.4,
                                    sigma=(500.0, 1800.0, 2600.0), sss_colour=(0.85, 0.3, 0.25),
                                    layers=COLON_LAYERS),
    # Small bowel mucosa: like the colon's [Bashkatov05], redder and more vascular, with dense circular folds
    # (plicae circulares, ~3-10 mm apart: 8 across a 3 cm tile) and a thicker mucus layer.
    "small_bowel": OpticalMaterial(albedo=(0.64, 0.26, 0.22), roughness=0.2, ior=1.36, k_sss=0.4,
                                   sigma=(550.0, 2000.0, 2800.0), sss_colour=(0.85, 0.28, 0.22),
                                   layers=stack_for((0.64, 0.26, 0.22), (250.0, 900.0, 1300.0), 400e-6, "bowel_folds",
                                                    27, coat_roughness=0.05, coat_ior=1.34, coat_thickness=200e-6,
                                                    coat_absorption=(5.0, 8.0, 15.0), granular_weight=0.05,
                                                    granular_roughness=0.35, vessel_density=1.2)),
    # Fat: weakly absorbing, strongly scattering; mu_a ~ 0.01/mm, mu_s' ~ 1.2/mm [Bashkatov05]. Lobules
    # ~5 mm (6 across a tile) with small vessels in the septa.
    "fat": OpticalMaterial(albedo=(0.78, 0.65, 0.38), roughness=0.45, ior=1.46, k_sss=0.5,
                           sigma=(190.0, 260.0, 420.0), sss_colour=(0.9, 0.75, 0.45),
                           layers=stack_for((0.78, 0.65, 0.38), (200.0, 300.0, 600.0), 500e-6, "fat_lobules", 29,
                                            contrast=0.25, coat_roughness=0.1, granular_weight=0.02,
                                            granular_roughness=0.4, vessel_density=0.8, **SEROUS)),
    # Fascia: collagen sheet, high scattering, little blood; fibres along the sheet.
    "fascia": OpticalMaterial(albedo=(0.75, 0.68, 0.63), roughness=0.40, ior=1.41, k_sss=0.35,
                              sigma=(300.0, 450.0, 600.0), sss_colour=(0.85, 0.7, 0.65),
                              layers=stack_for((0.75, 0.68, 0.63), (300.0, 450.0, 600.0), 300e-6, "fibres", 31,
                                               contrast=0.2, coat_roughness=0.1, granular_weight=0.03,
                                               granular_roughness=0.35, vessel_density=0.4, **SEROUS)),
    # Peritoneum: thin translucent serosa over perfused tissue, fine vessels.
    "peritoneum": OpticalMaterial(albedo=(0.62, 0.40, 0.36), roughness=0.28, ior=1.38, k_sss=0.4,
                                  sigma=(400.0, 1200.0, 1800.0), sss_colour=(0.8, 0.4, 0.35),
                                  layers=stack_for((0.62, 0.40, 0.36), (500.0, 1500.0, 2200.0), 300e-6, "serosa", 33,
                                                   coat_roughness=0.05, granular_weight=0.03,
                                                   granular_roughness=0.3, vessel_density=0.9, **SEROUS)),
    # Vessels (large veins and arteries seen through their wall): blood absorbs strongly below 600 nm
    # (mu_a of whole blood ~ 0.2/mm at 630 nm, > 10/mm at 550 nm [Jacques13]): dark red, longitudinal fibres.
    "vessels": OpticalMaterial(albedo=(0.35, 0.05, 0.06), roughness=0.25, ior=1.39, k_sss=0.3,
                               sigma=(1200.0, 6000.0, 7000.0), sss_colour=(0.6, 0.05, 0.05),
                               layers=stack_for((0.35, 0.05, 0.06), (2000.0, 8000.0, 8000.0), 200e-6, "vessel_wall",
                                                35, coat_roughness=0.05, granular_weight=0.03,
                                                granular_roughness=0.25, vessel_density=0.5, **SEROUS)),
    # The plain reference: Mitsuba 3's roughplastic (GGX coat, polypropylene n = 1.49) over a grey
    # Lambertian base, no subsurface term (tissuerender.renderer.bsdf.plastic).
    "plastic": OpticalMaterial(albedo=(0.55, 0.55, 0.58), roughness=0.25, ior=1.49, k_sss=0.0,
                               sigma=(1.0, 1.0, 1.0), sss_colour=(0.0, 0.0, 0.0), bsdf="roughplastic"),
    # Freshly cut parenchyma (the faces a cut exposes, tissuerender.scene.cut_schema; not a body material): no
    # serosa, blood and tissue fluid on the cut: darker than liver's surface (exposed, blood-filled sinusoids
    # absorb green and blue [Jacques13]) and wet (a smooth liquid film: low roughness, water-like IOR). Design values.
    "tissue_cut": OpticalMaterial(albedo=(0.15, 0.025, 0.02), roughness=0.12, ior=1.36, k_sss=0.3,
                                  sigma=(1000.0, 4000.0, 5000.0), sss_colour=(0.4, 0.04, 0.03)),
    # Instruments (tools only, not a body material): stainless steel as the tissue BSDF's GGX lobe with
    # Schlick F0 = 0.533, the conductor reflectance of n + ik = 2.9 + 3.1i at normal incidence
    # (tissuerender.instruments.STEEL_F0), no diffuse or subsurface light; brushed: roughness 0.2.
    "steel": OpticalMaterial(albedo=(0.0, 0.0, 0.0), roughness=0.2, ior=1.5, k_sss=0.0, sigma=(1.0, 1.0, 1.0),
                             sss_colour=(0.0, 0.0, 0.0),
                             metal_f0=((2.9 - 1.0) ** 2 + 3.1 ** 2) / ((2.9 + 1.0) ** 2 + 3.1 ** 2)),
}


# The optical keys a scene (``[objects.optics]``) or ``tissuerender lookdev --set`` may override: the
# material's own, then its layer stack's (``TissueLayers``; RGB ones as lists).
MATERIAL_KEYS = ("albedo", "roughness", "ior", "k_sss", "sigma", "sss_colour")
LAYER_KEYS = ("coat_roughness", "coat_ior", "coat_thickness", "coat_absorption", "granular_weight",
              "granular_roughness", "connective_colour", "connective_thickness", "connective_absorption",
              "submucosa_colour", "connective_sss_colour", "connective_sigma", "submucosa_sss_colour",
              "submucosa_sigma", "vessel_density", "bump")
# layer keys whose None means "the material's own value" (optical_value reports that value)
LAYER_DEFAULTS = {"connective_sss_colour": "sss_colour", "submucosa_sss_colour": "sss_colour",
                  "connective_sigma": "sigma", "submucosa_sigma": "sigma"}
OVERRIDABLE = MATERIAL_KEYS + LAYER_KEYS


def optical_value(optics: OpticalMaterial, key: str):
    """The material's value of an :data:`OVERRIDABLE` key (None for a layer key of an unlayered material)."""
    if key in LAYER_KEYS:
        if optics.layers is None:
            return None
        value = getattr(optics.layers, key)
        return getattr(optics, LAYER_DEFAULTS[key]) if value is None and key in LAYER_DEFAULTS else value
    return optics.diffuse_albedo if key == "albedo" else getattr(optics, key)


def with_overrides(optics: OpticalMaterial, overrides: dict) -> OpticalMaterial:
    """``optics`` with some of its :data:`OVERRIDABLE` values replaced (tuples for the RGB ones).

    On a layered material ``albedo`` scales both tissue layers' colours (connective and deep) per channel so
    that the stack's diffuse albedo becomes ``albedo`` (colours clipped at 1); the texture keeps its
    pattern, contrast, vessels and relief, and the preset's own albedo changes nothing.
    Raises ``ValueError`` naming the key for a value the material does not use: the ``roughplastic``
    reference has no subsurface term (``k_sss``, ``sigma``, ``sss_colour``) and no layers. Ranges are the
    scene schema's business (``tissuerender.scene.optics_schema``)."""
    unknown = sorted(set(overrides) - set(OVERRIDABLE))
    if unknown:
        raise ValueError(f"{unknown[0]}: not an optical key; expected one of {', '.join(OVERRIDABLE)}")
    if optics.bsdf == "roughplastic":
        for key in ("k_sss", "sigma", "sss_colour"):
            if key in overrides:
                raise ValueError(f"{key}: the plastic reference (roughplastic) has no subsurface term")
    if optics.layers is None:
        for key in LAYER_KEYS:
            if key in overrides:
                raise ValueError(f"{key}: a layer key, and this material has no layer stack (no wet coat)")
    values = {k: tuple(float(c) for c in v) if isinstance(v, (list, tuple)) else float(v) for k, v in overrides.items()}
    layer_values = {k: values.pop(k) for k in LAYER_KEYS if k in values}
    if optics.layers is not None and "albedo" in values:
        # both tissue layers' colours scaled per channel by albedo / base_albedo: base_albedo is linear in
        # them, so it becomes ``albedo`` (unless a colour clips at 1) and the preset's own value changes nothing
        st = dataclasses.replace(optics.layers, **layer_values)
        base = np.asarray(st.base_albedo)
        target = np.asarray(values["albedo"])
        scale = np.where(base > 0.0, target / np.where(base > 0.0, base, 1.0), 1.0)
        # base_albedo's few operations round by a few ulps: a scale within 1e-12 of 1 is the preset's value
        scale = np.where(np.abs(scale - 1.0) < 1e-12, 1.0, scale)
        for key in ("connective_colour", "submucosa_colour"):
            colour = np.asarray(getattr(st, key))
            scaled = np.where(base > 0.0, colour * scale, target)
            layer_values[key] = tuple(float(c) for c in np.minimum(scaled, 1.0))
    if layer_values:
        values["layers"] = dataclasses.replace(optics.layers, **layer_values)
    return dataclasses.replace(optics, **values)


def untextured(optics: OpticalMaterial) -> OpticalMaterial:
    """``optics`` without its baked texture (uniform ``base_albedo``, no relief, no roughness map): the layer
    stack's BSDF alone, e.g. to check shading against closed forms."""
    if optics.layers is None or optics.layers.texture_seed is None:
        return optics
    return dataclasses.replace(optics, layers=dataclasses.replace(optics.layers, texture_seed=None))
