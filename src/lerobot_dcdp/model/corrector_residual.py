"""The residual corrector (default): ``a_s = plan_s + delta(z, plan_s, F, change since plan time, e_s)``.

Stage 1: one control step t per sample (``training_samples.py``: recorded corrections of stale chunks, or
plain demonstrations with synthesised object motion); frames t-K+1 .. t (K = max(M, H)), the last M feed F_t,
the one at t-s is the plan-time frame; ``L = MSE(plan_s + delta, a_t) + lambda_KL KL + lambda_diff L_diff``.
Stage 2: ``begin_chunk`` encodes the chunk once (and sums the head's per-chunk inputs, ``chunk_terms``);
``step`` adds delta to the planned action; delta == 0 returns the plan bit for bit.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lerobot_dcdp.model.action_vae import kl_to_standard_normal, reparameterize
from lerobot_dcdp.model.anchoring import ObjectAnchor
from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.corrector import Corrector
from lerobot_dcdp.model.dynamics import diff_loss
from lerobot_dcdp.model.episode_state import EpisodeState
from lerobot_dcdp.model.residual import ResidualHead, change_input
from lerobot_dcdp.model.training_samples import CorrectionSamples


class ResidualCorrector(Corrector):
    """``correction='residual'``: the chunk encoder E plus a residual head on the planned action.

    Args:
        config, state_dims, image_keys, action_low, action_high: As for ``corrector.Corrector``.
        normalizer: The base's normaliser (training plans and anchoring work in raw units).
        anchor: The object anchor, when the head also sees the anchoring rule's proposal (``anchor_input``).
    """

    def __init__(
        self,
        config,
        state_dims: dict[str, int],
        image_keys: list[str],
        action_low: Tensor,
        action_high: Tensor,
        normalizer: BaseNormalizer,
        anchor: ObjectAnchor | None = None,
        image_encoder: tuple[nn.Module, int] | None = None,
    ) -> None:
        super().__init__(config, state_dims, image_keys, action_low, action_high, image_encoder)
        action_dim = action_low.shape[0]
        change_dim = 2 * (sum(state_dims.values()) if state_dims else config.feature_dim)
        change_dim += action_dim if config.anchor_input else 0
        self.residual = ResidualHead(
            config.n_action_steps,
            action_dim,
            config.latent_dim,
            config.feature_dim,
            change_dim,
            config.decoder_hidden_dim,
            config.step_embed_dim,
        )
        if config.anchor_input and anchor is None:
            raise ValueError("anchor_input=True needs anchor_feature (the object's xy keypoints)")
        self.anchor = anchor
        self.samples = CorrectionSamples(config, normalizer, self.frame_keys)

    def loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        cfg = self.config
        sample = self.samples(batch)
        batch, plan, step = sample.batch, sample.plan, sample.step
        frames, vec = self.frame_encoder.encode(self.frames(batch))  # (B, K, d)
        if frames.dim() != 3:
            raise ValueError(
                "correction='residual' needs the observation history of the config's delta indices"
            )
        feature, d_last = self.extractor(frames[:, -cfg.n_history :])
        # what the head compares between plan time and now: the standardised vector inputs (tokens when the
        # corrector reads images only), (B, K, r)
        rep = frames if vec is None else vec
        k = rep.shape[1]
        then = (k - 1 - sample.age).clamp_min(0)  # the frame the chunk was planned from
        idx = then.view(-1, 1, 1).expand(-1, 1, rep.shape[-1])
        at_plan = rep.gather(1, idx)[:, 0]
        plan_unit = self.to_unit(plan)
        mu, logvar = self.encoder(plan_unit)
        z = reparameterize(mu, logvar) if self.training else mu
        rows = torch.arange(len(step), device=step.device)
        plan_s = plan_unit[rows, step]
        change = change_input(at_plan, rep[:, -1], cfg.change_scale)
        if cfg.anchor_input:
            kp = self.anchor.normalizer(self.anchor.key, batch[self.anchor.key], inverse=True)
            kp = kp.reshape(*kp.shape[:2], -1, 2)
            proposal = self.to_unit(self.anchor.carry(plan[rows, step], kp[rows, then], kp[:, -1]))
            change = torch.cat([change, cfg.change_scale * (proposal - plan_s)], dim=-1)
        delta = self.residual(z, plan_s, feature, change, step)
        target = self.to_unit(sample.target.reshape(plan_s.shape))
        extra = {"anchor_gap": ((proposal - target) ** 2).mean().item()} if cfg.anchor_input else {}
        valid = sample.valid.unsqueeze(-1)
        denom = (valid.sum() * delta.shape[-1]).clamp_min(1.0)
        recon = (((plan_s + delta - target) ** 2) * valid).sum() / denom
        kl = kl_to_standard_normal(mu, logvar)
        l_diff = diff_loss(feature, d_last)
        loss = recon + cfg.kl_weight * kl + (cfg.diff_weight * l_diff if cfg.use_diff_loss else 0.0)
        return loss, {
            "recon_loss": recon.item(),
            "plan_gap": ((((plan_s - target) ** 2) * valid).sum() / denom).item(),
            "kl_loss": kl.item(),
            "diff_loss": l_diff.item(),
            "synthesised": float(sample.synthesised),
            **extra,
        }

    def chunk_state(self, chunk: Tensor, at_plan: Tensor | None) -> tuple[Tensor, Tensor | None, ...]:
        """``(z, terms, w_step)``: the chunk's code and, on the fast path, the head's per-chunk inputs summed
        (``ResidualHead.chunk_terms``; None otherwise)."""
        z = self.encode_chunk(chunk)
        if self.fast_inference and not self.config.anchor_input and at_plan is not None:
            return (z, *self.residual.chunk_terms(z, self.to_unit(chunk), at_plan))
        return z, None, None

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        """Encode the chunk; on the fast path also sum the head's per-chunk inputs (``chunk_terms``), or take
        both from ``prepared`` (:meth:`chunk_state` done by the planner's worker)."""
        state.z, state.terms, state.w_step = prepared or self.chunk_state(chunk, state.at_plan)

    def step(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        """``plan_s + delta`` (base-normalised)."""
        plan_s = state.chunk[:, step]
        feature = self.feature(state)
        if state.terms is not None:  # per-chunk terms summed at plan time
            change = self.config.change_scale * (state.rep - state.at_plan)
            delta = self.residual.step(state.terms[:, step], feature, change, state.w_step)
            return plan_s + delta * self.action_half_range
        s = torch.full((plan_s.shape[0],), step, dtype=torch.long, device=plan_s.device)
        change = change_input(state.at_plan, state.rep, self.config.change_scale)
        plan_unit = self.to_unit(plan_s)
        if self.config.anchor_input:
            proposal = self.to_unit(self.anchor.carry(plan_s, state.anchor_plan, self.anchor.points(batch)))
            change = torch.cat([change, self.config.change_scale * (proposal - plan_unit)], dim=-1)
        delta = self.residual(state.z, plan_unit, feature, change, s)
        return plan_s + delta * self.action_half_range

    def query_chunk(self, state: EpisodeState, chunk: Tensor) -> Tensor:
        z, unit, feature = self.encode_chunk(chunk), self.to_unit(chunk), self.feature(state)
        change = change_input(state.rep, state.rep, self.config.change_scale)
        if self.config.anchor_input:  # a still object: the anchored proposal is the plan itself
            change = torch.cat([change, torch.zeros_like(unit[:, 0])], dim=-1)
        out = []
        for s in range(chunk.shape[1]):
            steps = torch.full((chunk.shape[0],), s, dtype=torch.long, device=chunk.device)
            delta = self.residual(z, unit[:, s], feature, change, steps)
            out.append(chunk[:, s] + delta * self.action_half_range)
        return torch.stack(out, dim=1)
