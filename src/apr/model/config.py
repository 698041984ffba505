"""Every size and learning hyperparameter of the APR model, in one place.

Each field carries its source: the APR paper (Zaky et al., section "Method"), GQN (Eslami et al. 2018 and
its supplementary material), SAC (Haarnoja et al. 2018a/b), or "ours" where the papers are silent (the
reason is in docs/decisions.md). Schedules are pure functions of the update count so that a resumed run
continues them exactly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal


@dataclass
class ModelConfig:
    """Sizes, optimiser settings and speed options of the APR learner (paper values by default)."""

    # --- inputs (paper, Method B; set from the environment's spaces) ---
    image_channels: int = 3
    """Channels of one view: 3 (RGB) or 4 (RGB + target mask, paper section 4A)."""
    image_size: int = 64
    """Side of the (foveated) view in pixels (paper, Method B: 64x64)."""
    viewpoint_dim: int = 6
    """v: the six joint angles of the head (paper, Method A)."""
    gripper_dim: int = 9
    """g = (x, y, z, sin a, cos a, sin b, cos b, sin c, cos c) (paper, Method B)."""
    grasp_action_dim: int = 6
    """Grasp action: 6 (dx, dy, dz, da, db, dc) or 4 (dx, dy, dz, da) (paper, Method A and section 4B)."""
    fixation_action_dim: int = 3
    """Fixation action: the 3-D fixation point (paper, Method A)."""

    # --- encoder: the GQN "tower" (Eslami et al. 2018, supplementary Fig. S1) ---
    encoder_channels: int = 256
    """Wide layers of the tower (Eslami et al. 2018: 256)."""
    encoder_narrow_channels: int = 128
    """Narrow 3x3 layers of the tower (Eslami et al. 2018: 128)."""
    representation_channels: int = 256
    """Channels of r_i at 16x16 (paper, Method B: 16x16x256)."""
    encoder_init: Literal["he", "torch"] = "he"
    """Initialisation of the tower's convolutions (ours; the papers do not say). "he": Kaiming-normal for ReLU and
    zero biases (He et al. 2015). "torch": PyTorch's default, under which what the images hold reaches r at about 1%
    of r's scale and Adam-trained heads read nothing of it (docs/decisions.md, "The encoder's initialisation")."""

    # --- generator: ConvDRAW (Eslami et al. 2018, supplementary section "Generator") ---
    generation_steps: int = 12
    """Autoregressive generation steps L (paper, Method B; Eslami et al. 2018: 12)."""
    lstm_channels: int = 128
    """Hidden channels of the generator and inference ConvLSTMs (Eslami et al. 2018: 128)."""
    lstm_kernel: int = 5
    """Kernel of the ConvLSTMs and of the prior/posterior heads (Eslami et al. 2018: 5x5)."""
    latent_channels: int = 3
    """Channels of each step's latent z at 16x16 (Eslami et al. 2018: 3)."""
    canvas_channels: int = 128
    """Channels of the 64x64 canvas u, written by a 4x4/4 transposed conv (ours; GQN reference: 128)."""

    # --- GQN optimisation (Eslami et al. 2018, supplementary "Optimisation") ---
    gqn_lr_start: float = 5e-4
    """Adam learning rate at update 0 (Eslami et al. 2018)."""
    gqn_lr_end: float = 5e-5
    """Adam learning rate after annealing (Eslami et al. 2018)."""
    sigma_start: float = 2.0
    """Pixel standard deviation of the Gaussian likelihood at update 0 (Eslami et al. 2018)."""
    sigma_end: float = 0.7
    """Pixel standard deviation after annealing (Eslami et al. 2018)."""
    gqn_anneal_updates: int = 200_000
    """Updates over which sigma and the GQN learning rate anneal linearly (paper/Eslami: 2e5 for sigma;
    one length for both here so a shorter run scales them together; set it to the run's length)."""
    gqn_mask_weight: float = 1.0
    """Weight of the target mask's channel (the 4th, with the environment's target) in the ELBO's reconstruction
    term. 1 (paper): every channel alike, "the generator is trained to also reconstruct the mask" (4A)."""
    gqn_init: str = ""
    """The encoder's and generator's starting weights. "" (paper): fresh ones. Else (ours) GQN weights trained on the
    benchmark's scenes before any grasp, by packaged name (``apr/model/pretrained/NAME.pt``) or path; a new run loads
    them once, before its first grasp (:mod:`apr.model.pretrained`; docs/decisions.md, "GQN training before the
    first grasp")."""
    gqn_batch_size: int = 36
    """Grasp-step observations per update that train the ELBO, the first ones of the grasp batch
    (Eslami et al. 2018: batch 36)."""
    gqn_fixation_batch_size: int = 4
    """Fixation observations added to the ELBO batch (ours: ~1 fixation view per 9 grasp views)."""
    gqn_update_every: int = 1
    """The ELBO trains the encoder and generator on every this-many-th joint update, the SAC losses on every one
    (ours; the paper trains both on every step; 2 in the CPU presets, where the ELBO is about half an update's cost:
    docs/decisions.md)."""

    # --- policy heads (paper, Method B) ---
    head_channels: tuple[int, ...] = (128, 64, 32)
    """Conv block of every actor and critic: 3x3 kernels with these channels (paper, Method B)."""
    heads_see_proprioception: bool = False
    """False: the actors and critics see r only (paper, Method B: g and v reach the policy only through the
    encoder). True (ours, the recipe of every Table 1 preset, ``apr.train.config.RECIPE``): they also see the gripper
    pose g tiled beside r (docs/decisions.md: the encoder, trained by the ELBO only, keeps little of g in r)."""
    heads_see_fixation: bool = False
    """True (ours): the heads also see the fixation point f and f - tip, tiled beside r. Only where the
    observation has f: the point a learned fixation chose, or the target's true centre in the labelled
    privileged preset (``--env.reveal-target``); never the simulator's answer otherwise."""
    heads_see_steps_left: bool = False
    """True (ours, the recipe of every Table 1 preset): the heads also see the grasp steps the episode has left,
    as a fraction of the 15-step limit, tiled beside r: the robot's own clock. It needs the environment's v1, whose
    limit is part of the task (docs/decisions.md, "The 15-step limit"; Pardo et al. 2018)."""
    log_std_min: float = -20.0
    """Clamp of the actor's log standard deviation, low end (Haarnoja et al. 2018 reference code: -20)."""
    log_std_max: float = 2.0
    """Clamp of the actor's log standard deviation, high end (Haarnoja et al. 2018 reference code: 2)."""

    # --- SAC (Haarnoja et al. 2018a/b) ---
    sac_lr: float = 3e-4
    """Adam learning rate of actors, critics and temperatures (Haarnoja et al. 2018)."""
    gamma: float = 0.99
    """Discount of the grasp policy (Haarnoja et al. 2018). The fixation bandit has no bootstrap."""
    n_step: int = 1
    """Environment steps a grasp critic's target sums rewards over before it bootstraps (n-step returns, Sutton and
    Barto 2018 section 7.1; Hessel et al. 2018 use 3): 1 is the one-step target of SAC (Haarnoja et al. 2018); 2 in
    the recipe of every Table 1 preset (ours, ``apr.train.config.RECIPE``; docs/decisions.md, "2-step returns"). An
    episode's end cuts the sum short."""
    tau: float = 0.005
    """Polyak rate of the soft target-critic update (Haarnoja et al. 2018)."""
    init_temperature: float = 1.0
    """Initial entropy temperature alpha (Haarnoja et al. 2018b reference code: 1.0; the Table 1 presets' recipe:
    0.01, docs/decisions.md)."""
    fixation_init_temperature: float | None = None
    """The fixation bandit's initial temperature, where it differs from the grasp heads'; None: ``init_temperature``
    (the recipe's 0.01 for both). At the paper's 1 the bandit looked almost at random for 300 grasps and its
    deterministic look ended further from objects (``cpu-active-learned-4d-bandit-temperature1``: 15 and 31% held out
    against 54 and 62%; docs/investigations.md, "The fixation bandit's exploration")."""
    batch_size: int = 256
    """Grasp transitions per update (Haarnoja et al. 2018: 256)."""
    fixation_batch_size: int = 256
    """Fixation (bandit) samples per update (Haarnoja et al. 2018: 256)."""
    fixation_reward: Literal["grasp", "tip-proximity", "proximity"] = "grasp"
    """What the fixation bandit regresses (:data:`apr.model.agent.FIXATION_REWARDS`). "grasp" (paper, Method A: the
    fixation policy "is optimized using the grasp reward only"): 1 when an object was lifted and the tool tip started
    the grasp within 10 cm of the point. "tip-proximity" (ours, from the robot's knowledge only): when an object was
    lifted, ``1 - d / 10 cm``, d from the point to the tool tip at the grasp's start. "proximity" (shaping from the
    simulator, never in a Table 1 row): ``1 - min(d, R) / R``, d from the point to the nearest object centre as the
    simulator reports it, R = ``fixation_proximity_radius``."""
    fixation_proximity_radius: float = 0.15
    """m: R of the "proximity" reward (ours; beyond it a point earns 0)."""
    fixation_relabels: int = 0
    """Per bandit sample, this many more fixation actions, uniform in the action box, each with the reward it would
    have earned in that episode (hindsight relabelling, Andrychowicz et al. 2017; ours): exact for every reward
    above, each a known function of the episode's end (the lift and the tool tip) or, for "proximity", of the
    scene. 0: the chosen action only (the paper)."""
    fixation_critic: Literal["tiled", "map"] = "tiled"
    """The fixation bandit's critics. "tiled": the action tiled over r's grid, as the grasp critics (paper, Method
    B). "map" (ours): the conv block and fully connected layer give a value per point of a 12 x 12 lattice over the
    fixation box's x and y, read at the action (:class:`apr.model.heads.MapCritic`), and the deterministic fixation
    (evaluation) takes x and y from the critics' best point and z from the actor (docs/decisions.md, "The fixation
    critic")."""

    # --- ablation (paper, section 4C) ---
    representation: bool = True
    """True: the encoder learns from the ELBO only (RL sees r detached). False: the "w/o representation"
    ablation: no generator; the critic losses train the encoder (paper, section 4C)."""
    critic_trains_encoder: bool = False
    """With the representation: the critic losses also train the encoder, beside the ELBO (ours, a departure: the
    paper's encoder "does not accumulate gradients from the reinforcement learning losses", Method C)."""
    elbo_encoder_scale: float = 1.0
    """With ``critic_trains_encoder``: the scale of the ELBO's gradient where it reaches the encoder (the generator's
    is its own). 1: the sum of the ELBO and the critic losses, in which the ELBO's gradient at the encoder was 147 and
    316 times the grasp critic's (``cpu-passive-target --model.critic-trains-encoder`` at 200 and 600 grasps,
    ``scripts/encoder_gradients.py``); 0.0033 (ours) gives both about one size (docs/investigations.md, "The passive
    cameras framed on the tray")."""

    # --- run, precision and speed (ours) ---
    seed: int = 0
    """Seeds parameter initialisation and every draw of the learner (context/query choice, noise)."""
    device: str = "auto"
    """"auto" (cuda when available, else cpu), "cpu", "cuda", "cuda:1", ..."""
    precision: Literal["auto", "fp32", "bf16"] = "auto"
    """Autocast dtype of the forward passes; "auto" = bf16 on CUDA, fp32 on CPU. Losses stay fp32."""
    channels_last: bool = False
    """Use the channels-last memory format for convolutions (faster with bf16 on recent GPUs)."""
    compile: bool = False
    """Wrap the encoder and generator in torch.compile."""

    @classmethod
    def tiny(cls, **overrides: object) -> ModelConfig:
        """A few-channel variant for tests and CPU smoke runs (same structure, tiny sizes)."""
        sizes: dict[str, object] = dict(
            encoder_channels=16,
            encoder_narrow_channels=8,
            representation_channels=16,
            generation_steps=3,
            lstm_channels=16,
            latent_channels=2,
            lstm_kernel=3,
            canvas_channels=8,
            head_channels=(16, 8, 8),
            gqn_anneal_updates=1_000,
            gqn_batch_size=8,
            gqn_fixation_batch_size=2,
            batch_size=16,
            fixation_batch_size=8,
            device="cpu",
        )
        sizes.update(overrides)
        return cls(**sizes)  # type: ignore[arg-type]

    @classmethod
    def preset(cls, name: Literal["paper", "tiny"], **overrides: object) -> ModelConfig:
        """The paper's sizes or the tiny ones, with field overrides."""
        return cls.tiny(**overrides) if name == "tiny" else cls(**overrides)  # type: ignore[arg-type]

    def replace(self, **changes: object) -> ModelConfig:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    @property
    def head_proprioception_dim(self) -> int:
        """Channels the proprioception adds to a head's input: g (9) with ``heads_see_proprioception``, f (3) and
        f - tip (3) with ``heads_see_fixation``, the steps left (1) with ``heads_see_steps_left``."""
        return (self.gripper_dim * self.heads_see_proprioception + 6 * self.heads_see_fixation
                + self.heads_see_steps_left)  # fmt: skip

    @property
    def pose_dim(self) -> int:
        """Length of one view's proprioceptive vector (v, g) tiled into the encoder and generator."""
        return self.viewpoint_dim + self.gripper_dim


def _linear_anneal(update: int, start: float, end: float, length: int) -> float:
    """start -> end linearly over ``length`` updates, then constant (Eslami et al. 2018)."""
    fraction = min(max(update, 0) / max(length, 1), 1.0)
    return start + (end - start) * fraction


def pixel_sigma(update: int, config: ModelConfig) -> float:
    """Standard deviation of the generator's Gaussian pixel likelihood at this update count."""
    return _linear_anneal(update, config.sigma_start, config.sigma_end, config.gqn_anneal_updates)


def gqn_learning_rate(update: int, config: ModelConfig) -> float:
    """Adam learning rate of the encoder and generator at this update count."""
    return _linear_anneal(update, config.gqn_lr_start, config.gqn_lr_end, config.gqn_anneal_updates)
