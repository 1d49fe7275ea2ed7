"""`togcrf compare`: two models over training seeds, each metric's difference with its 95 % intervals."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
from typer.testing import CliRunner

from togcrf.cli import app
from togcrf.compare import compare, interval, welch_interval

#: Student's t quantile for a two-sided 95 % interval with 3 degrees of freedom (any statistics table).
T_975_3 = 3.182


def sets_document(model: str, seed: int | None, acc_top1: dict[str, float], crowded: float) -> dict:
    """An eval-sets.json document: Acc-T top-1 per test set, one stratum of crowding, mAP fixed."""
    def metrics(value: float, protocol: str) -> dict:
        return {"protocol": protocol, "mAP": 0.5, "mAP-G": 0.2, "Acc-T top1": value, "Acc-T top5": None, "rois": 40,
                "Acc-T top10": 0.1, "Acc-T by other objects' share": {">=0.30": {"rois": 9, "Acc-T top1": crowded}}}
    return {"model": model, "seed": seed, "checkpoint": f"/nowhere/{model}-{seed}/checkpoint.pt",
            "test_sets": {name: {"metrics": {"ours": metrics(value, "ours"), "lab": metrics(value, "lab")}}
                          for name, value in acc_top1.items()}}


def test_intervals_follow_students_t() -> None:
    low, high = interval([1.0, 2.0, 3.0, 4.0])  # mean 2.5, sd 1.291
    assert (low + high) / 2 == pytest.approx(2.5)
    assert (high - low) / 2 == pytest.approx(T_975_3 * 1.2910 / 2, rel=1e-3)
    assert interval([1.0]) is None
    # Welch: equal groups give a zero-centred interval; a shift moves it by the shift
    low, high = welch_interval([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert low == pytest.approx(-high)
    shifted = welch_interval([1.0, 2.0, 3.0], [6.0, 7.0, 8.0])
    assert shifted[0] == pytest.approx(low + 5) and shifted[1] == pytest.approx(high + 5)


def test_pairing_by_seed_removes_the_spread_between_seeds() -> None:
    """The candidate is 2 points better than the baseline of its own seed, and the seeds spread by 20 points:
    paired by seed (in any order), the interval excludes zero; unpaired, it does not."""
    spread = {0: 0.30, 1: 0.50, 2: 0.40, 3: 0.60}
    jitter = {0: 0.001, 1: -0.002, 2: 0.0015, 3: -0.0005}
    baseline = [(Path(f"b{seed}"), sets_document("tog", seed, {"novel": value}, 0.2)) for seed, value in spread.items()]
    candidate = [(Path(f"c{seed}"), sets_document("tog-crfs", seed, {"novel": value + 0.02 + jitter[seed]}, 0.3))
                 for seed, value in spread.items()]
    random.Random(0).shuffle(candidate)
    result = compare(baseline, candidate)
    assert result["paired"] and result["baseline"]["model"] == "TOG" and result["candidate"]["model"] == "TOG-CRFs"
    cell = result["test_sets"]["novel"]["Acc-T top1"]
    assert cell["difference"] == pytest.approx(2.0, abs=0.01)
    assert 0 < cell["paired"][0] < 2.0 < cell["paired"][1]
    assert cell["unpaired"][0] < 0 < cell["unpaired"][1]
    # the crowded stratum compared too; a metric that is None anywhere is left out
    crowded = result["test_sets"]["novel"]["Acc-T by other objects' share: >=0.30"]
    assert crowded["difference"] == pytest.approx(10.0) and crowded["rois"] == 9
    assert cell["rois"] == 40 and "rois" not in result["test_sets"]["novel"]["mAP"]
    assert "Acc-T top5" not in result["test_sets"]["novel"]


def test_runs_whose_seeds_do_not_match_are_compared_unpaired() -> None:
    baseline = [(Path(f"b{seed}"), sets_document("tog", seed, {"seen": 0.5 + seed / 100}, 0.2)) for seed in (0, 1)]
    candidate = [(Path(f"c{seed}"), sets_document("tog-crfs", seed, {"seen": 0.5}, 0.2)) for seed in (0, 7)]
    result = compare(baseline, candidate)
    assert not result["paired"] and result["test_sets"]["seen"]["mAP"]["paired"] is None
    assert result["test_sets"]["seen"]["mAP"]["unpaired"] == (0.0, 0.0)


def test_compare_command_prints_writes_and_refuses_in_one_line(tmp_path: Path) -> None:
    paths = {}
    for model, shift in (("tog", 0.0), ("tog-crfs", 0.03)):
        for seed in range(3):
            paths[model, seed] = tmp_path / f"{model}-s{seed}-eval-sets.json"
            document = sets_document(model, seed, {"seen": 0.4 + seed / 10 + shift, "novel": 0.5}, 0.3)
            paths[model, seed].write_text(json.dumps(document))
    out = tmp_path / "compare.json"
    arguments = ["compare", *[part for seed in range(3) for part in ("--baseline", str(paths["tog", seed]))],
                 *[part for seed in range(3) for part in ("--candidate", str(paths["tog-crfs", seed]))]]
    result = CliRunner().invoke(app, [*arguments, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "paired by seed" in result.output and "test set seen" in result.output and "test set novel" in result.output
    written = json.loads(out.read_text())
    assert written["test_sets"]["seen"]["Acc-T top1"]["difference"] == pytest.approx(3.0)
    assert written["test_sets"]["novel"]["Acc-T top1"]["difference"] == pytest.approx(0.0)

    plain = tmp_path / "eval.json"
    plain.write_text(json.dumps({"model": "tog", "protocol": "lab", "metrics": {"mAP": 0.5}}))
    result = CliRunner().invoke(app, ["compare", "--baseline", str(plain), "--candidate", str(plain)])
    assert result.exit_code == 1 and result.output.count("\n") == 1 and "protocol 'lab', not 'ours'" in result.output
    result = CliRunner().invoke(app, ["compare", "--baseline", str(plain), "--candidate", str(paths["tog", 0]),
                                      "--protocol", "lab"])
    assert result.exit_code == 1 and "share no test set" in result.output
