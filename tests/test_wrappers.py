"""The wrappers for library agents (``apr.envs.wrappers``) and the vanilla baselines' runner (``apr.bench.vanilla``):
the wrapped spaces and values against the raw observation, fresh memory, reset and step, Stable-Baselines3's checker
and CNNs, the discrete actions, and a smoke run of the runner (the library tests skip without the ``baselines``
extra)."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from conftest import ACTIVE, PASSIVE
from gymnasium import spaces

from apr.envs.benchmark import BENCHMARK_ENV_ID, register_benchmark_envs
from apr.envs.config import GRASP
from apr.envs.wrappers import DiscreteActions, ImageObservation

register_benchmark_envs()

CASES = [
    pytest.param(BENCHMARK_ENV_ID, {}, 1, 3, id="benchmark"),
    pytest.param(PASSIVE, {"render_size": 64}, 3, 4, id="passive"),
    pytest.param(ACTIVE, {"render_size": 64, "dof": 4, "reveal_target": True}, 3, 4, id="active-env-revealed"),
]


def _raw_and_wrapped(make_env, env_id: str, kwargs: dict, **wrapper) -> tuple[gymnasium.Env, ImageObservation]:
    """Two environments of one id: one raw, one wrapped (each plays a seed the same)."""
    return make_env(env_id, **kwargs), ImageObservation(make_env(env_id, **kwargs), **wrapper)


def _assert_matches(raw: dict, wrapped: dict, views: int, stack: bool = False) -> None:
    """The wrapped observation holds the raw one's values: channel-first images, flat float32 vectors, steps / 15."""
    images = raw["images"].transpose(0, 3, 1, 2)
    if stack:
        np.testing.assert_array_equal(wrapped["images"], images.reshape(-1, *images.shape[2:]))
    for view in range(views if not stack else 0):
        np.testing.assert_array_equal(wrapped[f"image_{view}"], images[view])
        assert wrapped[f"image_{view}"].flags.c_contiguous
    np.testing.assert_array_equal(wrapped["viewpoints"], raw["viewpoints"].ravel())
    np.testing.assert_array_equal(wrapped["gripper"], raw["gripper"])
    assert wrapped["steps_left"].dtype == np.float32
    assert wrapped["steps_left"][0] == np.float32(raw["steps_left"] / GRASP.max_grasp_steps)
    if "fixation" in raw:
        np.testing.assert_array_equal(wrapped["fixation"], raw["fixation"])


@pytest.mark.parametrize(("env_id", "kwargs", "views", "channels"), CASES)
def test_spaces_values_reset_and_step(make_env, env_id: str, kwargs: dict, views: int, channels: int) -> None:
    raw_env, env = _raw_and_wrapped(make_env, env_id, kwargs)
    space = env.observation_space
    for view in range(views):
        assert space[f"image_{view}"] == spaces.Box(0, 255, (channels, 64, 64), np.uint8)
    assert space["viewpoints"] == spaces.Box(-2 * np.pi, 2 * np.pi, (6 * views,), np.float32)
    assert space["gripper"] == spaces.Box(-2.0, 2.0, (9,), np.float32)
    assert space["steps_left"] == spaces.Box(0.0, 1.0, (1,), np.float32)
    assert ("fixation" in space.spaces) == ("reveal_target" in kwargs)
    assert "images" not in space.spaces and env.action_space == raw_env.action_space
    raw, _ = raw_env.reset(seed=4)
    wrapped, _ = env.reset(seed=4)
    assert space.contains(wrapped)
    _assert_matches(raw, wrapped, views)
    action = np.array([0.3, -0.2, -1.0, 0.5, 0.0, 0.0][: env.action_space.shape[0]], np.float32)
    raw, reward_raw, *ends_raw, _ = raw_env.step(action)
    wrapped, reward, *ends, _ = env.step(action)
    assert space.contains(wrapped) and reward == reward_raw and ends == ends_raw
    _assert_matches(raw, wrapped, views)


def test_stacked_views(make_env) -> None:
    raw_env, env = _raw_and_wrapped(make_env, PASSIVE, {"render_size": 64}, stack_views=True)
    assert env.observation_space["images"] == spaces.Box(0, 255, (12, 64, 64), np.uint8)
    raw, _ = raw_env.reset(seed=1)
    wrapped, _ = env.reset(seed=1)
    _assert_matches(raw, wrapped, 3, stack=True)


