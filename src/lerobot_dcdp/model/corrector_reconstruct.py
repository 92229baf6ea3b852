"""The paper's corrector: a VAE that re-decodes every action of the chunk from its code and the dynamics.

Stage 1 reconstructs demonstration chunks: ``L = MSE(A_hat, A) + lambda_KL KL(q(z|A) || N(0, I)) + lambda_diff
L_diff`` on observations t-M+1 .. t+H-1 and actions t .. t+H-1; stage 2 decodes action s as ``D(z, F_{t+s},
e_s)``. Measured to hurt on PushT (docs/FINDINGS.md, "The paper's reconstruct recipe"); kept as the
``configs/policy/dcdp_paper.json`` preset.
"""

from __future__ import annotations

import torch
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.model.action_vae import ActionDecoder, kl_to_standard_normal, reparameterize
from lerobot_dcdp.model.correction import sliding_windows
from lerobot_dcdp.model.corrector import Corrector
from lerobot_dcdp.model.dynamics import diff_loss
from lerobot_dcdp.model.episode_state import EpisodeState


class ReconstructCorrector(Corrector):
    """``correction='reconstruct'``: the chunk encoder E plus a recurrent action decoder D (module doc)."""

    def __init__(self, config, state_dims, image_keys, action_low, action_high, image_encoder=None) -> None:
        super().__init__(config, state_dims, image_keys, action_low, action_high, image_encoder)
        self.decoder = ActionDecoder(
            config.n_action_steps,
            action_low.shape[0],
            config.latent_dim,
            config.feature_dim,
            config.decoder_hidden_dim,
            config.step_embed_dim,
        )

    def _features(self, frames: Tensor) -> tuple[Tensor, Tensor]:
        """Frame tokens (B, T, d) -> per-step F (B, T-M+1, d) and last differentials (B, T-M+1, d)."""
        windows = sliding_windows(frames, self.config.n_history)  # (B, S, M, d)
        b, s = windows.shape[:2]
        f, d_last = self.extractor(windows.reshape(b * s, *windows.shape[2:]))
        return f.reshape(b, s, -1), d_last.reshape(b, s, -1)

    def loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        cfg = self.config
        frames = self.frame_encoder(self.frames(batch))  # (B, M+H-1, d)
        feats, d_last = self._features(frames)  # (B, H, d)
        target = self.to_unit(batch[ACTION])
        mu, logvar = self.encoder(target)
        z = reparameterize(mu, logvar) if self.training else mu
        pred = self.decoder(z, feats)
        valid = (
            (~batch["action_is_pad"]).unsqueeze(-1).to(pred.dtype)
            if "action_is_pad" in batch
            else torch.ones_like(pred[..., :1])
        )
        recon = ((pred - target) ** 2 * valid).sum() / (valid.sum() * pred.shape[-1]).clamp_min(1.0)
        kl = kl_to_standard_normal(mu, logvar)
        loss = recon + cfg.kl_weight * kl
        l_diff = diff_loss(feats.flatten(0, 1), d_last.flatten(0, 1))
        if cfg.use_diff_loss:
            loss = loss + cfg.diff_weight * l_diff
        return loss, {
            "recon_loss": recon.item(),
            "kl_loss": kl.item(),
            "diff_loss": l_diff.item(),
            "alpha": float(self.extractor.alpha.detach()),
        }

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        state.z = self.encode_chunk(chunk)
        state.h = self.decoder.initial_state(state.z)

    def step(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        a, state.h = self.decoder.step(state.z, self.feature(state), step, state.h)
        return self.from_unit(a)

    def query_chunk(self, state: EpisodeState, chunk: Tensor) -> Tensor:
        feats = self.feature(state).unsqueeze(1).expand(-1, self.config.n_action_steps, -1)
        return self.from_unit(self.decoder(self.encode_chunk(chunk), feats))
