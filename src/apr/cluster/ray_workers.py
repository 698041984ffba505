"""Environment workers as Ray actors: the same pool as :class:`apr.train.workers.EnvWorkers`, spread over a
Ray cluster's nodes (``apr train --backend ray [--ray-address ADDR]``).

Each actor is one process with one environment (one physics client, so EGL keeps one context per process) and
reserves one CPU; they are spread over the cluster's nodes, or placed in the caller's placement group when
there is one (a campaign run, :mod:`apr.cluster.ray_campaign`). The learner and the policies' batched forward pass
stay in the driver, on its GPU; an actor answers ``reset(seed)`` and ``step(action)``, exactly as a local
worker does over its pipe, and returns the uint8 observations as NumPy arrays, which Ray hands to the driver
without a copy when they share a node. So :func:`apr.train.rollout.run_round` drives both pools, and a run gives
the same numbers on either (``docs/decisions.md``, "Ray actors step; they do not run whole episodes").

A dead actor (its process or its node) is restarted by Ray (``max_restarts``), an actor whose environment
raised is restarted the same way, and ``receive`` reports the lost episode as the local pool does. Actors are
replaced by fresh ones every ``RECYCLE_EVERY_RESETS`` episodes.

The trainer does not know Ray: its caller passes :class:`RayWorkers` (``Trainer(config, workers=RayWorkers(
address))``; ``apr train --backend ray`` does), as it would pass any other :class:`apr.train.workers.WorkersFactory`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import time
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from apr.cluster import require
from apr.train.workers import (
    MAX_FAILURES_IN_A_ROW,
    RECYCLE_EVERY_RESETS,
    StepResult,
    WorkerFailure,
    Workers,
    renderer_counts,
)

READY_TIMEOUT_S = 300.0
"""How long a started or restarted actor may take to answer (a node may have to start one first)."""


def connect(address: str = "") -> None:
    """Connect this process to Ray, once: to ``address`` (``auto`` or ``HOST:6379``), or,
    when empty, to the ``RAY_ADDRESS`` cluster or one started on this machine (``ray start``), or else to a new
    Ray instance on this machine. The actors' own output stays in Ray's log folder, off the console."""
    ray = require("ray", "--backend ray")
    if not ray.is_initialized():
        ray.init(address=address or None, logging_level=logging.ERROR, log_to_driver=False)


class EnvActor:
    """One environment in a Ray actor's process (made remote by :class:`RayEnvWorkers`)."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any]):
        import apr  # noqa: F401  (registers the environments in this process)

        with contextlib.suppress(ValueError):  # Ctrl-C is the trainer's to handle (not in the main thread: moot)
            signal.signal(signal.SIGINT, signal.SIG_IGN)

        self.env = gym.make(env_id, **env_kwargs)

    def where(self) -> tuple[str, str, int, str]:
        """(Ray node id, node IP address, process id, renderer in use) of this actor. The world is built here,
        so the renderer is the one its episodes will use: ``auto`` falls back to TinyRenderer where EGL does not
        load, and the driver should say so (this actor's warnings stay in Ray's logs)."""
        import ray

        renderer = self.env.unwrapped.renderer_in_use()
        return ray.get_runtime_context().get_node_id(), ray.util.get_node_ip_address(), os.getpid(), renderer

    def reset(self, seed: int) -> tuple[dict, dict]:
        return self.env.reset(seed=seed)

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        return self.env.step(action)


@dataclass
class _Slot:
    actor: Any
    node_id: str = ""
    node_ip: str = ""
    pid: int = 0
    renderer: str = ""
    pending: tuple[str, Any] | None = None
    """(command, Ray object reference) of the call whose answer has not been received yet."""
    failures_in_a_row: int = 0
    resets: int = 0


