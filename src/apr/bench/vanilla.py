"""Vanilla deep RL from a well-kept library on the benchmark's own task, beside apr's runs: ``python -m
apr.bench.vanilla`` (the ``baselines`` extra: ``pip install -e ".[baselines]"``, Stable-Baselines3).

For each seed it trains a Stable-Baselines3 agent (SAC with its NatureCNN on every image, ``MultiInputPolicy``; or
DQN on the benchmark's discrete actions) on an apr environment wrapped by :class:`apr.envs.wrappers.ImageObservation`,
counts grasps (episodes) with a callback, and at each of ``--eval-at`` grasps evaluates the deterministic policy on
the held-out split with apr's own evaluation (:func:`apr.train.evaluation.evaluate_policy`: the seeds ``EVAL_SEED +
k``, the same 100 held-out episodes as every apr evaluation). Beside it, on the same episodes: the scripted floor
(straight down from where the gripper starts: what grasping blind at the tray's middle earns) and uniformly random
actions. Each goes to a run folder as apr's trainer writes them (``OUT/PRESET__sSEED/config.json``,
``eval/eval_XXXXXXXX.json``, ``metrics.csv``), so ``apr plot`` and ``apr reproduce``'s readers take them, and the
command writes ``OUT/vanilla_table.md`` (and ``.json``, ``vanilla_curves.png``): held-out success at each grasp
count, and with ``--compare`` apr's runs beside them and the paper's four-times claim (apr at N grasps against the
baseline at 4N).

The tasks: ``benchmark`` is ``apr/BenchmarkGrasp-v4`` (one static camera, any object; 4-DoF by default), and
``passive-target`` is ``apr/PassiveGrasp-v4`` with the environment of the ``cpu-passive-target`` preset (three tray
cameras, 6-DoF, its reach reward), to set beside that preset's runs.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from tqdm import tqdm

from apr.envs.benchmark import BENCHMARK_ENV_ID, register_benchmark_envs
from apr.envs.config import GRASP
from apr.envs.wrappers import DiscreteActions, ImageObservation

Baseline = Literal["sb3-sac", "sb3-dqn", "scripted-floor", "random"]
Task = Literal["benchmark", "passive-target"]
TRAINED: tuple[str, ...] = ("sb3-sac", "sb3-dqn")
"""The baselines that train (the others are evaluated once per seed, on the same episodes)."""
PASSIVE_PRESET = "cpu-passive-target"
"""The apr preset whose environment the ``passive-target`` task takes, and beside whose runs it goes."""
STEPS_PER_GRASP_MAX = GRASP.max_grasp_steps
"""An episode takes at most this many steps: ``total_grasps`` times it bounds a run's steps (its replay's size)."""
METRICS_COLUMNS = ("grasps", "env_steps", "updates", "wall_s", "train_success", "eval_success", "eval_ci_low",
                   "eval_ci_high", "attempt_rate", "train_s", "eval_s")  # fmt: skip
"""``metrics.csv``: apr's trainer's columns that a library agent has (``apr plot`` reads grasps and eval_success)."""
TABLE_NAME = "vanilla_table.md"
RENDERER = "tiny"
"""The runner's environments render with TinyRenderer, as apr's CPU presets do: it holds a training and an evaluation
environment in one process, and pybullet's EGL serves one world per process."""


@dataclass
class SacSettings:
    """Stable-Baselines3 SAC: the library's defaults (its documentation, ``stable_baselines3.SAC``), except where the
    CPU or the run's length forces a change. The RL Zoo (rl-baselines3-zoo ``hyperparams/sac.yml``) tunes SAC on no
    raw-image task (its CarRacing entry runs on a pre-trained autoencoder's features), so the library's defaults are
    the settings of record."""

    learning_rate: float = 3e-4
    """SB3 default."""
    buffer_size: int = 0
    """Transitions kept; 0: every transition of the run (``total_grasps * 15``). SB3's default, 1e6, would keep
    every transition too, but allocates 1e6 image pairs (25 GB for one 64x64 RGB view) up front."""
    learning_starts: int = 100
    """Random-action steps before the first update (SB3 default)."""
    batch_size: int = 64
    """SB3's default is 256; on this 2-core CPU an update with its NatureCNNs (actor, critic and the critic's target,
    each its own) takes about 0.44 s at 256 against 0.19 s at 64 (one torch thread), so 64 (forced by the CPU)."""
    tau: float = 0.005
    gamma: float = 0.99
    train_freq: int = 1
    gradient_steps: int = 1
    """One update per environment step (SB3 defaults)."""
    ent_coef: str = "auto"
    """The entropy temperature learned toward ``target_entropy="auto"`` (-dof), from 1 (SB3 default)."""


@dataclass
class DqnSettings:
    """Stable-Baselines3 DQN on the benchmark's discrete actions (:class:`apr.envs.wrappers.DiscreteActions`): the
    RL Zoo's Atari settings (rl-baselines3-zoo ``hyperparams/dqn.yml``, ``atari``), scaled to the run where the zoo's
    assume 10M frames."""

    learning_rate: float = 1e-4
    buffer_size: int = 0
    """0: every transition of the run (the zoo: 100K, more than a CPU run collects)."""
    learning_starts: int = 1_000
    """The zoo: 100K steps, more than a whole CPU run (2,400 grasps are about 20-30K steps): scaled down."""
    batch_size: int = 32
    target_update_interval: int = 1_000
    train_freq: int = 4
    gradient_steps: int = 1
    exploration_fraction: float = 0.1
    """Of the run's step bound (``total_grasps * 15``): epsilon falls over the first 10% of that."""
    exploration_final_eps: float = 0.01
    gamma: float = 0.99