def test_no_entry_shares_memory(make_env) -> None:
    raw_env = make_env(PASSIVE, render_size=64)
    raw, _ = raw_env.reset(seed=2)
    for stack in (False, True):
        wrapped = ImageObservation(raw_env, stack_views=stack).observation(raw)
        entries = list(wrapped.values())
        for key, value in wrapped.items():
            for source in (raw["images"], raw["viewpoints"], raw["gripper"]):
                assert not np.shares_memory(value, source), key
        for i, first in enumerate(entries):
            for second in entries[i + 1 :]:
                assert not np.shares_memory(first, second)
    before = raw["images"].copy()
    wrapped["images"][...] = 0  # writing into the wrapped observation leaves the environment's untouched
    np.testing.assert_array_equal(raw["images"], before)


def test_a_learned_fixation_is_refused_in_one_line(make_env) -> None:
    env = make_env(ACTIVE, target="learned", render_size=64)
    for wrapper in (ImageObservation, DiscreteActions):
        with pytest.raises(ValueError, match="learned fixation") as caught:
            wrapper(env)
        assert "\n" not in str(caught.value)
    with pytest.raises(ValueError, match="apr's grasping environments"):
        ImageObservation(gymnasium.make("CartPole-v1"))


def test_discrete_actions_are_the_benchmarks(make_env) -> None:
    env = DiscreteActions(ImageObservation(make_env(BENCHMARK_ENV_ID)))
    assert env.action_space == spaces.Discrete(9)
    # stay, -x, +x, -y, +y, -z, +z, -a, +a: KukaDiverseObjectEnv's order with removeHeightHack=True
    expected = [[0, 0, 0, 0], [-1, 0, 0, 0], [1, 0, 0, 0], [0, -1, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0],
                [0, 0, 1, 0], [0, 0, 0, -1], [0, 0, 0, 1]]  # fmt: skip
    np.testing.assert_array_equal(env.table, np.array(expected, np.float32))
    env.reset(seed=0)
    ends = []
    while not ends or not any(ends[-1]):
        _, _, terminated, truncated, info = env.step(np.int64(5))  # -z: the scripted floor
        ends.append((terminated, truncated))
    assert info["grasp_attempted"] and len(ends) == 7
    assert DiscreteActions(ImageObservation(make_env(PASSIVE, render_size=64))).action_space == spaces.Discrete(13)


# --------------------------------------------------------------------------------------------- Stable-Baselines3
@pytest.mark.parametrize(
    ("env_id", "kwargs"),
    [pytest.param(BENCHMARK_ENV_ID, {}, id="benchmark"), pytest.param(PASSIVE, {"render_size": 64}, id="passive")],
)
def test_sb3_check_env_without_warnings_and_one_cnn_per_image(make_env, one_thread, env_id: str, kwargs: dict) -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_checker import check_env
    from stable_baselines3.common.torch_layers import NatureCNN

    env = ImageObservation(make_env(env_id, **kwargs))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env)
    assert not [str(w.message) for w in caught], [str(w.message) for w in caught]
    model = SAC("MultiInputPolicy", env, buffer_size=16, device="cpu")
    extractors = model.policy.actor.features_extractor.extractors
    images = [key for key in env.observation_space.spaces if key.startswith("image")]
    assert images and all(isinstance(extractors[key], NatureCNN) for key in images)
    assert not any(isinstance(extractors[key], NatureCNN) for key in extractors if key not in images)


def _fake_apr_run(folder: Path, seed: int, grasps: int, successes: int) -> None:
    """A run folder as apr's trainer writes one (config.json, one evaluation)."""
    (folder / "eval").mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"preset": "cpu-active-learned-4d", "seed": seed,
                                                    "total_grasps": grasps}))  # fmt: skip
    result = {"grasps": grasps, "episodes": 2, "successes": successes, "success_rate": successes / 2,
              "attempts": 2, "final": True}  # fmt: skip
    (folder / "eval" / f"eval_{grasps:08d}.json").write_text(json.dumps(result))


