"""The APR learner: encoder + generator + grasp and fixation SAC heads, updated jointly from one stream.

One update (``APRAgent.update``):
  1. per sample, two of the step's three views are the context (r = r1 + r2), the third is the query;
  2. the ELBO of the generator on the query view trains the encoder and generator (paper, Method C);
  3. the grasp SAC losses and the fixation bandit SAC losses see r detached (stop-gradient), unless the
     "w/o representation" ablation (``representation=False``) or ``critic_trains_encoder`` lets the critic losses
     train the encoder;
  4. all losses are computed from the same parameters, summed, back-propagated once; every optimiser
     steps (the parameter sets are disjoint) and the grasp target critics are Polyak-averaged.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from apr.envs.config import GRASP, REWARD
from apr.model.config import ModelConfig, gqn_learning_rate, pixel_sigma
from apr.model.encoder import TowerEncoder, encode_scene, images_to_float, tile
from apr.model.generator import ConvDRAWGenerator, gqn_elbo_loss
from apr.model.heads import PolicyHeads
from apr.model.sac import (
    Metrics,
    bandit_critic_loss,
    sac_actor_loss,
    sac_critic_loss,
    soft_update,
    temperature_loss,
)

Policy = Literal["grasp", "fixation"]
FIXATION_REWARDS = {
    "grasp": "the paper's: 1 when an object was lifted and the tool tip started the grasp within 10 cm of the point "
             "(Method A); with relabelled points, that reward of each (hindsight relabelling)",
    "tip-proximity": "ours, the robot's knowledge only: when an object was lifted, 1 - d / 10 cm, d from the point to "
                     "the tool tip when the grasp started (0 beyond 10 cm, or without a lift)",
    "proximity": "shaping from the simulator (a flag, never a Table 1 row): 1 - d / R, d from the point to the "
                 "nearest object centre as the simulator reports it",
}  # fmt: skip
"""What the fixation bandit can regress (``ModelConfig.fixation_reward``)."""
NUM_VIEWS = 3  # views rendered per step around the fixation point (paper, Method C)
PROPRIOCEPTION_ORIGIN = (0.55, 0.0, 0.0)
"""m: the middle of the drop area in x and y, between the tray floor and the gripper's start in z."""
PROPRIOCEPTION_SCALE = 0.1
"""m: the unit of the positions the heads see (the tool tip and the fixation point vary by ~0.1 m)."""


def _as_tensor(
    value: np.ndarray | torch.Tensor, device: torch.device, dtype: torch.dtype | None = None
) -> torch.Tensor:
    tensor = value if isinstance(value, torch.Tensor) else torch.from_numpy(np.asarray(value))
    return tensor.to(device=device, dtype=dtype, non_blocking=True)


