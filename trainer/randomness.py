"""One seeded source of randomness per run, derived into independent named streams.

A run has one seed (``run.seed``; evaluation its own fixed seed). Every consumer of randomness
draws from a stream derived from that seed and the stream's name, so no two consumers share a
sequence (before, the env's reset generator and PPO's minibatch shuffle were two torch
generators seeded with the same number, and drew the same numbers), and adding a stream never
shifts another one:

==================  ==================  ====================================================
stream              kind                what draws from it
==================  ==================  ====================================================
``layouts``         numpy Generator     which objects fill each layout's slots (``GraspTask``)
``resets``          torch Generator     settled state, yaw and target of each new episode
``actions``         torch global        the policy's sampled actions (TorchRL samples with
                                        torch's global generator) and the networks' initial
                                        weights
``shuffle``         torch Generator     PPO's minibatch order
``grasp_starts``    torch Generator     the resets of the scripted trials that
                                        ``[run] grasp_starts`` records
``grasp_choice``    torch Generator     which training resets start from them, and where
==================  ==================  ====================================================

A run spread over processes (``torchrun``: ``trainer.training.distributed``) gives each rank
its own streams: rank r > 0 mixes r into every seed except ``layouts`` (every rank must place
the same objects in the same envs, then step its own slice of them); rank 0's streams are
those of a one-process run, which a world of one therefore reproduces bit for bit.

The initial-state banks are not run randomness: they are cached data, keyed by their content
(``trainer.init_states``), seeded by ``init.seed`` and the objects they hold.

Runs whose config.json predates the streams (no ``run.random_streams``) used the seed itself
for every generator; ``RandomStreams(seed, legacy=True)`` reproduces that, so they resume and
evaluate exactly as they ran.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from trainer.config import TrainConfig

STREAMS = ("layouts", "resets", "actions", "shuffle", "grasp_starts", "grasp_choice")
SHARED_STREAMS = ("layouts",)
"""The streams every rank of a distributed run draws alike (the others are per rank)."""


class RandomStreams:
    """The named random streams of one run, all derived from ``seed``; those of process
    ``rank`` of a distributed run (0: a one-process run's)."""

    def __init__(self, seed: int, legacy: bool = False, rank: int = 0) -> None:
        self.seed = int(seed)
        self.legacy = legacy
        self.rank = int(rank)

    def seed_of(self, stream: str) -> int:
        """The 63-bit seed of ``stream``: ``seed`` and the stream's name through numpy's
        ``SeedSequence`` (statistically independent streams, stable across platforms)."""
        if stream not in STREAMS:
            raise ValueError(f"unknown random stream {stream!r}: one of {', '.join(STREAMS)}")
        per_rank = self.rank > 0 and stream not in SHARED_STREAMS
        if self.legacy and not per_rank:
            return self.seed
        name_key = int.from_bytes(hashlib.sha256(stream.encode()).digest()[:8], "little")
        # (rank 0 keeps the one-element key: its seeds are a one-process run's)
        key = (name_key, self.rank) if per_rank else (name_key,)
        sequence = np.random.SeedSequence(self.seed, spawn_key=key)
        return int(sequence.generate_state(1, np.uint64)[0] >> np.uint64(1))

    def numpy(self, stream: str) -> np.random.Generator:
        """A numpy generator of ``stream``."""
        return np.random.default_rng(self.seed_of(stream))

    def torch(self, stream: str, device: torch.device | str = "cpu") -> torch.Generator:
        """A torch generator of ``stream`` on ``device``."""
        return torch.Generator(device=device).manual_seed(self.seed_of(stream))

    def seed_global_torch(self, stream: str = "actions") -> None:
        """Seed torch's global generator (what TorchRL's action sampling and the networks'
        initialisation draw from) with ``stream``."""
        torch.manual_seed(self.seed_of(stream))


def run_streams(cfg: TrainConfig, rank: int = 0) -> RandomStreams:
    """The streams of a training run (of its process ``rank``): its seed, derived unless its
    config predates the streams (``run.random_streams`` false)."""
    return RandomStreams(cfg.run.seed, legacy=not cfg.run.random_streams, rank=rank)
