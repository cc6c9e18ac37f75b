"""Policy and value networks: observation normalization, a PointNet-like encoder for point
clouds, 3-layer MLPs, and the TorchRL modules the PPO loop uses.

Observation keys come from ``trainer.env``: ``proprio`` (E, 20) and ``object`` (E, D) or
(E, N, 3) for point clouds. Values are predicted normalized (``ValueNorm``): the critic used by
the loss outputs the normalized value, the one used by GAE the value in reward units.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import IndependentNormal, ProbabilisticActor

from trainer.config import ACTION_DIM, PPOConfig
from trainer.env import PROPRIO_DIM
from trainer.representations import representation_shape


class RunningNorm(nn.Module):
    """Running mean / variance of features of shape ``shape`` (batch dims are pooled), and
    ``(x - mean) / std`` clipped to ±``clip``. The statistics are buffers: they are saved in
    checkpoints and frozen unless ``update`` is called."""

    def __init__(self, shape: tuple[int, ...], clip: float = 5.0, eps: float = 1e-6) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape))
        self.register_buffer("var", torch.ones(shape))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.clip = clip
        self.eps = eps

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Merge the statistics of ``x`` (..., *shape) into the running ones (Chan et al.)."""
        x = x.reshape(-1, *self.mean.shape).to(self.mean.dtype)
        x = x[torch.isfinite(x).reshape(len(x), -1).all(-1)]
        n = x.shape[0]
        if n == 0:
            return
        mean, var = x.mean(0), x.var(0, unbiased=False)
        total = self.count + n
        delta = mean - self.mean
        # In place: TorchRL's loss modules hold references to these very tensors.
        self.var.copy_(
            self.var * (self.count / total).float()
            + var * (n / total).float()
            + delta**2 * (self.count * n / total**2).float()
        )
        self.mean += delta * (n / total).float()
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = (x - self.mean) / (self.var + self.eps).sqrt()
        return z.clamp(-self.clip, self.clip)

    def denormalize(self, z: torch.Tensor) -> torch.Tensor:
        return z * (self.var + self.eps).sqrt() + self.mean


class ObservationNorm(nn.Module):
    """Normalizers of ``proprio`` and ``object`` (shared by actor and critic). Point clouds are
    normalized per coordinate, pooled over points, so the encoder stays permutation-invariant."""

    def __init__(self, representation: str) -> None:
        super().__init__()
        shape = representation_shape(representation)
        self.is_cloud = len(shape) == 2
        self.proprio = RunningNorm((PROPRIO_DIM,))
        self.object = RunningNorm((3,) if self.is_cloud else shape)

    def update(self, proprio: torch.Tensor, obj: torch.Tensor) -> None:
        self.proprio.update(proprio)
        self.object.update(obj)

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # noqa: E501
        return self.proprio(proprio), self.object(obj)


def mlp(sizes: list[int], activation: type[nn.Module] = nn.ELU, last_activation: bool = True) -> nn.Sequential:  # noqa: E501
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if k < len(sizes) - 2 or last_activation:
            layers.append(activation())
    return nn.Sequential(*layers)


class Encoder(nn.Module):
    """Normalized observation -> feature vector: the object representation as it is, or for
    point clouds a shared per-point MLP followed by max pooling (PointNet-like)."""

    def __init__(self, representation: str, norm: ObservationNorm, cfg: PPOConfig) -> None:
        super().__init__()
        self.norm = norm
        shape = representation_shape(representation)
        if norm.is_cloud:
            self.points = mlp([3, *cfg.pointnet_hidden])
            self.out_dim = PROPRIO_DIM + cfg.pointnet_hidden[-1]
        else:
            self.points = None
            self.out_dim = PROPRIO_DIM + shape[0]

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> torch.Tensor:
        proprio, obj = self.norm(proprio, obj)
        if self.points is not None:
            obj = self.points(obj).amax(dim=-2)
        return torch.cat([proprio, obj], dim=-1)


class PolicyNet(nn.Module):
    """(proprio, object) -> (loc, scale) of a diagonal Gaussian over the 11-d action; the
    scale is state-independent (a learned log-std per action dimension)."""

    def __init__(self, representation: str, norm: ObservationNorm, cfg: PPOConfig) -> None:
        super().__init__()
        self.encoder = Encoder(representation, norm, cfg)
        self.body = mlp([self.encoder.out_dim, *cfg.hidden])
        self.loc = nn.Linear(cfg.hidden[-1], ACTION_DIM)
        if len(cfg.init_action_mean) != ACTION_DIM:
            raise ValueError(f"init_action_mean needs {ACTION_DIM} values")
        with torch.no_grad():
            self.loc.bias.copy_(torch.tensor(cfg.init_action_mean))
            self.loc.weight.mul_(0.01)  # start near the mean action whatever the observation
        self.log_std = nn.Parameter(torch.full((ACTION_DIM,), cfg.init_log_std))

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # noqa: E501
        loc = self.loc(self.body(self.encoder(proprio, obj)))
        scale = self.log_std.clamp(-5.0, 1.0).exp().expand_as(loc)
        return loc, scale


class ValueNet(nn.Module):
    """(proprio, object) -> normalized state value (E, 1)."""

    def __init__(self, representation: str, norm: ObservationNorm, cfg: PPOConfig) -> None:
        super().__init__()
        self.encoder = Encoder(representation, norm, cfg)
        self.body = mlp([self.encoder.out_dim, *cfg.hidden, 1], last_activation=False)

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> torch.Tensor:
        return self.body(self.encoder(proprio, obj))


class Denormalize(nn.Module):
    """A normalized-value network with its output mapped back to reward units."""

    def __init__(self, value_net: ValueNet, value_norm: RunningNorm) -> None:
        super().__init__()
        self.value_net = value_net
        self.value_norm = value_norm

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> torch.Tensor:
        return self.value_norm.denormalize(self.value_net(proprio, obj))


class Agent(nn.Module):
    """Everything PPO learns or tracks, in one state dict: networks and normalizers.

    ``actor``: TorchRL ProbabilisticActor writing ``action`` and its log-prob;
    ``critic``: normalized ``state_value`` (for the loss); ``critic_denorm``: ``state_value``
    in reward units (for GAE).
    """

    def __init__(self, representation: str, cfg: PPOConfig) -> None:
        super().__init__()
        self.obs_norm = ObservationNorm(representation)
        self.value_norm = RunningNorm((1,), clip=1e6)
        self.policy_net = PolicyNet(representation, self.obs_norm, cfg)
        self.value_net = ValueNet(representation, self.obs_norm, cfg)
        keys = ["proprio", "object"]
        self.actor = ProbabilisticActor(
            TensorDictModule(self.policy_net, in_keys=keys, out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"],
            distribution_class=IndependentNormal,
            return_log_prob=True,
        )
        self.critic = TensorDictModule(self.value_net, in_keys=keys, out_keys=["state_value"])
        self.critic_denorm = TensorDictModule(
            Denormalize(self.value_net, self.value_norm), in_keys=keys, out_keys=["state_value"]
        )
