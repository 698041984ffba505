"""The training configuration and the presets of the paper's Table 1.

A preset is a :class:`TrainConfig`; any field can be overridden on the command line
(``apr train --preset active-target --seed 1 --model.batch-size 128``). Learning hyperparameters live in
:class:`apr.model.config.ModelConfig`; this file holds the run: the environment, the experience stream, the
evaluation and checkpoint schedule.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import gymnasium
import tyro

from apr.envs.grasp_env import render_size_problem
from apr.model import pretrained
from apr.model.config import ModelConfig

ACTIVE_ENV_ID = "apr/ActiveGrasp-v4"
"""The active model's environment: the head camera that looks."""
PASSIVE_ENV_ID = "apr/PassiveGrasp-v4"
"""The passive model's environment: three static cameras framed on the tray, no head, no log-polar warp."""
EnvId = Literal[
    "apr/ActiveGrasp-v4",
    "apr/PassiveGrasp-v4",
    "apr/BenchmarkGrasp-v4",
    "apr/ActiveGrasp-v3",
    "apr/PassiveGrasp-v3",
    "apr/ActiveGrasp-v2",
    "apr/PassiveGrasp-v2",
    "apr/ActiveGrasp-v1",
    "apr/PassiveGrasp-v1",
    "apr/ActiveGrasp-v0",
    "apr/PassiveGrasp-v0",
]
"""v4 (the presets'): the passive cameras are framed on the tray; the active environment is v2's. v3: v2 with a
change of tilt turning the gripper about its tool tip (measured and not taken). v2: the 15-step limit is part of the
task (it terminates; the observation has the steps left) and a tilted gripper can reach the grasp height; the
passive cameras see the tray across a third of each image. v1: the same limit, but a gripper tilted by more than
about 40 degrees never reaches the grasp height. v0: the limit truncates, no clock. Runs saved on each evaluate on
it (docs/environments.md, "Versions")."""


def is_passive(env_id: str) -> bool:
    """``env_id`` is a version of the passive model's environment."""
    return env_id.startswith("apr/PassiveGrasp-")


def model_env_id(env_id: str, passive: bool) -> str:
    """The active (or passive) model's environment at the version of ``env_id``."""
    version = env_id.rpartition("-")[2]
    return f"apr/{'Passive' if passive else 'Active'}Grasp-{version}"


STEPS_PER_GRASP_ESTIMATE = 10
"""Grasp steps an episode takes on average (a guess for sizing schedules; episodes take 1 to 15)."""


class ConfigError(ValueError):
    """A configuration that cannot run; the message names the command-line flag of each field at fault."""


def flag(path: str) -> str:
    """The command-line flag of the field ``path`` ("model.batch_size" -> "--model.batch-size")."""
    return "--" + path.replace("_", "-")