@dataclass
class Observation:
    """A batch of env observations, as the environment returns them (images stay uint8 until used)."""

    images: torch.Tensor
    """uint8 (B, 3, 64, 64, C): the step's three views, HWC."""
    viewpoints: torch.Tensor
    """float32 (B, 3, 6): each view's head joint angles v."""
    gripper: torch.Tensor
    """float32 (B, 9): the gripper pose g, shared by the three views."""
    fixation: torch.Tensor | None = None
    """float32 (B, 3): the point the head fixates (m), where the observation has it (a learned fixation's
    chosen point; the revealed target of the privileged preset); None otherwise."""
    steps_left: torch.Tensor | None = None
    """float32 (B,): the grasp steps the episode has left (15 to 0), where the observation has them (v1); None
    otherwise."""

    @classmethod
    def from_env(cls, obs: Mapping[str, Any], device: torch.device | str = "cpu") -> Observation:
        """From a (vector-)env observation dict of arrays; an unbatched observation gets a batch axis."""
        device = torch.device(device)
        images = _as_tensor(obs["images"], device)
        viewpoints = _as_tensor(obs["viewpoints"], device, torch.float32)
        gripper = _as_tensor(obs["gripper"], device, torch.float32)
        fixation = _as_tensor(obs["fixation"], device, torch.float32) if "fixation" in obs else None
        steps_left = _as_tensor(obs["steps_left"], device, torch.float32) if "steps_left" in obs else None
        if images.ndim == 4:
            images, viewpoints, gripper = images[None], viewpoints[None], gripper[None]
            fixation = None if fixation is None else fixation[None]
            steps_left = None if steps_left is None else steps_left.reshape(1)
        return cls(images, viewpoints, gripper, fixation, steps_left)

    def __len__(self) -> int:
        return self.images.shape[0]

    def __getitem__(self, index: slice | torch.Tensor) -> Observation:
        return Observation(*(None if value is None else value[index] for value in self._fields()))

    def to(self, device: torch.device | str) -> Observation:
        return Observation(*(None if value is None else value.to(device) for value in self._fields()))

    def _fields(self) -> tuple[torch.Tensor | None, ...]:
        return self.images, self.viewpoints, self.gripper, self.fixation, self.steps_left

    def poses(self) -> torch.Tensor:
        """(B, 3, 15): each view's (v, g), the proprioceptive input of the encoder and the generator."""
        gripper = self.gripper[:, None, :].expand(-1, self.viewpoints.shape[1], -1)
        return torch.cat([self.viewpoints, gripper], dim=-1)

    def proprioception(self, gripper: bool, fixation: bool, steps_left: bool = False) -> torch.Tensor:
        """(B, 9 * gripper + 6 * fixation + steps_left): g, then the fixation point f and f - tip, then the steps
        left as a fraction of the limit: what the policy heads see beside r (``ModelConfig.heads_see_proprioception``,
        ``heads_see_fixation``, ``heads_see_steps_left``). Positions are in units of
        ``PROPRIOCEPTION_SCALE`` from ``PROPRIOCEPTION_ORIGIN`` (the tool tip is g's first three entries), so that
        every entry varies by about 1, as r's channels do; in metres they would vary by ~0.1 and the heads would
        barely feel them."""
        origin = torch.tensor(PROPRIOCEPTION_ORIGIN, device=self.gripper.device)
        tip, angles = self.gripper[:, :3], self.gripper[:, 3:]
        scale = PROPRIOCEPTION_SCALE
        parts = [(tip - origin) / scale, angles] if gripper else []
        if fixation:
            if self.fixation is None:
                raise ValueError("the heads see the fixation point, but the observation has none (only a learned "
                                 "fixation or reveal_target=True put it there)")  # fmt: skip
            parts += [(self.fixation - origin) / scale, (self.fixation - tip) / scale]
        if steps_left:
            if self.steps_left is None:
                raise ValueError("the heads see the steps left, but the observation has none (only the environments' "
                                 "v1, whose 15-step limit is part of the task, put them there)")  # fmt: skip
            parts.append(self.steps_left[:, None] / GRASP.max_grasp_steps)
        return torch.cat(parts, dim=-1)


@dataclass
class GraspBatch:
    """Grasp transitions sampled from replay."""

    obs: Observation
    action: torch.Tensor
    """(B, A) in [-1, 1]."""
    reward: torch.Tensor
    """(B,): sparse grasp reward + auxiliary reach reward."""
    next_obs: Observation
    """The observation after the action (for a truncated episode, its final observation)."""
    terminated: torch.Tensor
    """(B,) bool/float: 1 when the episode ended (no bootstrap): by a grasp attempt or, in v1, at the 15-step limit,
    which is part of the task; 0 otherwise, and at v0's truncation, which bootstraps."""
    steps: torch.Tensor | None = None
    """(B,) environment steps from obs to next_obs (``ModelConfig.n_step``); None: one for every transition."""


