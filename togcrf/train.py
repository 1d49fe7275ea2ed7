"""Training from ``samples`` shards, checkpoints, and the ``togcrf train`` command.

The library entry point is :func:`train` (no printing; progress goes to an
optional callback and to ``logging``); the command wraps it with a progress
bar. A run dir holds:

- ``config.json``: every training option, the model options and the data identity;
- ``metrics.csv``: one row per epoch: mean of every loss term, the total,
  the learning rate, seconds, and ``train_acc_t_top1`` measured on the fly
  (``togcrf.losses.top1_task_hits``);
- ``checkpoint.pt``: the latest epoch (contract: "model", "optimizer",
  "scheduler", "epoch", "config", "data");
- ``tensorboard/``: the same scalars, when the ``tensorboard`` package is installed.

Defaults follow the paper (Section V): 10 epochs, SGD, lr 0.001, momentum
0.9. Our additions: a linear warm-up over the first ``warmup_steps`` steps
and gradient-norm clipping, both because the detector is trained from
scratch (no pretrained weights can be downloaded) and the first steps of the
randomly initialised grasp head have large gradients; weight decay 1e-4 as
torchvision's detection references. Seeding: ``torch.manual_seed(seed +
epoch)`` at the start of every epoch (RoI sampling), augmentation drawn from
``(seed, epoch, item)`` and a seeded shard-grouped data order, so a resumed
run continues as the uninterrupted one would.
"""

from __future__ import annotations

import csv
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import torch
import typer
from torch.utils.data import DataLoader

from togcrf.data import SamplesDataset, ShardGroupedSampler, collate
from togcrf.model import BACKBONES, MODEL_NAMES, build_model

logger = logging.getLogger(__name__)

#: Loss terms in metrics.csv, in order (the model's loss keys).
LOSS_TERMS = ("rpn_objectness", "rpn_box", "rcnn_class", "rcnn_box", "grasp_stability", "grasp_regression",
              "grasp_task")


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
    seed: int = 0
    max_samples: int | None = None
    workers: int = 0
    split: str = "train"
    model_options: dict[str, Any] = field(default_factory=dict)
    resume: bool = False

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


@dataclass(frozen=True)
class Progress:
    """One progress event for a callback: after each step (``step``) and after each epoch (``metrics``)."""

    epoch: int
    epochs: int
    step: int
    steps: int
    losses: dict[str, float]
    metrics: dict[str, float] | None = None


