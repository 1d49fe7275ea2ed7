"""The engine of training and evaluation: one epoch of training, the evaluation of a model, device and precision.

:func:`train_one_epoch` runs one pass over a :class:`TrainingRun`'s data and returns the epoch's metrics
row; :func:`evaluate_model` scores a model on samples with :mod:`togcrf.metrics` and measures its speed.
``togcrf.train`` builds the run and drives the epochs; ``togcrf.evaluate`` loads checkpoints and writes
evaluation documents. Seeding: ``torch.manual_seed(seed + epoch)`` at the start of every epoch (RoI
sampling), so that a resumed run continues as the uninterrupted one would.

Precision: on CUDA with ``amp``, bfloat16 autocast where supported, else float16 with loss scaling; on a
CPU with ``cpu_bf16``, bfloat16 autocast where the CPU computes bfloat16 natively (AVX-512 BF16 or AMX),
float32 elsewhere.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader

from togcrf import distributed
from togcrf.config import TrainConfig
from togcrf.crf import MeanFieldCrf
from togcrf.data import SamplesDataset, ShardGroupedSampler, depth_to_tensor
from togcrf.losses import LOSS_KEYS
from togcrf.metrics import TOP_K, Detections, GroundTruth, TableTwoEvaluator, measure_speed
from togcrf.tta import view_averaged_output

#: Held-out metrics per epoch in metrics.csv (``val_`` + the Table II column).
VALIDATION_COLUMNS = ("val_mAP", "val_mAP-G", "val_Acc-T top1")


@dataclass(frozen=True)
class Progress:
    """One progress event for a callback: after each step (``step``) and after each epoch (``metrics``)."""

    epoch: int
    epochs: int
    step: int
    steps: int
    losses: dict[str, float]
    metrics: dict[str, float] | None = None
    images_per_second: float | None = None
    #: Fraction of the time budget spent so far (its clock counts training steps only); None without a budget.
    budget_spent: float | None = None


def resolve_device(name: str) -> torch.device:
    """"auto" -> CUDA when available, else CPU; "cuda" without a GPU raises."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device is available")
    return torch.device(name)


@dataclass
class TrainingRun:
    """What one training run carries from epoch to epoch."""

    config: TrainConfig
    device: torch.device
    model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LambdaLR
    loader: DataLoader
    dataset: SamplesDataset
    sampler: ShardGroupedSampler
    validation: list[int]
    context: distributed.Context = field(default_factory=distributed.Context)
    forward: torch.nn.Module | None = None  # the model, or DistributedDataParallel around it
    scaler: torch.amp.GradScaler | None = None  # loss scaling of float16 mixed precision (disabled otherwise)
    trained_seconds: float = 0.0
    global_step: int = 0
    out_of_time: bool = False

    def budget_spent(self) -> float:
        """Fraction of the time budget spent (0 without a budget)."""
        budget = self.config.time_budget_minutes
        return 0.0 if budget is None else self.trained_seconds / (60.0 * budget)


def _to_device(images: list[torch.Tensor], targets: list[dict[str, torch.Tensor]], device: torch.device):
    return ([image.to(device, non_blocking=True) for image in images],
            [{key: value.to(device, non_blocking=True) for key, value in target.items()} for target in targets])


def cpu_has_native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX-512 BF16 or AMX tiles), so that autocast pays.

    torch's own CPU-feature probes (private: a torch without them reads False).
    """
    probes = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(bool(getattr(torch.cpu, probe, lambda: False)()) for probe in probes)


def mixed_precision(config: TrainConfig, device: torch.device) -> tuple[bool, torch.dtype]:
    """Whether the forward pass runs under autocast, and in which type.

    CUDA with ``amp``: bfloat16 where supported, else float16 (with loss
    scaling). CPU with ``cpu_bf16``: bfloat16 where the CPU has it natively.
    """
    if device.type == "cuda":
        use_amp = config.amp
        return use_amp, torch.bfloat16 if use_amp and torch.cuda.is_bf16_supported() else torch.float16
    use_amp = config.cpu_bf16 and device.type == "cpu" and cpu_has_native_bfloat16()
    return use_amp, torch.bfloat16


def precision_name(config: TrainConfig, device: torch.device) -> str:
    """The precision a run's forward pass computes in: float32, bfloat16 or float16."""
    use_amp, amp_dtype = mixed_precision(config, device)
    return str(amp_dtype).removeprefix("torch.") if use_amp else "float32"


