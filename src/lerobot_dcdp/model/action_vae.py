"""Asymmetric action VAE (paper Sec. 3.3).

The encoder E sees only the min-max normalised action chunk and returns ``mu, logvar`` of the latent z;
the decoder D is a GRU that emits action s of the chunk from ``(z, F_{t+s}, e_s)`` -- the latent of the
planned chunk, the dynamic feature of the newest observation window, and a step embedding. Decoding one
step at a time with a carried hidden state is exactly what stage 2 does, so training loops the same
:meth:`ActionDecoder.step` over the chunk.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class ChunkEncoder(nn.Module):
    """E: normalised chunk (B, H, A) -> (mu, logvar), each (B, latent)."""

    def __init__(self, horizon: int, action_dim: int, hidden_dim: int, latent_dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Flatten(),
            nn.Linear(horizon * action_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, 2 * latent_dim),
        )

    def forward(self, chunk: Tensor) -> tuple[Tensor, Tensor]:
        mu, logvar = self.net(chunk).chunk(2, dim=-1)
        return mu, logvar.clamp(-10.0, 10.0)


class ActionDecoder(nn.Module):
    """D: GRU decoder; ``step(z, F_{t+s}, s, h) -> (action_s in [-1, 1], h')``."""

    def __init__(
        self, horizon: int, action_dim: int, latent_dim: int, feature_dim: int, hidden_dim: int, step_dim: int
    ) -> None:
        super().__init__()
        self.step_embed = nn.Embedding(horizon, step_dim)
        self.init_hidden = nn.Linear(latent_dim, hidden_dim)
        self.cell = nn.GRUCell(latent_dim + feature_dim + step_dim, hidden_dim)
        self.out = nn.Sequential(
            nn.Linear(hidden_dim + latent_dim, hidden_dim), nn.GELU(), nn.Linear(hidden_dim, action_dim)
        )

    def initial_state(self, z: Tensor) -> Tensor:
        return torch.tanh(self.init_hidden(z))

    def step(self, z: Tensor, feature: Tensor, s: int | Tensor, h: Tensor) -> tuple[Tensor, Tensor]:
        if isinstance(s, int):
            s = torch.full((z.shape[0],), s, dtype=torch.long, device=z.device)
        h = self.cell(torch.cat([z, feature, self.step_embed(s)], dim=-1), h)
        return torch.tanh(self.out(torch.cat([h, z], dim=-1))), h

    def forward(self, z: Tensor, features: Tensor) -> Tensor:
        """Decode a whole chunk: z (B, latent), features (B, H, d) -> actions (B, H, A)."""
        h = self.initial_state(z)
        actions = []
        for s in range(features.shape[1]):
            a, h = self.step(z, features[:, s], s, h)
            actions.append(a)
        return torch.stack(actions, dim=1)


def reparameterize(mu: Tensor, logvar: Tensor) -> Tensor:
    return mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)


def kl_to_standard_normal(mu: Tensor, logvar: Tensor) -> Tensor:
    """KL(q(z|A) || N(0, I)) summed over latent dims, averaged over the batch."""
    return (-0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum(-1)).mean()
