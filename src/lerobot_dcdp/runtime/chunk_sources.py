"""How a chunk is obtained from each kind of base policy, feeding it the observation history it expects.

Every adapter offers ``reset()``, ``observe(batch) -> prepared`` (called once per control step with the
newest normalised observation; returns the batch in the form the base reads),
``chunk(prepared, length) -> (B, length, A)`` (normalised actions starting at the observation's step) and
``chunk_from(prepared, snapshot, length)`` (the chunk the base plans from an earlier step's observation and
history: a base that answers late) and ``samples(prepared, n, length)`` (``n`` chunks drawn at once, for a
sampling base's test-time selection). They call the base's own public methods so the base runs exactly as
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
    """Any LeRobot base with ``predict_action_chunk``, fed its observation history the LeRobot way.

    A base that keeps ``_queues`` after ``reset()`` (diffusion, VQ-BeT, multi_task_dit, smolvla, ...) gets
    each step's observation appended with LeRobot's ``populate_queues``, its cameras stacked into
    ``observation.images`` when it keeps that queue (as its own ``select_action`` does), so
    ``predict_action_chunk`` reads the history ``select_action`` would; a base without queues (ACT, pi0, ...)
    gets the current observation. What a call returns and the longest chunk it can return come from the base's
    config (:attr:`chunk_length`, :attr:`max_length`).
    """

    def __init__(self, base: PreTrainedPolicy) -> None:
        self.base = base

    @property
    def _slices_horizon(self) -> bool:
        """The base denoises ``horizon`` steps and keeps ``n_action_steps`` of them from the current one
        (diffusion, multi_task_dit): it can return up to ``horizon - n_obs_steps + 1``."""
        cfg = self.base.config
        return all(
            isinstance(getattr(cfg, n, None), int) for n in ("horizon", "n_obs_steps", "n_action_steps")
        )

    @property
    def chunk_length(self) -> int:
        """Actions one chunk call returns (what H may not exceed)."""
        cfg = self.base.config
        names = (
            ("n_action_steps",)
            if self._slices_horizon
            else ("action_chunk_size", "chunk_size", "n_action_steps")
        )
        for name in names:
            if getattr(cfg, name, None):
                return int(getattr(cfg, name))
        raise ValueError(
            f"cannot tell how many actions base type {cfg.type!r} returns per call: its config has none of "
            f"{names}"
        )

    @property
    def max_length(self) -> int:
        """The most actions one call can return (``chunk(prepared, length)``'s limit)."""
        cfg = self.base.config
        if self._slices_horizon:
            return int(cfg.horizon - cfg.n_obs_steps + 1)
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
        """Append the newest normalised observation to the base's history; returns what the base reads."""
        batch = _without_action(batch)
        queues = getattr(self.base, "_queues", None)
        if queues is None:
            return batch
        images = getattr(self.base.config, "image_features", None)
        if images and OBS_IMAGES in queues:
            batch[OBS_IMAGES] = _stack_images(batch, images)
        self.base._queues = populate_queues(queues, batch, exclude_keys=[ACTION])
        return batch

    def chunk(self, prepared: dict[str, Tensor], length: int | None = None) -> Tensor:
        """``length`` (default ``chunk_length``) actions from the step of ``prepared``'s observation; a
        horizon-slicing base reads further into the same sample for a longer chunk (the denoised horizon
        and its noise are the same whatever is kept)."""
        length = self._check_length(length)
        cfg = self.base.config
        longer = self._slices_horizon and length > cfg.n_action_steps
        with _kept_actions(cfg, length) if longer else contextlib.nullcontext():
            return self.base.predict_action_chunk(dict(prepared))[:, :length]

    def chunk_from(self, prepared: dict[str, Tensor], snapshot: dict | None, length: int) -> Tensor:
        """The chunk planned from an earlier step: its prepared batch and the base's history then
        (``snapshot()`` taken right after that step's ``observe``). The current history is kept."""
        now = self.snapshot()
        self.restore(snapshot)
        try:
            return self.chunk(prepared, length)
        finally:
            self.restore(now)

    def samples(self, prepared: dict[str, Tensor], n: int, length: int | None = None) -> Tensor:
        """``n`` chunks (B, n, length, A) sampled from the same observation and history: one call of the base
        on a batch repeated ``n`` times (a sampling base draws each one's noise on its own). The history is
        the same afterwards."""
        now = self.snapshot()
        if now is not None:
            self.base._queues = {
                k: type(q)((_repeat(x, n) for x in q), maxlen=q.maxlen) for k, q in now.items()
            }
        try:
            chunks = self.chunk({k: _repeat(v, n) for k, v in prepared.items()}, length)
        finally:
            self.restore(now)
        return chunks.reshape(-1, n, *chunks.shape[1:])

    def _check_length(self, length: int | None) -> int:
        length = self.chunk_length if length is None else length
        if not 1 <= length <= self.max_length:
            raise ValueError(
                f"base type {self.base.config.type!r} returns at most {self.max_length} actions per call, "
                f"{length} were asked for"
            )
        return length


@contextlib.contextmanager
def _kept_actions(cfg, n: int):
    """A horizon-slicing base keeps ``config.n_action_steps`` actions of the horizon it denoises: keep ``n``
    for one call."""
    kept = cfg.n_action_steps
    cfg.n_action_steps = n
    try:
        yield
    finally:
        cfg.n_action_steps = kept


class RenormalizedSource(ChunkSource):
    """A second policy's chunk source in the first one's units: each observation, normalised with the first
    policy's statistics, is mapped to raw units and normalised with the second's before the second reads
    it, and the second's chunks are mapped back the same way (exact: both mappings are the saved
    normalisers' own). BID's weak reference policy is fed so when it was trained on other statistics.

    Args:
        base: The second policy.
        ours: The normaliser the observations and chunks are in (the first policy's).
        theirs: The second policy's normaliser.
    """

    def __init__(self, base: PreTrainedPolicy, ours, theirs) -> None:
        super().__init__(base)
        self.ours, self.theirs = ours, theirs

    def observe(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        mapped = {
            k: self.theirs(k, self.ours(k, v, inverse=True)) if isinstance(v, Tensor) else v
            for k, v in batch.items()
        }
        return super().observe(mapped)

    def chunk(self, prepared: dict[str, Tensor], length: int | None = None) -> Tensor:
        return self.ours(ACTION, self.theirs(ACTION, super().chunk(prepared, length), inverse=True))


def _repeat(x, n: int):
    """Each batch entry of a tensor repeated ``n`` times in a row (B*n, ...); anything else as it is."""
    return x.repeat_interleave(n, dim=0) if isinstance(x, Tensor) else x


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
    if getattr(base.config, "n_obs_steps", 1) != 1 and getattr(base, "_queues", None) is None:
        raise ValueError(
            f"base policy type {base.config.type!r} reads n_obs_steps={base.config.n_obs_steps} frames but "
            "keeps no observation queues (_queues) after reset(): dcdp cannot feed it its history"
        )
    return ChunkSource(base)
