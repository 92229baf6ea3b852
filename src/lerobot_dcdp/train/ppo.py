"""The PPO arithmetic of ``dcdp-finetune-rl``, as pure functions on tensors (Schulman et al. 2017; the
residual-RL setting of ResiP, Ankile et al. 2024).

- :func:`progress_rewards`: an env's per-step reward turned into its increments, so that an episode's return
  is its last reward (what ends early on success is never paid less than hovering below the threshold).
- :func:`generalized_advantages`: GAE(gamma, lambda) over one flat buffer of concatenated episodes.
- :func:`gaussian_log_prob`: the log-density of a diagonal Gaussian action.
- :func:`clipped_policy_loss`: PPO's clipped surrogate.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def progress_rewards(rewards: Tensor) -> Tensor:
    """``r_t - r_{t-1}`` along one episode's rewards (T,), with ``r_{-1} = 0``: the env's reward used as a
    potential, so the episode's return (undiscounted) is its last reward."""
    previous = torch.cat([rewards.new_zeros(1), rewards[:-1]])
    return rewards - previous


def generalized_advantages(
    rewards: Tensor, values: Tensor, dones: Tensor, gamma: float, lam: float
) -> tuple[Tensor, Tensor]:
    """GAE over a flat buffer of whole episodes laid end to end.

    Args:
        rewards: (N,) reward of each transition.
        values: (N,) the critic's value of each transition's state.
        dones: (N,) True on each episode's last transition (nothing is bootstrapped past it).
        gamma: Discount.
        lam: GAE's lambda.

    Returns:
        ``(advantages, returns)``, each (N,); ``returns = advantages + values`` (the critic's target).
    """
    if not (rewards.shape == values.shape == dones.shape) or rewards.dim() != 1:
        raise ValueError(
            f"rewards, values and dones must be equal 1-D shapes, got {tuple(rewards.shape)}, "
            f"{tuple(values.shape)}, {tuple(dones.shape)}"
        )
    if len(dones) and not bool(dones[-1]):
        raise ValueError("the buffer must end with a finished episode (dones[-1] is False)")
    advantages = torch.zeros_like(rewards)
    running = rewards.new_zeros(())
    for i in range(len(rewards) - 1, -1, -1):
        last = bool(dones[i])
        next_value = rewards.new_zeros(()) if last else values[i + 1]
        delta = rewards[i] + gamma * next_value - values[i]
        running = delta + (0.0 if last else gamma * lam * running)
        advantages[i] = running
    return advantages, advantages + values


def gaussian_log_prob(sample: Tensor, mean: Tensor, log_std: Tensor) -> Tensor:
    """Log-density of ``sample`` under N(mean, exp(log_std)^2) per dimension, summed over the last one."""
    var = torch.exp(2 * log_std)
    per_dim = -((sample - mean) ** 2) / (2 * var) - log_std - 0.5 * math.log(2 * math.pi)
    return per_dim.sum(-1)


def clipped_policy_loss(log_prob: Tensor, old_log_prob: Tensor, advantages: Tensor, clip: float) -> Tensor:
    """PPO's surrogate ``-E[min(rho A, clip(rho, 1 - eps, 1 + eps) A)]``, ``rho = exp(logp - logp_old)``."""
    ratio = torch.exp(log_prob - old_log_prob)
    unclipped = ratio * advantages
    clipped = ratio.clamp(1.0 - clip, 1.0 + clip) * advantages
    return -torch.minimum(unclipped, clipped).mean()
