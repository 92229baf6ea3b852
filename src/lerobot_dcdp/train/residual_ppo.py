"""The learner of residual RL (``dcdp-finetune-rl``): one iteration's transitions, the reward PPO optimises,
and the actor-critic update with its optimisers.

The actor is the corrector's residual head plus a learned exploration noise
(:class:`~lerobot_dcdp.train.residual_exploration.ResidualExploration`); the critic is a
:class:`~lerobot_dcdp.train.residual_exploration.ValueCritic`, built on the first rollout (its input width
follows the head's inputs). The loss of the actor is PPO's clipped surrogate plus ``kl_weight`` times the KL
divergence to the starting corrector's Gaussian (same noise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

from lerobot_dcdp.train.ppo import (
    clipped_policy_loss,
    gaussian_log_prob,
    generalized_advantages,
    progress_rewards,
)
from lerobot_dcdp.train.residual_exploration import ResidualExploration, ValueCritic, critic_input

if TYPE_CHECKING:  # the run's settings; finetune_rl imports this module
    from lerobot_dcdp.train.finetune_rl import RLConfig


@dataclass
class Rollout:
    """One iteration's transitions, episodes laid end to end (the layout GAE expects).

    Attributes:
        inputs: The residual head's inputs per transition, each with the transitions first.
        mean: (N, A) the head's delta: the exploration Gaussian's mean.
        sample: (N, A) the sampled delta.
        elapsed: (N,) the step's share of the episode's step limit.
        rewards: (N,) the env's rewards.
        dones: (N,) ``True`` on each episode's last transition.
        successes: Per episode, whether it succeeded.
        max_rewards: Per episode, the best reward reached.
    """

    inputs: tuple[torch.Tensor, ...]
    mean: torch.Tensor
    sample: torch.Tensor
    elapsed: torch.Tensor
    rewards: torch.Tensor
    dones: torch.Tensor
    successes: list[bool]
    max_rewards: list[float]

    def episode_lengths(self) -> list[int]:
        """The number of transitions of each episode, in order."""
        ends = torch.nonzero(self.dones).flatten().tolist()
        return [e - s for s, e in zip([-1, *ends[:-1]], ends, strict=True)]

    def success_steps(self, lengths: list[int]) -> list[int]:
        """Per episode, the index of the step that succeeded (-1: none): lock-step ends an episode on
        success, so it is the episode's last step."""
        return [n - 1 if ok else -1 for n, ok in zip(lengths, self.successes, strict=True)]


def shaped_rewards(
    rollout: Rollout, cfg: RLConfig, episode_lengths: list[int], success_steps: list[int]
) -> torch.Tensor:
    """The reward PPO optimises, per transition: the env's reward as increments (``cfg.reward='progress'``)
    or as is (``raw``), plus ``cfg.success_bonus`` on the step that succeeded."""
    out, start = [], 0
    for length, success_at in zip(episode_lengths, success_steps, strict=True):
        r = rollout.rewards[start : start + length]
        r = progress_rewards(r) if cfg.reward == "progress" else r.clone()
        if success_at >= 0:
            r[success_at] += cfg.success_bonus
        out.append(r)
        start += length
    return torch.cat(out)