@dataclass
class EnvConfig:
    """Which environment the workers run (paper, section 4)."""

    env_id: EnvId = ACTIVE_ENV_ID
    """The active model (head camera) or the passive one (three static cameras); v0 is the earlier task, whose
    15-step limit truncates with no clock in the observation (docs/decisions.md, "The 15-step limit")."""
    dof: Literal[4, 6] = 6
    """Gripper degrees of freedom (paper: 6; 4 for Active-Learned-4D)."""
    target: Literal["env", "learned"] = "env"
    """Environment-selected target (section 4A) or learned fixation (section 4B). Passive: env only (its cameras
    are static: there is no fixation to learn), and learned is refused."""
    foveation: Literal["logpolar", "resize"] = "logpolar"
    """Log-polar-like warp or plain resize (the "w/o log-polar" ablation, section 4C). Passive: always resize
    (a run records it so); an explicit --env.foveation logpolar is refused."""
    renderer: Literal["auto", "egl", "tiny"] = "auto"
    """auto: EGL when its plugin loads, else TinyRenderer (the environments' own default is tiny; each worker is
    a process with one environment, so EGL's one world per process is no limit here). What the workers resolved
    it to is recorded in the checkpoints, and evaluations of the policy are checked against it."""
    reach_scale: float = 10.0
    """Reach reward per metre of progress toward the fixation point (ours; the paper gives no formula). At 1.0
    the reach reward (at most ~0.06 a step) is drowned by SAC's entropy bonus: docs/decisions.md."""
    render_size: int = 256
    """Side of each render before the warp to 64x64, a multiple of 64 (paper: 256; the CPU presets: 128, which
    saves CPU time per render and blurs the warp's inner ring: docs/decisions.md)."""

    reveal_target: bool = False
    """Put the target's true centre, the simulator's answer, in the observation (``fixation``; env target only).
    Not the robot's knowledge and not the paper's: only the labelled ``cpu-4d`` preset and the scripted
    baseline use it."""
    initial_views: Literal["drawn", "fixed"] = "drawn"
    """The head's views at reset (active env only): "drawn" around the point as at every step (paper, Method A:
    "we sample a viewpoint from a sphere centered on it"), or "fixed" (ours): the same three viewpoints in every
    episode (``HEAD.fixed_initial_views``), so that where an object lies in the first images says where it lies on
    the tray (docs/investigations.md, "What the representation knows")."""

    cameras: Literal["", "wide", "sides", "front"] = ""
    """The passive cameras' layout (passive env only): "" the version's (``apr.PASSIVE_CAMERAS``: v4's "sides", framed
    on the tray from its front, left and right); "front" (ours, an option): so framed, all three from the front, 20
    deg apart; "wide": v0-v3's."""

    def make_kwargs(self, split: str) -> dict[str, Any]:
        """Keyword arguments of ``gymnasium.make(self.env_id, ...)`` for ``split``."""
        kwargs: dict[str, Any] = {"dof": self.dof, "split": split, "renderer": self.renderer,
                                  "reach_scale": self.reach_scale, "render_size": self.render_size,
                                  "reveal_target": self.reveal_target}  # fmt: skip
        if not is_passive(self.env_id):
            kwargs.update(target=self.target, foveation=self.foveation)
            if self.initial_views != "drawn":  # v0 and saved runs never had it
                kwargs["initial_views"] = self.initial_views
        elif self.cameras:
            kwargs["cameras"] = self.cameras
        return kwargs

    @property
    def learned_fixation(self) -> bool:
        return not is_passive(self.env_id) and self.target == "learned"

    @property
    def observes_fixation(self) -> bool:
        """The observations hold a fixation point: the one a learned fixation chose, or the revealed target."""
        return self.learned_fixation or self.reveal_target

    @property
    def initial_views_problem(self) -> str:
        """Why ``initial_views`` cannot be had in this environment (empty: it can), for a caller to put after its
        flag."""
        if is_passive(self.env_id) and self.initial_views != "drawn":
            return f"{self.initial_views} needs the head: the passive model's cameras are static"
        return ""

    @property
    def observes_steps_left(self) -> bool:
        """The observations hold the grasp steps left: the environments' v1 and v2, whose 15-step limit is part of
        the task (``limit_in_task``, as ``apr`` registers each version)."""
        return bool(gymnasium.spec(self.env_id).kwargs["limit_in_task"])

    @property
    def image_channels(self) -> int:
        return 3 if self.learned_fixation else 4


