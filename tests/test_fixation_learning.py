"""Signs of life of the fixation bandit: trained through the learner (encoder r detached, SAC heads, proximity
reward with relabelled points), it chooses points nearer the object than any fixed point can, on scenes it never
saw. A fixation policy that ignored its images could do no better than the best fixed point."""

from __future__ import annotations

import numpy as np
import torch

from apr.model.agent import APRAgent, FixationBatch, GraspBatch, Observation, fixation_points, proximity_reward
from apr.model.config import ModelConfig

SIDE = 64
BLOB = 12  # pixels: the object's picture, a bright square on a grey floor
STEPS = 400  # learner updates


def synthetic_scenes(count: int, rng: np.random.Generator) -> tuple[Observation, torch.Tensor]:
    """Scenes of one object in one of the fixation box's four quarters (at their centres, z fixed); every view
    shows it as a square whose place in the picture is the object's place in the box (a camera straight above).
    Returns the observations and the object centres (count, 1, 3)."""
    actions = np.zeros((count, 3), np.float32)
    actions[:, :2] = rng.choice([-0.5, 0.5], (count, 2))
    centres = fixation_points(torch.from_numpy(actions))[:, None]
    images = np.full((count, 3, SIDE, SIDE, 3), 90, np.uint8)
    pixels = ((actions[:, :2] + 1) / 2 * (SIDE - BLOB)).astype(int)
    for k, (col, row) in enumerate(pixels):
        images[k, :, row : row + BLOB, col : col + BLOB] = (230, 60, 40)
    observation = Observation(torch.from_numpy(images), torch.zeros(count, 3, 6), torch.zeros(count, 9),
                              torch.tensor([[0.55, 0.0, -0.15]]).expand(count, 3).clone())  # fmt: skip
    return observation, centres


def median_distance(points: torch.Tensor, centres: torch.Tensor) -> float:
    return float((points[:, None] - centres).norm(dim=-1).amin(dim=1).median())


def test_the_fixation_bandit_learns_to_look_at_the_object(one_thread) -> None:
    rng = np.random.default_rng(0)
    config = ModelConfig.tiny(
        image_channels=3, grasp_action_dim=4, fixation_reward="proximity", fixation_relabels=8,
        fixation_batch_size=16, batch_size=8, gqn_batch_size=4, gqn_fixation_batch_size=4, init_temperature=0.01,
        heads_see_fixation=True, heads_see_proprioception=True,
    )  # fmt: skip
    agent = APRAgent(config)
    train, train_centres = synthetic_scenes(256, rng)
    test, test_centres = synthetic_scenes(64, rng)
    for step in range(STEPS):
        index = torch.from_numpy(rng.integers(0, 256, config.fixation_batch_size))
        chosen = torch.from_numpy(rng.uniform(-1, 1, (len(index), 3)).astype(np.float32))
        fixation = FixationBatch(obs=train[index], action=chosen,
                                 reward=torch.zeros(len(index)), object_centres=train_centres[index])  # fmt: skip
        grasp_index = index[: config.batch_size]
        grasp = GraspBatch(obs=train[grasp_index], action=torch.zeros(len(grasp_index), 4),
                           reward=torch.zeros(len(grasp_index)), next_obs=train[grasp_index],
                           terminated=torch.ones(len(grasp_index)))  # fmt: skip
        agent.update(grasp, fixation, step)
    chosen = fixation_points(torch.from_numpy(agent.act(test, deterministic=True, policy="fixation")))
    # the best one point for all scenes: the chosen points' mean, or the box centre (where objects are on average)
    fixed = [median_distance(point.expand(len(test_centres), 3), test_centres)
             for point in (chosen.mean(0), fixation_points(torch.zeros(3)))]  # fmt: skip
    learned = median_distance(chosen, test_centres)
    assert learned < 0.75 * min(fixed), (learned, fixed)
    # and the proximity reward agrees: the learned choices earn more than the fixed point's
    actions = torch.from_numpy(agent.act(test, deterministic=True, policy="fixation"))[:, None]
    assert proximity_reward(actions, test_centres, 0.15).mean() > proximity_reward(
        torch.zeros_like(actions), test_centres, 0.15).mean()  # fmt: skip
