"""Policy heads on top of the scene representation r: a tanh-Gaussian actor and twin Q critics.

Each output is a conv block (3x3 kernels, 128/64/32 channels, ReLU) then one fully connected layer
(paper, Method B). The critic sees the action tiled over r's 16x16 grid and concatenated to r's channels,
so that Q is a nonlinear function of the action. The input "r" of a head may carry more channels than the
representation (the proprioception tiled beside it: ``APRAgent._head_input``).

The heads always compute in fp32, also under bf16 autocast: Q must resolve per-step rewards of a few
hundredths, which bf16's 8-bit mantissa cannot (about 0.004 at Q ~ 1).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

from apr.model.encoder import tile


def conv_block(in_channels: int, channels: tuple[int, ...]) -> nn.Sequential:
    """3x3 convolutions (padding 1, stride 1), ReLU after each (paper, Method B)."""
    layers: list[nn.Module] = []
    for out_channels in channels:
        layers += [nn.Conv2d(in_channels, out_channels, kernel_size=3, padding=1), nn.ReLU()]
        in_channels = out_channels
    return nn.Sequential(*layers, nn.Flatten())


class SpatialSoftArgmax(nn.Module):
    """Keypoints of feature maps (Levine et al. 2016, "End-to-End Training of Deep Visuomotor Policies"; Finn et al.
    2016, "Deep Spatial Autoencoders"): per channel, the expected position of a softmax over its cells.

    (B, C, H, W) -> (B, 2C): each channel's expected x (column) then y (row), in [-1, 1] from the first cell to the
    last. The softmax temperature is learned (it starts at 1).
    """

    def __init__(self) -> None:
        super().__init__()
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        height, width = features.shape[-2:]
        weights = torch.softmax(features.flatten(2) / self.log_temperature.exp(), dim=-1).unflatten(-1, (height, width))
        rows = torch.linspace(-1.0, 1.0, height, device=features.device, dtype=weights.dtype)
        columns = torch.linspace(-1.0, 1.0, width, device=features.device, dtype=weights.dtype)
        x = (weights.sum(dim=2) * columns).sum(-1)  # (B, C): the column marginal's mean
        y = (weights.sum(dim=3) * rows).sum(-1)  # the row marginal's mean
        return torch.stack([x, y], dim=-1).flatten(1)


class Actor(nn.Module):
    """pi(a | r): conv block + linear -> mean and log-std of a Gaussian, squashed by tanh into [-1, 1]^A."""

    def __init__(
        self,
        representation_channels: int,
        action_dim: int,
        channels: tuple[int, ...] = (128, 64, 32),
        grid: int = 16,
        log_std_bounds: tuple[float, float] = (-20.0, 2.0),
    ) -> None:
        super().__init__()
        self.trunk = conv_block(representation_channels, channels)
        self.out = nn.Linear(channels[-1] * grid * grid, 2 * action_dim)
        self.log_std_min, self.log_std_max = log_std_bounds

    def forward(self, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """r: (B, R, 16, 16). Returns the pre-tanh mean and log-std, each (B, A), fp32."""
        with torch.autocast(r.device.type, enabled=False):
            mean, log_std = self.out(self.trunk(r.float())).chunk(2, dim=-1)
        return mean, log_std.clamp(self.log_std_min, self.log_std_max)

    def sample(self, r: torch.Tensor, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample and its log-probability: action (B, A) in (-1, 1), log_prob (B,)."""
        mean, log_std = self(r)
        noise = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        pre_tanh = mean + log_std.exp() * noise
        gaussian_log_prob = (-0.5 * noise**2 - log_std - 0.5 * math.log(2 * math.pi)).sum(dim=-1)
        # log|d tanh(u)/du| = log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), the stable form.
        log_det = (2 * (math.log(2) - pre_tanh - F.softplus(-2 * pre_tanh))).sum(dim=-1)
        return torch.tanh(pre_tanh), gaussian_log_prob - log_det

    def mode(self, r: torch.Tensor) -> torch.Tensor:
        """The deterministic action tanh(mean), (B, A), used for evaluation."""
        return torch.tanh(self(r)[0])


