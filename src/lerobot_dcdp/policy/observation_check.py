"""One check of every observation the policy receives, before anything enters its state."""

from __future__ import annotations

import torch
from torch import Tensor

from lerobot_dcdp.model.episode_state import EpisodeState


class ObservationCheck:
    """Refuses, with one ``ValueError`` naming the key and what was expected: a missing key, a feature of the
    wrong shape, a batch size that changes within a chunk, a non-finite value.

    Args:
        config: The policy config (execution mode, anchor feature, planning, history length).
        expected_shapes: The shape (without batch) each observation key the policy reads must have (None:
            any shape).
    """

    def __init__(self, config, expected_shapes: dict[str, tuple[int, ...] | None]) -> None:
        self.config = config
        self.expected_shapes = expected_shapes

    def __call__(self, batch: dict[str, Tensor], state: EpisodeState) -> None:
        cfg = self.config
        missing = [k for k in self.expected_shapes if k not in batch]
        if cfg.execution == "object_anchored" or cfg.anchor_input:
            if not cfg.anchor_feature:
                raise ValueError(
                    f"execution={cfg.execution!r} needs anchor_feature (the object's xy keypoints): set "
                    "--policy.anchor_feature=<observation key>"
                )
            missing += [cfg.anchor_feature] if cfg.anchor_feature not in batch else []
        if missing:
            raise ValueError(f"observation is missing {missing}; it has {sorted(batch)}")
        planned = None if state.chunk is None else state.chunk.shape[0]
        mid_chunk = planned is not None and (state.step != 0 or cfg.planning == "async")
        for key, shape in self.expected_shapes.items():
            x = batch[key]
            if shape is not None and tuple(x.shape[1:]) != shape:
                raise ValueError(
                    f"observation {key!r} has shape {tuple(x.shape)}, expected (batch, "
                    f"{', '.join(map(str, shape))}) as the corrector and its base were trained"
                )
            if mid_chunk and x.shape[0] != planned:
                width = ", ".join(map(str, x.shape[1:]))
                raise ValueError(
                    f"observation {key!r} has batch {x.shape[0]} but the current chunk was planned for "
                    f"batch {planned}: expected (batch, features) = ({planned}, {width}) as in this chunk "
                    "(call reset() between episodes)"
                )
            if x.is_floating_point() and not torch.isfinite(x).all():
                raise ValueError(
                    f"observation {key!r} holds a non-finite value (NaN or inf); the corrector would carry "
                    f"it in its history for {cfg.n_history} steps -- fix the sensor or filter the "
                    "observation"
                )
