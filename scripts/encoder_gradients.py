"""How large is each loss's gradient where it reaches the encoder? Read on a run's own checkpoint and replay.

With ``--model.critic-trains-encoder`` the encoder's gradient is the sum of the ELBO's and the critics'; one Adam step
takes the sum, so a loss whose gradient is hundreds of times smaller hardly moves the encoder. This script draws
grasp batches from the run's replay (the size its learner drew), computes every loss of one joint update at the
checkpoint's update count (``APRAgent.compute_losses``) and, for each loss, the norm of its gradient over the encoder's
parameters, then prints one line per batch and writes the medians.

    python scripts/encoder_gradients.py results/passive-encoder/cpu-passive-target-critic-encoder__s0 --grasps 600 \
        --out results/passive-encoder/encoder-gradients-s0-600grasps.json
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro

from apr.model.agent import APRAgent, GraspBatch, Observation
from apr.train.checkpoints import read_checkpoint
from apr.train.config import TrainConfig
from apr.train.replay import ReplayBuffer, ReplaySpec


@dataclass
class Args:
    run: tyro.conf.Positional[Path]
    """A run folder with ``checkpoints/checkpoint_GRASPS.pt`` and ``replay_GRASPS.npz``."""
    grasps: int = 600
    """Which checkpoint (its grasp count)."""
    batches: int = 10
    """Grasp batches drawn; the medians are over them."""
    losses: tuple[str, ...] = ("gqn/elbo", "grasp/critic")
    """Losses of ``APRAgent.compute_losses`` to measure."""
    seed: int = 0
    out: Path | None = None
    """A JSON file for the medians (and each batch's norms); None: print only."""


def main(args: Args) -> None:
    folder = args.run / "checkpoints"
    state = read_checkpoint(folder / f"checkpoint_{args.grasps:08d}.pt")
    config = TrainConfig.from_json(state["config"]).resolved()
    if config.env.learned_fixation:
        raise SystemExit(f"{args.run}: a learned-fixation run; this script reads grasp batches only")
    agent = APRAgent(config.model)
    agent.load_state_dict(state["agent"])
    spec = ReplaySpec(
        image_shape=(3, config.model.image_size, config.model.image_size, config.env.image_channels),
        viewpoint_shape=(3, config.model.viewpoint_dim), gripper_dim=config.model.gripper_dim,
        grasp_action_dim=config.env.dof, fixation_dim=0, steps_left=config.env.observes_steps_left,
    )  # fmt: skip
    replay = ReplayBuffer(config.replay_capacity, spec)
    replay.load(folder / f"replay_{args.grasps:08d}.npz")
    rng = np.random.default_rng(args.seed)
    step = int(state["progress"]["updates"])
    step -= step % config.model.gqn_update_every  # an update with the ELBO
    norms: list[dict[str, float]] = []
    for batch_index in range(args.batches):
        drawn = replay.sample_grasp(config.model.batch_size, rng)
        batch = GraspBatch(
            obs=Observation.from_env(drawn["obs"]), action=torch.from_numpy(drawn["action"]),
            reward=torch.from_numpy(drawn["reward"]), next_obs=Observation.from_env(drawn["next_obs"]),
            terminated=torch.from_numpy(drawn["terminated"]),
            steps=torch.from_numpy(drawn["steps"]) if config.model.n_step > 1 else None,
        )  # fmt: skip
        losses, _ = agent.compute_losses(batch, None, step)
        row = {}
        for name in args.losses:
            agent.networks.zero_grad(set_to_none=True)
            losses[name].backward(retain_graph=True)
            grads = [p.grad.flatten() for p in agent.encoder.parameters() if p.grad is not None]
            row[name] = float(torch.cat(grads).norm()) if grads else 0.0
        norms.append(row)
        print(f"batch {batch_index}: " + ", ".join(f"{name} {value:.4g}" for name, value in row.items()), flush=True)
    medians = {name: float(np.median([row[name] for row in norms])) for name in args.losses}
    first, *others = args.losses
    ratios = {f"{first} / {other}": medians[first] / max(medians[other], 1e-12) for other in others}
    print(f"{args.run.name} at {args.grasps} grasps, median encoder gradient norms: "
          + ", ".join(f"{name} {value:.4g}" for name, value in medians.items())
          + "; " + ", ".join(f"{name} {value:.1f}" for name, value in ratios.items()))  # fmt: skip
    if args.out is not None:
        result = {"run": str(args.run), "grasps": args.grasps, "update": step, "batch_size": config.model.batch_size,
                  "median_norms": medians, "ratios": ratios, "batches": norms}  # fmt: skip
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main(tyro.cli(Args))