@dataclass
class VanillaArgs:
    """Train Stable-Baselines3 on an apr task and evaluate it, the scripted floor and random actions on apr's held-out
    episodes; write run folders and a table (with --compare: beside apr's runs, and the four-times claim)."""

    out: Path = Path("runs/vanilla")
    """Results folder: one run folder per baseline and seed, and the table."""
    baselines: tuple[Baseline, ...] = ("sb3-sac", "scripted-floor", "random")
    """What to run; () only rebuilds the table from the runs in OUT (and --compare)."""
    task: Task = "benchmark"
    """benchmark: apr/BenchmarkGrasp-v4 (one camera, any object); passive-target: apr/PassiveGrasp-v4 with the
    environment of the cpu-passive-target preset."""
    dof: Literal[4, 6] | None = None
    """Gripper degrees of freedom; default 4 for benchmark, the preset's (6) for passive-target."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """One run per seed (the scripted floor, deterministic, runs for the first seed only)."""
    eval_at: tuple[int, ...] = (800, 1_600, 2_400)
    """Grasps (training episodes) at which the policy is evaluated; the largest is the run's budget."""
    eval_episodes: int = 100
    """Held-out episodes per evaluation, seeds EVAL_SEED + k (apr's final evaluations: 100)."""
    render_size: int = 0
    """Side of each render before the resize to 64; 0: the benchmark's 128, or the preset's for passive-target."""
    stack_views: bool = False
    """Stack the views' channels into one image (one NatureCNN for all views) instead of SB3's one CNN per image
    entry (its ``MultiInputPolicy`` default): with passive-target's three views an update then costs about a third."""
    down_probability: float = 0.0
    """The chance that a trained baseline's random action moves straight down (dz = -1, the rest uniform): SAC's
    warm-up steps (``--sac.learning-starts``) and DQN's epsilon draws. 0: the library's uniform draws; 0.9: the
    benchmark's own random policy (bullet3's ``ContinuousDownwardBiasPolicy`` for ``KukaDiverseObjectEnv``, its
    ``height_hack_prob``), without which 15 uniform steps rarely bring the gripper down to the grasp height. The run's
    preset then ends in ``-down90``."""
    threads: int = 1
    """torch threads. On this 2-core CPU beside other jobs, 2 threads made an update 4 times slower than 1."""
    sac: SacSettings = field(default_factory=SacSettings)
    dqn: DqnSettings = field(default_factory=DqnSettings)
    compare: tuple[Path, ...] = ()
    """apr run folders (or folders of runs) to set beside the baselines in the table, e.g.
    results/table1-cpu/cpu-active-learned-4d__s0 ..."""
    factor: int = 4
    """The four-times claim: apr at N grasps against a trained baseline at factor * N."""
    claim_presets: tuple[str, ...] = ("cpu-active-learned-4d",)
    """The apr presets among --compare that the four-times claim is tested for (the paper's claim is its full model's:
    learned fixation; at CPU scale on 4-DoF, as the benchmark's task)."""
    rerun: bool = False
    """Train a finished run again (default: a run folder with its final evaluation is kept as it is)."""
    checkpoint_every: int = 200
    """Grasps between checkpoints of a trained baseline (its model, replay and counters, ``RUN/checkpoints/``), and
    at each of ``eval_at``: an interrupted run resumes from its last one. 0: at ``eval_at`` only."""


# ----------------------------------------------------------------------------------------------- environments
def task_env(task: Task, dof: int | None, renderer: str, render_size: int) -> tuple[str, dict[str, Any]]:
    """The environment id and keyword arguments (less ``split``) of ``task``.

    Returns:
        (env_id, kwargs) for ``gymnasium.make(env_id, split=..., **kwargs)``.
    """
    if task == "benchmark":
        register_benchmark_envs()
        kwargs: dict[str, Any] = {"dof": dof or 4, "renderer": renderer}
        if render_size:
            kwargs["render_size"] = render_size
        return BENCHMARK_ENV_ID, kwargs
    from apr.train.config import preset

    env = preset(PASSIVE_PRESET).env
    env = dataclasses.replace(env, renderer=renderer, dof=dof or env.dof, render_size=render_size or env.render_size)
    kwargs = env.make_kwargs("train")
    del kwargs["split"]
    return env.env_id, kwargs


def make_env(env_id: str, kwargs: dict[str, Any], split: str, discrete: bool = False,
             stack_views: bool = False) -> gym.Env:  # fmt: skip
    """``gymnasium.make(env_id, split=split, **kwargs)`` wrapped for a library agent (:class:`ImageObservation`,
    and :class:`DiscreteActions` when ``discrete``)."""
    env: gym.Env = ImageObservation(gym.make(env_id, split=split, **kwargs), stack_views=stack_views)
    return DiscreteActions(env) if discrete else env


