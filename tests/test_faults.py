"""Fault injection: what survives damaged checkpoints, a killed writer, a second process, refused starts and
resumes, bad flags, vectorised environments, and pybullet's console chatter.

Run folders here are made without simulating: a trainer's replay gets a few blank frames and checkpoints are
written directly, so the run tests cost well under a second each once the module's run exists.
"""

from __future__ import annotations

import dataclasses
import gc
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_recycling_replays_a_seed

from apr.cli import main
from apr.envs import rendering
from apr.train import checkpoints, trainer
from apr.train.checkpoints import CheckpointError, RunLock, RunLocked
from apr.train.config import PRESETS, TrainConfig, preset
from apr.train.trainer import RunFinished, Trainer

SRC = Path(__file__).resolve().parents[1] / "src"


def tiny_config(runs_dir: Path, name: str, **changes) -> TrainConfig:
    """The smoke preset on one worker with TinyRenderer, in ``runs_dir/name``."""
    base = preset("smoke")
    config = dataclasses.replace(
        base, env=dataclasses.replace(base.env, renderer="tiny"), workers=1, total_grasps=4, eval_episodes=1,
        keep_checkpoints=3, runs_dir=runs_dir, run_name=name,
    )  # fmt: skip
    return dataclasses.replace(config, **changes)


def blank_observation(replay) -> dict[str, np.ndarray]:
    """A zero observation with the shapes of ``replay``'s frames."""
    frames = replay.frames
    return {name: np.zeros(value.shape[1:], value.dtype) for name, value in vars(frames).items()
            if isinstance(value, np.ndarray) and name != "stamp"}  # fmt: skip


def advance(run: Trainer, grasps: int) -> None:
    """Pretend the run reached ``grasps``: a frame and a transition more in replay, the counter moved."""
    first = run.replay.add_frame(blank_observation(run.replay))
    second = run.replay.add_frame(blank_observation(run.replay))
    run.replay.add_transition(first, np.zeros(run.config.env.dof, np.float32), 0.0, second, True)
    run.progress.grasps = grasps


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory) -> Path:
    """A run folder with checkpoints at 1, 2 and 3 of its 4 grasps, each with its replay file."""
    run = Trainer(tiny_config(tmp_path_factory.mktemp("runs"), "saved"))
    for grasps in (1, 2, 3):
        advance(run, grasps)
        run._checkpoint()
    (run.run_dir / "metrics.csv").write_text("grasps\n1\n2\n3\n")
    run.close()
    return run.run_dir


@pytest.fixture
def run_dir(saved_run: Path, tmp_path: Path) -> Path:
    """A fresh copy of the saved run for one test."""
    return Path(shutil.copytree(saved_run, tmp_path / "runs" / saved_run.name))


def names(run_dir: Path) -> list[str]:
    return sorted(path.name for path in (run_dir / "checkpoints").iterdir())


def pairs(*grasps: int) -> list[str]:
    """The file names of checkpoints at ``grasps``, each with its replay."""
    return sorted(f"{kind}_{g:08d}.{ext}" for g in grasps for kind, ext in (("checkpoint", "pt"), ("replay", "npz")))


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def python(code: str, **kwargs) -> subprocess.Popen:
    """A Python process running ``code`` with this checkout's ``apr`` first on the path."""
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], env=env, text=True, **kwargs)


# ------------------------------------------------------------------------------------- checkpoints
def test_every_kept_checkpoint_has_its_replay_and_reads_back(saved_run: Path):
    assert names(saved_run) == pairs(1, 2, 3)
    for path in checkpoints.checkpoint_files(saved_run):
        state = checkpoints.read_checkpoint(path)
        checkpoints.verify_replay(checkpoints.replay_file(path, state))


def test_a_new_checkpoint_prunes_whole_pairs_and_only_after_it_reads_back(run_dir: Path, monkeypatch, capsys):
    resumed = Trainer.resume(run_dir)
    try:
        advance(resumed, 4)
        monkeypatch.setattr(trainer, "verify_replay", lambda path: (_ for _ in ()).throw(CheckpointError("bad")))
        with pytest.raises(RuntimeError, match="older checkpoints are kept"):
            resumed._checkpoint()
        assert {"checkpoint_00000001.pt", "replay_00000001.npz"} <= set(names(run_dir))  # nothing pruned
        monkeypatch.undo()
        resumed._checkpoint()
        assert names(run_dir) == pairs(2, 3, 4)
    finally:
        resumed.close()


