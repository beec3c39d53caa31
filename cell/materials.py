"""A part's mass: its "mass_g" key, else its volume times the density of its "material" key, else aluminium.

Scene and assembly files carry both as free keys of a part (the parts library writes both). "mass_g", when
given, is the mass and wins; it must be a positive finite number (`check_mass_keys` refuses the rest when a
file is read, `cell.scene.parse_part`). "material" is read for the mass only when there is no "mass_g", and
only for the part being weighed (the target). It is a free description (CONTRACT.md does not name it): a name
of `DENSITY_G_CM3` in any case and spelling ("FR-4", "Stainless Steel"), else the longest such name among its
words ("Aluminium 6061-T6", "steel, galvanised"), with a warning naming the name taken, else steel's density
(the densest common metal: the load check errs on the heavy side), with a warning asking for "mass_g" (a scene
with "material": "PLA" was refused whole, exit 2). Neither key: aluminium.
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
UNKNOWN_MATERIAL = "steel"  # a material none of these names: weighed heavy, so that the load check errs safe


def check_mass_keys(raw: dict, where: str) -> None:
    """Refuse a "mass_g" that is no positive finite number. "mass_g": null is no mass (files written before
    the key was checked have it)."""
    if raw.get("mass_g") is not None:
        m = raw["mass_g"]
        if not is_finite_number(m) or m <= 0:
            raise BadInput(f"{where}: 'mass_g' must be a positive number of grams, got {short_repr(m)}")


def material_name(material) -> tuple[str | None, bool]:
    """(the DENSITY_G_CM3 name a material description gives, whether that is the whole description): the whole
    of it in any case, with any punctuation or spaces ("Stainless Steel" -> stainless_steel, "FR-4" -> fr4),
    else the longest name among its words, the first in the alphabet of equally long ones ("Stainless Steel
    304" -> stainless_steel, "non-steel" -> steel: a guess, told); (None, False) when there is none."""
    if not isinstance(material, str):
        return None, False
    words = [w for w in re.split(r"[^a-z0-9]+", material.lower()) if w]
    for name in ("_".join(words), "".join(words)):
        if name in DENSITY_G_CM3:
            return name, True
    runs = {"_".join(words[i:j]) for i in range(len(words)) for j in range(i + 1, len(words) + 1)}
    found = sorted((n for n in runs if n in DENSITY_G_CM3), key=lambda n: (-len(n), n))
    return (found[0], False) if found else (None, False)


def density_g_cm3(material, where: str = "part") -> float:
    """The density of `material` (`material_name`); a partial match or none is told once (a part is weighed at
    every plan), and none is weighed as steel."""
    name, whole = material_name(material)
    if whole:
        return DENSITY_G_CM3[name]
    taken = name or UNKNOWN_MATERIAL
    if (where, repr(material)) not in _WARNED:
        _WARNED.add((where, repr(material)))
        why = f"taken as {taken!r} from its words" if name else f"has no known density: weighed as {taken}, to be safe"
        log.warning("%s: 'material' %s %s (%g g/cm3); give its 'mass_g' in grams to weigh it right",
                    where, short_repr(material), why, DENSITY_G_CM3[taken])
    return DENSITY_G_CM3[taken]


def mass_g(meta: dict, volume_cm3: float, where: str = "part") -> float:
    """The mass a part's free keys `meta` give it (see the module), `volume_cm3` its outline x height."""
    check_mass_keys(meta, where)
    if meta.get("mass_g") is not None:
        return float(meta["mass_g"])
    material = meta.get("material")
    return volume_cm3 * density_g_cm3(DEFAULT_MATERIAL if material is None else material, where)