@dataclass
class TrainConfig:
    """A training run of APR."""

    preset: Annotated[str, tyro.conf.Suppress] = "active-target"
    """The preset this configuration started from (it names the run; chosen with ``apr train --preset``)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    seed: int = 0
    """Seeds the episodes (objects, targets, viewpoints), the warm-up actions and the learner."""
    total_grasps: int = 70_000
    """Grasp episodes to run (paper: learning saturates before 70K grasps)."""
    max_train_minutes: float = 0.0
    """Also stop after this many minutes of training, evaluations not counted (0: no time limit). The run then
    ends as at ``total_grasps``: a final evaluation and checkpoint."""
    workers: int = 0
    """Environment processes (Ray actors with ``--backend ray``); 0 = one per CPU core of this machine."""
    backend: Literal["local", "ray"] = "local"
    """Where the environment workers run: processes of this machine, or Ray actors spread over a Ray cluster's
    nodes (the learner stays in this process; ``pip install -e ".[cluster]"``). Either gives the same numbers.
    ``apr train`` opens the workers this names and passes them to the trainer (``Trainer(config, workers=...)``)."""
    ray_address: str = ""
    """The Ray cluster of ``--backend ray``: ``auto`` or ``HOST:6379``; empty = the
    ``RAY_ADDRESS`` cluster, one started on this machine with ``ray start``, or else a new one on this machine."""
    random_grasps: int = 200
    """Warm-up episodes with random actions before the policies act (ours; SAC practice)."""
    warmup_down_probability: float = 0.0
    """Chance that a warm-up grasp step moves straight down (dz = -1), the rest of its action uniform in [-1, 1]
    (0.9: the benchmark's random policy, pybullet's ``ContinuousDownwardBiasPolicy``; Quillen et al. 2018). 0 (the
    recipe): uniform, which never attempts a grasp from the start height; 0.9 made 64-80% of the warm-up attempt
    and did not change ``cpu-active-target`` seed 1's held-out success at 600 grasps (docs/decisions.md,
    "Warm-up")."""
    updates_per_step: float = 0.25
    """Learner updates per grasp step collected (the update-to-data ratio; ours, the paper does not say)."""
    replay_capacity: int = 50_000
    """Grasp transitions kept in replay (ours; each stores one 3x64x64xC uint8 observation)."""
    anneal_over_run: bool = True
    """Scale the GQN schedules (sigma, learning rate) to this run's expected updates instead of the 200K
    updates of Eslami et al. (SPEC section 4)."""
    eval_every_grasps: int = 2_000
    """Evaluate on held-out objects every this many grasps (and at the end)."""
    eval_episodes: int = 100
    """Episodes per evaluation (SPEC: at least 100)."""
    final_eval_episodes: int = 0
    """Episodes of the evaluation at the end of the run; 0 = ``eval_episodes`` (a cheaper curve, a full end)."""
    eval_workers: int = 0
    """Processes for evaluation; 0 = as many as ``workers``."""
    checkpoint_every_grasps: int = 1_000
    """Write a checkpoint every this many grasps (and at the end, and on Ctrl-C)."""
    keep_checkpoints: int = 3
    """Checkpoints kept; older ones are deleted."""
    log_every_grasps: int = 100
    """Write a metrics.csv row and TensorBoard scalars every this many grasps."""
    image_every_grasps: int = 2_000
    """Log views and GQN predictions to TensorBoard every this many grasps."""
    runs_dir: Path = Path("runs")
    """Parent folder of run folders."""
    run_name: str = ""
    """Run folder name; empty = PRESET__sSEED__YYYYmmdd-HHMMSS."""

    def resolved(self) -> TrainConfig:
        """A copy with the fields that follow from others filled in (what a run saves and uses)."""
        model = self.model.replace(
            image_channels=self.env.image_channels,
            grasp_action_dim=self.env.dof,
            seed=self.seed,
        )
        if self.anneal_over_run:
            expected = self.total_grasps * STEPS_PER_GRASP_ESTIMATE * self.updates_per_step
            model = model.replace(gqn_anneal_updates=max(int(expected), 1))
        workers = self.workers or os.cpu_count() or 1
        env = self.env
        if is_passive(env.env_id):  # its three static cameras are resized, whatever a preset said
            env = dataclasses.replace(env, foveation="resize")
        return dataclasses.replace(self, env=env, model=model, workers=workers,
                                   eval_workers=self.eval_workers or workers)  # fmt: skip

    def problems(self) -> list[str]:
        """What makes this configuration unrunnable, one sentence per field, each naming its flag (empty: none)."""
        problems = [f"{flag(path)} {message}" for path, message in _field_problems(self)]
        if is_passive(self.env.env_id) and self.env.target == "learned":
            problems.append(f"--env.target learned contradicts --env.env-id {self.env.env_id}: the passive model's "
                            "cameras are static, it has no fixation to learn; use --env.target env, or "
                            f"--env.env-id {ACTIVE_ENV_ID} for learned fixation")  # fmt: skip
        if self.env.initial_views_problem:
            problems.append(f"--env.initial-views {self.env.initial_views_problem}")
        if self.env.cameras and not is_passive(self.env.env_id):
            problems.append(f"--env.cameras {self.env.cameras} needs the passive model: {self.env.env_id} has the head")
        if self.env.reveal_target and self.env.target == "learned":
            problems.append("--env.reveal-target needs --env.target env: a learned fixation has no target to reveal")
        if self.model.heads_see_fixation and not self.env.observes_fixation:
            problems.append("--model.heads-see-fixation needs a fixation point in the observation: --env.target "
                            "learned (the point chosen), or --env.reveal-target (the simulator's answer, not the "
                            "robot's knowledge)")  # fmt: skip
        if self.model.elbo_encoder_scale != 1.0 and not self.model.critic_trains_encoder:
            problems.append("--model.elbo-encoder-scale needs --model.critic-trains-encoder: alone, the ELBO's is the "
                            "encoder's only gradient and Adam undoes its scale")  # fmt: skip
        if self.model.heads_see_steps_left and not self.env.observes_steps_left:
            problems.append(f"--model.heads-see-steps-left needs the steps left in the observation: --env.env-id "
                            f"{self.env.env_id} is the earlier task, whose limit truncates with no clock; use its "
                            "-v2")  # fmt: skip
        if self.replay_capacity >= 1 and self.model.batch_size >= 1 and self.replay_capacity < self.model.batch_size:
            problems.append(f"--replay-capacity {self.replay_capacity} is smaller than one learner batch "
                            f"(--model.batch-size {self.model.batch_size}): the learner would never start")  # fmt: skip
        if self.run_name and (self.run_name in (".", "..") or "/" in self.run_name or os.sep in self.run_name):
            problems.append(f"--run-name {self.run_name!r} must be a plain folder name (no path separators)")
        if self.runs_dir.exists() and not self.runs_dir.is_dir():
            problems.append(f"--runs-dir {self.runs_dir} is a file, not a folder")
        if self.backend == "ray" and self.workers == 0:
            problems.append("--workers 0 means this machine's cores; with --backend ray give the number of "
                            "environment actors to spread over the cluster (at most its CPUs)")  # fmt: skip
        problems += pretrained.problems(self.model)
        device = self.model.device
        if device.startswith("cuda"):
            import torch

            if not torch.cuda.is_available():
                problems.append(f"--model.device {device}: torch sees no CUDA device here; use auto or cpu")
        return problems

    def check(self) -> None:
        """Raise :class:`ConfigError` listing every problem of :meth:`problems`."""
        problems = self.problems()
        if problems:
            raise ConfigError("\n".join(problems))

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, default=str)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        data = json.loads(text)
        model, env = data.pop("model"), data.pop("env")
        model["head_channels"] = tuple(model["head_channels"])
        data.setdefault("warmup_down_probability", 0.0)  # saved before the field: the warm-up was uniform
        model.setdefault("encoder_init", "torch")  # saved before the field: PyTorch's default initialisation
        if "heads_see_fixation" not in model:  # saved before the observation rule: g came with f and f - tip ...
            model["heads_see_fixation"] = model.get("heads_see_proprioception", False)
            # ... and the observation always held f, the target's true centre with an env target
            env.setdefault("reveal_target", model["heads_see_fixation"] and env.get("target") == "env")
        return cls(env=EnvConfig(**env), model=ModelConfig(**model), runs_dir=Path(data.pop("runs_dir")),
                   **data)  # fmt: skip


FIXED_ON_RESUME = {"preset", "seed", "replay_capacity", "runs_dir", "run_name"}
"""Run fields a resumed run keeps: the episodes' seeds, the replay's layout, the folder. Every other run field
(budgets, schedules, processes) may change on resume."""
CHANGEABLE_ON_RESUME = {
    "env.renderer", "model.device", "model.precision", "model.channels_last", "model.compile",
    "model.gqn_anneal_updates",
}  # fmt: skip
"""Environment and model fields a resumed run may change; every other one shapes the saved networks, optimiser
states or replay, or what they were trained on."""
DERIVED_MODEL_FIELDS = {"image_channels": "--env.target", "grasp_action_dim": "--env.dof", "seed": "--seed"}
"""Model fields that follow from other fields (``TrainConfig.resolved``), with the flag they follow from."""


def resume_conflicts(saved: TrainConfig, new: TrainConfig) -> list[str]:
    """Why ``new`` cannot continue a run saved with ``saved`` (both resolved): one sentence per field that
    differs and may not change on resume, naming its flag (empty: it can)."""
    conflicts = []
    for path, before, after in _differences(saved, new):
        section, _, name = path.rpartition(".")
        if (section == "" and path not in FIXED_ON_RESUME) or path in CHANGEABLE_ON_RESUME:
            continue
        if section == "model" and name in DERIVED_MODEL_FIELDS:
            continue  # follows from a field compared on its own
        conflicts.append(f"{flag(path)} cannot change when resuming (the run has {before!r}, asked: {after!r})")
    return conflicts


def _differences(first: Any, second: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(field path, first value, second value) of every field that differs, nested dataclasses walked."""
    found = []
    for item in dataclasses.fields(first):
        a, b = getattr(first, item.name), getattr(second, item.name)
        if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
            found += _differences(a, b, f"{prefix}{item.name}.")
        elif a != b:
            found.append((f"{prefix}{item.name}", a, b))
    return found