@pytest.mark.parametrize("damage", ["truncated checkpoint", "garbage checkpoint", "missing replay", "truncated replay"])
def test_resume_falls_back_to_the_newest_intact_checkpoint_and_says_why(run_dir: Path, damage: str, capsys):
    newest = run_dir / "checkpoints" / "checkpoint_00000003.pt"
    replay = run_dir / "checkpoints" / "replay_00000003.npz"
    {"truncated checkpoint": lambda: truncate(newest), "garbage checkpoint": lambda: newest.write_text("not torch"),
     "missing replay": replay.unlink, "truncated replay": lambda: truncate(replay)}[damage]()  # fmt: skip
    resumed = Trainer.resume(run_dir)
    resumed.close()
    out = capsys.readouterr().out
    assert resumed.progress.grasps == 2
    assert "skipping checkpoint_00000003.pt" in out and "using checkpoint_00000002.pt" in out
    assert (run_dir / "checkpoints" / "checkpoint_00000003.pt.skipped").exists()  # set aside, not deleted
    assert "checkpoint_00000003.pt" not in names(run_dir)
    assert [row.split(",")[0] for row in (run_dir / "metrics.csv").read_text().splitlines()[1:]] == ["1", "2"]


def test_eval_falls_back_too_and_a_damaged_file_is_named(run_dir: Path, capsys):
    from apr.commands.train import eval_checkpoint

    truncate(run_dir / "checkpoints" / "checkpoint_00000003.pt")
    path, state = eval_checkpoint(run_dir)
    assert path.name == "checkpoint_00000002.pt" and state["progress"]["grasps"] == 2
    assert "skipping checkpoint_00000003.pt" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="checkpoint_00000003.pt: unreadable"):
        eval_checkpoint(run_dir / "checkpoints" / "checkpoint_00000003.pt")
    from apr.reproduce.policies import load_run

    assert load_run(run_dir).grasps == 2  # apr demo --checkpoint RUN and apr figures RUN


def test_no_intact_checkpoint_is_a_clear_error_listing_each_file(run_dir: Path):
    for path in (run_dir / "checkpoints").glob("checkpoint_*.pt"):
        truncate(path)
    before = (run_dir / "config.json").read_text()
    with pytest.raises(CheckpointError, match="no intact checkpoint") as error:
        Trainer.resume(run_dir)
    assert all(f"checkpoint_0000000{g}.pt" in str(error.value) for g in (1, 2, 3))
    assert (run_dir / "config.json").read_text() == before
    assert not (run_dir / "train.lock").exists()


def test_a_writer_killed_between_temporary_file_and_rename_leaves_the_previous_checkpoint_usable(run_dir: Path, capsys):
    """SIGKILL in the middle of a checkpoint: after the replay is renamed, before the checkpoint is."""
    writer = python(f"""
        import os, signal
        from pathlib import Path
        from apr.train import checkpoints
        from apr.train.trainer import Trainer

        run = Trainer.resume(Path({str(run_dir)!r}))
        run.progress.grasps = 4
        def killed(temporary, path):  # the moment between the temporary file and its rename
            os.kill(os.getpid(), signal.SIGKILL)
        checkpoints.commit = killed
        run._checkpoint()
    """, stdout=subprocess.DEVNULL)  # fmt: skip
    assert writer.wait(timeout=120) == -signal.SIGKILL
    left = names(run_dir)
    assert {"checkpoint_00000004.pt.tmp", "replay_00000004.npz"} <= set(left) and "checkpoint_00000004.pt" not in left
    assert (run_dir / "train.lock").read_text().strip() == str(writer.pid)  # the dead writer's stale lock

    resumed = Trainer.resume(run_dir)  # takes the stale lock over, resumes from the previous checkpoint
    resumed.close()
    out = capsys.readouterr().out
    assert f"took over the lock of process {writer.pid}" in out and resumed.progress.grasps == 3
    assert "checkpoint_00000004.pt.tmp" not in names(run_dir) and "replay_00000004.npz" not in names(run_dir)


