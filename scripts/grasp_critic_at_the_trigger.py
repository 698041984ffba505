"""What a grasp policy's critic thinks of attempting: the deterministic policy's own episodes, step by step.

On held-out episodes (the evaluation's seeds) the grasp policy acts with its deterministic action, as in an
evaluation. At every step it also asks its own critics (min of the twins) what the deterministic action is worth and
what the same action is worth with the gripper sent fully down (dz = -1, 6 cm: from within 6 cm of the trigger, an
attempt), and how often the stochastic policy's samples would cross the trigger there. Whether a policy that hovers
above the trigger does so because its critic values hovering more (a value problem) or although the critic values
the attempt more (an actor problem) is then read off the episodes. The share of samples that would cross assumes the
gripper moves as commanded: a gripper held up (by the workspace's floor, the tray or an object) pushes down without
descending, which the tool tip's height from step to step shows. The tool tip and target come from ``info``, as a
probe may; the heads see what they see in training.

    python scripts/grasp_critic_at_the_trigger.py results/archive/gqn-anneal2000/cpu-active-target__s0

Prints one JSON line per episode, then a summary line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import gymnasium as gym
import numpy as np
import torch
import tyro

import apr.envs  # noqa: F401  (registers the environments)
from apr.envs.config import GRASP
from apr.model.agent import Observation
from apr.reproduce.policies import load_policy
from apr.train.evaluation import EVAL_SEED

SAMPLES = 64
"""Samples of the stochastic policy per step, for the share that would cross the trigger."""


@dataclass
class Args:
    checkpoint: Annotated[Path, tyro.conf.Positional]
    """A run folder (its latest checkpoint) or a training checkpoint."""
    episodes: int = 10
    """Held-out episodes (the evaluation's first seeds)."""


def main(args: Args) -> None:
    torch.set_num_threads(1)
    snapshot = load_policy(args.checkpoint)
    agent, config = snapshot.agent, snapshot.config
    env = gym.make(config.env.env_id, **config.env.make_kwargs("test"))
    generator = torch.Generator().manual_seed(0)
    summary: dict[str, list[float]] = {"hover_q_det": [], "hover_q_down": [], "hover_sample_cross": []}
    for episode in range(args.episodes):
        observation, info = env.reset(seed=EVAL_SEED + episode)
        steps, done = [], False
        while not done:
            batch = Observation.from_env({k: np.asarray(v)[None] for k, v in observation.items()}, agent.device)
            with torch.no_grad():
                r = agent._head_input(agent._scene(batch, agent._first_two(1), with_grad=0), batch)
                mean, log_std = agent.grasp.actor(r)
                deterministic = torch.tanh(mean)
                down = deterministic.clone()
                down[:, 2] = -1.0
                q_det = torch.minimum(*agent.grasp.critic(r, deterministic))
                q_down = torch.minimum(*agent.grasp.critic(r, down))
                samples = torch.tanh(mean + log_std.exp() * torch.randn((SAMPLES, mean.shape[1]), generator=generator))
            above = float(info["tool_tip"][2]) - GRASP.grasp_height
            to_target = float(np.linalg.norm(info["tool_tip"][:2] - info["fixation_point"][:2]))
            steps.append({
                "steps_left": int(observation.get("steps_left", -1)), "above_cm": round(100 * above, 1),
                "to_target_xy_cm": round(100 * to_target, 1),
                "dz": round(float(deterministic[0, 2]), 2), "dz_std": round(float(log_std[0, 2].exp()), 2),
                "q_det": round(float(q_det), 3), "q_down": round(float(q_down), 3),
                "sample_cross": round(float((samples[:, 2] * GRASP.position_step < -above).float().mean()), 2),
            })  # fmt: skip
            if 0 < above < GRASP.position_step:
                summary["hover_q_det"].append(float(q_det))
                summary["hover_q_down"].append(float(q_down))
                summary["hover_sample_cross"].append(steps[-1]["sample_cross"])
            observation, _, terminated, truncated, info = env.step(deterministic[0].numpy())
            done = terminated or truncated
        print(json.dumps({"seed": EVAL_SEED + episode, "attempted": bool(info.get("grasp_attempted", False)),
                          "success": bool(info.get("grasp_success", False)), "steps": steps}), flush=True)  # fmt: skip
    print(json.dumps({key: round(float(np.mean(values)), 3) if values else None for key, values in summary.items()}
                     | {"hover_steps": len(summary["hover_q_det"])}))  # fmt: skip


if __name__ == "__main__":
    main(tyro.cli(Args))