AT_LEAST_ONE = {"total_grasps", "eval_episodes", "replay_capacity", "keep_checkpoints"}
"""Run fields that must be at least 1; every other number of a run must be at least 0."""
MODEL_AT_LEAST_ZERO = {"seed", "fixation_relabels"}
"""Model fields that may be 0; every other integer of the model must be at least 1."""


def _field_problems(config: TrainConfig) -> list[tuple[str, str]]:
    """(field path, what is wrong) for numbers out of range: negative counts, zero sizes, NaN or infinite values."""
    found: list[tuple[str, str]] = []

    def number(path: str, value: object, low: float, strict: bool = False) -> None:
        if isinstance(value, bool) or not isinstance(value, int | float):
            return
        if not math.isfinite(value):
            found.append((path, f"must be a finite number, got {value}"))
        elif value < low or (strict and value == low):
            found.append((path, f"must be {'above' if strict else 'at least'} {low:g}, got {value}"))

    for item in dataclasses.fields(config):
        if item.name not in ("env", "model"):
            number(item.name, getattr(config, item.name), 1 if item.name in AT_LEAST_ONE else 0)
    number("env.reach_scale", config.env.reach_scale, 0.0)
    if config.warmup_down_probability > 1:
        found.append(("warmup_down_probability", f"must be at most 1, got {config.warmup_down_probability}"))
    render_size = render_size_problem(config.env.render_size)
    if render_size:
        found.append(("env.render_size", render_size))
    model = config.model
    for item in dataclasses.fields(model):
        value, kind = getattr(model, item.name), str(item.type)
        if kind == "int":
            number(f"model.{item.name}", value, 0 if item.name in MODEL_AT_LEAST_ZERO else 1)
        elif kind in ("float", "float | None") and not item.name.startswith("log_std"):
            number(f"model.{item.name}", value, 0.0, strict=item.name != "gamma")  # None: no number to check
        elif isinstance(value, tuple) and (not value or any(isinstance(v, int) and v < 1 for v in value)):
            found.append((f"model.{item.name}", f"must be positive sizes, got {value}"))
    for name in ("gamma", "tau"):
        if getattr(model, name) > 1:
            found.append((f"model.{name}", f"must be at most 1, got {getattr(model, name)}"))
    if model.log_std_min >= model.log_std_max:
        found.append(("model.log_std_min", f"must be below --model.log-std-max ({model.log_std_max})"))
    return found


