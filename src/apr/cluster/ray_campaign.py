"""``apr reproduce table1 --backend ray``: each (preset, seed) run is a Ray task on a cluster.

A run's task reserves one CPU and ``gpus_per_run`` GPUs for its learner, inside a placement group that also
reserves one CPU for each of its ``workers`` environment actors (``apr train --backend ray`` in the task; the
actors are captured by the group, so a run's CPUs are held for it while it trains). Placement groups pack a run
onto one node where they can and spread it where they must. Every task plans its run again when it starts, so a
task Ray retries after a node died resumes from the run's checkpoint; the run folders must be on a filesystem
every node shares.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from apr.cluster import require
from apr.cluster.ray_workers import RayWorkers, connect
from apr.reproduce.campaign import PlannedRun, train_replanned_logged


def run_campaign_ray(plans: Sequence[PlannedRun], address: str = "", gpus_per_run: float = 1.0,
                     max_jobs: int = 0) -> list[tuple[PlannedRun, int]]:  # fmt: skip
    """Train the runs that are not done as Ray tasks, at most ``max_jobs`` at once (0: as many as the cluster
    has room for); return (run, exit code) for each one trained."""
    ray = require("ray", "--backend ray")
    connect(address)
    from ray.util.placement_group import placement_group, remove_placement_group
    from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

    # One task per worker process (max_calls=1): a run redirects its process's output to RUN/train.log.
    train = ray.remote(num_cpus=1, num_gpus=gpus_per_run, max_calls=1)(train_replanned_logged)
    todo = [plan for plan in plans if plan.status != "done"]
    pending, running, finished = list(todo), {}, []
    while pending or running:
        while pending and (max_jobs <= 0 or len(running) < max_jobs):
            plan = pending.pop(0)
            learner = {"CPU": 1.0, **({"GPU": gpus_per_run} if gpus_per_run > 0 else {})}
            group = placement_group([learner] + [{"CPU": 1.0}] * plan.config.workers, strategy="PACK")
            strategy = PlacementGroupSchedulingStrategy(group, placement_group_bundle_index=0,
                                                        placement_group_capture_child_tasks=True)  # fmt: skip
            config = dataclasses.replace(plan.config, backend="ray", ray_address="")
            task = train.options(scheduling_strategy=strategy)
            reference = task.remote(
                dataclasses.replace(plan, config=config), RayWorkers()
            )  # the task is connected to Ray
            running[reference] = (plan, group)
            print(f"{plan.run_dir}: {plan.status}, submitted to Ray ({plan.config.workers} environment actors, "
                  f"{gpus_per_run:g} GPU; log: train.log)")  # fmt: skip
        done, _ = ray.wait(list(running), num_returns=1)
        plan, group = running.pop(done[0])
        try:
            ray.get(done[0])
            code, outcome = 0, "finished"
        except ray.exceptions.RayError as error:
            code, outcome = 1, f"FAILED ({str(error).strip().splitlines()[-1]})"
        remove_placement_group(group)
        finished.append((plan, code))
        print(f"{plan.run_dir}: {outcome}")
    return finished