def train_one_epoch(run: TrainingRun, epoch: int, progress: Callable[[Progress], None] | None = None,
                    writer: Any = None) -> dict[str, Any]:
    """One pass over the training data; the epoch's metrics row (losses averaged over its steps)."""
    config, model, optimizer = run.config, run.model, run.optimizer
    use_amp, amp_dtype = mixed_precision(config, run.device)
    scaler = run.scaler
    model.train()
    run.dataset.set_epoch(epoch)
    run.sampler.set_epoch(epoch)
    torch.manual_seed(config.seed + epoch)
    sums = dict.fromkeys(LOSS_KEYS, 0.0)
    hits = rois = samples = steps = 0
    started = time.perf_counter()
    for cpu_images, cpu_targets, sample_ids in run.loader:
        step_started = time.perf_counter()
        images, targets = _to_device(cpu_images, cpu_targets, run.device)
        with torch.autocast(device_type=run.device.type, dtype=amp_dtype, enabled=use_amp):
            losses = run.forward(images, targets)
        total = sum(losses.values())
        if not torch.isfinite(total):
            terms = {key: float(value) for key, value in losses.items()}
            raise FloatingPointError(f"non-finite loss at epoch {epoch} step {steps} (samples {sample_ids}): "
                                     f"{terms}; lower --lr or check the data")
        optimizer.zero_grad(set_to_none=True)
        scaler.scale(total).backward()
        if config.clip_grad_norm > 0:
            scaler.unscale_(optimizer)
            torch.nn.utils.clip_grad_norm_(model.parameters(), config.clip_grad_norm)
        scaler.step(optimizer)
        scaler.update()
        run.scheduler.step()
        run.global_step += 1
        # rank 0's clock in every process, so that all stop at the same step of a time budget
        run.trained_seconds += distributed.rank_zero_value(time.perf_counter() - step_started, run.context,
                                                           run.device)
        if config.time_budget_minutes is not None and config.lr_schedule == "cosine":
            _follow_the_budget(run)
        steps += 1
        samples += len(images)
        step_losses = {key: float(value.detach()) for key, value in losses.items()}
        for key in LOSS_KEYS:
            sums[key] += step_losses.get(key, 0.0)
        stats = getattr(model, "last_training_stats", {})
        hits += stats.get("acc_t_hits", 0)
        rois += stats.get("acc_t_rois", 0)
        if writer is not None:
            for key, value in step_losses.items():
                writer.add_scalar(f"step/{key}", value, run.global_step)
        if progress is not None:
            progress(Progress(epoch, config.epochs, steps, len(run.loader), step_losses,
                              images_per_second=samples / max(time.perf_counter() - started, 1e-9),
                              budget_spent=None if config.time_budget_minutes is None else run.budget_spent()))
        if run.budget_spent() >= 1.0:
            run.out_of_time = True
            break
    seconds = time.perf_counter() - started
    means = {key: value / max(steps, 1) for key, value in sums.items()}
    return {"epoch": epoch, "steps": steps, "samples": samples, "seconds": round(seconds, 3),
            "images_per_second": round(samples / max(seconds, 1e-9), 3), "lr": optimizer.param_groups[0]["lr"],
            "loss": sum(means.values()), **means, "train_acc_t_top1": hits / rois if rois else float("nan")}