def _preset(name: str, description: str, **changes: Any) -> tuple[str, tuple[str, TrainConfig]]:
    env = EnvConfig(**changes.pop("env", {}))
    model = changes.pop("model", ModelConfig())
    return name, (description, TrainConfig(preset=name, env=env, model=model, **changes))


CPU_RENDERING: dict[str, Any] = dict(renderer="tiny", render_size=128)
"""How the CPU presets render (ours; the paper presets keep EGL at 256x256): TinyRenderer at 128x128 costs an env
step 70 ms of CPU against 150 ms for EGL through llvmpipe at 256 and renders bitwise reproducibly; the price is a
blurrier inner ring of the log-polar views (docs/decisions.md, "Views and rendering"; docs/benchmarks.md)."""
RECIPE: dict[str, Any] = dict(heads_see_proprioception=True, heads_see_steps_left=True, init_temperature=0.01,
                              n_step=2)  # fmt: skip
"""The learning recipe of every preset of Table 1, at both scales (ours; docs/decisions.md, "One recipe for Table
1"): the heads see the gripper pose g and the grasp steps left beside r (the 15-step limit is part of the task:
"The 15-step limit"), the entropy temperature starts at 0.01, and the grasp critics learn from 2-step returns
("2-step returns"). With a learned fixation the heads also see the point chosen, and the bandit learns as
:data:`PAPER_BANDIT` says (:func:`with_recipe`). Never the simulator's target or objects: the rows differ in what
they see."""
PAPER_BANDIT: dict[str, Any] = dict(fixation_reward="grasp", fixation_relabels=0)
"""The fixation bandit of the recipe, the paper's (Method A: "optimized using the grasp reward only"): its critic
regresses the episode's grasp reward at the point chosen, and nothing else. Hindsight relabelling (more points per
sample, each with the grasp reward it would have earned) is a flag, ``--model.fixation-relabels``, out of the recipe:
on seeds 0 and 1 at CPU scale it did not help (docs/decisions.md, "The fixation bandit's reward")."""
CPU_MODEL: dict[str, Any] = dict(batch_size=32, gqn_batch_size=8, gqn_update_every=2, channels_last=True)
"""How the CPU scale's learner saves time (ours): batch 32 (8 of them for the ELBO), the ELBO on every second update
(about half of a tiny update's cost) and channels-last convolutions (about 9% less on this CPU); docs/decisions.md,
"The model"."""
CPU_RUN: dict[str, Any] = dict(
    total_grasps=5_000, max_train_minutes=60.0, workers=2, random_grasps=50, updates_per_step=1.0,
    replay_capacity=30_000, eval_every_grasps=200, eval_episodes=30, final_eval_episodes=100,
    checkpoint_every_grasps=200, log_every_grasps=25, image_every_grasps=500,
)  # fmt: skip
"""The CPU presets' run: an hour of a 2-core CPU, a 30-episode evaluation every 200 grasps, 100 at the end."""
CPU_LOOK_ENV: dict[str, Any] = dict(initial_views="fixed")
CPU_LOOK_MODEL: dict[str, Any] = dict(fixation_critic="map")
"""How a learned fixation looks at CPU scale (ours; the paper presets keep the paper's drawn initial views and tiled
critic): the views at reset from three fixed viewpoints, so that where an object lies in the first images says where
it lies on the tray, and the fixation bandit's critic as a map over the fixation box, whose best point is the
deterministic look (docs/decisions.md, "The fixation critic")."""
CPU_PASSIVE_MODEL: dict[str, Any] = dict(critic_trains_encoder=True, elbo_encoder_scale=0.0033)
"""How the passive row's encoder learns at CPU scale (ours, a departure): its critics train it beside the ELBO, whose
gradient there is scaled to about the critics' size. The paper's, the ELBO alone, keeps nothing of the target at this
scale (its GQN predicts the mean view; five factors changed one at a time did not mend it), and beside the critics at
full weight it drowns theirs 147-316 times (docs/decisions.md, "The passive row's encoder at CPU scale";
``cpu-passive-target-elbo-encoder`` keeps the paper's)."""
CPU_RELABELS = 64
"""Relabelled points per bandit sample of the CPU variants that relabel (``cpu-active-learned-4d-relabel`` and the
reward variants): the map critic reads all of them from one map at little cost."""
TABLE1_CPU_GRASPS = 600
"""The grasp budget of every row of Table 1 at CPU scale (ours): where the recipe's learned-fixation run levels off
on the 2-core CPU (its held-out success at 200, 400 and 600 grasps: 63, 67 and 65% for seed 0; docs/investigations.md,
"Learned fixation"), about 27 minutes of that machine per run with its evaluations at one update per grasp step, about
35 expected at :data:`TABLE1_CPU_UPDATES_PER_STEP`. No time limit, so that every row gets the same grasps whatever
else shares the machine."""
TABLE1_CPU_UPDATES_PER_STEP = 2.0
"""Joint updates per grasp step of the Table 1 rows at CPU scale (ours): at batch 32 they replay 64 transitions per
collected step, as the paper presets' 0.25 updates at batch 256 do. Against one update, on seeds 0, 1 and 2 of
``cpu-active-target``: 40, 42 and 56% held-out at 600 grasps against 37, 24 and 33%, each seed ahead
(docs/decisions.md, "One recipe for Table 1, two scales"; docs/investigations.md, "The 15-step limit")."""
TABLE1_CPU_RUN: dict[str, Any] = {**CPU_RUN, "total_grasps": TABLE1_CPU_GRASPS, "max_train_minutes": 0.0,
                                  "updates_per_step": TABLE1_CPU_UPDATES_PER_STEP}  # fmt: skip
