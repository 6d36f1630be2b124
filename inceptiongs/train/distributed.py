"""Blocks spread over processes and machines with torch.distributed (torchrun sets the ranks).

``torchrun --nproc-per-node P [--nnodes N --rdzv-endpoint HOST:PORT ...] -m inceptiongs train SCENE
--blocks B --out SHARED/RUN``: every rank plans the same blocks (rank 0 writes the plan, the others
read it after a barrier), trains its share (:func:`assign`, largest first), waits at a barrier,
and rank 0 merges. The run folder on a shared file system is the only hand-off; the process group
carries nothing but the barriers. Without torchrun the same code runs as one process of one rank.

On CPUs the group uses gloo, on GPUs NCCL, each rank on its own GPU (LOCAL_RANK). A barrier waits
as long as the slowest rank trains (hours on a large capture), so the group's timeout is long.
"""

from __future__ import annotations

import datetime
import os
from dataclasses import dataclass
from typing import Sequence

from ..errors import InputError

# A rank waits this long at a barrier for the others to finish their blocks.
BARRIER_TIMEOUT = datetime.timedelta(days=7)


@dataclass(frozen=True)
class Ranks:
    """This process's place: rank in 0..world-1, local_rank and local_world on its machine."""

    rank: int = 0
    world: int = 1
    local_rank: int = 0
    local_world: int = 1

    @property
    def distributed(self) -> bool:
        return self.world > 1


def ranks_from_environment(environ=os.environ) -> Ranks:
    """The ranks torchrun set (RANK, WORLD_SIZE, LOCAL_RANK, LOCAL_WORLD_SIZE); one rank without them."""
    def number(name: str, default: int) -> int:
        value = environ.get(name)
        if value is None:
            return default
        try:
            return int(value)
        except ValueError:
            raise InputError(f"{name}={value!r}: not an integer (set by torchrun)") from None

    world = number("WORLD_SIZE", 1)
    ranks = Ranks(number("RANK", 0), world, number("LOCAL_RANK", 0), number("LOCAL_WORLD_SIZE", world))
    if not (ranks.world >= 1 and 0 <= ranks.rank < ranks.world and 0 <= ranks.local_rank < ranks.local_world):
        raise InputError(f"RANK {ranks.rank} of WORLD_SIZE {ranks.world} (LOCAL_RANK {ranks.local_rank} of "
                         f"{ranks.local_world}): inconsistent ranks")
    return ranks


def start_group(ranks: Ranks, cuda: bool) -> None:
    """Join the process group (gloo, or NCCL on GPUs) and split the machine's cores (each rank
    takes its share of them, numba's threads too) or its GPUs (one each)."""
    if not ranks.distributed:
        return
    import torch
    import torch.distributed as dist

    if cuda:
        torch.cuda.set_device(ranks.local_rank)
    share = max(1, (os.cpu_count() or 1) // ranks.local_world)
    os.environ.setdefault("OMP_NUM_THREADS", str(share))
    try:
        import numba

        numba.set_num_threads(min(share, numba.config.NUMBA_NUM_THREADS))
    except ImportError:
        pass
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo", timeout=BARRIER_TIMEOUT)


def barrier(ranks: Ranks) -> None:
    """Every rank waits here for the others (nothing with one rank)."""
    if ranks.distributed:
        import torch.distributed as dist

        dist.barrier()


def end_group(ranks: Ranks) -> None:
    if ranks.distributed:
        import torch.distributed as dist

        if dist.is_initialized():
            dist.destroy_process_group()


def assign(costs: Sequence[float], world: int) -> list[list[int]]:
    """Blocks (by their ``costs``, e.g. photo counts) to ``world`` ranks: largest first, each to
    the rank with the least work so far (ties: the lower rank). The same on every rank."""
    loads = [0.0] * world
    shares: list[list[int]] = [[] for _ in range(world)]
    for index in sorted(range(len(costs)), key=lambda i: (-costs[i], i)):
        rank = min(range(world), key=lambda r: (loads[r], r))
        shares[rank].append(index)
        loads[rank] += costs[index]
    return shares