def _follow_the_budget(run: TrainingRun) -> None:
    """Set the learning rate from the spent fraction of the time budget: warm-up, then a cosine to 0."""
    schedule = run.scheduler.lr_lambdas[0]
    warmup = 1.0 if run.global_step >= schedule.warmup_steps else 0.01 + 0.99 * run.global_step / max(
        1, schedule.warmup_steps)
    factor = warmup * 0.5 * (1.0 + math.cos(math.pi * min(1.0, run.budget_spent())))
    for group, base in zip(run.optimizer.param_groups, run.scheduler.base_lrs, strict=True):
        group["lr"] = base * factor


def validation_metrics(run: TrainingRun) -> dict[str, float]:
    """Held-out mAP, mAP-G and Acc-T top-1 of the run's model on its validation slice (empty without one)."""
    if not run.validation:
        return {}
    result = evaluate_model(run.model, run.validation, run.config.image_size, device=str(run.device),
                            speed_images=0, depth_reference=run.config.depth_reference)
    metrics = result["metrics"]
    return {f"val_{name}": float(metrics.get(name, float("nan"))) for name in ("mAP", "mAP-G", "Acc-T top1")}


def prediction_to_numpy(output: dict[str, torch.Tensor], scale: float) -> Detections:
    """One image's model output (the contract's eval format) in the sample's pixel frame.

    Parameters
    ----------
    output : dict of tensors
        ``boxes`` (N, 4), ``labels`` (N,) category index + 1, ``scores``
        (N,), ``grasps`` (N, K, 5), ``grasp_stability`` (N, K),
        ``grasp_task_probs`` (N, K, T) over the model's T tasks, all in network-input pixels.
    scale : float
        The factor :func:`togcrf.data.depth_to_tensor` applied to the image.

    Returns
    -------
    Detections
        Boxes and grasp centres and sizes divided by ``scale``; angles kept.
    """
    def array(name: str) -> np.ndarray:
        return output[name].detach().to("cpu", torch.float64).numpy()

    boxes = array("boxes").reshape(-1, 4) / scale
    count = len(boxes)
    # The model's own (N, K, ...) shapes, so that N = 0 (nothing detected)
    # keeps K and the task count instead of leaving -1 to infer from nothing.
    grasps = array("grasps").reshape(count, *output["grasps"].shape[1:2] or (0,), 5).copy()
    grasps[..., :4] /= scale
    task_probs = array("grasp_task_probs")
    return Detections(
        boxes=boxes,
        categories=output["labels"].detach().cpu().numpy().astype(np.int64).reshape(-1) - 1,
        scores=array("scores").reshape(-1),
        grasps=grasps,
        grasp_stability=array("grasp_stability").reshape(count, grasps.shape[1]),
        grasp_task_probs=task_probs.reshape(count, grasps.shape[1], task_probs.shape[-1] if task_probs.ndim else 0),
    )


def run_model(model: torch.nn.Module, image: torch.Tensor, scale: float, views: int = 1) -> Detections:
    """Detections of a model (eval mode) on one ``(1, H, W)`` image tensor, in sample pixels.

    ``views`` > 1 averages the grasp candidates over that many test-time views (:mod:`togcrf.tta`).
    """
    with torch.inference_mode():
        output = view_averaged_output(model, image, views)
    return prediction_to_numpy(output, scale)