class RayEnvWorkers:
    """``num_workers`` environments, each in its own Ray actor; the interface of :class:`EnvWorkers`.

    Args:
        address: the Ray cluster to connect to (see :func:`connect`); ignored when this process is connected.
        cpus_per_worker: CPUs each actor reserves. Evaluation actors reserve none: the training actors are idle
            while the held-out episodes run.
        recycle_every: episodes after which an actor is replaced by a fresh one (0: never).
    """

    def __init__(self, num_workers: int, env_id: str, env_kwargs: dict[str, Any], address: str = "",
                 cpus_per_worker: float = 1.0, recycle_every: int = RECYCLE_EVERY_RESETS):  # fmt: skip
        if num_workers < 1:
            raise ValueError(f"num_workers must be at least 1, got {num_workers}")
        connect(address)
        import ray
        from ray.util import get_current_placement_group

        self._ray = ray
        in_placement_group = get_current_placement_group() is not None  # a campaign run: its actors go in there
        self._actor_class = ray.remote(EnvActor).options(
            num_cpus=cpus_per_worker, max_restarts=-1, max_task_retries=0,
            scheduling_strategy=None if in_placement_group else "SPREAD",
        )  # fmt: skip
        self.env_id, self.env_kwargs, self.recycle_every = env_id, dict(env_kwargs), recycle_every
        self.failures = 0
        self.recycled = 0
        self._slots = [_Slot(self._new_actor()) for _ in range(num_workers)]
        for index in range(num_workers):
            self._await_ready(index)

    def _new_actor(self) -> Any:
        return self._actor_class.remote(self.env_id, self.env_kwargs)

    def __len__(self) -> int:
        return len(self._slots)

    # --------------------------------------------------------------------------------------- placement
    def pid(self, index: int) -> int | None:
        """The process id of actor ``index`` (on its node)."""
        return self._slots[index].pid

    def node_ids(self) -> list[str]:
        """The Ray node each actor runs on."""
        return [slot.node_id for slot in self._slots]

    def describe(self) -> str:
        """Where the actors run and what renders their views, in one line."""
        nodes = len(set(self.node_ids()))
        counts = renderer_counts(self.renderers())
        return f"{len(self)} environment actors on {nodes} Ray node{'s' * (nodes != 1)} (renderer: {counts})"

    def renderers(self) -> list[str]:
        """The renderer each actor's environment uses (known since it answered first)."""
        return [slot.renderer for slot in self._slots]

    def on_this_machine(self) -> int:
        """Actors on this machine's IP address: they share its cores with the learner."""
        here = self._ray.util.get_node_ip_address()
        return sum(slot.node_ip == here for slot in self._slots)

    # ---------------------------------------------------------------------------------------- commands
    def send_reset(self, index: int, seed: int) -> None:
        slot = self._slots[index]
        if self.recycle_every > 0 and slot.resets >= self.recycle_every:
            self._recycle(index)
            slot = self._slots[index]
        slot.resets += 1
        slot.pending = ("reset", slot.actor.reset.remote(seed))

    def send_step(self, index: int, action: Any) -> None:
        slot = self._slots[index]
        slot.pending = ("step", slot.actor.step.remote(action))

    def receive(self, index: int) -> tuple[dict, dict] | StepResult | WorkerFailure:
        """The answer of actor ``index``: (observation, info) after a reset, a StepResult after a step."""
        ray, slot = self._ray, self._slots[index]
        assert slot.pending is not None, f"actor {index} was sent nothing"
        (command, reference), slot.pending = slot.pending, None
        try:
            answer = ray.get(reference)
        except ray.exceptions.RayTaskError as error:  # the environment raised: restart the actor
            reason = f"{type(error.cause).__name__}: {error.cause}"
            ray.kill(slot.actor, no_restart=False)
        except ray.exceptions.RayError as error:  # the process or its node died: Ray restarts it
            reason = f"the actor died ({type(error).__name__}: {str(error).splitlines()[0]})"
        else:
            slot.failures_in_a_row = 0
            return StepResult(*answer) if command == "step" else answer
        if slot.failures_in_a_row + 1 >= MAX_FAILURES_IN_A_ROW:
            raise RuntimeError(f"actor {index} failed {MAX_FAILURES_IN_A_ROW} times in a row; last: {reason}")
        slot.failures_in_a_row += 1
        self.failures += 1
        self._await_ready(index)
        return WorkerFailure(index, reason)

    def _await_ready(self, index: int) -> None:
        """Wait until actor ``index`` (new or restarting) answers, and record where it runs. An actor that can no
        longer be restarted is replaced by a new one."""
        ray, slot = self._ray, self._slots[index]
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            try:
                answer = ray.get(slot.actor.where.remote(), timeout=READY_TIMEOUT_S)
                slot.node_id, slot.node_ip, slot.pid, slot.renderer = answer
                return
            except ray.exceptions.ActorDiedError:
                slot.actor = self._new_actor()
            except (ray.exceptions.ActorUnavailableError, ray.exceptions.GetTimeoutError):
                pass  # still restarting
            if time.monotonic() > deadline:
                raise RuntimeError(f"actor {index} did not start within {READY_TIMEOUT_S:.0f} s: does the cluster "
                                   "have a free CPU for it?")  # fmt: skip
            time.sleep(0.2)

    def _recycle(self, index: int) -> None:
        """Replace a healthy actor, between episodes, by a fresh one (``RECYCLE_EVERY_RESETS``)."""
        self._ray.kill(self._slots[index].actor, no_restart=True)
        self._slots[index] = _Slot(self._new_actor())
        self._await_ready(index)
        self.recycled += 1

    def close(self) -> None:
        for slot in self._slots:
            self._ray.kill(slot.actor, no_restart=True)
        self._slots = []

    def __enter__(self) -> RayEnvWorkers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class RayWorkers:
    """Opens :class:`RayEnvWorkers` on the Ray cluster at ``address`` (see :func:`connect`): the
    :class:`apr.train.workers.WorkersFactory` of ``--backend ray``. Training pools reserve one CPU per actor,
    evaluation pools none (the training actors wait while they run)."""

    address: str = ""
    backend = "ray"

    def __call__(
        self, num_workers: int, env_id: str, env_kwargs: dict[str, Any], *, evaluation: bool = False
    ) -> Workers:
        return RayEnvWorkers(num_workers, env_id, env_kwargs, self.address, cpus_per_worker=0.0 if evaluation else 1.0)
