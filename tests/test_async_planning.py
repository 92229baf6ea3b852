"""``--policy.planning=async``: the base plans on a worker thread; no control tick waits for it."""

from __future__ import annotations

import threading

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.processor_dcdp import make_dcdp_pre_post_processors


def _policy(diffusion_base, demo_root, **kw):
    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", latent_dim=4, **kw).eval()
    torch.manual_seed(1)
    with torch.no_grad():  # a corrector that moves the plan, so its every input matters
        for p in policy.corrector.residual.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return policy


def _run(policy, observations) -> torch.Tensor:
    torch.manual_seed(3)
    policy.reset()
    return torch.stack([policy.select_action(dict(o)) for o in observations])


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
    sync = _run(policy, observations)
    policy.config.planning, policy.config.planning_clock = "async", "steps"
    asynchronous = _run(policy, observations)
    assert policy._async.planner is not None  # the worker planned every chunk after the first
    assert (policy.state.kernel is not None) == (mode == "dcdp")  # quiet ticks ran on the compiled kernel
    torch.testing.assert_close(asynchronous, sync, atol=1e-6, rtol=0)
    policy.config.planning = "sync"
    policy.config.inference_delay = delay + 1
    assert (_run(policy, observations) - asynchronous).abs().max() > 1e-4  # the delay matters
    policy.close()


class _GatedBase:
    """Wraps the base's predict_action_chunk: the first call (an episode's first chunk) runs at once, every
    later one blocks until the test opens ``gate``."""

    def __init__(self, base) -> None:
        self.inner = base.predict_action_chunk
        self.gate = threading.Event()
        self.calls = 0
        self.blocked_calls = 0
        base.predict_action_chunk = self

    def __call__(self, batch):
        self.calls += 1
        if self.calls > 1:
            self.blocked_calls += 1
            assert self.gate.wait(timeout=120), "the test never opened the gate"
        return self.inner(batch)


def test_wall_clock_ticks_never_wait_for_a_slow_base(diffusion_base, demo_root) -> None:
    """With the base stuck mid-plan, every tick still returns: the chunk runs past its end holding its last
    (corrected) step; once the worker returns, the next tick switches to the new chunk, its entries for the
    ticks past since its observation skipped."""
    horizon = 4
    policy = _policy(
        diffusion_base, demo_root, n_action_steps=horizon, execution="open_loop", planning="async"
    )
    gated = _GatedBase(policy.base)
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in env_observations(1, 16)]
    torch.manual_seed(3)
    policy.reset()
    first = None
    for t in range(12):  # the base is blocked from its second call on: no tick may wait for it
        action = policy.select_action(dict(observations[t]))
        if t == 0:
            first = policy.planned_chunk.clone()
        assert policy.last_step == min(t, horizon - 1)
        torch.testing.assert_close(action, first[:, min(t, horizon - 1)])
    assert gated.blocked_calls == 1 and policy._async.planner.pending
    t_obs = policy._async.planner.t_obs
    assert 1 <= t_obs < horizon  # planned during the first chunk (how early depends on measured times)
    gated.gate.set()
    job_future = policy._async.planner._job[0]
    planned, _ = job_future.result(timeout=120)  # the test waits for the worker; the policy never does
    action = policy.select_action(dict(observations[12]))
    age = 12 - t_obs
    assert policy.last_step == 0
    torch.testing.assert_close(action, planned[:, age])
    torch.testing.assert_close(policy.planned_chunk[:, 0], planned[:, age])
    policy.reset()  # a new episode: nothing pending, the worker idle
    assert not policy._async.planner.pending
    policy.close()
    assert policy._async.planner is None


def test_async_planning_is_refused_where_every_step_replans(diffusion_base, demo_root) -> None:
    with pytest.raises(ValueError, match="planning='async' applies to the chunk modes"):
        make_dcdp_policy(diffusion_base, demo_root, planning="async", execution="closed_loop")
    with pytest.raises(ValueError, match="did you mean 'async'"):
        make_dcdp_policy(diffusion_base, demo_root, planning="asynch")