def evaluate_model(
    model: torch.nn.Module,
    samples: Iterable[Any],
    image_size: int | None,
    *,
    device: str = "cpu",
    speed_images: int = 10,
    unmatched_task: str = "nearest",
    protocol: str = "ours",
    depth_reference: str = "table",
    views: int = 1,
    protocols: Sequence[str] = (),
) -> dict[str, Any]:
    """Table II metrics and speed of a model on samples.

    Parameters
    ----------
    model : torch.nn.Module
        In eval mode, on ``device``.
    samples : iterable of ``osgd.contract.samples.Sample``
    image_size : int or None
        Passed to :func:`togcrf.data.depth_to_tensor` (the training config's).
    device : str
    speed_images : int
        How many of the first images are kept for the speed measurement
        (after the metrics pass, so the model is warm; 0 skips it).
    unmatched_task : {"nearest", "wrong"}
        See :mod:`togcrf.metrics` (Acc-T).
    protocol : {"ours", "lab"}
        The rules of mAP and mAP-G (:mod:`togcrf.metrics`, Protocols).
    depth_reference : {"table", "median"}
        Passed to :func:`togcrf.data.depth_to_tensor` (the training config's).
    views : int
        Test-time views averaged per image (:mod:`togcrf.tta`, ``VIEW_COUNTS``); 1: the image as given.
        The speed is measured with the same views.
    protocols : sequence of str
        Further protocols scored on the same detections (one pass of the model).

    Returns
    -------
    dict
        ``metrics`` (with its ``protocol``) and ``speed`` (None when skipped); with ``protocols``, also
        ``metrics_by_protocol``: ``protocol`` and each of ``protocols`` to its metrics.

    Raises
    ------
    ValueError
        If there are no samples, the protocol is unknown, or the views are not allowed for the model.
    """
    categories = model.vocabulary["categories"]
    evaluators = {name: TableTwoEvaluator(top_k=TOP_K, unmatched_task=unmatched_task, protocol=name,
                                          categories=categories)
                  for name in dict.fromkeys([protocol, *protocols])}
    evaluator = evaluators[protocol]
    kept_images: list[torch.Tensor] = []
    model.eval()
    for sample in samples:
        image, scale = depth_to_tensor(sample.depth, image_size, depth_reference)
        image = image.to(device)
        detections, truth = run_model(model, image, scale, views), GroundTruth.from_sample(sample)
        for each in evaluators.values():
            each.add(detections, truth)
        if len(kept_images) < speed_images:
            kept_images.append(image)
    if evaluator.images == 0:
        raise ValueError("no samples to evaluate")
    speed = None
    if kept_images:
        def run_once(image: torch.Tensor) -> None:
            with torch.inference_mode():
                view_averaged_output(model, image, views)

        speed = dict(measure_speed(run_once, kept_images, warmup=min(2, len(kept_images)), device=device))
        speed.update(crf_time_share(model, run_once, kept_images, device))
    scored = {name: each.result() for name, each in evaluators.items()}
    result = {"metrics": scored[protocol], "speed": speed}
    if protocols:
        result["metrics_by_protocol"] = scored
    return result


def crf_time_share(model: torch.nn.Module, run_once: Any, inputs: list[torch.Tensor], device: str) -> dict[str, float]:
    """Seconds per image spent in the model's CRF, and their share of the whole (paper V-B discusses its cost).

    A second pass over ``inputs`` with a timer around every
    :class:`togcrf.crf.MeanFieldCrf` forward (CUDA synchronised at both
    ends, so this pass runs a little slower than the speed pass). Models
    without a CRF give ``{}``.
    """
    modules = [module for module in model.modules() if isinstance(module, MeanFieldCrf)]
    if not modules:
        return {}
    synchronise = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    spent = [0.0]
    started: list[float] = []

    def before(*_: Any) -> None:
        synchronise()
        started.append(time.perf_counter())

    def after(*_: Any) -> None:
        synchronise()
        spent[0] += time.perf_counter() - started.pop()

    handles = [hook for module in modules
               for hook in (module.register_forward_pre_hook(before), module.register_forward_hook(after))]
    try:
        synchronise()
        start = time.perf_counter()
        for image in inputs:
            run_once(image)
        synchronise()
        total = time.perf_counter() - start
    finally:
        for handle in handles:
            handle.remove()
    return {"crf_seconds_per_image": spent[0] / len(inputs), "crf_share": spent[0] / total if total > 0 else 0.0}
