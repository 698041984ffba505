"""Soft Actor-Critic losses (Haarnoja et al. 2018a/b), one function per loss, each with its metrics.

Twin Q critics with Polyak-averaged target copies and an automatically tuned temperature (the later SAC of
Haarnoja et al. 2018b) rather than the separate V network of 2018a. The losses only compute: the caller
sums them, steps the optimisers and logs the metrics (DrQ-v2 style). Metrics are detached scalar tensors,
so the caller can move them to the host with one synchronisation.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn

from apr.model.heads import PolicyHeads

Metrics = dict[str, torch.Tensor]


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Evaluate a module without recording its parameters in the graph (gradients still flow to inputs)."""
    flags = [p.requires_grad for p in module.parameters()]
    module.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in zip(module.parameters(), flags, strict=True):
            p.requires_grad_(flag)


def sac_critic_loss(
    heads: PolicyHeads,
    r: torch.Tensor,
    action: torch.Tensor,
    reward: torch.Tensor,
    r_next: torch.Tensor,
    terminated: torch.Tensor,
    gamma: float,
    generator: torch.Generator | None = None,
    steps: torch.Tensor | None = None,
) -> tuple[torch.Tensor, Metrics]:
    """Soft Bellman residual of both critics.

    target = reward + gamma^steps (1 - terminated) (min_j Q'_j(r', a') - alpha log pi(a' | r')), a' ~ pi(. | r').
    Truncated transitions (v0's 15-step limit) have terminated = 0 and bootstrap from their final r'.

    Args:
        r: (B, R, 16, 16), detached unless the "w/o representation" ablation trains the encoder here.
        action: (B, A); reward: (B,), over an n-step transition the discounted sum of its rewards;
        r_next: (B, R, 16, 16); terminated: (B,) in {0, 1}.
        steps: (B,) environment steps from r to r_next (n-step returns); None: 1 for every transition.

    Returns:
        0.5 * sum_j mean (Q_j - target)^2 and metrics.
    """
    assert heads.critic_target is not None, "a bootstrapping critic needs its target copy"
    with torch.no_grad():
        next_action, next_log_prob = heads.actor.sample(r_next, generator)
        next_q = torch.min(*heads.critic_target(r_next, next_action))
        soft_value = next_q - heads.log_alpha.exp() * next_log_prob
        discount = gamma if steps is None else gamma ** steps.float()
        target = reward + discount * (1.0 - terminated.float()) * soft_value
    q1, q2 = heads.critic(r, action)
    loss = 0.5 * ((q1 - target) ** 2).mean() + 0.5 * ((q2 - target) ** 2).mean()
    return loss, {"critic_loss": loss.detach(), "q": q1.mean().detach(), "target_q": target.mean()}


def bandit_critic_loss(
    heads: PolicyHeads, r: torch.Tensor, action: torch.Tensor, reward: torch.Tensor
) -> tuple[torch.Tensor, Metrics]:
    """Critic of a contextual bandit (the fixation policy): both critics regress the reward, no bootstrap.

    Args:
        r: (B, R, 16, 16); action: (B, A) and reward (B,), or K of each per scene: (B, K, A) and (B, K).
    """
    q1, q2 = heads.critic(r, action)
    loss = 0.5 * ((q1 - reward) ** 2).mean() + 0.5 * ((q2 - reward) ** 2).mean()
    return loss, {"critic_loss": loss.detach(), "q": q1.mean().detach(), "reward": reward.mean()}


def sac_actor_loss(
    heads: PolicyHeads, r: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, torch.Tensor, Metrics]:
    """Policy loss mean(alpha log pi(a | r) - min_j Q_j(r, a)), a ~ pi(. | r) reparameterised.

    The critics are frozen during this evaluation, so the loss moves the actor only (r must be detached).

    Args:
        r: (B, R, 16, 16), detached.

    Returns:
        the loss, log pi(a | r) of the sampled actions (B,) for the temperature loss, and metrics.
    """
    action, log_prob = heads.actor.sample(r, generator)
    with frozen(heads.critic):
        q = torch.min(*heads.critic(r, action))
    loss = (heads.log_alpha.exp().detach() * log_prob - q).mean()
    return loss, log_prob, {"actor_loss": loss.detach(), "entropy": -log_prob.mean().detach()}


def temperature_loss(
    log_alpha: torch.Tensor, log_prob: torch.Tensor, target_entropy: float
) -> tuple[torch.Tensor, Metrics]:
    """Automatic entropy tuning: -mean(log alpha * (log pi + target entropy)) (Haarnoja et al. 2018b).

    Args:
        log_alpha: scalar parameter; log_prob: (B,), treated as a constant.
    """
    loss = -(log_alpha * (log_prob.detach() + target_entropy)).mean()
    return loss, {"temperature_loss": loss.detach(), "alpha": log_alpha.exp().detach()}


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """Polyak averaging: target <- (1 - tau) target + tau source."""
    for target_param, source_param in zip(target.parameters(), source.parameters(), strict=True):
        target_param.lerp_(source_param, tau)
