"""Exploration around a residual corrector for on-policy RL (``dcdp-finetune-rl``): the actor and the critic.

The actor is the corrector's own :class:`~lerobot_dcdp.model.residual.ResidualHead`: its delta is the mean of
a
diagonal Gaussian in the [-1, 1] action range. :class:`ResidualExploration` is a forward hook on that head:
during a rollout it replaces each delta by a sample, bounded to ``max_deviation`` around the *starting*
corrector's delta (so exploration never strays far from the corrector RL began with), and records the head's
inputs, which are fixed functions of the observations (the frame encoder, the extractor and the chunk encoder
stay frozen). The PPO update recomputes the delta from those inputs with gradients.

:class:`ValueCritic` scores the same inputs (plus the episode's elapsed share); it is trained beside the actor
and is not part of the saved policy.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from torch import Tensor, nn
from torch.nn import functional

from lerobot_dcdp.model.residual import ResidualHead


@dataclass
class HeadCall:
    """One call of the residual head during a rollout.

    Attributes:
        inputs: The head's inputs ``(z, plan_s, feature, change, step)``, each with the batch first.
        mean: The head's delta (B, A): the Gaussian's mean.
        sample: The sampled delta (B, A), before bounding.
    """

    inputs: tuple[Tensor, ...]
    mean: Tensor
    sample: Tensor


class ResidualExploration:
    """Turns a residual head into a Gaussian policy while it is ``active`` (a forward hook).

    Args:
        head: The corrector's residual head (the actor; trained).
        log_std: (A,) log standard deviation of the exploration noise, in the [-1, 1] action range.
        max_deviation: Bound on ``|executed delta - starting delta|`` per action dimension.
        generator: The noise's random generator (a run's samples are reproducible).
    """

    def __init__(self, head: ResidualHead, log_std: Tensor, max_deviation: float, generator: torch.Generator):
        if max_deviation <= 0:
            raise ValueError(f"max_deviation must be > 0, got {max_deviation}")
        self.head = head
        #: the corrector RL starts from, frozen: the centre of the bound and of the KL penalty
        self.start = copy.deepcopy(head).requires_grad_(False).eval()
        self.log_std = log_std
        self.max_deviation = max_deviation
        self.generator = generator
        self.active = False
        self.calls: list[HeadCall] = []
        self._handle = head.register_forward_hook(self._hook)

    def _hook(self, module: nn.Module, args: tuple, output: Tensor) -> Tensor | None:
        if not self.active:
            return None
        noise = torch.randn(output.shape, generator=self.generator) * self.log_std.detach().exp()
        sample = output.detach() + noise
        with torch.no_grad():
            start = self.start(*args)
        self.calls.append(HeadCall(tuple(a.detach() for a in args), output.detach(), sample))
        low, high = start - self.max_deviation, start + self.max_deviation
        return torch.maximum(torch.minimum(sample, high), low)

    def take(self) -> HeadCall:
        """The one head call since the last ``take`` (a control step of the ``dcdp`` mode makes one)."""
        if len(self.calls) != 1:
            raise RuntimeError(
                f"expected one residual-head call per control step, saw {len(self.calls)}: run the policy "
                "with execution='dcdp' and corrector.fast_inference=False"
            )
        return self.calls.pop()

    def remove(self) -> None:
        """Detach the hook: the head is the plain corrector again."""
        self._handle.remove()


def critic_input(inputs: tuple[Tensor, ...], horizon: int, elapsed: Tensor) -> Tensor:
    """What the critic sees: the head's inputs (the step as one-hot over ``horizon``) and ``elapsed`` (B,),
    the episode's elapsed share of its step limit (the episode's end is part of the state)."""
    z, plan_s, feature, change, step = inputs
    onehot = functional.one_hot(step.long(), horizon).to(z.dtype)
    return torch.cat([z, plan_s, feature, change, onehot, elapsed.unsqueeze(-1).to(z.dtype)], dim=-1)


class ValueCritic(nn.Module):
    """V(state) from :func:`critic_input`: a layer-normalised MLP."""

    def __init__(self, input_dim: int, hidden_dim: int = 256) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.LayerNorm(input_dim),
            nn.Linear(input_dim, hidden_dim),
            nn.Tanh(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.Tanh(),
            nn.Linear(hidden_dim, 1),
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x).squeeze(-1)