def test_vanilla_runner_smoke(tmp_path: Path, one_thread) -> None:
    """SAC and DQN for 2 grasps, the scripted floor and random actions, each evaluated on 2 held-out episodes; the run
    folders hold what apr's readers need, and the table sets an apr run beside them (at factor 2, one grasp)."""
    pytest.importorskip("stable_baselines3")
    from apr.bench.vanilla import DqnSettings, SacSettings, VanillaArgs, run
    from apr.reproduce.runs import read_run
    from apr.train.evaluation import EVAL_SEED

    compare = tmp_path / "apr"
    _fake_apr_run(compare / "cpu-active-learned-4d__s0", 0, 1, 1)
    args = VanillaArgs(out=tmp_path / "out", baselines=("sb3-sac", "sb3-dqn", "scripted-floor", "random"),
                       seeds=(0,), eval_at=(1, 2), eval_episodes=2, render_size=64,
                       sac=SacSettings(learning_starts=4, batch_size=4),
                       dqn=DqnSettings(learning_starts=4, batch_size=4, target_update_interval=4),
                       compare=(compare,), factor=2)  # fmt: skip
    table = run(args)
    for preset, grasps in [("sb3-sac-benchmark-4d", [1, 2]), ("sb3-dqn-benchmark-4d", [1, 2]),
                           ("scripted-floor-benchmark-4d", [0]), ("random-benchmark-4d", [0])]:  # fmt: skip
        folder = args.out / f"{preset}__s0"
        summary = read_run(folder)
        assert summary.preset == preset and summary.seed == 0 and summary.finished
        found = sorted(int(path.stem.split("_")[1]) for path in (folder / "eval").glob("eval_*.json"))
        assert found == grasps
        result = summary.final_eval
        assert [outcome["seed"] for outcome in result["outcomes"]] == [EVAL_SEED, EVAL_SEED + 1]
        assert result["split"] == "test" and result["episodes"] == 2 and result["renderer"] == "tiny"
        assert {"successes", "success_rate", "attempts", "ci_low", "ci_high", "train_s", "final"} <= set(result)
        assert (folder / "metrics.csv").read_text().startswith("grasps,")
    assert read_run(args.out / "scripted-floor-benchmark-4d__s0").final_eval["successes"] == 2  # pinned: both lift
    config = json.loads((args.out / "sb3-sac-benchmark-4d__s0" / "config.json").read_text())
    assert config["total_grasps"] == 2 and config["settings"]["buffer_size"] == 2 * GRASP.max_grasp_steps
    assert (args.out / "sb3-sac-benchmark-4d__s0" / "model.zip").is_file()
    for preset in ("sb3-sac-benchmark-4d", "sb3-dqn-benchmark-4d"):  # the final policy, given another scene's images
        blind = json.loads((args.out / f"{preset}__s0" / "eval" / "blind_both_00000002.json").read_text())
        assert blind["blind"] == "both" and blind["episodes"] == 2 and blind["grasps"] == 2
        assert [outcome["seed"] for outcome in blind["outcomes"]] == [EVAL_SEED, EVAL_SEED + 1]
    text = table.read_text()
    assert "cpu-active-learned-4d (apr)" in text and "four-times claim" in text
    claims = json.loads(table.with_suffix(".json").read_text())["four_times"]
    assert {(c["library"], c["apr_grasps"], c["library_grasps"]) for c in claims} == {
        ("sb3-sac-benchmark-4d", 1, 2), ("sb3-dqn-benchmark-4d", 1, 2)}  # fmt: skip
    rows = {row["preset"]: row for row in json.loads(table.with_suffix(".json").read_text())["rows"]}
    assert set(rows["sb3-dqn-benchmark-4d"]["blind"]) == {"0"} and rows["scripted-floor-benchmark-4d"]["blind"] == {}
    assert (args.out / "vanilla_curves.png").is_file()
    assert run(VanillaArgs(out=args.out, baselines=("scripted-floor",), eval_episodes=2, render_size=64)) == table
    # a finished run made before blind evaluations existed gets one from its saved model, and is not trained again
    dqn = args.out / "sb3-dqn-benchmark-4d__s0"
    (dqn / "eval" / "blind_both_00000002.json").unlink()
    before = (dqn / "metrics.csv").read_text()
    run(dataclasses.replace(args, baselines=("sb3-dqn",)))
    assert (dqn / "eval" / "blind_both_00000002.json").is_file() and (dqn / "metrics.csv").read_text() == before


