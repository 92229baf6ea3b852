"""Asynchronous planning: the base plans the next chunk on a worker thread while the control loop runs.

``--policy.planning=async`` (:class:`~lerobot_dcdp.policy.modeling_dcdp.DCDPPolicy`) hands the base's chunk
calls to
a :class:`BackgroundPlanner`: every control tick returns the corrected action of the chunk being executed at
once, and the next chunk is planned from a newer observation in the background. The worker runs the base on
a shallow copy of it (the same weights and config, its own observation history), so the control thread may
keep appending observations to the base's history while a chunk is being planned; the base is never called
from both threads at once (:meth:`BackgroundPlanner.cancel` waits for a running call).
"""

from __future__ import annotations

import copy
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from torch import Tensor

from lerobot_dcdp.runtime.chunk_sources import ChunkSource


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

    def __init__(self, cpus: set[int] | None = None, idle: bool = False) -> None:
        if idle and not hasattr(os, "SCHED_IDLE"):
            raise ValueError("planner_priority='idle' needs Linux's SCHED_IDLE, which this system lacks")
        self._pool: ThreadPoolExecutor | None = None
        self._job: tuple[Future, int, Any] | None = None
        self._cpus = None if cpus is None else set(cpus)
        self._idle = idle
        self._control_cpus: tuple[int, set[int]] | None = None  # (thread id, its CPUs before pinning)

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
            if self._cpus is not None:
                self._control_cpus = pin_apart(self._cpus)
            self._pool = ThreadPoolExecutor(
                max_workers=1,
                thread_name_prefix=self.thread_name,
                initializer=schedule_worker,
                initargs=(self._cpus, self._idle),
            )
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
        if self._control_cpus is not None:
            thread, cpus = self._control_cpus
            self._control_cpus = None
            try:
                os.sched_setaffinity(thread, cpus)
            except OSError:  # that thread has ended: nothing to give back
                pass


class BackgroundPlanner(OneJobWorker):
    """The base's chunk calls, one at a time, on one worker thread.

    Args:
        source: The control thread's chunk source; the worker plans with a copy of its base whose
            observation history is the snapshot given to :meth:`submit`.
        cpus: CPUs the worker thread runs on (``DCDPConfig.planner_cpus``; None: wherever the scheduler
            puts it). The thread that starts the worker (the control loop) is moved to its other CPUs
            until :meth:`close`.
        idle: Run the worker under ``SCHED_IDLE`` (``DCDPConfig.planner_priority='idle'``).
    """

    def __init__(self, source: ChunkSource, cpus: set[int] | None = None, idle: bool = False) -> None:
        super().__init__(cpus, idle)
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


def schedule_worker(cpus: set[int] | None, idle: bool) -> None:
    """Run in the worker thread as it starts: keep it on ``cpus`` (None: any) and, with ``idle``, give it
    ``SCHED_IDLE``, so any other thread that wants its CPU runs first (Linux; both for this thread only)."""
    if cpus is not None:
        os.sched_setaffinity(0, cpus)
    if idle:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def pin_apart(cpus: set[int]) -> tuple[int, set[int]]:
    """Move the calling thread off ``cpus`` (onto the rest of the CPUs it may use) and return its thread id
    and former CPU set, so it can be given back. ``cpus`` must be CPUs the process may use and leave at least
    one to the calling thread (else ValueError, nothing changed).
    """
    thread = threading.get_native_id()
    allowed = os.sched_getaffinity(0)
    if not set(cpus) <= allowed:
        raise ValueError(
            f"planner_cpus {sorted(cpus)} are not all CPUs this process may use ({sorted(allowed)})"
        )
    rest = allowed - set(cpus)
    if not rest:
        raise ValueError(
            f"planner_cpus {sorted(cpus)} leave no CPU to the control loop (it may use {sorted(allowed)})"
        )
    os.sched_setaffinity(0, rest)
    return thread, allowed
