"""Fast dynamic-aware feature extractor pi_f (paper Sec. 3.2).

``pi_f(O_{t-M+1:t}) -> F_t``: a per-frame backbone gives tokens X (one per frame), the learnable-alpha
differentials ``D = alpha (X_{k+1} - X_k)`` expose motion, temporal self-attention (TA) mixes the frame
tokens, diff cross-attention (DCA) lets them query D, and pooling gives F. The self-supervised loss
``L_diff`` ties F to the latest differential (authors' code: ``kl_div(log_softmax(F), softmax(D_last))``).

The per-frame backbone is split from the temporal part so stage 2 can cache frame tokens: one new frame
per control step, not M.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor, nn


class StateBackbone(nn.Module):
    """Per-frame MLP over concatenated state / keypoint vectors -> (.., d)."""

    def __init__(self, in_dim: int, hidden_dim: int, out_dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(in_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.GELU(),
            nn.Linear(hidden_dim, out_dim),
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


class ImageBackbone(nn.Module):
    """ResNet18 trunk -> 1x1 conv 512->d, GroupNorm, 3x3 depthwise conv, average pool (authors' code)."""

    def __init__(self, out_dim: int, weights_path: str | None = None, freeze: bool = True) -> None:
        super().__init__()
        import torchvision

        resnet = torchvision.models.resnet18(weights=None)
        if weights_path:
            resnet.load_state_dict(torch.load(weights_path, map_location="cpu", weights_only=True))
        self.trunk = nn.Sequential(*list(resnet.children())[:-2])
        self.frozen = freeze
        if freeze:
            for p in self.trunk.parameters():
                p.requires_grad_(False)
        groups = 8 if out_dim % 8 == 0 else 1
        self.head = nn.Sequential(
            nn.Conv2d(512, out_dim, 1),
            nn.GroupNorm(groups, out_dim),
            nn.ReLU(),
            nn.Conv2d(out_dim, out_dim, 3, padding=1, groups=out_dim),
        )

    def train(self, mode: bool = True) -> ImageBackbone:
        super().train(mode)
        if self.frozen:
            self.trunk.eval()  # frozen BatchNorm statistics stay put
        return self

    def forward(self, img: Tensor) -> Tensor:
        return self.head(self.trunk(img)).mean(dim=(-2, -1))


#: the column ``dcdp-precompute-base-features`` writes a camera's base-encoder features to: ``<camera>`` +
#: this suffix
BASE_ENCODED_SUFFIX = ".base_encoded"


class BaseEncoderBackbone(nn.Module):
    """The frozen base's own image encoder (kept out of this module's parameters and ``state_dict``: the base
    folder holds it) -> a trainable linear map to d. :meth:`project` maps features encoded beforehand."""

    def __init__(self, encoder: nn.Module, feature_dim: int, out_dim: int) -> None:
        super().__init__()
        object.__setattr__(self, "_encoder", encoder)  # not a submodule: never trained, saved or moved here
        self.proj = nn.Linear(feature_dim, out_dim)

    def forward(self, img: Tensor) -> Tensor:
        with torch.no_grad():
            feat = self._encoder(img)
        return self.project(feat)

    def project(self, feat: Tensor) -> Tensor:
        """Encoder features (.., F) -> tokens (.., d)."""
        return self.proj(feat)


class FrameEncoder(nn.Module):
    """Per-frame backbone over every observation key -> one token of size d per frame.

    Vectors (state, environment state) are concatenated and go through :class:`StateBackbone`; each camera
    goes through a shared :class:`ImageBackbone` (or, given ``image_encoder``, the base's frozen encoder:
    :class:`BaseEncoderBackbone`, which takes the camera's ``BASE_ENCODED_SUFFIX`` entry in place of its
    frames where a training batch holds it); the parts are summed after a linear projection each.
    """

    def __init__(
        self,
        state_dims: dict[str, int],
        image_keys: list[str],
        out_dim: int,
        hidden_dim: int,
        image_weights: str | None = None,
        freeze_images: bool = True,
        image_encoder: tuple[nn.Module, int] | None = None,
    ) -> None:
        super().__init__()
        self.state_keys = list(state_dims)
        self.image_keys = list(image_keys)
        n_state = sum(state_dims.values())
        self.state = StateBackbone(n_state, hidden_dim, out_dim) if state_dims else None
        # Fixed affine scaling of the vector inputs the base's normaliser leaves raw (saved with the weights).
        self.register_buffer("state_shift", torch.zeros(n_state))
        self.register_buffer("state_scale", torch.ones(n_state))
        if not image_keys:
            self.image = None
        elif image_encoder is not None:
            self.image = BaseEncoderBackbone(*image_encoder, out_dim)
        else:
            self.image = ImageBackbone(out_dim, image_weights, freeze_images)
        self.cam_embed = nn.Parameter(torch.zeros(len(image_keys), out_dim)) if image_keys else None

    def vector(self, obs: dict[str, Tensor]) -> Tensor | None:
        """The standardised, concatenated vector inputs of a frame (None when the frame has none)."""
        if self.state is None:
            return None
        x = torch.cat([obs[k] for k in self.state_keys], dim=-1)
        return (x - self.state_shift) / self.state_scale

    def forward(self, obs: dict[str, Tensor]) -> Tensor:
        """Frames with any leading shape ``(*lead, feat)`` / ``(*lead, C, H, W)`` -> ``(*lead, d)``."""
        return self.encode(obs)[0]

    def encode(self, obs: dict[str, Tensor]) -> tuple[Tensor, Tensor | None]:
        """The frame tokens and the standardised vector inputs they were computed from (None: no vectors)."""
        out = vec = None
        if self.state is not None:
            vec = self.vector(obs)
            out = self.state(vec)
        for i, k in enumerate(self.image_keys):
            encoded = obs.get(k + BASE_ENCODED_SUFFIX)
            if encoded is not None and isinstance(self.image, BaseEncoderBackbone):  # encoded beforehand
                tok = self.image.project(encoded) + self.cam_embed[i]
            else:
                img = obs[k]
                lead = img.shape[:-3]
                tok = self.image(img.reshape(-1, *img.shape[-3:])).reshape(*lead, -1) + self.cam_embed[i]
            out = tok if out is None else out + tok
        return out, vec


class DynamicFeatureExtractor(nn.Module):
    """Temporal part of pi_f: frame tokens X (B, M, d) -> dynamic feature F (B, d) and the last differential.

    Args:
        n_history: M.
        dim: Token width d.
        n_heads: Attention heads.
        alpha_init: Initial alpha of ``D = alpha (X_{k+1} - X_k)`` (paper Eq. for the differential features).
        temporal_attention: TA on/off (off: frame tokens + positions go straight on).
        diff_cross_attention: DCA on/off (off: no cross-attention to D).
    """

    def __init__(
        self,
        n_history: int,
        dim: int,
        n_heads: int,
        alpha_init: float = 1.0,
        temporal_attention: bool = True,
        diff_cross_attention: bool = True,
        use_alpha: bool = True,
    ) -> None:
        super().__init__()
        # alpha only receives gradients through DCA or L_diff; freeze it otherwise (DDP: no unused params)
        self.alpha = nn.Parameter(torch.tensor(float(alpha_init)), requires_grad=use_alpha)
        self.pos = nn.Parameter(torch.zeros(n_history, dim))
        nn.init.normal_(self.pos, std=0.02)
        self.temporal = (
            nn.TransformerEncoderLayer(dim, n_heads, 2 * dim, dropout=0.0, batch_first=True, norm_first=True)
            if temporal_attention
            else None
        )
        if diff_cross_attention:
            self.diff_pos = nn.Parameter(torch.zeros(n_history - 1, dim))
            nn.init.normal_(self.diff_pos, std=0.02)
            self.cross = nn.MultiheadAttention(dim, n_heads, batch_first=True)
            self.cross_norm_q = nn.LayerNorm(dim)
            self.cross_norm_kv = nn.LayerNorm(dim)
        else:
            self.cross = None
        self.pool = nn.Sequential(nn.LayerNorm(2 * dim), nn.Linear(2 * dim, dim))

    def differentials(self, x: Tensor) -> Tensor:
        """``D = alpha (X_{k+1} - X_k)``: (..., M, d) -> (..., M-1, d)."""
        return self.alpha * (x[..., 1:, :] - x[..., :-1, :])

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """X (B, M, d) -> (F (B, d), D_last (B, d))."""
        d = self.differentials(x)
        h = x + self.pos
        if self.temporal is not None:
            h = self.temporal(h)
        if self.cross is not None:
            kv = self.cross_norm_kv(d + self.diff_pos)
            h = h + self.cross(self.cross_norm_q(h), kv, kv, need_weights=False)[0]
        f = self.pool(torch.cat([h.mean(dim=1), h[:, -1]], dim=-1))
        return f, d[:, -1]


def diff_loss(features: Tensor, last_diff: Tensor) -> Tensor:
    """Self-supervised ``L_diff``: ``KL(softmax(D_last) || softmax(F))`` as the authors' code computes it
    (``F.kl_div(log_softmax(F), softmax(D))``, D not detached), averaged over the batch."""
    return F.kl_div(F.log_softmax(features, dim=-1), F.softmax(last_diff, dim=-1), reduction="batchmean")
