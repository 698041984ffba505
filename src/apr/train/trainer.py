"""Training APR end to end: env workers, replay, the joint learner, logging, evaluation, checkpoints.

The loop, one round at a time:
  1. every worker runs one episode (glimpse, then grasp steps) with actions from one batched forward pass;
  2. while the workers simulate, the learner makes ``updates_per_step`` joint updates per step collected
     (ELBO + grasp SAC + fixation SAC, from the same replay);
  3. between rounds: metrics.csv and TensorBoard, evaluation on held-out objects, checkpoints.

A run folder holds ``config.json`` (the resolved configuration), ``metrics.csv``, ``eval/``, ``checkpoints/``
and ``tb/`` (TensorBoard), and ``train.lock`` while a process trains in it. ``Trainer.resume(run_dir)``
continues a run exactly where its newest intact checkpoint left it. Nothing is written before the whole
configuration has been checked: a refused start leaves no folder, a refused resume leaves the folder as it was.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from apr.model.agent import APRAgent, FixationBatch, GraspBatch, Observation
from apr.model.pretrained import load_gqn_init
from apr.train.checkpoints import (
    CheckpointError,
    RunLock,
    checkpoint_files,
    fsync_file,
    newest_intact,
    prune,
    read_checkpoint,
    replay_file,
    verify_replay,
    write_atomically,
    write_text_atomically,
)
from apr.train.config import ConfigError, TrainConfig, flag, resume_conflicts
from apr.train.evaluation import evaluate, renderer_request
from apr.train.replay import ReplayBuffer, ReplaySpec
from apr.train.rollout import EpisodeResult, episode_seed, random_policy, run_round
from apr.train.workers import LocalWorkers, StepResult, WorkersFactory, pool_renderer, renderer_counts

METRICS_COLUMNS = (
    "grasps", "env_steps", "updates", "wall_s", "train_success", "eval_success", "eval_ci_low", "eval_ci_high",
    "attempt_rate", "reach_return", "lost_episodes", "grasps_per_min", "train_s", "learner_s", "act_s", "eval_s",
)  # fmt: skip
TIMING_COLUMNS = ("wall_s", "grasps_per_min", "train_s", "learner_s", "act_s", "eval_s")
"""The metrics.csv columns that depend on the wall clock, not on the computation."""
RECENT_EPISODES = 100
"""Training success is the share of the last this many episodes."""


@dataclass
class Progress:
    """Counters of a run; saved in every checkpoint."""

    grasps: int = 0
    """Episodes finished (each ends with a grasp attempt or after 15 steps)."""
    env_steps: int = 0
    updates: int = 0
    episodes_started: int = 0
    lost_episodes: int = 0
    wall_s: float = 0.0
    """Seconds of the run so far, evaluations included."""
    eval_s: float = 0.0
    """Seconds spent evaluating on held-out objects."""
    learner_s: float = 0.0
    """Seconds spent in learner updates (they overlap the workers' simulation)."""
    act_s: float = 0.0
    """Seconds spent choosing actions (the policies' forward passes)."""
    update_debt: float = 0.0
    """Updates owed to the update-to-data ratio and not made yet."""
    recent: list[list[float]] = field(default_factory=list)
    """(success, attempted, reach return) of the last episodes."""
    loss_sums: dict[str, float] = field(default_factory=dict)
    loss_count: int = 0
    loss_counts: dict[str, int] = field(default_factory=dict)
    """Updates that reported each metric since the last log (the ELBO's skip updates with ``gqn_update_every``)."""

    @property
    def train_s(self) -> float:
        """Seconds of training: the run's wall clock less its evaluations."""
        return self.wall_s - self.eval_s

    def out_of_time(self, max_train_minutes: float) -> bool:
        """The training-time budget is spent (never, for a budget of 0)."""
        return max_train_minutes > 0 and self.train_s >= 60 * max_train_minutes


class RunFinished(Exception):
    """A resumed run has already spent its grasp budget; the message says how to extend it."""


def run_dir_for(config: TrainConfig) -> Path:
    """The folder a new run of ``config`` gets."""
    name = config.run_name or f"{config.preset}__s{config.seed}__{time.strftime('%Y%m%d-%H%M%S')}"
    return config.runs_dir / name


def check_new_run_dir(run_dir: Path) -> None:
    """Refuse a folder that exists or cannot be made, before any work."""
    if run_dir.exists():
        raise SystemExit(f"{run_dir} exists: continue it with `apr train --resume {run_dir}`, or choose a --run-name")
    parent = next((p for p in run_dir.parents if p.exists()), Path("."))
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"--runs-dir {run_dir.parent}: cannot create folders in {parent}")