@dataclass
class FixationBatch:
    """Fixation samples (a one-step contextual bandit): bin-centre observation, chosen point, reward."""

    obs: Observation
    action: torch.Tensor
    """(B, 3) in [-1, 1]."""
    reward: torch.Tensor
    """(B,): the episode's sparse grasp reward."""
    lifted: torch.Tensor | None = None
    """(B,) 0/1: an object was lifted by the episode's grasp (what the grasp reward reads)."""
    grasp_tip: torch.Tensor | None = None
    """(B, 3): the tool tip when the grasp started (m; NaN where no grasp was attempted), the robot's own pose. With
    ``lifted`` it gives the grasp reward that any other fixation point would have earned (hindsight relabelling)."""
    object_centres: torch.Tensor | None = None
    """(B, N, 3): the objects' centres when the point was chosen (m; NaN rows pad scenes with fewer objects),
    from the simulator: what the proximity reward (shaping from the simulator, a flag) is computed from, never a
    policy input."""


def fixation_points(action: torch.Tensor) -> torch.Tensor:
    """Fixation actions in [-1, 1]^3 (..., 3) -> points (m) of the workspace box, as the environment maps them
    (:meth:`apr.envs.task.GraspTask.fixation_from_action`)."""
    low = torch.tensor(REWARD.workspace_low, device=action.device, dtype=action.dtype)
    high = torch.tensor(REWARD.workspace_high, device=action.device, dtype=action.dtype)
    return low + 0.5 * (action + 1.0) * (high - low)


def proximity_reward(action: torch.Tensor, object_centres: torch.Tensor, radius: float) -> torch.Tensor:
    """``1 - min(d, radius) / radius``, d the distance from each action's point to the nearest object centre.

    Args:
        action: (B, K, 3) fixation actions in [-1, 1]; object_centres: (B, N, 3), NaN rows for no object.

    Returns:
        (B, K) in [0, 1]; 0 in a scene without objects.
    """
    offsets = fixation_points(action)[:, :, None, :] - object_centres[:, None, :, :]  # (B, K, N, 3)
    distance = offsets.norm(dim=-1).nan_to_num(nan=float("inf")).amin(dim=-1)  # (B, K)
    return 1.0 - distance.clamp(max=radius) / radius


def hindsight_grasp_reward(action: torch.Tensor, lifted: torch.Tensor, grasp_tip: torch.Tensor, radius: float,
                           profile: Literal["ball", "cone"] = "ball") -> torch.Tensor:  # fmt: skip
    """The grasp reward each fixation action would have earned in an episode that ended as this one did.

    The paper's reward of a learned fixation is 1 when an object was lifted and the tool tip was within
    ``radius`` (10 cm) of the fixation point when the grasp started (Method A): a function of what the robot knows
    (whether something was lifted, where its own tool tip was), so it is exact for any other point too (hindsight
    relabelling, Andrychowicz et al. 2017). ``profile="ball"`` is that reward; ``"cone"`` (ours) falls from 1 at the
    tool tip to 0 at ``radius``, so that the points nearest the grasp earn most.

    Args:
        action: (B, K, 3) fixation actions in [-1, 1]; lifted: (B,) 0/1; grasp_tip: (B, 3), NaN without an attempt.

    Returns:
        (B, K) in [0, 1]; 0 wherever nothing was lifted or no grasp was attempted.
    """
    distance = (fixation_points(action) - grasp_tip[:, None, :]).norm(dim=-1)  # (B, K), NaN without an attempt
    near = (distance <= radius).to(action.dtype) if profile == "ball" else 1.0 - distance.clamp(max=radius) / radius
    return (lifted[:, None] > 0).to(action.dtype) * near.nan_to_num(nan=0.0)


