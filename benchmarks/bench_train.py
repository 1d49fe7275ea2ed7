"""Training throughput and peak memory of the TOG-CRFs model per backbone.

Each backbone runs in its own child process, so that the peak resident
memory (``ru_maxrss``) belongs to that backbone alone. A child writes
synthetic samples (tests/helpers.py), trains ``--warmup`` steps untimed,
then ``--steps`` timed steps of ``--batch-size`` images at ``--image-size``
px with the default model options, and prints one JSON line.

Usage::

    python benchmarks/bench_train.py                       # CPU, 128 px, resnet18/34/50/101
    python benchmarks/bench_train.py --device cuda --image-size 512 --batch-size 4
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(arguments: argparse.Namespace) -> None:
    import torch  # noqa: PLC0415

    sys.path.insert(0, str(ROOT / "tests"))
    from helpers import write_synthetic_samples  # noqa: PLC0415

    from osgd.store import ShardStore  # noqa: PLC0415
    from togcrf.data import SamplesDataset, collate  # noqa: PLC0415
    from togcrf.model import build_model  # noqa: PLC0415

    torch.manual_seed(0)
    device = torch.device(arguments.device)
    with tempfile.TemporaryDirectory() as directory:
        write_synthetic_samples(ShardStore(directory), arguments.batch_size * 2,
                                height=arguments.image_size, width=arguments.image_size)
        dataset = SamplesDataset(directory, pipeline="synthetic", split=None, image_size=arguments.image_size,
                                 augment=True)
        batches = [collate([dataset[index] for index in range(start, start + arguments.batch_size)])
                   for start in (0, arguments.batch_size)]
    model = build_model("tog-crfs", arguments.backbone).to(device)
    model.train()
    optimizer = torch.optim.SGD(model.parameters(), lr=0.001, momentum=0.9)
    use_amp = device.type == "cuda"

    def step(index: int) -> None:
        images, targets, _ = batches[index % 2]
        images = [image.to(device) for image in images]
        targets = [{key: value.to(device) for key, value in target.items()} for target in targets]
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16, enabled=use_amp):
            losses = model(images, targets)
        optimizer.zero_grad()
        sum(losses.values()).backward()
        optimizer.step()

    for index in range(arguments.warmup):
        step(index)
    if device.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    started = time.perf_counter()
    for index in range(arguments.steps):
        step(index)
    if device.type == "cuda":
        torch.cuda.synchronize()
    seconds = time.perf_counter() - started
    result = {
        "backbone": arguments.backbone,
        "device": arguments.device,
        "image_size": arguments.image_size,
        "batch_size": arguments.batch_size,
        "threads": torch.get_num_threads(),
        "seconds_per_step": seconds / arguments.steps,
        "images_per_second": arguments.steps * arguments.batch_size / seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "parameters_millions": sum(parameter.numel() for parameter in model.parameters()) / 1e6,
    }
    if device.type == "cuda":
        result["peak_cuda_mib"] = torch.cuda.max_memory_allocated() / 2**20
    print(json.dumps(result))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backbones", nargs="+", default=["resnet18", "resnet34", "resnet50", "resnet101"])
    parser.add_argument("--backbone", help=argparse.SUPPRESS)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--image-size", type=int, default=128)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--warmup", type=int, default=1)
    arguments = parser.parse_args()
    if arguments.backbone:
        child(arguments)
        return
    print(f"TOG-CRFs training, {arguments.device}, {arguments.image_size} px, batch {arguments.batch_size}, "
          f"{arguments.steps} timed steps after {arguments.warmup}")
    print(f"{'backbone':<10} {'s/step':>8} {'img/s':>8} {'peak RSS MiB':>13} {'params M':>9}")
    for backbone in arguments.backbones:
        command = [sys.executable, __file__, "--backbone", backbone, "--device", arguments.device,
                   "--image-size", str(arguments.image_size), "--batch-size", str(arguments.batch_size),
                   "--steps", str(arguments.steps), "--warmup", str(arguments.warmup)]
        completed = subprocess.run(command, capture_output=True, text=True, check=False, cwd=ROOT)
        if completed.returncode != 0:
            print(f"{backbone:<10} failed: {completed.stderr.strip().splitlines()[-1:]}")
            continue
        result = json.loads(completed.stdout.strip().splitlines()[-1])
        line = (f"{backbone:<10} {result['seconds_per_step']:>8.2f} {result['images_per_second']:>8.2f} "
                f"{result['peak_rss_mib']:>13.0f} {result['parameters_millions']:>9.1f}")
        if "peak_cuda_mib" in result:
            line += f"  peak CUDA {result['peak_cuda_mib']:.0f} MiB"
        print(line)
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"largest child peak RSS: {children:.0f} MiB")


if __name__ == "__main__":
    main()
