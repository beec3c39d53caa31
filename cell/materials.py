"""A part's mass: its "mass_g" key, else its volume times the density of its "material" key, else aluminium.

Scene and assembly files carry both as free keys of a part (the parts library writes both). "mass_g", when
given, is the mass and wins; it must be a positive finite number (`check_mass_keys` refuses the rest when a
file is read, `cell.scene.parse_part`). "material" is read for the mass only when there is no "mass_g", and
only for the part being weighed (the target). It is a free description (CONTRACT.md does not name it): a name
of `DENSITY_G_CM3` in any case and spelling ("Stainless Steel 304", "FR-4", "steel, galvanised"), else
aluminium, with a warning that says so and asks for "mass_g" (a scene with "material": "PLA" was refused
whole, exit 2). Neither key: aluminium.
"""

from __future__ import annotations

import logging
import re

from cell.errors import BadInput
from cell.fileio import is_finite_number, short_repr

log = logging.getLogger(__name__)
_WARNED: set[tuple[str, str]] = set()

# g/cm3. The parts library's materials (steel, aluminium, brass, plastic, fr4) with its values, a few common
# others, and the simulated camera's names (`cell.vision.simcamera.MATERIALS`: *_plastic, pcb_green)
DENSITY_G_CM3 = {
    "steel": 7.85, "stainless": 7.9, "stainless_steel": 7.9, "cast_iron": 7.2,
    "aluminium": 2.7, "aluminum": 2.7, "brass": 8.5, "copper": 8.96, "zinc": 7.1, "titanium": 4.5,
    "plastic": 1.2, "abs": 1.05, "nylon": 1.15, "pom": 1.41, "rubber": 1.2, "fr4": 1.9, "pcb_green": 1.9,
    "dark_plastic": 1.2, "blue_plastic": 1.2, "red_plastic": 1.2, "white_plastic": 1.2, "grey_plastic": 1.2,
    # more of what a disassembly line takes apart (file keys written before the table existed named these)
    "pa": 1.14, "pa6": 1.14, "pa66": 1.14, "pc": 1.2, "pvc": 1.4, "pp": 0.9, "pe": 0.95, "pet": 1.38,
    "pbt": 1.31, "peek": 1.3, "ptfe": 2.2, "silicone": 1.1, "epoxy": 1.2, "glass": 2.5, "ceramic": 2.4,
    "wood": 0.7, "mdf": 0.75, "cardboard": 0.7, "magnesium": 1.74, "lead": 11.3, "tin": 7.3, "nickel": 8.9,
    "bronze": 8.8, "ferrite": 4.8, "pla": 1.24, "petg": 1.27, "hips": 1.05,
}
DEFAULT_MATERIAL = "aluminium"  # a part that carries neither its mass nor its material


def check_mass_keys(raw: dict, where: str) -> None:
    """Refuse a "mass_g" that is no positive finite number. "mass_g": null is no mass (files written before
    the key was checked have it)."""
    if raw.get("mass_g") is not None:
        m = raw["mass_g"]
        if not is_finite_number(m) or m <= 0:
            raise BadInput(f"{where}: 'mass_g' must be a positive number of grams, got {short_repr(m)}")


def known_density_g_cm3(material) -> float | None:
    """The density of a material description: a name of DENSITY_G_CM3 in any case, with any punctuation or
    spaces ("Stainless Steel" -> stainless_steel, "FR-4" -> fr4), else the longest name found among its words
    ("Stainless Steel 304" -> stainless_steel, "steel, galvanised" -> steel); None when there is none."""
    if not isinstance(material, str):
        return None
    words = [w for w in re.split(r"[^a-z0-9]+", material.lower()) if w]
    for name in ("_".join(words), "".join(words)):
        if name in DENSITY_G_CM3:
            return DENSITY_G_CM3[name]
    runs = {"_".join(words[i:j]) for i in range(len(words)) for j in range(i + 1, len(words) + 1)}
    found = sorted((n for n in runs if n in DENSITY_G_CM3), key=len, reverse=True)
    return DENSITY_G_CM3[found[0]] if found else None


def density_g_cm3(material, where: str = "part") -> float:
    """The density of `material` (`known_density_g_cm3`); else aluminium's, with a warning."""
    d = known_density_g_cm3(material)
    if d is None:
        d = DENSITY_G_CM3[DEFAULT_MATERIAL]
        if (where, repr(material)) in _WARNED:  # (a part is weighed at every plan: told once)
            return d
        _WARNED.add((where, repr(material)))
        log.warning("%s: 'material' %s has no known density: weighed as %s (%g g/cm3); give its 'mass_g' in "
                    "grams to weigh it right", where, short_repr(material), DEFAULT_MATERIAL, d)
    return d


def mass_g(meta: dict, volume_cm3: float, where: str = "part") -> float:
    """The mass a part's free keys `meta` give it (see the module), `volume_cm3` its outline x height."""
    check_mass_keys(meta, where)
    if meta.get("mass_g") is not None:
        return float(meta["mass_g"])
    material = meta.get("material")
    return volume_cm3 * density_g_cm3(DEFAULT_MATERIAL if material is None else material, where)
