"""How a chunk is obtained from each kind of base policy, feeding it the observation history it expects.

Every adapter offers ``reset()``, ``observe(batch) -> prepared`` (called once per control step with the
newest normalised observation; returns the batch in the form the base reads),
``chunk(prepared, length) -> (B, length, A)`` (normalised actions starting at the observation's step) and
``chunk_from(prepared, snapshot, length)`` (the chunk the base plans from an earlier step's observation and
history: a base that answers late). They call the base's own public methods so the base runs exactly as
LeRobot runs it.
"""

from __future__ import annotations

import contextlib
import copy

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION, OBS_IMAGES
from torch import Tensor


class ChunkSource:
    """Generic base: ``predict_action_chunk`` on the current observation (n_obs_steps == 1)."""

    def __init__(self, base: PreTrainedPolicy) -> None:
        self.base = base

    @property
    def chunk_length(self) -> int:
        """Actions one chunk call returns (what H may not exceed)."""
        cfg = self.base.config
        for name in ("n_action_steps", "chunk_size", "horizon"):
            if getattr(cfg, name, None):
                return int(getattr(cfg, name))
        raise ValueError(f"cannot tell the chunk length of base type {cfg.type!r}")

    @property
    def max_length(self) -> int:
        """The most actions one call can return (``chunk(prepared, length)``'s limit)."""
        return self.chunk_length

    def reset(self) -> None:
        self.base.reset()

    def snapshot(self) -> dict | None:
        """The base's observation history (LeRobot bases keep it in ``_queues``), to restore after a query."""
        queues = getattr(self.base, "_queues", None)
        return None if queues is None else {k: copy.copy(v) for k, v in queues.items()}

    def restore(self, snapshot: dict | None) -> None:
        if snapshot is not None:
            self.base._queues = snapshot

    def observe(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return _without_action(batch)

    def chunk(self, prepared: dict[str, Tensor], length: int | None = None) -> Tensor:
        """``length`` (default ``chunk_length``) actions from the step of ``prepared``'s observation."""
        length = self._check_length(length)
        return self.base.predict_action_chunk(prepared)[:, :length]

    def chunk_from(self, prepared: dict[str, Tensor], snapshot: dict | None, length: int) -> Tensor:
        """The chunk planned from an earlier step: its prepared batch and the base's history then
        (``snapshot()`` taken right after that step's ``observe``). The current history is kept."""
        now = self.snapshot()
        self.restore(snapshot)
        try:
            return self.chunk(prepared, length)
        finally:
            self.restore(now)

    def _check_length(self, length: int | None) -> int:
        length = self.chunk_length if length is None else length
        if not 1 <= length <= self.max_length:
            raise ValueError(
                f"base type {self.base.config.type!r} returns at most {self.max_length} actions per call, "
                f"{length} were asked for"
            )
        return length


class DiffusionChunkSource(ChunkSource):
    """Diffusion Policy: keeps the base's ``n_obs_steps`` observation queues filled (as its
    ``select_action`` does) so ``predict_action_chunk`` reads the same history; returns ``n_action_steps``
    actions starting at the current step."""

    @property
    def chunk_length(self) -> int:
        return int(self.base.config.n_action_steps)

    def _prepare(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        batch = _without_action(batch)
        if self.base.config.image_features:
            batch[OBS_IMAGES] = _stack_images(batch, self.base.config.image_features)
        return batch

    @property
    def max_length(self) -> int:
        """The whole horizon from the current step: ``horizon - n_obs_steps + 1``."""
        cfg = self.base.config
        return int(cfg.horizon - cfg.n_obs_steps + 1)

    def observe(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        prepared = self._prepare(batch)
        self.base._queues = populate_queues(self.base._queues, prepared)
        return prepared

    def chunk(self, prepared: dict[str, Tensor], length: int | None = None) -> Tensor:
        """The base keeps ``n_action_steps`` of its horizon; a longer chunk reads further into the same
        sample (the denoised horizon and its noise are the same whatever is kept)."""
        length = self._check_length(length)
        cfg = self.base.config
        with _kept_actions(cfg, length) if length > cfg.n_action_steps else contextlib.nullcontext():
            return self.base.predict_action_chunk(prepared)[:, :length]


class ACTChunkSource(ChunkSource):
    """ACT: the whole ``chunk_size`` prediction; ACT's own temporal ensembler (in its ``select_action``) is
    bypassed, the wrapper's execution mode decides how the chunk is executed."""

    @property
    def chunk_length(self) -> int:
        return int(self.base.config.chunk_size)


@contextlib.contextmanager
def _kept_actions(cfg, n: int):
    """LeRobot's diffusion model keeps ``config.n_action_steps`` actions of the horizon it denoises: keep
    ``n`` for one call."""
    kept = cfg.n_action_steps
    cfg.n_action_steps = n
    try:
        yield
    finally:
        cfg.n_action_steps = kept


def _without_action(batch: dict[str, Tensor]) -> dict[str, Tensor]:
    return {k: v for k, v in batch.items() if k != ACTION and not k.endswith("_is_pad")}


def _stack_images(batch: dict[str, Tensor], keys) -> Tensor:
    return torch.stack([batch[k] for k in keys], dim=-4)


def make_chunk_source(base: PreTrainedPolicy) -> ChunkSource:
    """Adapter for a base policy; raises ValueError for a base that cannot produce chunks."""
    if not callable(getattr(base, "predict_action_chunk", None)):
        raise ValueError(
            f"base policy type {base.config.type!r} has no predict_action_chunk: it cannot plan chunks"
        )
    kind = base.config.type
    if kind == "diffusion":
        return DiffusionChunkSource(base)
    if kind == "act":
        return ACTChunkSource(base)
    if getattr(base.config, "n_obs_steps", 1) != 1:
        raise ValueError(
            f"base policy type {kind!r} needs n_obs_steps={base.config.n_obs_steps} frames "
            "and has no adapter; "
            "only single-frame bases are supported generically"
        )
    return ChunkSource(base)
