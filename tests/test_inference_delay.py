"""``inference_delay``: a base that answers d control steps late, honoured by every execution mode."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors
from lerobot_dcdp.runtime.chunk_sources import ChunkSource

H = 8


class StepIndexBase:
    """A chunking base whose chunk from the observation of step tau is ``[(tau, tau + k) for k < L]``:
    entry k is the action planned for step tau + k, labelled with the step it was planned from. It reads
    tau from ``observation.state[:, 0]``."""

    def __init__(self, length: int = 16) -> None:
        self.config = SimpleNamespace(type="step_index", n_action_steps=None, chunk_size=length)
        self.calls: list[int] = []

    def reset(self) -> None:
        self.calls.clear()

    def predict_action_chunk(self, batch: dict) -> torch.Tensor:
        tau = batch["observation.state"][:, 0]
        self.calls.append(int(tau[0]))
        k = torch.arange(self.config.chunk_size, dtype=torch.float32)
        return torch.stack([tau[:, None].expand(-1, len(k)), tau[:, None] + k], dim=-1)


def step_observations(steps: int, n_envs: int = 2) -> list[dict]:
    """Observation t carries t in its state; the keypoints translate by one unit per step."""
    kp = torch.arange(16, dtype=torch.float32).repeat(n_envs, 1)
    shift = torch.tensor([1.0, 0.0]).repeat(8)
    return [
        {
            "observation.state": torch.full((n_envs, 2), float(t)),
            "observation.environment_state": kp + t * shift,
        }
        for t in range(steps)
    ]


def run_with_fake_base(act_base, demo_root, execution: str, delay: int, steps: int):
    policy = make_dcdp_policy(act_base, demo_root, execution=execution, inference_delay=delay).eval()
    fake = StepIndexBase()
    policy.source = ChunkSource(fake)
    policy.reset()
    obs = step_observations(steps)
    return policy, fake, obs, [policy.select_action(dict(o)) for o in obs]


@pytest.mark.parametrize("execution", ["open_loop", "closed_loop", "temporal_ensemble"])
def test_executed_sequence_with_delay_2(execution, act_base, demo_root) -> None:
    """d = 2: a chunk used from step t was planned from step max(t-2, 0) and entries for the steps past
    since then are skipped, so every executed action is the one planned for its own step."""
    steps, d = 3 * H, 2
    _, fake, _, actions = run_with_fake_base(act_base, demo_root, execution, d, steps)
    for t, a in enumerate(actions):
        if execution == "open_loop":
            planned_from = 0 if t < H else (t // H) * H - d
        else:
            planned_from = max(t - d, 0)
        expected = torch.tensor([[planned_from, t]] * 2, dtype=torch.float32)
        if execution == "temporal_ensemble" and t > 0:
            # a blend of the chunks planned from max(t-d-j, 0), each one's entry for step t
            assert torch.equal(a[:, 1], torch.full((2,), float(t))), t
            continue
        assert torch.equal(a, expected), (execution, t, a)
    if execution == "open_loop":
        assert fake.calls == [0, H - d, 2 * H - d]
    else:
        assert fake.calls == [max(t - d, 0) for t in range(steps)]


def test_delay_0_plans_from_the_current_step(act_base, demo_root) -> None:
    _, fake, _, actions = run_with_fake_base(act_base, demo_root, "open_loop", 0, 2 * H)
    assert fake.calls == [0, H]
    for t, a in enumerate(actions):
        assert torch.equal(a[0], torch.tensor([(t // H) * H, t], dtype=torch.float32))


@pytest.mark.parametrize("execution", ["object_anchored", "dcdp"])
def test_corrections_measure_change_since_the_observation_planned_from(execution, act_base, demo_root):
    """object_anchored / dcdp compare now with the observation the late chunk was planned from."""
    d = 3
    policy = make_dcdp_policy(
        act_base,
        demo_root,
        execution=execution,
        inference_delay=d,
        anchor_feature="observation.environment_state",
        correction="residual" if execution == "dcdp" else "reconstruct",
        anchor_input=execution == "dcdp",
    ).eval()
    policy.source = ChunkSource(StepIndexBase())
    policy.reset()
    obs = step_observations(2 * H + 1)
    for t, o in enumerate(obs):
        policy.select_action(dict(o))
        if t == H:  # replan at step H, planned from step H - d
            torch.testing.assert_close(policy.state.anchor_plan, policy.anchor.points(obs[H - d]))
            assert torch.equal(policy.state.chunk[0, :, 0], torch.full((H,), float(H - d)))
            assert torch.equal(policy.state.chunk[0, :, 1], torch.arange(H, 2 * H, dtype=torch.float32))
            if execution == "dcdp":
                rep_then = policy.corrector.frame_encoder.encode(
                    {k: obs[H - d][k] for k in policy.corrector.frame_keys}
                )[1]
                torch.testing.assert_close(policy.state.at_plan, rep_then)


@pytest.mark.parametrize(
    "execution", ["open_loop", "closed_loop", "temporal_ensemble", "object_anchored", "dcdp"]
)
def test_the_default_delay_0_plans_every_chunk_from_its_own_step(execution, act_base, demo_root) -> None:
    """inference_delay defaults to 0, and 0 is the undelayed path in every mode: each chunk is planned from
    the observation of the step that starts using it, from its first entry (the chunking modes replan every
    H steps, the per-step modes every step), and no observations are kept for late plans."""
    assert DCDPConfig.__dataclass_fields__["inference_delay"].default == 0
    policy = make_dcdp_policy(
        act_base,
        demo_root,
        execution=execution,
        anchor_feature="observation.environment_state",
        correction="residual" if execution == "dcdp" else "reconstruct",
    ).eval()
    assert policy.config.inference_delay == 0
    fake = StepIndexBase()
    policy.source = ChunkSource(fake)
    policy.reset()
    steps = 2 * H
    for t, o in enumerate(step_observations(steps)):
        action = policy.select_action(dict(o))
        assert policy.chunk_delay == 0 and len(policy.state.past) == 0, t
        if execution in ("open_loop", "closed_loop"):  # the executed action is the planned one, as planned
            planned_from = t if execution == "closed_loop" else (t // H) * H
            assert torch.equal(action[0], torch.tensor([planned_from, t], dtype=torch.float32)), t
        if execution in ("open_loop", "object_anchored", "dcdp"):  # the chunk planned now, from entry 0
            assert torch.equal(policy.state.chunk[0, :, 0], torch.full((H,), float((t // H) * H))), t
    replans = range(0, steps, H) if execution in ("open_loop", "object_anchored", "dcdp") else range(steps)
    assert fake.calls == list(replans)


def test_diffusion_base_returns_its_horizon_on_demand(diffusion_base, demo_root) -> None:
    """Asked for more than n_action_steps, the diffusion source reads further into the same sample."""
    policy = make_dcdp_policy(diffusion_base, demo_root).eval()
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    prepared = policy.source.observe(pre(env_observations(2, 1)[0]))
    cfg = policy.base.config
    assert policy.source.max_length == cfg.horizon - cfg.n_obs_steps + 1
    torch.manual_seed(3)
    short = policy.source.chunk(prepared)
    torch.manual_seed(3)
    long = policy.source.chunk(prepared, policy.source.max_length)
    assert short.shape[1] == cfg.n_action_steps and long.shape[1] == policy.source.max_length
    assert torch.equal(long[:, : cfg.n_action_steps], short)
    assert cfg.n_action_steps == 8  # the base's own setting is restored


def test_a_base_too_short_for_the_delay_is_refused(diffusion_base, act_base, demo_root) -> None:
    with pytest.raises(ValueError, match=r"n_action_steps \+ inference_delay = 24 .* at most 15"):
        make_dcdp_policy(diffusion_base, demo_root, inference_delay=16)
    with pytest.raises(ValueError, match=r"= 17 .* at most 16"):
        make_dcdp_policy(act_base, demo_root, inference_delay=9)
    with pytest.raises(ValueError, match="inference_delay must be >= 0"):
        make_dcdp_policy(act_base, demo_root, inference_delay=-1)
