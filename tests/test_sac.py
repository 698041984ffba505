"""SAC with the APR heads: squashed-Gaussian log-probability, Bellman target, learning a bandit."""

from __future__ import annotations

import math

import torch
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from apr.model import (
    PolicyHeads,
    bandit_critic_loss,
    sac_actor_loss,
    sac_critic_loss,
    soft_update,
    temperature_loss,
)

CHANNELS, GRID = 8, 16


def tiny_heads(action_dim: int, seed: int = 0, **kwargs: object) -> PolicyHeads:
    torch.manual_seed(seed)
    return PolicyHeads(CHANNELS, action_dim, channels=(8, 8, 8), grid=GRID, **kwargs)  # type: ignore[arg-type]


def heads_with_constant_target(action_dim: int, value: float = 2.0) -> PolicyHeads:
    """Tiny heads whose target critics answer ``value`` everywhere, with a temperature of ~0: a critic target is then
    reward + discount * value where the episode goes on, and reward where it ended."""
    heads = tiny_heads(action_dim)
    heads.log_alpha.data.fill_(math.log(1e-12))
    for critic in (heads.critic_target.q1, heads.critic_target.q2):
        critic.out.weight.data.zero_()
        critic.out.bias.data.fill_(value)
    return heads


def test_squashed_log_prob_matches_the_change_of_variables() -> None:
    heads = tiny_heads(4)
    r = torch.randn(64, CHANNELS, GRID, GRID)
    generator = torch.Generator().manual_seed(0)
    action, log_prob = heads.actor.sample(r, generator)
    mean, log_std = heads.actor(r)
    reference = TransformedDistribution(Normal(mean, log_std.exp()), TanhTransform(cache_size=1))
    pre_tanh = torch.atanh(action.clamp(-1 + 1e-6, 1 - 1e-6))
    expected = reference.log_prob(torch.tanh(pre_tanh)).sum(-1)
    inside = action.abs().max(-1).values < 0.999  # atanh is ill-conditioned at the edges
    torch.testing.assert_close(log_prob[inside], expected[inside], rtol=1e-3, atol=1e-3)


def test_critic_target_bootstraps_unless_terminated() -> None:
    heads = tiny_heads(6)
    heads.log_alpha.data.fill_(math.log(0.3))
    batch = 8
    r, r_next = torch.randn(batch, CHANNELS, GRID, GRID), torch.randn(batch, CHANNELS, GRID, GRID)
    action, reward = torch.rand(batch, 6) * 2 - 1, torch.rand(batch)
    terminated = torch.tensor([1, 0, 1, 0, 0, 0, 1, 0], dtype=torch.float32)
    gamma = 0.99

    loss, metrics = sac_critic_loss(
        heads, r, action, reward, r_next, terminated, gamma, torch.Generator().manual_seed(7)
    )
    with torch.no_grad():  # the same draw of a' by hand
        next_action, next_log_prob = heads.actor.sample(r_next, torch.Generator().manual_seed(7))
        next_q = torch.min(*heads.critic_target(r_next, next_action))
        bootstrap = gamma * (next_q - 0.3 * next_log_prob)
        target = torch.where(terminated.bool(), reward, reward + bootstrap)
        q1, q2 = heads.critic(r, action)
        expected = 0.5 * ((q1 - target) ** 2).mean() + 0.5 * ((q2 - target) ** 2).mean()
    torch.testing.assert_close(loss, expected)
    torch.testing.assert_close(metrics["target_q"], target.mean())
    assert bootstrap.abs().min() > 1e-3  # so the terminated flag really matters in this check


def test_bandit_critic_regresses_the_reward_without_bootstrap() -> None:
    """Critics that answer 0.5 and -1.0 everywhere, rewards 0, 1, 0.5 and 2: each critic's squared errors are
    (0.25, 0.25, 0, 2.25) and (1, 4, 2.25, 9), means 0.6875 and 4.0625, and the loss is half their sum, 2.375,
    whatever r and the actions (no next state, no target critic); the same with two actions for each of 2 scenes."""
    heads = tiny_heads(3, target_critic=False)
    assert heads.critic_target is None
    for critic, value in ((heads.critic.q1, 0.5), (heads.critic.q2, -1.0)):
        critic.out.weight.data.zero_()
        critic.out.bias.data.fill_(value)
    r, action, reward = torch.randn(4, CHANNELS, GRID, GRID), torch.rand(4, 3), torch.tensor([0.0, 1.0, 0.5, 2.0])
    loss, _ = bandit_critic_loss(heads, r, action, reward)
    assert loss.item() == 2.375
    loss, _ = bandit_critic_loss(heads, r[:2], action.view(2, 2, 3), reward.view(2, 2))
    assert loss.item() == 2.375


def test_temperature_rises_when_entropy_is_below_target() -> None:
    log_alpha = torch.zeros((), requires_grad=True)
    low_entropy_log_prob = torch.full((16,), 5.0)  # entropy -5 < target -3
    loss, _ = temperature_loss(log_alpha, low_entropy_log_prob, target_entropy=-3.0)
    loss.backward()
    assert log_alpha.grad < 0  # gradient descent increases alpha


def test_soft_update_moves_tau_of_the_way() -> None:
    source, target = torch.nn.Linear(3, 2), torch.nn.Linear(3, 2)
    before = target.weight.detach().clone()
    soft_update(target, source, tau=0.25)
    torch.testing.assert_close(target.weight, before + 0.25 * (source.weight - before))


def test_sac_learns_a_continuous_bandit() -> None:
    """reward = -||a - a*||^2 for a fixed random r: the mean action moves to a*, the sampled reward rises."""
    heads = tiny_heads(3, target_critic=False, init_temperature=0.05)
    generator = torch.Generator().manual_seed(0)
    r = torch.randn(1, CHANNELS, GRID, GRID, generator=generator).expand(32, -1, -1, -1)
    best_action = torch.tensor([0.6, -0.5, 0.3])
    optimizer = torch.optim.Adam(heads.parameters(), lr=2e-3)

    def reward_of(action: torch.Tensor) -> torch.Tensor:
        return -((action - best_action) ** 2).sum(-1)

    def evaluate() -> tuple[float, float]:
        with torch.no_grad():
            mean_action_reward = reward_of(heads.actor.mode(r[:1])).item()
            sampled_reward = reward_of(heads.actor.sample(r, generator)[0]).mean().item()
        return mean_action_reward, sampled_reward

    initial, initial_sampled = evaluate()
    for _ in range(200):
        with torch.no_grad():
            action = heads.actor.sample(r, generator)[0]
        critic_loss, _ = bandit_critic_loss(heads, r, action, reward_of(action))
        actor_loss, log_prob, _ = sac_actor_loss(heads, r, generator)
        alpha_loss, _ = temperature_loss(heads.log_alpha, log_prob, heads.target_entropy)
        optimizer.zero_grad()
        (critic_loss + actor_loss + alpha_loss).backward()
        optimizer.step()
    final, final_sampled = evaluate()
    assert initial < -0.5 and final > -0.1, (initial, final)
    assert final_sampled > initial_sampled + 1.0, (initial_sampled, final_sampled)
