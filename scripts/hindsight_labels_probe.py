"""Where a learned fixation's look is lost under the paper's grasp reward: the bandit's own samples, read three ways.

A run of ``cpu-active-learned-4d`` stores, for each episode, the frame the fixation chose from, the point chosen, the
grasp reward, whether an object was lifted and the tool tip at the grasp's start (and, for probes only, the objects'
centres). From the run's newest checkpoint and its replay this script reports:

1. where the labels point: for every lift, the xy distance (cm) from the tool tip at the grasp's start to the nearest
   object centre. Hindsight relabelling can only teach a look as precise as that.
2. where the run looked: the xy distance from the points it chose to the nearest object, early and late in training,
   and the grasp reward of its samples by that distance (what looking near an object earns the chosen point).
3. an upper bound of the bandit's critic on this encoder: a fresh map critic (the preset's size) trained on the frozen
   ``r`` of the first 80% of the samples, each with 64 relabelled points, with the labels of ``--rewards`` (the
   paper's grasp reward relabelled, "grasp"; its cone, "tip-proximity"; the simulator's object centres, "proximity",
   the label a probe may read; the paper's grasp reward of the chosen point alone, not relabelled, "chosen"), and its
   best point's distance to the nearest object on the last 20%, beside one
   fixed point (the bin centre) and the run's own points on those samples.
4. with ``--critics projective``, the same for a critic that reads each lattice point's value where the robot's own
   cameras see that point: the conv block's features sampled, in each initial view, at the point's image position
   (its projection through the head camera's pose and field of view, then the log-polar warp), and one small network
   shared by every point (:class:`ProjectiveMapCritic`). What a place looks like is learned once for all places,
   where the map critic's linear layer learns each place's value apart.

    python scripts/hindsight_labels_probe.py results/fixation-reward/cpu-active-learned-4d-relabel__s0
    python scripts/hindsight_labels_probe.py results/table1-cpu/cpu-active-learned-4d__s1 --rewards chosen proximity \
        --critics map projective

Prints one JSON object (docs/investigations.md, "The fixation bandit's reward").
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import torch
import torch.nn.functional as F
import tyro
from torch import nn

from apr.envs.config import HEAD, REWARD, SCENE
from apr.envs.rendering import Camera
from apr.model.agent import Observation, fixation_points, hindsight_grasp_reward, proximity_reward
from apr.model.heads import MapCritic, PolicyHeads
from apr.model.sac import bandit_critic_loss
from apr.reproduce.episodes import make_env
from apr.reproduce.policies import load_run
from apr.train.checkpoints import newest_intact, replay_file
from apr.train.config import EnvConfig
from apr.train.replay import ReplayBuffer, ReplaySpec

Reward = Literal["grasp", "tip-proximity", "proximity", "chosen"]
CriticKind = Literal["map", "projective"]


@dataclass
class Args:
    run: Annotated[Path, tyro.conf.Positional]
    """A run folder of a learned-fixation preset, with its checkpoints."""
    rewards: tuple[Reward, ...] = ("grasp", "tip-proximity", "proximity")
    """The labels the upper-bound critic is trained on, one critic each."""
    radii_cm: tuple[float, ...] = (10.0,)
    """The radius of the hindsight labels ("grasp", "tip-proximity"), one critic each: the paper's 10 cm, or narrower
    balls and cones around the tool tip (ours; the robot's knowledge still)."""
    train_samples: tuple[int, ...] = (0,)
    """How many samples each critic learns from, one critic each: the last N before the held-out ones (0: all of the
    first 80%). Fewer samples than the run's say how the look improves with the bandit's data."""
    critics: tuple[CriticKind, ...] = ("map",)
    """The upper-bound critic's kind, one critic each: the preset's map critic, or one that reads each place where the
    initial views see it (:class:`ProjectiveMapCritic`)."""
    updates: int = 3000
    relabels: int = 64
    batch: int = 32
    seed: int = 0


def nearest_xy_cm(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(B,) cm from each point's xy (B, 2+) to the nearest of its scene's object centres (B, N, 3), NaN rows
    skipped."""
    offsets = points[:, None, :2] - centres[:, :, :2]
    return 100 * np.nanmin(np.linalg.norm(offsets, axis=-1), axis=1)


def image_coordinates(camera: Camera, points: np.ndarray, foveation: str) -> np.ndarray:
    """Where the world points (N, 3) lie in the camera's 64x64 view: (N, 2) in [-1, 1], x to the right and y down (the
    frame of ``grid_sample``): the pinhole projection of the camera's pose and square field of view, then, for the
    log-polar view, the inverse of the warp ``(u, v) -> log(rho + 1) (u, v)`` (:func:`apr.foveation.logpolar_grid`)."""
    forward = camera.forward / np.linalg.norm(camera.forward)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    offset = points - camera.eye
    scale = (offset @ forward) * math.tan(math.radians(camera.fov_deg) / 2)
    rendered = np.stack([offset @ right / scale, -(offset @ up) / scale], axis=-1)
    if foveation != "logpolar":
        return rendered
    radius = np.linalg.norm(rendered, axis=-1)
    low, high = np.zeros_like(radius), np.full_like(radius, 4.0)
    for _ in range(60):  # rho log(rho + 1) = radius, by bisection (it rises monotonically)
        middle = (low + high) / 2
        below = middle * np.log(middle + 1) < radius
        low, high = np.where(below, middle, low), np.where(below, high, middle)
    return rendered * ((low + high) / 2 / np.maximum(radius, 1e-12))[:, None]


def initial_view_grid(env_config: EnvConfig, map_grid: int, height: float) -> torch.Tensor:
    """(V, G, G, 2): where each point of the map critic's lattice over the fixation box (at ``height`` m) lies in
    each fixed initial view, the lattice indexed [x, y] as :class:`MapCritic`'s."""
    env = make_env(env_config, "train")
    try:
        env.reset(seed=0)
        world = env.unwrapped.world
        lattice = torch.linspace(-1.0, 1.0, map_grid)
        x, y = torch.meshgrid(lattice, lattice, indexing="ij")
        points = fixation_points(torch.stack([x, y, torch.zeros_like(x)], dim=-1).reshape(-1, 3)).numpy()
        points[:, 2] = height
        grids = []
        for view in HEAD.fixed_initial_views:
            camera, _ = world.head.look_from(env.unwrapped.fixation_point, *view)
            grids.append(image_coordinates(camera, points, env_config.foveation).reshape(map_grid, map_grid, 2))
    finally:
        env.close()
    return torch.from_numpy(np.stack(grids)).float()


class ProjectiveMapCritic(MapCritic):
    """A map critic whose value at each lattice point is read where the initial views see that point: the conv block's
    features (without the flattening) sampled at the point's position in each view, concatenated, and a 1x1-conv
    network shared by all points. ``view_grid``: (V, G, G, 2) from :func:`initial_view_grid`."""

    def __init__(self, representation_channels: int, action_dim: int, channels: tuple[int, ...],
                 view_grid: torch.Tensor, hidden: int = 32) -> None:  # fmt: skip
        super().__init__(representation_channels, action_dim, channels, map_grid=view_grid.shape[1])
        self.trunk = self.trunk[:-1]  # the features keep their places
        self.out = nn.Sequential(nn.Conv2d(channels[-1] * len(view_grid), hidden, 1), nn.ReLU(),
                                 nn.Conv2d(hidden, 1, 1))  # fmt: skip
        self.register_buffer("view_grid", view_grid)

    def value_map(self, r: torch.Tensor) -> torch.Tensor:
        features = self.trunk(r.float())  # (B, C, 16, 16)
        # grid_sample's point is (x, y) = (column, row) of the image; view_grid holds (x right, y down) already
        sampled = [F.grid_sample(features, grid.expand(len(r), -1, -1, -1), align_corners=False)
                   for grid in self.view_grid]  # fmt: skip
        return self.out(torch.cat(sampled, dim=1))[:, 0]  # (B, G, G)


def main(args: Args) -> dict:
    torch.manual_seed(args.seed)
    snapshot = load_run(args.run)
    agent, config = snapshot.agent, snapshot.config
    checkpoint, state = newest_intact(args.run, with_replay=True)
    spec = ReplaySpec(
        image_shape=(3, 64, 64, config.env.image_channels),
        viewpoint_shape=(3, 6),
        gripper_dim=9,
        grasp_action_dim=config.env.dof,
        fixation_dim=3,
        steps_left=config.env.observes_steps_left,
    )
    replay = ReplayBuffer(config.replay_capacity, spec)
    replay.load(replay_file(checkpoint, state))
    count = min(replay.f_count, replay.fixation_capacity)
    frames = replay.frames.batch(replay.f_frame[:count])
    action, reward = replay.f_action[:count], replay.f_reward[:count]
    lifted, tip, centres = replay.f_lifted[:count], replay.f_tip[:count], replay.f_centres[:count]
    chosen = fixation_points(torch.from_numpy(action)).numpy()

    report: dict = {"run": str(args.run), "checkpoint": checkpoint.name, "samples": int(count),
                    "lifts": int(lifted.sum()), "rewarded": int(reward.sum())}  # fmt: skip
    lift = lifted > 0
    report["lift_tip_to_object_cm"] = float(np.median(nearest_xy_cm(tip[lift], centres[lift])))
    looked = nearest_xy_cm(chosen, centres)
    fifth = max(count // 5, 1)
    report["looked_first_fifth_cm"] = float(np.median(looked[:fifth]))
    report["looked_last_fifth_cm"] = float(np.median(looked[-fifth:]))
    edges = (0, 2, 4, 6, 8, 12, math.inf)
    report["reward_by_look_cm"] = []
    for low, high in zip(edges[:-1], edges[1:], strict=True):
        band = (looked >= low) & (looked < high)
        mean = float(reward[band].mean()) if band.any() else None
        to = None if math.isinf(high) else high  # JSON has no infinity
        report["reward_by_look_cm"].append({"from": low, "to": to, "samples": int(band.sum()), "reward": mean})
    bin_centre = np.broadcast_to(np.array(SCENE.bin_centre), chosen.shape)
    report["bin_centre_cm"] = float(np.median(nearest_xy_cm(bin_centre, centres)))

    with torch.no_grad():
        obs = Observation.from_env(frames, agent.device)
        r = torch.cat([agent._head_input(agent._scene(obs[k : k + 64], agent._first_two(len(obs[k : k + 64])), 0),
                                         obs[k : k + 64]) for k in range(0, len(obs), 64)])  # fmt: skip
    train, held = slice(0, count - fifth), slice(count - fifth, count)
    report["held_out_samples"] = int(fifth)
    report["held_out_run_looked_cm"] = float(np.median(looked[held]))
    model = config.model
    rng = torch.Generator().manual_seed(args.seed)
    arrays = {"action": action, "reward": reward, "lifted": lifted, "tip": tip, "centres": centres}
    tensors = {name: torch.from_numpy(value) for name, value in arrays.items()}
    paper_radius = (REWARD.fixation_radius * 100,)
    variants = [(kind, radius, samples, critic) for kind in args.rewards
                for radius in (paper_radius if kind in ("proximity", "chosen") else args.radii_cm)
                for samples in args.train_samples for critic in args.critics]  # fmt: skip
    view_grid = None
    if "projective" in args.critics:
        if config.env.initial_views != "fixed":
            raise SystemExit(f"{args.run}: --critics projective needs the fixed initial views of the CPU presets")
        height = float(np.nanmedian(centres[..., 2]))  # where objects lie: the lattice's height
        view_grid = initial_view_grid(config.env, MapCritic(1, 3).map_grid, height)
        report["projective_lattice_height_m"] = height
        report["projective_lattice_in_view"] = float((view_grid.abs() <= 1).all(dim=-1).float().mean())
    for kind, radius_cm, samples, critic in variants:  # "chosen": the point the run chose and its reward, one each
        first = train.stop - min(samples or train.stop, train.stop)
        heads = PolicyHeads(r.shape[1], 3, tuple(model.head_channels), grid=r.shape[-1], critic="map")
        if critic == "projective":  # the twin critics replaced, the rest of the heads kept
            heads.critic.q1, heads.critic.q2 = (ProjectiveMapCritic(r.shape[1], 3, tuple(model.head_channels),
                                                                    view_grid) for _ in range(2))  # fmt: skip
        optimizer = torch.optim.Adam(heads.critic.parameters(), lr=model.sac_lr)
        for _ in range(args.updates):
            index = torch.randint(first, train.stop, (args.batch,), generator=rng)
            points = torch.rand((args.batch, args.relabels, 3), generator=rng) * 2 - 1
            if kind == "chosen":
                points = tensors["action"][index][:, None].float()
                labels = tensors["reward"][index][:, None].float()
            elif kind == "proximity":
                labels = proximity_reward(points, tensors["centres"][index], REWARD.fixation_radius)
            else:
                profile = "ball" if kind == "grasp" else "cone"
                labels = hindsight_grasp_reward(points, tensors["lifted"][index], tensors["tip"][index],
                                                radius_cm / 100, profile)  # fmt: skip
            loss, _ = bandit_critic_loss(heads, r[index], points, labels)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        with torch.no_grad():
            best = heads.critic.best_xy(r[held])
        points = fixation_points(torch.cat([best, torch.zeros(len(best), 1)], dim=1)).numpy()
        name = kind if radius_cm == REWARD.fixation_radius * 100 else f"{kind}@{radius_cm:g}cm"
        name += f"/{samples}" if samples else ""
        name += "/projective" if critic == "projective" else ""
        report[f"critic_{name}_held_out_cm"] = float(np.median(nearest_xy_cm(points, centres[held])))
    print(json.dumps(report))
    return report


if __name__ == "__main__":
    main(tyro.cli(Args))
