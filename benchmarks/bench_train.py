"""Training throughput and peak memory: the CPU recipe beside the configuration it replaced.

Each configuration runs in its own child process, so that the peak resident
memory (``ru_maxrss``) belongs to it alone, and all run in the same
invocation, so the ratio compares like with like on one machine:

- ``before``: the training of commit 4bf0b66: TOG at 192 px, batch 2,
  torchvision's FPN from stride 4 with 256 channels and no normalisation,
  256 RCNN RoIs per image, a 1024-wide box head, 256-channel grasp blocks,
  16 px grasp anchors and a scale jitter of +-10 % (images up to 211 px,
  padded to 224);
- ``recipe-192-c5``: the recipe with the whole ResNet-18 (C3-C5 in the FPN;
  RPN anchors of 16-128 px over four levels) at 192 px, with 12 px grasp
  anchors and 16 grasp RoIs per image, in float32;
- ``recipe``: ``togcrf.config.CPU`` (the ``cpu`` preset) (its model options, batch size,
  image size, scale jitter, optimiser and precision): the ResNet stops
  after C4 and the images are 160 px;
- ``recipe-16-rois``: the recipe with its grasp head trained on up to 16
  foreground RoIs per image instead of 8;
- ``recipe-tv-roialign``: the recipe with torchvision's RoIAlign backward
  instead of :mod:`togcrf.roi_align`'s sparse one (``before`` runs
  torchvision's too, as at 4bf0b66);
- ``recipe-float32``: the recipe without its bfloat16 autocast (the
  recipe's forward pass runs in bfloat16 on a CPU with native bfloat16,
  ``togcrf train --cpu-bf16``; on any other CPU the recipe runs in float32
  and the two are the same configuration). Each child's line names the
  precision it ran in.

``--only`` picks some of them (the ratios are printed for those present;
``recipe-float32 / before`` is the speed-up a CPU without native bfloat16
gets).

To see what a CPU without AVX-512 gets on one that has it, cap the
instruction sets of oneDNN (the convolutions) and of ATen's own kernels
(``INSTRUCTION_SET_CAPS``; the header then names the caps)::

    ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 python benchmarks/bench_train.py --data data \
        --pipeline recipe-pairs96 --only before recipe-float32

Each configuration steps its own optimiser, built as ``togcrf train`` builds
it (``togcrf.train.build_optimizer``): SGD with momentum before the recipe,
the recipe's AdamW (fused) after.

A child trains ``--warmup`` steps untimed, then ``--steps`` timed steps, on
real samples (``--data DIR --pipeline P``: the first training samples) or,
without ``--data``, on synthetic samples (tests/helpers.py), and prints one
JSON line.

Usage::

    python benchmarks/bench_train.py                                   # synthetic samples
    python benchmarks/bench_train.py --data data --pipeline recipe-pairs96     # the recipe's data
    python benchmarks/bench_train.py --data data --pipeline recipe-pairs96 --profile recipe   # where its step goes
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Environment variables that cap the instruction set torch uses on the CPU: oneDNN's (its documented
#: ``ONEDNN_MAX_CPU_ISA``) and ATen's vectorised kernels' (``ATEN_CPU_CAPABILITY``: default, avx2, avx512).
INSTRUCTION_SET_CAPS = ("ONEDNN_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY")

#: The speed-ups printed, (faster, baseline), for the configurations that ran: the recipe against each
#: earlier configuration, and the float32 recipe (what a CPU without native bfloat16 trains) against before.
RATIOS = (("recipe", "before"), ("recipe", "recipe-192-c5"), ("recipe", "recipe-16-rois"),
          ("recipe", "recipe-tv-roialign"), ("recipe", "recipe-float32"), ("recipe-float32", "before"))

#: Distinct batches a child cycles through (their image sizes differ with the scale jitter).
BATCHES = 4

#: Model options of the training before the recipe (the defaults of commit 4bf0b66).
BEFORE_OPTIONS = {"backbone.fpn_norm": False, "grasp_head.trunk_norm": False, "backbone.fpn_min_stride": 4,
                  "backbone.fpn_channels": 256, "rpn.anchor_sizes": [16, 32, 64, 128, 256],
                  "box_head.batch_per_image": 256, "box_head.size": 1024, "grasp_head.channels": 256,
                  "rpn.pre_nms_train": 1000, "rpn.post_nms_train": 500, "grasp_head.anchor_size": 16.0}


def configurations() -> dict[str, dict]:
    """Name -> {"model_options", "batch_size", "image_size", "jitter_up", "jitter_down", "optimizer", "lr",
    "torchvision_roi_align", "cpu_bf16"}."""
    from togcrf.config import CPU  # noqa: PLC0415
    from togcrf.model.options import dotted_options  # noqa: PLC0415

    recipe = {"model_options": dotted_options(CPU.model_options), "batch_size": CPU.batch_size,
              "image_size": CPU.image_size, "jitter_up": 0.0, "jitter_down": CPU.scale_jitter,
              "optimizer": CPU.optimizer, "lr": CPU.lr, "torchvision_roi_align": False, "cpu_bf16": CPU.cpu_bf16}
    whole_backbone = {**recipe, "image_size": 192, "cpu_bf16": False, "model_options": {
        **recipe["model_options"], "backbone.fpn_max_stride": 32, "rpn.anchor_sizes": (16, 32, 64, 128),
        "grasp_head.anchor_size": 12.0, "grasp_head.rois_per_image": 16}}
    return {
        "before": {"model_options": BEFORE_OPTIONS, "batch_size": 2, "image_size": 192, "jitter_up": 0.1,
                   "jitter_down": 0.1, "optimizer": "sgd", "lr": 0.01, "torchvision_roi_align": True,
                   "cpu_bf16": False},
        "recipe-192-c5": whole_backbone,
        "recipe-16-rois": {**recipe, "model_options": {**recipe["model_options"], "grasp_head.rois_per_image": 16}},
        "recipe-tv-roialign": {**recipe, "torchvision_roi_align": True},
        "recipe-float32": {**recipe, "cpu_bf16": False},
        "recipe": recipe,
    }


def use_torchvision_roi_align(model: object) -> None:
    """Pool the model's RoIs with torchvision's own MultiScaleRoIAlign (its CPU backward), same levels."""
    from torchvision.ops import MultiScaleRoIAlign  # noqa: PLC0415

    pool = model.roi_heads.box_roi_pool
    plain = MultiScaleRoIAlign(pool.featmap_names, pool.output_size, pool.sampling_ratio)
    plain.scales, plain.map_levels = pool.scales, pool.map_levels
    model.roi_heads.box_roi_pool = plain


def _batches(arguments: argparse.Namespace, setting: dict, count: int) -> list:
    """``count`` collated batches, each image scaled by a draw from the setting's jitter range."""
    import numpy as np  # noqa: PLC0415
    import torch  # noqa: PLC0415

    from togcrf.data import (  # noqa: PLC0415
        Augmentation,
        SamplesDataset,
        augment,
        collate,
        drop_degenerate_objects,
        normalise_depth,
        resize_scale,
        sample_targets,
    )

    def load(directory: str, pipeline: str | None) -> list:
        dataset = SamplesDataset(directory, pipeline=pipeline, split="train", max_samples=count * setting["batch_size"])
        rng = np.random.default_rng(0)
        items = []
        for index in range(len(dataset)):
            sample = dataset.read_sample(index)
            scale = float(rng.uniform(1 - setting["jitter_down"], 1 + setting["jitter_up"]))
            images, boxes, rectangles = augment([normalise_depth(sample.depth)], sample.boxes,
                                                sample.grasp_rectangles, Augmentation(scale=scale),
                                                resize_scale(sample.depth.shape, setting["image_size"]))
            targets = drop_degenerate_objects(sample_targets(sample, boxes, rectangles))
            items.append((torch.from_numpy(images[0])[None], targets, sample.sample_id))
        size = setting["batch_size"]
        return [collate(items[start:start + size]) for start in range(0, len(items) - size + 1, size)]

    if arguments.data:
        return load(arguments.data, arguments.pipeline)
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers import write_synthetic_samples  # noqa: PLC0415

    from osgd.store import ShardStore  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as directory:
        write_synthetic_samples(ShardStore(directory), count * setting["batch_size"], height=320, width=320,
                                test_every=10**9)
        return load(directory, "synthetic")


