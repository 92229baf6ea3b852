"""``--policy.planning=async``: the base plans on a worker thread; no control tick waits for it."""

from __future__ import annotations

import os
import threading
from functools import partial

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors


def _policy(diffusion_base, demo_root, **kw):
    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", latent_dim=4, **kw).eval()
    torch.manual_seed(1)
    with torch.no_grad():  # a corrector that moves the plan, so its every input matters
        for p in policy.corrector.residual.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return policy


def _run(policy, observations, delays: list[int] | None = None) -> torch.Tensor:
    """One episode's actions over ``observations`` (each tick's ``chunk_delay`` appended to ``delays``)."""
    torch.manual_seed(3)
    policy.reset()
    actions = []
    for o in observations:
        actions.append(policy.select_action(dict(o)))
        if delays is not None:
            delays.append(policy.chunk_delay)
    return torch.stack(actions)


@pytest.mark.parametrize("mode", ["dcdp", "open_loop"])
@pytest.mark.parametrize("delay", [0, 3])
def test_step_clock_gives_the_actions_of_sync_planning_with_that_delay(
    diffusion_base, demo_root, mode, delay
) -> None:
    """planning_clock='steps' (lerobot-eval): the chunk planned on the worker d ticks before it is used,
    from that tick's observation, is the one synchronous planning with inference_delay=d uses."""
    policy = _policy(diffusion_base, demo_root, n_action_steps=4, execution=mode, inference_delay=delay)
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(2, 14)]
    sync_delays, async_delays = [], []
    sync = _run(policy, observations, sync_delays)
    policy.config.planning, policy.config.planning_clock = "async", "steps"
    threads = []  # where the corrector's per-chunk work ran
    chunk_state = policy.corrector.chunk_state
    policy.corrector.chunk_state = lambda *a: (
        threads.append(threading.current_thread().name) or chunk_state(*a)
    )
    asynchronous = _run(policy, observations, async_delays)
    # the chunk's delay the recorder stores: the first chunk on time, every later one d steps late
    assert sync_delays == async_delays == [0] * 4 + [delay] * 10
    assert policy._async.planner is not None  # the worker planned every chunk after the first
    assert (policy.state.kernel is not None) == (mode == "dcdp")  # quiet ticks ran on the compiled kernel
    if mode == "dcdp":  # the first chunk of each episode on the tick, every later one on the worker
        assert threads[0] == "MainThread" and len(threads) > 2
        assert all(name.startswith("dcdp-planner") for name in threads[1:]), threads
    torch.testing.assert_close(asynchronous, sync, atol=1e-6, rtol=0)
    policy.config.planning = "sync"
    policy.config.inference_delay = delay + 1
    assert (_run(policy, observations) - asynchronous).abs().max() > 1e-4  # the delay matters
    policy.close()


def test_step_clock_gives_the_gated_anchoring_of_sync_planning(diffusion_base, demo_root) -> None:
    """A completion gate around ``object_anchored`` (a ``dcdp-fit-completion-gate --base`` folder) scales the
    same plan step under async planning as under sync planning with the same delay."""
    key = "observation.environment_state"
    policy = _policy(
        diffusion_base,
        demo_root,
        n_action_steps=4,
        execution="object_anchored",
        anchor_feature=key,
        completion_gate=True,
        inference_delay=2,
    )
    with torch.no_grad():  # p(near) = 0.5 everywhere: half of the anchoring's change kept
        policy.completion_gate.net[-1].weight.zero_()
        policy.completion_gate.net[-1].bias.zero_()
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(2, 14)]
    sync = _run(policy, observations)
    policy.config.completion_gate = False
    ungated = _run(policy, observations)
    assert (sync - ungated).abs().max() > 1e-4  # the block moves in these episodes: the gate matters
    policy.config.completion_gate = True
    policy.config.planning, policy.config.planning_clock = "async", "steps"
    torch.testing.assert_close(_run(policy, observations), sync, atol=1e-6, rtol=0)
    policy.close()


class _Clock:
    """A controlled clock for ``planning_clock='wall'`` (``AsyncPlanning.clock``): it reads ``now`` and moves
    only when the test moves it, so the tick period and planning time the policy measures, and the planning
    lead it takes from them, cannot depend on the machine's load."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class _GatedBase:
    """Wraps the base's predict_action_chunk: the first call (an episode's first chunk) runs at once, taking
    ``first_call_s`` on ``clock``; every later one blocks until the test opens ``gate`` (the wait's timeout
    only guards against a hang)."""

    def __init__(self, base, clock: _Clock, first_call_s: float = 0.0) -> None:
        self.inner = base.predict_action_chunk
        self.clock, self.first_call_s = clock, first_call_s
        self.gate = threading.Event()
        self.calls = 0
        self.blocked_calls = 0
        base.predict_action_chunk = self

    def __call__(self, batch):
        self.calls += 1
        if self.calls == 1:
            self.clock.now += self.first_call_s
        else:
            self.blocked_calls += 1
            assert self.gate.wait(timeout=120), "the test never opened the gate"
        return self.inner(batch)


def _gated(policy, first_call_s: float = 0.0) -> tuple[_GatedBase, _Clock]:
    """Give ``policy``'s async planning a controlled clock and its base a gate."""
    clock = _Clock()
    policy._async.clock = clock
    return _GatedBase(policy.base, clock, first_call_s), clock