class ResidualPPO:
    """The actor (the corrector's residual head and the noise scale), the critic and their optimisers.

    Args:
        policy: The DCDP policy whose ``corrector.residual`` head is trained.
        cfg: The run's settings (noise, bound, learning rates, PPO's epochs, minibatch, clip, KL weight).
        generator: The exploration noise's random generator.
    """

    def __init__(self, policy, cfg: RLConfig, generator: torch.Generator) -> None:
        self.cfg = cfg
        self.policy = policy
        head = policy.corrector.residual
        action_dim = head.net[-1].out_features
        self.log_std = torch.nn.Parameter(torch.full((action_dim,), math.log(cfg.init_std)))
        self.explore = ResidualExploration(head, self.log_std, cfg.max_deviation, generator)
        self.horizon = policy.config.n_action_steps
        self.critic: ValueCritic | None = None
        self.actor_opt = torch.optim.Adam([*head.parameters(), self.log_std], lr=cfg.lr)
        self.critic_opt: torch.optim.Optimizer | None = None

    def _ensure_critic(self, rollout: Rollout) -> None:
        if self.critic is None:
            first = critic_input(tuple(a[:1] for a in rollout.inputs), self.horizon, rollout.elapsed[:1])
            self.critic = ValueCritic(first.shape[-1])
            self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=self.cfg.critic_lr)

    def update(
        self, rollout: Rollout, rewards: torch.Tensor, train_actor: bool, generator: torch.Generator
    ) -> dict[str, float]:
        """PPO epochs over one rollout (the critic always, the actor when ``train_actor``).

        Returns:
            The mean ``policy_loss``, ``kl_to_start`` and ``value_loss`` over the minibatches, and the
            ``noise_std`` after the update.
        """
        cfg = self.cfg
        self._ensure_critic(rollout)
        x = critic_input(rollout.inputs, self.horizon, rollout.elapsed)
        with torch.no_grad():
            values = self.critic(x)
            old_log_prob = gaussian_log_prob(rollout.sample, rollout.mean, self.log_std)
        advantages, returns = generalized_advantages(rewards, values, rollout.dones, cfg.gamma, cfg.lam)
        advantages = (advantages - advantages.mean()) / advantages.std().clamp_min(1e-8)
        n = len(rewards)
        sums = {"policy_loss": 0.0, "kl_to_start": 0.0, "value_loss": 0.0}
        count = 0
        for _ in range(cfg.epochs):
            order = torch.randperm(n, generator=generator)
            for begin in range(0, n, cfg.minibatch):
                idx = order[begin : begin + cfg.minibatch]
                value_loss = ((self.critic(x[idx]) - returns[idx]) ** 2).mean()
                self.critic_opt.zero_grad()
                value_loss.backward()
                self.critic_opt.step()
                sums["value_loss"] += value_loss.item()
                if train_actor:
                    policy_loss, kl = self._actor_step(rollout, idx, old_log_prob[idx], advantages[idx])
                    sums["policy_loss"] += policy_loss
                    sums["kl_to_start"] += kl
                count += 1
        out = {k: v / max(count, 1) for k, v in sums.items()}
        out["noise_std"] = self.log_std.exp().mean().item()
        return out

    def _actor_step(
        self, rollout: Rollout, idx: torch.Tensor, old_log_prob: torch.Tensor, advantages: torch.Tensor
    ) -> tuple[float, float]:
        """One gradient step of the actor on the transitions ``idx``; returns its surrogate loss and KL."""
        cfg, head = self.cfg, self.explore.head
        inputs = tuple(a[idx] for a in rollout.inputs)
        mean = head(*inputs)
        log_prob = gaussian_log_prob(rollout.sample[idx], mean, self.log_std)
        policy_loss = clipped_policy_loss(log_prob, old_log_prob, advantages, cfg.clip)
        with torch.no_grad():
            start = self.explore.start(*inputs)
        # KL(N(mean, s) || N(start, s)) with the same noise s; s is held fixed here, or the penalty could be
        # lowered by raising the noise instead of staying near the start
        kl = (((mean - start) / self.log_std.detach().exp()) ** 2).sum(-1).mean() / 2
        loss = policy_loss + cfg.kl_weight * kl
        self.actor_opt.zero_grad()
        loss.backward()
        self.actor_opt.step()
        with torch.no_grad():
            self.log_std.clamp_(min=math.log(cfg.min_std))
        return policy_loss.item(), kl.item()

    def state_dict(self) -> dict:
        """The noise, the starting head, the critic (``None`` before the first update) and the optimisers."""
        return {
            "log_std": self.log_std.detach().clone(),
            "start_head": self.explore.start.state_dict(),
            "critic": None if self.critic is None else self.critic.state_dict(),
            "critic_input_dim": None if self.critic is None else self.critic.net[0].normalized_shape[0],
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": None if self.critic_opt is None else self.critic_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned."""
        with torch.no_grad():
            self.log_std.copy_(state["log_std"])
        self.explore.start.load_state_dict(state["start_head"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        if state["critic"] is not None:
            self.critic = ValueCritic(state["critic_input_dim"])
            self.critic.load_state_dict(state["critic"])
            self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=self.cfg.critic_lr)
            self.critic_opt.load_state_dict(state["critic_opt"])