# ------------------------------------------------------------------------------------------- the lock
def test_a_second_process_on_a_locked_run_is_refused_with_the_holders_pid(run_dir: Path):
    holder = python(f"""
        import sys, time
        from pathlib import Path
        from apr.train.checkpoints import RunLock
        lock = RunLock(Path({str(run_dir)!r}))
        print("locked", flush=True)
        sys.stdin.read()
    """, stdin=subprocess.PIPE, stdout=subprocess.PIPE)  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = (run_dir / "config.json").read_text()
        with pytest.raises(SystemExit, match=f"process {holder.pid} is training in it"):
            main(["train", "--resume", str(run_dir)])
        assert (run_dir / "config.json").read_text() == before
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    assert not (run_dir / "train.lock").exists()  # released by its holder
    Trainer.resume(run_dir).close()  # and free again


def test_a_run_is_locked_while_its_trainer_lives(run_dir: Path):
    first = Trainer.resume(run_dir)
    try:
        with pytest.raises(RunLocked, match=f"process {os.getpid()}"):
            Trainer.resume(run_dir)
    finally:
        first.close()
    with RunLock(run_dir) as lock:
        assert lock.held


# ------------------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(
    "flags, named",
    [
        (["--total-grasps", "-5"], "--total-grasps"),
        (["--workers", "-1"], "--workers"),
        (["--replay-capacity", "0"], "--replay-capacity"),
        (["--replay-capacity", "10000000000"], "--replay-capacity"),
        (["--eval-episodes", "0"], "--eval-episodes"),
        (["--keep-checkpoints", "0"], "--keep-checkpoints"),
        (["--updates-per-step", "nan"], "--updates-per-step"),
        (["--model.batch-size", "0"], "--model.batch-size"),
        (["--run-name", "a/b"], "--run-name"),
    ],
)
def test_a_refused_start_names_the_flag_and_leaves_no_folder(tmp_path: Path, flags: list[str], named: str):
    args = ["train", "--preset", "smoke", "--runs-dir", str(tmp_path / "runs"), "--run-name", "refused", *flags]
    with pytest.raises(SystemExit, match=named):
        main(args)
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "flags, named",
    [
        (["--env.dof", "6"], "--env.dof"),
        (["--env.target", "env"], "--env.target"),
        (["--model.batch-size", "32"], "--model.batch-size"),
        (["--replay-capacity", "3000"], "--replay-capacity"),
        (["--seed", "1"], "--seed"),
    ],
)
def test_a_failed_resume_names_the_field_and_leaves_the_folder_as_it_was(run_dir: Path, flags: list[str], named):
    before = {path: path.read_bytes() for path in run_dir.rglob("*") if path.is_file()}
    with pytest.raises(SystemExit, match=f"{named} cannot change when resuming"):
        main(["train", "--resume", str(run_dir), *flags])
    assert {path: path.read_bytes() for path in run_dir.rglob("*") if path.is_file()} == before
    Trainer.resume(run_dir).close()  # a plain resume still works


def test_resume_may_change_budgets_and_processes(run_dir: Path):
    config = dataclasses.replace(Trainer.saved_config(run_dir), total_grasps=9, workers=2, eval_episodes=3)
    resumed = Trainer.resume(run_dir, config)
    resumed.close()
    assert TrainConfig.from_json((run_dir / "config.json").read_text()).total_grasps == 9


def test_resuming_a_finished_run_says_so_and_how_to_extend_it(run_dir: Path, capsys):
    before = {path: path.read_bytes() for path in run_dir.rglob("*") if path.is_file()}
    with pytest.raises(RunFinished):
        Trainer.resume(run_dir, dataclasses.replace(Trainer.saved_config(run_dir), total_grasps=3))
    main(["train", "--resume", str(run_dir), "--total-grasps", "3"])  # the command: a message, exit status 0
    out = capsys.readouterr().out
    assert "is finished: 3 of 3 grasps" in out and "--total-grasps N (N > 3)" in out
    assert {path: path.read_bytes() for path in run_dir.rglob("*") if path.is_file()} == before