def resolve_device(name: str) -> torch.device:
    """"auto" -> CUDA when available, else CPU; "cuda" without a GPU raises."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device is available")
    return torch.device(name)


class WarmupSchedule:
    """Learning-rate factor per optimiser step: linear warm-up, then 0.1 per passed decay epoch.

    A callable object (not a closure) so that ``LambdaLR.state_dict`` saves it.
    """

    def __init__(self, warmup_steps: int, steps_per_epoch: int, decay_epochs: list[int]) -> None:
        self.warmup_steps = warmup_steps
        self.steps_per_epoch = max(1, steps_per_epoch)
        self.decay_epochs = sorted(decay_epochs)

    def __call__(self, step: int) -> float:
        warmup = 1.0 if step >= self.warmup_steps else 0.01 + 0.99 * step / self.warmup_steps
        epoch = step // self.steps_per_epoch
        return warmup * 0.1 ** sum(epoch >= decay for decay in self.decay_epochs)


def _to_device(images: list[torch.Tensor], targets: list[dict[str, torch.Tensor]], device: torch.device):
    return ([image.to(device, non_blocking=True) for image in images],
            [{key: value.to(device, non_blocking=True) for key, value in target.items()} for target in targets])


def _atomic_save(value: Any, path: Path) -> None:
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(value, temporary)
    os.replace(temporary, path)


def _read_metrics(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    columns = ["epoch", "steps", "samples", "seconds", "lr", "loss", *LOSS_TERMS, "train_acc_t_top1"]
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
_RESUME_MUST_MATCH = ("model", "backbone", "image_size", "model_options", "batch_size")


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
    device = resolve_device(config.device)
    run_dir = Path(config.out)
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"

    dataset = SamplesDataset(config.data, pipeline=config.pipeline, split=config.split,
                             image_size=config.image_size, augment=config.augment, seed=config.seed,
                             max_samples=config.max_samples)
    sampler = ShardGroupedSampler(dataset, seed=config.seed)
    loader = DataLoader(dataset, batch_size=config.batch_size, sampler=sampler, collate_fn=collate,
                        num_workers=config.workers, pin_memory=device.type == "cuda")
    data_identity = {"data_dir": str(Path(config.data).resolve()), "pipeline": config.pipeline,
                     "split": config.split, "shards": dataset.shard_keys(), "samples": len(dataset)}

    torch.manual_seed(config.seed)
    model = build_model(config.model, config.backbone, **config.model_options).to(device)
    stored_config = {**asdict(config), "model_options": _model_options(model, config)}
    optimizer = torch.optim.SGD([p for p in model.parameters() if p.requires_grad], lr=config.lr,
                                momentum=config.momentum, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, WarmupSchedule(config.warmup_steps, len(loader), config.lr_decay_epochs))
    start_epoch = 0
    if checkpoint_path.exists():
        if not config.resume:
            raise ValueError(f"{checkpoint_path} exists: pass --resume to continue it, or choose another --out")
        checkpoint = torch.load(checkpoint_path, map_location=device, weights_only=False)
        for key in _RESUME_MUST_MATCH:
            if checkpoint["config"].get(key) != stored_config.get(key):
                raise ValueError(f"{checkpoint_path}: cannot resume, {key} was {checkpoint['config'].get(key)!r}, "
                                 f"now {stored_config.get(key)!r}")
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        scheduler.load_state_dict(checkpoint["scheduler"])
        start_epoch = int(checkpoint["epoch"]) + 1
        logger.info("resuming %s after epoch %d", checkpoint_path, start_epoch - 1)
    (run_dir / "config.json").write_text(json.dumps({**stored_config, "data_identity": data_identity}, indent=2))

    use_amp = config.amp and device.type == "cuda"
    amp_dtype = torch.bfloat16 if use_amp and torch.cuda.is_bf16_supported() else torch.float16
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    metrics_path = run_dir / "metrics.csv"
    rows = [row for row in _read_metrics(metrics_path) if int(row["epoch"]) < start_epoch]
    writer = _tensorboard_writer(run_dir)
    last_row: dict[str, Any] = {}
    global_step = start_epoch * len(loader)
    for epoch in range(start_epoch, config.epochs):
        model.train()
        dataset.set_epoch(epoch)
        sampler.set_epoch(epoch)
        torch.manual_seed(config.seed + epoch)
        sums = dict.fromkeys(LOSS_TERMS, 0.0)
        hits = rois = samples = steps = 0
        started = time.perf_counter()
        for cpu_images, cpu_targets, sample_ids in loader:
            images, targets = _to_device(cpu_images, cpu_targets, device)
            with torch.autocast(device_type=device.type, dtype=amp_dtype, enabled=use_amp):
                losses = model(images, targets)
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
            scheduler.step()
            global_step += 1
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
                    writer.add_scalar(f"step/{key}", value, global_step)
            if progress is not None:
                progress(Progress(epoch, config.epochs, steps, len(loader), step_losses))
        means = {key: value / max(steps, 1) for key, value in sums.items()}
        last_row = {"epoch": epoch, "steps": steps, "samples": samples,
                    "seconds": round(time.perf_counter() - started, 3), "lr": optimizer.param_groups[0]["lr"],
                    "loss": sum(means.values()), **means,
                    "train_acc_t_top1": hits / rois if rois else float("nan")}
        rows.append(last_row)
        _write_metrics(metrics_path, rows)
        _atomic_save({"model": model.state_dict(), "optimizer": optimizer.state_dict(),
                      "scheduler": scheduler.state_dict(), "epoch": epoch, "config": stored_config,
                      "data": data_identity}, checkpoint_path)
        if writer is not None:
            for key in ("loss", *LOSS_TERMS, "train_acc_t_top1"):
                writer.add_scalar(f"epoch/{key}", last_row[key], epoch)
            writer.flush()
        logger.info("epoch %d: loss %.4f, train Acc-T top-1 %.3f", epoch, last_row["loss"],
                    last_row["train_acc_t_top1"])
        if progress is not None:
            progress(Progress(epoch, config.epochs, steps, len(loader), step_losses, metrics=last_row))
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


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[torch.nn.Module, dict[str, Any]]:
    """The model of a checkpoint (eval mode, on ``device``) and its training config.

    Parameters
    ----------
    path : path
        ``RUN_DIR/checkpoint.pt`` (or a run dir).
    device : str

    Returns
    -------
    model, config : torch.nn.Module, dict
        ``config`` is the stored training config plus ``"epoch"`` and ``"data"``.

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file, or not a togcrf checkpoint.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "checkpoint.pt"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no checkpoint")
    checkpoint = torch.load(path, map_location=device, weights_only=False)
    if not isinstance(checkpoint, dict) or "model" not in checkpoint or "config" not in checkpoint:
        raise ValueError(f"{path}: not a togcrf checkpoint (needs 'model' and 'config')")
    config = dict(checkpoint["config"])
    model = build_model(config["model"], config["backbone"], **config.get("model_options", {}))
    model.load_state_dict(checkpoint["model"])
    model.to(device).eval()
    config["epoch"] = checkpoint.get("epoch")
    config["data"] = checkpoint.get("data")
    return model, config


