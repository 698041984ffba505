"""Beyond one machine: environment workers as Ray actors on a two-node cluster simulated on this machine, and
the Table 1 campaign as Ray tasks and as a submitit job array (submitit's local executor stands in for Slurm).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import assert_recycling_replays_a_seed, kill_worker_once_while_stepping

from apr.reproduce import campaign
from apr.reproduce.campaign import Table1Args, plan_runs
from apr.reproduce.runs import read_metrics, without_timings
from apr.train.config import TrainConfig, preset
from apr.train.trainer import Trainer
from apr.train.workers import WorkerFailure

ray = pytest.importorskip("ray", reason='the cluster extra is not installed: pip install -e ".[cluster]"')
submitit = pytest.importorskip("submitit", reason='the cluster extra is not installed: pip install -e ".[cluster]"')

from ray.cluster_utils import Cluster  # noqa: E402

from apr.cluster.ray_workers import RayWorkers  # noqa: E402
from apr.cluster.slurm_campaign import CampaignJob, run_campaign_slurm  # noqa: E402
from apr.commands.backends import campaign_executor  # noqa: E402

TINY_CAMPAIGN_RUN = dict(total_grasps=2, random_grasps=1, eval_episodes=1, eval_every_grasps=0,
                         checkpoint_every_grasps=1, image_every_grasps=0, log_every_grasps=1)  # fmt: skip
"""The smoke preset shrunk to 2 grasps (1 random) and one evaluation episode at the end."""


def read_rows(run_dir: Path) -> list[dict[str, str]]:
    """The run's metrics.csv rows, less the wall-clock columns."""
    return without_timings(read_metrics(run_dir))


def _parent_pid(stat: Path) -> int | None:
    """The parent's process id from ``/proc/PID/stat`` (None if the process is gone)."""
    try:
        return int(stat.read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return None


def small_run(tmp: Path, name: str, backend: str) -> TrainConfig:
    """Two workers, four grasps (two rounds: random actions, then the policy acting and the learner updating)."""
    base = preset("smoke")
    return dataclasses.replace(
        base, env=dataclasses.replace(base.env, renderer="tiny"), workers=2, total_grasps=4, random_grasps=2,
        updates_per_step=0.5, eval_every_grasps=0, eval_episodes=1, checkpoint_every_grasps=2, log_every_grasps=1,
        image_every_grasps=0, runs_dir=tmp, run_name=name, backend=backend,
    )  # fmt: skip


@contextlib.contextmanager
def two_node_cluster(second_node_cpus: int) -> Iterator[tuple[Cluster, Any]]:
    """A Ray cluster of two nodes (two raylets on this machine; the head with two CPUs), this process its
    driver; yields the cluster and the second node."""
    ray.shutdown()  # a cluster a fixture of this module may still hold
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 2, "object_store_memory": 80 * 2**20})
    second = cluster.add_node(num_cpus=second_node_cpus, object_store_memory=80 * 2**20)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, logging_level=logging.ERROR, log_to_driver=False)
    try:
        yield cluster, second
    finally:
        ray.shutdown()
        cluster.shutdown()


@pytest.fixture(scope="module")
def two_nodes() -> Iterator[Cluster]:
    """Two nodes of two CPUs each."""
    with two_node_cluster(second_node_cpus=2) as (cluster, _):
        yield cluster


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return Trainer(small_run(tmp_path_factory.mktemp("runs"), "local", "local")).train()


