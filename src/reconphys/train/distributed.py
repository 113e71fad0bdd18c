"""Multi-process training with ``torchrun`` (DDP): set up from the RANK / WORLD_SIZE variables.

``torchrun --nproc_per_node N -m reconphys.cli train CONFIG`` starts N processes; each reads its
rank from the environment, joins the process group (NCCL on CUDA, gloo on CPU), takes
``batch_size / N`` samples of every global batch, and averages gradients with the others. Only
rank 0 writes checkpoints, logs and the exported model. Without those variables (or with
WORLD_SIZE = 1) training runs in the one process and none of this is used.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from ..devices import resolve_device


@dataclass(frozen=True)
class Distributed:
    rank: int = 0
    local_rank: int = 0
    world_size: int = 1

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def _select_cuda(device: torch.device) -> torch.device:
    """Make a CUDA device this process's current one (``cuda`` → ``cuda:<current index>``)."""
    if device.type == "cuda":
        if device.index is None:
            device = torch.device(f"cuda:{torch.cuda.current_device()}")
        torch.cuda.set_device(device)
    return device


def setup(device_name: str) -> tuple[Distributed, torch.device]:
    """Join the torchrun process group when launched by torchrun; the device of this process."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size <= 1:
        return Distributed(), _select_cuda(resolve_device(device_name, field="train.device"))
    rank = int(os.environ["RANK"])
    local_rank = int(os.environ.get("LOCAL_RANK", rank))
    device = _select_cuda(resolve_device(device_name, local_rank, field="train.device"))
    if not dist.is_initialized():
        backend = "nccl" if device.type == "cuda" else "gloo"
        dist.init_process_group(backend=backend, rank=rank, world_size=world_size)
    return Distributed(rank, local_rank, world_size), device


def cleanup(context: Distributed) -> None:
    if context.enabled and dist.is_initialized():
        dist.destroy_process_group()


def all_reduce_mean(values: torch.Tensor, context: Distributed) -> torch.Tensor:
    """The mean of ``values`` over the ranks (unchanged without DDP)."""
    if not context.enabled:
        return values
    values = values.clone()
    dist.all_reduce(values, op=dist.ReduceOp.SUM)
    return values / context.world_size


def barrier(context: Distributed) -> None:
    if context.enabled:
        dist.barrier()
