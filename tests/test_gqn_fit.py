"""The GQN fits real rendered views: joint updates on a fixed batch of env observations lower the ELBO."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
import torch

import apr  # noqa: F401  (registers the environments)
from apr.model import APRAgent, GraspBatch, ModelConfig, Observation, encode_scene, gqn_elbo_loss, images_to_float

STEPS = 12
UPDATES = 100


@pytest.fixture(scope="module")
def rendered_observations() -> Observation:
    """12 grasp-step observations of the active env (target mask: 4 channels), random actions."""
    env = gymnasium.make("apr/ActiveGrasp-v2", renderer="tiny")
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    collected = []
    while len(collected) < STEPS:
        collected.append(obs)
        obs, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 6).astype(np.float32))
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    return Observation.from_env({key: np.stack([o[key] for o in collected]) for key in collected[0]})


def evaluate_elbo(agent: APRAgent, obs: Observation, sigma: float) -> dict[str, float]:
    """The ELBO at a fixed sigma, views 0 and 1 as context, view 2 as query, fixed noise."""
    with torch.no_grad():
        images, poses = images_to_float(obs.images), obs.poses()
        r = encode_scene(agent.encoder, images[:, :2], poses[:, :2])
        noise = torch.randn(
            agent.generator.noise_shape(len(obs), r.shape[-1]), generator=torch.Generator().manual_seed(0)
        )
        _, metrics = gqn_elbo_loss(agent.generator, r, poses[:, 2], images[:, 2], sigma, noise)
    return {name: value.item() for name, value in metrics.items()}


def test_gqn_fits_rendered_views(rendered_observations: Observation) -> None:
    obs = rendered_observations
    assert obs.images.shape == (STEPS, 3, 64, 64, 4) and obs.images.dtype == torch.uint8
    assert obs.images.float().std() > 10, "the rendered views should not be blank"
    config = ModelConfig.tiny(
        image_channels=4,
        batch_size=STEPS,
        gqn_batch_size=STEPS,
        gqn_anneal_updates=UPDATES,  # the whole sigma schedule 2.0 -> 0.7, compressed
        gqn_lr_start=3e-3,  # a short fit: a larger step than Eslami's 5e-4
        gqn_lr_end=3e-4,
    )
    agent = APRAgent(config)
    batch = GraspBatch(obs, torch.zeros(STEPS, 6), torch.zeros(STEPS), obs, torch.zeros(STEPS))

    sigma = config.sigma_end
    before = evaluate_elbo(agent, obs, sigma)
    for step in range(UPDATES):
        metrics = agent.update(batch, None, step)
        assert math.isfinite(metrics["gqn/elbo_loss"])
    after = evaluate_elbo(agent, obs, sigma)

    # The part of -ELBO that depends on the model: squared error / (2 sigma^2) + KL, above its constant.
    constant = obs.images[:, 0].numel() / STEPS * (math.log(sigma) + 0.5 * math.log(2 * math.pi))
    assert after["gqn/elbo_loss"] - constant < 0.5 * (before["gqn/elbo_loss"] - constant), (before, after)
    assert after["gqn/mse"] < 0.5 * before["gqn/mse"], (before, after)
    assert after["gqn/kl"] > 0