def resolve_device(name: str) -> torch.device:
    """Device name, with "auto" meaning cuda when available, else cpu."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class APRAgent:
    """The joint learner: acts with the grasp or fixation policy and updates everything in one step."""

    def __init__(self, config: ModelConfig) -> None:
        self.config = config
        self.device = resolve_device(config.device)
        precision = config.precision
        if precision == "auto":
            precision = "bf16" if self.device.type == "cuda" else "fp32"
        self.autocast_dtype = torch.bfloat16 if precision == "bf16" else None

        with torch.random.fork_rng(devices=[]):  # seeded initialisation without touching global RNG
            torch.manual_seed(config.seed)
            self.encoder = TowerEncoder(
                config.image_channels,
                config.pose_dim,
                config.encoder_channels,
                config.encoder_narrow_channels,
                config.representation_channels,
                config.encoder_init,
            )
            self.generator = (
                ConvDRAWGenerator(
                    config.image_channels,
                    config.pose_dim,
                    config.representation_channels,
                    config.lstm_channels,
                    config.latent_channels,
                    config.canvas_channels,
                    config.generation_steps,
                    config.lstm_kernel,
                )
                if config.representation
                else None
            )
            grid = config.image_size // 4
            head_inputs = config.representation_channels + config.head_proprioception_dim
            head_args = dict(
                channels=tuple(config.head_channels),
                grid=grid,
                log_std_bounds=(config.log_std_min, config.log_std_max),
                init_temperature=config.init_temperature,
            )
            self.grasp = PolicyHeads(head_inputs, config.grasp_action_dim, **head_args)
            fixation_temperature = config.fixation_init_temperature or config.init_temperature
            fixation_args = dict(head_args, init_temperature=fixation_temperature)
            self.fixation = PolicyHeads(head_inputs, config.fixation_action_dim, target_critic=False,
                                        critic=config.fixation_critic, **fixation_args)  # fmt: skip
        self.networks = nn.ModuleDict({"encoder": self.encoder, "grasp": self.grasp, "fixation": self.fixation})
        if self.generator is not None:
            self.networks["generator"] = self.generator
        self.networks.to(self.device)
        if config.channels_last:
            self.networks.to(memory_format=torch.channels_last)
        self._encoder: nn.Module = torch.compile(self.encoder) if config.compile else self.encoder
        self._generator: nn.Module | None = (
            torch.compile(self.generator) if config.compile and self.generator is not None else self.generator
        )

        adam = dict(lr=config.sac_lr)
        critic_params = list(self.grasp.critic.parameters()) + list(self.fixation.critic.parameters())
        if not config.representation:  # the ablation: the critic losses train the encoder
            critic_params += list(self.encoder.parameters())
        self.optimizers: dict[str, torch.optim.Optimizer] = {
            "critic": torch.optim.Adam(critic_params, **adam),
            "actor": torch.optim.Adam([*self.grasp.actor.parameters(), *self.fixation.actor.parameters()], **adam),
            "temperature": torch.optim.Adam([self.grasp.log_alpha, self.fixation.log_alpha], **adam),
        }
        if self.generator is not None:
            gqn_params = [*self.encoder.parameters(), *self.generator.parameters()]
            self.optimizers["gqn"] = torch.optim.Adam(gqn_params, lr=config.gqn_lr_start)

        self.rng = torch.Generator(self.device).manual_seed(config.seed)  # learner draws
        self.act_rng = torch.Generator(self.device).manual_seed(config.seed + 1)  # acting draws

    # ------------------------------------------------------------------ helpers
    def _autocast(self) -> AbstractContextManager[Any]:
        if self.autocast_dtype is None:
            return nullcontext()
        return torch.autocast(self.device.type, dtype=self.autocast_dtype)

    def _views(self, obs: Observation, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Gather views per sample: index (B, K) -> images (B, K, C, 64, 64) in [0, 1], poses (B, K, P)."""
        rows = torch.arange(len(obs), device=self.device)[:, None]
        images = images_to_float(obs.images[rows, index])
        if not self.config.channels_last:
            images = images.contiguous()
        return images, obs.poses()[rows, index]

    def _scene(self, obs: Observation, context: torch.Tensor, with_grad: int) -> torch.Tensor:
        """r = r1 + r2 of the context views (B, 2) -> (B, R, 16, 16); the first ``with_grad`` samples
        are encoded with gradient, the rest without (they only feed the detached RL inputs)."""
        images, poses = self._views(obs, context)
        parts = []
        if with_grad > 0:
            parts.append(encode_scene(self._encoder, images[:with_grad], poses[:with_grad]))
        if with_grad < len(obs):
            with torch.no_grad():
                parts.append(encode_scene(self._encoder, images[with_grad:], poses[with_grad:]))
        return torch.cat(parts)

    def _split_context_query(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Per sample, a random query view q in {0, 1, 2}; the other two are the context. (B, 2), (B, 1)."""
        query = torch.randint(NUM_VIEWS, (batch, 1), generator=self.rng, device=self.device)
        context = torch.cat([(query + 1) % NUM_VIEWS, (query + 2) % NUM_VIEWS], dim=1)
        return context, query

    def _head_input(self, r: torch.Tensor, obs: Observation) -> torch.Tensor:
        """What the policy heads see: r (B, R, 16, 16), with the proprioception (B, P) tiled over its grid and
        concatenated to its channels (``ModelConfig.head_proprioception_dim``) -> (B, R + P, 16, 16)."""
        config = self.config
        if not config.head_proprioception_dim:
            return r
        proprioception = obs.proprioception(config.heads_see_proprioception, config.heads_see_fixation,
                                            config.heads_see_steps_left)  # fmt: skip
        return torch.cat([r, tile(proprioception.to(r.dtype), r.shape[-1])], dim=1)

    def _first_two(self, batch: int) -> torch.Tensor:
        return torch.tensor([[0, 1]], device=self.device).expand(batch, 2)

    # ------------------------------------------------------------------ acting
    @torch.no_grad()
    def act(
        self, obs: Mapping[str, Any] | Observation, deterministic: bool = False, policy: Policy = "grasp"
    ) -> np.ndarray:
        """Actions for a batch of env observations.

        Args:
            obs: dict with images uint8 (N, 3, 64, 64, C), viewpoints (N, 3, 6), gripper (N, 9); views 0 and 1
                are the context (the views are i.i.d. around the fixation point).
            deterministic: the heads' deterministic action (:meth:`apr.model.heads.PolicyHeads.mode`: tanh(mu),
                or with the map critic ``fixation_critic="map"`` x and y from the critics' best point) instead of
                a sample.
            policy: "grasp" (action (N, 4 or 6)) or "fixation" (action (N, 3)).

        Returns:
            float32 (N, A) in [-1, 1].
        """
        obs = obs.to(self.device) if isinstance(obs, Observation) else Observation.from_env(obs, self.device)
        heads = self.grasp if policy == "grasp" else self.fixation
        with self._autocast():
            r = self._head_input(self._scene(obs, self._first_two(len(obs)), with_grad=0), obs)
            action = heads.mode(r) if deterministic else heads.actor.sample(r, self.act_rng)[0]
        return action.float().cpu().numpy()

    @torch.no_grad()
    def predict_view(self, obs: Mapping[str, Any] | Observation, query_view: int = 2) -> np.ndarray:
        """The generator's prediction of one view from the other two, sampled from the prior (for pictures).

        Returns:
            float32 (N, 64, 64, C) in [0, 1], HWC like the env's images.
        """
        if self.generator is None:
            raise RuntimeError("the 'w/o representation' ablation has no generator")
        obs = obs.to(self.device) if isinstance(obs, Observation) else Observation.from_env(obs, self.device)
        context = torch.tensor([[v for v in range(NUM_VIEWS) if v != query_view]], device=self.device)
        with self._autocast():
            r = self._scene(obs, context.expand(len(obs), 2), with_grad=0)
            query_pose = obs.poses()[:, query_view]
            noise = torch.randn(
                self.generator.noise_shape(len(obs), r.shape[-1]), generator=self.act_rng, device=self.device
            )
            image = self.generator.sample(r, query_pose, noise)
        return image.permute(0, 2, 3, 1).float().cpu().numpy()

    @torch.no_grad()
    def gqn_measure(self, obs: Mapping[str, Any] | Observation) -> dict[str, float]:
        """How well the generator predicts view 2 of each observation from views 0 and 1, beside the mean image.

        Returns:
            ``prediction_mse`` (the prior's prediction with zero noise: its latent means), ``reconstruction_mse``
            (through the posterior, which sees the view), ``kl`` (nats per image, summed over steps), and
            ``mean_image_mse``: the error of one image for all, the pixel-wise mean of these very views (a
            predictor that knows nothing of the scene; its error is the views' variance). Pixel errors are per
            value, images in [0, 1]. {} for the "w/o representation" ablation, which has no generator.
        """
        if self.generator is None:
            return {}
        obs = obs.to(self.device) if isinstance(obs, Observation) else Observation.from_env(obs, self.device)
        batch = len(obs)
        r = self._scene(obs, self._first_two(batch), with_grad=0).float()
        truth, pose = self._views(obs, torch.full((batch, 1), 2, device=self.device))
        truth, pose = truth[:, 0].float(), pose[:, 0]
        noise = torch.zeros(self.generator.noise_shape(batch, r.shape[-1]), device=self.device)
        predicted = self.generator.sample(r, pose, noise)
        reconstructed, kl = self.generator(r, pose, truth, noise)
        mean_image = truth.mean(dim=0, keepdim=True)
        return {
            "prediction_mse": float(((predicted - truth) ** 2).mean()),
            "reconstruction_mse": float(((reconstructed - truth) ** 2).mean()),
            "kl": float(kl.mean()),
            "mean_image_mse": float(((mean_image - truth) ** 2).mean()),
            "views": batch,
        }

    # ------------------------------------------------------------------ learning
    def compute_losses(
        self, grasp_batch: GraspBatch, fixation_batch: FixationBatch | None, step: int
    ) -> tuple[dict[str, torch.Tensor], Metrics]:
        """Every loss of one joint update, from the current parameters (nothing is stepped).

        Returns:
            losses by name (gqn/elbo, grasp/critic, grasp/actor, grasp/temperature, fixation/...) and metrics.
        """
        config = self.config
        losses: dict[str, torch.Tensor] = {}
        metrics: Metrics = {}
        batch = len(grasp_batch.obs)
        fix_batch = 0 if fixation_batch is None else len(fixation_batch.obs)
        elbo_now = config.representation and step % config.gqn_update_every == 0
        n_grasp_gqn = min(config.gqn_batch_size, batch) if elbo_now else 0
        n_fix_gqn = min(config.gqn_fixation_batch_size, fix_batch) if elbo_now else 0
        # The critics train the encoder (the ablation, or critic_trains_encoder): every r gets its gradient; else only
        # the ELBO's samples.
        critic_grad = not config.representation or config.critic_trains_encoder
        grasp_grad = batch if critic_grad else n_grasp_gqn
        fix_grad = fix_batch if critic_grad else n_fix_gqn

        with self._autocast():
            context, query = self._split_context_query(batch)
            r = self._scene(grasp_batch.obs, context, grasp_grad)
            with torch.no_grad():
                next_obs = grasp_batch.next_obs
                r_next = self._head_input(self._scene(next_obs, self._first_two(batch), with_grad=0), next_obs)
            if fixation_batch is not None:
                fix_context, fix_query = self._split_context_query(fix_batch)
                r_fix = self._scene(fixation_batch.obs, fix_context, fix_grad)

            if self._generator is not None and n_grasp_gqn + n_fix_gqn > 0:
                query_images, query_poses = self._views(grasp_batch.obs[:n_grasp_gqn], query[:n_grasp_gqn])
                r_gqn = r[:n_grasp_gqn]
                if n_fix_gqn > 0:
                    fix_images, fix_poses = self._views(fixation_batch.obs[:n_fix_gqn], fix_query[:n_fix_gqn])
                    query_images = torch.cat([query_images, fix_images])
                    query_poses = torch.cat([query_poses, fix_poses])
                    r_gqn = torch.cat([r_gqn, r_fix[:n_fix_gqn]])
                if config.elbo_encoder_scale != 1.0:  # the same r forward, its gradient to the encoder scaled
                    r_gqn = r_gqn * config.elbo_encoder_scale + r_gqn.detach() * (1.0 - config.elbo_encoder_scale)
                losses["gqn/elbo"], gqn_metrics = self._elbo(r_gqn, query_images[:, 0], query_poses[:, 0], step)
                metrics.update(gqn_metrics)

            # Stop-gradient: the RL losses see r detached, except the critics that train the encoder.
            r_critic = self._head_input(r if critic_grad else r.detach(), grasp_batch.obs)
            r_actor = self._head_input(r.detach(), grasp_batch.obs)
            losses["grasp/critic"], m = sac_critic_loss(
                self.grasp,
                r_critic,
                grasp_batch.action.float(),
                grasp_batch.reward.float(),
                r_next,
                grasp_batch.terminated.float(),
                config.gamma,
                self.rng,
                grasp_batch.steps,
            )
            metrics.update({f"grasp/{k}": v for k, v in m.items()})
            losses["grasp/actor"], log_prob, m = sac_actor_loss(self.grasp, r_actor, self.rng)
            metrics.update({f"grasp/{k}": v for k, v in m.items()})
            losses["grasp/temperature"], m = temperature_loss(self.grasp.log_alpha, log_prob, self.grasp.target_entropy)
            metrics.update({f"grasp/{k}": v for k, v in m.items()})

            if fixation_batch is not None:
                fix_obs = fixation_batch.obs
                r_fix_critic = self._head_input(r_fix if critic_grad else r_fix.detach(), fix_obs)
                actions, rewards = self._bandit_targets(fixation_batch)  # (B, K, 3), (B, K)
                losses["fixation/critic"], m = bandit_critic_loss(
                    self.fixation, r_fix_critic, actions.float(), rewards.float()
                )
                metrics.update({f"fixation/{k}": v for k, v in m.items()})
                r_fix_actor = self._head_input(r_fix.detach(), fix_obs)
                losses["fixation/actor"], log_prob, m = sac_actor_loss(self.fixation, r_fix_actor, self.rng)
                metrics.update({f"fixation/{k}": v for k, v in m.items()})
                losses["fixation/temperature"], m = temperature_loss(
                    self.fixation.log_alpha, log_prob, self.fixation.target_entropy
                )
                metrics.update({f"fixation/{k}": v for k, v in m.items()})
        return losses, metrics

    def _elbo(self, r: torch.Tensor, query_images: torch.Tensor, query_poses: torch.Tensor,
              step: int) -> tuple[torch.Tensor, Metrics]:  # fmt: skip
        """The generator's negative ELBO of query views (B, C, 64, 64) at poses (B, P) given r (B, R, 16, 16), at the
        pixel sigma of update ``step``."""
        assert self._generator is not None
        noise = torch.randn(self.generator.noise_shape(len(r), r.shape[-1]), generator=self.rng, device=self.device)
        weights = None
        if self.config.image_channels == 4 and self.config.gqn_mask_weight != 1.0:
            weights = torch.tensor([1.0, 1.0, 1.0, self.config.gqn_mask_weight], device=self.device)
        return gqn_elbo_loss(self._generator, r, query_poses, query_images, pixel_sigma(step, self.config), noise,
                             weights)  # fmt: skip

    def _bandit_targets(self, batch: FixationBatch) -> tuple[torch.Tensor, torch.Tensor]:
        """The fixation critic's (action, reward) pairs per sample: (B, K, 3) and (B, K): the chosen action, then
        ``fixation_relabels`` uniform ones, each with the reward it would have earned (:data:`FIXATION_REWARDS`).
        Without relabelled points and with the grasp reward: the chosen action and the episode's reward (K = 1)."""
        config = self.config
        actions = batch.action[:, None].float()
        if config.fixation_reward == "grasp" and not config.fixation_relabels:
            return actions, batch.reward[:, None].float()
        if config.fixation_relabels:
            shape = (len(batch.action), config.fixation_relabels, actions.shape[-1])
            uniform = torch.rand(shape, generator=self.rng, device=self.device) * 2.0 - 1.0
            actions = torch.cat([actions, uniform], dim=1)
        if config.fixation_reward == "proximity":
            if batch.object_centres is None:
                raise ValueError("the proximity reward needs the fixation samples' object centres")
            return actions, proximity_reward(actions, batch.object_centres.float(), config.fixation_proximity_radius)
        if batch.lifted is None or batch.grasp_tip is None:
            raise ValueError("relabelling the grasp reward needs the fixation samples' lift and grasp tip")
        profile = "ball" if config.fixation_reward == "grasp" else "cone"
        rewards = hindsight_grasp_reward(actions, batch.lifted.float(), batch.grasp_tip.float(),
                                         REWARD.fixation_radius, profile)  # fmt: skip
        if profile == "ball":  # the chosen point's reward is the episode's own (the same, up to rounding at the rim)
            rewards[:, 0] = batch.reward.float()
        return actions, rewards

    def update(self, grasp_batch: GraspBatch, fixation_batch: FixationBatch | None, step: int) -> dict[str, float]:
        """One joint step: ELBO + grasp SAC + fixation SAC; ``step`` is the update count (schedules).

        Returns:
            metrics by name (floats), one host synchronisation.
        """
        losses, metrics = self.compute_losses(grasp_batch, fixation_batch, step)
        for optimizer in self.optimizers.values():
            optimizer.zero_grad(set_to_none=True)
        torch.stack(list(losses.values())).sum().backward()
        if "gqn" in self.optimizers:
            learning_rate = gqn_learning_rate(step, self.config)
            for group in self.optimizers["gqn"].param_groups:
                group["lr"] = learning_rate
        for optimizer in self.optimizers.values():
            optimizer.step()
        soft_update(self.grasp.critic_target, self.grasp.critic, self.config.tau)

        values = torch.stack([v.float() for v in metrics.values()]).tolist()  # one sync
        result = dict(zip(metrics.keys(), values, strict=True))
        if "gqn/elbo_loss" in result:
            result["gqn/sigma"] = pixel_sigma(step, self.config)
            result["gqn/lr"] = gqn_learning_rate(step, self.config)
        return result

    def gqn_update(self, obs: Observation, step: int) -> dict[str, float]:
        """One step of the encoder and generator alone: the ELBO of a batch of observations, each with a random query
        view and the other two as the context, as in :meth:`update` but without the policies (GQN training on scenes
        before the first grasp). ``step`` counts these updates (the sigma and learning-rate schedules).

        Returns:
            the ELBO's metrics by name (gqn/elbo_loss, gqn/nll, gqn/kl, gqn/mse) and gqn/sigma, gqn/lr.
        """
        if "gqn" not in self.optimizers:
            raise RuntimeError("the 'w/o representation' ablation has no generator")
        obs = obs.to(self.device)
        with self._autocast():
            context, query = self._split_context_query(len(obs))
            r = self._scene(obs, context, with_grad=len(obs))
            query_images, query_poses = self._views(obs, query)
            loss, metrics = self._elbo(r, query_images[:, 0], query_poses[:, 0], step)
        optimizer = self.optimizers["gqn"]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        for group in optimizer.param_groups:
            group["lr"] = gqn_learning_rate(step, self.config)
        optimizer.step()
        values = torch.stack([v.float() for v in metrics.values()]).tolist()
        return {**dict(zip(metrics.keys(), values, strict=True)), "gqn/sigma": pixel_sigma(step, self.config),
                "gqn/lr": gqn_learning_rate(step, self.config)}  # fmt: skip

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """Networks, optimisers and random-generator states: a resumed run continues exactly."""
        return {
            "networks": self.networks.state_dict(),
            "optimizers": {name: opt.state_dict() for name, opt in self.optimizers.items()},
            "rng": self.rng.get_state(),
            "act_rng": self.act_rng.get_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.networks.load_state_dict(state["networks"])
        for name, opt in self.optimizers.items():
            opt.load_state_dict(state["optimizers"][name])
        self.rng.set_state(state["rng"])
        self.act_rng.set_state(state["act_rng"])

    def num_parameters(self) -> dict[str, int]:
        """Trainable parameter counts per network (the target critics excluded)."""
        return {
            name: sum(p.numel() for p in module.parameters() if p.requires_grad)
            for name, module in self.networks.items()
        }