def test_wall_clock_ticks_never_wait_for_a_slow_base(diffusion_base, demo_root) -> None:
    """With the base stuck mid-plan, every tick still returns: the chunk runs past its end holding its last
    (corrected) step; once the worker returns, the next tick switches to the new chunk, its entries for the
    ticks past since its observation skipped."""
    horizon = 4
    policy = _policy(
        diffusion_base, demo_root, n_action_steps=horizon, execution="open_loop", planning="async"
    )
    gated, clock = _gated(policy, first_call_s=0.125)  # the first chunk takes 0.125 s to plan
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(1, 16)]
    torch.manual_seed(3)
    policy.reset()
    first = None
    for t in range(12):  # the base is blocked from its second call on: no tick may wait for it
        clock.now += 0.25 if t else 0.0  # a 4 Hz loop
        action = policy.select_action(dict(observations[t]))
        if t == 0:
            first = policy.planned_chunk.clone()
        assert policy.last_step == min(t, horizon - 1)
        torch.testing.assert_close(action, first[:, min(t, horizon - 1)])
    assert gated.blocked_calls == 1 and policy._async.planner.pending
    # submitted at tick 2: ceil(0.125 s planning / 0.3375 s smoothed tick period) + 1 = 2 ticks before the
    # first chunk's end
    t_obs = policy._async.planner.t_obs
    assert t_obs == horizon - 2
    gated.gate.set()
    job_future = policy._async.planner._job[0]
    planned = job_future.result(timeout=120)[0]  # the test waits for the worker (the timeout: a hang only)
    action = policy.select_action(dict(observations[12]))
    age = 12 - t_obs
    assert policy.last_step == 0
    torch.testing.assert_close(action, planned[:, age])
    torch.testing.assert_close(policy.planned_chunk[:, 0], planned[:, age])
    policy.reset()  # a new episode: nothing pending, the worker idle
    assert not policy._async.planner.pending
    policy.close()
    assert policy._async.planner is None


def test_a_chunk_late_for_its_expected_age_is_prepared_on_the_tick(diffusion_base, demo_root) -> None:
    """dcdp, wall clock: the worker prepares each chunk for the age it is expected to start at; a chunk that
    arrives later than that is prepared again on the switching tick (never installed with the wrong slice),
    and its actions are those of the chunk's right entries."""
    horizon = 4
    policy = _policy(diffusion_base, demo_root, n_action_steps=horizon, execution="dcdp", planning="async")
    gated, _ = _gated(policy)  # a clock that never moves: no planning time measured, a lead of 1 tick
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(1, 14)]
    threads = []
    chunk_state = policy.corrector.chunk_state

    def traced(*args):
        threads.append(threading.current_thread().name)
        return chunk_state(*args)

    policy.corrector.chunk_state = traced
    torch.manual_seed(3)
    policy.reset()
    for t in range(12):  # the second chunk is held back well past the end of the first
        policy.select_action(dict(observations[t]))
    gated.gate.set()
    planned, _, prepared = policy._async.planner._job[0].result(timeout=120)  # the timeout: a hang only
    t_obs = policy._async.planner.t_obs
    assert t_obs == horizon - 1  # submitted one tick before the first chunk's end ...
    # ... so the worker prepared it to start 1 step after its observation; it arrives 12 - 3 = 9 steps after
    assert prepared is not None and prepared[0] == 1
    action = policy.select_action(dict(observations[12]))
    assert threads[0] == "MainThread" and threads[1].startswith("dcdp-planner") and threads[2] == "MainThread"
    age = 12 - t_obs
    torch.testing.assert_close(policy.planned_chunk, planned[:, age : age + horizon])
    reference = policy.state.copy()  # the same step computed from the installed chunk, eagerly
    policy.corrector.fast_inference = False
    reference.terms = reference.w_step = reference.kernel = None
    reference.step = 0
    policy.corrector.begin_chunk(reference, policy.planned_chunk)
    assert reference.z is not None
    torch.testing.assert_close(policy.state.z, reference.z)
    torch.testing.assert_close(
        action, policy.corrector.step(reference, 0, dict(observations[12])), atol=1e-5, rtol=0
    )
    policy.close()


