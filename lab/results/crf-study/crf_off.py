"""A TOG-CRFs checkpoint scored with its CRF's mean field switched off at test time: the task labels from the
unary potentials alone (``log_softmax`` of the task logits), on the same detections and candidates.

Writes an eval-sets.json-like document (``model`` ``tog-crfs, unary only``, the checkpoint's ``seed``), so that
``togcrf compare --baseline OFF.json ... --candidate ON.json ...`` pairs the two readouts by seed. Run from the
repository root:

    .venv/bin/python lab/results/crf-study/crf_off.py CHECKPOINT DATA OUT.json seen=default novel=gap-novel
"""

from __future__ import annotations

import sys
from pathlib import Path

from osgd.contract.samples import iter_samples
from togcrf.checkpoint import load_checkpoint
from togcrf.engine import evaluate_model
from togcrf.evaluate import check_test_sets, parse_test_sets, write_json
from togcrf.metrics import PROTOCOLS


def main() -> None:
    checkpoint, data, out, *sets = sys.argv[1:]
    model, config = load_checkpoint(checkpoint)
    if model.crf is None:
        raise SystemExit(f"{checkpoint}: a {config['model']} checkpoint has no CRF")
    model.crf.iterations = 0  # forward() then returns log_softmax of the unary logits
    test_sets = parse_test_sets(sets)
    shards = check_test_sets(Path(data), test_sets, config["vocabulary"])
    document = {"model": "unary only", "seed": config.get("seed"), "checkpoint": checkpoint,
                "data": data, "test_sets": {}}
    for name in test_sets:
        result = evaluate_model(model, iter_samples(Path(data), split="test", shards=shards[name]),
                                config.get("image_size"), speed_images=0, depth_reference=config["depth_reference"],
                                protocols=PROTOCOLS)
        document["test_sets"][name] = {"pipeline": test_sets[name], "metrics": result["metrics_by_protocol"]}
    write_json(Path(out), document)


if __name__ == "__main__":
    main()
