"""Training from ``samples`` shards: the run dir, checkpoints, resume, and the ``togcrf train`` command.

The library entry point is :func:`train` (no printing; progress goes to an optional callback and to
``logging``); it builds a :class:`togcrf.engine.TrainingRun` from a :class:`togcrf.config.TrainConfig`
and runs :func:`togcrf.engine.train_one_epoch` per epoch. The command wraps it with a progress bar. A
run dir holds:

- ``config.json``: the resolved :class:`~togcrf.config.TrainConfig` (model options nested by group), the
  precision that ran (``precision``) and the data identity;
- ``metrics.csv``: one row per epoch: mean of every loss term, the total, the learning rate, seconds,
  images per second, ``train_acc_t_top1`` measured on the fly (``togcrf.losses.top1_task_hits``) and,
  with ``val_samples``, the held-out ``val_mAP``, ``val_mAP-G`` and ``val_Acc-T top1`` of the epoch's
  model (``togcrf curves`` draws them);
- ``train.log``: the progress lines (step, losses, images/s, time left);
- ``checkpoint.pt``: the latest epoch's model ("model", "epoch", "config", "data", "stopped_by_budget",
  "trained_seconds"; ``togcrf.checkpoint``), and ``training-state.pt``: what ``--resume`` needs besides
  ("optimizer", "scheduler", "scaler", "epoch"), written with it so that the run dir always holds a
  checkpoint and the state of its epoch;
- ``tensorboard/``: the same scalars, when the ``tensorboard`` package is installed.

Defaults follow the paper (Section V): 10 epochs, SGD, lr 0.001, momentum 0.9. Our additions: a linear
warm-up over the first ``warmup_steps`` steps and gradient-norm clipping, because the detector is trained
from scratch (no pretrained depth weights exist) and the first steps of the randomly initialised grasp
head have large gradients; weight decay 1e-4 as torchvision's detection references; AdamW and a cosine
schedule as options. The validation slice is the last ``val_samples`` samples of the training split, held
out of training. Augmentation is drawn from ``(seed, epoch, item)`` and the data order is a seeded
shard-grouped one, so a resumed run continues as the uninterrupted one would.
"""

from __future__ import annotations

import csv
import inspect
import json
import logging
import math
import os
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import torch
import typer
from torch.utils.data import DataLoader
from tqdm import tqdm

from osgd.contract.samples import held_out_models
from togcrf import distributed
from togcrf.checkpoint import (
    CHECKPOINT_FILE,
    check_vocabulary,
    one_line_of,
    read_checkpoint,
    save_checkpoint,
)
from togcrf.config import TrainConfig, command_parameters, config_from_command, preset
from togcrf.data import SamplesDataset, ShardGroupedSampler, collate
from togcrf.engine import (
    VALIDATION_COLUMNS,
    Progress,
    TrainingRun,
    mixed_precision,
    precision_name,
    resolve_device,
    train_one_epoch,
    validation_metrics,
)
from togcrf.losses import LOSS_KEYS
from togcrf.model import build_model, options_dict, stored_options
from togcrf.model.options import dotted_options

logger = logging.getLogger(__name__)


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


