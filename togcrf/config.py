"""Every setting of a training run, defined once (:class:`TrainConfig`), and the named presets.

:class:`TrainConfig` is the one definition of each training option: its type, its default and its help
text (the field's metadata). ``togcrf train`` and ``togcrf reproduce`` derive their command-line options
from its fields (:func:`command_parameters`), a run's ``config.json`` and checkpoint store it whole,
resolved, and the presets are complete configurations of it:

- ``paper``: the paper's setting (Section V: 10 epochs, SGD at lr 0.001, momentum 0.9; Section IV-B:
  ResNet-101), native image size, every sample;
- ``gpu``: what fits a short GPU lease (ResNet-50 at the samples' native 320 px, batch 8, AdamW with a
  cosine over an 11-minute budget, data loaded by 5 processes; ``gpu/table-gpu.sh``);
- ``cpu``: the CPU recipe, one hour of training per model on 2 cores: ResNet-18 stopped after C4 with an
  FPN on C3-C4 at 160 px, AdamW with a cosine over the hour, bfloat16 autocast where the CPU has it, a
  64-sample validation slice, on the data of ``pipelines/recipe-pairs96.toml`` (``docs/results.md``);
- ``small``: shows the pipeline running end to end in minutes (ResNet-18, 8 epochs, 64 training and 32
  test samples at 192 px, lr 0.01 so that a model trained from scratch moves in 256 steps).

Without a preset a run takes the field defaults, which are the paper's setting with data loaded in the
training process. Options given explicitly override the preset.
"""

from __future__ import annotations

import inspect
import json
import types
import typing
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from typing import Annotated, Any

import typer

from togcrf.data import DEPTH_REFERENCES
from togcrf.model import BACKBONES, MODEL_NAMES, ModelOptions, model_options, options_dict
from togcrf.model.options import with_options

#: Optimisers of ``--optimizer``.
OPTIMIZERS = ("sgd", "adamw")

#: Learning-rate schedules of ``--lr-schedule``.
LR_SCHEDULES = ("step", "cosine")

#: Devices of ``--device``.
DEVICES = ("auto", "cpu", "cuda")


def _option(default: Any = MISSING, help: str = "", *, factory: Any = MISSING, cli: str | None = None,
            zero_is_none: bool = False) -> Any:
    """A field with its command-line help; ``cli`` names its option when that is not the field's name,
    ``zero_is_none``: 0 on the command line means None (no limit, native, all)."""
    metadata = {"help": help, "cli": cli, "zero_is_none": zero_is_none}
    if factory is not MISSING:
        return field(default_factory=factory, metadata=metadata)
    return field(default=default, metadata=metadata)


