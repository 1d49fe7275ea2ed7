"""Real sizes and physical properties of each object category: the one table.

Every model's real length is drawn from its category's range here, and its
density and friction coefficients come from here too.

Where the numbers come from
---------------------------
- ``length_range``: REFERENCE.md section 7, the longest (PCA) extents of
  real scanned and CAD meshes of each tool, in metres. The OSGD models are
  ShapeNet-normalised (about one unit long, REFERENCE section 2) and must be
  scaled into these ranges before simulation.
- ``density``: our choice, an effective uniform density for a tool of mixed
  materials (steel 7,850 kg/m^3, aluminium 2,700, polypropylene/ABS
  900-1,050, hardwood 700), set so that a tool of the middle length weighs
  about what the real one does (a table knife ~100 g with our 3 mm minimum
  blade thickness, a claw hammer ~0.5 kg, an all-steel wrench or pliers
  ~0.2-0.3 kg, a pen ~10 g). Spoons and forks are steel, but our parts are at
  least 3.2 mm thick (thicker than real cutlery), so their density is lowered
  to 4,000 to keep the masses near the real 40-60 g.
- ``mass_range``: our choice, the masses of such tools in retail listings
  (table cutlery 20-100 g, kitchen knives up to 250 g, claw hammers 0.2-1 kg,
  pliers and wrenches 0.1-0.7 kg, pens 4-30 g). Density times volume is an
  estimate; an authored mesh bulkier than the real tool would otherwise
  weigh several times as much (OSGD pliers_007: 2.9 kg), so the mass is
  clamped into this range (``osgd.models.mass.clamp_mass``). Every
  procedural model falls inside it.
- ``friction``: lateral coefficients are our choice from common engineering
  tables (dry steel on steel or rubber-gripped handles 0.5-0.8, smooth
  plastic 0.3-0.5), clamped to what a rubber-padded gripper sees. Rolling
  and spinning friction are 0.01: REFERENCE section 8 measured that this
  lets 10/10 dropped stacks settle (0.001 only 7/10). ACRONYM likewise stores
  density and friction per object (REFERENCE section 5).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from osgd.contract.taxonomy import CATEGORIES

#: Rolling and spinning friction of every model (REFERENCE section 8).
ROLLING_FRICTION: Final[float] = 0.01
SPINNING_FRICTION: Final[float] = 0.01


@dataclass(frozen=True)
class CategoryProperties:
    """Size and material of one category.

    Attributes
    ----------
    length_range : (float, float)
        Real longest extent, minimum and maximum, metres.
    density : float
        Effective uniform density, kg/m^3.
    mass_range : (float, float)
        Real mass, minimum and maximum, kg.
    lateral_friction : float
        Coulomb friction coefficient, dimensionless.
    """

    length_range: tuple[float, float]
    density: float
    mass_range: tuple[float, float]
    lateral_friction: float

    @property
    def friction(self) -> tuple[float, float, float]:
        """(lateral, rolling, spinning) coefficients, pybullet's order."""
        return (self.lateral_friction, ROLLING_FRICTION, SPINNING_FRICTION)


#: The table, by category (see the module docstring for the sources).
CATEGORY_PROPERTIES: Final[dict[str, CategoryProperties]] = {
    "knife": CategoryProperties((0.16, 0.22), 2500.0, (0.04, 0.25), 0.5),
    "screwdriver": CategoryProperties((0.19, 0.29), 1800.0, (0.04, 0.30), 0.7),
    "spoon": CategoryProperties((0.20, 0.22), 4000.0, (0.02, 0.10), 0.5),
    "fork": CategoryProperties((0.19, 0.20), 4000.0, (0.02, 0.10), 0.5),
    "wrench": CategoryProperties((0.19, 0.30), 7850.0, (0.10, 0.70), 0.6),
    "hammer": CategoryProperties((0.21, 0.33), 2800.0, (0.20, 1.00), 0.7),
    "pen": CategoryProperties((0.12, 0.15), 900.0, (0.004, 0.03), 0.5),
    "toothbrush": CategoryProperties((0.17, 0.19), 1000.0, (0.006, 0.04), 0.5),
    "spatula": CategoryProperties((0.24, 0.32), 1500.0, (0.03, 0.25), 0.5),
    "pliers": CategoryProperties((0.16, 0.30), 7850.0, (0.12, 0.50), 0.7),
}

assert set(CATEGORY_PROPERTIES) == set(CATEGORIES), "every category needs a row"

#: A model whose real length lies outside ``[FAR_OFF_SCALE_LOW * min, FAR_OFF_SCALE_HIGH * max]``
#: of its category range is rejected as far off scale (a unit mix-up: mm for m).
FAR_OFF_SCALE_LOW: Final[float] = 0.5
FAR_OFF_SCALE_HIGH: Final[float] = 2.0


def category_properties(category: str) -> CategoryProperties:
    """The row of ``category``.

    Raises
    ------
    ValueError
        If the category is not one of :data:`osgd.contract.taxonomy.CATEGORIES`.
    """
    try:
        return CATEGORY_PROPERTIES[category]
    except KeyError:
        raise ValueError(f"unknown category {category!r}; expected one of {list(CATEGORIES)}") from None


def draw_length(category: str, rng: np.random.Generator) -> float:
    """A real length for one model, uniform in its category's range, metres."""
    low, high = category_properties(category).length_range
    return float(rng.uniform(low, high))


def plausible_length_range(category: str) -> tuple[float, float]:
    """The lengths accepted before a model counts as far off scale, metres."""
    low, high = category_properties(category).length_range
    return (FAR_OFF_SCALE_LOW * low, FAR_OFF_SCALE_HIGH * high)
