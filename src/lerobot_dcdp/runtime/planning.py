"""When the base plans and which chunk each control step executes: synchronous and asynchronous planning.

``SyncPlanning`` (``--policy.planning=sync``): the base plans on the control step itself, every H steps (every
step for the per-step modes, every ``bid_replan_every`` for ``bid``: the mode's ``plan_period``); with
``inference_delay`` d the chunk is the one a base answering d steps late would deliver (planned from the
observation d steps back, its first d entries skipped).
``AsyncPlanning`` (``planning=async``): the base plans the next chunk on a worker thread
(:class:`~lerobot_dcdp.runtime.planner.BackgroundPlanner`) while every step returns an action of the current
chunk
at once (see ``DCDPConfig.planning`` and ``planning_clock``).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

import torch
from torch import Tensor

from lerobot_dcdp.model.anchoring import ObjectAnchor
from lerobot_dcdp.model.episode_state import EpisodeState
from lerobot_dcdp.runtime.chunk_sources import ChunkSource
from lerobot_dcdp.runtime.execution_modes import ExecutionMode
from lerobot_dcdp.runtime.planner import BackgroundPlanner


def new_episode(config) -> EpisodeState:
    """A fresh episode state for ``config`` (its delay window sized to ``inference_delay``)."""
    return EpisodeState(past=deque(maxlen=config.inference_delay + 1))


class SyncPlanning:
    """The base plans on the control step (see the module docstring).

    Args:
        config: The policy config (``n_action_steps``, ``inference_delay``).
        source: The base's chunk source.
        anchor: Reads the object keypoints an anchored mode needs at plan time.
    """

    def __init__(self, config, source: ChunkSource, anchor: ObjectAnchor) -> None:
        self.config = config
        self.source = source
        self.anchor = anchor

    def act(self, state: EpisodeState, batch: dict[str, Tensor], mode: ExecutionMode) -> Tensor:
        """This step's action (B, A), base-normalised."""
        prepared = self.source.observe(batch)
        switching = state.step == 0  # a mode's plan period starts
        mode.observe(state, batch, switching)
        if self.config.inference_delay:
            state.past.append(
                {
                    "t": state.t,
                    "prepared": prepared,
                    "queues": self.source.snapshot(),
                    "rep": state.rep,
                    "anchor": self.anchor.points(batch) if mode.anchored else None,
                }
            )
        if switching:
            mode.begin_chunk(state, self._chunk(state, prepared, batch, mode))
        state.t += 1
        step = state.step
        state.last_step = step
        state.step = (step + 1) % mode.plan_period
        return mode.act(state, step, batch)

    def _chunk(
        self, state: EpisodeState, prepared: dict[str, Tensor], batch: dict[str, Tensor], mode: ExecutionMode
    ) -> Tensor:
        """The chunk that starts being used now; sets the plan-time references (rep, anchor keypoints)."""
        length = mode.plan_length
        if not self.config.inference_delay:
            state.at_plan = state.rep
            state.anchor_plan = self.anchor.points(batch) if mode.anchored else None
            state.chunk_delay = 0
            return mode.plan(state, self.source, prepared, length)
        then = state.past[0]
        skip = state.chunk_delay = state.t - then["t"]
        length = min((length or self.source.chunk_length) + skip, self.source.max_length)
        state.at_plan, state.anchor_plan = then["rep"], then["anchor"]
        return self.source.chunk_from(then["prepared"], then["queues"], length)[:, skip:]