def child(arguments: argparse.Namespace) -> None:
    import torch  # noqa: PLC0415

    from togcrf.config import TrainConfig  # noqa: PLC0415
    from togcrf.engine import mixed_precision, precision_name  # noqa: PLC0415
    from togcrf.model import build_model  # noqa: PLC0415
    from togcrf.train import build_optimizer  # noqa: PLC0415

    setting = configurations()[arguments.configuration]
    batches = _batches(arguments, setting, BATCHES)
    torch.manual_seed(0)
    model = build_model("tog", arguments.backbone, setting["model_options"])
    if setting["torchvision_roi_align"]:
        use_torchvision_roi_align(model)
    model.train()
    config = TrainConfig(data="", out="", optimizer=setting["optimizer"], lr=setting["lr"],
                         cpu_bf16=setting["cpu_bf16"])
    optimizer = build_optimizer(model, config)
    use_amp, amp_dtype = mixed_precision(config, torch.device("cpu"))

    def step(index: int) -> None:
        images, targets, _ = batches[index % len(batches)]
        with torch.autocast("cpu", dtype=amp_dtype, enabled=use_amp):
            losses = model(images, targets)
        optimizer.zero_grad()
        sum(losses.values()).backward()
        optimizer.step()

    for index in range(arguments.warmup):
        step(index)
    if arguments.profile:
        _print_profile(step, arguments.steps)
        return
    started = time.perf_counter()
    for index in range(arguments.steps):
        step(index)
    seconds = time.perf_counter() - started
    print(json.dumps({
        "configuration": arguments.configuration,
        "batch_size": setting["batch_size"],
        "image_size": setting["image_size"],
        "threads": torch.get_num_threads(),
        "precision": precision_name(config, torch.device("cpu")),
        "seconds_per_step": seconds / arguments.steps,
        "images_per_second": arguments.steps * setting["batch_size"] / seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "parameters_millions": sum(parameter.numel() for parameter in model.parameters()) / 1e6,
    }))


