"""Asynchronous planning: the base plans the next chunk on a worker thread while the control loop runs.

``--policy.planning=async`` (:class:`~lerobot_dcdp.modeling_dcdp.DCDPPolicy`) hands the base's chunk calls to
a :class:`BackgroundPlanner`: every control tick returns the corrected action of the chunk being executed at
once, and the next chunk is planned from a newer observation in the background. The worker runs the base on
a shallow copy of it (the same weights and config, its own observation history), so the control thread may
keep appending observations to the base's history while a chunk is being planned; the base is never called
from both threads at once (:meth:`BackgroundPlanner.cancel` waits for a running call).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from torch import Tensor

from lerobot_dcdp.chunk_sources import ChunkSource


@dataclass
class PlannedChunk:
    """A chunk the worker planned: from the observation of control step ``t_obs`` (``context``: whatever the
    caller attached at submission, e.g. the corrector's plan-time references) in ``seconds`` of wall time;
    ``prepared``: what the caller's ``finish(chunk)`` returned on the worker (None without one)."""

    chunk: Tensor
    t_obs: int
    context: Any
    seconds: float
    prepared: Any = None


class OneJobWorker:
    """At most one planning job at a time on one worker thread: the job bookkeeping both planners share
    (:class:`BackgroundPlanner` here, ``remote_planner.RemotePlanner`` over gRPC)."""

    thread_name = "dcdp-planner"

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._job: tuple[Future, int, Any] | None = None

    @property
    def pending(self) -> bool:
        """Whether a chunk was submitted and not taken yet."""
        return self._job is not None

    @property
    def t_obs(self) -> int | None:
        """Control step whose observation the pending chunk is planned from."""
        return None if self._job is None else self._job[1]

    def _start(self, t_obs: int, context, fn, *args) -> None:
        """Run ``fn(*args)`` on the worker as the job planned from step ``t_obs``."""
        if self._job is not None:
            raise RuntimeError("a chunk is already being planned: take() it first")
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=self.thread_name)
        self._job = (self._pool.submit(fn, *args), int(t_obs), context)

    def _finished(self, wait: bool) -> tuple[Any, int, Any] | None:
        """``(fn's result, t_obs, context)`` of the pending job once it is done (``wait``: block until it
        is), else ``None``; an error ``fn`` raised is raised here."""
        if self._job is None:
            return None
        future, t_obs, context = self._job
        if not wait and not future.done():
            return None
        self._job = None
        return future.result(), t_obs, context

    def cancel(self) -> None:
        """Drop the pending chunk (a new episode); a call already running is waited for and its chunk or
        error discarded, so the planner is idle afterwards."""
        if self._job is not None:
            future = self._job[0]
            self._job = None
            if not future.cancel():
                future.exception()  # waits; the chunk (or the error) is dropped

    def close(self) -> None:
        """Drop the pending chunk and stop the worker thread."""
        self.cancel()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


class BackgroundPlanner(OneJobWorker):
    """The base's chunk calls, one at a time, on one worker thread.

    Args:
        source: The control thread's chunk source; the worker plans with a copy of its base whose
            observation history is the snapshot given to :meth:`submit`.
    """

    def __init__(self, source: ChunkSource) -> None:
        super().__init__()
        self._worker = ChunkSource(copy.copy(source.base))  # shares weights and config; own history

    def submit(
        self,
        t_obs: int,
        prepared: dict[str, Tensor],
        snapshot: dict | None,
        length: int,
        context=None,
        finish: Callable[[Tensor], Any] | None = None,
    ):
        """Start planning ``length`` actions from step ``t_obs``'s prepared observation and the base's history
        then (``ChunkSource.snapshot()`` right after that step's ``observe``); ``finish(chunk)``, when given,
        runs on the worker after the base (the taken chunk's ``prepared``). One job at a time."""
        self._start(t_obs, context, self._plan, dict(prepared), snapshot, length, finish)

    def _plan(self, prepared: dict[str, Tensor], snapshot: dict | None, length: int, finish=None) -> tuple:
        started = time.perf_counter()
        self._worker.restore(snapshot)
        chunk = self._worker.chunk(prepared, length)
        seconds = time.perf_counter() - started
        return chunk, seconds, None if finish is None else finish(chunk)

    def take(self, wait: bool) -> PlannedChunk | None:
        """The pending chunk if it is done (``wait``: block until it is), else ``None``; an error the base
        raised is raised here."""
        done = self._finished(wait)
        if done is None:
            return None
        (chunk, seconds, finished), t_obs, context = done
        return PlannedChunk(chunk, t_obs, context, seconds, finished)
