"""What every corrector holds: the frame encoder, the dynamic feature extractor and the chunk encoder.

A corrector is an ``nn.Module`` with four entry points, used by ``DCDPPolicy``: ``loss(batch)`` (stage 1),
``begin_chunk(state, chunk)`` (once per planned chunk), ``step(state, s, batch)`` (the corrected action s of
the chunk, every control step) and ``query_chunk(state, chunk)`` (the corrected
chunk a still world would get). The two kinds are in ``corrector_residual.py`` (default) and
``corrector_reconstruct.py`` (the paper's).
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING

import torch
from lerobot.configs.types import NormalizationMode
from torch import Tensor, nn

from lerobot_dcdp.model.action_vae import ChunkEncoder
from lerobot_dcdp.model.correction import from_unit_range, to_unit_range
from lerobot_dcdp.model.dynamics import BASE_ENCODED_SUFFIX, DynamicFeatureExtractor, FrameEncoder
from lerobot_dcdp.model.episode_state import EpisodeState

if TYPE_CHECKING:  # the config lives in the policy layer, above this one
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig


class Corrector(nn.Module):
    """Frame encoder, dynamic feature extractor F and chunk encoder E, shared by both corrector kinds.

    Args:
        config: The policy's config (sizes, history length, feature switches).
        state_dims: Width of each vector observation the corrector reads, in input order.
        image_keys: The camera observations it reads (empty for vector-only correctors).
        action_low: Low end of the base-normalised action range (A,), mapped to -1 before encoding.
        action_high: High end of that range (A,), mapped to +1.
    """

    def __init__(
        self,
        config: DCDPConfig,
        state_dims: dict[str, int],
        image_keys: list[str],
        action_low: Tensor,
        action_high: Tensor,
        image_encoder: tuple[nn.Module, int] | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.frame_encoder = FrameEncoder(
            state_dims,
            image_keys,
            config.feature_dim,
            config.state_hidden_dim,
            config.image_backbone_weights,
            config.freeze_image_backbone,
            image_encoder,
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
            config.n_action_steps, action_low.shape[0], config.encoder_hidden_dim, config.latent_dim
        )
        self.register_buffer("action_low", action_low, persistent=False)
        self.register_buffer("action_high", action_high, persistent=False)
        self.register_buffer("action_half_range", 0.5 * (action_high - action_low), persistent=False)
        #: the observation keys one frame is made of (vectors first, then cameras)
        self.frame_keys = list(state_dims) + list(image_keys)
        #: inference: allow the per-chunk shortcuts (the residual head's chunk terms, the compiled kernel);
        #: False runs every step through the plain modules (same actions up to float rounding)
        self.fast_inference = True

    def to_unit(self, actions: Tensor) -> Tensor:
        """Base-normalised actions -> the [-1, 1] range the networks work in."""
        return to_unit_range(actions, self.action_low, self.action_high)

    def from_unit(self, actions: Tensor) -> Tensor:
        """Inverse of :meth:`to_unit`."""
        return from_unit_range(actions, self.action_low, self.action_high)

    def set_input_scaling(self, stats: dict, raw_keys: Collection[str] | None = None) -> None:
        """Standardise, with the dataset's ``stats``, the vector inputs that the base's normaliser leaves raw
        (saved with the weights): ``raw_keys``, default those whose feature type the base's normalisation
        mapping leaves as they are (a key the base has no statistics for is raw too: pass it here)."""
        cfg, encoder = self.config, self.frame_encoder
        shift, scale, i = encoder.state_shift.clone(), encoder.state_scale.clone(), 0
        for key in encoder.state_keys:
            dim = cfg.input_features[key].shape[0]
            mode = cfg.normalization_mapping.get(
                cfg.input_features[key].type.value, NormalizationMode.IDENTITY
            )
            identity = NormalizationMode(mode) is NormalizationMode.IDENTITY
            raw = identity if raw_keys is None else key in raw_keys
            if raw and "mean" in stats.get(key, {}):
                shift[i : i + dim] = torch.as_tensor(stats[key]["mean"], dtype=torch.float32).reshape(-1)
                scale[i : i + dim] = (
                    torch.as_tensor(stats[key]["std"], dtype=torch.float32).reshape(-1).clamp_min(1e-6)
                )
            i += dim
        encoder.state_shift.copy_(shift)
        encoder.state_scale.copy_(scale)

    def encode_chunk(self, chunk: Tensor) -> Tensor:
        """Normalise a base chunk (B, H, A) to [-1, 1] and encode it to z = mu."""
        return self.encoder(self.to_unit(chunk))[0]

    def frames(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The observation entries one frame is made of: a camera's base-encoder features encoded beforehand
        (``dcdp-precompute-base-features``) in place of its frames where the batch holds them."""
        out = {}
        for k in self.frame_keys:
            encoded = k + BASE_ENCODED_SUFFIX
            if encoded in batch:
                out[encoded] = batch[encoded]
            else:
                out[k] = batch[k]
        return out

    def push_frame(self, state: EpisodeState, batch: dict[str, Tensor]) -> None:
        """Encode the newest observation into the history bank (filled with it on an episode's first step)
        and keep its change representation (its standardised vectors, or its token without vectors)."""
        token, vec = self.frame_encoder.encode(self.frames(batch))
        if state.bank is None or state.bank.shape[0] != token.shape[0]:
            state.bank = token.unsqueeze(1).repeat(1, self.config.n_history, 1)
        else:
            state.bank = torch.cat([state.bank[:, 1:], token.unsqueeze(1)], dim=1)
        state.rep = token if vec is None else vec
        state.frame_pushed = True

    def feature(self, state: EpisodeState) -> Tensor:
        """The dynamic feature F of the history bank, (B, d)."""
        return self.extractor(state.bank)[0]

    # ------------------------------------------------------------------ what each kind provides
    def loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Stage-1 loss and its logged parts."""
        raise NotImplementedError

    def chunk_state(self, chunk: Tensor, at_plan: Tensor | None):
        """The per-chunk work of :meth:`begin_chunk` that needs only the chunk and the plan-time reference,
        so a planner's worker can do it before the chunk starts (``None``: this kind has none)."""
        return None

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        """Per-chunk work when ``chunk`` (B, H, A, base-normalised) starts being executed (``prepared``:
        :meth:`chunk_state` of this chunk, already computed)."""
        raise NotImplementedError

    def step(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        """The corrected action ``step`` of the current chunk (B, A), base-normalised; the frame is in the
        bank already."""
        raise NotImplementedError

    def query_chunk(self, state: EpisodeState, chunk: Tensor) -> Tensor:
        """Every step of ``chunk`` corrected with the current F and nothing changed since plan time."""
        raise NotImplementedError
