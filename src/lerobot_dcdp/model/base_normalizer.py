"""The base policy's own normalisation, reproduced from its saved statistics (no processor pipeline)."""

from __future__ import annotations

from torch import Tensor

from lerobot_dcdp.model.correction import action_range, check_normalization, normalize, unnormalize

#: the statistics (un)normalising reads; the rest of a saved processor's stats is dropped
NORMALIZER_STATS = ("min", "max", "mean", "std", "q01", "q99", "q10", "q90")


class BaseNormalizer:
    """(Un)normalise features exactly as the base's saved normaliser does.

    Args:
        stats: ``{feature: (mode, {stat: tensor})}`` as ``base_policy.load_base_stats`` returns it; modes the
            correction math cannot reproduce are refused here, naming the feature.
    """

    def __init__(self, stats: dict[str, tuple[str, dict[str, Tensor]]]) -> None:
        self.stats = {
            key: (mode, {k: v for k, v in values.items() if k in NORMALIZER_STATS})
            for key, (mode, values) in stats.items()
        }
        for key, (mode, values) in self.stats.items():
            check_normalization(key, mode, values)

    def __call__(self, key: str, x: Tensor, inverse: bool = False) -> Tensor:
        """Normalise feature ``key`` (``inverse``: map it back to raw units) as the base does."""
        mode, stats = self.stats.get(key, ("IDENTITY", {}))
        if any(v.device != x.device or v.dtype != x.dtype for v in stats.values()):
            stats = {k: v.to(x.device, x.dtype) for k, v in stats.items()}
        return unnormalize(x, stats, mode) if inverse else normalize(x, stats, mode)

    def action_range(self, action_key: str, action_dim: int) -> tuple[Tensor, Tensor]:
        """Range of the base-normalised actions, mapped to [-1, 1] before encoding (paper: min-max)."""
        mode, stats = self.stats.get(action_key, ("IDENTITY", {}))
        return action_range(stats, mode, action_dim)
