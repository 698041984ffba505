"""The fixation bandit on a trained encoder's frozen r: where a learned fixation's look is lost.

A fresh fixation head (the preset's sizes, the critic kind chosen) is trained with the learner's own losses
(``bandit_critic_loss``, ``sac_actor_loss``, ``temperature_loss``) on the frozen r of the probe's scenes (``apr
probe``'s cache: training-split scenes, and the held-out ones with the test objects), with the proximity reward and
its relabelled points, as in a run but without the grasping. On the held-out scenes it reports how far from the
nearest object (xy, cm, median) the actor's deterministic point lies, and the critics' own best point: the gap
between the two is the actor's, the rest the critic's. The reward reads the simulator's object centres, as rewards
may; the heads see r only.

    python scripts/fixation_bandit_offline.py results/archive/fixed-views/cpu-active-learned-4d__s0 --critic map

Prints one JSON line per run (docs/benchmarks.md, "The fixation bandit on a frozen encoder").
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import torch
import tyro

from apr.model.agent import fixation_points, proximity_reward
from apr.model.heads import MapCritic, PolicyHeads
from apr.model.sac import bandit_critic_loss, sac_actor_loss, temperature_loss
from apr.reproduce.policies import load_policy
from apr.reproduce.probe import HELDOUT_OFFSET, PROBE_SEED, cached_scenes, encode

OBJECT_Z = -0.155
"""m: the objects' centre height given to the reward (the scenes record xy only): the median of the 3,000 object
centres in the fixation samples of ``results/archive/fixed-views/cpu-active-learned-4d__s0`` (range -0.20 to -0.10)."""
SEARCH_GRID = 25
"""Points per side of the search for a tiled critic's best point (a map critic has its own lattice)."""


@dataclass
class Args:
    run: Annotated[Path, tyro.conf.Positional]
    """A run folder (its latest checkpoint): the encoder whose r the bandit reads."""
    critic: Literal["tiled", "map"] = "tiled"
    """The fixation critics (``ModelConfig.fixation_critic``)."""
    scenes: int = 600
    """Training-split scenes the bandit learns from (a 600-grasp run sees 600)."""
    updates: int = 5000
    """Bandit updates (a 600-grasp ``cpu-active-learned-4d`` run makes about 5,000)."""
    batch: int = 8
    """Bandit samples per update (the CPU presets: 8), each with ``--relabels`` more points."""
    relabels: int = 8
    """Relabelled points per sample (``ModelConfig.fixation_relabels``: 8 at paper size, 64 in the CPU presets)."""
    radius: float | None = None
    """m: the proximity reward's radius (default: the run's ``ModelConfig.fixation_proximity_radius``)."""
    seed: int = 0
    """Seeds the head's initialisation and the bandit's draws."""
    cache: Path = Path("runs/probe-scenes")
    """``apr probe``'s scene cache (rendered there if missing)."""
    cache_scenes: int = 2000
    """The cached training-split file to read (``--train-scenes`` of the probe that rendered it)."""


def look_cm(points: torch.Tensor, object_xy: torch.Tensor) -> float:
    """Median xy distance (cm) from each scene's point (S, 2) to its nearest object (S, N, 2; NaN rows: none)."""
    distance = (points[:, None] - object_xy).norm(dim=-1).nan_to_num(nan=float("inf")).amin(dim=1)
    return float(distance.median()) * 100


def best_xy(heads: PolicyHeads, r: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The critics' best x, y per scene (S, 2) in [-1, 1]: a map critic's lattice point, else a grid search at z."""
    if isinstance(heads.critic.q1, MapCritic):
        return heads.critic.best_xy(r)
    line = torch.linspace(-1.0, 1.0, SEARCH_GRID)
    grid = torch.stack(torch.meshgrid(line, line, indexing="ij"), -1).reshape(-1, 2)
    best = []
    for k in range(len(r)):
        actions = torch.cat([grid, z[k].expand(len(grid), 1)], dim=1)
        q1, q2 = heads.critic(r[k : k + 1].expand(len(grid), -1, -1, -1), actions)
        best.append(grid[torch.minimum(q1, q2).argmax()])
    return torch.stack(best)


def main(args: Args) -> dict:
    torch.set_num_threads(1)
    snapshot = load_policy(args.run)
    config = snapshot.config
    env = dataclasses.replace(config.env, renderer="tiny")
    train = cached_scenes(env, "train", args.cache_scenes, PROBE_SEED, args.cache)
    heldout = cached_scenes(env, "test", 100, PROBE_SEED + HELDOUT_OFFSET, args.cache)
    if args.scenes > len(train):
        raise SystemExit(f"--scenes {args.scenes}: the cache has {len(train)} training scenes")
    train_r, heldout_r = encode(snapshot.agent, train)[: args.scenes], encode(snapshot.agent, heldout)
    train_xy = torch.from_numpy(train.object_xy[: args.scenes])
    heldout_xy = torch.from_numpy(heldout.object_xy)
    model = config.model
    radius = model.fixation_proximity_radius if args.radius is None else args.radius
    generator = torch.Generator().manual_seed(args.seed)
    torch.manual_seed(args.seed)
    heads = PolicyHeads(train_r.shape[1], 3, channels=tuple(model.head_channels), grid=train_r.shape[-1],
                        init_temperature=model.init_temperature, target_critic=False, critic=args.critic)  # fmt: skip
    optimizers = [torch.optim.Adam(parameters, lr=model.sac_lr) for parameters in
                  (heads.critic.parameters(), heads.actor.parameters(), [heads.log_alpha])]  # fmt: skip
    started = time.time()
    for _ in range(args.updates):
        index = torch.randint(args.scenes, (args.batch,), generator=generator)
        r = train_r[index]
        with torch.no_grad():
            chosen = heads.actor.sample(r, generator)[0]
        uniform = torch.rand((args.batch, args.relabels, 3), generator=generator) * 2 - 1
        actions = torch.cat([chosen[:, None], uniform], dim=1)  # (B, K, 3)
        xy = train_xy[index]
        centres = torch.cat([xy, torch.full((*xy.shape[:-1], 1), OBJECT_Z)], dim=-1)
        rewards = proximity_reward(actions, centres, radius)
        critic_loss, _ = bandit_critic_loss(heads, r, actions, rewards)
        actor_loss, log_prob, _ = sac_actor_loss(heads, r, generator)
        alpha_loss, _ = temperature_loss(heads.log_alpha, log_prob, heads.target_entropy)
        for optimizer in optimizers:  # as the learner does: one backward of the sum, then every step
            optimizer.zero_grad(set_to_none=True)
        (critic_loss + actor_loss + alpha_loss).backward()
        for optimizer in optimizers:
            optimizer.step()
    with torch.no_grad():
        mode = heads.actor.mode(heldout_r)
        critic_best = best_xy(heads, heldout_r, mode[:, 2:])
    actor_points = fixation_points(mode)[:, :2]
    critic_points = fixation_points(torch.cat([critic_best, mode[:, 2:]], dim=1))[:, :2]
    result = {
        "run": str(args.run), "critic": args.critic, "scenes": args.scenes, "updates": args.updates,
        "batch": args.batch, "relabels": args.relabels, "radius": radius, "seed": args.seed,
        "actor_cm": round(look_cm(actor_points, heldout_xy), 2),
        "critic_best_cm": round(look_cm(critic_points, heldout_xy), 2),
        "actor_spread_cm": [round(float(s) * 100, 2) for s in actor_points.std(0)],
        "critic_best_spread_cm": [round(float(s) * 100, 2) for s in critic_points.std(0)],
        "seconds": round(time.time() - started),
    }  # fmt: skip
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