class _InProcessPool:
    """apr's worker pool (:class:`apr.train.workers.Workers`) over environments of this process: the evaluation
    steps them in turn, with no process to start (TinyRenderer serves any number of worlds in one process)."""

    def __init__(self, envs: Sequence[gym.Env]) -> None:
        self.envs = list(envs)
        self._answers: list[Any] = [None] * len(self.envs)

    def __len__(self) -> int:
        return len(self.envs)

    def send_reset(self, index: int, seed: int) -> None:
        self._answers[index] = self.envs[index].reset(seed=seed)

    def send_step(self, index: int, action: Any) -> None:
        from apr.train.workers import StepResult

        observation, reward, terminated, truncated, info = self.envs[index].step(action)
        self._answers[index] = StepResult(observation, float(reward), bool(terminated), bool(truncated), info)

    def receive(self, index: int) -> Any:
        answer, self._answers[index] = self._answers[index], None
        return answer

    def pid(self, index: int) -> int | None:
        return None

    def on_this_machine(self) -> int:
        return len(self.envs)

    def describe(self) -> str:
        return f"{len(self.envs)} environment(s) in this process"

    def renderers(self) -> list[str]:
        return [env.unwrapped.renderer_in_use() for env in self.envs]

    def close(self) -> None:
        """The environments stay open: the next evaluation of the run takes them again."""

    def __enter__(self) -> _InProcessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class InProcessWorkers:
    """A :class:`apr.train.workers.WorkersFactory` that hands every evaluation held-out environments of this process,
    built once each as the evaluations need them (one; two for a blind evaluation, which pairs scenes), with its
    ``env_id`` and keyword arguments, not the evaluation's, which name apr's own environments."""

    backend = "local"

    def __init__(self, env_id: str, kwargs: dict[str, Any]) -> None:
        self.env_id, self.kwargs = env_id, kwargs
        self.envs: list[gym.Env] = []

    def __call__(self, num_workers: int, env_id: str, env_kwargs: dict[str, Any], *,
                 evaluation: bool = False) -> _InProcessPool:  # fmt: skip
        while len(self.envs) < max(num_workers, 1):
            self.envs.append(gym.make(self.env_id, split="test", **self.kwargs))
        return _InProcessPool(self.envs[: max(num_workers, 1)])

    def close(self) -> None:
        for env in self.envs:
            env.close()


# ---------------------------------------------------------------------------------------------------- policies
Policy = Callable[[dict[str, np.ndarray], str], np.ndarray]
"""apr's evaluation policy: (batched raw observations, "grasp") -> actions float32 (N, dof)."""


def floor_policy(dof: int) -> Policy:
    """The scripted floor: straight down from wherever the gripper is (it starts over the tray's middle), never
    turning; grasps blind. Actions float32 (N, dof), dz = -1."""

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        actions = np.zeros((len(observations["images"]), dof), np.float32)
        actions[:, 2] = -1.0
        return actions

    return policy


def library_policy(model: Any, wrapper: ImageObservation, table: np.ndarray | None = None) -> Policy:
    """A Stable-Baselines3 model's deterministic action on apr's batched raw observations.

    Args:
        model: an SB3 algorithm whose ``predict`` takes the wrapper's observations.
        wrapper: converts one raw observation (``images`` (V, 64, 64, C), ...) into the model's.
        table: (n, dof) the continuous action of each discrete one (DQN), or None (the model acts in the Box).
    """

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        count = len(observations["images"])
        wrapped = [wrapper.observation({key: value[i] for key, value in observations.items()}) for i in range(count)]
        batch = {key: np.stack([item[key] for item in wrapped]) for key in wrapped[0]}
        actions, _ = model.predict(batch, deterministic=True)
        if table is not None:
            return table[np.asarray(actions, np.int64).reshape(count)]
        return np.asarray(actions, np.float32).reshape(count, -1)

    return policy


def env_policy(model: Any, env: gym.Env) -> Policy:
    """:func:`library_policy` of a model trained on ``env`` (:func:`make_env`'s: with :class:`DiscreteActions`
    outermost for DQN, whose table then maps its actions)."""
    if isinstance(env, DiscreteActions):
        return library_policy(model, env.env, env.table)
    return library_policy(model, env)


# ---------------------------------------------------------------------------------------------------- run folders
def preset_name(baseline: str, task: str, dof: int) -> str:
    """The run's ``preset`` in config.json, e.g. ``scripted-floor-benchmark-4d``; a trained baseline's adds its
    options (:func:`trained_preset`)."""
    return f"{baseline}-{task}-{dof}d"


def trained_preset(baseline: str, args: VanillaArgs, dof: int) -> str:
    """The preset of a trained baseline: :func:`preset_name`, then ``-stacked`` with ``--stack-views`` and ``-downP``
    (percent) with ``--down-probability P``, e.g. ``sb3-sac-benchmark-4d-down90``."""
    down = f"-down{round(100 * args.down_probability)}" if args.down_probability else ""
    return preset_name(baseline, args.task, dof) + ("-stacked" if args.stack_views else "") + down


class DownwardBox(gym.spaces.Box):
    """A continuous action space whose random draws are the benchmark's random policy: uniform, except that with
    ``probability`` dz (the third number) is -1. SB3 draws its warm-up actions from the algorithm's ``action_space``;
    the environment's own space stays uniform."""

    def __init__(self, space: gym.spaces.Box, probability: float) -> None:
        super().__init__(space.low, space.high, space.shape, space.dtype)
        self.probability = probability

    def sample(self, *args: Any, **kwargs: Any) -> np.ndarray:
        action = super().sample(*args, **kwargs)
        if self.np_random.random() < self.probability:
            action[2] = self.low[2]
        return action


