"""The grasps stage's parameters: the ``[grasps]`` section of a pipeline config."""

from __future__ import annotations

from pydantic import Field

from osgd.contract.taxonomy import Taxonomy
from osgd.grasps.labels import LabelRule, rule_mistakes
from osgd.stage import StageParams


class GraspsStageParams(StageParams):
    """Parameters of the grasps stage (lengths in metres, angles in radians)."""

    approach_count: int = Field(
        8, ge=1, le=64, description="approach directions tried evenly around each closing axis"
    )
    collision_margin: float = Field(
        0.001, ge=0.0, le=0.005,
        description="penetration of the object into a gripper box that is tolerated, m (pads resting on it)",
    )
    surface_spacing: float = Field(
        0.002, gt=0.0, le=0.01, description="nominal spacing of the surface samples of the collision test, m"
    )
    max_surface_points: int = Field(
        200_000, ge=1_000, description="cap on surface samples per model (the spacing grows past it)"
    )
    friction: float = Field(
        0.4, gt=0.0, le=2.0,
        description="Coulomb friction of the sampler's force-closure test; below the simulated 0.8 on purpose, "
        "so sampled grasps keep a margin when the check stage simulates them",
    )
    sampler_points: int = Field(
        3000, ge=10, description="surface points drawn per model by the antipodal sampler (over-generation)"
    )
    sampler_max_pairs: int = Field(
        48, ge=1, description="contact pairs kept per sampled model, best quality first after thinning"
    )
    thin_distance: float = Field(
        0.008, ge=0.0, description="sampled pairs whose centres are closer than this, m, ..."
    )
    thin_angle: float = Field(
        0.35, ge=0.0, le=1.5708, description="... and whose closing axes are within this, rad (20 deg), are duplicates"
    )
    label_margin: float = Field(
        0.002, ge=0.0,
        description="the region between the pads is grown by this, m, when collecting the touched parts",
    )
    label_rules: dict[str, LabelRule] = Field(
        default_factory=dict,
        description="per-category replacements of osgd.grasps.labels.DEFAULT_RULES (docs/grasps.md)",
    )

    def taxonomy_mistakes(self, taxonomy: Taxonomy) -> list[str]:
        """A replaced rule of a category or with a part that the taxonomy has not."""
        return rule_mistakes(self.label_rules, taxonomy)