def test_vanilla_run_resumes_from_its_checkpoint(tmp_path: Path, one_thread, monkeypatch, capsys) -> None:
    """A SAC run stopped after its checkpoint at 2 grasps resumes there: the model's steps and replay come back, the
    evaluations after the checkpoint are repeated once, and the finished run drops its checkpoints."""
    pytest.importorskip("stable_baselines3")
    from apr.bench import vanilla

    args = vanilla.VanillaArgs(out=tmp_path, baselines=("sb3-sac",), seeds=(0,), eval_at=(1, 3), eval_episodes=1,
                               render_size=64, checkpoint_every=2, sac=vanilla.SacSettings(learning_starts=4,
                                                                                          batch_size=4))  # fmt: skip
    saved = vanilla.save_checkpoint
    stopped: dict[str, int] = {}

    def save_then_stop(path: Path, model, state: dict) -> None:
        saved(path, model, state)
        if state["grasps"] == 2:
            stopped.update(steps=model.num_timesteps, replay=model.replay_buffer.size())
            raise KeyboardInterrupt

    monkeypatch.setattr(vanilla, "save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        vanilla.run(args)
    folder = tmp_path / "sb3-sac-benchmark-4d__s0"
    assert sorted(path.name for path in (folder / "checkpoints").iterdir()) == ["g00000002"]
    assert sorted(path.name for path in (folder / "checkpoints" / "g00000002").iterdir()) == sorted(
        vanilla.CHECKPOINT_FILES)  # fmt: skip
    (folder / "eval" / "eval_00000003.json").write_text("{}")  # as if written after the checkpoint, then cut off

    loaded: dict[str, int] = {}
    monkeypatch.setattr(vanilla, "save_checkpoint", saved)
    import stable_baselines3

    original = stable_baselines3.SAC.load_replay_buffer

    def spy(self, path, *rest, **kwargs) -> None:
        original(self, path, *rest, **kwargs)
        loaded.update(steps=self.num_timesteps, replay=self.replay_buffer.size())

    monkeypatch.setattr(stable_baselines3.SAC, "load_replay_buffer", spy)
    vanilla.run(args)
    assert loaded == stopped and loaded["steps"] > 0
    assert "resumed at 2 grasps" in capsys.readouterr().out
    found = sorted(path.name for path in (folder / "eval").glob("eval_*.json"))
    assert found == ["eval_00000001.json", "eval_00000003.json"]
    assert json.loads((folder / "eval" / "eval_00000003.json").read_text())["final"] is True
    rows = (folder / "metrics.csv").read_text().splitlines()
    assert [row.split(",")[0] for row in rows] == ["grasps", "1", "3"]
    assert not (folder / "checkpoints").exists() and (folder / "model.zip").is_file()


def test_downward_exploration_draws_the_benchmarks_random_policy(make_env) -> None:
    """With --down-probability 0.9 a SAC warm-up action moves straight down 9 times in 10 (the rest uniform) and DQN's
    random draws pick -z as often; the environment's own space stays uniform; the preset says so."""
    pytest.importorskip("stable_baselines3")
    import stable_baselines3 as sb3

    from apr.bench.vanilla import VanillaArgs, bias_exploration, trained_preset

    env = ImageObservation(make_env(BENCHMARK_ENV_ID, render_size=64))
    model = sb3.SAC("MultiInputPolicy", env, learning_starts=1_000, buffer_size=10, device="cpu", seed=0)
    bias_exploration(model, 0.9, seed=0, table=None)
    warmup = np.array([model._sample_action(learning_starts=1_000)[1][0] for _ in range(2_000)])
    down = warmup[:, 2] == -1.0
    assert 0.87 < down.mean() < 0.93
    assert np.abs(warmup[~down]).max() <= 1.0 and warmup[~down, 0].std() > 0.5  # the rest uniform
    assert not (np.array([env.action_space.sample()[2] for _ in range(200)]) == -1.0).any()

    discrete = DiscreteActions(ImageObservation(make_env(BENCHMARK_ENV_ID, render_size=64)))
    dqn = sb3.DQN("MultiInputPolicy", discrete, buffer_size=10, device="cpu", seed=0)
    bias_exploration(dqn, 0.9, seed=0, table=discrete.table)
    dqn.exploration_rate = 1.0
    observation = dqn.env.reset()  # a VecEnv: one environment, batched
    draws = np.array([dqn.predict(observation)[0][0] for _ in range(1_000)])
    assert dqn.action_space.down == 5 and (discrete.table[5] == [0, 0, -1, 0]).all()
    assert 0.88 < (draws == 5).mean() < 0.94  # 0.9 + 0.1 / 9
    assert trained_preset("sb3-sac", VanillaArgs(down_probability=0.9), 4) == "sb3-sac-benchmark-4d-down90"
    assert trained_preset("sb3-sac", VanillaArgs(), 4) == "sb3-sac-benchmark-4d"
