"""The compiled per-step kernel (``step_kernel.py``) behind one runner: when it applies, its packed weights,
one control step on it, and the fall-back to the PyTorch path when numba cannot be used."""

from __future__ import annotations

import logging
import time

import torch
from torch import Tensor

from lerobot_dcdp.model.corrector_residual import ResidualCorrector
from lerobot_dcdp.model.episode_state import EpisodeState

log = logging.getLogger(__name__)


class KernelRunner:
    """Runs a residual corrector's control steps as one compiled kernel on CPU (same actions up to float
    rounding as the PyTorch path).

    Args:
        corrector: The corrector whose weights the kernel packs (re-packed whenever they change).
    """

    def __init__(self, corrector) -> None:
        self.corrector = corrector
        self.config = corrector.config
        self._packed: tuple[tuple, object] | None = None  # (weight versions, step_kernel.StepWeights)
        self._supported: bool | None = None  # step_kernel.supports(...) of these modules, once known
        self._run = None

    def applies(self) -> bool:
        """Whether the kernel covers the corrector as it runs now: a residual head without anchor input or a
        synchronous inference delay, vector frames, float32 on CPU, eval mode, ``fast_inference``,
        ``compiled_kernel`` not ``off`` (with ``planning='async'``: the ticks that neither submit nor switch
        a chunk run on it)."""
        cfg, corrector = self.config, self.corrector
        if not isinstance(corrector, ResidualCorrector):
            return False
        weight = corrector.residual.net[0].weight
        if not (
            corrector.fast_inference
            and cfg.compiled_kernel != "off"
            and not corrector.training
            and not (cfg.anchor_input or (cfg.inference_delay and cfg.planning == "sync"))
            and weight.device.type == "cpu"
            and weight.dtype == torch.float32
        ):
            return False
        if self._supported is None:
            try:
                from lerobot_dcdp.runtime import step_kernel
            except Exception as err:  # numba missing, or it cannot set up its cache
                self.failed(err)
                return False
            self._supported = step_kernel.supports(corrector.frame_encoder, corrector.extractor)
        return self._supported

    def warm_up(self) -> None:
        """Load the kernel now, when it will be used: its first call in a process loads it from numba's disk
        cache (~0.5 s with the import) or compiles it (~15 s, once per machine), which would otherwise stall
        the first control step."""
        if self.applies():
            try:
                self._weights()
            except Exception as err:
                self.failed(err)

    def failed(self, err: Exception) -> None:
        """``compiled_kernel='auto'``: fall back to the PyTorch path for good, with one warning."""
        if self.config.compiled_kernel == "on":
            raise RuntimeError(
                f"compiled_kernel='on' but the numba kernel failed ({type(err).__name__}: {err}); use "
                "--policy.compiled_kernel=auto to fall back to the PyTorch path"
            ) from err
        log.warning(
            "dcdp: the compiled per-step kernel is unavailable (%s: %s); using the PyTorch path (same "
            "actions, slower). Set DCDP_KERNEL_CACHE to a writable folder or --policy.compiled_kernel=off.",
            type(err).__name__,
            err,
        )
        self._supported = False

    def _weights(self):
        """The packed weights, re-packed (and the kernel loaded) when the module weights changed."""
        from lerobot_dcdp.runtime import step_kernel

        corrector = self.corrector
        # a tensor's storage and version change with optimiser steps, load_state_dict (copy or assign) and
        # `param.data = ...`; writes through `param.data` change neither, so each tensor's sum is compared too
        # (~0.05 ms per chunk)
        tensors = (*corrector.parameters(), *corrector.buffers())
        versions = (
            self.config.change_scale,
            *((t.data_ptr(), t._version) for t in tensors),
            torch.stack([t.detach().double().sum() for t in tensors]).tolist(),
        )
        if self._packed is None or self._packed[0] != versions:
            packed = step_kernel.pack_weights(
                corrector.frame_encoder, corrector.extractor, corrector.residual, self.config.change_scale
            )
            first = not step_kernel.loaded()
            started = time.perf_counter()
            step_kernel.warm_up(packed)  # the first call in a process loads the kernel: not on a control step
            if first:
                log.info(
                    "dcdp: compiled per-step kernel ready in %.1f s (cache: %s)",
                    time.perf_counter() - started,
                    step_kernel.cache_dir(),
                )
            self._packed = (versions, packed)
        self._run = step_kernel.residual_step  # numba is imported only once a kernel is used
        return self._packed[1]

    def pack(self, w_step: Tensor) -> tuple | None:
        """The kernel's inputs for a chunk whose residual head has per-step weights ``w_step``: the packed
        weights, ``w_step`` in the kernel's (out, in) layout and the action half range, as arrays (None where
        the kernel does not apply or failed: the PyTorch path)."""
        if not self.applies():
            return None
        try:
            weights = self._weights()
        except Exception as err:  # compile or cache failure: this chunk and later ones run eagerly
            self.failed(err)
            return None
        return weights, w_step.T.contiguous().numpy(), self.corrector.action_half_range.numpy()

    def prepare(self, state: EpisodeState, packed: tuple | None = None) -> None:
        """Run the current chunk's steps on the kernel when it applies (after ``begin_chunk``'s chunk terms):
        sets ``state.kernel`` (None: the PyTorch path); ``packed``: :meth:`pack` of the chunk, if done."""
        state.kernel = None
        if state.terms is None or state.rep is None or state.bank is None:
            return
        if packed is None:
            state.kernel = self.pack(state.w_step)  # checks applies() itself
        elif self.applies():
            state.kernel = packed

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        """Chunk step ``step`` on the kernel from this step's observation; pushes the frame into the bank."""
        keys = self.corrector.frame_encoder.state_keys
        x = torch.cat([batch[k] for k in keys], dim=-1)
        weights, w_step, half = state.kernel
        expected = (state.bank.shape[0], weights.shift.shape[0])
        if tuple(x.shape) != expected:  # the kernel does not bounds-check: refuse before it runs
            raise ValueError(
                f"observation vector inputs {keys} have shape {tuple(x.shape)}, expected (batch, features) = "
                f"{expected} as in this chunk (call reset() between episodes)"
            )
        action, state.bank, state.rep = self._run(
            weights, x, state.bank, state.at_plan, state.terms[:, step], w_step, state.chunk[:, step], half
        )
        state.frame_pushed = True
        return action
