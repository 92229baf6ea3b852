"""DCDP policy: a frozen chunking base plus a corrector that re-decodes every action of a chunk per step.

Stage 1 (``forward``): the corrector -- dynamic feature extractor pi_f and asymmetric action VAE -- learns to
reconstruct demonstration chunks ``A_{t:t+H-1}`` from their latent z and the per-step features
``F_{t+s} = pi_f(O_{t+s-M+1:t+s})``:
``L = MSE(A_hat, A) + lambda_KL KL(q(z|A) || N(0, I)) + lambda_diff L_diff``
(paper Eq. for the stage-1 objective). The base is not called.

Stage 2 (``select_action``): every H steps the base plans a chunk, which is normalised to [-1, 1] and
encoded once to ``z_t = mu``; at every step s the newest observation enters the history bank (one
cached frame token per step) and the action is ``D(z_t, F_{t+s}, e_s)``. The baselines (open loop, closed
loop, temporal ensemble) are other execution modes of this same loop.
"""

from __future__ import annotations

import os

import torch
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.action_vae import ActionDecoder, ChunkEncoder, kl_to_standard_normal, reparameterize
from lerobot_dcdp.base_policy import load_base_action_stats, load_base_policy
from lerobot_dcdp.chunk_sources import ChunkSource, make_chunk_source
from lerobot_dcdp.configuration_dcdp import DCDPConfig
from lerobot_dcdp.correction import (
    from_unit_range,
    sliding_windows,
    state_dict_sha256,
    temporal_ensemble_step,
    to_unit_range,
)
from lerobot_dcdp.dynamics import DynamicFeatureExtractor, FrameEncoder, diff_loss


class BaseMismatchError(ValueError):
    """The base policy found at load time is not the one the corrector was trained against."""


