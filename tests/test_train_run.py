"""Training runs end to end (small): the smoke preset through the CLI, determinism, resume, a killed worker."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from conftest import kill_worker_once_while_stepping

from apr.cli import main
from apr.model.agent import APRAgent
from apr.reproduce.runs import read_metrics, without_timings
from apr.train.config import TrainConfig, preset
from apr.train.rollout import run_round
from apr.train.trainer import METRICS_COLUMNS, Trainer, latest_checkpoint
from apr.train.workers import EnvWorkers


def tiny_run(tmp: Path, name: str, **changes) -> TrainConfig:
    """Four grasps with one worker: warm-up, then the policy acting and the learner updating.

    TinyRenderer: Mesa's llvmpipe (EGL on a CPU) can differ in a pixel between runs (docs/decisions.md).
    """
    base = preset("smoke")
    config = dataclasses.replace(
        base, env=dataclasses.replace(base.env, renderer="tiny"), workers=1, total_grasps=4, random_grasps=1,
        updates_per_step=0.5, eval_every_grasps=0, eval_episodes=1, checkpoint_every_grasps=2, log_every_grasps=1,
        image_every_grasps=0, runs_dir=tmp, run_name=name,
    )  # fmt: skip
    return dataclasses.replace(config, **changes)


def test_smoke_preset_runs_end_to_end(tmp_path: Path):
    main(["train", "--preset", "smoke", "--runs-dir", str(tmp_path), "--run-name", "smoke"])
    run = tmp_path / "smoke"
    rows = read_metrics(run)
    assert list(rows[0]) == list(METRICS_COLUMNS)
    assert int(rows[-1]["grasps"]) == 8 and int(rows[-1]["updates"]) > 0 and int(rows[-1]["env_steps"]) >= 8
    assert rows[-1]["eval_success"] != "" and float(rows[-1]["eval_ci_low"]) <= float(rows[-1]["eval_ci_high"])
    evaluations = sorted((run / "eval").glob("eval_*.json"))
    assert [json.loads(p.read_text())["grasps"] for p in evaluations] == [4, 8]
    assert json.loads(evaluations[-1].read_text())["episodes"] == 2
    assert latest_checkpoint(run).name == "checkpoint_00000008.pt"
    saved = TrainConfig.from_json((run / "config.json").read_text())
    assert saved.preset == "smoke" and saved.model.image_channels == 3 and saved.model.grasp_action_dim == 4
    assert list((run / "tb").iterdir()), "TensorBoard wrote nothing"

    out = tmp_path / "eval.json"
    main(["eval", str(run), "--episodes", "1", "--json", str(out)])
    result = json.loads(out.read_text())
    assert result["episodes"] == 1 and result["split"] == "test" and result["grasps"] == 8


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    return Trainer(tiny_run(tmp_path_factory.mktemp("runs"), "uninterrupted")).train()


def test_a_run_records_its_renderer_and_apr_eval_refuses_images_of_another(uninterrupted: Path, tmp_path: Path,
                                                                            capsys):  # fmt: skip
    """The renderer the workers used is in every checkpoint and evaluation; apr eval checks it before any episode
    (a refusal naming the way out), and an explicit --renderer evaluates anyway, with a warning."""
    import torch

    from apr.train.checkpoints import read_checkpoint

    state = read_checkpoint(latest_checkpoint(uninterrupted))
    assert state["renderer"] == "tiny"
    assert json.loads(sorted((uninterrupted / "eval").glob("eval_*.json"))[-1].read_text())["renderer"] == "tiny"
    claimed = tmp_path / "checkpoint_00000004.pt"
    torch.save({**state, "renderer": "egl"}, claimed)  # as if trained on EGL images
    with pytest.raises(SystemExit, match="trained on egl images, but these environments render with tiny") as refusal:
        main(["eval", str(claimed), "--episodes", "1"])
    assert "--renderer tiny" in str(refusal.value) and "apt-get install" in str(refusal.value)
    out = tmp_path / "eval.json"
    main(["eval", str(claimed), "--episodes", "1", "--renderer", "tiny", "--json", str(out)])
    assert "warning: the policy was trained on egl images" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["episodes"] == 1 and result["renderer"] == "tiny" and result["trained_renderer"] == "egl"


def test_apr_eval_blind_pairs_the_episodes_and_says_where_the_policy_looked(uninterrupted: Path, tmp_path: Path,
                                                                             capsys):  # fmt: skip
    out = tmp_path / "blind.json"
    main(["eval", str(uninterrupted), "--episodes", "1", "--blind", "fixation", "--json", str(out)])
    result = json.loads(out.read_text())
    assert result["blind"] == "fixation" and result["episodes"] == 2  # a pair: each sees the other's scene
    assert [o["seed"] for o in result["outcomes"]] == [2_000_000_000, 2_000_000_001]
    stats = result["fixation"]
    assert stats["scenes"] == 2 and stats["fixed_median_cm"] > 0 and stats["uniform_median_cm"] > 0
    assert all(0 <= o["fixation_object_distance"] < 1 for o in result["outcomes"])
    printed = capsys.readouterr().out
    assert "another scene's images in the fixation phase" in printed and "fixation: median" in printed


def test_same_seed_gives_identical_metrics(uninterrupted: Path, tmp_path: Path):
    again = Trainer(tiny_run(tmp_path, "again")).train()
    rows = read_metrics(uninterrupted)
    assert without_timings(read_metrics(again)) == without_timings(rows)
    assert int(rows[-1]["updates"]) > 0, "the learner never ran: the comparison would prove nothing"


def test_stopping_and_resuming_gives_the_uninterrupted_result(uninterrupted: Path, tmp_path: Path):
    trainer = Trainer(tiny_run(tmp_path, "interrupted"))
    between_rounds = trainer._between_rounds

    def stop_after_two_grasps(grasps_before: int) -> None:  # as Ctrl-C does: finish the round, then stop
        between_rounds(grasps_before)
        if trainer.progress.grasps >= 2:
            trainer._stop_requested = True

    trainer._between_rounds = stop_after_two_grasps
    run = trainer.train()
    assert int(read_metrics(run)[-1]["grasps"]) == 2
    Trainer.resume(run).train()
    assert without_timings(read_metrics(run)) == without_timings(read_metrics(uninterrupted))


def test_a_killed_worker_is_replaced_and_the_run_finishes(tmp_path: Path):
    trainer = Trainer(tiny_run(tmp_path, "killed", total_grasps=3, checkpoint_every_grasps=0))
    killed = kill_worker_once_while_stepping(trainer, grasps=1, worker=0)
    run = trainer.train()
    rows = read_metrics(run)
    assert killed and int(rows[-1]["lost_episodes"]) == 1
    assert int(rows[-1]["grasps"]) == 3  # the lost episode does not count; the run still did its 3


@pytest.mark.slow  # 143 s on the quiet 2-core CPU; the default run has the learner's signs of life on tiny tasks
def test_signs_of_life_the_trained_policy_attempts_grasps_the_untrained_one_never_does(tmp_path: Path):
    """The CPU preset (4-DoF, the environment's target, tiny networks, heads that see g and f, its default
    renderer) for 24 grasps: 8 random, then about 2 joint updates per grasp step. Afterwards the deterministic
    grasp policy, on 8 fixed training episodes, starts a grasp (brings the tool tip down to the grasp height) in
    at least half of them (7/8 and 6/8 measured); the same agent untrained starts none: its mean action barely
    moves the gripper, which starts 0.4 m above the grasp height.

    What it shows: experience flows from the workers through replay into the joint GQN + SAC update, and within a
    few hundred updates the policy goes for the target and attempts the grasp (the precondition of any success:
    the sparse reward is only earned by an attempt). Success itself takes longer: ``apr bench learning``.
    """
    base = preset("cpu-4d")
    config = dataclasses.replace(
        base, total_grasps=24, max_train_minutes=0.0, final_eval_episodes=0,
        random_grasps=8, updates_per_step=2.0, eval_every_grasps=0, eval_episodes=1, checkpoint_every_grasps=0,
        log_every_grasps=8, image_every_grasps=0, replay_capacity=2_000, runs_dir=tmp_path, run_name="signs-of-life",
    )  # fmt: skip
    untrained = APRAgent(config.resolved().model)  # the run's initial weights (same seed)
    trainer = Trainer(config)
    trainer.train()
    policies = {
        "trained": lambda observations, phase: trainer.agent.act(observations, deterministic=True, policy=phase),
        "untrained": lambda observations, phase: untrained.act(observations, deterministic=True, policy=phase),
    }
    seeds = list(range(500, 508))
    attempts = {}
    with EnvWorkers(2, config.env.env_id, config.env.make_kwargs("train")) as workers:
        for name, policy in policies.items():
            rounds = [run_round(workers, seeds[k : k + 2], policy, 4, False) for k in range(0, len(seeds), 2)]
            attempts[name] = sum(result.attempted for results in rounds for result in results)
    print(f"grasp attempts in {len(seeds)} episodes: {attempts}")
    assert attempts["untrained"] == 0
    assert attempts["trained"] >= 4