@dataclass
class TrainConfig:
    """Every option of a training run; all of them are written to ``config.json`` and the checkpoint."""

    data: str = _option("", "Data dir with samples shards.")
    out: str = _option("", "Run dir (checkpoint.pt, metrics.csv, config.json, train.log).")
    pipeline: str | None = _option(None, "Use the shards of this pipeline's manifest (else every samples shard).")
    model: str = _option("tog-crfs", f"One of {', '.join(MODEL_NAMES)}.")
    backbone: str = _option("resnet101", f"ResNet depth: {', '.join(BACKBONES)} (paper: resnet101).")
    epochs: int = _option(10, "Epochs (paper: 10); an upper bound under --time-budget.")
    lr: float = _option(0.001, "Base learning rate (paper: 0.001 with SGD).")
    momentum: float = _option(0.9, "SGD momentum (paper: 0.9).")
    weight_decay: float = _option(1e-4, "Weight decay (none on normalisation weights and biases with AdamW).")
    batch_size: int = _option(2, "Images per step (per process under torchrun).")
    image_size: int | None = _option(None, "Longer image side fed to the network, pixels (0: native).",
                                     zero_is_none=True)
    augment: bool = _option(True, "Flips, quarter turns and scale jitter.")
    warmup_steps: int = _option(100, "Linear learning-rate warm-up from lr / 100 over this many steps.")
    lr_decay_epochs: list[int] = _option(help="With --lr-schedule step: x0.1 from this epoch on (repeatable).",
                                         factory=list, cli="lr-decay-epoch")
    clip_grad_norm: float = _option(10.0, "Gradient-norm clipping (0: off).")
    device: str = _option("auto", "auto (CUDA when available), cpu or cuda.")
    amp: bool = _option(True, "Mixed precision on CUDA: bfloat16 where supported, else float16 with loss scaling.")
    cpu_bf16: bool = _option(False, "bfloat16 autocast on a CPU with native bfloat16 (AVX-512 BF16 or AMX; "
                             "float32 elsewhere, and the log says so).")
    seed: int = _option(0, "Seed of initialisation, data order and augmentation.")
    max_samples: int | None = _option(None, "Train on the first N samples only (0: all).", zero_is_none=True)
    eval_max_samples: int | None = _option(None, "Test samples `togcrf reproduce` evaluates (0: all).",
                                           zero_is_none=True)
    workers: int = _option(0, "DataLoader worker processes (0: load in the training process).")
    split: str = _option("train", "Split trained on (its last --val-samples are held out).")
    model_options: ModelOptions = _option(
        help="Model option GROUP.NAME=JSON_VALUE, e.g. rpn.anchor_sizes=[27,53,107] (repeatable; "
        "`togcrf options` lists them).", factory=ModelOptions, cli="option")
    resume: bool = _option(False, "Continue RUN_DIR/checkpoint.pt (without it an existing checkpoint is an error).")
    optimizer: str = _option("sgd", f"One of {', '.join(OPTIMIZERS)} (paper: sgd; adamw: betas 0.9, 0.999).")
    lr_schedule: str = _option("step", "step: x0.1 from each --lr-decay-epoch; cosine: to 0 over the run "
                               "(over the time budget's spent fraction under --time-budget).")
    scale_jitter: float = _option(0.1, "Augmentation scales are drawn from [1 - this, 1].")
    depth_reference: str = _option("table", "Input height above: table (the fitted table plane) or median "
                                   "(the image's median depth).")
    val_samples: int = _option(0, "Training samples held out for validation metrics after every epoch (0: none).")
    time_budget_minutes: float | None = _option(
        None, "Minutes of training steps after which the run stops, its checkpoint holding the part epoch "
        "(0: none, the epochs end the run).", cli="time-budget", zero_is_none=True)
    init: str | None = _option(None, "Start from this checkpoint's weights (fine-tuning; the optimiser and "
                               "schedule start afresh).")
    train_only: list[str] = _option(help="Train only the parameters whose names start with this prefix "
                                    "(repeatable); with --init such layers may be new.", factory=list)

    def __post_init__(self) -> None:
        self.model_options = model_options(self.model_options)

    def validate(self) -> None:
        """Raise ValueError naming the bad option and what is allowed."""
        choices = {"model": MODEL_NAMES, "backbone": BACKBONES, "device": DEVICES, "optimizer": OPTIMIZERS,
                   "lr_schedule": LR_SCHEDULES, "depth_reference": DEPTH_REFERENCES}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise ValueError(f"--{option_name(name)} {getattr(self, name)!r}: expected one of {', '.join(allowed)}")
        for name in ("epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{option_name(name)} {getattr(self, name)}: expected 1 or more")
        if not self.lr > 0:
            raise ValueError(f"--lr {self.lr}: expected a rate > 0")
        for name in ("warmup_steps", "workers", "val_samples"):
            if getattr(self, name) < 0:
                raise ValueError(f"--{option_name(name)} {getattr(self, name)}: expected 0 or more")
        if not 0 <= self.scale_jitter < 1:
            raise ValueError(f"--scale-jitter {self.scale_jitter}: expected a value in [0, 1)")
        if self.time_budget_minutes is not None and not self.time_budget_minutes > 0:
            raise ValueError(f"--time-budget {self.time_budget_minutes}: expected minutes > 0, or 0 for none")
        for name in ("image_size", "max_samples", "eval_max_samples"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"--{option_name(name)} {value}: expected 1 or more, or 0 for none")

    def as_dict(self) -> dict[str, Any]:
        """JSON values of every field, the model options nested by group."""
        return {**asdict(self), "model_options": options_dict(self.model_options)}


def option_name(field_name: str) -> str:
    """The command-line option of a field: ``--time-budget`` for ``time_budget_minutes``."""
    spec = next(item for item in fields(TrainConfig) if item.name == field_name)
    return spec.metadata.get("cli") or field_name.replace("_", "-")


#: The paper's setting: the field defaults, with 5 data-loading processes.
PAPER = TrainConfig(workers=5)

#: The CPU recipe's model options: a lighter detector (the ResNet stopped after C4 and an FPN on C3-C4 with 128
#: channels, 64 RoIs per image for the RCNN loss, a 256-wide box head, 128-channel grasp blocks, fewer training
#: proposals), RPN anchors of 27, 53 and 107 px for boxes of 20-120 px at 160 px, 10 px grasp anchors (ROI-GD's
#: 12 px at 192 px, REFERENCE section 3, scaled to 160 px), the top-1 ranking term at weight 0.2, and 8 RoIs per
#: image for the grasp head.
CPU_MODEL_OPTIONS = model_options({
    "backbone": {"fpn_min_stride": 8, "fpn_max_stride": 16, "fpn_channels": 128},
    "rpn": {"anchor_sizes": (27, 53, 107), "pre_nms_train": 500, "post_nms_train": 250},
    "box_head": {"batch_per_image": 64, "size": 256},
    "grasp_head": {"channels": 128, "anchor_size": 10.0, "rois_per_image": 8},
    "loss": {"ranking_weight": 0.2},
})