"""The run of a CPU-scale Table 1 preset: :data:`CPU_RUN` with :data:`TABLE1_CPU_GRASPS`, no time limit and
:data:`TABLE1_CPU_UPDATES_PER_STEP`."""
CPU_PREFIX = "cpu-"
"""A paper preset's CPU scale is named ``cpu-PRESET`` (:func:`cpu_scale`)."""
RENAMED_PRESETS = {
    "cpu-learned-4d": "cpu-active-learned-4d",
    "cpu-learned-4d-grasp-reward": "cpu-active-learned-4d",
    "cpu-active-learned-4d-no-relabel": "cpu-active-learned-4d",
}
"""Presets' earlier names, as old runs' config.json files give them: the settings are the same."""


def with_recipe(config: TrainConfig) -> TrainConfig:
    """``config`` with the learning settings of :data:`RECIPE` (and, with a learned fixation, the point chosen
    in the heads' input and :data:`PAPER_BANDIT`)."""
    learned = config.env.learned_fixation
    changes = {**RECIPE, "heads_see_fixation": learned, **(PAPER_BANDIT if learned else {})}
    return dataclasses.replace(config, model=config.model.replace(**changes))


SCALE_FREE_MODEL_FIELDS = ("representation", "heads_see_proprioception", "heads_see_fixation", "heads_see_steps_left",
                           "init_temperature", "n_step", "fixation_reward")  # fmt: skip
