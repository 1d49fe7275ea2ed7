"""Data-parallel training with ``torchrun``: the process group and what ``togcrf.train`` needs of it.

``torchrun --nproc-per-node N -m togcrf train ...`` starts N processes, each
with ``RANK``, ``WORLD_SIZE`` and ``LOCAL_RANK`` in its environment (torch's
elastic launcher). Each process trains a replica on its own share of every
step's samples (``--batch-size`` is per process, as in torchvision's
detection references), torch's ``DistributedDataParallel`` averages the
gradients, so N processes at batch b take the steps of one process at
batch N x b (the RPN and RoI sampling draws differ; ``docs/togcrf.md``).
Backends: NCCL on GPUs (one per process, ``cuda:LOCAL_RANK``), gloo on the
CPU. Rank 0 alone writes the run dir (checkpoint, metrics, logs) and runs
the validation; a resumed run loads the checkpoint in every process.

Without ``WORLD_SIZE`` (or with 1) nothing here does anything, so a plain
``togcrf train`` is the single-process run it always was.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
from torch import distributed, nn


@dataclass(frozen=True)
class Context:
    """This process's place in the run: ``rank`` of ``world`` processes, ``local_rank`` on its machine."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Rank 0: the process that writes the run dir."""
        return self.rank == 0

    @property
    def parallel(self) -> bool:
        """More than one process."""
        return self.world > 1


def from_environment() -> Context:
    """The context torchrun gives (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``); one process without them."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Context()
    return Context(int(os.environ["RANK"]), world, int(os.environ.get("LOCAL_RANK", "0")))


def process_device(context: Context, device: torch.device) -> torch.device:
    """The device of this process: ``cuda:LOCAL_RANK`` for CUDA runs of several processes, else ``device``."""
    if context.parallel and device.type == "cuda":
        torch.cuda.set_device(context.local_rank)
        return torch.device("cuda", context.local_rank)
    return device


def start(context: Context, device: torch.device) -> None:
    """Join the process group (NCCL on CUDA, gloo on the CPU), once per process."""
    if context.parallel and not distributed.is_initialized():
        distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")


def wrap(model: nn.Module, context: Context, device: torch.device) -> nn.Module:
    """``DistributedDataParallel`` around the model for several processes; the model itself for one.

    ``find_unused_parameters``: a step may leave parts unused (no
    foreground RoI in an image gives the grasp branch nothing to do).
    """
    if not context.parallel:
        return model
    device_ids = [context.local_rank] if device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(model, device_ids=device_ids, find_unused_parameters=True)


def rank_zero_value(value: float, context: Context, device: torch.device) -> float:
    """Rank 0's ``value`` in every process (so that all stop at the same step of a time budget)."""
    if not context.parallel:
        return value
    tensor = torch.tensor([value], dtype=torch.float64, device=device)
    distributed.broadcast(tensor, src=0)
    return float(tensor.item())


def barrier(context: Context) -> None:
    """Wait for every process (after rank 0 wrote a checkpoint, before the others read it)."""
    if context.parallel:
        distributed.barrier()
