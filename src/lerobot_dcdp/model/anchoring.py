"""Object anchoring: a planned action carried along with the object's rigid motion since plan time."""

from __future__ import annotations

from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.correction import anchor_actions, rigid_fit_2d


class ObjectAnchor:
    """Reads the object's xy keypoints from observations and anchors base-normalised actions to them.

    Args:
        config: The policy config; its ``anchor_feature`` names the observation holding the object's keypoints
            (flattened xy pairs).
        normalizer: The base's normaliser (keypoints and actions are anchored in raw units).
    """

    def __init__(self, config, normalizer: BaseNormalizer) -> None:
        self.config = config
        self.normalizer = normalizer

    @property
    def key(self) -> str | None:
        """The anchor feature (``anchor_feature``; None: no object keypoints are known)."""
        return self.config.anchor_feature

    def points(self, batch: dict[str, Tensor]) -> Tensor:
        """Raw (un-normalised) keypoints (B, N, 2) of the observation in ``batch``."""
        x = self.normalizer(self.key, batch[self.key], inverse=True)
        return x.reshape(x.shape[0], -1, 2)

    def carry(self, action: Tensor, at_plan: Tensor, now: Tensor) -> Tensor:
        """The base-normalised ``action`` (B, A) moved with the rigid motion (least squares) that takes the
        keypoints ``at_plan`` to ``now`` (both (B, N, 2), raw)."""
        rot, shift = rigid_fit_2d(at_plan, now)
        raw = self.normalizer(ACTION, action, inverse=True)
        return self.normalizer(ACTION, anchor_actions(raw, rot, shift))
