"""What the ended episodes of training say: success at the task's lift height (over all
episodes and per target object), the running return and length of every env's episode, and the
rollout's episode statistics for ``metrics.csv``.

The lift curriculum (``curriculum.py``) counts its own windows with ``ObjectOutcomes``; it is
handed the ended episodes as an ``OutcomeSink``, so this module does not import it."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase


class OutcomeSink(Protocol):
    """What ``EpisodeStats.record`` tells of the ended episodes: their target object and success
    at the target they trained for (``trainer.training.curriculum.LiftCurriculum``)."""

    def record(self, object_ids: list[int], successes: list[bool]) -> None: ...


class ObjectOutcomes:
    """Success at the task's lift height per target object: each object's last ``window``
    episodes.

    ``rate`` is the mean over the objects of their own success rates (the paper's "average
    success rate across all objects"). The plain rate over the last ended episodes
    (``success_rate``) over-counts the objects that are lifted: a lifted object's episode ends
    early, so it ends more episodes per iteration than one that is not (in a run with 300-step
    episodes, ~35 steps against 300)."""

    def __init__(self, window: int) -> None:
        self.window = window
        self.by_object: dict[int, deque[bool]] = {}

    def extend(self, object_ids: list[int], successes: list[bool]) -> None:
        for object_id, success in zip(object_ids, successes, strict=True):
            if object_id not in self.by_object:
                self.by_object[object_id] = deque(maxlen=self.window)
            self.by_object[object_id].append(success)

    def rate(self) -> float:
        """Mean over the objects with an ended episode of their success rates (NaN: none)."""
        rates = [sum(d) / len(d) for d in self.by_object.values() if d]
        return sum(rates) / len(rates) if rates else float("nan")

    def state_dict(self) -> dict[int, list[bool]]:
        return {k: list(v) for k, v in self.by_object.items()}

    def load_state_dict(self, state: dict[int, list[bool]]) -> None:
        for object_id, values in state.items():
            self.by_object[int(object_id)] = deque(values, maxlen=self.window)


@dataclass
class EndedEpisodes:
    """The episodes that ended in one rollout (n of them), in the order they ended (time step
    first, then env), and what else the rollout's row counts."""

    order: torch.Tensor
    """(n,) long: time step x the run's envs + the env's index in the run (the sort key that
    merges the processes' episodes into a one-process run's order)."""
    returns: torch.Tensor
    """(n,) their returns."""
    lengths: torch.Tensor
    """(n,) their lengths (actions)."""
    success: torch.Tensor
    """(n,) bool: lifted by the task's height."""
    objects: torch.Tensor
    """(n,) long: their target object's id."""
    target_success: torch.Tensor
    """(n,) bool: success at the target they trained for (the curriculum's)."""
    grasp_start_lifted: torch.Tensor
    """(m,) float 0/1: the episodes started from a scripted grasp that ended (counted nowhere
    else): whether each met its training target."""
    unstable: int
    """Resets because the simulation blew up, in the rollout."""

    @staticmethod
    def merged(parts: list[EndedEpisodes]) -> EndedEpisodes:
        """The processes' ``parts`` as one rollout's, in the order a one-process run ends
        them."""
        order = torch.cat([p.order for p in parts])
        sort = torch.argsort(order, stable=True)

        def cat(name: str) -> torch.Tensor:
            return torch.cat([getattr(p, name) for p in parts])[sort]

        return EndedEpisodes(
            order=order[sort], returns=cat("returns"), lengths=cat("lengths"),
            success=cat("success"), objects=cat("objects"),
            target_success=cat("target_success"),
            grasp_start_lifted=torch.cat([p.grasp_start_lifted for p in parts]),
            unstable=sum(p.unstable for p in parts),
        )


class EpisodeStats:
    """The training episodes of ``num_envs`` envs: those running (their return and length so
    far, shape (num_envs,), on ``device``) and the last ``window`` ended ones (success at the
    task's lift height ``task_h_bar`` (m), over all of them and per target object)."""

    def __init__(
        self, num_envs: int, window: int, task_h_bar: float, device: torch.device,
        env_offset: int = 0, run_envs: int | None = None,
    ) -> None:
        # (a process of a distributed run: its envs are env_offset.. of the run's run_envs)
        self.env_offset = env_offset
        self.run_envs = num_envs if run_envs is None else run_envs
        self.task_h_bar = task_h_bar
        self.outcomes: deque[bool] = deque(maxlen=window)
        self.objects = ObjectOutcomes(window)
        self.episode_return = torch.zeros(num_envs, device=device)
        self.episode_length = torch.zeros(num_envs, device=device)

    def success_rate(self) -> float:
        """Over the last ``window`` ended episodes, whatever their object (NaN: none yet)."""
        return sum(self.outcomes) / len(self.outcomes) if self.outcomes else float("nan")

    def object_success_rate(self) -> float:
        """The mean over the objects of their own rates (NaN: none yet)."""
        return self.objects.rate()

    def record(
        self, data: TensorDictBase, curriculum: OutcomeSink,
        merge: Callable[[EndedEpisodes], EndedEpisodes] | None = None,
    ) -> dict[str, float]:
        """Walk a rollout ``data`` of shape (num_envs, T) in time (a loop over T steps, not over
        envs): accumulate the running returns, record the episodes that ended here and, by
        their success at its current training target(s), in ``curriculum`` (not those that
        started from a scripted grasp: ``grasp_start``). ``merge``: the episodes that ended in
        every process of a distributed run from this one's (then every process counts the
        same). Returns the rollout's ``episodes``, mean ``episode_return`` and
        ``episode_length`` of those ended (NaN: none) and ``unstable_resets``; where episodes
        that started from a scripted grasp ended, also their count and success at their
        training target (``grasp_start_*``)."""
        ended = self.ended_in(data)
        if merge is not None:
            ended = merge(ended)
        return self.count(ended, curriculum)

    def ended_in(self, data: TensorDictBase) -> EndedEpisodes:
        """Accumulate the running returns and lengths over the rollout ``data`` (num_envs, T);
        the episodes that ended in it."""
        episode_return, episode_length = self.episode_return, self.episode_length
        reward = data["next", "reward"][..., 0]
        done = data["next", "done"][..., 0]
        target_success = data["next", "success"][..., 0]
        success = target_success & (data["next", "lift_height"][..., 0] >= self.task_h_bar)
        # On the device, without a host sync per step: the return and length each env has at
        # each step, then one transfer of the ended episodes.
        return_at = torch.empty_like(reward)
        length_at = torch.empty_like(reward)
        for t in range(reward.shape[1]):
            episode_return += reward[:, t]
            episode_length += 1
            return_at[:, t] = episode_return
            length_at[:, t] = episode_length
            keep = (~done[:, t]).to(episode_return.dtype)
            episode_return.mul_(keep)
            episode_length.mul_(keep)
        # Episodes in the order they ended (time first, then env).
        # Episodes started from a scripted grasp (``[run] grasp_starts``) count nowhere.
        from_grasp = data.get(("next", "grasp_start"), None)
        ended = (done if from_grasp is None else done & ~from_grasp[..., 0]).T.cpu()
        steps, envs = ended.nonzero(as_tuple=True)
        lifted = torch.zeros(0)
        if from_grasp is not None:
            started = (done & from_grasp[..., 0]).T.cpu()
            lifted = target_success.T.cpu()[started].float()
        return EndedEpisodes(
            order=steps * self.run_envs + self.env_offset + envs,
            returns=return_at.T.cpu()[ended],
            lengths=length_at.T.cpu()[ended],
            success=success.T.cpu()[ended],
            # The target of an ended episode is in its last step's "next" (the reset after).
            objects=data["next", "object_id"][..., 0].T.cpu()[ended],
            target_success=target_success.T.cpu()[ended],
            grasp_start_lifted=lifted,
            unstable=int(data["next", "unstable"].sum()),
        )

    def count(self, ended: EndedEpisodes, curriculum: OutcomeSink) -> dict[str, float]:
        """Record ``ended`` (``ended_in``'s, or every process's merged) here and in
        ``curriculum``; the rollout's statistics (``record``'s)."""
        ended_success = ended.success.tolist()
        self.outcomes.extend(ended_success)
        ended_objects = ended.objects.tolist()
        self.objects.extend(ended_objects, ended_success)
        curriculum.record(ended_objects, ended.target_success.tolist())
        extra = {}
        lifted = ended.grasp_start_lifted
        if len(lifted):  # for TensorBoard (metrics.csv keeps its columns)
            extra = {"grasp_start_episodes": len(lifted),
                     "grasp_start_success": float(lifted.mean())}
        returns, lengths = ended.returns, ended.lengths
        return {
            **extra,
            "episodes": len(ended_success),
            "episode_return": float(returns.mean()) if len(returns) else float("nan"),
            "episode_length": float(lengths.mean()) if len(lengths) else float("nan"),
            "unstable_resets": ended.unstable,
        }

    def state_dict(self) -> dict[str, Any]:
        """The checkpoint's ``outcomes``, ``object_outcomes``, ``episode_return`` and
        ``episode_length``."""
        return {
            "outcomes": list(self.outcomes),
            "object_outcomes": self.objects.state_dict(),
            "episode_return": self.episode_return.clone(),
            "episode_length": self.episode_length.clone(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """From ``state_dict``'s keys (checkpoints from before the per-object counters lack
        ``object_outcomes``: none recorded)."""
        device = self.episode_return.device
        self.outcomes.extend(state["outcomes"])
        self.objects.load_state_dict(state.get("object_outcomes", {}))
        self.episode_return = state["episode_return"].to(device)
        self.episode_length = state["episode_length"].to(device)
