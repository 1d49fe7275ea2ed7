"""Training from ``samples`` shards, checkpoints, and the ``togcrf train`` command.

The library entry point is :func:`train` (no printing; progress goes to an
optional callback and to ``logging``); the command wraps it with a progress
bar. A run dir holds:

- ``config.json``: every training option, the model options, the precision
  that ran (``precision``) and the data identity;
- ``metrics.csv``: one row per epoch: mean of every loss term, the total,
  the learning rate, seconds, images per second, ``train_acc_t_top1``
  measured on the fly (``togcrf.losses.top1_task_hits``) and, with
  ``val_samples``, the held-out ``val_mAP``, ``val_mAP-G`` and
  ``val_Acc-T top1`` of the epoch's model (``togcrf curves`` draws them);
- ``train.log``: the progress lines (step, losses, images/s, time left);
- ``checkpoint.pt``: the latest epoch (contract: "model", "optimizer",
  "scheduler", "epoch", "config", "data");
- ``tensorboard/``: the same scalars, when the ``tensorboard`` package is installed.

Defaults follow the paper (Section V): 10 epochs, SGD, lr 0.001, momentum
0.9. Our additions: a linear warm-up over the first ``warmup_steps`` steps
and gradient-norm clipping, both because the detector is trained from
scratch (no pretrained weights can be downloaded) and the first steps of the
randomly initialised grasp head have large gradients; weight decay 1e-4 as
torchvision's detection references; AdamW and a cosine schedule as options
(the CPU recipe, ``togcrf.reproduce.CPU_SCALE``), and bfloat16 autocast on a
CPU that computes bfloat16 natively (``cpu_bf16``, the recipe since
2026-11-28). The validation slice is
the last ``val_samples`` samples of the training split, held out of
training. Seeding: ``torch.manual_seed(seed +
epoch)`` at the start of every epoch (RoI sampling), augmentation drawn from
``(seed, epoch, item)`` and a seeded shard-grouped data order, so a resumed
run continues as the uninterrupted one would.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import torch
import typer
from torch.utils.data import DataLoader

from togcrf import distributed
from togcrf.checkpoint import check_vocabulary, current_vocabulary, read_checkpoint, save_checkpoint
from togcrf.data import DEPTH_REFERENCES, SamplesDataset, ShardGroupedSampler, collate
from togcrf.losses import LOSS_KEYS
from togcrf.model import BACKBONES, MODEL_NAMES, build_model

logger = logging.getLogger(__name__)

#: Optimisers of ``--optimizer``.
OPTIMIZERS = ("sgd", "adamw")

#: Learning-rate schedules of ``--lr-schedule``.
LR_SCHEDULES = ("step", "cosine")

#: Held-out metrics per epoch in metrics.csv (``val_`` + the Table II column).
VALIDATION_COLUMNS = ("val_mAP", "val_mAP-G", "val_Acc-T top1")

#: Loss terms in metrics.csv, in order (the model's loss keys, ``togcrf.losses.LOSS_KEYS``).
LOSS_TERMS = LOSS_KEYS


@dataclass
class TrainConfig:
    """Every option of a training run (all are written to config.json and the checkpoint).

    Attributes
    ----------
    data : str
        Data dir with ``samples`` shards.
    out : str
        Run dir.
    pipeline : str or None
        Use the shards of this pipeline's manifest (else every samples shard).
    model : str
        One of ``togcrf.model.MODEL_NAMES``.
    backbone : str
        resnet18/34/50/101 (the paper: resnet101).
    epochs : int
        Paper: 10.
    lr, momentum : float
        SGD, paper: 0.001 and 0.9.
    weight_decay : float
    batch_size : int
    image_size : int or None
        Longer image side fed to the network (None: native).
    augment : bool
        Flips, quarter turns, scale jitter.
    warmup_steps : int
        Linear learning-rate warm-up from lr / 100 (our choice, see module docstring).
    lr_decay_epochs : list of int
        Multiply the learning rate by 0.1 from each of these epochs on (none by default: the paper gives none).
    clip_grad_norm : float
        Gradient-norm clipping (0 disables).
    device : {"auto", "cpu", "cuda"}
    amp : bool
        Mixed precision (bfloat16, or float16 with loss scaling) on CUDA.
    cpu_bf16 : bool
        bfloat16 autocast of the forward pass on the CPU, where the CPU
        computes bfloat16 natively (AVX-512 BF16 or AMX: oneDNN's
        convolutions then run about 1.35x faster, docs/togcrf-evaluation.md
        "bfloat16 on the CPU"); on other CPUs the run stays float32 and says
        so in its log. The run's ``config.json`` records the precision that
        ran (``precision``).
    seed : int
    max_samples : int or None
        Use only the first samples (quick runs).
    workers : int
        DataLoader worker processes.
    split : str
        Split trained on.
    model_options : dict
        ``togcrf.model.ModelOptions`` overrides.
    resume : bool
        Continue ``out/checkpoint.pt`` (without it an existing checkpoint is an error).
    optimizer : {"sgd", "adamw"}
        SGD with ``momentum`` (paper), or AdamW (betas 0.9, 0.999).
    lr_schedule : {"step", "cosine"}
        "step": 0.1 from each of ``lr_decay_epochs``; "cosine": from ``lr``
        to 0 over all epochs' steps, after the warm-up.
    scale_jitter : float
        Augmentation scales are drawn from ``[1 - scale_jitter, 1]``.
    depth_reference : {"table", "median"}
        What the input height is measured from (``togcrf.data.DEPTH_REFERENCES``): the
        fitted table plane (the recipe) or the image's median depth (before it).
    val_samples : int
        Samples at the end of the training split held out for per-epoch
        validation metrics (0: none).
    init : str or None
        Start from the model weights of this checkpoint (fine-tuning): the
        model and its options must give the same layers, bar new layers that
        ``train_only`` names; the optimiser, schedule and epochs start afresh.
    train_only : list of str
        Train only the parameters whose names start with one of these
        prefixes (e.g. ``grasp_head.confidence``); the others stay frozen.
        Empty: train every parameter.
    time_budget_minutes : float or None
        Stop after the step that exceeds this much training time (the steps'
        time, validation excluded; kept across ``--resume``); the checkpoint
        then holds the partial epoch and the run is complete. With the cosine
        schedule the learning rate then follows the spent fraction of the
        budget instead of the steps, so that it reaches 0 when the time is
        up whatever the machine's speed (``epochs`` is then an upper bound;
        such a run is not bit-reproducible).
    """

    data: str
    out: str
    pipeline: str | None = None
    model: str = "tog-crfs"
    backbone: str = "resnet101"
    epochs: int = 10
    lr: float = 0.001
    momentum: float = 0.9
    weight_decay: float = 1e-4
    batch_size: int = 2
    image_size: int | None = None
    augment: bool = True
    warmup_steps: int = 100
    lr_decay_epochs: list[int] = field(default_factory=list)
    clip_grad_norm: float = 10.0
    device: str = "auto"
    amp: bool = True
    cpu_bf16: bool = False
    seed: int = 0
    max_samples: int | None = None
    workers: int = 0
    split: str = "train"
    model_options: dict[str, Any] = field(default_factory=dict)
    resume: bool = False
    optimizer: str = "sgd"
    lr_schedule: str = "step"
    scale_jitter: float = 0.1
    depth_reference: str = "table"
    val_samples: int = 0
    time_budget_minutes: float | None = None
    init: str | None = None
    train_only: list[str] = field(default_factory=list)

    def validate(self) -> None:
        """Raise ValueError naming the bad option."""
        if self.model not in MODEL_NAMES:
            raise ValueError(f"--model {self.model!r}: expected one of {MODEL_NAMES}")
        if self.backbone not in BACKBONES:
            raise ValueError(f"--backbone {self.backbone!r}: expected one of {BACKBONES}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise ValueError(f"--device {self.device!r}: expected auto, cpu or cuda")
        if self.epochs < 1 or self.batch_size < 1 or self.lr <= 0:
            raise ValueError(f"epochs ({self.epochs}), batch size ({self.batch_size}) and lr ({self.lr}) must be > 0")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"--optimizer {self.optimizer!r}: expected one of {OPTIMIZERS}")
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(f"--lr-schedule {self.lr_schedule!r}: expected one of {LR_SCHEDULES}")
        if not 0 <= self.scale_jitter < 1:
            raise ValueError(f"--scale-jitter {self.scale_jitter}: expected a value in [0, 1)")
        if self.depth_reference not in DEPTH_REFERENCES:
            raise ValueError(f"--depth-reference {self.depth_reference!r}: expected one of {DEPTH_REFERENCES}")
        if self.val_samples < 0:
            raise ValueError(f"--val-samples {self.val_samples}: expected 0 or more")
        if self.time_budget_minutes is not None and not self.time_budget_minutes > 0:
            raise ValueError(f"--time-budget {self.time_budget_minutes}: expected minutes > 0, or no budget "
                             "(None here; 0 or left out on the command line)")


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


class WarmupSchedule:
    """Learning-rate factor per optimiser step: linear warm-up, then step decay or a cosine to 0.

    A callable object (not a closure) so that ``LambdaLR.state_dict`` saves it.
    """

    def __init__(self, warmup_steps: int, steps_per_epoch: int, decay_epochs: list[int],
                 cosine_steps: int | None = None) -> None:
        self.warmup_steps = warmup_steps
        self.steps_per_epoch = max(1, steps_per_epoch)
        self.decay_epochs = sorted(decay_epochs)
        self.cosine_steps = cosine_steps

    def __call__(self, step: int) -> float:
        warmup = 1.0 if step >= self.warmup_steps else 0.01 + 0.99 * step / self.warmup_steps
        if self.cosine_steps is not None:
            span = max(1, self.cosine_steps - self.warmup_steps)
            progress = min(1.0, max(0, step - self.warmup_steps) / span)
            return warmup * 0.5 * (1.0 + math.cos(math.pi * progress))
        epoch = step // self.steps_per_epoch
        return warmup * 0.1 ** sum(epoch >= decay for decay in self.decay_epochs)


def build_optimizer(model: torch.nn.Module, config: TrainConfig) -> torch.optim.Optimizer:
    """The optimiser of ``config.optimizer``; no weight decay on normalisation weights and biases with AdamW."""
    parameters = [parameter for parameter in model.parameters() if parameter.requires_grad]
    if config.optimizer == "sgd":
        return torch.optim.SGD(parameters, lr=config.lr, momentum=config.momentum, weight_decay=config.weight_decay)
    decayed = [parameter for parameter in parameters if parameter.dim() > 1]
    plain = [parameter for parameter in parameters if parameter.dim() <= 1]
    # fused: one kernel over all parameters instead of a Python loop per tensor (4.4x faster steps of the
    # optimiser on one CPU thread for the 192 px recipe's 118 tensors: 22 ms against 100 ms)
    return torch.optim.AdamW([{"params": decayed, "weight_decay": config.weight_decay},
                              {"params": plain, "weight_decay": 0.0}], lr=config.lr, fused=True)


def _to_device(images: list[torch.Tensor], targets: list[dict[str, torch.Tensor]], device: torch.device):
    return ([image.to(device, non_blocking=True) for image in images],
            [{key: value.to(device, non_blocking=True) for key, value in target.items()} for target in targets])


def _read_metrics(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    columns = ["epoch", "steps", "samples", "seconds", "images_per_second", "lr", "loss", *LOSS_TERMS,
               "train_acc_t_top1", *VALIDATION_COLUMNS]
    temporary = path.with_suffix(".csv.tmp")
    with temporary.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    os.replace(temporary, path)


def _tensorboard_writer(run_dir: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter  # noqa: PLC0415 - optional dependency
    except ImportError:
        return None
    return SummaryWriter(str(run_dir / "tensorboard"))


#: Config entries that must agree between a checkpoint and a run resuming it.
_RESUME_MUST_MATCH = ("model", "backbone", "image_size", "model_options", "batch_size", "optimizer",
                      "lr_schedule", "val_samples", "depth_reference", "train_only")


@dataclass
class _Run:
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


def _build_run(config: TrainConfig) -> tuple[_Run, dict[str, Any], dict[str, Any]]:
    """Data, model, optimiser and schedule of a run; the stored config and the data identity."""
    context = distributed.from_environment()
    device = distributed.process_device(context, resolve_device(config.device))
    distributed.start(context, device)
    dataset = SamplesDataset(config.data, pipeline=config.pipeline, split=config.split,
                             image_size=config.image_size, augment=config.augment, seed=config.seed,
                             max_samples=config.max_samples, scale_jitter=config.scale_jitter,
                             depth_reference=config.depth_reference,
                             instance_masks=bool(config.model_options.get("grasp_object_map", False)))
    check_vocabulary(current_vocabulary(), dataset.vocabulary, f"the model of this code (--model {config.model})",
                     f"{config.data}/samples")
    if config.val_samples and config.val_samples >= len(dataset):
        raise ValueError(f"--val-samples {config.val_samples}: the training split has only {len(dataset)}")
    kept = len(dataset) - config.val_samples
    validation_samples = [dataset.read_sample(item) for item in range(kept, len(dataset))]
    dataset.index = dataset.index[:kept]
    sampler = ShardGroupedSampler(dataset, seed=config.seed, rank=context.rank, world=context.world,
                                  batch_size=config.batch_size)
    loader = DataLoader(dataset, batch_size=config.batch_size, sampler=sampler, collate_fn=collate,
                        num_workers=config.workers, pin_memory=device.type == "cuda")
    data_identity = {"data_dir": str(Path(config.data).resolve()), "pipeline": config.pipeline,
                     "split": config.split, "shards": dataset.shard_keys(), "samples": len(dataset),
                     "validation_samples": [sample.sample_id for sample in validation_samples]}
    torch.manual_seed(config.seed)
    model = build_model(config.model, config.backbone, **config.model_options).to(device)
    if config.init:
        _load_initial_weights(model, Path(config.init), device, config.train_only)
    _freeze_all_but(model, config.train_only)
    stored_config = {**asdict(config), "model_options": _model_options(model, config),
                     "precision": precision_name(config, device)}
    if config.cpu_bf16 and device.type == "cpu" and stored_config["precision"] == "float32":
        logger.warning("--cpu-bf16: this CPU has no native bfloat16 (AVX-512 BF16 or AMX); training in float32")
    optimizer = build_optimizer(model, config)
    cosine_steps = config.epochs * len(loader) if config.lr_schedule == "cosine" else None
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, WarmupSchedule(config.warmup_steps, len(loader), config.lr_decay_epochs, cosine_steps))
    use_amp, amp_dtype = mixed_precision(config, device)
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    run = _Run(config, device, model, optimizer, scheduler, loader, dataset, sampler, validation_samples,
               context, distributed.wrap(model, context, device), scaler)
    return run, stored_config, data_identity


def _load_initial_weights(model: torch.nn.Module, path: Path, device: torch.device,
                          new_layers: list[str] = ()) -> None:
    """Copy the model weights of a checkpoint into ``model`` (``--init``); layers under ``new_layers`` may be
    missing from it (they keep their initialisation)."""
    if not path.is_file():
        raise FileNotFoundError(f"--init {path}: no such checkpoint")
    weights = read_checkpoint(path, device)["model"]
    own = model.state_dict()
    new = [name for name in own if name not in weights and name.startswith(tuple(new_layers))]
    try:
        model.load_state_dict({**weights, **{name: own[name] for name in new}})
    except RuntimeError as error:
        first = str(error).strip().splitlines()[0]
        raise ValueError(f"--init {path}: its layers differ from this model's ({first}); use the same "
                         "--model, --backbone and layer options") from error
    logger.info("initial weights from %s%s", path, f" ({len(new)} new tensors kept as initialised)" if new else "")


def _freeze_all_but(model: torch.nn.Module, prefixes: list[str]) -> None:
    """Stop the gradients of every parameter whose name starts with none of ``prefixes`` (``--train-only``)."""
    if not prefixes:
        return
    trained = 0
    for name, parameter in model.named_parameters():
        parameter.requires_grad_(name.startswith(tuple(prefixes)))
        trained += parameter.requires_grad
    if not trained:
        raise ValueError(f"--train-only {' '.join(prefixes)}: no parameter of this model has such a name "
                         "(e.g. grasp_head.confidence with --option grasp_confidence=true)")
    logger.info("training %d parameter tensors (--train-only %s); the others are frozen", trained,
                " ".join(prefixes))


def _with_this_implementation(state: dict[str, Any], optimizer: torch.optim.Optimizer) -> dict[str, Any]:
    """A saved optimiser state whose groups keep this optimiser's implementation flags (``fused``, ``foreach``).

    ``load_state_dict`` takes every group setting from the saved state, so a state saved before AdamW was
    fused would turn it back to the per-tensor loop, which then refuses the float16 loss scaler's scale.
    """
    groups = [{**saved, **{key: current[key] for key in ("fused", "foreach") if key in current}}
              for saved, current in zip(state["param_groups"], optimizer.param_groups, strict=False)]
    return {**state, "param_groups": groups}


def _resume(run: _Run, checkpoint_path: Path, stored_config: dict[str, Any]) -> int:
    """Load a checkpoint into the run; the first epoch still to train."""
    checkpoint = read_checkpoint(checkpoint_path, run.device)
    saved = {**checkpoint["config"], "model_options": _saved_model_options(checkpoint["config"], run.model)}
    for key in _RESUME_MUST_MATCH:
        if saved.get(key) != stored_config.get(key):
            raise ValueError(f"{checkpoint_path}: cannot resume, {key} was {saved.get(key)!r}, "
                             f"now {stored_config.get(key)!r}")
    run.model.load_state_dict(checkpoint["model"])
    run.optimizer.load_state_dict(_with_this_implementation(checkpoint["optimizer"], run.optimizer))
    run.scheduler.load_state_dict(checkpoint["scheduler"])
    if checkpoint.get("scaler"):  # absent from checkpoints written before it was saved (2026-11)
        run.scaler.load_state_dict(checkpoint["scaler"])
    logger.info("resuming %s after epoch %d", checkpoint_path, int(checkpoint["epoch"]))
    run.trained_seconds = float(checkpoint.get("trained_seconds", 0.0))
    if checkpoint.get("stopped_by_budget"):
        return run.config.epochs
    return int(checkpoint["epoch"]) + 1


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


def train_one_epoch(run: _Run, epoch: int, progress: Callable[[Progress], None] | None = None,
                    writer: Any = None) -> dict[str, Any]:
    """One pass over the training data; the epoch's metrics row (losses averaged over its steps)."""
    config, model, optimizer = run.config, run.model, run.optimizer
    use_amp, amp_dtype = mixed_precision(config, run.device)
    scaler = run.scaler
    model.train()
    run.dataset.set_epoch(epoch)
    run.sampler.set_epoch(epoch)
    torch.manual_seed(config.seed + epoch)
    sums = dict.fromkeys(LOSS_TERMS, 0.0)
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
        for key in LOSS_TERMS:
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


