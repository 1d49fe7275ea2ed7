"""Hand-made scenes, grasps and checks for the samples stage's tests.

Until the grasps, checks and scenes stages are used in these tests, their
rows are written here by hand, in the real schemas: the fixture tools of
``helpers.py`` lying on the floor (world z up, floor at z = 0), grasps across
the hammer's handle with the gripper approaching from above, and check rows
marking all but a known few stable.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from helpers import fixture_models, write_models
from scipy.spatial.transform import Rotation

from osgd.contract.schemas import CHECKS, GRASPS, SCENES
from osgd.store import ShardStore

#: Mesh-frame heights that rest each fixture tool on the floor: the hammer's
#: head (3 cm tall) and the screwdriver's handle (3 cm across), the block (4 cm).
REST_HEIGHT = {"hammer": 0.015, "screwdriver": 0.015, "knife": 0.02}

#: Gripper frame (columns x = closing, y, z = approach) closing along the
#: object's y axis and approaching straight down.
TOP_DOWN_ACROSS_Y = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def grasp_row(model_id: str, grasp_id: int, task: str, position, rotation, width: float, contact_half) -> dict:
    position = np.asarray(position, dtype=np.float64)
    closing = np.asarray(rotation)[:, 0]
    return {
        "model_id": model_id, "grasp_id": grasp_id, "task": task, "position": position.tolist(),
        "quaternion": Rotation.from_matrix(rotation).as_quat().tolist(), "width": width,
        "contact_a": (position - contact_half * closing).tolist(),
        "contact_b": (position + contact_half * closing).tolist(),
        "origin": "test", "pair_index": grasp_id, "quality": 1.0,
    }


def hammer_grasps(model_id: str) -> list[dict]:
    """Grasps of the fixture hammer (handle along x from -0.15 to 0.09, head at +x).

    ids 0-9: across the handle, approach from above (hammer task on the
    handle's far half, hand over near the head); id 10: closing vertical
    (dropped: along the optical axis); id 11: closing 30 degrees from
    vertical (dropped); id 12: a copy of grasp 2 shifted 2 mm (NMS drops one
    of them); id 13: marked unstable by the checks.
    """
    rows = []
    for grasp_id, x in enumerate(np.linspace(-0.14, 0.07, 10)):
        task = "hammer" if x < -0.03 else "hand over"
        rows.append(grasp_row(model_id, grasp_id, task, [x, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.035, 0.0125))
    vertical = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # closing along z
    rows.append(grasp_row(model_id, 10, "hammer", [-0.1, 0.0, 0.0], vertical, 0.035, 0.0125))
    tilted = Rotation.from_euler("x", np.pi / 3).as_matrix() @ TOP_DOWN_ACROSS_Y  # closing 30 deg from z
    rows.append(grasp_row(model_id, 11, "hammer", [-0.08, 0.0, 0.0], tilted, 0.035, 0.0125))
    shifted = rows[2]["position"][0] + 0.002
    rows.append(grasp_row(model_id, 12, "hammer", [shifted, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.035, 0.0125))
    rows.append(grasp_row(model_id, 13, "hammer", [-0.12, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.035, 0.0125))
    return rows


def screwdriver_grasps(model_id: str) -> list[dict]:
    """Across the handle (screw) and across the shaft (hand over), from above."""
    return [
        grasp_row(model_id, 0, "screw", [-0.07, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.04, 0.015),
        grasp_row(model_id, 1, "screw", [-0.04, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.04, 0.015),
        grasp_row(model_id, 2, "hand over", [0.06, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.02, 0.0035),
    ]


def block_grasps(model_id: str) -> list[dict]:
    """Across the block (4 cm), from above."""
    return [grasp_row(model_id, grasp_id, "cut", [x, 0.0, 0.0], TOP_DOWN_ACROSS_Y, 0.05, 0.02)
            for grasp_id, x in enumerate((-0.04, 0.0, 0.04))]


def scene_row(scene_index: int, placements: list[tuple[dict, list[float], float]]) -> dict:
    """A ``scenes`` row; each placement is (model row, [x, y] or [x, y, z], yaw)."""
    objects = []
    for model, where, yaw in placements:
        position = [*list(where), REST_HEIGHT[model["category"]]] if len(where) == 2 else list(where)
        objects.append({"model_id": model["model_id"], "category": model["category"], "position": position,
                        "quaternion": Rotation.from_euler("z", yaw).as_quat().tolist()})
    return {"scene_id": f"scene_{scene_index:06d}", "scene_index": scene_index, "seed": scene_index, "attempts": 1,
            "rejections": "{}", "objects": objects, "settled": True, "sim_time": 1.0, "sim_steps": 240}


def write_fixture_inputs(store: ShardStore, scenes: list[dict] | None = None) -> dict[str, list[str]]:
    """Write models, grasps, checks and scenes shards; returns table -> keys.

    The default scenes: 0 has the three tools apart; 1 puts the block across
    the hammer's handle (occluding part of it); 2 has the hammer alone.
    """
    hammer, screwdriver, block = fixture_models()
    keys = {"models": [write_models(store, [hammer, screwdriver, block], key="a" * 64)]}
    grasps = hammer_grasps(hammer["model_id"]) + screwdriver_grasps(screwdriver["model_id"]) + block_grasps(
        block["model_id"])
    store.write("grasps", "b" * 64, "fixture", pa.Table.from_pylist(grasps, schema=GRASPS))
    held = [not (row["model_id"] == hammer["model_id"] and row["grasp_id"] == 13) for row in grasps]
    checks = [{"model_id": row["model_id"], "grasp_id": row["grasp_id"],
               "stable": stable, "lift_stable": stable, "shake_stable": stable,
               "fail_reason": "", "slip_distance": 0.0, "slip_rotation": 0.0, "final_opening": row["width"],
               "sim_steps": 100} for row, stable in zip(grasps, held, strict=True)]
    store.write("checks", "c" * 64, "fixture", pa.Table.from_pylist(checks, schema=CHECKS))
    if scenes is None:
        scenes = [
            scene_row(0, [(hammer, [0.0, 0.0], 0.3), (screwdriver, [0.05, 0.12], -0.4), (block, [-0.06, -0.13], 1.2)]),
            # The block rests across the handle (top of the handle at 2.75 cm).
            scene_row(1, [(hammer, [0.0, 0.0], 0.0), (block, [-0.11, 0.0, 0.0475], np.pi / 2)]),
            scene_row(2, [(hammer, [0.02, -0.01], -0.8)]),
        ]
    store.write("scenes", "d" * 64, "scenes_0000", pa.Table.from_pylist(scenes, schema=SCENES))
    keys.update({"grasps": ["b" * 64], "checks": ["c" * 64], "scenes": ["d" * 64]})
    return keys