class DCDPPolicy(PreTrainedPolicy):
    """DCDP corrector around a frozen chunking base policy (see the module docstring)."""

    config_class = DCDPConfig
    name = "dcdp"

    def __init__(self, config: DCDPConfig, dataset_stats: dict | None = None, dataset_meta=None, **kwargs):
        super().__init__(config)
        self.config = config
        base = load_base_policy(config.base_policy_path, config.device, config.pretrained_path)
        object.__setattr__(self, "_base", base)  # not a submodule: out of state_dict/parameters/train()
        digest = state_dict_sha256(base.state_dict())
        if config.base_weights_sha256 is None:
            config.base_weights_sha256 = digest
        elif config.base_weights_sha256 != digest:
            raise BaseMismatchError(
                f"base_weights_sha256 mismatch: the corrector was trained against base weights "
                f"{config.base_weights_sha256[:12]}..., but base_policy_path={config.base_policy_path!r} "
                f"now holds {digest[:12]}...; retrain stage 1 or point base_policy_path at the original base"
            )
        if config.base_policy_type not in (None, base.config.type):
            raise BaseMismatchError(
                f"base_policy_type mismatch: recorded {config.base_policy_type!r}, found {base.config.type!r}"
            )
        config.base_policy_type = base.config.type
        config.normalization_mapping = dict(base.config.normalization_mapping)
        self.source: ChunkSource = make_chunk_source(base)
        self._check_against_base(base)
        config.validate_features()

        feats = config.input_features
        keys = config.corrector_features
        state_dims = {
            k: feats[k].shape[0] for k in keys if feats[k].type in (FeatureType.STATE, FeatureType.ENV)
        }
        image_keys = [k for k in keys if feats[k].type is FeatureType.VISUAL]
        if config.resolved_backbone == "mlp":
            image_keys = []
        action_dim = config.action_feature.shape[0]
        self.frame_encoder = FrameEncoder(
            state_dims,
            image_keys,
            config.feature_dim,
            config.state_hidden_dim,
            config.image_backbone_weights,
            config.freeze_image_backbone,
        )
        self.extractor = DynamicFeatureExtractor(
            config.n_history,
            config.feature_dim,
            config.n_heads,
            config.alpha_init,
            config.use_temporal_attention,
            config.use_diff_cross_attention,
            use_alpha=config.use_diff_cross_attention or config.use_diff_loss,
        )
        self.encoder = ChunkEncoder(
            config.n_action_steps, action_dim, config.encoder_hidden_dim, config.latent_dim
        )
        self.decoder = ActionDecoder(
            config.n_action_steps,
            action_dim,
            config.latent_dim,
            config.feature_dim,
            config.decoder_hidden_dim,
            config.step_embed_dim,
        )
        if dataset_stats is not None:
            self._set_raw_input_scaling(state_dims, dataset_stats)
        low, high = self._action_range(action_dim)
        self.register_buffer("action_low", low, persistent=False)
        self.register_buffer("action_high", high, persistent=False)
        self._frame_keys = list(state_dims) + image_keys
        self._needed_keys = sorted(set(self._frame_keys) | set(base.config.input_features or {}))
        self.reset()

    # ------------------------------------------------------------------ set-up helpers
    @property
    def base(self) -> PreTrainedPolicy:
        """The frozen base policy (not a submodule of this one)."""
        return self._base

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, config: DCDPConfig | None = None, **kwargs):
        if config is None:
            config = DCDPConfig.from_pretrained(
                pretrained_name_or_path,
                **{
                    k: v
                    for k, v in kwargs.items()
                    if k in ("revision", "cache_dir", "local_files_only", "token")
                },
            )
        if config.pretrained_path is None and os.path.isdir(str(pretrained_name_or_path)):
            config.pretrained_path = pretrained_name_or_path
        return super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)

    def _check_against_base(self, base: PreTrainedPolicy) -> None:
        cfg, bcfg = self.config, base.config
        if cfg.n_action_steps > self.source.chunk_length:
            raise ValueError(
                f"n_action_steps={cfg.n_action_steps} exceeds the base's chunk: "
                f"base type {bcfg.type!r} returns "
                f"{self.source.chunk_length} actions per call"
            )
        if cfg.output_features and bcfg.output_features:
            ours, theirs = cfg.action_feature, bcfg.action_feature
            if ours is not None and theirs is not None and tuple(ours.shape) != tuple(theirs.shape):
                raise ValueError(
                    f"feature mismatch on 'action': dataset/env shape {tuple(ours.shape)}, "
                    f"base {tuple(theirs.shape)}"
                )
        if cfg.input_features:
            for key, ft in (bcfg.input_features or {}).items():
                if key not in cfg.input_features:
                    raise ValueError(
                        f"feature mismatch: the base needs input {key!r}, "
                        "which the dataset/env does not provide "
                        f"(has {sorted(cfg.input_features)})"
                    )
                if tuple(cfg.input_features[key].shape) != tuple(ft.shape):
                    raise ValueError(
                        f"feature mismatch on {key!r}: "
                        f"dataset/env shape {tuple(cfg.input_features[key].shape)}, "
                        f"base {tuple(ft.shape)}"
                    )
        else:
            cfg.input_features = dict(bcfg.input_features)
            cfg.output_features = dict(bcfg.output_features)

    def _set_raw_input_scaling(self, state_dims: dict[str, int], stats: dict) -> None:
        """Standardise (with the dataset's stats) the vector inputs that the base's normaliser leaves raw."""
        mapping = self.config.normalization_mapping
        shift, scale, i = self.frame_encoder.state_shift.clone(), self.frame_encoder.state_scale.clone(), 0
        for key, dim in state_dims.items():
            mode = mapping.get(self.config.input_features[key].type.value, NormalizationMode.IDENTITY)
            if (
                NormalizationMode(mode) is NormalizationMode.IDENTITY
                and key in stats
                and "mean" in stats[key]
            ):
                shift[i : i + dim] = torch.as_tensor(stats[key]["mean"], dtype=torch.float32).reshape(-1)
                scale[i : i + dim] = (
                    torch.as_tensor(stats[key]["std"], dtype=torch.float32).reshape(-1).clamp_min(1e-6)
                )
            i += dim
        self.frame_encoder.state_shift.copy_(shift)
        self.frame_encoder.state_scale.copy_(scale)

    def _action_range(self, action_dim: int) -> tuple[Tensor, Tensor]:
        """Range of the base-normalised actions, mapped to [-1, 1] before encoding (paper: min-max)."""
        ones = torch.ones(action_dim)
        stats = load_base_action_stats(self.config.base_policy_path, self.config.pretrained_path)
        mode = self.config.normalization_mapping.get("ACTION", NormalizationMode.MIN_MAX)
        mode = NormalizationMode(mode) if not isinstance(mode, NormalizationMode) else mode
        if stats is None or mode is NormalizationMode.MIN_MAX or "min" not in stats:
            return -ones, ones
        lo = torch.as_tensor(stats["min"], dtype=torch.float32).reshape(-1)
        hi = torch.as_tensor(stats["max"], dtype=torch.float32).reshape(-1)
        if mode is NormalizationMode.MEAN_STD:
            mean = torch.as_tensor(stats["mean"], dtype=torch.float32).reshape(-1)
            std = torch.as_tensor(stats["std"], dtype=torch.float32).reshape(-1).clamp_min(1e-8)
            lo, hi = (lo - mean) / std, (hi - mean) / std
        return lo, hi

    def to(self, *args, **kwargs):
        super().to(*args, **kwargs)
        self._base.to(*args, **kwargs)
        return self

    def generate_model_card(self, dataset_repo_id, model_type, license, tags, cfg=None, dataset_meta=None):
        """DCDP's own card (base reference and hash, measured numbers, eval command); built offline."""
        from lerobot_dcdp.model_card import make_model_card

        return make_model_card(
            self.config, state_dict_sha256(self.state_dict()), dataset_repo_id, license, tags
        )

    def get_optim_params(self) -> list[torch.nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    # ------------------------------------------------------------------ stage 1
    def _features(self, frames: Tensor) -> tuple[Tensor, Tensor]:
        """Frame tokens (B, T, d) -> per-step F (B, T-M+1, d) and last differentials (B, T-M+1, d)."""
        windows = sliding_windows(frames, self.config.n_history)  # (B, S, M, d)
        b, s = windows.shape[:2]
        f, d_last = self.extractor(windows.reshape(b * s, *windows.shape[2:]))
        return f.reshape(b, s, -1), d_last.reshape(b, s, -1)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Stage-1 loss on a sample of observations t-M+1..t+H-1 and actions t..t+H-1."""
        cfg = self.config
        frames = self.frame_encoder({k: batch[k] for k in self._frame_keys})  # (B, M+H-1, d)
        feats, d_last = self._features(frames)  # (B, H, d)
        target = to_unit_range(batch[ACTION], self.action_low, self.action_high)
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

    # ------------------------------------------------------------------ stage 2
    def reset(self) -> None:
        """Clear the history bank and the chunk state, and reset the base (call on env reset)."""
        self.source.reset()
        self._bank: Tensor | None = None  # (B, M, d) cached frame tokens
        self._step = 0
        self._chunk: Tensor | None = None
        self._plan: Tensor | None = None
        self._z: Tensor | None = None
        self._h: Tensor | None = None

    def _check_batch(self, batch: dict[str, Tensor]) -> None:
        missing = [k for k in self._needed_keys if k not in batch]
        if missing:
            raise ValueError(f"observation is missing {missing}; it has {sorted(batch)}")

    def _push_frame(self, batch: dict[str, Tensor]) -> None:
        token = self.frame_encoder({k: batch[k] for k in self._frame_keys})  # (B, d): one new frame
        if self._bank is None or self._bank.shape[0] != token.shape[0]:
            self._bank = token.unsqueeze(1).repeat(1, self.config.n_history, 1)
        else:
            self._bank = torch.cat([self._bank[:, 1:], token.unsqueeze(1)], dim=1)

    def encode_chunk(self, chunk: Tensor) -> Tensor:
        """Normalise a base chunk (B, H, A) to [-1, 1] and encode it to z = mu."""
        return self.encoder(to_unit_range(chunk, self.action_low, self.action_high))[0]

    def decode_step(self, feature: Tensor, step: int) -> Tensor:
        """Action of chunk step ``step`` from the current z, F and decoder state (base-normalised)."""
        a, self._h = self.decoder.step(self._z, feature, step, self._h)
        return from_unit_range(a, self.action_low, self.action_high)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor]) -> Tensor:
        """One action (B, A) per environment for the current step (normalised; the post-processor maps it)."""
        self._check_batch(batch)
        mode, horizon = self.config.execution, self.config.n_action_steps
        prepared = self.source.observe(batch)
        if mode == "dcdp":
            self._push_frame(batch)
        replan = mode in ("closed_loop", "temporal_ensemble") or self._step == 0
        if replan:
            chunk = self.source.chunk(prepared)
            if mode == "temporal_ensemble":
                self._plan = temporal_ensemble_step(self._plan, chunk, self.config.te_weight)
            elif mode == "closed_loop":
                self._plan = chunk
            else:
                self._chunk = chunk[:, :horizon]
                if mode == "dcdp":
                    self._z = self.encode_chunk(self._chunk)
                    self._h = self.decoder.initial_state(self._z)
        if mode in ("closed_loop", "temporal_ensemble"):
            return self._plan[:, 0]
        step = self._step
        self._step = (self._step + 1) % horizon
        if mode == "open_loop":
            return self._chunk[:, step]
        feature, _ = self.extractor(self._bank)
        return self.decode_step(feature, step)

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor]) -> Tensor:
        """A corrected chunk (B, H, A) for the current observation, decoded with the current feature F
        for every step (no future observations exist yet)."""
        self._check_batch(batch)
        prepared = self.source.observe(batch)
        self._push_frame(batch)
        chunk = self.source.chunk(prepared)[:, : self.config.n_action_steps]
        z = self.encode_chunk(chunk)
        feature, _ = self.extractor(self._bank)
        feats = feature.unsqueeze(1).expand(-1, self.config.n_action_steps, -1)
        return from_unit_range(self.decoder(z, feats), self.action_low, self.action_high)


__all__ = ["DCDPPolicy", "BaseMismatchError"]
