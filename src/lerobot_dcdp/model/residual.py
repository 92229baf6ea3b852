"""Residual correction head: ``a_s = plan_s + delta`` (ours; the paper re-decodes the whole action).

The paper's decoder reproduces action s from ``(z, F_{t+s}, e_s)``; trained to reconstruct static
demonstrations, it either copies the chunk (z explains everything) or becomes a reactive policy on F (the
collapse measured in docs/FINDINGS.md). The residual head keeps the base's plan as the answer and learns
only how far to move it: it sees the chunk's latent z (encoder E), the planned action ``plan_s``, the
dynamic feature F of the latest M frames, the change of the observation since the chunk was planned, and
``e_s``. Its last layer starts at zero, so a fresh corrector is exactly open loop.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def change_input(at_plan: Tensor, now: Tensor, scale: float) -> Tensor:
    """What the residual head sees of the observation: where it was at plan time and how it moved since."""
    return torch.cat([at_plan, scale * (now - at_plan)], dim=-1)


class ResidualHead(nn.Module):
    """delta(z, plan_s, F, change, e_s) -> (B, A) in the [-1, 1] action range; zero at initialisation."""

    def __init__(
        self,
        horizon: int,
        action_dim: int,
        latent_dim: int,
        feature_dim: int,
        change_dim: int,
        hidden_dim: int,
        step_dim: int,
    ) -> None:
        super().__init__()
        self.split = (latent_dim, action_dim, feature_dim, change_dim // 2, change_dim - change_dim // 2)
        self.step_embed = nn.Embedding(horizon, step_dim)
        self.net = nn.Sequential(
            nn.Linear(latent_dim + action_dim + feature_dim + change_dim + step_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, action_dim),
        )
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, z: Tensor, plan_s: Tensor, feature: Tensor, change: Tensor, step: Tensor) -> Tensor:
        return self.net(torch.cat([z, plan_s, feature, change, self.step_embed(step)], dim=-1))

    def chunk_terms(self, z: Tensor, plan_unit: Tensor, at_plan: Tensor) -> tuple[Tensor, Tensor]:
        """Work done once per chunk for the per-step path of :meth:`step` (inference; the change input is
        :func:`change_input`'s ``[at_plan, scale * (now - at_plan)]``).

        The first layer is linear in its concatenated input, so the parts fixed for a whole chunk -- z, each
        step's ``plan_s`` and ``e_s``, the plan-time observation, the bias -- are summed once per chunk:
        ``(B, H, hidden)``. Returns them and the first layer's weights for the per-step inputs (F, change).
        """
        w, b = self.net[0].weight, self.net[0].bias
        wz, wp, wf, wc1, wc2, we = w.split((*self.split, self.step_embed.embedding_dim), dim=1)
        steps = self.step_embed.weight[: plan_unit.shape[1]]  # (H, e)
        fixed = b + z @ wz.T + at_plan @ wc1.T  # (B, hidden)
        terms = fixed.unsqueeze(1) + plan_unit @ wp.T + steps @ we.T  # (B, H, hidden)
        return terms, torch.cat([wf, wc2], dim=1).T.contiguous()

    def step(self, terms_s: Tensor, feature: Tensor, change: Tensor, w_step: Tensor) -> Tensor:
        """delta for one step from :meth:`chunk_terms`' ``terms[:, s]``: the same function as ``forward``
        (equal up to float rounding), a few small ops instead of a concatenation of five inputs."""
        h = torch.addmm(terms_s, torch.cat([feature, change], dim=-1), w_step)
        return self.net[1:](h)