def _read_metrics(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    columns = ["epoch", "steps", "samples", "seconds", "images_per_second", "lr", "loss", *LOSS_KEYS,
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


def _build_run(config: TrainConfig) -> tuple[TrainingRun, dict[str, Any], dict[str, Any]]:
    """Data, model, optimiser and schedule of a run; the stored config and the data identity."""
    context = distributed.from_environment()
    device = distributed.process_device(context, resolve_device(config.device))
    distributed.start(context, device)
    dataset = SamplesDataset(config.data, pipeline=config.pipeline, split=config.split,
                             image_size=config.image_size, augment=config.augment, seed=config.seed,
                             max_samples=config.max_samples, scale_jitter=config.scale_jitter,
                             depth_reference=config.depth_reference)
    leaked = dataset.models_shown(held_out_models(config.data, config.pipeline))
    if leaked:
        raise ValueError(f"{config.data}: the manifest holds models out for test, but the {config.split!r} samples "
                         f"trained on show {len(leaked)} of them: {', '.join(sorted(leaked))} (e.g. in "
                         f"{leaked[min(leaked)]}); rebuild the samples with the scenes' split, or train on another "
                         "data dir")
    if config.val_samples and config.val_samples >= len(dataset):
        raise ValueError(f"--val-samples {config.val_samples}: the training split has only {len(dataset)}")
    kept = len(dataset) - config.val_samples
    validation_samples = [dataset.read_sample(item) for item in range(kept, len(dataset))]
    dataset.index = dataset.index[:kept]
    trained_models = sorted(dataset.models_shown())
    sampler = ShardGroupedSampler(dataset, seed=config.seed, rank=context.rank, world=context.world,
                                  batch_size=config.batch_size)
    loader = DataLoader(dataset, batch_size=config.batch_size, sampler=sampler, collate_fn=collate,
                        num_workers=config.workers, pin_memory=device.type == "cuda")
    data_identity = {"data_dir": str(Path(config.data).resolve()), "pipeline": config.pipeline,
                     "split": config.split, "shards": dataset.shard_keys(), "samples": len(dataset),
                     "validation_samples": [sample.sample_id for sample in validation_samples],
                     "models": trained_models}
    torch.manual_seed(config.seed)
    model = build_model(config.model, config.backbone, config.model_options, dataset.vocabulary).to(device)
    if config.init:
        # The tools the weights have seen: those of the run they came from as well (None: not recorded there).
        earlier = _load_initial_weights(model, Path(config.init), device, config.train_only)
        data_identity["models"] = None if earlier is None else sorted({*trained_models, *earlier})
    _freeze_all_but(model, config.train_only)
    stored_config = {**config.as_dict(), "precision": precision_name(config, device)}
    if config.cpu_bf16 and device.type == "cpu" and stored_config["precision"] == "float32":
        logger.warning("--cpu-bf16: this CPU has no native bfloat16 (AVX-512 BF16 or AMX); training in float32")
    optimizer = build_optimizer(model, config)
    cosine_steps = config.epochs * len(loader) if config.lr_schedule == "cosine" else None
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, WarmupSchedule(config.warmup_steps, len(loader), config.lr_decay_epochs, cosine_steps))
    use_amp, amp_dtype = mixed_precision(config, device)
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)
    run = TrainingRun(config, device, model, optimizer, scheduler, loader, dataset, sampler, validation_samples,
               context, distributed.wrap(model, context, device), scaler)
    return run, stored_config, data_identity


def _load_initial_weights(model: torch.nn.Module, path: Path, device: torch.device,
                          new_layers: list[str] = ()) -> list[str] | None:
    """Copy the model weights of a checkpoint into ``model`` (``--init``); layers under ``new_layers`` may be
    missing from it (they keep their initialisation). Returns the model ids its training showed (None: not
    recorded)."""
    if not path.is_file():
        raise FileNotFoundError(f"--init {path}: no such checkpoint")
    checkpoint = read_checkpoint(path, device)
    check_vocabulary(checkpoint["vocabulary"], model.vocabulary, f"--init {path}", "the data trained on")
    weights = checkpoint["model"]
    own = model.state_dict()
    new = [name for name in own if name not in weights and name.startswith(tuple(new_layers))]
    try:
        model.load_state_dict({**weights, **{name: own[name] for name in new}})
    except RuntimeError as error:
        first = str(error).strip().splitlines()[0]
        raise ValueError(f"--init {path}: its layers differ from this model's ({first}); use the same "
                         "--model, --backbone and layer options") from error
    logger.info("initial weights from %s%s", path, f" ({len(new)} new tensors kept as initialised)" if new else "")
    return (checkpoint.get("data") or {}).get("models")


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
                         "(the names are the model's state_dict keys, e.g. grasp_head.task)")
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


#: The optimiser, schedule and loss-scaler state of a run dir, beside ``checkpoint.pt``: what ``--resume`` needs
#: and evaluation, prediction and the robot do not, so the checkpoint holds the model alone.
TRAINING_STATE_FILE = "training-state.pt"