def _follow_the_budget(run: _Run) -> None:
    """Set the learning rate from the spent fraction of the time budget: warm-up, then a cosine to 0."""
    schedule = run.scheduler.lr_lambdas[0]
    warmup = 1.0 if run.global_step >= schedule.warmup_steps else 0.01 + 0.99 * run.global_step / max(
        1, schedule.warmup_steps)
    factor = warmup * 0.5 * (1.0 + math.cos(math.pi * min(1.0, run.budget_spent())))
    for group, base in zip(run.optimizer.param_groups, run.scheduler.base_lrs, strict=True):
        group["lr"] = base * factor


def validate(run: _Run) -> dict[str, float]:
    """Held-out mAP, mAP-G and Acc-T top-1 of the run's model on its validation slice (empty without one)."""
    if not run.validation:
        return {}
    from togcrf.evaluate import evaluate_model  # noqa: PLC0415

    result = evaluate_model(run.model, run.validation, run.config.image_size, device=str(run.device),
                            speed_images=0, depth_reference=run.config.depth_reference)
    metrics = result["metrics"]
    return {f"val_{name}": float(metrics.get(name, float("nan"))) for name in ("mAP", "mAP-G", "Acc-T top1")}


def train(config: TrainConfig, progress: Callable[[Progress], None] | None = None) -> dict[str, Any]:
    """Train a model on the samples of ``config.data``; write the run dir.

    Parameters
    ----------
    config : TrainConfig
    progress : callable, optional
        Called with a :class:`Progress` after every step and every epoch.

    Returns
    -------
    dict
        The last epoch's metrics row (empty if nothing was left to train).

    Raises
    ------
    ValueError
        Bad options, or ``--resume`` with a checkpoint of another configuration.
    FileNotFoundError
        No samples.
    FloatingPointError
        A non-finite loss (names the step and the terms).
    """
    config.validate()
    run_dir = Path(config.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"
    run, stored_config, data_identity = _build_run(config)
    start_epoch = 0
    if checkpoint_path.exists():
        if not config.resume:
            raise ValueError(f"{checkpoint_path} exists: pass --resume to continue it, or choose another --out")
        start_epoch = _resume(run, checkpoint_path, stored_config)
    main = run.context.main  # only rank 0 writes the run dir and validates (togcrf.distributed)
    if main:
        (run_dir / "config.json").write_text(json.dumps({**stored_config, "data_identity": data_identity},
                                                        indent=2))
    metrics_path = run_dir / "metrics.csv"
    rows = [row for row in _read_metrics(metrics_path) if int(row["epoch"]) < start_epoch]
    writer = _tensorboard_writer(run_dir) if main else None
    last_row: dict[str, Any] = {}
    run.global_step = start_epoch * len(run.loader)
    for epoch in range(start_epoch, config.epochs):
        last_row = train_one_epoch(run, epoch, progress if main else None, writer)
        if main:
            last_row.update(validate(run))
            rows.append(last_row)
            _write_metrics(metrics_path, rows)
            save_checkpoint(checkpoint_path, {
                "model": run.model.state_dict(), "optimizer": run.optimizer.state_dict(),
                "scheduler": run.scheduler.state_dict(), "scaler": run.scaler.state_dict(), "epoch": epoch,
                "config": stored_config, "data": data_identity, "stopped_by_budget": run.out_of_time,
                "trained_seconds": run.trained_seconds}, run.dataset.vocabulary)
        distributed.barrier(run.context)
        if writer is not None:
            for key in ("loss", *LOSS_TERMS, "train_acc_t_top1", *VALIDATION_COLUMNS):
                if key in last_row:
                    writer.add_scalar(f"epoch/{key}", last_row[key], epoch)
            writer.flush()
        logger.info("epoch %d: loss %.4f, train Acc-T top-1 %.3f", epoch, last_row["loss"],
                    last_row["train_acc_t_top1"])
        if progress is not None and main:
            progress(Progress(epoch, config.epochs, last_row["steps"], len(run.loader), {}, metrics=last_row))
        if run.out_of_time:
            logger.info("time budget of %s minutes spent after epoch %d", config.time_budget_minutes, epoch)
            break
    if writer is not None:
        writer.close()
    return last_row


def _model_options(model: torch.nn.Module, config: TrainConfig) -> dict[str, Any]:
    """The model's full options (defaults filled in) as JSON values; the overrides for other models."""
    from togcrf.model import ModelOptions, model_options_dict  # noqa: PLC0415

    options = getattr(model, "options", None)
    if isinstance(options, ModelOptions):
        return model_options_dict(options)
    return dict(config.model_options)


def _saved_model_options(saved_config: dict[str, Any], model: torch.nn.Module) -> dict[str, Any]:
    """A checkpoint's model options with the defaults of options added since it was written filled in.

    A checkpoint stores every option its code knew; one written before an option existed (``fpn_max_stride``,
    2026-11-27) ran with that option's default, so it resumes under a config that has the default.
    """
    from togcrf.model import ModelOptions, model_options_dict  # noqa: PLC0415

    saved = saved_config.get("model_options")
    options = getattr(model, "options", None)
    if saved is None or not isinstance(options, ModelOptions):
        return saved
    return {**model_options_dict(type(options)()), **saved}


def _duration(seconds: float) -> str:
    """``1h02m``, ``4m05s`` or ``12s``."""
    seconds = max(0, int(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    if seconds >= 60:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds}s"


class ProgressReport:
    """The command's progress: a bar on a terminal, and lines at a steady pace in ``train.log`` and off a terminal.

    A line: epoch, step, total loss and its largest terms, images per second,
    the time left in the epoch and in the run (under a time budget, the wall
    time the budget's spent fraction took so far, scaled to what is left).
    """

    #: Seconds between progress lines.
    LINE_INTERVAL = 30.0

    def __init__(self, run_dir: Path, epochs: int) -> None:
        from tqdm import tqdm  # noqa: PLC0415 - CLI side only

        self._tqdm = tqdm
        self.bar = None
        self.epochs = epochs
        self.first_spent: tuple[float, float] | None = None  # (budget fraction, wall seconds) at the first step
        self.started = time.perf_counter()
        self.last_line = 0.0
        self.steps_done = 0
        run_dir.mkdir(parents=True, exist_ok=True)
        self.log = (run_dir / "train.log").open("a", buffering=1)
        self.terminal = os.isatty(1)

    def line(self, text: str) -> None:
        """Write a line to the log, and to stdout where no bar shows it."""
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        self.log.write(f"{stamp} {text}\n")
        if self.bar is not None:
            self.bar.write(text)
        else:
            typer.echo(text)

    def _budget_left(self, elapsed: float, spent: float) -> float:
        """Wall seconds left of a time budget: the wall time per budget fraction so far, times the fraction left.

        The budget counts training steps only, so its wall time also holds the data loading and validation.
        """
        if self.first_spent is None:
            self.first_spent = (spent, elapsed)
        spent_here, wall_here = spent - self.first_spent[0], elapsed - self.first_spent[1]
        if spent_here <= 0 or wall_here <= 0:
            return float("inf")
        return max(0.0, 1.0 - spent) * wall_here / spent_here

    def __call__(self, event: Progress) -> None:
        if event.metrics is not None:
            self._epoch_done(event)
            return
        self.steps_done += 1
        elapsed = time.perf_counter() - self.started
        per_step = elapsed / self.steps_done
        epoch_left = (event.steps - event.step) * per_step
        run_left = epoch_left + (self.epochs - event.epoch - 1) * event.steps * per_step
        if event.budget_spent is not None:
            run_left = min(run_left, self._budget_left(elapsed, event.budget_spent))
        loss = sum(event.losses.values())
        if self.terminal:
            if self.bar is None:
                self.bar = self._tqdm(total=event.steps, desc=f"epoch {event.epoch + 1}/{event.epochs}", unit="step")
            self.bar.update(1)
            self.bar.set_postfix(loss=f"{loss:.3f}", img_s=f"{event.images_per_second or 0:.1f}",
                                 run_left=_duration(run_left))
        now = time.perf_counter()
        if now - self.last_line >= self.LINE_INTERVAL or event.step == event.steps:
            self.last_line = now
            terms = ", ".join(f"{key} {value:.3f}" for key, value in event.losses.items())
            text = (f"epoch {event.epoch + 1}/{event.epochs} step {event.step}/{event.steps}: loss {loss:.3f} "
                    f"({terms}); {event.images_per_second or 0:.2f} images/s; epoch left "
                    f"{_duration(epoch_left)}, run left {_duration(run_left)}")
            if self.terminal:
                self.log.write(f"{time.strftime('%Y-%m-%d %H:%M:%S')} {text}\n")
            else:
                self.line(text)

    def _epoch_done(self, event: Progress) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        metrics = event.metrics
        validation = "".join(f", {key} {metrics[key]:.3f}" for key in VALIDATION_COLUMNS if key in metrics)
        self.line(f"epoch {event.epoch + 1}/{event.epochs} done: loss {metrics['loss']:.4f}, train Acc-T top-1 "
                  f"{metrics['train_acc_t_top1']:.3f}{validation}; {metrics['images_per_second']:.2f} images/s")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.log.close()


def _parse_options(items: list[str] | None) -> dict[str, Any]:
    """``NAME=JSON_VALUE`` pairs (a value that is not JSON is kept as a string)."""
    options: dict[str, Any] = {}
    for item in items or []:
        name, separator, value = item.partition("=")
        if not separator:
            raise typer.BadParameter(f"--option {item!r}: expected NAME=VALUE")
        try:
            options[name] = json.loads(value)
        except json.JSONDecodeError:
            options[name] = value
    return options


#: The defaults of every option: the command's options take theirs from here.
_DEFAULTS = TrainConfig(data="", out="")


def register(app: typer.Typer) -> None:
    """Add the ``train`` command to the togcrf CLI."""
    def train_command(
        data: Annotated[Path, typer.Option("--data", help="Data dir with samples shards.")],
        out: Annotated[Path, typer.Option("--out", help="Run dir (checkpoint.pt, metrics.csv, config.json).")],
        pipeline: Annotated[str | None, typer.Option(help="Use the shards of this pipeline's manifest.")] = (
            _DEFAULTS.pipeline),
        model: Annotated[str, typer.Option(help=f"One of {', '.join(MODEL_NAMES)}.")] = _DEFAULTS.model,
        backbone: Annotated[str, typer.Option(help=f"One of {', '.join(BACKBONES)}.")] = _DEFAULTS.backbone,
        epochs: Annotated[int, typer.Option(help="Epochs (paper: 10).")] = _DEFAULTS.epochs,
        lr: Annotated[float, typer.Option(help="Learning rate (paper: 0.001 with SGD).")] = _DEFAULTS.lr,
        optimizer: Annotated[str, typer.Option(help=f"One of {', '.join(OPTIMIZERS)} (paper: sgd).")] = (
            _DEFAULTS.optimizer),
        lr_schedule: Annotated[str, typer.Option(
            help="step: x0.1 from each --lr-decay-epoch; cosine: to 0 over the run.")] = _DEFAULTS.lr_schedule,
        lr_decay_epoch: Annotated[list[int] | None, typer.Option(help="With step: decay from this epoch.")] = None,
        momentum: Annotated[float, typer.Option(help="SGD momentum (paper: 0.9).")] = _DEFAULTS.momentum,
        weight_decay: Annotated[float, typer.Option(help="Weight decay.")] = _DEFAULTS.weight_decay,
        batch_size: Annotated[int, typer.Option(help="Images per step.")] = _DEFAULTS.batch_size,
        image_size: Annotated[int | None, typer.Option(help="Longer image side fed to the network.")] = (
            _DEFAULTS.image_size),
        augment: Annotated[bool, typer.Option(help="Flips, 90-degree turns and scale jitter.")] = _DEFAULTS.augment,
        scale_jitter: Annotated[float, typer.Option(help="Augmentation scales in [1 - this, 1].")] = (
            _DEFAULTS.scale_jitter),
        depth_reference: Annotated[str, typer.Option(
            help="Input height above: table (the fitted table plane) or median (the image's median depth).")] = (
            _DEFAULTS.depth_reference),
        warmup_steps: Annotated[int, typer.Option(help="Linear learning-rate warm-up steps.")] = _DEFAULTS.warmup_steps,
        clip_grad_norm: Annotated[float, typer.Option(help="Gradient-norm clipping (0: off).")] = (
            _DEFAULTS.clip_grad_norm),
        val_samples: Annotated[int, typer.Option(
            help="Training samples held out for validation metrics after every epoch (0: none).")] = (
            _DEFAULTS.val_samples),
        time_budget: Annotated[float | None, typer.Option(
            help="Minutes of training after which the run stops (its checkpoint then holds the part epoch); "
            "0: none, the epochs alone end the run.")] = (
            _DEFAULTS.time_budget_minutes),
        resume: Annotated[bool, typer.Option(help="Continue RUN_DIR/checkpoint.pt.")] = _DEFAULTS.resume,
        init: Annotated[Path | None, typer.Option(
            help="Start from this checkpoint's weights (fine-tuning; optimiser and schedule start afresh).")] = None,
        device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = _DEFAULTS.device,
        amp: Annotated[bool, typer.Option(help="Mixed precision on CUDA.")] = _DEFAULTS.amp,
        cpu_bf16: Annotated[bool, typer.Option(
            help="bfloat16 autocast on a CPU with native bfloat16 (AVX-512 BF16 or AMX; elsewhere float32).")] = (
            _DEFAULTS.cpu_bf16),
        seed: Annotated[int, typer.Option(help="Seed of initialisation, data order and augmentation.")] = (
            _DEFAULTS.seed),
        max_samples: Annotated[int | None, typer.Option(help="Use only the first N samples (quick runs).")] = (
            _DEFAULTS.max_samples),
        workers: Annotated[int, typer.Option(help="DataLoader worker processes.")] = _DEFAULTS.workers,
        split: Annotated[str, typer.Option(help="Split trained on (its last --val-samples are held out).")] = (
            _DEFAULTS.split),
        option: Annotated[list[str] | None, typer.Option(help="Model option NAME=JSON_VALUE (ModelOptions).")] = None,
        train_only: Annotated[list[str] | None, typer.Option(
            help="Train only parameters whose names start with this prefix (repeatable; e.g. "
            "grasp_head.confidence); with --init such layers may be new.")] = None,
    ) -> None:
        """Train TOG / TOG-CRFs (or FCGN+Task) on samples shards.

        Progress: a bar on a terminal; a line every 30 s in RUN_DIR/train.log
        (and on stdout when it is not a terminal) with the losses, images/s
        and the time left. The CPU recipe is ``togcrf reproduce --scale cpu``.
        Several processes: ``torchrun --nproc-per-node N -m togcrf train ...``
        (``--batch-size`` per process; ``togcrf.distributed``).
        """
        config = TrainConfig(
            resume=resume, data=str(data), out=str(out), pipeline=pipeline, model=model, backbone=backbone,
            epochs=epochs, lr=lr, momentum=momentum, weight_decay=weight_decay, batch_size=batch_size,
            image_size=image_size, augment=augment, warmup_steps=warmup_steps, clip_grad_norm=clip_grad_norm,
            device=device, amp=amp, cpu_bf16=cpu_bf16, seed=seed, max_samples=max_samples, workers=workers,
            model_options=_parse_options(option), optimizer=optimizer, lr_schedule=lr_schedule,
            lr_decay_epochs=list(lr_decay_epoch or []), scale_jitter=scale_jitter, val_samples=val_samples,
            depth_reference=depth_reference,
            time_budget_minutes=time_budget or None, init=None if init is None else str(init), split=split,
            train_only=list(train_only or []))
        main = distributed.from_environment().main
        report = ProgressReport(out, epochs) if main else None
        try:
            result = train(config, report)
        except (ValueError, FileNotFoundError, FloatingPointError) as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(1) from error
        finally:
            if report is not None:
                report.close()
        if not main:
            return
        if not result:
            typer.echo(f"{out}: already trained {epochs} epochs")
        else:
            typer.echo(f"checkpoint: {out / 'checkpoint.pt'}")

    app.command("train")(train_command)