def test_a_chunk_older_than_its_length_starts_at_its_last_step(diffusion_base, demo_root) -> None:
    """A base stuck for longer than the chunk it returns covers: the tick after it returns executes the
    chunk's last action (every earlier entry is in the past), it does not fail on an empty slice."""
    horizon = 4
    policy = _policy(
        diffusion_base, demo_root, n_action_steps=horizon, execution="open_loop", planning="async"
    )
    gated, _ = _gated(policy)  # a clock that never moves: a lead of 1 tick
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    length = policy.source.max_length
    ticks = length + horizon + 2
    observations = [pre(dict(o)) for o in env_observations(1, ticks + 1)]
    torch.manual_seed(3)
    policy.reset()
    for t in range(ticks):
        policy.select_action(dict(observations[t]))
    t_obs = policy._async.planner.t_obs
    assert t_obs == horizon - 1 and ticks - t_obs > length  # the chunk is older than it is long
    gated.gate.set()
    planned = policy._async.planner._job[0].result(timeout=120)[0]
    action = policy.select_action(dict(observations[ticks]))
    torch.testing.assert_close(action, planned[:, -1])
    policy.close()


def test_async_planning_is_refused_where_every_step_replans(diffusion_base, demo_root) -> None:
    with pytest.raises(ValueError, match="planning='async' applies to the chunk modes"):
        make_dcdp_policy(diffusion_base, demo_root, planning="async", execution="closed_loop")
    with pytest.raises(ValueError, match="did you mean 'async'"):
        make_dcdp_policy(diffusion_base, demo_root, planning="asynch")


class _ScriptedPlanner:
    """A stand-in for a remote planner (``BackgroundPlanner``'s interface): chunk k is all ``k + 1``."""

    def __init__(self, horizon: int) -> None:
        self.horizon, self.submitted, self.job, self.cancels = horizon, [], None, 0

    @property
    def pending(self) -> bool:
        return self.job is not None

    @property
    def t_obs(self):
        return None if self.job is None else self.job[0]

    def submit(self, t_obs, prepared, snapshot, length, context=None, finish=None) -> None:
        self.submitted.append(t_obs)
        self.job = (t_obs, context)

    def take(self, wait: bool):
        from lerobot_dcdp.runtime.planner import PlannedChunk

        t_obs, context = self.job
        self.job = None
        chunk = torch.full((1, self.horizon + 4, 2), float(len(self.submitted)))
        return PlannedChunk(chunk, t_obs, context, 0.0)

    def cancel(self) -> None:
        self.job, self.cancels = None, self.cancels + 1

    def close(self) -> None:
        raise AssertionError("the policy must not close a planner it was handed")


def test_a_remote_base_plans_every_chunk_and_its_weights_are_never_read(diffusion_base, demo_root, tmp_path):
    """base_location='remote' (dcdp-robot-client): the base folder needs no weights; nothing runs until a
    planner is attached; then the episode's first chunk too comes from it, ``lead`` steps ahead."""
    import shutil

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    trained = _policy(diffusion_base, demo_root, n_action_steps=4, execution="open_loop")
    trained.save_pretrained(tmp_path / "corrector")
    weightless = tmp_path / "base_config_only"
    shutil.copytree(diffusion_base, weightless, ignore=shutil.ignore_patterns("model.safetensors"))
    config = type(trained.config).from_pretrained(tmp_path / "corrector")
    config.base_policy_path, config.planning, config.base_location = str(weightless), "async", "remote"
    policy = DCDPPolicy.from_pretrained(tmp_path / "corrector", config=config).eval()
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(1, 10)]
    with pytest.raises(ValueError, match="attach its planner"):
        policy.select_action(dict(observations[0]))
    planner = _ScriptedPlanner(4)
    policy.attach_planner(planner, lead=2)
    actions = torch.stack([policy.select_action(dict(o)) for o in observations])
    # chunk 1 from tick 0; chunk 2 requested 2 ticks before chunk 1 ends (tick 2), used at tick 4 with its
    # entries for ticks 2-3 skipped; chunk 3 requested at tick 6
    assert planner.submitted == [0, 2, 6]
    torch.testing.assert_close(actions[:, 0, 0], torch.tensor([1.0] * 4 + [2.0] * 4 + [3.0] * 2))
    policy.reset()
    assert planner.cancels >= 2  # attach and reset both drop a pending chunk
    policy.close()  # leaves the attached planner to its owner
    with pytest.raises(ValueError, match="planning=async"):
        type(config)(base_policy_path="base", base_location="remote")