def make_run_dir(config: TrainConfig) -> Path:
    run_dir = run_dir_for(config)
    check_new_run_dir(run_dir)
    run_dir.mkdir(parents=True)
    return run_dir


def available_memory_bytes() -> int | None:
    """MemAvailable from /proc/meminfo (Linux), or None where it cannot be read."""
    try:
        with open("/proc/meminfo") as file:
            for line in file:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


class Trainer:
    """One run. ``Trainer(config).train()`` starts it; ``Trainer.resume(run_dir).train()`` continues it.

    ``Trainer(config, run_dir=FOLDER)`` starts a new run in a given folder (which may exist). The run folder is
    locked (``train.lock``) from then until ``train()`` returns or :meth:`close` is called.

    ``workers`` opens the environment workers (:class:`apr.train.workers.WorkersFactory`; default: local
    processes). It must serve ``config.backend``: a Ray run takes ``workers=apr.cluster.ray_workers.RayWorkers(
    config.ray_address)``, which ``apr train --backend ray`` passes.

    ``agent`` is the learner (default: ``APRAgent(config.resolved().model)``): any object with ``act``, ``update``,
    ``state_dict``, ``load_state_dict`` and ``device`` as :class:`apr.model.agent.APRAgent` has them, e.g. a subclass
    with other losses (docs/extending.md, "A new learner").
    """

    def __init__(self, config: TrainConfig, run_dir: Path | None = None, *, workers: WorkersFactory | None = None,
                 agent: APRAgent | None = None, _resuming: bool = False):  # fmt: skip
        config.check()  # everything is checked and built before a run folder is touched
        self.workers_factory = workers or LocalWorkers()
        if self.workers_factory.backend != config.backend:
            raise ConfigError(
                f"--backend {config.backend}: this trainer was given {self.workers_factory.backend} workers; pass "
                f"the factory of the backend (apr train does: --backend ray opens apr.cluster.ray_workers.RayWorkers)"
            )
        self.config = config = config.resolved()

        spec = ReplaySpec(
            image_shape=(3, config.model.image_size, config.model.image_size, config.env.image_channels),
            viewpoint_shape=(3, config.model.viewpoint_dim), gripper_dim=config.model.gripper_dim,
            grasp_action_dim=config.env.dof, fixation_dim=3 if config.env.observes_fixation else 0,
            steps_left=config.env.observes_steps_left,
        )  # fmt: skip
        need = ReplayBuffer.bytes_needed(config.replay_capacity, spec)
        have = available_memory_bytes()
        print(f"replay: {config.replay_capacity:,} transitions, {need / 2**30:.2f} GiB"
              + (f" of {have / 2**30:.1f} GiB available" if have else ""))  # fmt: skip
        if have is not None and need > 0.8 * have:
            raise ConfigError(
                f"the replay buffer needs {need / 2**30:.1f} GiB but only {have / 2**30:.1f} GiB is available: "
                f"lower --replay-capacity (now {config.replay_capacity:,})"
            )
        try:
            self.replay = ReplayBuffer(config.replay_capacity, spec)
        except MemoryError:
            raise ConfigError(f"the replay buffer ({need / 2**30:.1f} GiB) does not fit in memory: lower "
                              f"--replay-capacity (now {config.replay_capacity:,})") from None  # fmt: skip
        self.agent = agent if agent is not None else APRAgent(config.model)
        load_gqn_init(self.agent)  # a resumed run's checkpoint then replaces them
        if self.agent.device.type == "cpu":  # leave the env workers their cores (docs/decisions.md)
            torch.set_num_threads(max(1, (os.cpu_count() or 1) - config.workers))
        self.rng = np.random.default_rng(config.seed)
        self.warmup_policy = random_policy(config.env.dof, self.rng, config.warmup_down_probability)
        self.progress = Progress()
        self.renderer = ""
        """What the training images so far came from: "egl", "tiny", or "mixed" (the workers did not agree, or a
        resume changed it); "" before the workers first answer. Saved in every checkpoint, and evaluations of its
        policy are checked against it."""
        self._recorder = _Recorder(self.replay, config.model.n_step, config.model.gamma)
        self._stop_requested = False
        self._lock: RunLock | None = None
        if not _resuming:  # a new run: make (or take) its folder, lock it, save the configuration
            self.run_dir = run_dir or make_run_dir(config)
            self.run_dir.mkdir(parents=True, exist_ok=True)
            self._lock = RunLock(self.run_dir)
            write_text_atomically(self.run_dir / "config.json", config.to_json())
            for sub in ("checkpoints", "eval"):
                (self.run_dir / sub).mkdir(exist_ok=True)

    def close(self) -> None:
        """Release the run folder's lock (``train()`` does when it returns)."""
        if self._lock is not None:
            self._lock.release()

    @staticmethod
    def saved_config(run_dir: Path) -> TrainConfig:
        """The resolved configuration a run folder was started with (``config.json``; if that is unreadable, the
        one in its newest intact checkpoint)."""
        path = run_dir / "config.json"
        if not path.exists() and not checkpoint_files(run_dir):
            raise SystemExit(f"{run_dir} is not a run folder (no config.json)")
        try:
            return TrainConfig.from_json(path.read_text())
        except (OSError, ValueError, TypeError, KeyError) as error:
            found = newest_intact(run_dir, with_replay=False, report=lambda line: None)
            if found is None:
                raise SystemExit(f"{path} is unreadable ({error}) and the run has no checkpoint") from None
            print(f"{path} is unreadable ({error}): using the configuration saved in {found[0].name}")
            return TrainConfig.from_json(found[1]["config"])

    @classmethod
    def resume(
        cls,
        run_dir: Path,
        config: TrainConfig | None = None,
        *,
        workers: WorkersFactory | None = None,
        agent: APRAgent | None = None,
    ) -> Trainer:
        """Continue the run in ``run_dir`` from its newest intact checkpoint (``config``: the saved one, or a
        changed copy of it, e.g. with more ``total_grasps``; ``workers`` and ``agent``: as for a new run).

        Nothing in the folder changes until the new configuration has been checked against the checkpoint's:
        a field that cannot change on resume is refused by name (:class:`ConfigError`), a finished run raises
        :class:`RunFinished`, and a folder another process trains in raises ``RunLocked``. A run that crashed
        before its first checkpoint starts again from the beginning.
        """
        run_dir = Path(run_dir)
        saved = cls.saved_config(run_dir)
        trainer = cls(config or saved, workers=workers, agent=agent, _resuming=True)
        config = trainer.config
        lock = RunLock(run_dir)
        try:
            found = newest_intact(run_dir, with_replay=True, map_location=trainer.agent.device)
            if found is None:
                print(f"{run_dir} has no checkpoint yet: starting it from the beginning")
                _clear_logs(run_dir)
            else:
                checkpoint, state = found
                trained_with = TrainConfig.from_json(state["config"]).resolved()
                conflicts = resume_conflicts(trained_with, config)
                if conflicts:
                    raise ConfigError("\n".join(conflicts) + "\nStart a new run for that (apr train --preset ...).")
                grasps = int(state["progress"]["grasps"])
                if grasps >= config.total_grasps:
                    raise RunFinished(
                        f"{run_dir} is finished: {grasps:,} of {config.total_grasps:,} grasps, with its final "
                        f"evaluation (eval/). To train it further, give a larger budget: apr train --resume {run_dir} "
                        f"{flag('total_grasps')} N (N > {grasps:,})"
                    )
                saved_progress = Progress(**state["progress"])
                if saved_progress.out_of_time(config.max_train_minutes):
                    minutes = saved_progress.train_s / 60
                    raise RunFinished(
                        f"{run_dir} is finished: {minutes:.1f} of {config.max_train_minutes:g} minutes of training "
                        f"({grasps:,} grasps), with its final evaluation (eval/). To train it further, give more "
                        f"time: apr train --resume {run_dir} {flag('max_train_minutes')} M (M > {minutes:.1f}), "
                        f"or 0 for no time limit"
                    )
                trainer._load(checkpoint, state)
                _set_aside_newer(checkpoint)
                prune(run_dir / "checkpoints", keep=len(checkpoint_files(run_dir)))  # temporary and orphan files
                _forget_after(run_dir, grasps)
                print(f"resumed {run_dir} at {trainer.progress.grasps} grasps from {checkpoint.name}")
            write_text_atomically(run_dir / "config.json", config.to_json())
            for sub in ("checkpoints", "eval"):
                (run_dir / sub).mkdir(exist_ok=True)
        except BaseException:
            lock.release()
            raise
        trainer._lock, trainer.run_dir = lock, run_dir
        return trainer

    def _load(self, checkpoint: Path, state: dict) -> None:
        """Restore the agent, counters, generator and replay from a checkpoint (already read and verified)."""
        try:
            self.agent.load_state_dict(state["agent"])
        except (RuntimeError, KeyError, ValueError) as error:
            reason = str(error).strip().splitlines()[0]
            raise ConfigError(f"{checkpoint.name} does not fit this configuration: {reason}") from None
        self.progress = Progress(**state["progress"])
        self.renderer = state.get("renderer", "")  # checkpoints written before the renderer was recorded: ""
        self.rng.bit_generator.state = state["rng"]
        try:
            self.replay.load(replay_file(checkpoint, state))
        except (ValueError, IndexError) as error:
            raise ConfigError(f"{state['replay']} does not fit this configuration's replay: {error}") from None

    # ------------------------------------------------------------------------------------------------ loop
    def train(self) -> Path:
        config, progress = self.config, self.progress
        env = config.env
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(self.run_dir / "tb"))
        workers = self.workers = self.workers_factory(config.workers, env.env_id, env.make_kwargs("train"))
        if config.backend != "local":
            print(f"{config.backend}: {workers.describe()}")
            if self.agent.device.type == "cpu":  # only the actors on this machine take our cores
                torch.set_num_threads(max(1, (os.cpu_count() or 1) - workers.on_this_machine()))
        previous_handler = signal.signal(signal.SIGINT, self._request_stop)
        started = time.perf_counter() - progress.wall_s
        bar = tqdm(total=config.total_grasps, initial=progress.grasps, unit="grasp", dynamic_ncols=True)
        try:
            self._record_renderer(workers.renderers())
            while not self._finished() and not self._stop_requested:
                before = progress.grasps
                count = min(len(workers), config.total_grasps - progress.grasps)
                seeds = [episode_seed(config.seed, progress.episodes_started + k) for k in range(count)]
                progress.episodes_started += count
                results = run_round(workers, seeds, self._policy, env.dof, env.learned_fixation,
                                    self._recorder, self._learn)  # fmt: skip
                self._count(results)
                progress.wall_s = time.perf_counter() - started
                bar.update(progress.grasps - before)
                bar.set_postfix(self._postfix(), refresh=False)
                if not self._finished():
                    self._between_rounds(before)
            if self._finished():  # the end: a last evaluation, row and pictures
                self._log(self._evaluate(config.final_eval_episodes or config.eval_episodes, final=True))
                self._log_images()
            self._checkpoint()
            if self._stop_requested:
                print(f"\nstopped at {progress.grasps} grasps; resume with: apr train --resume {self.run_dir}")
        finally:
            signal.signal(signal.SIGINT, previous_handler)
            bar.close()
            workers.close()
            self.writer.close()
            self.close()
        return self.run_dir

    def _record_renderer(self, renderers: list[str]) -> None:
        """Note what the workers render with (``renderers``, one per worker); warn where they disagree, or where a
        resumed run's workers render with another renderer than its earlier training did."""
        now, before = pool_renderer(renderers), self.renderer
        tqdm.write(f"renderer: {now}" + (f" ({renderer_counts(renderers)})" if now == "mixed" else ""))
        if now == "mixed":
            tqdm.write("warning: the environment workers render with different renderers: the policy learns from "
                       "two kinds of images, and no evaluation renderer matches them")  # fmt: skip
        if before and before != now:
            tqdm.write(f"warning: this run trained on {before} images until now, and its workers render with {now} "
                       f"here: recorded as mixed; resume where {before} serves to keep the images alike")  # fmt: skip
            now = "mixed"
        self.renderer = now

    def _finished(self) -> bool:
        """The grasp budget is spent, or the training-time budget (``max_train_minutes``)."""
        config, progress = self.config, self.progress
        return progress.grasps >= config.total_grasps or progress.out_of_time(config.max_train_minutes)

    def _request_stop(self, signum: int, frame: Any) -> None:
        print("\nCtrl-C: finishing this round, then saving a checkpoint (Ctrl-C again to quit at once)")
        self._stop_requested = True
        signal.signal(signal.SIGINT, signal.default_int_handler)

    def _policy(self, observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        """Random actions during warm-up (:func:`random_policy`), then samples of the stochastic policies."""
        if self.progress.grasps < self.config.random_grasps:
            return self.warmup_policy(observations, phase)
        started = time.perf_counter()
        actions = self.agent.act(observations, deterministic=False, policy=phase)
        self.progress.act_s += time.perf_counter() - started
        return actions

    def _learn(self, steps: int) -> None:
        """The learner's share of ``steps`` grasp steps: ``updates_per_step`` joint updates each."""
        config, progress = self.config, self.progress
        progress.update_debt += config.updates_per_step * steps
        warmed_up = progress.grasps >= config.random_grasps
        ready = warmed_up and self.replay.num_transitions() >= config.model.batch_size
        started = time.perf_counter()
        while ready and progress.update_debt >= 1.0:
            metrics = self.agent.update(*self._sample_batches(), step=progress.updates)
            progress.updates += 1
            progress.update_debt -= 1.0
            progress.loss_count += 1
            for name, value in metrics.items():
                progress.loss_sums[name] = progress.loss_sums.get(name, 0.0) + value
                progress.loss_counts[name] = progress.loss_counts.get(name, 0) + 1
        progress.learner_s += time.perf_counter() - started
        if not ready:
            progress.update_debt = 0.0  # no debt builds up during warm-up

    def _sample_batches(self) -> tuple[GraspBatch, FixationBatch | None]:
        device, model = self.agent.device, self.config.model
        grasp = self.replay.sample_grasp(model.batch_size, self.rng)
        grasp_batch = GraspBatch(
            obs=Observation.from_env(grasp["obs"], device),
            action=torch.from_numpy(grasp["action"]).to(device),
            reward=torch.from_numpy(grasp["reward"]).to(device),
            next_obs=Observation.from_env(grasp["next_obs"], device),
            terminated=torch.from_numpy(grasp["terminated"]).to(device),
            steps=torch.from_numpy(grasp["steps"]).to(device) if model.n_step > 1 else None,
        )
        if not self.config.env.learned_fixation or self.replay.num_fixations() == 0:
            return grasp_batch, None
        fixation = self.replay.sample_fixation(model.fixation_batch_size, self.rng)
        return grasp_batch, FixationBatch(
            obs=Observation.from_env(fixation["obs"], device),
            action=torch.from_numpy(fixation["action"]).to(device),
            reward=torch.from_numpy(fixation["reward"]).to(device),
            lifted=torch.from_numpy(fixation["lifted"]).to(device),
            grasp_tip=torch.from_numpy(fixation["grasp_tip"]).to(device),
            object_centres=torch.from_numpy(fixation["object_centres"]).to(device),
        )

    def _count(self, results: list[EpisodeResult]) -> None:
        progress = self.progress
        for result in results:
            if result.lost:
                progress.lost_episodes += 1
                tqdm.write(f"episode with seed {result.seed} lost: {result.lost} (worker restarted)")
                continue
            progress.grasps += 1
            progress.env_steps += result.grasp_steps
            progress.recent.append([float(result.success), float(result.attempted), result.reach_return])
        progress.recent = progress.recent[-RECENT_EPISODES:]

    def _postfix(self) -> dict[str, str]:
        recent = np.array(self.progress.recent or [[0.0, 0.0, 0.0]])
        per_minute = 60 * self.progress.grasps / max(self.progress.train_s, 1e-9)
        return {"success": f"{recent[:, 0].mean():.0%}", "grasps/min": f"{per_minute:.1f}",
                "updates": str(self.progress.updates)}  # fmt: skip

    # ----------------------------------------------------------------------------------- between rounds
    def _between_rounds(self, grasps_before: int) -> None:
        config, grasps = self.config, self.progress.grasps

        def crossed(every: int) -> bool:
            return every > 0 and grasps // every > grasps_before // every

        evaluation = self._evaluate() if crossed(config.eval_every_grasps) else None
        if crossed(config.log_every_grasps) or evaluation is not None:
            self._log(evaluation)
        if crossed(config.image_every_grasps):
            self._log_images()
        if crossed(config.checkpoint_every_grasps):
            self._checkpoint()

    def _evaluate(self, episodes: int | None = None, final: bool = False) -> dict:
        """Evaluate on held-out objects; write ``eval/eval_GRASPS.json`` (``final``: the run's last one)."""
        config = self.config
        started = time.perf_counter()
        env = dataclasses.replace(config.env, renderer=renderer_request(self.renderer, config.env.renderer))
        result = evaluate(self.agent, env, episodes or config.eval_episodes, "test", config.eval_workers,
                          self.workers_factory, self.renderer, on_mismatch="warn").to_dict()  # fmt: skip
        elapsed = time.perf_counter() - started
        self.progress.eval_s += elapsed
        self.progress.wall_s += elapsed  # the round loop recomputes it from the start time; the same sum
        result["grasps"] = self.progress.grasps
        result["train_s"] = round(self.progress.train_s, 2)
        result["updates"] = self.progress.updates
        result["final"] = final
        path = self.run_dir / "eval" / f"eval_{self.progress.grasps:08d}.json"
        path.write_text(json.dumps(result, indent=2))
        interval = f"95% CI {result['ci_low']:.1%}-{result['ci_high']:.1%}"
        gqn = result["gqn"]
        predicted = (f"; GQN's prediction error {gqn['prediction_mse']:.4f}, the mean image's "
                     f"{gqn['mean_image_mse']:.4f}") if gqn else ""  # fmt: skip
        tqdm.write(f"eval at {self.progress.grasps} grasps: {result['success_rate']:.1%} ({interval}, "
                   f"{result['episodes']} episodes, {result['attempts']} attempts{predicted})")  # fmt: skip
        return result

    def _log(self, evaluation: dict | None) -> None:
        progress = self.progress
        recent = np.array(progress.recent or [[math.nan] * 3])
        row = {
            "grasps": progress.grasps, "env_steps": progress.env_steps, "updates": progress.updates,
            "wall_s": round(progress.wall_s, 2), "train_success": recent[:, 0].mean(),
            "eval_success": evaluation["success_rate"] if evaluation else "",
            "eval_ci_low": evaluation["ci_low"] if evaluation else "",
            "eval_ci_high": evaluation["ci_high"] if evaluation else "",
            "attempt_rate": recent[:, 1].mean(), "reach_return": recent[:, 2].mean(),
            "lost_episodes": progress.lost_episodes,
            "grasps_per_min": round(60 * progress.grasps / max(progress.train_s, 1e-9), 2),
            "train_s": round(progress.train_s, 2), "learner_s": round(progress.learner_s, 2),
            "act_s": round(progress.act_s, 2), "eval_s": round(progress.eval_s, 2),
        }  # fmt: skip
        path = self.run_dir / "metrics.csv"
        new = not path.exists()
        with open(path, "a", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
            if new:
                writer.writeheader()
            writer.writerow(row)
        for name, value in row.items():
            if value != "" and name != "grasps":
                self.writer.add_scalar(f"run/{name}", float(value), progress.grasps)
        for name, value in (evaluation or {}).get("gqn", {}).items():  # the representation, against grasps
            self.writer.add_scalar(f"eval/gqn_{name}", float(value), progress.grasps)
        for name, total in progress.loss_sums.items():
            self.writer.add_scalar(name, total / max(progress.loss_counts.get(name, progress.loss_count), 1),
                                   progress.grasps)  # fmt: skip
        progress.loss_sums, progress.loss_count, progress.loss_counts = {}, 0, {}

    def _log_images(self) -> None:
        """The last stored observation's three views and, with a generator, its prediction of view 2."""
        frames = self.replay.frames
        if frames.writes == 0:
            return
        slot = (frames.writes - 1) % frames.capacity
        observation = frames.batch(np.array([slot]))
        views = torch.from_numpy(observation["images"][0][..., :3]).permute(0, 3, 1, 2)
        self.writer.add_images("views", views, self.progress.grasps)
        if self.agent.generator is not None:
            predicted = self.agent.predict_view(observation, query_view=2)[0][..., :3]
            pair = np.stack([observation["images"][0, 2, ..., :3] / 255.0, np.clip(predicted, 0, 1)])
            self.writer.add_images("gqn/truth_vs_prediction", torch.from_numpy(pair).permute(0, 3, 1, 2),
                                   self.progress.grasps)  # fmt: skip

    # ------------------------------------------------------------------------------------------ checkpoints
    def _checkpoint(self) -> Path:
        """Write the replay, then the checkpoint that names it, each atomically; read both back; only then
        delete the pairs beyond ``keep_checkpoints`` (each kept checkpoint keeps its replay)."""
        directory = self.run_dir / "checkpoints"
        grasps = self.progress.grasps
        replay_name = f"replay_{grasps:08d}.npz"
        self.replay.save(directory / replay_name)
        fsync_file(directory / replay_name)
        state = {
            "agent": self.agent.state_dict(),
            "progress": dataclasses.asdict(self.progress),
            "rng": self.rng.bit_generator.state,
            "replay": replay_name,
            "config": self.config.to_json(),
            "renderer": self.renderer,
        }
        path = directory / f"checkpoint_{grasps:08d}.pt"
        write_atomically(path, lambda temporary: torch.save(state, temporary))
        try:
            verify_replay(replay_file(path, read_checkpoint(path)))
        except CheckpointError as error:
            raise RuntimeError(f"the checkpoint just written does not read back ({error}); the older checkpoints "
                               "are kept: free disk space, then resume") from error  # fmt: skip
        prune(directory, self.config.keep_checkpoints)
        return path


class _Recorder:
    """Turns worker answers into replay entries: frames, grasp transitions, and fixation samples.

    With n-step returns (``n_step`` > 1) a step's transition waits until n steps of its episode have followed it,
    or the episode ended, and is then stored from its frame to the frame reached, with the discounted sum of the
    rewards between (Sutton and Barto 2018, section 7.1). A lost episode's waiting steps are dropped with it.
    """

    def __init__(self, replay: ReplayBuffer, n_step: int = 1, gamma: float = 0.99):
        self.replay, self.n_step, self.gamma = replay, n_step, gamma
        self.last_frame: dict[int, tuple[int, int]] = {}
        self.fixation: dict[int, tuple[tuple[int, int], np.ndarray, np.ndarray | None]] = {}
        self.waiting: dict[int, list[tuple[tuple[int, int], np.ndarray, float]]] = {}
        """Per worker: the (frame, action, reward) of steps not yet stored, oldest first."""

    def on_reset(self, worker: int, observation: dict) -> None:
        self.last_frame[worker] = self.replay.add_frame(observation)
        self.fixation.pop(worker, None)
        self.waiting[worker] = []

    def on_fixation(self, worker: int, action: np.ndarray, result: StepResult) -> None:
        self.fixation[worker] = (self.last_frame[worker], action, result.info.get("object_centres"))
        self.last_frame[worker] = self.replay.add_frame(result.observation)

    def on_step(self, worker: int, action: np.ndarray, result: StepResult) -> None:
        next_frame = self.replay.add_frame(result.observation)
        waiting = self.waiting.setdefault(worker, [])
        waiting.append((self.last_frame[worker], action, result.reward))
        self.last_frame[worker] = next_frame
        ended = result.terminated or result.truncated
        while waiting and (ended or len(waiting) == self.n_step):
            frame, first_action, _ = waiting[0]
            reward = sum(self.gamma**k * step_reward for k, (_, _, step_reward) in enumerate(waiting))
            self.replay.add_transition(frame, first_action, reward, next_frame, result.terminated, len(waiting))
            waiting.pop(0)

    def on_end(self, worker: int, result: EpisodeResult) -> None:
        if worker in self.fixation:  # the bandit's grasp reward: the episode's sparse grasp reward only
            frame, action, centres = self.fixation.pop(worker)
            self.replay.add_fixation(frame, action, float(result.success), centres, lifted=result.lifted > 0,
                                     grasp_tip=result.grasp_tip)  # fmt: skip


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The newest checkpoint file of a run, intact or not (:func:`apr.train.checkpoints.newest_intact` checks)."""
    checkpoints = checkpoint_files(run_dir)
    return checkpoints[-1] if checkpoints else None


def _set_aside_newer(checkpoint: Path) -> None:
    """Rename the checkpoints newer than the one a run resumes from (they could not be used) to ``*.skipped``,
    with their replay files: the run trains that stretch again, and they no longer count as kept."""
    for newer in checkpoint_files(checkpoint.parent.parent):
        if newer.name > checkpoint.name:
            replay = newer.parent / f"replay_{newer.stem.removeprefix('checkpoint_')}.npz"
            for path in (newer, replay):
                if path.exists():
                    path.replace(path.with_name(path.name + ".skipped"))
            print(f"set {newer.name} aside as {newer.name}.skipped")


def _forget_after(run_dir: Path, grasps: int) -> None:
    """Drop the metrics rows and evaluations written after the checkpoint (at ``grasps``) a run resumes from."""
    _truncate_metrics(run_dir / "metrics.csv", grasps)
    for evaluation in (run_dir / "eval").glob("eval_*.json"):
        if int(evaluation.stem.removeprefix("eval_")) > grasps:
            evaluation.unlink()


def _clear_logs(run_dir: Path) -> None:
    """Forget what a run logged before its first checkpoint (it starts again from the beginning)."""
    (run_dir / "metrics.csv").unlink(missing_ok=True)
    for stale in (run_dir / "eval").glob("eval_*.json"):
        stale.unlink()


def _truncate_metrics(path: Path, grasps: int) -> None:
    """Drop metrics rows written after the checkpoint a run resumes from."""
    if not path.exists():
        return
    with open(path, newline="") as file:
        rows = list(csv.DictReader(file))
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=METRICS_COLUMNS)
        writer.writeheader()
        writer.writerows(row for row in rows if int(row["grasps"]) <= grasps)