def _print_profile(step: Callable[[int], None], steps: int, rows: int = 25) -> None:
    """Run ``steps`` steps under torch.profiler; print the operators by self CPU time, by input shapes."""
    from torch.profiler import ProfilerActivity, profile  # noqa: PLC0415

    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as profiler:
        for index in range(steps):
            step(index)
    events = profiler.key_averages(group_by_input_shape=True)
    total = sum(event.self_cpu_time_total for event in events)
    convolutions = sum(event.self_cpu_time_total for event in events if "convolution" in event.key)
    print(f"{steps} steps, {total / 1e3 / steps:.0f} ms of operators per step, "
          f"{100 * convolutions / total:.0f} % in convolutions (forward and backward)")
    print(f"{'operator':<34} {'ms/step':>8} {'share':>6} {'calls':>6}  first input shapes")
    for event in sorted(events, key=lambda event: -event.self_cpu_time_total)[:rows]:
        print(f"{event.key[:34]:<34} {event.self_cpu_time_total / 1e3 / steps:>8.1f} "
              f"{100 * event.self_cpu_time_total / total:>5.1f}% {event.count / steps:>6.1f}  {event.input_shapes[:2]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", help="Data dir with samples shards (default: synthetic samples).")
    parser.add_argument("--pipeline", default=None, help="Pipeline whose samples to read from --data.")
    parser.add_argument("--backbone", default="resnet18")
    parser.add_argument("--steps", type=int, default=16, help="timed steps")
    parser.add_argument("--warmup", type=int, default=12,
                        help="untimed steps first: a fresh model's first steps are slower than the rest of a run "
                        "(the configuration before the recipe: 2.5-2.9 s for its first 6 steps on a 2-core EPYC, then "
                        "1.0-1.4 s), and a training run is nearly all later steps")
    parser.add_argument("--profile", choices=list(configurations()), metavar="CONFIGURATION",
                        help="instead of the comparison, run this one configuration here under torch.profiler and "
                        "print where its timed steps go: operators by self CPU time and input shapes")
    parser.add_argument("--only", nargs="+", choices=list(configurations()), metavar="CONFIGURATION",
                        help=f"run only these configurations (default: all of {', '.join(configurations())})")
    parser.add_argument("--configuration", help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    if arguments.profile:
        arguments.configuration = arguments.profile
    if arguments.configuration:
        child(arguments)
        return
    print(f"TOG training on the CPU, {arguments.backbone}, {arguments.steps} timed steps after "
          f"{arguments.warmup}, {'samples of ' + arguments.data if arguments.data else 'synthetic samples'}"
          + "".join(f", {name}={os.environ[name]}" for name in INSTRUCTION_SET_CAPS if os.environ.get(name)))
    print(f"{'configuration':<20} {'batch':>5} {'s/step':>8} {'img/s':>8} {'peak RSS MiB':>13} {'params M':>9} "
          f"{'precision':>9}")
    results = {}
    for name in arguments.only or configurations():
        command = [sys.executable, __file__, "--configuration", name, "--backbone", arguments.backbone,
                   "--steps", str(arguments.steps), "--warmup", str(arguments.warmup)]
        if arguments.data:
            command += ["--data", arguments.data] + (["--pipeline", arguments.pipeline] if arguments.pipeline else [])
        completed = subprocess.run(command, capture_output=True, text=True, check=False, cwd=ROOT)
        if completed.returncode != 0:
            print(f"{name:<20} failed: {completed.stderr.strip().splitlines()[-1:]}")
            continue
        result = results[name] = json.loads(completed.stdout.strip().splitlines()[-1])
        print(f"{name:<20} {result['batch_size']:>5} {result['seconds_per_step']:>8.2f} "
              f"{result['images_per_second']:>8.2f} {result['peak_rss_mib']:>13.0f} "
              f"{result['parameters_millions']:>9.1f} {result['precision']:>9}")
    for faster, baseline in RATIOS:
        if faster in results and baseline in results:
            ratio = results[faster]["images_per_second"] / results[baseline]["images_per_second"]
            print(f"{faster} / {baseline}: {ratio:.2f}x images per second")


if __name__ == "__main__":
    main()
