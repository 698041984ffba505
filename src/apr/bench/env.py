"""``apr bench env``: environment speed against the raw ceiling of the same work, for each renderer.

Measured, per renderer, in a process of its own (one EGL world per process):

- env step: ``ActiveGraspEnv`` (6-DoF, environment target, log-polar) with random actions that never descend,
  so no step includes the 1,000-step grasp routine; per step: IK, 80 physics steps, three head poses, three
  256x256 renders with masks, the warp.
- raw ceiling: the same world and cameras, nothing but 80 ``stepSimulation`` calls and three renders per step.
- env reset: the whole ``reset`` (drop and settle 5 objects from the pool, pick the target, three views).
- scene reset: the physics of a reset alone (reset the arm and head, drop and settle the objects), which is
  what the reload baseline does.
- reload reset: the benchmark's way, ``resetSimulation``, reload every URDF, then settle 2,500 steps.

Everything is timed after ``warmup_resets`` untimed resets: a world that has run many episodes, as in training.
Each (renderer, render size) pair is one row. Beside the wall-clock rates, the CPU time of an env step (every
thread of the process: EGL through llvmpipe renders on several) says what a step costs where workers and the
learner share the cores. A second table says what a smaller render loses: the mean absolute difference (0-255) of
the log-polar 64x64 views rendered at each size from those rendered at 512x512 by the same cameras, in three rings
of the output image (radius below 0.3, 0.3-0.6, above 0.6; 1 is the output's edge).
"""

from __future__ import annotations

import multiprocessing
import time
from dataclasses import dataclass

import numpy as np


@dataclass
class EnvBenchArgs:
    """Time env steps and resets against the raw ceiling and the reload-everything reset."""

    renderers: tuple[str, ...] = ("egl", "tiny")
    """Renderers to measure, each in its own process."""
    render_sizes: tuple[int, ...] = (256,)
    """Render sides to measure (multiples of 64; the paper: 256)."""
    steps: int = 60
    """Env steps timed per renderer (and as many raw-ceiling steps)."""
    resets: int = 8
    """Env resets timed per renderer."""
    reloads: int = 3
    """Reload-everything resets timed per renderer (about a second each)."""
    warmup_resets: int = 40
    """Untimed env resets first, so the object pool holds what it holds in a long run (parked objects cost
    render time)."""
    seed: int = 0


def run(args: EnvBenchArgs) -> None:
    context = multiprocessing.get_context("spawn")
    rows = []
    for renderer in args.renderers:
        for size in args.render_sizes:
            with context.Pool(1) as pool:
                rows.append(pool.apply(measure, (renderer, size, args)))
    header = ("renderer", "render", "env step/s", "CPU ms/step", "raw step/s", "env/raw", "env reset/s",
              "scene reset/s", "reload reset/s", "scene reset speed-up")  # fmt: skip
    print("| " + " | ".join(header) + " |")
    print("|" + " --- |" * len(header))
    for row in rows:
        if row.get("unavailable"):
            print(f"| {row['renderer']} | {row['render_size']} | unavailable: {row['unavailable']} |")
            continue
        print(
            f"| {row['renderer']} | {row['render_size']} | {row['env_step_hz']:.2f} | {row['env_step_cpu_ms']:.0f} | "
            f"{row['raw_step_hz']:.2f} | {row['env_step_hz'] / row['raw_step_hz']:.0%} | {row['env_reset_hz']:.2f} | "
            f"{row['scene_reset_hz']:.2f} | {row['reload_reset_hz']:.3f} | "
            f"{row['scene_reset_hz'] / row['reload_reset_hz']:.1f}x |"
        )
    fovea = [row for row in rows if "fovea_error" in row]
    if fovea:
        print("\nlog-polar views against the same views rendered at 512x512, mean |difference| (0-255) by ring:")
        print("| renderer | render | r < 0.3 | 0.3-0.6 | r > 0.6 |")
        print("| --- | --- | --- | --- | --- |")
        for row in fovea:
            inner, middle, outer = row["fovea_error"]
            print(f"| {row['renderer']} | {row['render_size']} | {inner:.2f} | {middle:.2f} | {outer:.2f} |")


