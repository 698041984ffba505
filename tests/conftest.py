"""Shared fixtures of the environment tests.

Every environment made here has the environments' default renderer, TinyRenderer, which any number of worlds
of one process share; pybullet's EGL plugin allows one EGL world per process, and the tests of that policy
(``test_env_world.py::test_egl_one_world_per_process``) must find none open. Every environment made through
these fixtures is closed at teardown.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator

import gymnasium
import numpy as np
import pytest
import torch

import apr  # noqa: F401  (registers the environments)

ACTIVE = "apr/ActiveGrasp-v4"
PASSIVE = "apr/PassiveGrasp-v4"
FALLBACK_WARNING = "falls back to TinyRenderer"

MakeEnv = Callable[..., gymnasium.Env]


def _factory() -> tuple[MakeEnv, list[gymnasium.Env]]:
    made: list[gymnasium.Env] = []

    def make(env_id: str = ACTIVE, **kwargs) -> gymnasium.Env:
        env = gymnasium.make(env_id, **kwargs)
        made.append(env)
        return env

    return make, made


@pytest.fixture
def one_thread() -> Iterator[None]:
    """Small tensors: one thread is fastest, and much faster than two beside other work on a 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def make_env() -> Iterator[MakeEnv]:
    """``make_env(env_id=ACTIVE, **kwargs)``: ``gymnasium.make``, closed at teardown."""
    make, made = _factory()
    yield make
    for env in made:
        env.close()


@pytest.fixture(scope="module")
def make_module_env() -> Iterator[MakeEnv]:
    """As ``make_env``, for environments shared by the tests of one module (each test resets what it uses)."""
    make, made = _factory()
    yield make
    for env in made:
        env.close()


def assert_obs_equal(first: dict, second: dict, where: str = "") -> None:
    """Two observations are identical, key by key (exact, dtype included)."""
    assert first.keys() == second.keys(), where
    for key in first:
        a, b = np.asarray(first[key]), np.asarray(second[key])
        assert a.dtype == b.dtype, f"{where} {key}: {a.dtype} != {b.dtype}"
        assert np.array_equal(a, b), f"{where} {key}: max abs diff {np.abs(a.astype(float) - b).max()}"


def obs_differ(first: dict, second: dict) -> bool:
    return any(not np.array_equal(np.asarray(first[k]), np.asarray(second[k])) for k in first)


def assert_recycling_replays_a_seed(workers) -> dict:
    """Worker 0 of a pool made with ``recycle_every=1``: its second reset runs in a fresh process (or actor),
    which plays the seed exactly as the first one did. Returns the observation of that seed."""
    workers.send_reset(0, 7)
    first, _ = workers.receive(0)
    before = workers.pid(0)
    workers.send_reset(0, 7)
    again, _ = workers.receive(0)
    assert workers.pid(0) != before and workers.recycled == 1
    assert_obs_equal(first, again, "after recycling")
    return first


def kill_worker_once_while_stepping(trainer, grasps: int, worker: int) -> list[int]:
    """Make ``trainer`` SIGKILL env worker ``worker`` while it steps, once, when the run is at ``grasps`` grasps;
    returns the list that receives the killed process id."""
    learn, killed = trainer._learn, []

    def kill_then_learn(steps: int) -> None:
        if not killed and trainer.progress.grasps == grasps:
            pid = trainer.workers.pid(worker)
            os.kill(pid, signal.SIGKILL)  # a Ray actor too: a simulated node is a process of this machine
            killed.append(pid)
        learn(steps)

    trainer._learn = kill_then_learn
    return killed