class Critic(nn.Module):
    """Q(r, a): the action tiled over the grid and concatenated to r, conv block + linear -> (B,)."""

    def __init__(
        self,
        representation_channels: int,
        action_dim: int,
        channels: tuple[int, ...] = (128, 64, 32),
        grid: int = 16,
    ) -> None:
        super().__init__()
        self.trunk = conv_block(representation_channels + action_dim, channels)
        self.out = nn.Linear(channels[-1] * grid * grid, 1)

    def forward(self, r: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """r: (B, R, 16, 16); action: (B, A), or (B, K, A) for K actions per scene. Returns Q: (B,) or (B, K),
        fp32. Each action is a pass of the conv block."""
        if action.dim() == 3:
            many = action.shape[1]
            return self(r.repeat_interleave(many, dim=0), action.flatten(0, 1)).view(-1, many)
        with torch.autocast(r.device.type, enabled=False):
            x = torch.cat([r.float(), tile(action.float(), r.shape[-1])], dim=1)
            return self.out(self.trunk(x)).squeeze(-1)


class MapCritic(nn.Module):
    """Q(r, a) read from a map over the action's first two coordinates (ours, for the fixation bandit).

    The conv block and one linear layer give a value at each point of a ``map_grid`` x ``map_grid`` lattice over
    [-1, 1]^2 (the fixation box's x and y); Q is that map bilinearly interpolated at the action's x and y, plus a
    small function of the action's other coordinates (z). The tiled critic must compare an action it sees as a
    constant over r's grid with where things are in r, which a conv block does poorly (Liu et al. 2018, "An
    Intriguing Failing of Convolutional Neural Networks and the CoordConv Solution"); this one reads a value per
    place, as the probe's ``object_map`` readout does (docs/decisions.md, "The fixation critic").
    """

    def __init__(
        self,
        representation_channels: int,
        action_dim: int,
        channels: tuple[int, ...] = (128, 64, 32),
        grid: int = 16,
        map_grid: int = 12,
    ) -> None:
        super().__init__()
        if action_dim < 2:
            raise ValueError("a map critic needs an action of at least 2 coordinates (x, y)")
        self.map_grid = map_grid
        self.trunk = conv_block(representation_channels, channels)
        self.out = nn.Linear(channels[-1] * grid * grid, map_grid * map_grid)
        rest = action_dim - 2
        self.rest = nn.Sequential(nn.Linear(rest, 16), nn.ReLU(), nn.Linear(16, 1)) if rest else None

    def value_map(self, r: torch.Tensor) -> torch.Tensor:
        """r: (B, R, 16, 16) -> the map (B, G, G), fp32; [b, i, j] is the value at x = lattice[i], y = lattice[j]."""
        with torch.autocast(r.device.type, enabled=False):
            return self.out(self.trunk(r.float())).view(-1, self.map_grid, self.map_grid)

    def forward(self, r: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """r: (B, R, 16, 16); action: (B, A), or (B, K, A) for K actions per scene. Returns Q: (B,) or (B, K),
        fp32. The map is computed once per scene, however many actions read it."""
        many = action.dim() == 3
        action = (action if many else action[:, None]).float()  # (B, K, A)
        # grid_sample's point is (column, row) = (y, x) for a map indexed [x, y]
        where = action[:, None, :, [1, 0]]  # (B, 1, K, 2)
        q = F.grid_sample(self.value_map(r)[:, None], where, align_corners=True)[:, 0, 0]  # (B, K)
        if self.rest is not None:
            with torch.autocast(r.device.type, enabled=False):
                q = q + self.rest(action[..., 2:]).squeeze(-1)
        return q if many else q[:, 0]


class TwinCritic(nn.Module):
    """Two independent Q networks (clipped double Q, Fujimoto et al. 2018; Haarnoja et al. 2018b)."""

    def __init__(self, *args: object, kind: Literal["tiled", "map"] = "tiled", **kwargs: object) -> None:
        super().__init__()
        critic = {"tiled": Critic, "map": MapCritic}[kind]
        self.q1 = critic(*args, **kwargs)  # type: ignore[arg-type]
        self.q2 = critic(*args, **kwargs)  # type: ignore[arg-type]

    def forward(self, r: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Both Q estimates, (B,) each for actions (B, A), (B, K) each for (B, K, A)."""
        return self.q1(r, action), self.q2(r, action)

    def best_xy(self, r: torch.Tensor) -> torch.Tensor:
        """Map critics only: the critics' best x, y per sample, (B, 2) in [-1, 1]: the lattice point of the highest
        value of min(Q1, Q2), refined within its cell (:func:`refined_peak`). The lattice is 3.4 x 3.6 cm at 12
        points a side; the interpolated Q itself peaks at a lattice point, so the lattice alone rounds every look to
        it."""
        if not isinstance(self.q1, MapCritic):
            raise TypeError("only a map critic has a best point")
        values = torch.minimum(self.q1.value_map(r), self.q2.value_map(r))  # (B, G, G)
        return refined_peak(values) * (2.0 / (self.q1.map_grid - 1)) - 1.0


def refined_peak(values: torch.Tensor) -> torch.Tensor:
    """The peak of each map (B, G, G), (B, 2) in lattice units (row, column; fractional): the lattice point of the
    highest value, moved within its cell to the peak of a parabola through it and its two neighbours along each axis
    (sub-pixel peak refinement, as heatmap keypoint detectors read a place finer than their grid). At the map's
    edge, or where the values do not curve down along an axis, the lattice coordinate is kept."""
    size = values.shape[-1]
    best = values.flatten(1).argmax(dim=1)
    row, column = best // size, best % size
    samples = torch.arange(len(values), device=values.device)

    def offset(index: torch.Tensor, value_at: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
        """The parabola's peak, in cells from ``index``, along one axis (0 at the edge or without a peak)."""
        inside = (index > 0) & (index < size - 1)
        before, here, after = (value_at((index + step).clamp(0, size - 1)) for step in (-1, 0, 1))
        curvature = before - 2 * here + after
        peak = 0.5 * (before - after) / torch.where(curvature < 0, curvature, -torch.ones_like(curvature))
        return torch.where(inside & (curvature < 0), peak.clamp(-0.5, 0.5), torch.zeros_like(peak))

    row_offset = offset(row, lambda index: values[samples, index, column])
    column_offset = offset(column, lambda index: values[samples, row, index])
    return torch.stack([row + row_offset, column + column_offset], dim=-1)


class PolicyHeads(nn.Module):
    """Everything one SAC policy owns: actor, twin critics, their target copies and the temperature. ``critic``:
    "tiled" (:class:`Critic`) or "map" (:class:`MapCritic`)."""

    def __init__(
        self,
        representation_channels: int,
        action_dim: int,
        channels: tuple[int, ...] = (128, 64, 32),
        grid: int = 16,
        log_std_bounds: tuple[float, float] = (-20.0, 2.0),
        init_temperature: float = 1.0,
        target_critic: bool = True,
        critic: Literal["tiled", "map"] = "tiled",
    ) -> None:
        super().__init__()
        self.action_dim = action_dim
        self.actor = Actor(representation_channels, action_dim, channels, grid, log_std_bounds)
        self.critic = TwinCritic(representation_channels, action_dim, channels, grid, kind=critic)
        # Only a bootstrapping critic needs a target copy; the fixation bandit regresses its reward.
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False) if target_critic else None
        self.log_alpha = nn.Parameter(torch.tensor(math.log(init_temperature)))

    def mode(self, r: torch.Tensor) -> torch.Tensor:
        """The deterministic action (B, A) used for evaluation: the actor's tanh(mean); with a map critic, x and y
        from the critics' best point instead (the actor's other coordinates kept)."""
        action = self.actor.mode(r)
        if isinstance(self.critic.q1, MapCritic):
            action[:, :2] = self.critic.best_xy(r)
        return action

    @property
    def target_entropy(self) -> float:
        """-dim(A) (Haarnoja et al. 2018b)."""
        return -float(self.action_dim)

    def rl_parameters(self) -> dict[str, list[nn.Parameter]]:
        """Trainable parameters by optimiser: actor, critic, temperature (the targets are not trained)."""
        return {
            "actor": list(self.actor.parameters()),
            "critic": list(self.critic.parameters()),
            "temperature": [self.log_alpha],
        }
