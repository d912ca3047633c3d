"""Mechanical halves of the material presets: what the simulation core needs to know about a tissue.

Values are small-strain moduli of ex-vivo / in-vivo soft tissue as reported in the literature; each
line cites its source. Soft tissue is strongly non-linear and rate dependent, so these are starting
points for a hyperelastic model at moderate strains, not universal constants.

Sources
-------
- [Samani07] A. Samani, J. Zubovits, D. Plewes, "Elastic moduli of normal and pathological human
  breast tissues", Phys. Med. Biol. 52 (2007) 1565 — fat 3.25 +/- 0.91 kPa.
- [Chen96] E. J. Chen et al., "Young's modulus measurements of soft tissues with application to
  elasticity imaging", IEEE TUFFC 43 (1996) — liver about 0.6–3 kPa range at low strain;
  we take the in-vivo figure of [Yeh02].
- [Yeh02] W.-C. Yeh et al., "Elastic modulus measurements of human liver and correlation with
  pathology", Ultrasound Med. Biol. 28 (2002) 467 — normal liver 0.6–1.7 kPa at 1 %, rising to
  about 4–6 kPa at 10–15 % strain (we use 4.6 kPa for the moderate strains of probing).
- [Bensamoun08] kidney cortex shear moduli 1.5–2.5 kPa by MR elastography
  (Bensamoun et al., J. Magn. Reson. Imaging 28 (2008) 1287); E = 3 mu ~ 6 kPa.
- [Christensen15] M. B. Christensen et al., "Viscoelastic properties of intact porcine colon",
  J. Mech. Behav. Biomed. Mater. (2015) — low-strain colon wall modulus of tens of kPa.
- [Stecco11] C. Stecco et al., "The fascia: the forgotten structure", Ital. J. Anat. Embryol. 116
  (2011) — deep fascia is collagen-rich and two to three orders stiffer than parenchyma; we cap
  it at 200 kPa so scenes stay well conditioned.
- [Duck90] F. A. Duck, "Physical properties of tissue" (Academic Press, 1990) — densities:
  liver 1060, kidney 1050, fat 916–950, colon/muscle ~1040 kg/m^3.
- [Zhang17] J. Zhang thesis (seeds/000), §5.3: E = 3000 Pa, nu = 0.49 for the cylinder and cube
  benchmarks, viscoelastic alpha1 = 0.5, tau1 = 0.58 s.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Mechanics:
    """Mechanical parameters of one tissue.

    Attributes
    ----------
    E : Young's modulus [Pa], typical soft tissue 1e3–1e5.
    nu : Poisson ratio, 0 <= nu < 0.5 (soft tissue 0.45–0.49: nearly incompressible).
    density : mass density [kg/m^3].
    constitutive : constitutive model name (see ``sim.constitutive.MODEL_CODES``).
    fibre : unit fibre direction for anisotropic models, or ``None``.
    prony : Prony series terms ``((alpha_i, tau_i [s]), ...)``; empty for purely elastic tissue.
    """

    E: float
    nu: float
    density: float
    constitutive: str = "stable_neo_hookean"
    fibre: tuple[float, float, float] | None = None
    prony: tuple[tuple[float, float], ...] = field(default_factory=tuple)

    @property
    def viscoelastic(self) -> bool:
        return len(self.prony) > 0


MECHANICS: dict[str, Mechanics] = {
    # [Yeh02] moderate-strain modulus; [Duck90] density.
    "liver": Mechanics(E=4600.0, nu=0.47, density=1060.0),
    # [Bensamoun08] mu ~ 2 kPa -> E ~ 6 kPa; [Duck90] density.
    "kidney": Mechanics(E=6000.0, nu=0.47, density=1050.0),
    # gallbladder wall: thin muscular wall; modelled like the colon wall [Christensen15] (design value).
    "gallbladder": Mechanics(E=20000.0, nu=0.45, density=1040.0),
    # [Christensen15] colon wall; viscoelastic relaxation of the order of a second ([Zhang17] form).
    "colon_mucosa": Mechanics(E=20000.0, nu=0.45, density=1040.0, prony=((0.5, 0.58),)),
    # small bowel wall: like the colon wall [Christensen15], with the same relaxation form ([Zhang17]).
    "small_bowel": Mechanics(E=15000.0, nu=0.45, density=1040.0, prony=((0.5, 0.58),)),
    # [Samani07] fat 3.25 kPa; [Duck90] 916-950 kg/m^3.
    "fat": Mechanics(E=3250.0, nu=0.49, density=930.0),
    # [Stecco11] fibrous sheet, fibres in-plane (x); capped at 200 kPa.
    "fascia": Mechanics(
        E=200000.0, nu=0.45, density=1100.0, constitutive="anisotropic_neo_hookean", fibre=(1.0, 0.0, 0.0)
    ),
    # thin serous membrane over organs; modelled like a stiffened connective layer.
    "peritoneum": Mechanics(E=30000.0, nu=0.45, density=1050.0),
    # vessel wall: 0.1-1 MPa at physiological strain (Humphrey, Cardiovascular Solid Mechanics, 2002);
    # capped at 200 kPa like fascia so scenes stay well conditioned; blood-filled: [Duck90] ~1060.
    "vessels": Mechanics(E=200000.0, nu=0.45, density=1060.0),
    # The [Zhang17] benchmark material, paired with the plain reference optics.
    "plastic": Mechanics(E=3000.0, nu=0.49, density=1000.0, constitutive="neo_hookean"),
}