#: The training state of the epoch before, kept until the checkpoint of the new epoch is written: an interrupt
#: between the two writes leaves one state that goes with the checkpoint on disk.
PREVIOUS_TRAINING_STATE_FILE = "training-state.previous.pt"


def _save_epoch(run_dir: Path, run: TrainingRun, epoch: int, checkpoint: dict[str, Any]) -> None:
    """Write the training state and the checkpoint of ``epoch``, each atomically, so that the run dir always
    holds a checkpoint and the training state of its epoch (the previous state is kept while the new
    checkpoint is written)."""
    state_path, previous = run_dir / TRAINING_STATE_FILE, run_dir / PREVIOUS_TRAINING_STATE_FILE
    if state_path.exists():
        os.replace(state_path, previous)
    temporary = state_path.with_suffix(".pt.tmp")
    torch.save({"optimizer": run.optimizer.state_dict(), "scheduler": run.scheduler.state_dict(),
                "scaler": run.scaler.state_dict(), "epoch": epoch}, temporary)
    os.replace(temporary, state_path)
    save_checkpoint(run_dir / CHECKPOINT_FILE, checkpoint, run.dataset.vocabulary)
    previous.unlink(missing_ok=True)


def _read_training_state(path: Path, device: torch.device) -> dict[str, Any] | None:
    """A training state file, None if there is none; a ValueError naming it if it is not one."""
    if not path.is_file():
        return None
    try:
        state = torch.load(path, map_location=device, weights_only=True)
    except (RuntimeError, ValueError, EOFError, OSError, pickle.UnpicklingError) as error:
        raise ValueError(f"--resume: {path} is not a readable training state ({one_line_of(error)})") from error
    if not isinstance(state, dict) or "optimizer" not in state:
        raise ValueError(f"--resume: {path} is not a training state (needs 'optimizer')")
    return state


def _training_state(checkpoint_path: Path, checkpoint: dict[str, Any], device: torch.device) -> dict[str, Any]:
    """The training state that goes with a checkpoint: ``training-state.pt`` beside it (or the state of the epoch
    before, where an interrupt came between the two writes), or the checkpoint itself where it holds one
    (checkpoints that kept the optimiser inside)."""
    if "optimizer" in checkpoint:
        return checkpoint
    path = checkpoint_path.parent / TRAINING_STATE_FILE
    states = [_read_training_state(candidate, device)
              for candidate in (path, checkpoint_path.parent / PREVIOUS_TRAINING_STATE_FILE)]
    matching = [state for state in states if state is not None and state.get("epoch") == checkpoint.get("epoch")]
    if not matching:
        found = ", ".join(f"epoch {state.get('epoch')}" for state in states if state is not None) or "none"
        raise ValueError(f"--resume: no training state of epoch {checkpoint.get('epoch')} beside "
                         f"{checkpoint_path} ({path}: {found}); the checkpoint alone cannot continue the run "
                         "exactly (use --init to start a new run from its weights)")
    return matching[0]


def _resume(run: TrainingRun, checkpoint_path: Path, stored_config: dict[str, Any]) -> int:
    """Load a checkpoint into the run; the first epoch still to train."""
    checkpoint = read_checkpoint(checkpoint_path, run.device)
    saved = {**checkpoint["config"],
             "model_options": options_dict(stored_options(checkpoint["config"].get("model_options"), training=True))}
    for key in _RESUME_MUST_MATCH:
        if saved.get(key) != stored_config.get(key):
            raise ValueError(f"{checkpoint_path}: cannot resume, {key} was {saved.get(key)!r}, "
                             f"now {stored_config.get(key)!r}")
    check_vocabulary(checkpoint["vocabulary"], run.dataset.vocabulary, str(checkpoint_path), "the data trained on")
    state = _training_state(checkpoint_path, checkpoint, run.device)
    run.model.load_state_dict(checkpoint["model"])
    run.optimizer.load_state_dict(_with_this_implementation(state["optimizer"], run.optimizer))
    run.scheduler.load_state_dict(state["scheduler"])
    if state.get("scaler"):  # older checkpoints have no scaler state
        run.scaler.load_state_dict(state["scaler"])
    logger.info("resuming %s after epoch %d", checkpoint_path, int(checkpoint["epoch"]))
    run.trained_seconds = float(checkpoint.get("trained_seconds", 0.0))
    if checkpoint.get("stopped_by_budget"):
        return run.config.epochs
    return int(checkpoint["epoch"]) + 1


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
            last_row.update(validation_metrics(run))
            rows.append(last_row)
            _write_metrics(metrics_path, rows)
            _save_epoch(run_dir, run, epoch, {
                "model": run.model.state_dict(), "epoch": epoch, "config": stored_config, "data": data_identity,
                "stopped_by_budget": run.out_of_time, "trained_seconds": run.trained_seconds})
        distributed.barrier(run.context)
        if writer is not None:
            for key in ("loss", *LOSS_KEYS, "train_acc_t_top1", *VALIDATION_COLUMNS):
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