class DownwardDiscrete(gym.spaces.Discrete):
    """:class:`DownwardBox` for :class:`apr.envs.wrappers.DiscreteActions`: with ``probability`` the draw is the
    action that moves down one unit (-z), else uniform over all."""

    def __init__(self, space: gym.spaces.Discrete, table: np.ndarray, probability: float) -> None:
        super().__init__(int(space.n), start=int(space.start))
        down = np.zeros(table.shape[1], table.dtype)
        down[2] = -1.0
        self.down = int(np.flatnonzero((table == down).all(axis=1))[0]) + int(space.start)
        self.probability = probability

    def sample(self, *args: Any, **kwargs: Any) -> np.int64:
        if self.np_random.random() < self.probability:
            return np.int64(self.down)
        return super().sample(*args, **kwargs)


def bias_exploration(model: Any, probability: float, seed: int, table: np.ndarray | None) -> None:
    """Make ``model``'s random actions (SAC's warm-up, DQN's epsilon draws) the benchmark's downward-biased ones."""
    if not probability:
        return
    space = model.action_space
    model.action_space = (DownwardBox(space, probability) if table is None
                          else DownwardDiscrete(space, table, probability))  # fmt: skip
    model.action_space.seed(seed)


def run_dir(out: Path, preset: str, seed: int) -> Path:
    return out / f"{preset}__s{seed}"


def is_finished(path: Path) -> bool:
    """The run folder holds its final evaluation."""
    return any(json.loads(item.read_text()).get("final") for item in (path / "eval").glob("eval_*.json"))


def _start_run(path: Path, config: dict) -> None:
    """Write ``config.json`` into a fresh run folder (what an earlier unfinished attempt wrote is removed)."""
    for name in ("eval", "metrics.csv", "model.zip", "config.json", "checkpoints"):
        target = path / name
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()
    (path / "eval").mkdir(parents=True, exist_ok=True)
    (path / "config.json").write_text(json.dumps(config, indent=2) + "\n")


CHECKPOINT_FILES = ("model.zip", "replay.pkl", "state.json")
"""A checkpoint folder ``RUN/checkpoints/gGRASPS`` is whole once ``state.json``, written last, is there."""


def last_checkpoint(path: Path, config: dict) -> Path | None:
    """The newest whole checkpoint of the run at ``path`` if its ``config.json`` is ``config`` (the same run), else
    None."""
    try:
        same = json.loads((path / "config.json").read_text()) == config
    except (OSError, ValueError):
        return None
    whole = sorted(folder for folder in (path / "checkpoints").glob("g*") if (folder / "state.json").exists())
    return whole[-1] if same and whole else None


def save_checkpoint(path: Path, model: Any, state: dict) -> None:
    """Save the model, its replay and ``state`` (grasps, clocks, the recent outcomes) to
    ``RUN/checkpoints/gGRASPS``; then remove the older checkpoints."""
    folder = path / "checkpoints" / f"g{state['grasps']:08d}"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    model.save(folder / "model.zip")
    model.save_replay_buffer(folder / "replay.pkl")
    (folder / "state.json").write_text(json.dumps(state, indent=2) + "\n")
    for older in (path / "checkpoints").glob("g*"):
        if older.name < folder.name:
            shutil.rmtree(older)


