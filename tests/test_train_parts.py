"""The training machinery in isolation: replay, statistics, configuration, presets, workers."""

from __future__ import annotations

import dataclasses
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from apr.reproduce import campaign
from apr.reproduce.paper import PAPER_PRESETS
from apr.train.config import (
    PRESETS,
    SCALE_FREE_MODEL_FIELDS,
    TABLE1_CPU_GRASPS,
    ConfigError,
    TrainConfig,
    preset,
)
from apr.train.evaluation import evaluate_policy, wilson_interval
from apr.train.replay import ReplayBuffer, ReplaySpec
from apr.train.rollout import EVAL_SEED, EVAL_SEED_COUNT, episode_seed
from apr.train.workers import WORKER_NICENESS, EnvWorkers, StepResult, WorkerFailure

SPEC = ReplaySpec(image_shape=(3, 8, 8, 4), viewpoint_shape=(3, 6), gripper_dim=9, grasp_action_dim=4)


def observation(value: int) -> dict[str, np.ndarray]:
    return {
        "images": np.full(SPEC.image_shape, value % 256, np.uint8),
        "viewpoints": np.full(SPEC.viewpoint_shape, value, np.float32),
        "gripper": np.full(9, value, np.float32),
        "fixation": np.full(3, value, np.float32),
    }


def fill_episode(replay: ReplayBuffer, start: int, steps: int) -> None:
    """An episode whose frame k holds the value start + k; transition k's reward is start + k."""
    frame = replay.add_frame(observation(start))
    for k in range(steps):
        next_frame = replay.add_frame(observation(start + k + 1))
        replay.add_transition(frame, np.full(4, start + k, np.float32), start + k, next_frame, k == steps - 1)
        frame = next_frame


def test_replay_transitions_point_at_their_own_frames():
    replay = ReplayBuffer(100, SPEC)
    fill_episode(replay, 0, 5)
    fill_episode(replay, 50, 3)
    batch = replay.sample_grasp(64, np.random.default_rng(0))
    reward = batch["reward"]
    # obs holds the value of the step's start, next_obs the value one later, whatever the episode
    np.testing.assert_array_equal(batch["obs"]["gripper"][:, 0], reward)
    np.testing.assert_array_equal(batch["next_obs"]["gripper"][:, 0], reward + 1)
    np.testing.assert_array_equal(batch["obs"]["images"][:, 0, 0, 0, 0], reward.astype(np.uint8))
    assert set(reward) <= {0, 1, 2, 3, 4, 50, 51, 52}
    assert batch["terminated"][reward == 4].all() and not batch["terminated"][reward == 3].any()
    assert batch["obs"]["images"].dtype == np.uint8


def test_replay_never_samples_overwritten_frames():
    replay = ReplayBuffer(8, SPEC)  # 12 frames, 8 transitions
    for episode in range(10):
        fill_episode(replay, 100 * episode, 3)
    valid = replay.num_transitions()
    assert 0 < valid <= 8
    batch = replay.sample_grasp(256, np.random.default_rng(1))
    np.testing.assert_array_equal(batch["obs"]["gripper"][:, 0], batch["reward"])
    np.testing.assert_array_equal(batch["next_obs"]["gripper"][:, 0], batch["reward"] + 1)
    assert batch["reward"].min() >= 700  # only the newest episodes survive


def test_replay_fixation_samples_and_save_load_round_trip(tmp_path: Path):
    replay = ReplayBuffer(20, SPEC)
    start = replay.add_frame(observation(7))
    replay.add_fixation(start, np.array([0.1, 0.2, 0.3], np.float32), 1.0)
    fill_episode(replay, 10, 4)
    path = tmp_path / "replay.npz"
    replay.save(path)
    restored = ReplayBuffer(20, SPEC)
    restored.load(path)
    for name, array in replay.state().items():
        np.testing.assert_array_equal(restored.state()[name], array, err_msg=name)
    fixation = restored.sample_fixation(4, np.random.default_rng(0))
    np.testing.assert_array_equal(fixation["obs"]["gripper"][:, 0], 7)
    np.testing.assert_allclose(fixation["action"], [[0.1, 0.2, 0.3]] * 4)
    assert not (tmp_path / "replay.npz.tmp").exists()


