"""A preset of the Table 1 recipe trained end to end, tiny, through :class:`Trainer`, with spies on both ends.

The smoke preset that the other end-to-end tests train takes one-step targets, and its heads see neither the clock
nor the gripper pose. Here ``cpu-active-learned-4d`` (the recipe: 2-step returns, heads that see g, the point
chosen and the steps left, a fixation bandit learning the grasp reward of the point chosen) trains for four
grasps on real environments in this process. Its pool records what each environment was asked and answered (the
truth), and a spy on the learner records what each update was given; the tests compare the two:

* every fixation sample is the frame before its fixation, the action chosen, and its episode's grasp reward, lift
  and tool tip at the grasp's start; the bandit regresses the episode's grasp reward at the point chosen only;
* every grasp transition is its episode's 2-step return (cut short at the episode's end), to the frame reached;
* the heads' input holds the gripper pose g, the fixation point and the clock of the very observation it is for;
* training pools play the "train" split, evaluations the "test" one, and training seeds are the run's own, never
  an evaluation seed;
* a run stopped after some updates and resumed ends in the state of the uninterrupted run, bit for bit.

The two warm-up episodes are scripted (:func:`scripted_warmup`): one grasp lifts an object far from the point
looked at (no reward), the other lifts one near it (the reward), and the policy's episodes attempt none; a bandit fed
the lift, the attempt or anything but the grasp reward would show.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
import torch

from apr.envs.config import GRASP, REWARD
from apr.model.agent import PROPRIOCEPTION_ORIGIN, PROPRIOCEPTION_SCALE, FixationBatch, GraspBatch, Observation
from apr.train.config import TrainConfig, preset
from apr.train.evaluation import EVAL_SEED
from apr.train.rollout import Policy, episode_seed
from apr.train.trainer import Trainer
from apr.train.workers import StepResult

PRESET = "cpu-active-learned-4d"
TOTAL_GRASPS = 4
RANDOM_GRASPS = 2
STOP_AT = 3
"""The interrupted run stops after this many grasps: past the warm-up, so that updates happen on both sides."""


# ------------------------------------------------------------------------------------------------ the spies
@dataclass
class Episode:
    """What one environment was asked and answered in one episode (copies: nothing the trainer does touches it)."""

    seed: int
    reset: dict
    reset_info: dict
    steps: list[tuple[Any, StepResult]] = field(default_factory=list)
    """(action sent, answer) of every step, the fixation step first."""

    @property
    def grasp_steps(self) -> list[tuple[np.ndarray, StepResult]]:
        return [(action["grasp"], answer) for action, answer in self.steps[1:]]

    @property
    def fixation_action(self) -> np.ndarray:
        return self.steps[0][0]["fixation"]

    @property
    def end(self) -> dict:
        """The info of the episode's last step."""
        return self.steps[-1][1].info


