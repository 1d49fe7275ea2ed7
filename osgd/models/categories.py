"""Real sizes and physical properties of each object category.

Every model's real length is drawn from its category's range here, and its
density and friction coefficients come from here too.

The figures, and where they come from, are the taxonomy's
(``osgd/contract/table1.toml``, :mod:`osgd.contract.taxonomy`); rolling and
spinning friction are 0.01 for every model: REFERENCE section 8 measured
that this lets 10/10 dropped stacks settle (0.001 only 7/10). ACRONYM
likewise stores density and friction per object (REFERENCE section 5).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from osgd.contract.taxonomy import TABLE1, CategorySpec, Taxonomy

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


def _properties(category: CategorySpec) -> CategoryProperties:
    return CategoryProperties(category.length_range, category.density, category.mass_range,
                              category.lateral_friction)


#: The properties of each category of Table I (``osgd/contract/table1.toml`` gives their sources).
CATEGORY_PROPERTIES: Final[dict[str, CategoryProperties]] = {
    category.name: _properties(category) for category in TABLE1.categories
}

#: A model whose real length lies outside ``[FAR_OFF_SCALE_LOW * min, FAR_OFF_SCALE_HIGH * max]``
#: of its category range is rejected as far off scale (a unit mix-up: mm for m).
FAR_OFF_SCALE_LOW: Final[float] = 0.5
FAR_OFF_SCALE_HIGH: Final[float] = 2.0


def category_properties(category: str, taxonomy: Taxonomy = TABLE1) -> CategoryProperties:
    """The properties of ``category`` in the taxonomy.

    Raises
    ------
    ValueError
        If the taxonomy has no such category.
    """
    return _properties(taxonomy.category(category))


def draw_length(category: str, rng: np.random.Generator) -> float:
    """A real length for one model of Table I, uniform in its category's range, metres."""
    low, high = category_properties(category).length_range
    return float(rng.uniform(low, high))


def plausible_length_range(category: str, taxonomy: Taxonomy = TABLE1) -> tuple[float, float]:
    """The lengths accepted before a model counts as far off scale, metres."""
    low, high = category_properties(category, taxonomy).length_range
    return (FAR_OFF_SCALE_LOW * low, FAR_OFF_SCALE_HIGH * high)
