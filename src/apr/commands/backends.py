"""Where the work runs, chosen from the command line and passed down.

Training (:mod:`apr.train`) and reproduction (:mod:`apr.reproduce`) never import the optional cluster layer
(:mod:`apr.cluster`): they take a workers factory (``Trainer(config, workers=...)``) or a campaign executor
(``campaign.run(args, executor=...)``) from their caller, as a Stable-Baselines3 user picks a VecEnv. This is the
caller of the ``apr`` command: it maps ``--backend`` to the factory or the executor, and checks first that the
backend's packages are installed.
"""

from __future__ import annotations

import shutil
from functools import partial

from apr.cluster import missing
from apr.commands import checks
from apr.reproduce import campaign
from apr.reproduce.campaign import CampaignExecutor, Table1Args
from apr.train.workers import LocalWorkers, WorkersFactory

WORKERS_BACKENDS = ("local", "ray")
"""The values of ``TrainConfig.backend``."""


def workers_problems(backend: str) -> list[str | None]:
    """Why the environment workers of ``--backend BACKEND`` cannot open here (None entries: fine)."""
    return [missing("ray", "--backend ray")] if backend == "ray" else []


def workers_factory(backend: str, ray_address: str = "") -> WorkersFactory:
    """The workers factory of ``--backend BACKEND``: local processes, or Ray actors on the cluster at
    ``ray_address`` (``apr.cluster.ray_workers.RayWorkers``)."""
    if backend == "local":
        return LocalWorkers()
    if backend == "ray":
        from apr.cluster.ray_workers import RayWorkers

        return RayWorkers(ray_address)
    raise ValueError(f"unknown backend {backend!r}; choose one of {WORKERS_BACKENDS}")


def cluster_problems(args: Table1Args) -> list[str | None]:
    """Why the cluster options of ``apr reproduce table1`` cannot work (before anything is submitted)."""
    if args.backend == "local" or args.table_only:
        return []
    module = "ray" if args.backend == "ray" else "submitit"
    return [
        missing(module, f"--backend {args.backend}"),
        None if args.workers > 0 else f"--backend {args.backend} needs --workers N: the environment workers "
        "each run reserves CPUs for",
        checks.at_least("--max-jobs", args.max_jobs, 0),
        None if args.gpus_per_run >= 0 else f"--gpus-per-run must be at least 0, got {args.gpus_per_run}",
        None if args.backend != "slurm" or float(args.gpus_per_run).is_integer()
        else f"--gpus-per-run {args.gpus_per_run}: Slurm reserves whole GPUs",
        checks.at_least("--slurm-timeout-min", args.slurm_timeout_min, 1),
        None if args.backend != "slurm" or shutil.which("sbatch") else "--backend slurm: no Slurm here (sbatch is "
        "not on PATH); run the command on the cluster's login node",
    ]  # fmt: skip


def campaign_executor(args: Table1Args) -> CampaignExecutor:
    """The executor of ``apr reproduce table1 --backend BACKEND``: this machine (``--parallel`` runs at a time),
    Ray tasks (``apr.cluster.ray_campaign``) or a Slurm job array (``apr.cluster.slurm_campaign``)."""
    if args.backend == "ray":
        from apr.cluster.ray_campaign import run_campaign_ray

        return partial(run_campaign_ray, address=args.ray_address, gpus_per_run=args.gpus_per_run,
                       max_jobs=args.max_jobs)  # fmt: skip
    if args.backend == "slurm":
        from apr.cluster.slurm_campaign import run_campaign_slurm

        return partial(run_campaign_slurm, folder=args.out / "slurm", partition=args.slurm_partition,
                       timeout_min=args.slurm_timeout_min, gpus_per_run=int(args.gpus_per_run),
                       max_jobs=args.max_jobs, cluster="slurm")  # fmt: skip
    return partial(campaign.run_campaign, parallel=args.parallel)


def table1(args: Table1Args) -> None:
    """``apr reproduce table1``: every flag checked (the cluster's too), then the campaign on its backend."""
    checks.refuse("apr reproduce table1", [*campaign.problems(args), *cluster_problems(args)])
    campaign.run(args, executor=None if args.table_only else campaign_executor(args))
