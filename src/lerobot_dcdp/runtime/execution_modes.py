"""The execution modes: how a planned chunk becomes this control step's action.

``dcdp`` (the corrector), the baselines ``open_loop``, ``object_anchored``, the per-step replanners
``closed_loop`` and ``temporal_ensemble``, and ``bid`` (Bidirectional Decoding: several sampled chunks, one
selected). A mode sees the episode state and says how often it plans (:attr:`ExecutionMode.plan_period`) and
how a plan is drawn from the base (:meth:`ExecutionMode.plan`); when the base is called is the planning's
business (``planning.py``).
"""

from __future__ import annotations

from torch import Tensor

from lerobot_dcdp.model.anchoring import ObjectAnchor
from lerobot_dcdp.model.bid_selection import bid_select
from lerobot_dcdp.model.correction import temporal_ensemble_step
from lerobot_dcdp.model.corrector import Corrector
from lerobot_dcdp.model.episode_state import EpisodeState
from lerobot_dcdp.runtime.chunk_sources import ChunkSource
from lerobot_dcdp.runtime.kernel_runner import KernelRunner

#: Base types whose chunk is a function of the observation (ACT decodes with its latent at zero): nothing to
#: sample, so ``bid`` refuses them by name.
DETERMINISTIC_BASES = ("act",)


class ExecutionMode:
    """A chunk mode executes a chunk of ``n_action_steps`` actions, one per step (the base of the modes).

    Attributes:
        replans_every_step: The base plans at every step and only the plan's first action is used.
        plan_length: Actions asked of the base per plan (None: its whole chunk).
        anchored: The mode reads the object's keypoints at plan time.
    """

    replans_every_step = False
    anchored = False

    def __init__(self, config) -> None:
        self.config = config

    @property
    def plan_length(self) -> int | None:
        return self.config.n_action_steps

    @property
    def plan_period(self) -> int:
        """Control steps between two plans (``replans_every_step`` modes: 1)."""
        return 1 if self.replans_every_step else self.config.n_action_steps

    def reset(self) -> None:
        """Start a new episode (a mode that keeps state of its own clears it)."""

    def plan(self, state: EpisodeState, source: ChunkSource, prepared: dict, length: int | None) -> Tensor:
        """The chunk planned now from ``prepared`` (the base's input for this step): one call of the base."""
        return source.chunk(prepared, length)

    def observe(self, state: EpisodeState, batch: dict[str, Tensor], switching: bool) -> None:
        """Take in this step's observation before any chunk is planned (``switching``: a chunk may be
        planned or started on this step)."""

    def prepare_chunk(self, chunk: Tensor, at_plan: Tensor | None):
        """The per-chunk work :meth:`begin_chunk` can take ready-made (a planner's worker does it before the
        chunk starts); ``None``: this mode has none."""
        return None

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        """Start executing ``chunk`` (B, L, A, base-normalised); ``state.at_plan`` / ``anchor_plan`` hold the
        references of the observation it was planned from; ``prepared``: :meth:`prepare_chunk` of it."""
        state.chunk = chunk

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        """The action (B, A), base-normalised, for chunk step ``step`` given this step's observation."""
        raise NotImplementedError


class OpenLoop(ExecutionMode):
    """``open_loop``: the chunk as planned."""

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        return state.chunk[:, step]


class ObjectAnchored(ExecutionMode):
    """``object_anchored``: the planned action carried along with the object's rigid motion since plan time,
    estimated from the anchor keypoints (least squares)."""

    anchored = True

    def __init__(self, config, anchor: ObjectAnchor) -> None:
        super().__init__(config)
        self.anchor = anchor

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        return self.anchor.carry(state.chunk[:, step], state.anchor_plan, self.anchor.points(batch))


class Corrected(ExecutionMode):
    """``dcdp``: every action of the chunk corrected from the newest observations.

    Each step's frame enters the corrector's history bank; while a chunk runs on the compiled kernel, the
    kernel pushes it itself (one call per step), so the frame waits for it.

    Args:
        config: The policy config.
        corrector: The corrector.
        kernel: The compiled-kernel runner (residual correctors), or None.
    """

    def __init__(self, config, corrector: Corrector, kernel: KernelRunner | None) -> None:
        super().__init__(config)
        self.corrector = corrector
        self.kernel = kernel
        self.anchored = bool(corrector.config.anchor_input)

    def observe(self, state: EpisodeState, batch: dict[str, Tensor], switching: bool) -> None:
        if switching:  # a chunk that will run on the kernel needs only the frame's vector as its reference
            first = batch[self.corrector.frame_keys[0]]
            defer = (
                self.kernel is not None
                and state.bank is not None
                and state.bank.shape[0] == first.shape[0]
                and self.kernel.applies()
            )
            if defer:
                state.rep = self.corrector.frame_encoder.vector(self.corrector.frames(batch))
        else:
            defer = state.kernel is not None
        if defer:
            state.frame_pushed = False
        else:
            self.corrector.push_frame(state, batch)

    def prepare_chunk(self, chunk: Tensor, at_plan: Tensor | None):
        """The corrector's per-chunk state and the kernel's packed inputs (see ``Corrector.chunk_state``)."""
        done = self.corrector.chunk_state(chunk, at_plan)
        if done is None:
            return None
        packed = None if self.kernel is None or done[2] is None else self.kernel.pack(done[2])
        return done, packed

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        state.chunk = chunk
        done, packed = prepared if prepared is not None else (None, None)
        self.corrector.begin_chunk(state, chunk, done)
        if self.kernel is not None:
            self.kernel.prepare(state, packed)
        else:
            state.kernel = None

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        if not state.frame_pushed:
            if state.kernel is not None:
                return self.kernel.act(state, step, batch)
            self.corrector.push_frame(state, batch)
        return self.corrector.step(state, step, batch)