def test_a_run_out_of_training_time_is_finished_too(run_dir: Path, capsys):
    run = Trainer.resume(run_dir)
    run.progress.wall_s = 90.0  # 1.5 minutes of training
    run._checkpoint()
    run.close()
    with pytest.raises(RunFinished, match=r"1\.5 of 1 minutes of training"):
        Trainer.resume(run_dir, dataclasses.replace(Trainer.saved_config(run_dir), max_train_minutes=1.0))
    main(["train", "--resume", str(run_dir), "--max-train-minutes", "1"])
    assert "--max-train-minutes M (M > 1.5)" in capsys.readouterr().out
    Trainer.resume(run_dir, dataclasses.replace(Trainer.saved_config(run_dir), max_train_minutes=2.0)).close()


def test_a_run_that_died_before_its_first_checkpoint_starts_again(tmp_path: Path, capsys):
    fresh = Trainer(tiny_config(tmp_path, "early-crash"))
    fresh.close()
    (fresh.run_dir / "metrics.csv").write_text("grasps\n1\n")
    resumed = Trainer.resume(fresh.run_dir)
    resumed.close()
    assert "no checkpoint yet: starting it from the beginning" in capsys.readouterr().out
    assert resumed.progress.grasps == 0 and not (fresh.run_dir / "metrics.csv").exists()


def test_derived_model_fields_are_refused_not_dropped(tmp_path: Path, monkeypatch):
    started = []
    base = ["train", "--preset", "smoke", "--runs-dir", str(tmp_path)]
    for flag in ("--model.image-channels", "--model.grasp-action-dim", "--model.seed", "--model.image_channels"):
        with pytest.raises(SystemExit, match="not an option"):
            main([*base, flag, "4"])
    with pytest.raises(SystemExit, match="--no-anneal-over-run"):
        main([*base, "--model.gqn-anneal-updates", "5000"])

    class Recorder:
        def __init__(self, config: TrainConfig, workers=None):
            started.append(config)

        def train(self) -> Path:
            return tmp_path

    monkeypatch.setattr(trainer, "Trainer", Recorder)
    main([*base, "--model.gqn-anneal-updates", "5000", "--no-anneal-over-run"])
    assert started[-1].model.gqn_anneal_updates == 5000
    assert started[-1].resolved().model.gqn_anneal_updates == 5000  # an explicit value wins when it can


def test_contradictory_env_flags_are_refused_by_name_and_a_presets_own_values_are_not(tmp_path: Path, monkeypatch):
    started = []

    class Recorder:  # stands in for the trainer: what would have trained
        def __init__(self, config: TrainConfig, workers=None):
            started.append(config)

        def train(self) -> Path:
            return tmp_path

    monkeypatch.setattr(trainer, "Trainer", Recorder)
    runs = tmp_path / "runs"
    passive = ["train", "--preset", "active-target", "--runs-dir", str(runs), "--env.env-id", "apr/PassiveGrasp-v2"]
    for flag, value in (("--env.target", "learned"), ("--env.foveation", "logpolar")):
        with pytest.raises(SystemExit) as refused:
            main([*passive, flag, value])
        message = str(refused.value)
        assert message.startswith(f"apr train: error: {flag} {value} contradicts --env.env-id apr/PassiveGrasp-v2")
        assert "\n" not in message
    assert not started and not runs.exists()

    main(passive)  # active-target's own logpolar: the passive cameras are resized, and the run says so
    assert started[-1].env.foveation == "logpolar" and started[-1].resolved().env.foveation == "resize"
    for name in PRESETS:
        assert preset(name).problems() == [], name


def test_plot_of_a_folder_without_runs_is_one_line_and_writes_nothing(tmp_path: Path):
    empty, out = tmp_path / "empty", tmp_path / "x.png"
    empty.mkdir()
    with pytest.raises(SystemExit) as refused:
        main(["plot", str(empty), "--out", str(out)])
    assert str(refused.value) == f"apr plot: error: {empty} is not a run folder (no config.json) and holds none"
    assert not out.exists()