def train_command(preset_name: str | None = None, **given: Any) -> None:
    """Train TOG / TOG-CRFs (or FCGN + Task) on samples shards.

    Progress: a bar on a terminal; a line every 30 s in RUN_DIR/train.log (and on stdout when it is not a
    terminal) with the losses, images/s and the time left. ``--preset cpu`` is the CPU recipe (``togcrf
    reproduce --scale cpu`` trains and evaluates all of Table II with it); any option given overrides the
    preset. Several processes: ``torchrun --nproc-per-node N -m togcrf train ...`` (``--batch-size`` per
    process; ``togcrf.distributed``).
    """
    base = TrainConfig() if preset_name is None else preset(preset_name, torch.cuda.is_available())
    config = config_from_command(base, given)
    config.validate()
    out = Path(config.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file; expected a run dir")
    if config.resume and not (out / "checkpoint.pt").is_file():
        raise ValueError(f"--resume: {out / 'checkpoint.pt'} does not exist; leave out --resume to start a run")
    main = distributed.from_environment().main
    report = ProgressReport(out, config.epochs) if main else None
    try:
        result = train(config, report)
    finally:
        if report is not None:
            report.close()
    if not main:
        return
    if not result:
        typer.echo(f"{out}: already trained {config.epochs} epochs")
    else:
        typer.echo(f"checkpoint: {out / 'checkpoint.pt'}")


def _train_command_signature():
    """``train_command`` with the options of every :class:`TrainConfig` field (``togcrf.config``)."""
    preset_option = typer.Option("--preset", help="Start from a named configuration: paper, gpu, cpu, small, or "
                                 "auto (paper with CUDA, else cpu; togcrf.config.PRESETS); the options given override "
                                 "it.")
    parameters = [inspect.Parameter("preset_name", inspect.Parameter.KEYWORD_ONLY, default=None,
                                    annotation=Annotated[str | None, preset_option]),
                  *command_parameters(excluded=("eval_max_samples",), required=("data", "out"))]
    return inspect.Signature(parameters)


def options_command(
    preset_name: Annotated[str | None, typer.Option("--preset", help="Show this preset's values: paper, gpu, cpu or "
                                                    "small.")] = None,
) -> None:
    """List every model option (``--option GROUP.NAME=VALUE``) with its value, the defaults or a preset's.

    The groups and their meaning, units and sources: ``togcrf.model.options`` and docs/togcrf.md.
    """
    config = TrainConfig() if preset_name is None else preset(preset_name, torch.cuda.is_available())
    for name, value in dotted_options(config.model_options).items():
        typer.echo(f"{name}={json.dumps(value, separators=(',', ':'))}")


def register(app: typer.Typer) -> None:
    """Add the ``train`` and ``options`` commands to the togcrf CLI."""
    def command(**given: Any) -> None:
        train_command(**given)

    command.__doc__ = train_command.__doc__
    command.__signature__ = _train_command_signature()
    command.__annotations__ = {name: parameter.annotation
                               for name, parameter in command.__signature__.parameters.items()}
    app.command("train")(command)
    app.command("options")(options_command)
