"""``apr reproduce table1 --backend slurm``: each (preset, seed) run is a task of one Slurm job array,
submitted through submitit.

A task has one node's ``workers + 1`` CPUs and ``gpus_per_run`` GPUs, and trains its run there with the local
worker pool. A task preempted or out of time is requeued by submitit (:class:`CampaignJob` is
``Checkpointable``) and continues from the run's newest checkpoint: every task plans its run again when it
starts. The run folders must be on a filesystem the nodes share; submitit's own files go to ``OUT/slurm``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import submitit

from apr.reproduce.campaign import PlannedRun, train_replanned_logged


class CampaignJob(submitit.helpers.Checkpointable):
    """One run as a Slurm task; on preemption or timeout submitit requeues it with the same plan, which the task
    plans again (resume) when it restarts."""

    def __call__(self, plan: PlannedRun) -> None:
        train_replanned_logged(plan)


def run_campaign_slurm(plans: Sequence[PlannedRun], folder: Path, partition: str = "", timeout_min: int = 1440,
                       gpus_per_run: int = 1, max_jobs: int = 0,
                       cluster: str | None = None) -> list[tuple[PlannedRun, int]]:  # fmt: skip
    """Submit the runs that are not done as one job array, wait for it, and return (run, exit code) for each.

    Args:
        folder: submitit's folder (job scripts, pickles, logs).
        max_jobs: array tasks running at once (0: all).
        cluster: submitit's executor: None picks Slurm where it is available; "local" runs the tasks as
            processes of this machine (tests), "debug" in this process.
    """
    todo = [plan for plan in plans if plan.status != "done"]
    if not todo:
        return []
    executor = submitit.AutoExecutor(folder=folder, cluster=cluster)
    workers = max(plan.config.workers for plan in todo)
    executor.update_parameters(
        name="apr-table1", timeout_min=timeout_min, nodes=1, tasks_per_node=1, cpus_per_task=workers + 1,
        gpus_per_node=gpus_per_run, slurm_partition=partition or None,
        slurm_array_parallelism=max_jobs if max_jobs > 0 else len(todo),
    )  # fmt: skip
    jobs = executor.map_array(CampaignJob(), todo)
    for plan, job in zip(todo, jobs, strict=True):
        print(f"{plan.run_dir}: {plan.status}, job {job.job_id} (logs: {folder}; run log: train.log)")
    print("waiting for the jobs; Ctrl-C stops waiting, not the jobs (then: apr reproduce table1 ... --table-only)")
    finished = []
    try:
        for plan, job in zip(todo, jobs, strict=True):
            try:
                job.result()
                code, outcome = 0, "finished"
            except (submitit.core.utils.FailedJobError, submitit.core.utils.UncompletedJobError) as error:
                code, outcome = 1, f"FAILED ({str(error).strip().splitlines()[-1]})"
            finished.append((plan, code))
            print(f"{plan.run_dir}: {outcome}")
    except KeyboardInterrupt:
        raise SystemExit("stopped waiting; the jobs go on (squeue). When they are done, write the table with the "
                         "same command and --table-only") from None  # fmt: skip
    return finished