@pytest.mark.parametrize("planning", ["sync", "async"])
def test_ticks_per_step_holds_each_planned_action(diffusion_base, demo_root, planning) -> None:
    """ticks_per_step=k (a 10 Hz base on a k*10 Hz loop): every k-th call computes the action of the next
    planned step from its own observation, the calls between return it unchanged and never read theirs (so
    the base, the corrector and their histories run at the base's rate): the actions of the base's rate, each
    k times (async planning on the step clock: its chunks are planned and aged in computing calls)."""
    policy = _policy(diffusion_base, demo_root, n_action_steps=4, inference_delay=1)
    policy.config.planning, policy.config.planning_clock = planning, "steps"
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(2, 10)]
    at_base_rate = _run(policy, observations)
    policy.config.ticks_per_step = 3
    torch.manual_seed(3)
    policy.reset()
    out, holds = [], []
    for o in observations:
        other = {k: v + 7.0 if k.startswith("observation") else v for k, v in o.items()}
        for tick in range(3):  # the ticks between planned steps see another scene: it must not matter
            batch = o if tick == 0 else other
            holds.append(policy.holds_next_tick)
            out.append(policy.select_action(dict(batch)))
    assert holds == [False, True, True] * len(observations)
    torch.testing.assert_close(torch.stack(out), at_base_rate.repeat_interleave(3, dim=0), atol=0, rtol=0)
    policy.reset()  # a new episode holds nothing
    assert not policy.holds_next_tick
    policy.close()
    with pytest.raises(ValueError, match="ticks_per_step must be an integer >= 1"):
        type(policy.config)(base_policy_path=str(diffusion_base), ticks_per_step=0)


def _worker_episode(diffusion_base, demo_root, probe, **kw) -> tuple[list, list]:
    """Ten ticks of an async open-loop episode (worker options ``kw``): ``(thread name, probe())`` at every
    base call, and ``probe()`` on the control thread after every tick. The policy is closed afterwards."""
    policy = _policy(
        diffusion_base,
        demo_root,
        n_action_steps=4,
        execution="open_loop",
        planning="async",
        planning_clock="steps",
        inference_delay=1,
        **kw,
    )
    seen = []
    inner = policy.base.predict_action_chunk

    def recording(batch):
        seen.append((threading.current_thread().name, probe()))
        return inner(batch)

    policy.base.predict_action_chunk = recording
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    control = []
    for o in env_observations(1, 10):
        policy.select_action(pre(dict(o)))
        control.append(probe())
    policy.close()
    return seen, control


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="pinning apart needs two CPUs")
def test_planner_cpus_pins_the_worker_and_moves_the_control_loop_off_them(diffusion_base, demo_root) -> None:
    """planner_cpus: the base runs on those CPUs only, the control thread on the others while the worker
    lives, and gets its CPUs back on close."""
    allowed = os.sched_getaffinity(0)
    worker_cpu = max(allowed)
    affinity = partial(os.sched_getaffinity, 0)
    seen, control = _worker_episode(diffusion_base, demo_root, affinity, planner_cpus=[worker_cpu])
    assert seen[0] == ("MainThread", allowed)  # the episode's first chunk, before the worker exists
    worker_calls = [cpus for name, cpus in seen[1:] if name.startswith("dcdp-planner")]
    assert len(worker_calls) == len(seen) - 1 >= 2
    assert all(cpus == {worker_cpu} for cpus in worker_calls)
    assert control[-1] == allowed - {worker_cpu}
    assert os.sched_getaffinity(0) == allowed  # given back on close


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="SCHED_IDLE is Linux's")
def test_planner_priority_idle_runs_the_base_under_sched_idle(diffusion_base, demo_root) -> None:
    """planner_priority='idle': every base call on the worker runs under SCHED_IDLE; the control thread keeps
    its own scheduling."""
    before = os.sched_getscheduler(0)
    scheduler = partial(os.sched_getscheduler, 0)
    seen, control = _worker_episode(diffusion_base, demo_root, scheduler, planner_priority="idle")
    worker_calls = [sched for name, sched in seen if name.startswith("dcdp-planner")]
    assert len(worker_calls) >= 2 and set(worker_calls) == {os.SCHED_IDLE}
    assert set(control) == {before} and before != os.SCHED_IDLE


def test_planner_cpus_must_leave_the_control_loop_a_cpu() -> None:
    from lerobot_dcdp.runtime.planner import pin_apart

    allowed = os.sched_getaffinity(0)
    with pytest.raises(ValueError, match="leave no CPU to the control loop"):
        pin_apart(set(allowed))
    with pytest.raises(ValueError, match="are not all CPUs this process may use"):
        pin_apart({max(allowed) + 1})
    assert os.sched_getaffinity(0) == allowed  # nothing changed