class ClosedLoop(ExecutionMode):
    """``closed_loop``: the base plans at every step; its first action is executed."""

    replans_every_step = True

    @property
    def plan_length(self) -> int | None:
        return 1

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        state.plan = chunk

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        return state.plan[:, 0]


class TemporalEnsemble(ClosedLoop):
    """``temporal_ensemble``: the base plans its whole chunk at every step; the plans are averaged over time
    with exponential weights (``te_weight``)."""

    @property
    def plan_length(self) -> int | None:
        return None

    def begin_chunk(self, state: EpisodeState, chunk: Tensor, prepared=None) -> None:
        state.plan = temporal_ensemble_step(state.plan, chunk, self.config.te_weight)


class Bidirectional(ExecutionMode):
    """``bid``: every ``bid_replan_every`` steps the base samples ``bid_samples`` chunks (its longest) and the
    weak reference policy as many; BID's selection (:func:`~lerobot_dcdp.model.bid_selection.bid_select`)
    picks one, coherent with what the previous choice still planned; it runs until the next decision.

    Args:
        config: The policy config (the ``bid_*`` options).
        weak: The weak reference policy's chunk source, fed every observation as the base is; None: no
            forward negative term.
    """

    def __init__(self, config, weak: ChunkSource | None = None) -> None:
        super().__init__(config)
        self.weak = weak
        self._weak_prepared: dict | None = None

    @property
    def plan_period(self) -> int:
        return self.config.bid_replan_every

    def reset(self) -> None:
        if self.weak is not None:
            self.weak.reset()
        self._weak_prepared = None

    def observe(self, state: EpisodeState, batch: dict[str, Tensor], switching: bool) -> None:
        if self.weak is not None:
            self._weak_prepared = self.weak.observe(batch)

    def plan(self, state: EpisodeState, source: ChunkSource, prepared: dict, length: int | None) -> Tensor:
        """BID's choice among the sampled chunks (B, L, A), L the base's longest chunk.

        Raises:
            ValueError: The base is deterministic (nothing to sample).
        """
        kind = getattr(source.base.config, "type", None)
        if kind in DETERMINISTIC_BASES:
            raise ValueError(
                f"execution='bid' selects among sampled chunks, and base type {kind!r} returns the same "
                "chunk for the same observation: use a sampling base (diffusion, vqbet, ...)"
            )
        n, length = self.config.bid_samples, source.max_length
        strong = source.samples(prepared, n, length)
        weak = None
        if self.weak is not None:
            weak = self.weak.samples(self._weak_prepared, n, min(length, self.weak.max_length))
            strong_steps = min(length, weak.shape[2])
            strong, weak = strong[:, :, :strong_steps], weak[:, :, :strong_steps]
        prior = None
        if state.chunk is not None and state.chunk.shape[0] == strong.shape[0]:
            prior = state.chunk[:, self.plan_period :]  # what the last choice planned from this step on
            if prior.shape[1] == 0:
                prior = None
        return bid_select(strong, weak, prior, self.config.bid_decay, self.config.bid_modes)

    def act(self, state: EpisodeState, step: int, batch: dict[str, Tensor]) -> Tensor:
        return state.chunk[:, step]


def make_execution_modes(
    config,
    corrector: Corrector,
    kernel: KernelRunner | None,
    anchor: ObjectAnchor,
    weak: ChunkSource | None = None,
) -> dict[str, ExecutionMode]:
    """Every execution mode by its ``--policy.execution`` name (``weak``: BID's reference policy, also
    settable later on ``modes["bid"].weak``)."""
    return {
        "open_loop": OpenLoop(config),
        "object_anchored": ObjectAnchored(config, anchor),
        "dcdp": Corrected(config, corrector, kernel),
        "closed_loop": ClosedLoop(config),
        "temporal_ensemble": TemporalEnsemble(config),
        "bid": Bidirectional(config, weak),
    }
