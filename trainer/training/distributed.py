"""One run spread over several processes (``torchrun``), each stepping its share of the envs.

``torchrun --nproc_per_node N trainer run ...`` starts N copies of the trainer with ``RANK``,
``WORLD_SIZE`` and ``LOCAL_RANK`` set; ``world()`` reads them (a plain ``trainer run`` is a
world of one, and never touches ``torch.distributed``). What the processes share, all through
the collectives below (gloo on the CPU, NCCL on CUDA):

- the agent: rank 0's initial weights broadcast at the start (``broadcast_module``); each
  minibatch's gradient averaged (``average_gradients``: one all-reduce of the flattened
  gradient), so every rank takes the same optimizer step and the parameters stay identical;
- the normalizers' batch moments (``pool_moments``), the advantage moments of each minibatch,
  the adaptive learning rate's KL (``all_reduce_mean``);
- the ended episodes (``all_gather``), so every rank counts the whole run's successes and
  moves the lift curriculum alike;
- whether to stop, and rank 0's clock (``agree_to_stop``), so all stop at one iteration;
- each rank's own state for the checkpoint (``gather_to_main``), written by rank 0 alone.

A collective that fails (another process died, or answered nothing within the process group's
timeout) is a one-line ``TrainerError``; torchrun's own failure handling ends the others.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

import torch
import torch.distributed as dist
from torch import nn

from trainer.errors import TrainerError

TIMEOUT_ENV = "GEOMGRASP_DIST_TIMEOUT_S"
"""Environment variable: seconds a collective waits for the other processes before the run
fails (default ``DEFAULT_TIMEOUT_S``). A process that dies is noticed by torchrun at once;
the timeout only ends a run whose process hangs, or waits longer than this for rank 0 to
record the grasp starts."""
DEFAULT_TIMEOUT_S = 1800.0


@dataclass(frozen=True)
class World:
    """This process's place in a run: ``rank`` of ``size`` processes, ``local_rank`` on its
    machine (its GPU's index)."""

    rank: int = 0
    size: int = 1
    local_rank: int = 0

    @property
    def distributed(self) -> bool:
        return self.size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the one that writes the run's files and shows its progress."""
        return self.rank == 0


def world() -> World:
    """The world torchrun set up (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``), or a world of one
    where ``WORLD_SIZE`` is unset."""
    if "WORLD_SIZE" not in os.environ:
        return World()
    try:
        return World(int(os.environ.get("RANK", "0")), int(os.environ["WORLD_SIZE"]),
                     int(os.environ.get("LOCAL_RANK", "0")))
    except ValueError:
        raise TrainerError(
            "RANK, WORLD_SIZE and LOCAL_RANK must be integers: launch with torchrun, or unset "
            "them for a one-process run"
        ) from None


def local_envs(num_envs: int, size: int) -> int:
    """Envs each of ``size`` processes steps: ``num_envs / size``, refused unless whole."""
    if num_envs % size:
        raise TrainerError(
            f"num_envs {num_envs} does not divide among {size} processes: choose --num-envs a "
            f"multiple of {size} (or another --nproc_per_node)"
        )
    return num_envs // size


def device_of(device: str, w: World) -> str:
    """The device of ``w``'s process for a run on ``device``: a CUDA run's rank takes GPU
    ``LOCAL_RANK`` of its machine; a CPU run stays on the CPU."""
    if w.distributed and torch.device(device).type == "cuda":
        return f"cuda:{w.local_rank}"
    return device


def threads_of(nthread: int, w: World) -> int:
    """Simulation threads of ``w``'s process for a run of ``nthread`` (0: all cores): a
    distributed run's "all cores" is this machine's cores shared by its processes
    (``LOCAL_WORLD_SIZE``), not every core for each."""
    if nthread or not w.distributed:
        return nthread
    local = int(os.environ.get("LOCAL_WORLD_SIZE", str(w.size)))
    return max(1, (os.cpu_count() or 1) // max(local, 1))


def timeout_s() -> float:
    """The process group's timeout (s): ``TIMEOUT_ENV`` or ``DEFAULT_TIMEOUT_S``."""
    value = os.environ.get(TIMEOUT_ENV, "")
    if not value:
        return DEFAULT_TIMEOUT_S
    try:
        seconds = float(value)
    except ValueError:
        seconds = -1.0
    if not seconds > 0:
        raise TrainerError(f"{TIMEOUT_ENV}={value!r}: must be a number of seconds above 0")
    return seconds


def setup(w: World, device: str) -> None:
    """Join the process group of ``w`` (once per process; nothing for a world of one): NCCL
    for a CUDA run (this process on GPU ``local_rank``), else gloo."""
    if not w.distributed or dist.is_initialized():
        return
    cuda = torch.device(device).type == "cuda"
    if cuda:
        torch.cuda.set_device(w.local_rank)
    dist.init_process_group("nccl" if cuda else "gloo", timeout=timedelta(seconds=timeout_s()))


def shutdown() -> None:
    """Leave the process group, if this process joined one."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


@contextmanager
def _collective(what: str) -> Iterator[None]:
    """A failed collective as one line: which, and what to do."""
    try:
        yield
    except RuntimeError as exc:  # (torch's DistBackendError and gloo's errors are these)
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise TrainerError(
            f"rank {dist.get_rank()}: {what} failed ({first[:200]}): another process of the "
            f"run ended or stopped answering; resume the run with the same --nproc_per_node"
        ) from None


def all_reduce_sum(tensor: torch.Tensor) -> torch.Tensor:
    """``tensor`` (any shape) summed over the processes, in place; returned."""
    with _collective("all_reduce"):
        dist.all_reduce(tensor)
    return tensor


def all_reduce_mean(tensor: torch.Tensor) -> torch.Tensor:
    """``tensor`` (any shape) averaged over the processes, in place; returned."""
    return all_reduce_sum(tensor).div_(dist.get_world_size())


def average_gradients(parameters: Iterable[nn.Parameter]) -> None:
    """Replace every gradient by its mean over the processes: one all-reduce of all of them
    flattened into one vector (the networks are small MLPs: one message beats a bucket per
    layer). Parameters without a gradient are left out, alike on every rank."""
    grads = [p.grad for p in parameters if p.grad is not None]
    if not grads:
        return
    flat = all_reduce_mean(torch.cat([g.reshape(-1) for g in grads]))
    offset = 0
    for g in grads:
        g.copy_(flat[offset:offset + g.numel()].view_as(g))
        offset += g.numel()


def pool_moments(
    n: int, mean: torch.Tensor, var: torch.Tensor
) -> tuple[int, torch.Tensor, torch.Tensor]:
    """The count, mean and (biased) variance of the union of every process's batch, from each
    one's ``n`` samples of mean ``mean`` and variance ``var`` (the same shape on every rank):
    one all-reduce of (n, n·mean, n·(var + mean²)). The result is the same on every rank."""
    dtype = torch.float64  # (sums of squares of many samples)
    packed = torch.cat([
        torch.tensor([float(n)], dtype=dtype, device=mean.device),
        (n * mean.to(dtype)).reshape(-1),
        (n * (var.to(dtype) + mean.to(dtype) ** 2)).reshape(-1),
    ])
    all_reduce_sum(packed)
    total = int(packed[0].item())
    if total == 0:
        return 0, torch.zeros_like(mean), torch.zeros_like(var)
    sums, squares = packed[1:1 + mean.numel()], packed[1 + mean.numel():]
    pooled_mean = sums / total
    pooled_var = (squares / total - pooled_mean**2).clamp_min(0.0)
    return total, pooled_mean.view_as(mean).to(mean.dtype), pooled_var.view_as(var).to(var.dtype)


def standardize(x: torch.Tensor) -> torch.Tensor:
    """``x`` (any shape) minus the mean over every process's ``x``, over their (unbiased)
    standard deviation clamped to >= 1e-6: what TorchRL's ``ClipPPOLoss`` does to one
    minibatch's advantages, done to the minibatch the processes' parts make together."""
    packed = torch.stack([torch.tensor(float(x.numel()), dtype=torch.float64, device=x.device),
                          x.double().sum(), x.double().pow(2).sum()])
    all_reduce_sum(packed)
    n, total, squares = packed[0], packed[1], packed[2]
    if n.item() < 2:
        return x
    mean = total / n
    std = ((squares - n * mean**2).clamp_min(0.0) / (n - 1)).sqrt()
    return (x - mean.to(x.dtype)) / std.to(x.dtype).clamp_min(torch.finfo(torch.float).resolution)


def _flat_state(module: nn.Module) -> torch.Tensor:
    """Every parameter and floating buffer of ``module``, flattened into one float64 vector."""
    tensors = [t.detach().reshape(-1).to(torch.float64) for t in module.state_dict().values()
               if torch.is_floating_point(t)]
    return torch.cat(tensors)


def broadcast_module(module: nn.Module) -> None:
    """Give every process rank 0's parameters and buffers (a fresh run's ranks initialise
    their networks from their own streams)."""
    with _collective("broadcast"), torch.no_grad():
        for tensor in module.state_dict().values():
            dist.broadcast(tensor, src=0)


def check_same(module: nn.Module, what: str) -> None:
    """Refuse to go on if ``module``'s state differs from rank 0's on any process (the
    averaged updates keep them equal; this catches a broken guarantee, not noise)."""
    mine = _flat_state(module)
    theirs = mine.clone()
    with _collective("broadcast"):
        dist.broadcast(theirs, src=0)
    differs = torch.tensor([float(not torch.equal(mine, theirs))], device=mine.device)
    if all_reduce_sum(differs).item() > 0:
        raise TrainerError(f"{what}: the processes' agents differ from rank 0's; the run "
                           f"cannot continue as one run (a bug: please report it)")


def all_gather(obj: Any) -> list[Any]:
    """Every process's ``obj`` (picklable), in rank order, on every process."""
    out: list[Any] = [None] * dist.get_world_size()
    with _collective("all_gather_object"):
        dist.all_gather_object(out, obj)
    return out


def gather_to_main(obj: Any) -> list[Any] | None:
    """Every process's ``obj`` (picklable) in rank order on rank 0; None elsewhere."""
    rank = dist.get_rank()
    out: list[Any] | None = [None] * dist.get_world_size() if rank == 0 else None
    with _collective("gather_object"):
        dist.gather_object(obj, out, dst=0)
    return out


def agree_to_stop(stop: bool, wall_time_s: float, device: torch.device) -> tuple[bool, float]:
    """(whether any process was asked to stop, rank 0's training time (s)): one all-reduce,
    so that every rank leaves at the same iteration and judges the time budget alike."""
    rank0 = dist.get_rank() == 0
    packed = torch.tensor([float(stop), wall_time_s if rank0 else 0.0], dtype=torch.float64,
                          device=device)
    all_reduce_sum(packed)
    return bool(packed[0].item() > 0), float(packed[1].item())


def barrier() -> None:
    """Wait until every process gets here."""
    with _collective("barrier"):
        dist.barrier()


PER_RANK_KEYS = ("shuffle_rng", "torch_rng", "cuda_rng", "episode_return", "episode_length",
                 "env")
"""The checkpoint keys each process has its own of (its envs, their running episodes, its
generators); all else (agent, optimizer, counters, curriculum, iteration) is the same on
every rank. Rank 0's are the checkpoint's own keys, as in a one-process run's; the others'
are in its ``ranks`` list (rank r at index r - 1)."""


def rank_part(state: dict[str, Any]) -> dict[str, Any]:
    """The ``PER_RANK_KEYS`` of a ``TrainState.state_dict``."""
    return {k: state[k] for k in PER_RANK_KEYS if k in state}


def with_ranks(state: dict[str, Any], parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Rank 0's ``state`` with every other rank's part (``parts``, in rank order, rank 0's
    first) as its ``ranks`` list."""
    return {**state, "ranks": parts[1:]} if len(parts) > 1 else state


def state_of_rank(state: dict[str, Any], rank: int, size: int) -> dict[str, Any]:
    """What process ``rank`` of ``size`` resumes from: the checkpoint ``state`` with that
    rank's own part in place of rank 0's (a checkpoint of another world size is refused)."""
    ranks = state.get("ranks", [])
    if len(ranks) != size - 1:
        raise TrainerError(
            f"the checkpoint holds the state of {len(ranks) + 1} processes, this launch has "
            f"{size}: resume with torchrun --nproc_per_node {len(ranks) + 1}"
        )
    if rank == 0:
        return state
    return {**{k: v for k, v in state.items() if k not in PER_RANK_KEYS}, **ranks[rank - 1]}
