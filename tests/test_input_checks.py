"""One input check on every execution path: feature widths, batch size within a chunk, non-finite values."""

from __future__ import annotations

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors


@pytest.fixture(scope="module")
def policy_and_obs(diffusion_base, demo_root):
    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", latent_dim=4).eval()
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    return policy, [pre(dict(o)) for o in env_observations(2, 3)]


@pytest.mark.parametrize("mode", ["dcdp", "open_loop", "object_anchored", "temporal_ensemble"])
def test_a_feature_of_the_wrong_width_is_named(policy_and_obs, mode) -> None:
    policy, obs = policy_and_obs
    policy.config.execution = mode
    policy.config.anchor_feature = "observation.environment_state"
    policy.reset()
    bad = dict(obs[0])
    bad["observation.environment_state"] = bad["observation.environment_state"][:, :14]
    with pytest.raises(
        ValueError, match=r"'observation.environment_state' has shape \(2, 14\), expected \(batch, 16\)"
    ):
        policy.select_action(bad)
    policy.config.execution = "dcdp"


@pytest.mark.parametrize("mode", ["dcdp", "open_loop"])
def test_a_batch_that_changes_within_a_chunk_is_refused(policy_and_obs, mode) -> None:
    policy, obs = policy_and_obs
    policy.config.execution = mode
    policy.reset()
    policy.select_action(dict(obs[0]))
    one = {k: v[:1] for k, v in obs[1].items() if isinstance(v, torch.Tensor)}
    with pytest.raises(ValueError, match=r"batch 1 but the current chunk was planned for batch 2"):
        policy.select_action(one)
    policy.reset()
    assert policy.select_action(one).shape[0] == 1  # a new episode may change the batch
    policy.config.execution = "dcdp"


def test_a_non_finite_observation_is_refused_before_it_enters_the_history(policy_and_obs) -> None:
    policy, obs = policy_and_obs
    policy.reset()
    policy.select_action(dict(obs[0]))
    bank = policy.state.bank.clone()
    bad = dict(obs[1])
    bad["observation.state"] = bad["observation.state"].clone()
    bad["observation.state"][1, 0] = float("nan")
    with pytest.raises(ValueError, match=r"'observation.state' holds a non-finite value"):
        policy.select_action(bad)
    assert torch.equal(policy.state.bank, bank) and policy.state.step == 1  # nothing advanced
