"""Ground-truth grasps per test object and category in two pipelines of ``data/`` (a diagnostic).

Usage::

    python lab/results/ground-truth-collision-2026-11-28/gt_density.py recipe recipe-nocollide
"""

from __future__ import annotations

import sys
from collections import defaultdict

import numpy as np

from osgd.contract.samples import iter_samples


def grasps_per_object(pipeline: str) -> dict[str, list[int]]:
    """The number of ground-truth grasps of each test object, by category."""
    counts = defaultdict(list)
    for sample in iter_samples("data", pipeline, split="test"):
        per_object = np.bincount(sample.grasp_objects, minlength=len(sample.categories))
        for category, count in zip(sample.categories, per_object, strict=True):
            counts[category].append(int(count))
    return counts


def main() -> None:
    first_name, second_name = sys.argv[1:3]
    first, second = grasps_per_object(first_name), grasps_per_object(second_name)
    print(f"{'category':12s} objects   grasps per object ({first_name} / {second_name})   without a grasp")
    rows = [(category, np.array(first[category]), np.array(second[category])) for category in sorted(first)]
    rows.append(("all", np.concatenate([row[1] for row in rows]), np.concatenate([row[2] for row in rows])))
    for category, a, b in rows:
        print(f"{category:12s} {len(a):7d}   {a.mean():5.2f} / {b.mean():5.2f}"
              f"{'':30s}{100 * (a == 0).mean():5.1f} % / {100 * (b == 0).mean():5.1f} %")


if __name__ == "__main__":
    main()
