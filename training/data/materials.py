"""Surface materials of spacecraft and how they shade.

Each face of a spacecraft mesh carries a material id. A material is a small set of
Blinn-Phong parameters plus two procedural details that make spacecraft look like
spacecraft: the cell grid of solar arrays and the crinkle of multi-layer insulation (MLI).
Per model, the parameters are jittered (seeded) so that no two spacecraft look alike.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum

import numpy as np


class Material(IntEnum):
    SOLAR_CELL = 0
    MLI_GOLD = 1
    MLI_SILVER = 2
    WHITE_PAINT = 3
    METAL = 4
    DARK = 5
    RADIATOR = 6


@dataclass(frozen=True)
class Shading:
    """Reflectance of one material; albedo and specular in [0, 1], exponent dimensionless."""

    albedo: float
    specular: float
    shininess: float
    crinkle: float = 0.0  # amplitude of the normal perturbation (MLI), radians-ish
    cell_pitch_m: float = 0.0  # solar-cell grid pitch in metres, 0 = no grid
    grid_albedo: float = 0.0  # albedo of the interconnect lines between cells


BASE_SHADING: dict[Material, Shading] = {
    Material.SOLAR_CELL: Shading(0.06, 0.55, 120.0, cell_pitch_m=0.12, grid_albedo=0.35),
    Material.MLI_GOLD: Shading(0.55, 0.45, 25.0, crinkle=0.25),
    Material.MLI_SILVER: Shading(0.70, 0.55, 30.0, crinkle=0.2),
    Material.WHITE_PAINT: Shading(0.80, 0.05, 10.0),
    Material.METAL: Shading(0.45, 0.60, 60.0),
    Material.DARK: Shading(0.07, 0.10, 15.0),
    Material.RADIATOR: Shading(0.85, 0.25, 40.0),
}


#: Albedo jitter per material (factor range); solar arrays range from near-black to the grey of
#: arrays seen at grazing sun or with bright cover glass.
ALBEDO_JITTER: dict[Material, tuple[float, float]] = {Material.SOLAR_CELL: (0.6, 3.0)}
#: Share of spacecraft whose radiators are black (anodised or painted) rather than white.
DARK_RADIATORS = 0.3


def jittered_shading(rng: np.random.Generator) -> list[Shading]:
    """Per-model variation of every material, indexed by ``Material`` value: albedo, and a
    specular lobe from dull to mirror-like (tight, strong lobes give the glints that saturate
    a camera); on some spacecraft black radiators."""
    table = []
    for material in Material:
        base = BASE_SHADING[material]
        albedo = base.albedo * rng.uniform(*ALBEDO_JITTER.get(material, (0.7, 1.3)))
        table.append(
            replace(
                base,
                albedo=float(np.clip(albedo, 0.02, 0.95)),
                grid_albedo=base.grid_albedo * rng.uniform(0.5, 1.5),
                specular=float(np.clip(base.specular * rng.uniform(0.5, 2.0), 0.0, 0.95)),
                shininess=float(base.shininess * rng.uniform(0.5, 3.0)),
                crinkle=base.crinkle * rng.uniform(0.6, 1.5),
                cell_pitch_m=base.cell_pitch_m * rng.uniform(0.6, 1.6),
            )
        )
    if rng.random() < DARK_RADIATORS:
        radiator = table[Material.RADIATOR]
        table[Material.RADIATOR] = replace(radiator, albedo=float(rng.uniform(0.04, 0.15)))
    return table


def shading_arrays(table: list[Shading]) -> dict[str, np.ndarray]:
    """Column arrays of a shading table, for vectorised lookup by material id."""
    return {
        name: np.array([getattr(s, name) for s in table], dtype=np.float64)
        for name in ("albedo", "specular", "shininess", "crinkle", "cell_pitch_m", "grid_albedo")
    }
