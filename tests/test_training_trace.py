"""The fixed-seed training trace: what 30 steps on the golden samples learn does not change by accident.

``tests/traces/training-trace.json`` was recorded with ``python tests/trace_training.py`` before the
detector's code was reorganised; a refactoring must give the same losses at every step and the same
evaluation figures. Re-record it (and say why in the commit) only for a change that is meant to change
training.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
RECORDED = TESTS / "traces" / "training-trace.json"

#: Relative tolerance of a loss (the runs are bit-identical on one machine; other processors run the same
#: pinned kernels, and this leaves room for a last-bit difference that grows).
TOLERANCE = 1e-3

#: Steps compared per run, and whether its evaluation is. FCGN + Task with SGD gives the recorded trace on
#: every processor tried. TOG-CRFs with the recipe's options does not: on an AMD EPYC (Zen 4) it differs
#: from the Intel recording in the last bit from step 1 on, about 1e-6 by step 4, and a proposal or sample
#: that crosses a threshold at step 5 then makes the run another one (1e-3 at step 5, 10 % by step 8). Its
#: first five steps hold every part of the recipe (forward, losses, backward, fused AdamW, the warm-up) at
#: a difference far below what any change of the code gives.
COMPARED = {"tog-crfs-recipe": (5, False), "fcgn-task-sgd": (30, True)}


def _close(first, second) -> bool:
    if first is None or second is None:
        return first is second
    return math.isclose(first, second, rel_tol=TOLERANCE, abs_tol=1e-5)


def test_thirty_steps_on_the_golden_samples_give_the_recorded_losses_and_evaluation(tmp_path):
    out = tmp_path / "trace.json"
    environment = {**os.environ, "PYTHONHASHSEED": "0"}
    subprocess.run([sys.executable, str(TESTS / "trace_training.py"), str(out)], check=True, env=environment,
                   timeout=600)
    recorded, traced = json.loads(RECORDED.read_text()), json.loads(out.read_text())
    assert traced.keys() == recorded.keys()
    assert traced.keys() == COMPARED.keys()
    for name, run in recorded.items():
        steps = traced[name]["steps"]
        assert len(steps) == len(run["steps"]) == 30, name
        compared, with_evaluation = COMPARED[name]
        for index, (want, got) in enumerate(zip(run["steps"][:compared], steps[:compared], strict=True)):
            assert got.keys() == want.keys(), (name, index)
            different = {key: (want[key], got[key]) for key in want if not _close(want[key], got[key])}
            assert not different, (name, index, different)
        evaluation = traced[name]["eval"]
        assert evaluation.keys() == run["eval"].keys(), name
        if with_evaluation:
            assert all(_close(run["eval"][key], evaluation[key]) for key in run["eval"]), (name, evaluation)
