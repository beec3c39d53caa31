"""A part's mass: its "mass_g" key, else its volume times the density of its "material" key, else aluminium.

Scene and assembly files carry both as free keys of a part (the parts library writes both). "mass_g", when
given, is the mass and wins; it must be a positive finite number. "material" is read for the mass only when
there is no "mass_g": it must then be a name of `DENSITY_G_CM3` (any case), since a density guessed for an
unknown material would judge a steel part as aluminium (a third of its weight). With a "mass_g" the material
is only a name (the simulated camera colours parts by it) and any string is taken. Neither key: aluminium.
`check_mass_keys` refuses the rest when a file is read (`cell.scene.parse_part`).
"""

from __future__ import annotations

from cell.errors import BadInput
from cell.fileio import is_finite_number, short_repr

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
    "bronze": 8.8, "ferrite": 4.8,
}
DEFAULT_MATERIAL = "aluminium"  # a part that carries neither its mass nor its material


def check_mass_keys(raw: dict, where: str) -> None:
    """Refuse a "mass_g" that is no positive finite number, and a "material" the mass would be taken from
    (no "mass_g") that is not in the table. "mass_g": null is no mass (files written before the key was
    checked have it)."""
    if raw.get("mass_g") is not None:
        m = raw["mass_g"]
        if not is_finite_number(m) or m <= 0:
            raise BadInput(f"{where}: 'mass_g' must be a positive number of grams, got {short_repr(m)}")
    elif "material" in raw:
        density_g_cm3(raw["material"], where)


def density_g_cm3(material, where: str = "part") -> float:
    """The density of `material` (a name of DENSITY_G_CM3, any case); BadInput naming the known ones else."""
    d = DENSITY_G_CM3.get(material.strip().lower()) if isinstance(material, str) else None
    if d is None:
        raise BadInput(f"{where}: 'material' {short_repr(material)} has no known density and the part has no "
                       f"'mass_g': give its mass in grams, or one of {', '.join(sorted(DENSITY_G_CM3))}")
    return d


def mass_g(meta: dict, volume_cm3: float, where: str = "part") -> float:
    """The mass a part's free keys `meta` give it (see the module), `volume_cm3` its outline x height."""
    check_mass_keys(meta, where)
    if meta.get("mass_g") is not None:
        return float(meta["mass_g"])
    return volume_cm3 * density_g_cm3(meta.get("material", DEFAULT_MATERIAL), where)