"""Model fields a scale keeps: the structure (the ablation switch) and the recipe. The rest are sizes, speed and,
with a learned fixation, how it looks (:data:`CPU_LOOK_MODEL`: the critic; and the variants' relabelled points and
the proximity reward's radius)."""


def trains_passive_encoder_at_cpu_scale(config: TrainConfig) -> bool:
    """Whether :data:`CPU_PASSIVE_MODEL` applies at CPU scale: the passive model with the generator."""
    return is_passive(config.env.env_id) and config.model.representation


def cpu_scale(name: str, config: TrainConfig) -> TrainConfig:
    """The CPU scale of the paper preset ``name`` (``config``): the same env, structure and recipe, with tiny
    networks (:meth:`ModelConfig.tiny`), :data:`CPU_MODEL`, TinyRenderer at 128 and :data:`TABLE1_CPU_RUN`; a
    learned fixation also looks as :data:`CPU_LOOK_ENV` and :data:`CPU_LOOK_MODEL` say, and the passive model with
    the generator trains its encoder as :data:`CPU_PASSIVE_MODEL` says."""
    kept = {field_name: getattr(config.model, field_name) for field_name in SCALE_FREE_MODEL_FIELDS}
    learned = config.env.learned_fixation
    passive = trains_passive_encoder_at_cpu_scale(config)
    env = dataclasses.replace(config.env, **CPU_RENDERING, **(CPU_LOOK_ENV if learned else {}))
    model = ModelConfig.tiny(**kept, **CPU_MODEL, **(CPU_LOOK_MODEL if learned else {}),
                             **(CPU_PASSIVE_MODEL if passive else {}))  # fmt: skip
    return dataclasses.replace(config, preset=CPU_PREFIX + name, env=env, model=model, **TABLE1_CPU_RUN)


PAPER_PRESET_LIST: list[tuple[str, tuple[str, TrainConfig]]] = [
    _preset("active-target", "head camera fixating the env's target, 6-DoF, log-polar, GQN (Table 1: 84%)"),
    _preset("passive-target", "three static cameras, 6-DoF, no log-polar, GQN (Table 1: 76%)",
            env=dict(env_id=PASSIVE_ENV_ID, foveation="resize")),
    _preset("active-target-no-logpolar", "active-target with a plain resize instead of the warp (Table 1: 79%)",
            env=dict(foveation="resize")),
    _preset("active-target-no-representation",
            "active-target without the generator; RL trains the encoder (paper: negligible improvement)",
            model=ModelConfig(representation=False)),
    _preset("passive-target-no-representation",
            "passive-target without the generator; RL trains the encoder (paper: representation learning \"benefited "
            "both passive and active models\")",
            env=dict(env_id=PASSIVE_ENV_ID, foveation="resize"), model=ModelConfig(representation=False)),
    _preset("active-learned-6d", "the full APR: learned fixation, 6-DoF (Table 1: 85% after 70K grasps)",
            env=dict(target="learned")),
    _preset("active-learned-4d", "learned fixation, 4-DoF (Table 1: 85% after 25K grasps)",
            env=dict(target="learned", dof=4), total_grasps=25_000),
]  # fmt: skip
"""The presets of the paper's Table 1 at paper size, each with :data:`RECIPE` (:func:`with_recipe`)."""
PAPER_SCALE = {name: (text, with_recipe(config)) for name, (text, config) in PAPER_PRESET_LIST}
CPU_SCALE = {
    CPU_PREFIX + name: (f"{name} at CPU scale: tiny networks, TinyRenderer at 128, {TABLE1_CPU_GRASPS} grasps; the "
                        "same structure and recipe" + ("; the fixation looks from fixed initial views with a map "
                                                       "critic" if config.env.learned_fixation else "")
                        + ("; the critics train the encoder beside the ELBO, scaled"
                           if trains_passive_encoder_at_cpu_scale(config) else ""),
                        cpu_scale(name, config))
    for name, (_, config) in PAPER_SCALE.items()
}  # fmt: skip
"""Table 1 at CPU scale (``apr reproduce table1 --scale cpu``)."""
_LEARNED_4D_CPU = CPU_SCALE["cpu-active-learned-4d"][1]