def test_a_ray_run_spreads_its_actors_over_both_nodes_and_gives_the_local_pools_numbers(two_nodes, local_run,
                                                                                       tmp_path, capsys):  # fmt: skip
    trainer = Trainer(small_run(tmp_path, "ray", "ray"), workers=RayWorkers())
    learn, nodes = trainer._learn, []

    def learn_and_look(steps: int) -> None:
        nodes.append(tuple(trainer.workers.node_ids()))
        learn(steps)

    trainer._learn = learn_and_look
    ray_run = trainer.train()
    assert "ray: 2 environment actors on 2 Ray nodes (renderer: 2 with tiny)" in capsys.readouterr().out
    cluster_nodes = {node["NodeID"] for node in ray.nodes() if node["Alive"]}
    assert len(cluster_nodes) == 2 and set(nodes[0]) == cluster_nodes, "the two actors share a node"
    rows = read_rows(local_run)
    assert int(rows[-1]["updates"]) > 0, "the learner never ran: the comparison would prove nothing"
    assert read_rows(ray_run) == rows
    ray_eval, local_eval = (
        json.loads((run / "eval" / "eval_00000004.json").read_text()) for run in (ray_run, local_run)
    )
    assert ray_eval["outcomes"] == local_eval["outcomes"]
    assert json.loads((ray_run / "config.json").read_text())["backend"] == "ray"


def test_an_actor_killed_mid_round_is_restarted_and_the_run_finishes_counting_the_lost_episode(two_nodes,
                                                                                              tmp_path):  # fmt: skip
    trainer = Trainer(small_run(tmp_path, "killed", "ray"), workers=RayWorkers())
    killed = kill_worker_once_while_stepping(trainer, grasps=2, worker=1)
    run = trainer.train()
    rows = read_rows(run)
    assert killed and int(rows[-1]["lost_episodes"]) == 1
    assert int(rows[-1]["grasps"]) == 4  # the lost episode does not count; the run still did its 4
    assert trainer.workers.failures == 1


def test_an_actor_is_recycled_after_its_episodes_and_an_environment_error_costs_one_episode(two_nodes):
    """A fresh actor plays a seed exactly as the one it replaced; an actor whose environment raised is restarted
    and answers the next reset."""
    from apr.cluster.ray_workers import RayEnvWorkers

    with RayEnvWorkers(1, "apr/ActiveGrasp-v2", {"dof": 4, "target": "env", "renderer": "tiny"},
                       recycle_every=1) as workers:  # fmt: skip
        first = assert_recycling_replays_a_seed(workers)
        workers.send_step(0, np.zeros(7, np.float32))  # a 4-DoF environment refuses a 7-number action
        failure = workers.receive(0)
        assert isinstance(failure, WorkerFailure) and workers.failures == 1, failure
        workers.send_reset(0, 7)
        after, _ = workers.receive(0)
        assert np.array_equal(after["images"], first["images"])


def test_the_campaign_trains_each_run_as_a_ray_task_and_builds_the_table_from_the_folders(two_nodes, tmp_path):
    out = tmp_path / "table1"
    args = Table1Args(seeds=1, presets=("smoke",), out=out, backend="ray", workers=1, gpus_per_run=0)
    campaign.run(args, overrides=TINY_CAMPAIGN_RUN, executor=campaign_executor(args))
    run = out / "smoke__s0"
    final = json.loads((run / "eval" / "eval_00000002.json").read_text())
    assert final["final"] and final["episodes"] == 1
    assert json.loads((run / "config.json").read_text())["backend"] == "ray"
    assert "smoke" in (out / "table1.md").read_text() and (run / "train.log").exists()
    assert campaign.plan_runs(("smoke",), [0], out, TINY_CAMPAIGN_RUN)[0].status == "done"


def test_the_campaign_as_a_submitit_job_array_trains_the_runs_that_are_not_done(tmp_path: Path):
    """submitit's local executor runs the array's tasks as processes of this machine, as Slurm would on nodes."""
    out = tmp_path / "table1"
    plans = plan_runs(("smoke",), [0, 1], out, {**TINY_CAMPAIGN_RUN, "workers": 1})
    finished = run_campaign_slurm(plans[:1], out / "slurm", gpus_per_run=0, cluster="local")
    assert [(plan.run_dir.name, code) for plan, code in finished] == [("smoke__s0", 0)]
    assert json.loads((out / "smoke__s0" / "eval" / "eval_00000002.json").read_text())["final"]
    assert not (out / "smoke__s1").exists()

    replanned = plan_runs(("smoke",), [0, 1], out, {**TINY_CAMPAIGN_RUN, "workers": 1})
    assert [plan.status for plan in replanned] == ["done", "new"]
    # A preempted task is requeued with its plan, which it plans again when it restarts: resume, not restart.
    requeued = CampaignJob().checkpoint(replanned[1])
    assert requeued.args == (replanned[1],) and isinstance(requeued.function, CampaignJob)