class SpyPool:
    """Real environments in this process, one per worker, that log every episode (the ``Workers`` protocol)."""

    def __init__(self, size: int, env_id: str, env_kwargs: dict, evaluation: bool):
        self.env_kwargs, self.evaluation = dict(env_kwargs), evaluation
        self.envs = [gymnasium.make(env_id, **env_kwargs) for _ in range(size)]
        self.episodes: list[Episode] = []
        self.current: dict[int, Episode] = {}
        self.answers: dict[int, Any] = {}

    def __len__(self) -> int:
        return len(self.envs)

    def send_reset(self, index: int, seed: int) -> None:
        observation, info = self.envs[index].reset(seed=seed)
        episode = Episode(seed, copy.deepcopy(observation), copy.deepcopy(info))
        self.current[index] = episode
        self.episodes.append(episode)
        self.answers[index] = (observation, info)

    def send_step(self, index: int, action: Any) -> None:
        answer = StepResult(*self.envs[index].step(action))
        self.current[index].steps.append((copy.deepcopy(action), copy.deepcopy(answer)))
        self.answers[index] = answer

    def receive(self, index: int) -> Any:
        return self.answers.pop(index)

    def pid(self, index: int) -> int:
        return os.getpid()

    def on_this_machine(self) -> int:
        return len(self.envs)

    def describe(self) -> str:
        return f"{len(self.envs)} environments in the test's process"

    def renderers(self) -> list[str]:
        return [env.unwrapped.renderer_in_use() for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def __enter__(self) -> SpyPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SpyWorkers:
    """A ``WorkersFactory`` of :class:`SpyPool`; keeps every pool it opened."""

    backend = "local"

    def __init__(self) -> None:
        self.pools: list[SpyPool] = []

    def __call__(self, num_workers: int, env_id: str, env_kwargs: dict, *, evaluation: bool = False) -> SpyPool:
        pool = SpyPool(num_workers, env_id, env_kwargs, evaluation)
        self.pools.append(pool)
        return pool

    def training(self) -> list[Episode]:
        """The training pools' episodes, in the order they started."""
        return [episode for pool in self.pools if not pool.evaluation for episode in pool.episodes]


def scripted_warmup(workers: SpyWorkers) -> Policy:
    """The warm-up's policy. The first episode looks at a corner of the fixation box and descends at once where the
    gripper starts, some 30 cm away (an attempt that earns nothing, whatever it lifts); the others look at the first
    object of the scene (the simulator's answer, a test's device), move the tool tip over the point looked at and
    descend once within 2 cm of it in x and y (a grasp that earns the reward)."""
    low, high = np.array(REWARD.workspace_low), np.array(REWARD.workspace_high)

    def policy(observations: dict[str, np.ndarray], phase: str) -> np.ndarray:
        pool = workers.pools[-1]
        if phase == "fixation":  # every worker of the round looks, in worker order
            centres = [pool.current[w].reset_info["object_centres"][0] for w in sorted(pool.current)]
            looks = np.clip(2 * (np.array(centres) - low) / (high - low) - 1, -1, 1).astype(np.float32)
            return np.ones_like(looks) if len(pool.episodes) == 1 else looks
        error = observations["fixation"][:, :2] - observations["gripper"][:, :2]
        actions = np.zeros((len(error), 4), np.float32)
        actions[:, :2] = np.clip(error / GRASP.position_step, -1, 1)
        actions[:, 2] = np.where(np.linalg.norm(error, axis=1) < 0.02, -1.0, 0.0)
        if len(pool.episodes) == 1:
            actions[:] = [0.0, 0.0, -1.0, 0.0]
        return actions

    return policy


@dataclass
class Update:
    """What one learner update was given, and what the heads and the bandit's critic saw during it."""

    step: int
    grasp: GraspBatch
    fixation: FixationBatch | None
    head_inputs: list[tuple[str, torch.Tensor]] = field(default_factory=list)
    """(module, input r) of every actor and critic call."""
    bandit_targets: list[tuple[torch.Tensor, torch.Tensor]] = field(default_factory=list)


def spy_on_the_learner(trainer: Trainer) -> list[Update]:
    """Record every update's batches, the input of every head module called during it, and the bandit's
    (action, reward) targets. Nothing recorded changes the computation."""
    agent, updates = trainer.agent, []
    update, bandit_targets = agent.update, agent._bandit_targets
    updating = [False]

    def spy_update(grasp: GraspBatch, fixation: FixationBatch | None, step: int) -> dict[str, float]:
        updates.append(Update(step, grasp, fixation))
        updating[0] = True
        try:
            return update(grasp, fixation, step)
        finally:
            updating[0] = False  # acting and evaluation call the heads too: not recorded

    def spy_targets(batch: FixationBatch) -> tuple[torch.Tensor, torch.Tensor]:
        actions, rewards = bandit_targets(batch)
        updates[-1].bandit_targets.append((actions.detach().clone(), rewards.detach().clone()))
        return actions, rewards

    def hook(name: str) -> Callable[[torch.nn.Module, tuple], None]:
        def record(module: torch.nn.Module, inputs: tuple) -> None:
            if updating[0]:
                updates[-1].head_inputs.append((name, inputs[0].detach().clone()))

        return record

    for policy, heads in {"grasp": agent.grasp, "fixation": agent.fixation}.items():
        for part in ("actor", "critic", "critic_target"):
            if getattr(heads, part) is not None:
                getattr(heads, part).register_forward_pre_hook(hook(f"{policy}.{part}"))
    agent.update, agent._bandit_targets = spy_update, spy_targets
    return updates


def recipe_config(runs_dir: Path, name: str) -> TrainConfig:
    """The recipe preset at a tiny budget: one worker, four grasps (two of warm-up), a learner batch of 8, renders of
    64 pixels, a final evaluation of 2 episodes and no other."""
    base = preset(PRESET)
    return dataclasses.replace(
        base, env=dataclasses.replace(base.env, render_size=64),
        model=base.model.replace(batch_size=8, fixation_batch_size=4, gqn_batch_size=4, gqn_fixation_batch_size=2),
        workers=1, eval_workers=1, total_grasps=TOTAL_GRASPS, random_grasps=RANDOM_GRASPS, updates_per_step=0.5,
        replay_capacity=64, eval_every_grasps=0, eval_episodes=2, final_eval_episodes=0, checkpoint_every_grasps=0,
        log_every_grasps=0, image_every_grasps=0, runs_dir=runs_dir, run_name=name,
    )  # fmt: skip


def spied_trainer(config: TrainConfig, run_dir: Path | None = None) -> tuple[Trainer, SpyWorkers, list[Update]]:
    """A new run of ``config`` (or ``run_dir`` resumed) on spied pools, with the scripted warm-up and the learner's
    spy."""
    workers = SpyWorkers()
    trainer = Trainer.resume(run_dir, workers=workers) if run_dir else Trainer(config, workers=workers)
    trainer.warmup_policy = scripted_warmup(workers)
    return trainer, workers, spy_on_the_learner(trainer)


@dataclass
class Run:
    """A finished run: its trainer (its final state), what its pools recorded, and what its learner was given."""

    trainer: Trainer
    workers: SpyWorkers
    updates: list[Update]
    run_dir: Path


@pytest.fixture(scope="module")
def recipe_run(tmp_path_factory) -> Run:
    trainer, workers, updates = spied_trainer(recipe_config(tmp_path_factory.mktemp("runs"), "uninterrupted"))
    run_dir = trainer.train()
    return Run(trainer, workers, updates, run_dir)


# ------------------------------------------------------------------------------------------- the truth
def same(a: np.ndarray | torch.Tensor, b: np.ndarray | torch.Tensor) -> bool:
    """Bitwise equal, dtype and NaN included."""
    a, b = np.asarray(a), np.asarray(b)
    return (
        a.dtype == b.dtype
        and a.shape == b.shape
        and np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes()
    )


def observation_row(obs: Observation, row: int) -> dict[str, np.ndarray]:
    """One sample of a batch, as the environment's observation dict (the entries the model reads)."""
    names = ("images", "viewpoints", "gripper", "fixation", "steps_left")
    fields = zip(names, obs._fields(), strict=True)
    return {name: value[row].cpu().numpy() for name, value in fields if value is not None}


def assert_is_observation(row: dict[str, np.ndarray], truth: dict, where: str) -> None:
    """A replayed observation is the environment's, entry by entry."""
    for name, value in row.items():
        assert np.array_equal(value, np.asarray(truth[name], value.dtype)), f"{where}: {name}"


def head_proprioception(obs: Observation) -> torch.Tensor:
    """What the recipe's heads see beside r (``ModelConfig.heads_see_*``, in the units ``Observation.proprioception``
    documents): the tool tip and f in units of 0.1 m from the middle of the drop area, the gripper's angles, f - tip,
    and the steps left as a fraction of the 15-step limit."""
    origin, tip, fixation = torch.tensor(PROPRIOCEPTION_ORIGIN), obs.gripper[:, :3], obs.fixation
    unit = PROPRIOCEPTION_SCALE
    clock = obs.steps_left[:, None] / GRASP.max_grasp_steps
    return torch.cat([(tip - origin) / unit, obs.gripper[:, 3:], (fixation - origin) / unit, (fixation - tip) / unit,
                      clock], dim=1)  # fmt: skip


# ---------------------------------------------------------------------------------------------- the tests
def test_the_preset_is_the_recipe_and_the_run_learned_from_every_kind_of_grasp(recipe_run: Run):
    """The run exercised what the other tests check: the recipe's settings, updates, and bandit samples of grasps
    that earned the reward, of one that lifted an object far from the point looked at (lifted, no reward) and of
    episodes without an attempt (no grasp tip): a bandit fed the lift, the attempt or a constant would differ."""
    model = recipe_run.trainer.config.model
    assert (model.n_step, model.heads_see_proprioception, model.heads_see_fixation, model.heads_see_steps_left) == (
        2, True, True, True)  # fmt: skip
    assert model.fixation_reward == "grasp" and model.fixation_relabels == 0  # the paper's bandit
    assert len(recipe_run.updates) >= 5 and all(u.fixation is not None for u in recipe_run.updates)
    ends = [(e.end["grasp_attempted"], e.end["objects_lifted"] > 0, e.end["grasp_success"])
            for e in recipe_run.workers.training()]  # fmt: skip
    assert {(True, True, False), (True, True, True), (False, False, False)} <= set(ends), ends
    reward, lifted, tip = (torch.cat([getattr(u.fixation, name) for u in recipe_run.updates])
                           for name in ("reward", "lifted", "grasp_tip"))  # fmt: skip
    assert (reward == 1).any() and ((lifted == 1) & (reward == 0)).any() and tip.isnan().any()


def test_every_fixation_sample_is_its_episode_s_frame_action_reward_lift_and_grasp_tip(recipe_run: Run):
    """Each bandit sample is matched to its episode by the fixation action chosen (a continuous draw, or the
    scripted look at a scene's object): its observation is the frame before the fixation (the reset's), its reward
    the episode's grasp reward, its lift whether the grasp lifted anything, its tool tip where the grasp started
    (NaN without an attempt): what the relabelling variants read."""
    episodes = recipe_run.workers.training()
    assert len(episodes) == TOTAL_GRASPS and sum(bool(e.end["grasp_success"]) for e in episodes) >= 1
    for update in recipe_run.updates:
        batch = update.fixation
        for row in range(len(batch.action)):
            where = f"update {update.step}, fixation sample {row}"
            matches = [e for e in episodes if same(e.fixation_action, batch.action[row])]
            assert len(matches) == 1, f"{where}: no episode chose this fixation action"
            episode = matches[0]
            assert_is_observation(observation_row(batch.obs, row), episode.reset, where)
            assert batch.reward[row].item() == float(episode.end["grasp_success"]), where
            assert batch.lifted[row].item() == float(episode.end["objects_lifted"] > 0), where
            tip = episode.end["tool_tip"] if episode.end["grasp_attempted"] else np.full(3, np.nan, np.float32)
            assert same(batch.grasp_tip[row], tip), where


def test_the_bandit_regresses_the_episode_s_grasp_reward_at_the_point_chosen_only(recipe_run: Run):
    """The critic's targets per sample, the paper's bandit: the chosen action with its episode's grasp reward, and
    nothing else (no relabelled point, nothing of the simulator's); among them a 1 and a lift without the reward (0),
    so a bandit fed the lift or a constant would fail here."""
    rewards_seen = set()
    for update in recipe_run.updates:
        batch = update.fixation
        assert len(update.bandit_targets) == 1, f"update {update.step}"
        actions, rewards = (value.numpy() for value in update.bandit_targets[0])
        assert actions.shape == (len(batch.action), 1, 3) and rewards.shape == (len(batch.action), 1)
        assert np.array_equal(actions[:, 0], batch.action.numpy()) and np.array_equal(rewards[:, 0], batch.reward)
        rewards_seen |= {(float(r), float(lift)) for r, lift in zip(rewards[:, 0], batch.lifted.numpy(), strict=True)}
    assert {(1.0, 1.0), (0.0, 1.0)} <= rewards_seen, rewards_seen


def test_every_grasp_transition_is_its_episode_s_two_step_return(recipe_run: Run):
    """Each grasp transition is matched to its step by the action and the gripper pose before it; the stored step
    count is min(2, steps to the episode's end), the reward r_t + gamma r_t+1 (r_t alone at the end), next_obs the
    frame reached, terminated whether the episode ended there."""
    gamma, n_step = recipe_run.trainer.config.model.gamma, recipe_run.trainer.config.model.n_step
    steps_seen = set()
    for update in recipe_run.updates:
        batch = update.grasp
        assert batch.steps is not None, "the learner was given one-step transitions"
        for row in range(len(batch.action)):
            where = f"update {update.step}, grasp transition {row}"
            found = []
            for episode in recipe_run.workers.training():
                before = [episode.steps[0][1].observation] + [answer.observation for _, answer in episode.grasp_steps]
                for k, (action, _) in enumerate(episode.grasp_steps):
                    if same(action, batch.action[row]) and same(before[k]["gripper"], batch.obs.gripper[row]):
                        found.append((episode, k, before))
            assert len(found) == 1, f"{where}: matched {len(found)} steps"
            episode, k, before = found[0]
            answers = [answer for _, answer in episode.grasp_steps[k : k + n_step]]
            expected_reward = sum(gamma**j * answer.reward for j, answer in enumerate(answers))
            assert batch.steps[row].item() == len(answers), where
            assert batch.reward[row].item() == pytest.approx(expected_reward, rel=1e-6, abs=1e-7), where
            assert batch.terminated[row].item() == float(answers[-1].terminated), where
            assert_is_observation(observation_row(batch.obs, row), before[k], where)
            assert_is_observation(observation_row(batch.next_obs, row), answers[-1].observation, where)
            steps_seen.add(len(answers))
    assert steps_seen == {1, 2}, f"transitions of {steps_seen} steps only"


def test_the_heads_see_the_gripper_pose_the_point_chosen_and_the_clock_of_their_observation(recipe_run: Run):
    """Every actor and critic input of an update is r (16 channels) with the recipe's 16 proprioceptive channels
    tiled over the grid: those of the batch's observations for the critics, of the observations reached for the
    target critics (the actor sees both), of the fixation samples for the fixation heads. The clock takes several
    values over the run, so a head that did not see it would not match."""
    channels = recipe_run.trainer.config.model.representation_channels
    clocks: set[int] = set()
    for update in recipe_run.updates:
        grasp = update.grasp
        expected = {"obs": head_proprioception(grasp.obs), "next_obs": head_proprioception(grasp.next_obs),
                    "fixation": head_proprioception(update.fixation.obs)}  # fmt: skip
        allowed = {"grasp.critic": ["obs"], "grasp.critic_target": ["next_obs"], "grasp.actor": ["obs", "next_obs"],
                   "fixation.critic": ["fixation"], "fixation.actor": ["fixation"]}  # fmt: skip
        seen = set()
        for name, r in update.head_inputs:
            assert r.shape[1] == channels + 16, f"update {update.step}, {name}: {r.shape[1]} channels"
            tiled = r[:, channels:]
            assert torch.equal(tiled, tiled[:, :, :1, :1].expand_as(tiled)), f"{name}: not tiled over the grid"
            matches = [key for key in allowed[name] if torch.allclose(tiled[:, :, 0, 0], expected[key], atol=1e-5)]
            assert matches, f"update {update.step}, {name}: the proprioception is not its observation's"
            seen.update(f"{name}:{key}" for key in matches)
        assert {"grasp.critic:obs", "grasp.critic_target:next_obs", "fixation.critic:fixation"} <= seen, seen
        clocks.update(update.grasp.obs.steps_left.int().tolist())
    assert len(clocks) >= 3, f"the clock took the values {clocks} only"


def test_training_plays_the_train_split_on_the_run_s_seeds_and_evaluation_the_test_split_on_its_own(
    recipe_run: Run,
):
    """The pools the trainer opened: training on "train" with episode k's seed ``episode_seed(seed, k)`` (never an
    evaluation seed: ``test_train_parts.py``), the final evaluation on "test" (held-out objects) with EVAL_SEED + k."""
    pools = recipe_run.workers.pools
    assert [(pool.evaluation, pool.env_kwargs["split"]) for pool in pools] == [(False, "train"), (True, "test")]
    training, evaluation = ([e.seed for e in pool.episodes] for pool in pools)
    assert training == [episode_seed(recipe_run.trainer.config.seed, k) for k in range(TOTAL_GRASPS)]
    assert evaluation == [EVAL_SEED, EVAL_SEED + 1]
    result = json.loads(next((recipe_run.run_dir / "eval").glob("eval_*.json")).read_text())
    assert result["split"] == "test" and [o["seed"] for o in result["outcomes"]] == evaluation


def test_a_run_stopped_after_some_updates_and_resumed_ends_in_the_uninterrupted_run_s_state(
    recipe_run: Run, tmp_path: Path
):
    """Stopped as Ctrl-C stops it (the round finished, a checkpoint written) after 3 grasps, then resumed: the
    networks, optimisers, every random generator (the learner's, the acting one, the trainer's), the replay's
    arrays, the counters and the final evaluation's outcomes are those of the uninterrupted run, bitwise; and the
    learner updated on both sides of the stop."""
    trainer, _, _ = spied_trainer(recipe_config(tmp_path, "interrupted"))
    between_rounds = trainer._between_rounds

    def stop(grasps_before: int) -> None:
        between_rounds(grasps_before)
        if trainer.progress.grasps >= STOP_AT:
            trainer._stop_requested = True

    trainer._between_rounds = stop
    run_dir = trainer.train()
    updates_at_stop = trainer.progress.updates
    assert trainer.progress.grasps == STOP_AT and updates_at_stop > 0
    resumed, _, _ = spied_trainer(recipe_config(tmp_path, "interrupted"), run_dir)
    assert resumed.progress.updates == updates_at_stop
    resumed.train()
    uninterrupted = recipe_run.trainer
    assert resumed.progress.updates > updates_at_stop and resumed.progress.grasps == TOTAL_GRASPS

    mine, theirs = resumed.agent.state_dict(), uninterrupted.agent.state_dict()
    for name, tensor in theirs["networks"].items():
        assert torch.equal(mine["networks"][name], tensor), name
    for name in ("rng", "act_rng"):
        assert torch.equal(mine[name], theirs[name]), name
    for name, optimizer in theirs["optimizers"].items():
        assert optimizer["param_groups"] == mine["optimizers"][name]["param_groups"], name
        assert optimizer["state"].keys() == mine["optimizers"][name]["state"].keys(), name
        for index, state in optimizer["state"].items():
            for key, value in state.items():
                assert torch.equal(mine["optimizers"][name]["state"][index][key], value), (name, index, key)
    assert resumed.rng.bit_generator.state == uninterrupted.rng.bit_generator.state
    replay, expected = resumed.replay.state(), uninterrupted.replay.state()
    assert replay.keys() == expected.keys()
    for name, array in expected.items():
        assert same(replay[name], array), f"replay {name}"
    timings = {"wall_s", "eval_s", "learner_s", "act_s"}
    progress = {k: v for k, v in dataclasses.asdict(resumed.progress).items() if k not in timings}
    assert progress == {k: v for k, v in dataclasses.asdict(uninterrupted.progress).items() if k not in timings}

    def final_evaluation(run: Path) -> dict:
        result = json.loads((run / "eval" / f"eval_{TOTAL_GRASPS:08d}.json").read_text())
        return {k: v for k, v in result.items() if k != "train_s"}

    assert final_evaluation(run_dir) == final_evaluation(recipe_run.run_dir)