def _learned_4d_variant(name: str, description: str, **model: Any) -> tuple[str, tuple[str, TrainConfig]]:
    """``cpu-active-learned-4d-NAME``: the CPU learned-fixation row with one change of its fixation bandit."""
    full = f"cpu-active-learned-4d-{name}"
    config = dataclasses.replace(_LEARNED_4D_CPU, preset=full, model=_LEARNED_4D_CPU.model.replace(**model))
    return full, (f"cpu-active-learned-4d with {description}", config)


CPU_4D_MODEL: dict[str, Any] = dict(n_step=1)
"""``cpu-4d`` (privileged, not a Table 1 row) keeps the one-step targets its figures in the README were measured
with."""

PRESETS: dict[str, tuple[str, TrainConfig]] = {
    **PAPER_SCALE,
    **CPU_SCALE,
    **dict([
        _preset("cpu-4d",
                "PRIVILEGED, breaks the observation rule: its heads are handed the target's true centre (f, the "
                "simulator's answer) beside g; env target, 4-DoF, log-polar, tiny GQN, TinyRenderer at 128. It "
                "reaches a coordinate, hardly looks: its blind numbers are in the README",
                env=dict(dof=4, reveal_target=True, **CPU_RENDERING),
                model=ModelConfig.tiny(heads_see_fixation=True, **{**RECIPE, **CPU_4D_MODEL}, **CPU_MODEL), **CPU_RUN),
        ("cpu-passive-target-elbo-encoder",
         ("cpu-passive-target with the paper's encoder, trained by the ELBO alone (at CPU scale its GQN keeps nothing "
          "of the target: the row's recipe until the critics trained the encoder)",
          dataclasses.replace(CPU_SCALE["cpu-passive-target"][1], preset="cpu-passive-target-elbo-encoder",
                              model=CPU_SCALE["cpu-passive-target"][1].model.replace(critic_trains_encoder=False,
                                                                                     elbo_encoder_scale=1.0)))),
        _learned_4d_variant("relabel", f"hindsight relabelling (ours): besides the point chosen, {CPU_RELABELS} "
                            "uniform points per bandit sample, each with the grasp reward it would have earned, from "
                            "the lift and the tool tip at the grasp's start", fixation_relabels=CPU_RELABELS),
        _learned_4d_variant("bandit-temperature1", "the fixation bandit's entropy temperature starting at the paper's "
                            "1 (Haarnoja et al.) instead of the recipe's 0.01, which the grasp heads keep",
                            fixation_init_temperature=1.0),
        _learned_4d_variant("tip-proximity", "relabelled points that earn, when an object was lifted, 1 - d / 10 cm, "
                             "d to the tool tip at the grasp's start (ours; the robot's knowledge only)",
                             fixation_reward="tip-proximity", fixation_relabels=CPU_RELABELS),
        _learned_4d_variant("proximity", "SHAPING FROM THE SIMULATOR, not a Table 1 row: the bandit regresses, at "
                             "the point chosen and at relabelled points, 1 - d / 10 cm, d from the point to the "
                             "nearest object centre as the simulator reports it",
                             fixation_reward="proximity", fixation_proximity_radius=0.10,
                             fixation_relabels=CPU_RELABELS),
        _preset("smoke", "tiny sizes, a few grasps: the whole pipeline in about a minute on a CPU",
                env=dict(target="learned", dof=4, **CPU_RENDERING, **CPU_LOOK_ENV),
                model=ModelConfig.tiny(gqn_update_every=2, channels_last=True, **CPU_LOOK_MODEL),
                total_grasps=8, workers=2, random_grasps=2, updates_per_step=0.25, replay_capacity=2_000,
                eval_every_grasps=4, eval_episodes=2, checkpoint_every_grasps=4, log_every_grasps=2,
                image_every_grasps=4),
    ]),
}  # fmt: skip


def preset(name: str) -> TrainConfig:
    """A fresh copy of the preset ``name`` (or of the one it was renamed to)."""
    name = RENAMED_PRESETS.get(name, name)
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; the presets are: {', '.join(PRESETS)}")
    return copy.deepcopy(PRESETS[name][1])
