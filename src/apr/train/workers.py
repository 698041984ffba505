"""Environment workers: one process and one physics client per environment, restarted when one dies.

Gymnasium's ``AsyncVectorEnv`` stops the whole vector when a worker fails; a long training run must instead
replace the worker, count the episode it lost, and go on. So the pool is ours, and small: each worker owns
one environment and answers ``reset(seed)`` and ``step(action)`` over a pipe.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any, Protocol

import gymnasium as gym

MAX_FAILURES_IN_A_ROW = 5
"""A worker that fails this many times without one good answer between stops the run: it is not bad luck."""
WORKER_NICENESS = 10
"""Environment processes run at this lower scheduling priority (``os.nice``): where workers and the learner share
cores, the learner, whose updates every round waits for, gets its core first and the workers the rest
(docs/benchmarks.md, "Training speed")."""
RECYCLE_EVERY_RESETS = 1_000
"""A worker is replaced by a fresh process after this many episodes. pybullet keeps memory of the bodies it
removes (and EGL their GPU memory, bullet3 #1867): a worker's RSS grows by about 0.3 MiB per episode, with either
renderer, for as long as it lives (docs/benchmarks.md). A fresh environment plays a seed exactly as a used one
does, so recycling changes no result; it costs one process start (a few seconds) per this many episodes."""


@dataclass
class StepResult:
    observation: dict[str, Any]
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any]


@dataclass
class WorkerFailure:
    """A worker died or raised; it has been replaced, and its episode is lost."""

    worker: int
    reason: str


@dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    connection: Connection
    pending: str | None = None
    """The command whose answer has not been received yet."""
    failures_in_a_row: int = field(default=0)
    resets: int = 0
    """Episodes this process has started."""


def _serve(connection: Connection, env_id: str, env_kwargs: dict[str, Any]) -> None:
    """The worker's loop: build the env, then answer commands until told to close."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the trainer's to handle
    os.nice(WORKER_NICENESS)
    import apr  # noqa: F401  (registers the environments in this process)

    env = gym.make(env_id, **env_kwargs)
    try:
        while True:
            command, payload = connection.recv()
            if command == "close":
                break
            try:
                if command == "reset":
                    observation, info = env.reset(seed=payload)
                    connection.send(("ok", (observation, info)))
                elif command == "step":
                    connection.send(("ok", env.step(payload)))
                elif command == "renderer":
                    connection.send(("ok", env.unwrapped.renderer_in_use()))
                else:
                    raise ValueError(f"unknown command {command!r}")
            except Exception as error:  # a physics or env error: report it, then let the pool replace us
                connection.send(("error", f"{type(error).__name__}: {error}"))
                break
    finally:
        env.close()
        connection.close()


class Workers(Protocol):
    """What a round of episodes needs of a pool of environments (:func:`apr.train.rollout.run_round`)."""

    def __len__(self) -> int: ...

    def send_reset(self, index: int, seed: int) -> None: ...

    def send_step(self, index: int, action: Any) -> None: ...

    def receive(self, index: int) -> tuple[dict, dict] | StepResult | WorkerFailure: ...

    def pid(self, index: int) -> int | None: ...

    def on_this_machine(self) -> int:
        """Workers that share this machine's cores with the learner."""
        ...

    def describe(self) -> str:
        """Where the workers run, in one line."""
        ...

    def renderers(self) -> list[str]:
        """The renderer each worker's environment uses, "egl" or "tiny" (worlds not built yet are built)."""
        ...

    def close(self) -> None: ...

    def __enter__(self) -> Workers: ...

    def __exit__(self, *exc: object) -> None: ...


class WorkersFactory(Protocol):
    """Opens the pool of environments a run or an evaluation steps.

    The caller chooses it and passes it down (``Trainer(config, workers=...)``, ``evaluate(..., workers=...)``),
    as a Stable-Baselines3 user chooses a VecEnv: :class:`LocalWorkers` (processes of this machine, the default)
    or ``apr.cluster.ray_workers.RayWorkers`` (Ray actors). Training never imports the cluster layer.
    """

    backend: str
    """The ``TrainConfig.backend`` this factory serves ("local", "ray"); a trainer refuses a factory whose backend
    is not its configuration's, so that ``config.json`` says where a run's environments ran."""

    def __call__(
        self, num_workers: int, env_id: str, env_kwargs: dict[str, Any], *, evaluation: bool = False
    ) -> Workers:
        """A pool of ``num_workers`` environments ``gymnasium.make(env_id, **env_kwargs)``; ``evaluation``: for
        held-out episodes, which run while the training pool waits (a Ray pool then reserves no CPU)."""
        ...


class LocalWorkers:
    """Opens :class:`EnvWorkers`, one process of this machine per environment (``--backend local``)."""

    backend = "local"

    def __call__(
        self, num_workers: int, env_id: str, env_kwargs: dict[str, Any], *, evaluation: bool = False
    ) -> Workers:
        return EnvWorkers(num_workers, env_id, env_kwargs)


class EnvWorkers:
    """``num_workers`` environments, each in its own process.

    Calls are asynchronous: ``send_reset``/``send_step`` post a command to one worker, ``receive`` collects its
    answer. A worker that died or raised is restarted (a fresh process and environment) and ``receive``
    returns a :class:`WorkerFailure` instead of a result.
    """

    def __init__(self, num_workers: int, env_id: str, env_kwargs: dict[str, Any],
                 recycle_every: int = RECYCLE_EVERY_RESETS):  # fmt: skip
        if num_workers < 1:
            raise ValueError(f"num_workers must be at least 1, got {num_workers}")
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs)
        self.recycle_every = recycle_every
        """Episodes after which a worker is replaced by a fresh process (0: never)."""
        self.recycled = 0
        self._context = multiprocessing.get_context("spawn")
        self._workers = [self._start() for _ in range(num_workers)]
        self.failures = 0

    def __len__(self) -> int:
        return len(self._workers)

    def _start(self) -> _Worker:
        parent, child = self._context.Pipe()
        process = self._context.Process(target=_serve, args=(child, self.env_id, self.env_kwargs), daemon=True)
        process.start()
        child.close()
        return _Worker(process, parent)

    def pid(self, index: int) -> int | None:
        return self._workers[index].process.pid

    def on_this_machine(self) -> int:
        return len(self._workers)

    def describe(self) -> str:
        return f"{len(self)} environment processes on this machine"

    def renderers(self) -> list[str]:
        """The renderer each worker's environment uses (asked between episodes; a worker that fails to answer is
        replaced, counted in ``failures``, and asked again)."""
        for index in range(len(self)):
            self._send(index, ("renderer", None))
        answers: list[str] = []
        for index in range(len(self)):
            answer = self.receive(index)
            while isinstance(answer, WorkerFailure):
                self._send(index, ("renderer", None))
                answer = self.receive(index)
            answers.append(str(answer))
        return answers

    def send_reset(self, index: int, seed: int) -> None:
        if self.recycle_every > 0 and self._workers[index].resets >= self.recycle_every:
            self._recycle(index)
        self._workers[index].resets += 1
        self._send(index, ("reset", seed))

    def send_step(self, index: int, action: Any) -> None:
        self._send(index, ("step", action))

    def _send(self, index: int, message: tuple) -> None:
        self._workers[index].pending = message[0]
        with contextlib.suppress(BrokenPipeError, ConnectionResetError, EOFError, OSError):
            self._workers[index].connection.send(message)  # if it died, ``receive`` reports and replaces it

    def receive(self, index: int) -> tuple[dict, dict] | StepResult | WorkerFailure:
        """The answer of worker ``index``: (observation, info) after a reset, a StepResult after a step."""
        worker = self._workers[index]
        try:
            status, payload = worker.connection.recv()
        except (EOFError, ConnectionResetError, OSError):
            status, payload = "error", f"the worker process exited (code {worker.process.exitcode})"
        command, worker.pending = worker.pending, None
        if status == "ok":
            worker.failures_in_a_row = 0
            return StepResult(*payload) if command == "step" else payload
        if worker.failures_in_a_row + 1 >= MAX_FAILURES_IN_A_ROW:
            raise RuntimeError(f"worker {index} failed {MAX_FAILURES_IN_A_ROW} times in a row; last: {payload}")
        self._replace(index)
        return WorkerFailure(index, payload)

    def _replace(self, index: int) -> None:
        old = self._workers[index]
        old.connection.close()
        old.process.join(timeout=5)
        if old.process.is_alive():
            old.process.kill()
        self._workers[index] = self._start()
        self._workers[index].failures_in_a_row = old.failures_in_a_row + 1
        self.failures += 1

    def _recycle(self, index: int) -> None:
        """Replace a healthy worker, between episodes, by a fresh process (``RECYCLE_EVERY_RESETS``)."""
        old = self._workers[index]
        with contextlib.suppress(BrokenPipeError, OSError):
            old.connection.send(("close", None))
        old.process.join(timeout=10)
        if old.process.is_alive():
            old.process.kill()
        old.connection.close()
        self._workers[index] = self._start()
        self.recycled += 1

    def close(self) -> None:
        for worker in self._workers:
            with contextlib.suppress(BrokenPipeError, OSError):
                worker.connection.send(("close", None))
        for worker in self._workers:
            worker.process.join(timeout=10)
            if worker.process.is_alive():
                worker.process.kill()
            worker.connection.close()
        self._workers = []

    def __enter__(self) -> EnvWorkers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def pool_renderer(renderers: list[str]) -> str:
    """What a pool's environments render with: "egl" or "tiny" when they agree, "mixed" when they do not."""
    found = set(renderers)
    return found.pop() if len(found) == 1 else "mixed"


def renderer_counts(renderers: list[str]) -> str:
    """``renderers`` counted, e.g. "62 with egl, 2 with tiny"."""
    return ", ".join(f"{renderers.count(name)} with {name}" for name in sorted(set(renderers)))