def test_replay_bytes_needed_matches_what_it_allocates():
    replay = ReplayBuffer(1000, SPEC)
    owners = (vars(replay), vars(replay.frames))
    allocated = sum(value.nbytes for owner in owners for value in owner.values() if isinstance(value, np.ndarray))
    assert abs(allocated - ReplayBuffer.bytes_needed(1000, SPEC)) / allocated < 0.01


def test_wilson_interval_known_values():
    low, high = wilson_interval(84, 100)
    # by hand: centre 0.8274, half-width 0.0716
    assert low == pytest.approx(0.7557, abs=1e-3) and high == pytest.approx(0.8990, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(0, 10)[1] == pytest.approx(0.2775, abs=1e-3)
    assert wilson_interval(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-3)


def test_episode_seeds_are_reproducible_and_distinct():
    """The seeds the runs made so far trained on (recorded values: a change would make them unreproducible)."""
    seeds = [episode_seed(0, k) for k in range(1000)]
    assert seeds[:3] == [2968811710, 3964924996, 3141116543] and seeds[999] == 3570605061
    assert [episode_seed(1, k) for k in range(2)] == [1835504127, 1189033389]
    assert len(set(seeds)) == 1000


def test_episode_seeds_never_fall_among_the_evaluation_seeds_and_an_evaluation_never_runs_past_them():
    """A SeedSequence draw can fall among the evaluation seeds: run seed 1's episode 7625 drew 2,000,028,775, and
    run seed 3's episode 14933 2,000,073,315 (found by search). Such a draw is moved past them, so that no training
    scene is an evaluation scene; an evaluation that would need more seeds than are set aside is refused."""
    evaluation_seeds = range(EVAL_SEED, EVAL_SEED + EVAL_SEED_COUNT)
    for run_seed, episode in ((1, 7625), (3, 14933)):
        assert episode_seed(run_seed, episode) not in evaluation_seeds
    with pytest.raises(ValueError, match="evaluation seeds"):
        evaluate_policy(lambda observations, phase: None, preset("smoke").env, EVAL_SEED_COUNT + 1)


@pytest.mark.parametrize("name", list(PRESETS))
def test_presets_resolve_consistently_and_round_trip(name: str):
    config = preset(name).resolved()
    assert config.model.image_channels == (3 if config.env.learned_fixation else 4)
    assert config.model.grasp_action_dim == config.env.dof
    assert config.workers >= 1 and config.eval_workers >= 1
    assert TrainConfig.from_json(config.to_json()) == config


def test_preset_table_matches_the_paper():
    names = ("relabel", "bandit-temperature1", "tip-proximity", "proximity")
    variants = {f"cpu-active-learned-4d-{name}" for name in names}
    assert set(PRESETS) == {
        *PAPER_PRESETS, *(f"cpu-{name}" for name in PAPER_PRESETS), "cpu-4d", *variants,
        "cpu-passive-target-elbo-encoder", "smoke",
    }  # fmt: skip
    learned = preset("cpu-active-learned-4d")
    assert (learned.model.fixation_reward, learned.model.fixation_relabels) == ("grasp", 0)  # the paper's bandit
    for name in variants:  # each variant is one change of the bandit
        bandit = ("fixation_reward", "fixation_relabels", "fixation_proximity_radius", "fixation_init_temperature")
        changed = {field for field in bandit
                   if getattr(preset(name).model, field) != getattr(learned.model, field)}  # fmt: skip
        assert preset(name).model.replace(**{f: getattr(learned.model, f) for f in changed}) == learned.model, name
        assert preset(name).env == learned.env
    assert preset("cpu-active-learned-4d-relabel").model.fixation_relabels == 64
    assert preset("cpu-active-learned-4d-proximity").model.fixation_relabels == 64
    for earlier in ("cpu-learned-4d", "cpu-learned-4d-grasp-reward", "cpu-active-learned-4d-no-relabel"):
        assert preset(earlier) == learned  # its earlier names
    assert preset("passive-target").env.env_id == "apr/PassiveGrasp-v4"
    assert preset("active-target-no-logpolar").env.foveation == "resize"
    assert preset("active-target-no-representation").model.representation is False
    no_representation = preset("passive-target-no-representation")
    assert no_representation.model.representation is False and no_representation.env == preset("passive-target").env
    assert preset("active-learned-4d").env.dof == 4 and preset("active-learned-4d").env.target == "learned"
    with pytest.raises(ValueError, match="active-target"):
        preset("no-such-preset")


@pytest.mark.parametrize("name", PAPER_PRESETS)
def test_the_cpu_scale_keeps_the_structure_and_the_recipe_of_each_paper_preset(name: str):
    paper, cpu = preset(name), preset(f"cpu-{name}")
    structure = ("env_id", "dof", "target", "foveation", "reach_scale", "reveal_target")
    assert [getattr(cpu.env, field) for field in structure] == [getattr(paper.env, field) for field in structure]
    for field in SCALE_FREE_MODEL_FIELDS:  # the ablation switch and the learning recipe, at both scales
        assert getattr(cpu.model, field) == getattr(paper.model, field), field
    assert paper.model.heads_see_proprioception and paper.model.init_temperature == 0.01  # the recipe
    assert paper.model.n_step == 2 and preset("cpu-4d").model.n_step == 1  # cpu-4d keeps its measured targets
    assert paper.model.heads_see_fixation == paper.env.learned_fixation  # the point chosen, never the target
    assert paper.model.fixation_reward == "grasp"  # the paper's, in every row: never the simulator's objects
    assert paper.model.fixation_relabels == 0  # the chosen point's reward only, as the paper
    assert cpu.model.encoder_channels < paper.model.encoder_channels  # the scale: sizes and budgets
    assert (cpu.total_grasps, cpu.max_train_minutes, cpu.env.render_size) == (TABLE1_CPU_GRASPS, 0.0, 128)
    assert (paper.total_grasps, paper.env.render_size) == (25_000 if name == "active-learned-4d" else 70_000, 256)


def test_cpu_campaign_plans_every_rows_seed_0_first_with_its_seed_count(tmp_path: Path):
    args = campaign.Table1Args(scale="cpu", out=tmp_path)
    plans = campaign.plan_runs(args.preset_names(), args.seed_lists(), tmp_path)
    counts = {name: sum(plan.preset == f"cpu-{name}" for plan in plans) for name in PAPER_PRESETS}
    assert counts == {"active-target": 5, "passive-target": 5, "active-target-no-logpolar": 3,
                      "active-target-no-representation": 3, "passive-target-no-representation": 3,
                      "active-learned-6d": 3, "active-learned-4d": 5}  # fmt: skip
    assert [plan.preset for plan in plans[:7]] == [f"cpu-{name}" for name in PAPER_PRESETS]
    assert [plan.seed for plan in plans] == sorted(plan.seed for plan in plans)
    assert all(plan.config.total_grasps == TABLE1_CPU_GRASPS for plan in plans)
    assert campaign.command_line(args) == f"apr reproduce table1 --scale cpu --out {tmp_path}"


def test_presets_are_independent_copies():
    first = preset("active-target")
    first.env.dof = 4
    assert preset("active-target").env.dof == 6


@pytest.mark.parametrize("render_size", [96, 0, 100])
def test_a_render_size_the_foveations_cannot_sample_is_refused_by_its_flag(render_size: int):
    config = preset("cpu-4d")
    config.env.render_size = render_size
    assert config.problems() == [
        f"--env.render-size must be a positive multiple of 64 (the paper: 256), got {render_size}"
    ]


def test_the_bandit_s_own_temperature_is_checked_like_the_others():
    config = preset("cpu-active-learned-4d-bandit-temperature1")
    assert config.model.fixation_init_temperature == 1.0 and config.problems() == []
    config.model.fixation_init_temperature = 0.0
    assert config.problems() == ["--model.fixation-init-temperature must be above 0, got 0.0"]


def test_fixed_initial_views_reach_the_active_env_and_the_passive_one_refuses_them():
    config = preset("active-learned-4d")
    assert "initial_views" not in config.env.make_kwargs("train")  # drawn: the paper's, and every older run's
    config.env.initial_views = "fixed"
    assert config.env.make_kwargs("train")["initial_views"] == "fixed" and config.problems() == []
    passive = preset("cpu-passive-target")
    passive.env.initial_views = "fixed"
    assert passive.problems() == ["--env.initial-views fixed needs the head: the passive model's cameras are static"]


def test_the_passive_cameras_option_reaches_the_passive_env_and_the_active_one_refuses_it(make_env):
    passive = preset("cpu-passive-target")
    assert "cameras" not in passive.env.make_kwargs("train")  # "": the version's own (v4: "sides")
    passive.env.cameras = "front"
    kwargs = passive.env.make_kwargs("train")
    assert kwargs["cameras"] == "front" and passive.problems() == []
    env = make_env(passive.env.env_id, **{**kwargs, "render_size": 64})
    assert env.unwrapped.camera_layout == "front"
    active = preset("cpu-active-target")
    active.env.cameras = "front"
    assert "cameras" not in active.env.make_kwargs("train")
    assert active.problems() == ["--env.cameras front needs the passive model: apr/ActiveGrasp-v4 has the head"]


def test_a_learned_fixation_looks_with_fixed_views_and_a_map_critic_at_cpu_scale_only():
    for name in ("active-learned-4d", "active-learned-6d"):
        paper, cpu = preset(name), preset(f"cpu-{name}")
        assert (paper.env.initial_views, paper.model.fixation_critic) == ("drawn", "tiled")
        assert (cpu.env.initial_views, cpu.model.fixation_critic) == ("fixed", "map") and cpu.problems() == []
        assert (paper.model.fixation_relabels, cpu.model.fixation_relabels) == (0, 0)
        assert (paper.model.fixation_reward, cpu.model.fixation_reward) == ("grasp", "grasp")
    assert preset("cpu-active-learned-4d-proximity").model.fixation_proximity_radius == 0.10
    target = preset("cpu-active-target")
    assert (target.env.initial_views, target.model.fixation_critic) == ("drawn", "tiled")


def test_the_elbos_encoder_scale_is_refused_without_the_critics_training_the_encoder():
    """Alone the ELBO's gradient is the encoder's only one, and Adam undoes a scale of it: the flag is refused."""
    config = preset("cpu-passive-target-elbo-encoder")
    scaled = dataclasses.replace(config, model=config.model.replace(elbo_encoder_scale=0.0033))
    assert any("--model.elbo-encoder-scale needs --model.critic-trains-encoder" in p for p in scaled.problems())
    both = dataclasses.replace(scaled, model=scaled.model.replace(critic_trains_encoder=True))
    assert both.problems() == []


def test_the_passive_rows_encoder_learns_from_its_critics_too_at_cpu_scale_only():
    """CPU scale: the passive row with the generator trains its encoder with the critics and the ELBO scaled; the paper
    size, the row without the generator, the active rows and the variant keep the paper's encoder."""
    cpu = preset("cpu-passive-target").model
    assert (cpu.critic_trains_encoder, cpu.elbo_encoder_scale) == (True, 0.0033)
    for name in ("passive-target", "cpu-passive-target-elbo-encoder", "cpu-active-target", "cpu-active-learned-4d"):
        model = preset(name).model
        assert (model.critic_trains_encoder, model.elbo_encoder_scale) == (False, 1.0), name
    assert not preset("cpu-passive-target-no-representation").model.critic_trains_encoder
    variant = preset("cpu-passive-target-elbo-encoder")
    assert variant.env == preset("cpu-passive-target").env and variant.problems() == []


def test_a_replay_that_does_not_fit_is_refused(monkeypatch, tmp_path: Path):
    from apr.train import trainer

    monkeypatch.setattr(trainer, "available_memory_bytes", lambda: 10 * 2**20)
    config = dataclasses.replace(preset("smoke"), runs_dir=tmp_path, run_name="too-big", replay_capacity=100_000)
    with pytest.raises(ConfigError, match="replay-capacity"):
        trainer.Trainer(config)


def test_a_trainer_takes_only_the_workers_of_its_backend_and_a_campaign_only_its_executor(tmp_path: Path):
    """The cluster layer plugs in from above: without the Ray factory a Ray run is refused by name, before any
    folder exists; so is a cluster campaign without its executor."""
    from apr.reproduce import campaign
    from apr.train.trainer import Trainer

    config = dataclasses.replace(preset("smoke"), backend="ray", workers=2, runs_dir=tmp_path, run_name="ray")
    with pytest.raises(ConfigError, match="--backend ray: this trainer was given local workers"):
        Trainer(config)

    class RayLike:
        backend = "ray"

    with pytest.raises(ConfigError, match="--backend local: this trainer was given ray workers"):
        Trainer(dataclasses.replace(config, backend="local"), workers=RayLike())
    with pytest.raises(SystemExit, match="--backend slurm needs its campaign executor"):
        campaign.run(campaign.Table1Args(seeds=1, presets=("smoke",), out=tmp_path / "t", backend="slurm", workers=1))
    assert list(tmp_path.iterdir()) == []


def test_a_trainer_records_what_its_workers_render_with_and_warns_when_it_changes(tmp_path: Path, capsys):
    from apr.train.trainer import Trainer

    run = Trainer(dataclasses.replace(preset("smoke"), runs_dir=tmp_path, run_name="renderers"))
    try:
        run._record_renderer(["egl", "egl"])
        assert run.renderer == "egl" and "renderer: egl" in capsys.readouterr().out
        run._record_renderer(["tiny", "tiny"])  # a resume where EGL no longer loads
        assert run.renderer == "mixed" and "trained on egl images until now" in capsys.readouterr().out
        run.renderer = ""  # a checkpoint from before the renderer was recorded
        run._record_renderer(["egl", "tiny"])  # workers that disagree (a Ray cluster, some nodes without EGL)
        out = capsys.readouterr().out
        assert run.renderer == "mixed" and "1 with egl, 1 with tiny" in out and "two kinds of images" in out
    finally:
        run.close()


def test_a_killed_worker_is_replaced_and_the_episode_reported_lost():
    kwargs = {"dof": 4, "target": "env", "renderer": "tiny"}
    with EnvWorkers(1, "apr/ActiveGrasp-v2", kwargs) as workers:
        workers.send_reset(0, 1)
        observation_, _ = workers.receive(0)
        assert observation_["images"].shape == (3, 64, 64, 4)
        os.kill(workers.pid(0), signal.SIGKILL)
        workers.send_step(0, np.zeros(4, np.float32))
        failure = workers.receive(0)
        assert isinstance(failure, WorkerFailure) and "exited" in failure.reason
        assert workers.failures == 1
        workers.send_reset(0, 1)  # the replacement works, and the seed gives the same episode
        again, _ = workers.receive(0)
        np.testing.assert_array_equal(again["images"], observation_["images"])
        workers.send_step(0, np.zeros(4, np.float32))
        assert isinstance(workers.receive(0), StepResult)
        # Replacements, like the first workers, run below the learner's priority (WORKER_NICENESS).
        expected = min(os.getpriority(os.PRIO_PROCESS, 0) + WORKER_NICENESS, 19)
        assert os.getpriority(os.PRIO_PROCESS, workers.pid(0)) == expected


def test_a_trainer_trains_the_learner_it_is_given(tmp_path: Path):
    """docs/extending.md, "A new learner": a subclass of the agent, passed in, is the one the run acts and learns
    with (and a run without one builds the preset's)."""
    from apr.model.agent import APRAgent
    from apr.train.trainer import Trainer

    class LoggingAgent(APRAgent):
        pass

    config = dataclasses.replace(preset("smoke"), runs_dir=tmp_path, run_name="given")
    agent = LoggingAgent(config.resolved().model)
    trainer = Trainer(config, agent=agent)
    try:
        assert trainer.agent is agent
    finally:
        trainer.close()
    default = Trainer(dataclasses.replace(config, run_name="default"))
    try:
        assert type(default.agent) is APRAgent and default.agent.config == config.resolved().model
    finally:
        default.close()