def measure(renderer: str, render_size: int, args: EnvBenchArgs) -> dict:
    """All the timings of one renderer at one render size (runs in a fresh process)."""
    from apr.envs.config import PHYSICS
    from apr.envs.grasp_env import ActiveGraspEnv

    try:
        env = ActiveGraspEnv(dof=6, target="env", renderer=renderer, render_size=render_size)
    except RuntimeError as error:
        return {"renderer": renderer, "render_size": render_size, "unavailable": str(error).split(".")[0]}
    rng = np.random.default_rng(args.seed)
    env.reset(seed=args.seed)
    for _ in range(args.warmup_resets):
        env.reset()

    step_seconds = []
    cpu_started = time.process_time()
    for _ in range(args.steps):
        action = rng.uniform(-1.0, 1.0, env.dof).astype(np.float32)
        action[2] = abs(action[2])  # never descend: no step includes the grasp routine
        start = time.perf_counter()
        _, _, terminated, truncated, info = env.step(action)
        step_seconds.append(time.perf_counter() - start)
        assert not info["grasp_attempted"]
        if terminated or truncated:
            env.reset()
    step_cpu_seconds = (time.process_time() - cpu_started) / args.steps  # a few resets included

    world = env.world
    cameras = [world.head.look_at(env.fixation_point, rng)[0] for _ in range(3)]
    start = time.perf_counter()
    for _ in range(args.steps):
        world.step_simulation(PHYSICS.action_repeat)
        for camera in cameras:
            world.render(camera, segmentation=True, from_head=True)
    raw_seconds = (time.perf_counter() - start) / args.steps
    fovea_error = _fovea_error(world, cameras, render_size)

    start = time.perf_counter()
    for _ in range(args.resets):
        env.reset()
    reset_seconds = (time.perf_counter() - start) / args.resets
    start = time.perf_counter()
    for _ in range(args.resets):  # the physics of a reset alone, as the reload baseline is
        env.task.reset(world, rng)
    scene_reset_seconds = (time.perf_counter() - start) / args.resets
    numbers = list(world.object_numbers)
    env.close()

    reload_seconds = _reload_reset_seconds(numbers, args.reloads, args.seed)
    return {
        "renderer": renderer,
        "render_size": render_size,
        "env_step_hz": 1.0 / float(np.mean(step_seconds)),
        "env_step_cpu_ms": 1000 * step_cpu_seconds,
        "fovea_error": fovea_error,
        "raw_step_hz": 1.0 / raw_seconds,
        "env_reset_hz": 1.0 / reset_seconds,
        "scene_reset_hz": 1.0 / scene_reset_seconds,
        "reload_reset_hz": 1.0 / reload_seconds,
    }


def _fovea_error(world: object, cameras: list, render_size: int, reference_size: int = 512) -> tuple[float, ...]:
    """Mean |difference| (0-255) between the log-polar views of ``cameras`` rendered at ``render_size`` and at
    ``reference_size``, in the rings r < 0.3, 0.3 <= r < 0.6 and r >= 0.6 of the 64x64 output (r = 1 at its
    edge)."""
    from apr.envs.config import CAMERA
    from apr.envs.rendering import render
    from apr.foveation import logpolar_warp

    axis = np.linspace(-1.0, 1.0, CAMERA.image_size)
    radius = np.hypot(*np.meshgrid(axis, axis))
    rings = [radius < 0.3, (radius >= 0.3) & (radius < 0.6), radius >= 0.6]
    errors = [[] for _ in rings]
    for camera in cameras:
        views = [
            logpolar_warp(render(world.client, camera, size, world.renderer, CAMERA.near, CAMERA.far)[0]).astype(float)
            for size in (render_size, reference_size)
        ]
        difference = np.abs(views[0] - views[1]).mean(axis=-1)
        for ring, error in zip(rings, errors, strict=True):
            error.append(difference[ring].mean())
    return tuple(float(np.mean(error)) for error in errors)


def _reload_reset_seconds(numbers: list[int], repeats: int, seed: int) -> float:
    """Mean seconds of the benchmark's reset: reset the simulation, reload every URDF, settle 2,500 steps."""
    import pybullet as p
    import pybullet_data
    from pybullet_utils.bullet_client import BulletClient

    from apr.envs.config import OBJECTS, PHYSICS, SCENE
    from apr.envs.objects import object_urdf

    client = BulletClient(connection_mode=p.DIRECT)
    client.setAdditionalSearchPath(pybullet_data.getDataPath())
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    for _ in range(repeats):
        client.resetSimulation()
        client.setPhysicsEngineParameter(numSolverIterations=PHYSICS.solver_iterations)
        client.setTimeStep(PHYSICS.time_step)
        client.setGravity(0, 0, PHYSICS.gravity)
        client.loadURDF("plane.urdf", (0, 0, -1))
        client.loadURDF("table/table.urdf", SCENE.table_position)
        client.loadURDF("tray/tray.urdf", SCENE.tray_position, SCENE.tray_orientation)
        kuka = client.loadSDF("kuka_iiwa/kuka_with_gripper2.sdf")[0]
        client.resetBasePositionAndOrientation(kuka, SCENE.kuka_base_position, (0, 0, 0, 1))
        client.loadURDF("xarm/xarm6_robot.urdf", SCENE.head_base_position, useFixedBase=True)
        for number in numbers:
            x = OBJECTS.drop_x[0] + OBJECTS.drop_x[1] * rng.uniform()
            y = OBJECTS.drop_y_width * (rng.uniform() - 0.5)
            client.loadURDF(object_urdf(number), (x, y, OBJECTS.drop_z))
        for _ in range(2500):
            client.stepSimulation()
    seconds = (time.perf_counter() - start) / repeats
    client.disconnect()
    return seconds