def register(app: typer.Typer) -> None:
    """Add the ``train`` command to the togcrf CLI."""
    def train_command(
        data: Annotated[Path, typer.Option("--data", help="Data dir with samples shards.")],
        out: Annotated[Path, typer.Option("--out", help="Run dir (checkpoint.pt, metrics.csv, config.json).")],
        pipeline: Annotated[str | None, typer.Option(help="Use the shards of this pipeline's manifest.")] = None,
        model: Annotated[str, typer.Option(help=f"One of {', '.join(MODEL_NAMES)}.")] = "tog-crfs",
        backbone: Annotated[str, typer.Option(help=f"One of {', '.join(BACKBONES)}.")] = "resnet101",
        epochs: Annotated[int, typer.Option(help="Epochs (paper: 10).")] = 10,
        lr: Annotated[float, typer.Option(help="SGD learning rate (paper: 0.001).")] = 0.001,
        momentum: Annotated[float, typer.Option(help="SGD momentum (paper: 0.9).")] = 0.9,
        weight_decay: Annotated[float, typer.Option(help="SGD weight decay.")] = 1e-4,
        batch_size: Annotated[int, typer.Option(help="Images per step.")] = 2,
        image_size: Annotated[int | None, typer.Option(help="Longer image side fed to the network.")] = None,
        augment: Annotated[bool, typer.Option(help="Flips, 90-degree turns and scale jitter.")] = True,
        warmup_steps: Annotated[int, typer.Option(help="Linear learning-rate warm-up steps.")] = 100,
        clip_grad_norm: Annotated[float, typer.Option(help="Gradient-norm clipping (0: off).")] = 10.0,
        resume: Annotated[bool, typer.Option(help="Continue RUN_DIR/checkpoint.pt.")] = False,
        device: Annotated[str, typer.Option(help="auto, cpu or cuda.")] = "auto",
        amp: Annotated[bool, typer.Option(help="Mixed precision on CUDA.")] = True,
        seed: Annotated[int, typer.Option(help="Seed of initialisation, data order and augmentation.")] = 0,
        max_samples: Annotated[int | None, typer.Option(help="Use only the first N samples (quick runs).")] = None,
        workers: Annotated[int, typer.Option(help="DataLoader worker processes.")] = 0,
        option: Annotated[list[str] | None, typer.Option(help="Model option NAME=JSON_VALUE (ModelOptions).")] = None,
    ) -> None:
        """Train TOG / TOG-CRFs (or FCGN+Task) on samples shards."""
        from tqdm import tqdm  # noqa: PLC0415 - CLI side only

        model_options = {}
        for item in option or []:
            name, separator, value = item.partition("=")
            if not separator:
                raise typer.BadParameter(f"--option {item!r}: expected NAME=VALUE")
            try:
                model_options[name] = json.loads(value)
            except json.JSONDecodeError:
                model_options[name] = value
        config = TrainConfig(
            resume=resume, data=str(data), out=str(out), pipeline=pipeline, model=model, backbone=backbone,
            epochs=epochs, lr=lr, momentum=momentum, weight_decay=weight_decay, batch_size=batch_size,
            image_size=image_size, augment=augment, warmup_steps=warmup_steps, clip_grad_norm=clip_grad_norm,
            device=device, amp=amp, seed=seed, max_samples=max_samples, workers=workers,
            model_options=model_options)
        bar = None

        def show(event: Progress) -> None:
            nonlocal bar
            if event.metrics is not None:
                if bar is not None:
                    bar.close()
                    bar = None
                typer.echo(f"epoch {event.epoch + 1}/{event.epochs}: loss {event.metrics['loss']:.4f}, "
                           f"train Acc-T top-1 {event.metrics['train_acc_t_top1']:.3f}")
                return
            if bar is None:
                bar = tqdm(total=event.steps, desc=f"epoch {event.epoch + 1}/{event.epochs}", unit="step")
            bar.update(1)
            bar.set_postfix(loss=f"{sum(event.losses.values()):.3f}")

        try:
            result = train(config, show)
        except (ValueError, FileNotFoundError, FloatingPointError) as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(1) from error
        finally:
            if bar is not None:
                bar.close()
        if not result:
            typer.echo(f"{out}: already trained {epochs} epochs")
        else:
            typer.echo(f"checkpoint: {out / 'checkpoint.pt'}")

    app.command("train")(train_command)