def test_help_lists_train_and_its_presets(capsys):
    for args in (["--help"], ["train", "--help"]):
        with pytest.raises(SystemExit) as exit_:
            main(args)
        assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "train" in out.split("subcommands")[1]
    train_help = out.split("usage: apr train")[1]
    assert "--preset" in train_help and "--resume RUN_DIR" in train_help and "active-learned-4d" in train_help
    for hidden in ("--model.image-channels INT", "--model.grasp-action-dim INT", "--model.seed INT"):
        assert hidden not in train_help
    for args in ([], ["bogus"]):
        with pytest.raises(SystemExit):
            main(args)
        assert "train" in capsys.readouterr().err
    main(["--version"])
    assert capsys.readouterr().out.strip() == f"apr {__import__('apr').__version__}"


@pytest.mark.parametrize(
    "args, message",
    [
        (["eval", "RUN", "--episodes", "0"], "--episodes must be at least 1"),
        (["eval", "RUN", "--workers", "-1"], "--workers must be at least 0"),
        (["eval", "RUN", "--json", "/no/such/dir/x.json"], "the folder /no/such/dir does not exist"),
        (["eval", "RUN/config.json"], "is a run's configuration, not a checkpoint"),
        (["eval", "RUN/checkpoints/replay_00000003.npz"], "is a replay file"),
        (["eval", "RUN/metrics.csv"], "unreadable"),
        (["demo", "--episodes", "0"], "--episodes must be at least 1"),
        (["demo", "--gif-episodes", "-1"], "--gif-episodes must be at least 0"),
        (["demo", "--out", "RUN/config.json"], "is a file, not a folder"),
        (["demo", "--checkpoint", "RUN/config.json"], "is not a packaged checkpoint"),
        (["demo", "--checkpoint", "RUN/checkpoints/replay_00000003.npz"], "replay_00000003.npz: unreadable"),
        (["render", "--steps", "-1"], "--steps must be at least 0"),
        (["figures", "RUN", "--episodes", "0"], "--episodes must be at least 1"),
        (["reproduce", "table1", "--seeds", "-1"], "--seeds must be at least 0"),
        (["reproduce", "table1", "--scale", "cpu", "--tiny-model"], "the presets of --scale cpu are tiny already"),
    ],
)
def test_commands_check_their_arguments_before_any_work(run_dir: Path, args: list[str], message: str, monkeypatch):
    from apr.train import evaluation

    monkeypatch.setattr(evaluation, "evaluate", lambda *a, **k: pytest.fail("evaluated before checking"))
    with pytest.raises(SystemExit, match=message):
        main([arg.replace("RUN", str(run_dir)) for arg in args])


# ------------------------------------------------------------------------------------------ environments
ACTIVE = "apr/ActiveGrasp-v2"
VECTOR_SCRIPT = """
    import sys
    import gymnasium, numpy as np
    import apr

    make = lambda: gymnasium.make("apr/ActiveGrasp-v2", dof=4, renderer="auto")  # EGL where it loads
    if sys.argv[1] == "after-egl":  # this process renders with EGL before it forks
        env = make()
        env.reset(seed=0)
        env.close()
    envs = gymnasium.vector.AsyncVectorEnv([make] * 2)  # the default context: fork
    try:
        batch, _ = envs.reset(seed=0)
    finally:
        envs.close()
    single = make()
    observation, _ = single.reset(seed=0)
    print(single.unwrapped.world.renderer, np.array_equal(batch["images"][0], observation["images"]))
    single.close()
"""