def _forget_after(path: Path, grasps: int) -> None:
    """Drop the evaluations and metrics rows written after the checkpoint at ``grasps`` (the run repeats them)."""
    for item in (path / "eval").glob("eval_*.json"):
        if int(item.stem.split("_")[1]) > grasps:
            item.unlink()
    metrics = path / "metrics.csv"
    if metrics.exists():
        with open(metrics, newline="") as file:
            rows = [row for row in csv.DictReader(file) if int(row["grasps"]) <= grasps]
        with open(metrics, "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
            writer.writeheader()
            writer.writerows(rows)


def _write_eval(path: Path, result: dict) -> None:
    (path / "eval" / f"eval_{result['grasps']:08d}.json").write_text(json.dumps(result, indent=2) + "\n")


def _append_metrics(path: Path, row: dict) -> None:
    file_path = path / "metrics.csv"
    new = not file_path.exists()
    with open(file_path, "a", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
        if new:
            writer.writeheader()
        writer.writerow({name: row.get(name, "") for name in METRICS_COLUMNS})


def _evaluate(policy: Policy, workers: InProcessWorkers, env_id: str, dof: int, episodes: int,
              blind: str = "") -> dict:  # fmt: skip
    """apr's held-out evaluation of ``policy`` (seeds EVAL_SEED + k, split "test"), as a dict of
    :class:`apr.train.evaluation.EvalResult`; ``blind``: in the phases it names, the policy sees another scene's
    images (apr's blind baseline, :func:`apr.train.evaluation.evaluate_policy`)."""
    from apr.train.config import EnvConfig
    from apr.train.evaluation import evaluate_policy

    # EnvConfig gives the evaluation the grasp action's size and the phases (env target: grasp steps only); the
    # environment itself is the factory's.
    env = EnvConfig(env_id=env_id, dof=dof, target="env")  # type: ignore[arg-type]
    return evaluate_policy(policy, env, episodes, "test", num_workers=1, workers=workers, blind=blind).to_dict()


def evaluate_blind(path: Path, policy: Policy, workers: InProcessWorkers, env_id: str, dof: int, grasps: int) -> Path:
    """The final policy on the same held-out episodes as its final evaluation, given another scene's images (apr's
    blind baseline: what it does without seeing its own scene), written where apr's runs keep theirs."""
    from apr.reproduce.campaign import BLIND_MODE, write_blind_eval
    from apr.reproduce.runs import read_json

    own = read_json(path / "eval" / f"eval_{grasps:08d}.json")
    started = time.perf_counter()
    result = _evaluate(policy, workers, env_id, dof, int(own["episodes"]), blind=BLIND_MODE)
    return write_blind_eval(path, result, own, grasps, time.perf_counter() - started)


# ----------------------------------------------------------------------------------------------------- the runs
def run_fixed(baseline: str, args: VanillaArgs, seed: int, env_id: str, kwargs: dict, dof: int) -> Path:
    """Evaluate a baseline that does not learn (``scripted-floor``, ``random``) once on the held-out episodes; its
    run folder has one evaluation at 0 grasps, and its ``metrics.csv`` the same success at 0 and at the campaign's
    budget (a flat line beside the learning curves)."""
    from apr.train.rollout import random_policy

    preset = preset_name(baseline, args.task, dof)
    path = run_dir(args.out, preset, seed)
    if is_finished(path) and not args.rerun:
        print(f"{path}: finished, kept")
        return path
    config = {"preset": preset, "seed": seed, "total_grasps": 0, "baseline": baseline, "task": args.task,
              "env_id": env_id, "env_kwargs": kwargs, "dof": dof, "eval_episodes": args.eval_episodes,
              "learns": False}  # fmt: skip
    _start_run(path, config)
    policy = floor_policy(dof) if baseline == "scripted-floor" else random_policy(dof, np.random.default_rng(seed))
    workers = InProcessWorkers(env_id, kwargs)
    try:
        started = time.perf_counter()
        result = _evaluate(policy, workers, env_id, dof, args.eval_episodes)
    finally:
        workers.close()
    result.update(grasps=0, train_s=0.0, updates=0, env_steps=0, final=True)
    _write_eval(path, result)
    eval_s = round(time.perf_counter() - started, 2)
    for grasps in (0, max(args.eval_at)):
        _append_metrics(path, {"grasps": grasps, "eval_success": result["success_rate"], "eval_ci_low":
                               result["ci_low"], "eval_ci_high": result["ci_high"], "eval_s": eval_s})  # fmt: skip
    print(f"{path}: {result['success_rate']:.1%} held-out ({result['successes']}/{result['episodes']}, "
          f"{result['attempts']} attempts)")  # fmt: skip
    return path


def sb3_settings(baseline: str, args: VanillaArgs, total_grasps: int) -> dict[str, Any]:
    """The algorithm's keyword arguments (buffer_size resolved)."""
    settings = dataclasses.asdict(args.sac if baseline == "sb3-sac" else args.dqn)
    if not settings["buffer_size"]:
        settings["buffer_size"] = total_grasps * STEPS_PER_GRASP_MAX
    return settings


def run_trained(baseline: str, args: VanillaArgs, seed: int, env_id: str, kwargs: dict, dof: int) -> Path:
    """Train an SB3 agent for ``max(eval_at)`` grasps, evaluating its deterministic policy at each of ``eval_at``
    grasps; save the final model (``model.zip``). An unfinished run of the same config resumes from its last
    checkpoint (:func:`save_checkpoint`)."""
    try:
        import stable_baselines3 as sb3
        import torch
        from stable_baselines3.common.callbacks import BaseCallback
    except ImportError as error:  # pragma: no cover - depends on the extra
        raise SystemExit(f"{baseline} needs Stable-Baselines3: pip install -e '.[baselines]' ({error})") from error

    eval_at = sorted(set(args.eval_at))
    total_grasps = eval_at[-1]
    preset = trained_preset(baseline, args, dof)
    path = run_dir(args.out, preset, seed)
    discrete = baseline == "sb3-dqn"
    algorithm = sb3.SAC if baseline == "sb3-sac" else sb3.DQN
    if is_finished(path) and not args.rerun:
        from apr.reproduce.campaign import blind_eval_path

        if blind_eval_path(path, total_grasps).exists() or not (path / "model.zip").exists():
            print(f"{path}: finished, kept")
            return path
        env = make_env(env_id, kwargs, "test", discrete, args.stack_views)
        workers = InProcessWorkers(env_id, kwargs)
        try:
            evaluate_blind(path, env_policy(algorithm.load(path / "model.zip", device="cpu"), env), workers, env_id,
                           dof, total_grasps)  # fmt: skip
        finally:
            env.close()
            workers.close()
        return path
    settings = sb3_settings(baseline, args, total_grasps)
    config = {"preset": preset, "seed": seed, "total_grasps": total_grasps, "baseline": baseline, "task": args.task,
              "env_id": env_id, "env_kwargs": kwargs, "dof": dof, "eval_at": eval_at,
              "eval_episodes": args.eval_episodes, "learns": True,
              "library": f"stable-baselines3 {sb3.__version__}", "torch": torch.__version__,
              "algorithm": "SAC" if baseline == "sb3-sac" else "DQN", "policy": "MultiInputPolicy",
              "settings": settings, "threads": args.threads, "stack_views": args.stack_views,
              **({"down_probability": args.down_probability} if args.down_probability else {}),
              "wrappers": ["ImageObservation", *(["DiscreteActions"] if discrete else [])]}  # fmt: skip
    checkpoint = last_checkpoint(path, config)
    if checkpoint is None:
        _start_run(path, config)
    torch.set_num_threads(args.threads)
    env = make_env(env_id, kwargs, "train", discrete, args.stack_views)
    workers = InProcessWorkers(env_id, kwargs)
    state = {"grasps": 0, "wall_s": 0.0, "eval_s": 0.0, "recent": []}
    if checkpoint is None:
        model = algorithm("MultiInputPolicy", env, seed=seed, verbose=0, device="cpu", **settings)
    else:
        state = json.loads((checkpoint / "state.json").read_text())
        model = algorithm.load(checkpoint / "model.zip", env=env, device="cpu")
        model.load_replay_buffer(checkpoint / "replay.pkl")
        # the library saves no random generator: a resumed run is repeatable, not the uninterrupted run's twin
        model.set_random_seed(seed + state["grasps"])
        _forget_after(path, state["grasps"])
        print(f"{path}: resumed at {state['grasps']} grasps ({model.num_timesteps} steps)", flush=True)
    bias_exploration(model, args.down_probability, seed + state["grasps"], env.table if discrete else None)
    policy = env_policy(model, env)
    started = time.perf_counter() - state["wall_s"]
    clock = {"eval_s": state["eval_s"]}
    recent: list[tuple[float, float]] = [tuple(item) for item in state["recent"]]
    every = args.checkpoint_every
    checkpoint_at = {grasps for grasps in [*eval_at, *(range(every, total_grasps, every) if every else [])]
                     if grasps < total_grasps}  # fmt: skip

    class GraspCounter(BaseCallback):
        """Counts grasps (finished episodes); evaluates at each of ``eval_at``; checkpoints; stops at the last."""

        grasps = state["grasps"]

        def _on_step(self) -> bool:
            for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                if not done:
                    continue
                self.grasps += 1
                recent.append((float(info.get("grasp_success", False)), float(info.get("grasp_attempted", False))))
                del recent[:-100]
                bar.update()
                bar.set_postfix(success=f"{np.mean([won for won, _ in recent]):.0%}",
                                attempts=f"{np.mean([tried for _, tried in recent]):.0%}",
                                updates=self.model._n_updates, refresh=False)  # fmt: skip
                if self.grasps in eval_at:
                    evaluate_now(self.grasps, self.num_timesteps, self.model._n_updates)
                if self.grasps in checkpoint_at:
                    wall = time.perf_counter() - started
                    state = {"grasps": self.grasps, "eval_s": clock["eval_s"], "wall_s": wall, "recent": recent}
                    save_checkpoint(path, self.model, state)
            return self.grasps < total_grasps

    def evaluate_now(grasps: int, env_steps: int, updates: int) -> None:
        before = time.perf_counter()
        result = _evaluate(policy, workers, env_id, dof, args.eval_episodes)
        clock["eval_s"] += time.perf_counter() - before
        wall = time.perf_counter() - started
        train_s = wall - clock["eval_s"]
        result.update(grasps=grasps, train_s=round(train_s, 2), updates=int(updates), env_steps=int(env_steps),
                      final=grasps == total_grasps)  # fmt: skip
        _write_eval(path, result)
        window = np.array(recent or [(math.nan, math.nan)])
        _append_metrics(path, {"grasps": grasps, "env_steps": env_steps, "updates": updates, "wall_s": round(wall, 2),
                               "train_success": window[:, 0].mean(), "eval_success": result["success_rate"],
                               "eval_ci_low": result["ci_low"], "eval_ci_high": result["ci_high"],
                               "attempt_rate": window[:, 1].mean(), "train_s": round(train_s, 2),
                               "eval_s": round(clock["eval_s"], 2)})  # fmt: skip
        tqdm.write(f"{path.name}: {grasps} grasps, {env_steps} steps, {updates} updates, {train_s / 60:.1f} train "
                   f"min: {result['success_rate']:.1%} held-out ({result['successes']}/{result['episodes']}, "
                   f"{result['attempts']} attempts)")  # fmt: skip

    bar = tqdm(total=total_grasps, initial=state["grasps"], desc=preset, unit="grasp", dynamic_ncols=True)
    try:
        # the step bound counts from the run's start, so a resumed DQN's exploration schedule is the uninterrupted one's
        steps_left = total_grasps * STEPS_PER_GRASP_MAX - model.num_timesteps
        model.learn(total_timesteps=steps_left, callback=GraspCounter(), reset_num_timesteps=checkpoint is None)
        model.save(path / "model.zip")
        shutil.rmtree(path / "checkpoints", ignore_errors=True)
        bar.close()
        evaluate_blind(path, policy, workers, env_id, dof, total_grasps)
    finally:
        bar.close()
        env.close()
        workers.close()
    return path


def run(args: VanillaArgs) -> Path:
    """Run the baselines over the seeds, then write the table; return the table's path."""
    from apr.commands import checks

    checks.refuse("apr bench vanilla", [
        checks.output_folder("--out", args.out),
        checks.at_least("--eval-episodes", args.eval_episodes, 1),
        checks.at_least("--threads", args.threads, 1),
        checks.at_least("--checkpoint-every", args.checkpoint_every, 0),
        None if 0 <= args.down_probability <= 1 else f"--down-probability must be in [0, 1], got "
                                                      f"{args.down_probability}",
        None if args.eval_at and min(args.eval_at) >= 1 else "--eval-at needs grasp counts of at least 1",
        None if args.seeds else "--seeds needs at least one seed",
        *(None if path.exists() else f"--compare {path} does not exist" for path in args.compare),
    ])  # fmt: skip
    env_id, kwargs = task_env(args.task, args.dof, RENDERER, args.render_size)
    dof = int(kwargs["dof"])
    args.out.mkdir(parents=True, exist_ok=True)
    for baseline in args.baselines:
        seeds = args.seeds[:1] if baseline == "scripted-floor" else args.seeds
        for seed in seeds:
            if baseline in TRAINED:
                run_trained(baseline, args, seed, env_id, kwargs, dof)
            else:
                run_fixed(baseline, args, seed, env_id, kwargs, dof)
    table = write_table(args.out, args.compare, args.factor, args.claim_presets)
    print(f"wrote {table}")
    return table


# ------------------------------------------------------------------------------------------------------- the table
@dataclass
class Row:
    """A preset's runs: each seed's evaluations as {grasps: (successes, episodes)}."""

    preset: str
    learns: bool
    apr: bool = False
    """apr's own runs (``--compare``), beside the baselines."""
    seeds: dict[int, dict[int, tuple[int, int]]] = field(default_factory=dict)
    attempts: dict[int, tuple[int, int]] = field(default_factory=dict)
    """Each seed's final evaluation: (attempts, episodes)."""
    blind: dict[int, tuple[int, int]] = field(default_factory=dict)
    """Each seed's final policy given another scene's images (``eval/blind_both_*.json``): (successes, episodes)."""

    def at(self, grasps: int) -> list[tuple[int, int]]:
        """(successes, episodes) of each seed evaluated at ``grasps``."""
        return [evaluations[grasps] for evaluations in self.seeds.values() if grasps in evaluations]

    @property
    def grasps(self) -> list[int]:
        return sorted({grasps for evaluations in self.seeds.values() for grasps in evaluations})


def read_rows(run_dirs: Sequence[Path], apr: bool = False) -> list[Row]:
    """The run folders' evaluations, grouped by preset (in first-seen order); ``apr``: they are apr's runs."""
    from apr.reproduce.runs import blind_eval_files, eval_results, find_run_dirs, read_config, read_json, run_preset

    rows: dict[str, Row] = {}
    for path in find_run_dirs(run_dirs):
        config = read_config(path)
        results = eval_results(path)
        if not results:
            continue
        name = run_preset(config)
        row = rows.setdefault(name, Row(name, bool(config.get("learns", True)), apr))
        seed = int(config.get("seed", 0))
        row.seeds[seed] = {int(r["grasps"]): (int(r["successes"]), int(r["episodes"])) for r in results}
        row.attempts[seed] = (int(results[-1]["attempts"]), int(results[-1]["episodes"]))
        for blind_file in blind_eval_files(path, int(results[-1]["grasps"]))[:1]:
            blind = read_json(blind_file)
            row.blind[seed] = (int(blind["successes"]), int(blind["episodes"]))
    return list(rows.values())


def _cell(results: list[tuple[int, int]]) -> str:
    """Per-seed mean ± std (ddof=1) and the pooled successes/episodes."""
    if not results:
        return ""
    rates = [successes / episodes for successes, episodes in results]
    spread = f" ± {100 * np.std(rates, ddof=1):.1f}" if len(rates) > 1 else ""
    pooled = f"{sum(s for s, _ in results)}/{sum(e for _, e in results)}"
    return f"{100 * np.mean(rates):.1f}%{spread} ({pooled}, {len(rates)} seed{'s' if len(rates) > 1 else ''})"


def four_times(apr_rows: Sequence[Row], library_rows: Sequence[Row], factor: int) -> list[dict]:
    """The four-times claim at every grasp count N where an apr row was evaluated and a library row at factor * N:
    apr's per-seed mean minus the library's, its two-level bootstrap 95% interval and the verdict
    (:mod:`apr.reproduce.orderings`: "holds" when apr at N is ahead of the library at factor * N)."""
    from apr.reproduce.orderings import MIN_SEEDS, bootstrap_difference, verdict

    found = []
    for ours in apr_rows:
        for theirs in library_rows:
            for grasps in ours.grasps:
                if grasps <= 0 or not theirs.at(factor * grasps):
                    continue
                first = [[item] for item in ours.at(grasps)]
                second = [[item] for item in theirs.at(factor * grasps)]
                difference = bootstrap_difference(first, second)
                seeds = (len(first), len(second))
                found.append({"apr": ours.preset, "apr_grasps": grasps, "library": theirs.preset,
                              "library_grasps": factor * grasps, "seeds": list(seeds),
                              "difference": difference.difference, "ci_low": difference.low,
                              "ci_high": difference.high, "verdict": verdict(difference, seeds),
                              "min_seeds": MIN_SEEDS})  # fmt: skip
    return found


def render_table(rows: Sequence[Row], compared: Sequence[Row], claims: Sequence[dict], factor: int) -> str:
    """The table as markdown: held-out success at each grasp count, the final attempts, and the four-times claim."""
    counts = sorted({grasps for row in [*rows, *compared] for grasps in row.grasps if grasps > 0})
    header = ["run", "learns", *(f"{grasps:,} grasps" for grasps in counts), "not learning (0 grasps)",
              "final policy, blind", "final attempts (ended at the limit)"]  # fmt: skip
    lines = ["# Vanilla baselines: held-out success on apr's evaluation episodes", "",
             "| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]  # fmt: skip
    for row in [*rows, *compared]:
        attempts = sum(a for a, _ in row.attempts.values())
        episodes = sum(e for _, e in row.attempts.values())
        limit = f"{attempts}/{episodes} ({100 * (1 - attempts / episodes):.1f}% at the limit)" if episodes else ""
        name = row.preset + (" (apr)" if row.apr else "")
        cells = [name, "yes" if row.learns else "no", *(_cell(row.at(grasps)) for grasps in counts),
                 _cell(row.at(0)), _cell(list(row.blind.values())), limit]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "- Each cell: the per-seed mean of the held-out success ± its standard deviation (ddof=1), then the pooled "
        "successes/episodes and the seeds evaluated there. Every evaluation runs the deterministic policy on the "
        "held-out episodes of seeds EVAL_SEED + k (apr's), exactly 5 held-out objects each; apr's evaluations before "
        "the last take the first 30 of them.",
        "- *not learning*: the scripted floor (straight down from where the gripper starts) and random actions, "
        "evaluated once per seed on the same episodes.",
        "- *final policy, blind*: each seed's final policy on the same episodes given another scene's images (apr's "
        "blind baseline): what it does without seeing its own scene. A policy that uses its images loses success here.",
    ]
    if claims:
        lines += ["", f"## The four-times claim: apr at N grasps against the library at {factor}N", "",
                  "| apr | N | library | at | seeds | apr minus library | bootstrap 95% CI | verdict |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
        for item in claims:
            few = " (fewer than 3 seeds)" if min(item["seeds"]) < item["min_seeds"] else ""
            lines.append(
                f"| {item['apr']} | {item['apr_grasps']:,} | {item['library']} | {item['library_grasps']:,} | "
                f"{item['seeds'][0]} and {item['seeds'][1]} | {100 * item['difference']:+.1f} pts | "
                f"[{100 * item['ci_low']:+.1f}, {100 * item['ci_high']:+.1f}] | **{item['verdict']}**{few} |"
            )
        lines += [
            "",
            '- "Compared to vanilla deep Q-learning algorithms, our model is at least four times more '
            'sample-efficient" (APR, abstract): it holds at N when apr at N grasps is ahead of the library at '
            f"{factor}N (the interval above 0), is reversed when the library is ahead (below 0), and is not resolved "
            "when the interval holds 0 (then apr at N is about as good as the library at "
            f"{factor}N: at least {factor} times as sample-efficient is not ruled out). Interval: two-level bootstrap "
            "(apr.reproduce.orderings), each seed's evaluation at that count.",
        ]
    return "\n".join(lines) + "\n"


def write_table(out: Path, compare: Sequence[Path] = (), factor: int = 4,
                claim_presets: Sequence[str] = ("cpu-active-learned-4d",)) -> Path:  # fmt: skip
    """Write ``OUT/vanilla_table.md``, ``OUT/vanilla_table.json`` and ``OUT/vanilla_curves.png`` from the run folders
    in ``out`` and, beside them, ``compare`` (apr's runs); the four-times claim for the compared runs of
    ``claim_presets`` against every trained baseline; return the markdown's path."""
    from apr.reproduce.plot import plot_learning_curves

    out.mkdir(parents=True, exist_ok=True)
    has_runs = any(path.is_dir() and (path / "config.json").is_file() for path in out.iterdir())
    rows = read_rows([out]) if has_runs else []
    compared = read_rows(list(compare), apr=True) if compare else []
    library = [row for row in rows if row.learns]
    claims = four_times([row for row in compared if row.preset in claim_presets], library, factor)
    path = out / TABLE_NAME
    path.write_text(render_table(rows, compared, claims, factor))
    numbers = {"rows": [{"preset": row.preset, "learns": row.learns, "apr": row.apr,
                         "seeds": {str(seed): {str(g): list(r) for g, r in evaluations.items()}
                                   for seed, evaluations in row.seeds.items()},
                         "attempts": {str(seed): list(a) for seed, a in row.attempts.items()},
                         "blind": {str(seed): list(b) for seed, b in row.blind.items()}}
                        for row in [*rows, *compared]],
               "four_times": claims, "factor": factor}  # fmt: skip
    path.with_suffix(".json").write_text(json.dumps(numbers, indent=2) + "\n")
    run_dirs = ([out] if has_runs else []) + list(compare)
    if run_dirs:
        figure = plot_learning_curves(run_dirs, title="Held-out success: vanilla baselines beside apr")
        figure.savefig(out / "vanilla_curves.png", dpi=120)
    return path


if __name__ == "__main__":
    import tyro

    run(tyro.cli(VanillaArgs))
