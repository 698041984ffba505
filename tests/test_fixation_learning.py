"""Signs of life of the fixation bandit: trained through the learner (encoder r detached, SAC heads, the paper's grasp
reward with relabelled points: a grasp that started at the object lifted it, in most episodes), it chooses points
nearer the object than any fixed point can, on scenes it never saw. A fixation policy that ignored its images could
do no better than the best fixed point. The ELBO is left out (``gqn_update_every`` past the last update): the heads
read r detached in any case, so the bandit learns from the initial encoder's r, which keeps where the square is. On
the quiet 2-core CPU: 205 s with the ELBO and 400 updates, 108 s without it, 54 s at 200 updates (the learned points
then 3.3 cm from the object, the best fixed point 13.6)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from apr.model.agent import APRAgent, FixationBatch, GraspBatch, Observation, fixation_points
from apr.model.config import ModelConfig
from apr.model.heads import TwinCritic

SIDE = 64
BLOB = 12  # pixels: the object's picture, a bright square on a grey floor
STEPS = 200  # learner updates


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
        image_channels=3, grasp_action_dim=4, fixation_reward="grasp", fixation_relabels=8,
        fixation_batch_size=16, batch_size=8, gqn_batch_size=4, gqn_fixation_batch_size=4, init_temperature=0.01,
        gqn_update_every=STEPS + 1,
        heads_see_fixation=True, heads_see_proprioception=True,
    )  # fmt: skip
    agent = APRAgent(config)
    train, train_centres = synthetic_scenes(256, rng)
    test, test_centres = synthetic_scenes(64, rng)
    for step in range(STEPS):
        index = torch.from_numpy(rng.integers(0, 256, config.fixation_batch_size))
        chosen = torch.from_numpy(rng.uniform(-1, 1, (len(index), 3)).astype(np.float32))
        # the episode's grasp started at the object and lifted it, 70% of the time; the reward then follows from
        # where the point was chosen, as the environment gives it
        tip = train_centres[index, 0]
        lifted = torch.from_numpy((rng.random(len(index)) < 0.7).astype(np.float32))
        reward = lifted * ((fixation_points(chosen) - tip).norm(dim=-1) <= 0.10)
        fixation = FixationBatch(obs=train[index], action=chosen, reward=reward, lifted=lifted, grasp_tip=tip)
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
    # and the paper's reward agrees: more of the learned points lie within its 10 cm of the object
    near = (chosen[:, None] - test_centres).norm(dim=-1).amin(dim=1) <= 0.10
    near_fixed = (fixation_points(torch.zeros(3)) - test_centres).norm(dim=-1).amin(dim=1) <= 0.10
    assert near.float().mean() > near_fixed.float().mean()


def test_the_map_critic_reads_its_map_at_the_action_and_knows_its_best_point() -> None:
    critic = TwinCritic(4, 2, (4,), 16, kind="map", map_grid=3)  # actions are (x, y) only: Q is the map itself
    known = torch.arange(9.0).view(3, 3)  # [i, j]: the value at x = lattice[i], y = lattice[j], lattice -1, 0, 1
    for q, offset in ((critic.q1, 0.0), (critic.q2, 1.0)):
        nn.init.zeros_(q.out.weight)
        with torch.no_grad():
            q.out.bias.copy_(known.flatten() + offset)
    r = torch.randn(2, 4, 16, 16)
    q1, q2 = critic(r, torch.tensor([[1.0, -1.0], [0.5, 0.0]]))
    assert q1.tolist() == pytest.approx([6.0, (4.0 + 7.0) / 2])  # at a lattice point: its value; between two: theirs
    assert (q2 - q1).tolist() == pytest.approx([1.0, 1.0])
    assert critic.best_xy(r).tolist() == [[1.0, 1.0], [1.0, 1.0]]  # the highest of min(Q1, Q2): known[2, 2]


def test_the_map_critics_best_point_is_found_between_lattice_points() -> None:
    """A paraboloid peaking between lattice points: the refinement finds its peak exactly; one peaking at the
    map's edge keeps the lattice coordinate on that axis."""
    critic = TwinCritic(4, 2, (4,), 16, kind="map", map_grid=5)  # lattice -1, -0.5, 0, 0.5, 1
    lattice = torch.linspace(-1.0, 1.0, 5)
    x, y = torch.meshgrid(lattice, lattice, indexing="ij")
    for q in (critic.q1, critic.q2):
        nn.init.zeros_(q.out.weight)
        with torch.no_grad():
            q.out.bias.copy_((-((x - 0.1) ** 2) - (y + 0.2) ** 2).flatten())
    r = torch.randn(1, 4, 16, 16)
    assert critic.best_xy(r)[0].tolist() == pytest.approx([0.1, -0.2])
    for q in (critic.q1, critic.q2):
        with torch.no_grad():
            q.out.bias.copy_((-((x - 1.3) ** 2) - (y + 0.2) ** 2).flatten())
    assert critic.best_xy(r)[0].tolist() == pytest.approx([1.0, -0.2])  # x at the edge


@pytest.mark.parametrize("kind", ["tiled", "map"])
def test_a_critic_values_several_actions_per_scene_as_it_values_each_alone(kind: str) -> None:
    """The bandit's relabelled points: (B, K, A) actions give (B, K) values, each that of the (B, A) call."""
    torch.manual_seed(0)
    critic = TwinCritic(4, 3, (4,), 16, kind=kind)
    r, actions = torch.randn(2, 4, 16, 16), torch.rand(2, 5, 3) * 2 - 1
    together = critic(r, actions)
    for k in range(5):
        alone = critic(r, actions[:, k])
        for q_together, q_alone in zip(together, alone, strict=True):
            torch.testing.assert_close(q_together[:, k], q_alone)
    assert together[0].shape == (2, 5)


def test_with_the_map_critic_the_deterministic_fixation_looks_at_the_critics_best_point() -> None:
    config = ModelConfig.tiny(image_channels=3, grasp_action_dim=4, fixation_critic="map", fixation_reward="proximity",
                              fixation_relabels=8)  # fmt: skip
    agent = APRAgent(config)
    observation, centres = synthetic_scenes(4, np.random.default_rng(0))
    looked = agent.act(observation, deterministic=True, policy="fixation")
    r = agent._head_input(agent._scene(observation, agent._first_two(4), with_grad=0), observation)
    assert looked[:, :2].tolist() == agent.fixation.critic.best_xy(r).tolist()
    assert looked[:, 2].tolist() == pytest.approx(agent.fixation.actor.mode(r)[:, 2].tolist())
    fixation = FixationBatch(obs=observation, action=torch.zeros(4, 3), reward=torch.zeros(4), object_centres=centres)
    grasp = GraspBatch(obs=observation, action=torch.zeros(4, 4), reward=torch.zeros(4), next_obs=observation,
                       terminated=torch.ones(4))  # fmt: skip
    critic = agent.fixation.critic.q1
    trained = {"conv": critic.trunk[0].weight, "z": critic.rest[0].weight}
    before = {name: value.clone() for name, value in trained.items()}
    agent.update(grasp, fixation, 0)
    assert all(not torch.equal(before[name], trained[name]) for name in trained)  # the bandit loss reaches both