def run_script(script: str, *args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    """``script`` in a fresh Python process; a hang fails the test after ``timeout`` seconds instead of blocking."""
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    try:
        return subprocess.run([sys.executable, "-c", textwrap.dedent(script), *args], env=env, capture_output=True,
                              text=True, timeout=timeout)  # fmt: skip
    except subprocess.TimeoutExpired as error:
        pytest.fail(f"hung for {timeout} s: {error.stderr}")


def test_async_vector_env_with_the_auto_renderer_and_fork_resets_quietly_and_renders_as_one_env():
    """renderer="auto" in gymnasium's AsyncVectorEnv with its default fork context: no hang, each sub-env
    renders as a lone environment does, and the console holds nothing of pybullet's (nor of its children)."""
    result = run_script(VECTOR_SCRIPT, "clean")
    assert result.returncode == 0, result.stderr
    renderer, same = result.stdout.split()
    assert same == "True", "a sub-env's images differ from a lone environment's for one seed"
    assert result.stderr == "" and result.stdout == f"{renderer} True\n"  # nothing but the script's own line


def test_a_fork_after_egl_fails_at_once_naming_the_fix():
    result = run_script(VECTOR_SCRIPT, "after-egl")
    if "egl" not in result.stdout and result.returncode == 0:
        pytest.skip(f"EGL does not load here ({result.stdout.strip()}): nothing is inherited")
    assert result.returncode != 0
    assert "forked from one that had loaded pybullet's EGL renderer" in result.stderr
    assert "context='spawn'" in result.stderr and "renderer='tiny'" in result.stderr


def test_two_auto_environments_in_one_process_see_the_same_images():
    """renderer="auto" never mixes renderers in a process: a second world while an EGL one is open is refused."""
    import gymnasium

    first = gymnasium.make(ACTIVE, dof=4, renderer="auto")
    try:
        observation, _ = first.reset(seed=3)
        if first.unwrapped.world.renderer != "egl":
            pytest.skip("EGL does not load here; auto is TinyRenderer for the whole process")
        with pytest.raises(RuntimeError, match="serves one world per process"):
            gymnasium.make(ACTIVE, dof=4, renderer="auto")  # it would render with TinyRenderer: refused, not mixed
    finally:
        first.close()
    second = gymnasium.make(ACTIVE, dof=4, renderer="auto")
    try:
        second.reset(seed=5)
        again, _ = second.reset(seed=3)
        assert second.unwrapped.world.renderer == "egl"
        for key in observation:
            assert np.array_equal(observation[key], again[key]), key
    finally:
        second.close()
    with pytest.raises(RuntimeError, match="serves one world per process") as refused:
        gymnasium.vector.SyncVectorEnv([lambda: gymnasium.make(ACTIVE, dof=4, renderer="auto")] * 2)
    refused.value.__traceback__ = None  # its frames hold the vector's first sub-env, which holds EGL
    del refused
    gc.collect()
    assert rendering.egl_holder() is None  # let go: the next test may open EGL


def test_quiet_c_output_drops_pybullets_chatter_and_keeps_everything_else(capfd):
    import ctypes

    from apr.quiet import quiet_c_output

    libc = ctypes.CDLL(None)
    with quiet_c_output():
        libc.printf(b"argv[0]=\nven = Mesa/X.org\n")  # buffered C output, as pybullet's
        os.write(1, b"real output\nDestroy EGL OpenGL window.\n")
        os.write(2, b"EGL device choice: -1 of 1.\nb3Error: a real error\npybullet build time: Jan 29 2025\n")
    out, err = capfd.readouterr()
    assert out == "real output\n" and err == "b3Error: a real error\n"


@pytest.mark.slow  # about 35 s on 2 busy cores; the vector test above checks the console of every env step
def test_apr_demo_prints_only_its_own_lines(tmp_path: Path):
    result = run_script("from apr.cli import main; import sys; main(sys.argv[1:])",
                        "demo", "--episodes", "1", "--gif-episodes", "1", "--out", str(tmp_path / "demo"))  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    lines = result.stdout.splitlines()
    bars = [k for k, line in enumerate(lines) if set(line) == {"="}]
    own = lines[: bars[0]] + lines[bars[-1] + 1 :] if bars else lines  # the untrained-policy notice between bars
    assert own[0].startswith("policy: ") and own[-1].startswith("report: "), own
    assert all(line.startswith(("policy: ", "report: ")) or " held-out episodes succeeded: " in line for line in own)


def test_a_worker_is_recycled_after_its_episodes_and_plays_a_seed_as_before():
    """Long runs replace each worker now and then (pybullet's EGL keeps removed bodies' memory); a fresh one
    must continue exactly."""
    from apr.train.workers import EnvWorkers

    with EnvWorkers(1, ACTIVE, {"dof": 4, "target": "env", "renderer": "tiny"}, recycle_every=1) as workers:
        assert_recycling_replays_a_seed(workers)