@pytest.mark.slow
def test_a_preempted_slurm_task_is_requeued_and_resumes_its_run_from_its_checkpoint(tmp_path: Path):
    """submitit's local executor delivers the preemption signal as Slurm would; the task is requeued, plans its
    run again and resumes it from the newest checkpoint instead of starting over."""
    import time

    out = tmp_path / "table1"
    plans = plan_runs(("smoke",), [0], out, {**TINY_CAMPAIGN_RUN, "total_grasps": 8, "workers": 1})
    executor = submitit.AutoExecutor(folder=out / "slurm", cluster="local")
    executor.update_parameters(timeout_min=10, gpus_per_node=0)
    job = executor.submit(CampaignJob(), plans[0])
    checkpoints = out / "smoke__s0" / "checkpoints"
    deadline = time.monotonic() + 300
    while not list(checkpoints.glob("checkpoint_00000002.pt")) and time.monotonic() < deadline:
        time.sleep(0.5)
    controller = job._process.pid  # submitit's local controller; the task is its child process
    (task,) = [int(stat.parent.name) for stat in Path("/proc").glob("[0-9]*/stat")
               if _parent_pid(stat) == controller]  # fmt: skip
    os.kill(task, signal.SIGUSR2)  # what Slurm sends a task before preempting it (submitit's --signal)
    job.result()
    log = (out / "smoke__s0" / "train.log").read_text()
    assert "resumed" in log and "from checkpoint_" in log, log[-2000:]
    assert json.loads((out / "smoke__s0" / "eval" / "eval_00000008.json").read_text())["final"]


def test_apr_imports_without_ray_or_submitit_and_the_backends_say_how_to_install_them(tmp_path: Path):
    code = """
import sys
sys.modules["ray"] = None  # as if not installed
sys.modules["submitit"] = None
import apr.cli, apr.train.trainer, apr.reproduce.campaign
try:
    apr.cli.main(["train", "--preset", "smoke", "--backend", "ray", "--workers", "2", "--runs-dir", sys.argv[1]])
except SystemExit as refused:
    print(refused)
apr.cli.main(["reproduce", "table1", "--backend", "slurm", "--workers", "1", "--out", sys.argv[1]])
"""
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "out")], capture_output=True, text=True)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "apr train: error: --backend ray needs the 'ray' package" in done.stdout
    assert 'pip install -e ".[cluster]"' in done.stdout
    assert "--backend slurm needs the 'submitit' package" in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_node_lost_mid_round_costs_its_episode_and_its_actor_restarts_on_the_other_node(tmp_path: Path):
    with two_node_cluster(second_node_cpus=1) as (cluster, doomed):
        trainer = Trainer(small_run(tmp_path, "node-lost", "ray"), workers=RayWorkers())
        learn, removed, nodes = trainer._learn, [], []

        def remove_node_while_stepping(steps: int) -> None:
            if not removed and trainer.progress.grasps == 2:
                cluster.remove_node(doomed)
                removed.append(doomed)
            nodes.append(set(trainer.workers.node_ids()))
            learn(steps)

        trainer._learn = remove_node_while_stepping
        rows = read_rows(trainer.train())
        assert removed and int(rows[-1]["lost_episodes"]) == 1 and int(rows[-1]["grasps"]) == 4
        alive = {node["NodeID"] for node in ray.nodes() if node["Alive"]}
        assert len(nodes[0]) == 2 and nodes[-1] == alive and len(alive) == 1, (nodes, alive)