#: The CPU recipe (see the module docstring).
CPU = TrainConfig(backbone="resnet18", epochs=50, image_size=160, batch_size=4, warmup_steps=200,
                  optimizer="adamw", lr_schedule="cosine", scale_jitter=0.15, val_samples=64,
                  time_budget_minutes=60.0, cpu_bf16=True, model_options=CPU_MODEL_OPTIONS)

#: The GPU recipe: the CPU recipe's training at 320 px with a ResNet-50, batch 8, the grasp anchors scaled with
#: the image (12 px at 192 px is 20 px at 320 px).
GPU = TrainConfig(backbone="resnet50", epochs=50, image_size=320, batch_size=8, warmup_steps=200,
                  optimizer="adamw", lr_schedule="cosine", scale_jitter=0.15, val_samples=128,
                  time_budget_minutes=11.0, workers=5, model_options={"grasp_head": {"anchor_size": 20.0}})

#: The pipeline shown end to end in minutes on a CPU.
SMALL = TrainConfig(backbone="resnet18", epochs=8, image_size=192, max_samples=64, eval_max_samples=32,
                    warmup_steps=16, lr=0.01)

#: Every preset by its name (``--preset``, ``--scale``).
PRESETS: dict[str, TrainConfig] = {"paper": PAPER, "gpu": GPU, "cpu": CPU, "small": SMALL}


def preset(name: str, cuda_available: bool = False) -> TrainConfig:
    """A copy of the preset named ``paper``, ``gpu``, ``cpu``, ``small`` or ``auto`` (paper with CUDA, else cpu)."""
    if name == "auto":
        name = "paper" if cuda_available else "cpu"
    if name not in PRESETS:
        raise ValueError(f"preset {name!r}: expected auto, {', '.join(PRESETS)}")
    return replace(PRESETS[name])


def parse_model_options(items: list[str]) -> dict[str, Any]:
    """``GROUP.NAME=JSON_VALUE`` pairs as dotted option values (a value that is not JSON is kept as a string)."""
    values: dict[str, Any] = {}
    for item in items:
        name, separator, value = item.partition("=")
        if not separator or not name:
            raise ValueError(f"--option {item!r}: expected GROUP.NAME=VALUE, e.g. rpn.anchor_sizes=[27,53,107]")
        try:
            values[name] = json.loads(value)
        except json.JSONDecodeError:
            values[name] = value
    return values


def _base_type(annotation: Any) -> Any:
    """``int`` of ``int | None``; other annotations as they are."""
    arguments = [argument for argument in typing.get_args(annotation) if argument is not type(None)]
    if isinstance(annotation, types.UnionType) and len(arguments) == 1:
        return arguments[0]
    return annotation


def command_parameters(excluded: tuple[str, ...] = (), required: tuple[str, ...] = (),
                       defaults_shown: bool = True) -> list[inspect.Parameter]:
    """Typer parameters for the fields of :class:`TrainConfig`, all defaulting to None ("not given").

    ``required`` fields must be given; ``excluded`` fields are left out; ``defaults_shown``: the help
    names each field's default (not for a command whose preset always sets them). Lists are repeatable
    options, the model options ``--option GROUP.NAME=VALUE`` pairs, booleans ``--NAME/--no-NAME``.
    """
    hints = typing.get_type_hints(TrainConfig)
    parameters = []
    for spec in fields(TrainConfig):
        if spec.name in excluded:
            continue
        name = option_name(spec.name)
        kind = _base_type(hints[spec.name])
        if spec.name == "model_options":
            kind = list[str]
        flag = f"--{name}/--no-{name}" if kind is bool else f"--{name}"
        shown = defaults_shown and spec.default not in (MISSING, None, "") and spec.name not in required
        help_text = spec.metadata["help"] + (f" Default: {spec.default}." if shown else "")
        option = typer.Option(flag, help=help_text, show_default=False)
        default = inspect.Parameter.empty if spec.name in required else None
        parameters.append(inspect.Parameter(spec.name, inspect.Parameter.KEYWORD_ONLY, default=default,
                                            annotation=Annotated[kind | None, option]))
    return parameters


def config_from_command(base: TrainConfig, given: dict[str, Any]) -> TrainConfig:
    """``base`` with the options given on the command line (None: not given) applied; model options merged."""
    changes: dict[str, Any] = {}
    for spec in fields(TrainConfig):
        value = given.get(spec.name)
        if value is None or (isinstance(value, list | tuple) and not value):
            continue
        if spec.name == "model_options":
            value = with_options(base.model_options, parse_model_options(list(value)))
        elif spec.metadata.get("zero_is_none") and value == 0:
            value = None
        elif isinstance(value, tuple):
            value = list(value)
        changes[spec.name] = value
    return replace(base, **changes)
