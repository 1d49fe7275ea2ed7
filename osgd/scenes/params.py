"""The scenes stage's parameters: the ``[scenes]`` section of a pipeline config.

Lengths in metres, times in seconds (simulated, never wall-clock), speeds in
m/s and rad/s. The world frame is described in ``docs/scenes.md``: z up, the
floor at z = 0, the workbench (and the 1 m x 1 m walled area) centred on the
origin.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from osgd.contract.taxonomy import Taxonomy
from osgd.scenes.split import SplitParams
from osgd.stage import StageParams


class ScenesStageParams(StageParams):
    """Parameters of the scenes stage."""

    count: int = Field(1000, ge=0, description="scenes in all (the paper renders 8000 depth maps)")
    scenes_per_shard: int = Field(25, ge=1, description="scenes per shard; changing it changes no scene")
    min_objects: int = Field(3, ge=1, description="fewest objects in a scene (paper: 3)")
    max_objects: int = Field(6, ge=1, description="most objects in a scene (paper: 6)")
    balance: Literal["category", "model"] = Field(
        "category",
        description="'category': draw a category (by category_weights), then one of its models uniformly; "
        "'model': every model equally likely",
    )
    category_weights: dict[str, float] = Field(
        default_factory=dict,
        description="relative weight per category under balance='category'; unlisted categories weigh 1",
    )
    distinct_models: bool = Field(
        True, description="no model twice in one scene while the scene's categories still have unused models"
    )
    drop_height: float = Field(
        0.30, gt=0.0, description="height of each object's box centre above the floor at release (paper: 30 cm)"
    )
    drop_clearance: float = Field(
        0.01, ge=0.0, description="a released object starts at least this far above everything already there"
    )
    drop_radius: float = Field(
        0.05, ge=0.0,
        description="objects are released uniformly in a disc of this radius around the pile centre; small, "
        "so that they land on each other",
    )
    pile_center_radius: float = Field(
        0.10, ge=0.0, description="the pile centre is drawn uniformly in a disc of this radius around the origin"
    )
    release_interval: float = Field(
        0.20, ge=0.0, description="simulated time between two releases (free fall from 30 cm takes 0.25 s)"
    )
    area_size: float = Field(1.0, gt=0.1, description="side of the square area bounded by walls (paper: 1 m)")
    wall_height: float = Field(0.5, gt=0.0, description="height of the walls")
    floor_friction: tuple[float, float, float] = Field(
        (0.8, 0.01, 0.01),
        description="lateral, rolling, spinning friction of the floor and walls (rolling and spinning 0.01 let "
        "piles settle: REFERENCE section 8)",
    )
    timestep: float = Field(1.0 / 240.0, gt=0.0, le=0.1, description="simulated seconds per step (pybullet's 1/240)")
    rest_linear_speed: float = Field(
        0.005, gt=0.0, description="a scene is settled when every object moved less than this speed, m/s ..."
    )
    rest_angular_speed: float = Field(0.05, gt=0.0, description="... and turned less than this speed, rad/s ...")
    rest_steps: int = Field(
        60, ge=1, description="... allow over a window of this many steps (displacement over the window, "
        "not instantaneous speeds, which contact jitter keeps above the bounds)"
    )
    max_sim_time: float = Field(
        5.0, gt=0.0,
        description="cap on simulated time per attempt (6 releases take 1 s, a pile settles in about 0.5 s more), "
        "after which the attempt counts unsettled"
    )
    fixed_sim_time: float = Field(
        0.0, ge=0.0,
        description="if > 0, simulate exactly this long after the last release and ignore the rest test "
        "(the original generator ran a fixed 3 s); 0 stops at rest",
    )
    reject_unsettled: bool = Field(True, description="redraw attempts that hit max_sim_time before settling")
    max_linear_speed: float = Field(
        6.0, gt=0.0,
        description="faster than this the simulation blew up (free fall from 0.5 m lands at about 3 m/s)",
    )
    max_angular_speed: float = Field(150.0, gt=0.0, description="spinning faster than this, rad/s, blew up too")
    runaway_check_steps: int = Field(
        1, ge=1, json_schema_extra={"omit_default": True},
        description="test for a blow-up, an object out of the area or through the floor every this many steps "
                    "(and at every rest test and the last step); 1: every step. Each test asks pybullet three "
                    "things per object, a sizeable share of the stacking time at 1; what it catches (NaN, an "
                    "object flung out or through the floor) lasts, so a sparser test rejects the same attempts, "
                    "a few steps later, but for a speed spike shorter than the interval",
    )
    penetration_tolerance: float = Field(
        0.005, ge=0.0, description="objects interpenetrating deeper than this after settling are rejected"
    )
    max_attempts: int = Field(
        10, ge=1, description="attempts per scene; a scene that fails them all is left out with a note"
    )
    max_hull_vertices: int = Field(
        0, ge=0, json_schema_extra={"omit_default": True},
        description="above 0: while dropping, a convex part of more corners collides as the hull of this many "
                    "of its corners (osgd.physics.reduced_hull; fewer corners make stacking faster), and the "
                    "settled pile's interpenetration is judged on the stored parts; "
                    "0: the parts as stored",
    )
    maximal_coordinates: bool = Field(
        False, json_schema_extra={"omit_default": True},
        description="simulate the objects, floor and walls as plain rigid bodies (pybullet's "
                    "useMaximalCoordinates) instead of Featherstone multibodies with a free base: the same "
                    "contacts and friction, solved by Bullet's rigid-body solver, which stacks faster with piles "
                    "of the same statistics and stillness (docs/scenes.md); False: Featherstone multibodies",
    )

    split: SplitParams = Field(
        SplitParams(), json_schema_extra={"omit_default": True},
        description="which tools and piles are held out for test ([scenes.split]: by, model_fraction, "
                    "per_category, test_models, scene_fraction; osgd.scenes.split, docs/scenes.md); the default, "
                    "by = 'scene', draws every pile from every model and leaves the split to samples.test_fraction",
    )

    def taxonomy_mistakes(self, taxonomy: Taxonomy) -> list[str]:
        """Category weights of categories that the taxonomy has not."""
        unknown = sorted(set(self.category_weights) - set(taxonomy.category_names))
        if unknown:
            return [f"category_weights names unknown categories {unknown}; known: {list(taxonomy.category_names)}"]
        return []

    @model_validator(mode="after")
    def _check_ranges(self) -> ScenesStageParams:
        if self.max_objects < self.min_objects:
            raise ValueError(f"max_objects ({self.max_objects}) is below min_objects ({self.min_objects})")
        negative = {name: weight for name, weight in self.category_weights.items() if weight < 0}
        if negative:
            raise ValueError(f"category_weights must not be negative: {negative}")
        return self
