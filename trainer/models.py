"""Policy and value networks: observation normalization, a PointNet-like encoder for point
clouds, 3-layer MLPs, and the TorchRL modules the PPO loop uses.

The networks are built from the env's observation spec (``trainer.tasks.observation_spec``):
``proprio`` (E, P), ``object`` (E, D) or (E, N, 3) for point clouds, and for the bin task with
context ``context`` (E, M, C) with ``context_mask`` (E, M) bool, read by a permutation-invariant
encoder (a shared per-object MLP, then a max over the objects the mask keeps). Values are
predicted normalized (``ValueNorm``): the critic used by the loss outputs the normalized value,
the one used by GAE the value in reward units.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import Composite
from torchrl.modules import IndependentNormal, ProbabilisticActor

from trainer.config import ACTION_DIM, PPOConfig

PoolMoments = Callable[[int, torch.Tensor, torch.Tensor], tuple[int, torch.Tensor, torch.Tensor]]
"""(n, mean, var) of a batch -> those of the batches of every process pooled (a distributed
run's all-reduce; ``trainer.training.distributed.pool_moments``)."""


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
    def update(self, x: torch.Tensor, pool: PoolMoments | None = None) -> None:
        """Merge the statistics of ``x`` (..., *shape) into the running ones (Chan et al.).
        ``pool``: pools this batch's moments with those of the other processes of a distributed
        run first (``trainer.training.distributed.pool_moments``), so that every process merges
        the same whole-run batch."""
        x = x.reshape(-1, *self.mean.shape).to(self.mean.dtype)
        x = x[torch.isfinite(x).reshape(len(x), -1).all(-1)]
        n = x.shape[0]
        if pool is None:
            if n == 0:
                return
            self.merge(n, x.mean(0), x.var(0, unbiased=False))
            return
        # Every process joins the pooling, even one with no finite sample.
        mean = x.mean(0) if n else torch.zeros_like(self.mean)
        var = x.var(0, unbiased=False) if n else torch.zeros_like(self.var)
        n, mean, var = pool(n, mean, var)
        if n > 0:
            self.merge(n, mean, var)

    @torch.no_grad()
    def merge(self, n: int, mean: torch.Tensor, var: torch.Tensor) -> None:
        """Merge a batch of ``n`` samples with mean ``mean`` and (biased) variance ``var``
        (each of ``shape``) into the running statistics."""
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


class ObservationShapes:
    """Per-env shapes of the observations the networks read, from an observation spec."""

    def __init__(self, spec: Composite) -> None:
        self.proprio = tuple(spec["proprio"].shape[1:])
        self.object = tuple(spec["object"].shape[1:])
        self.context = tuple(spec["context"].shape[1:]) if "context" in spec.keys() else None  # noqa: SIM118

    @property
    def keys(self) -> list[str]:
        """The observation keys the networks take, in argument order."""
        return ["proprio", "object"] + (["context", "context_mask"] if self.context else [])


class ObservationNorm(nn.Module):
    """Normalizers of ``proprio``, ``object`` and ``context`` (shared by actor and critic).
    Point clouds are normalized per coordinate, pooled over points, and context boxes per
    feature, pooled over the objects the mask keeps, so the encoders stay
    permutation-invariant."""

    def __init__(self, shapes: ObservationShapes) -> None:
        super().__init__()
        self.is_cloud = len(shapes.object) == 2
        self.proprio = RunningNorm(shapes.proprio)
        self.object = RunningNorm((3,) if self.is_cloud else shapes.object)
        self.context = RunningNorm(shapes.context[-1:]) if shapes.context else None

    def update(
        self, proprio: torch.Tensor, obj: torch.Tensor, context: torch.Tensor | None = None,
        context_mask: torch.Tensor | None = None, pool: PoolMoments | None = None,
    ) -> None:
        """Merge a rollout's observations into the statistics (``pool``: as
        ``RunningNorm.update``'s)."""
        self.proprio.update(proprio, pool)
        self.object.update(obj, pool)
        if self.context is not None and context is not None:
            self.context.update(context[context_mask], pool)

    def forward(self, proprio: torch.Tensor, obj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # noqa: E501
        return self.proprio(proprio), self.object(obj)


def mlp(sizes: list[int], activation: type[nn.Module] = nn.ELU, last_activation: bool = True) -> nn.Sequential:  # noqa: E501
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if k < len(sizes) - 2 or last_activation:
            layers.append(activation())
    return nn.Sequential(*layers)


POINTS_PER_CHUNK = 8192
"""Points the per-point MLP processes at a time (whole samples): its activations then stay in
the CPU's cache, about twice as fast as one pass over a 1,024-frame minibatch of pc128
(bench/pointnet_update.py)."""


def max_pooled_points(layers: nn.Sequential, points: torch.Tensor) -> torch.Tensor:
    """``layers`` (a per-point MLP ending in a linear layer) on every point of ``points``
    (B, N, 3), then the max over the points: (B, C), in value and gradient what
    ``layers(points).max(dim=-2).values`` computes, at a fraction of the cost.

    The max passes the gradient of each output channel to one point (its argmax). So where
    gradients are needed and there are more points than channels, the points are first run
    without autograd to find each channel's argmax, and only those points (B, C, 3) are run
    again with it, the last layer reduced to each channel's own row. Without gradients, or
    with fewer points than channels, it is the plain max. Either way in chunks of
    ``POINTS_PER_CHUNK`` points (rounding differs from one pass by float error only)."""
    batch, (n, dim) = points.shape[:-2], points.shape[-2:]
    flat = points.reshape(-1, n, dim)
    chunks = flat.split(max(1, POINTS_PER_CHUNK // n))
    last = layers[-1]
    if not (torch.is_grad_enabled() and n > last.out_features):
        pooled = torch.cat([layers(c).max(dim=-2).values for c in chunks])
    else:
        with torch.no_grad():
            argmax = torch.cat([layers(c).max(dim=-2).indices for c in chunks])
        chosen = torch.gather(flat, -2, argmax[..., None].expand(*argmax.shape, dim))
        pooled = (layers[:-1](chosen) * last.weight).sum(-1) + last.bias
    return pooled.reshape(*batch, -1)


class Encoder(nn.Module):
    """Normalized observation -> feature vector: the object representation as it is, or for
    point clouds a shared per-point MLP followed by max pooling (PointNet-like); the context
    boxes through a shared per-object MLP and a max over the kept objects (zeros if none)."""

    def __init__(self, shapes: ObservationShapes, norm: ObservationNorm, cfg: PPOConfig) -> None:
        super().__init__()
        self.norm = norm
        self.out_dim = shapes.proprio[0]
        if norm.is_cloud:
            # The last activation is applied after the max over points: ELU is increasing, so
            # ELU(max) == max(ELU) exactly, on P times fewer values. The state-dict keys are
            # those of the full per-point MLP, so checkpoints of either form load.
            self.points = mlp([3, *cfg.pointnet_hidden], last_activation=False)
            self.points_activation = nn.ELU()
            self.out_dim += cfg.pointnet_hidden[-1]
        else:
            self.points = None
            self.out_dim += shapes.object[0]
        self.context = None
        if shapes.context:
            self.context = mlp([shapes.context[-1], *cfg.context_hidden])
            self.out_dim += cfg.context_hidden[-1]

    def forward(
        self, proprio: torch.Tensor, obj: torch.Tensor, context: torch.Tensor | None = None,
        context_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        proprio, obj = self.norm(proprio, obj)
        if self.points is not None:
            obj = self.points_activation(max_pooled_points(self.points, obj))
        parts = [proprio, obj]
        if self.context is not None:
            features = self.context(self.norm.context(context))
            keep = context_mask[..., None]
            pooled = features.masked_fill(~keep, float("-inf")).amax(dim=-2)
            parts.append(torch.where(keep.any(dim=-2), pooled, torch.zeros_like(pooled)))
        return torch.cat(parts, dim=-1)


LOG_STD_BOUNDS = (-5.0, 1.0)
"""The policy's log-std is clamped to these (std 0.0067 to 2.7)."""


class PolicyNet(nn.Module):
    """(proprio, object) -> (loc, scale) of a diagonal Gaussian over the 11-d action. The
    scale is a learned log-std per action dimension, state-independent by default; with
    ``[ppo] state_dependent_std`` a linear head on the body's features adds to it, so the
    policy can explore less where noise costs (holding a grasp) and more elsewhere."""

    def __init__(self, shapes: ObservationShapes, norm: ObservationNorm, cfg: PPOConfig) -> None:
        super().__init__()
        self.encoder = Encoder(shapes, norm, cfg)
        self.body = mlp([self.encoder.out_dim, *cfg.hidden])
        self.loc = nn.Linear(cfg.hidden[-1], ACTION_DIM)
        if len(cfg.init_action_mean) != ACTION_DIM:
            raise ValueError(f"init_action_mean needs {ACTION_DIM} values")
        with torch.no_grad():
            self.loc.bias.copy_(torch.tensor(cfg.init_action_mean))
            self.loc.weight.mul_(0.01)  # start near the mean action whatever the observation
        log_std = torch.as_tensor(cfg.init_log_std, dtype=torch.float32)
        self.log_std = nn.Parameter(log_std.expand(ACTION_DIM).clone())
        self.log_std_head: nn.Linear | None = None
        if cfg.state_dependent_std:
            # Zero weights: the untrained policy explores exactly as the state-independent one.
            self.log_std_head = nn.Linear(cfg.hidden[-1], ACTION_DIM, bias=False)
            nn.init.zeros_(self.log_std_head.weight)

    def forward(self, *obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.head(self.encoder(*obs))

    def head(self, encoded: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The layers after the encoder: encoded observation -> (loc, scale)."""
        features = self.body(encoded)
        loc = self.loc(features)
        log_std = self.log_std
        if self.log_std_head is not None:
            # The std reads the features the mean learned but does not shape them (detached,
            # as gSDE's default): the score of log-std is noisier than that of the mean.
            log_std = log_std + self.log_std_head(features.detach())
        scale = log_std.clamp(*LOG_STD_BOUNDS).exp().expand_as(loc)
        return loc, scale

    def mean_std(self, rollout_scale: torch.Tensor) -> float:
        """The action std to report for an iteration: the learned one (state-independent), or
        the mean over the rollout's states of the std it was collected with."""
        if self.log_std_head is None:
            return float(self.log_std.detach().clamp(*LOG_STD_BOUNDS).exp().mean())
        return float(rollout_scale.mean())


class ValueNet(nn.Module):
    """(proprio, object) -> normalized state value (E, 1); with ``encoder`` given, it uses that
    one (the policy's, ``[ppo] shared_encoder``) instead of its own."""

    def __init__(
        self, shapes: ObservationShapes, norm: ObservationNorm, cfg: PPOConfig,
        encoder: Encoder | None = None,
    ) -> None:
        super().__init__()
        self.encoder = encoder if encoder is not None else Encoder(shapes, norm, cfg)
        self.body = mlp([self.encoder.out_dim, *cfg.hidden, 1], last_activation=False)

    def forward(self, *obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(*obs))

    def head(self, encoded: torch.Tensor) -> torch.Tensor:
        """The layers after the encoder: encoded observation -> normalized value."""
        return self.body(encoded)


class Head(nn.Module):
    """A network's layers after its encoder (``net.head``) as a module of the encoded
    observation, for the shared encoder's wiring in ``Agent``."""

    def __init__(self, net: PolicyNet | ValueNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, encoded: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        return self.net.head(encoded)


class Denormalize(nn.Module):
    """A normalized-value network with its output mapped back to reward units."""

    def __init__(self, value_net: ValueNet | Head, value_norm: RunningNorm) -> None:
        super().__init__()
        self.value_net = value_net
        self.value_norm = value_norm

    def forward(self, *obs: torch.Tensor) -> torch.Tensor:
        return self.value_norm.denormalize(self.value_net(*obs))


class Agent(nn.Module):
    """Everything PPO learns or tracks, in one state dict: networks and normalizers.

    ``actor``: TorchRL ProbabilisticActor writing ``action`` and its log-prob;
    ``critic``: normalized ``state_value`` (for the loss); ``critic_denorm``: ``state_value``
    in reward units (for GAE). ``observation_spec``: the env's (``trainer.tasks.observation_spec``).

    With ``[ppo] shared_encoder`` the value network uses the policy's encoder; the actor writes
    the encoded observation (``ENCODED``) and ``critic`` is the value head reading it, so the
    loss, which runs the actor first, encodes each minibatch once (TorchRL's documented pattern
    for an actor and critic sharing a module).
    """

    ENCODED = "encoded_observation"

    def __init__(self, observation_spec: Composite, cfg: PPOConfig) -> None:
        super().__init__()
        shapes = ObservationShapes(observation_spec)
        self.obs_keys = shapes.keys
        self.obs_norm = ObservationNorm(shapes)
        self.value_norm = RunningNorm((1,), clip=1e6)
        self.policy_net = PolicyNet(shapes, self.obs_norm, cfg)
        shared = self.policy_net.encoder if cfg.shared_encoder else None
        self.shared_encoder = cfg.shared_encoder
        self.value_net = ValueNet(shapes, self.obs_norm, cfg, encoder=shared)
        keys = self.obs_keys
        if shared is None:
            policy: TensorDictModule | TensorDictSequential = TensorDictModule(
                self.policy_net, in_keys=keys, out_keys=["loc", "scale"])
            self.critic = TensorDictModule(self.value_net, in_keys=keys, out_keys=["state_value"])
            self.critic_denorm = TensorDictModule(
                Denormalize(self.value_net, self.value_norm), in_keys=keys,
                out_keys=["state_value"],
            )
        else:
            encode = TensorDictModule(shared, in_keys=keys, out_keys=[self.ENCODED])
            policy = TensorDictSequential(encode, TensorDictModule(
                Head(self.policy_net), in_keys=[self.ENCODED], out_keys=["loc", "scale"]))
            self.critic = TensorDictModule(
                Head(self.value_net), in_keys=[self.ENCODED], out_keys=["state_value"])
            self.critic_denorm = TensorDictSequential(encode, TensorDictModule(
                Denormalize(Head(self.value_net), self.value_norm), in_keys=[self.ENCODED],
                out_keys=["state_value"]))
        self.actor = ProbabilisticActor(
            policy, in_keys=["loc", "scale"], distribution_class=IndependentNormal,
            return_log_prob=True,
        )

    @torch.no_grad()
    def state_values(self, data: TensorDictBase) -> torch.Tensor:
        """State values in reward units (*B, 1) of ``data``'s observations (batch shape B). With
        ``[ppo] shared_encoder``, ``data``'s encoded observations (``ENCODED``) where it holds
        them: the policy wrote them as it collected, with these weights and normalizer
        statistics, so the value head reads them instead of encoding every point again."""
        if self.shared_encoder and self.ENCODED in data.keys():  # noqa: SIM118 (a TensorDict)
            return self.value_norm.denormalize(self.value_net.head(data[self.ENCODED]))
        return self.critic_denorm(data.select(*self.obs_keys))["state_value"]

    @torch.no_grad()
    def silence_unseen_features(self) -> int:
        """Zero the first-layer weights of every normalized observation feature this agent never
        saw vary (running variance 0 after some updates; for one object trained alone: its
        bbox's or superquadric's size and shape). Such a feature always reached the networks as
        0, so its weights never trained; on other objects its new value, clipped to ±5, would
        pass through those random initial weights and perturb every first-layer unit (the plate
        from a tuna can agent: its extents at +5, +5, -5). Zeroed, the agent computes exactly
        what it computed on its own observations, and the weights train from 0 where the value
        varies or differs from 0. Returns how many features were silenced."""
        norm = self.obs_norm

        def unseen(part: RunningNorm) -> torch.Tensor:
            return ((part.var == 0) & (part.count > 0)).flatten().nonzero().flatten()

        proprio, obj = unseen(norm.proprio), unseen(norm.object)
        context = unseen(norm.context) if norm.context is not None else proprio[:0]
        for net in (self.policy_net, self.value_net):  # (they share the normalizers)
            enc, first = net.encoder, net.body[0]
            first.weight[:, proprio] = 0.0
            if enc.points is not None:
                enc.points[0].weight[:, obj] = 0.0
            else:
                first.weight[:, norm.proprio.mean.numel() + obj] = 0.0
            if enc.context is not None:
                enc.context[0].weight[:, context] = 0.0
        return len(proprio) + len(obj) + len(context)