class AsyncPlanning:
    """The base plans on a worker thread; no step waits for it (see the module docstring).

    The next chunk is submitted ``lead`` steps before the current one ends (``planning_clock='steps'``:
    ``inference_delay``; ``'wall'``: the smoothed planning time over the smoothed tick period, + 1) and used
    once it is ready and the current chunk has run its H steps (until then the current chunk holds its last
    step), its entries for the steps since its observation skipped.

    Args:
        config: The policy config (``n_action_steps``, ``inference_delay``, ``planning_clock``).
        source: The base's chunk source (the worker plans with a copy of its base).
        anchor: Reads the object keypoints an anchored mode needs at plan time.
        clock: Seconds on a monotonic clock, read on the control tick to measure the tick period and an
            episode's first planning time (``planning_clock='wall'`` plans ahead by their ratio). Kept in
            :attr:`clock`; a test may substitute a controlled one.
    """

    def __init__(
        self,
        config,
        source: ChunkSource,
        anchor: ObjectAnchor,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.config = config
        self.source = source
        self.anchor = anchor
        self.clock = clock
        self.planner: BackgroundPlanner | None = None  # created on first use, or attached
        self.attached = False  # the planner was handed in (attach): it plans every chunk, the first too
        self.fixed_lead: int | None = None

    def attach(self, planner, lead: int | None = None) -> None:
        """Plan every chunk with ``planner`` (``BackgroundPlanner``'s interface), ``lead`` steps ahead."""
        if lead is not None and not 1 <= lead <= self.config.n_action_steps:
            raise ValueError(f"planning lead must be in [1, {self.config.n_action_steps}] steps, got {lead}")
        self.planner, self.attached, self.fixed_lead = planner, True, lead

    def act(self, state: EpisodeState, batch: dict[str, Tensor], mode: ExecutionMode) -> Tensor:
        """This step's action (B, A), base-normalised."""
        if mode.replans_every_step:
            raise ValueError(
                "planning='async' applies to the chunk modes (open_loop, object_anchored, dcdp), not "
                f"{self.config.execution!r}"
            )
        horizon = self.config.n_action_steps
        now = self.clock()
        if state.tick_at is not None:
            state.tick_s = _smoothed(state.tick_s, now - state.tick_at)
        state.tick_at = now
        prepared = self.source.observe(batch)
        pending = self.planner is not None and self.planner.pending
        submit = state.chunk is not None and not pending and state.step >= horizon - self.lead(state)
        take = pending and state.step >= horizon
        mode.observe(state, batch, switching=state.chunk is None or submit or take)
        if state.chunk is None or submit or take:
            context = (state.rep, self.anchor.points(batch) if mode.anchored else None)
            if state.chunk is None:  # an episode's first chunk: nothing to execute yet, planned on this step
                started = self.clock()
                if self.attached:
                    self.planner.submit(state.t, prepared, None, self.source.max_length, context)
                    chunk = self.planner.take(wait=True).chunk[:, :horizon]
                else:
                    chunk = self.source.chunk(prepared, horizon)
                state.plan_s = _smoothed(state.plan_s, self.clock() - started)
                self._begin(state, mode, chunk, context, delay=0)
            else:
                self._schedule(state, mode, prepared, context)
        step = min(state.step, state.chunk.shape[1] - 1)  # a chunk kept past its end holds its last step
        state.last_step = step
        state.step += 1
        state.t += 1
        return mode.act(state, step, batch)

    def _schedule(self, state: EpisodeState, mode: ExecutionMode, prepared: dict, context: tuple) -> None:
        """Submit the next chunk when it is due; start it when it is ready and the current one has ended."""
        cfg, horizon = self.config, self.config.n_action_steps
        if self.planner is None:
            cpus = cfg.planner_cpus
            idle = cfg.planner_priority == "idle"
            self.planner = BackgroundPlanner(self.source, None if cpus is None else set(cpus), idle)
        planner, t = self.planner, state.t
        if not planner.pending and state.step >= horizon - self.lead(state):
            finish = self._finisher(mode, horizon - state.step, context)
            extra = {} if finish is None else {"finish": finish}  # planners without it keep working
            planner.submit(t, prepared, self.source.snapshot(), self.source.max_length, context, **extra)
        if planner.pending and state.step >= horizon:
            if cfg.planning_clock == "steps":
                due = t - planner.t_obs >= cfg.inference_delay
                job = planner.take(wait=True) if due else None
            else:
                job = planner.take(wait=False)
            if job is not None:
                state.plan_s = _smoothed(state.plan_s, job.seconds)
                age = min(t - job.t_obs, job.chunk.shape[1] - 1)  # older than its length: its last step
                ready = job.prepared[1] if job.prepared is not None and job.prepared[0] == age else None
                self._begin(state, mode, job.chunk[:, age : age + horizon], job.context, ready, delay=age)

    def _finisher(self, mode: ExecutionMode, age: int, context: tuple):
        """What the worker does after the base when the chunk is expected to start ``age`` steps after its
        observation: the mode's per-chunk work on that slice (``(age, prepared)``), so the tick that switches
        chunks only installs it; None where the mode has no such work."""
        if type(mode).prepare_chunk is ExecutionMode.prepare_chunk:
            return None
        horizon = self.config.n_action_steps

        def finish(chunk: Tensor):
            start = min(age, chunk.shape[1] - 1)
            with torch.no_grad():
                return start, mode.prepare_chunk(_fit(chunk[:, start : start + horizon], horizon), context[0])

        return finish

    def _begin(
        self,
        state: EpisodeState,
        mode: ExecutionMode,
        chunk: Tensor,
        context: tuple,
        prepared=None,
        delay: int = 0,
    ) -> None:
        """Start executing ``chunk`` (B, <= H, A; a short one is padded with its last action) planned from
        the observation whose change representation and anchor keypoints ``context`` holds, ``delay`` steps
        before its first action (``prepared``: the mode's per-chunk work on it, done by the worker)."""
        state.at_plan, state.anchor_plan = context
        state.chunk_delay = delay
        state.step = 0
        mode.begin_chunk(state, _fit(chunk, self.config.n_action_steps), prepared)

    def lead(self, state: EpisodeState) -> int:
        """Steps before the chunk's end at which the next one is planned (``DCDPConfig.planning_clock``)."""
        cfg = self.config
        if self.fixed_lead is not None:
            return self.fixed_lead
        if cfg.planning_clock == "steps":
            return cfg.inference_delay
        if not state.plan_s or not state.tick_s:
            return 1
        return min(cfg.n_action_steps, math.ceil(state.plan_s / state.tick_s) + 1)

    def cancel(self) -> None:
        """Drop a chunk being planned (a new episode); waits for a running base call."""
        if self.planner is not None:
            self.planner.cancel()

    def close(self) -> None:
        """Stop the worker thread; planning restarts it on demand (an attached planner is its owner's)."""
        if self.planner is not None and not self.attached:
            self.planner.close()
            self.planner = None


def _fit(chunk: Tensor, horizon: int) -> Tensor:
    """``chunk`` (B, <= H, A) padded to ``horizon`` steps with its last action."""
    if chunk.shape[1] < horizon:
        chunk = torch.cat([chunk, chunk[:, -1:].expand(-1, horizon - chunk.shape[1], -1)], dim=1)
    return chunk


def _smoothed(previous: float | None, value: float, weight: float = 0.3) -> float:
    """Exponential moving average (the first value as is)."""
    return value if previous is None else (1 - weight) * previous + weight * value
