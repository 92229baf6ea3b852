"""Bidirectional Decoding (``execution='bid'``): its selection rule on hand-made chunks, its sampling of the
base, its replanning period, its refusals, and a run through the real ``lerobot-eval``."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import BIN, run

from lerobot_dcdp.model.bid_selection import bid_select, coherence_distance
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.loader import load_dcdp


def _chunks(*values: float, length: int = 6) -> torch.Tensor:
    """One batch row of constant 2-D chunks (1, N, length, 2), chunk i at (values[i], values[i])."""
    return torch.tensor(values).view(1, -1, 1, 1).expand(1, len(values), length, 2).clone()


def test_coherence_keeps_the_candidate_nearest_the_previous_decision() -> None:
    strong = _chunks(0.0, 1.0, 2.0)
    prior = torch.full((1, 5, 2), 1.8)  # the previous choice, from this step on
    chosen = bid_select(strong, None, prior, decay=0.5, n_mode=3)  # keeps 3 // 3 = 1: the coherent one
    torch.testing.assert_close(chosen, strong[0, 2:3])
    # without a previous decision the centre of the dense group wins over the lone candidate (positive term)
    strong = _chunks(0.0, 1.0, 1.05, 1.1)
    chosen = bid_select(strong, None, None, decay=0.5, n_mode=1)
    assert chosen[0, 0, 0].item() == pytest.approx(1.05)


def test_coherence_weighs_the_nearest_steps_most() -> None:
    """Two candidates, each matching the prior on half of the steps: the decay decides which half counts."""
    prior = torch.zeros(1, 6, 2)
    early = torch.zeros(1, 1, 6, 2)
    early[:, :, 3:] = 1.0  # matches the prior's first three steps
    late = torch.zeros(1, 1, 6, 2)
    late[:, :, :3] = 1.0  # matches its last three
    both = torch.cat([late, early], dim=1)
    d = coherence_distance(both, prior, decay=0.5)
    assert d[0, 1] < d[0, 0]
    torch.testing.assert_close(bid_select(both, None, prior, 0.5, 2), early[:, 0])
    d_flat = coherence_distance(both, prior, decay=1.0)  # uniform weights: a tie
    torch.testing.assert_close(d_flat[0, 0], d_flat[0, 1])


def test_contrast_moves_away_from_the_weak_samples() -> None:
    strong = _chunks(0.0, 0.05, 1.0, 1.05)  # two equally tight modes; the first one wins a tie
    assert bid_select(strong, None, None, 0.5, 1)[0, 0, 0].item() < 0.5
    weak = _chunks(0.02, 0.03, 0.04)  # the weak policy sits on the first mode
    chosen = bid_select(strong, weak, None, 0.5, 1)
    assert chosen[0, 0, 0].item() > 0.5
    # batch rows are independent: the same weak samples near the second mode for row 2
    strong2 = torch.cat([strong, strong])
    weak2 = torch.cat([weak, _chunks(1.02, 1.03, 1.04)])
    chosen2 = bid_select(strong2, weak2, None, 0.5, 1)
    assert chosen2[0, 0, 0].item() > 0.5 and chosen2[1, 0, 0].item() < 0.5


def _bid_policy(base, **flags):
    cfg = DCDPConfig(base_policy_path=str(base), execution="bid", device="cpu", **flags)
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    return DCDPPolicy(cfg).eval()


def _observation(batch: int = 1) -> dict[str, torch.Tensor]:
    torch.manual_seed(0)
    return {
        "observation.state": torch.rand(batch, 2) * 2 - 1,
        "observation.environment_state": torch.rand(batch, 16) * 2 - 1,
    }


def test_bid_samples_the_base_and_replans_on_its_period(diffusion_base) -> None:
    policy = _bid_policy(diffusion_base, bid_samples=4, bid_modes=2, bid_replan_every=3)
    source = policy.source
    calls: list[tuple] = []
    real = source.samples

    def counting(prepared, n, length=None):
        out = real(prepared, n, length)
        calls.append((n, tuple(out.shape)))
        return out

    source.samples = counting
    policy.reset()
    queue_lengths = None
    actions = []
    for _ in range(7):
        actions.append(policy.select_action(_observation(2)))
        queue_lengths = {k: len(q) for k, q in policy.base._queues.items()}
    # decisions at steps 0, 3, 6; each draws 4 chunks of the base's longest length for both batch rows
    assert len(calls) == 3
    assert calls[0] == (4, (2, 4, source.max_length, 2))
    assert queue_lengths["observation.state"] == policy.base.config.n_obs_steps  # history untouched
    # between decisions the chosen chunk runs on: steps 1, 2 are its entries 1, 2
    chunk = policy.state.chunk
    assert chunk.shape == (2, source.max_length, 2)
    assert all(a.shape == (2, 2) for a in actions)
    # the candidates differ (a sampling base): BID has something to choose from
    policy.reset()
    samples = real(source.observe(_observation(1)), 4, source.max_length)
    assert not torch.allclose(samples[0, 0], samples[0, 1])


def test_bid_with_a_weak_policy_runs_and_refuses_what_it_cannot_compare(diffusion_base, act_base) -> None:
    policy = _bid_policy(diffusion_base, bid_samples=3, bid_weak_policy_path=str(diffusion_base))
    policy.reset()
    for _ in range(3):
        assert policy.select_action(_observation()).shape == (1, 2)
    other = _bid_policy(diffusion_base, bid_samples=3, bid_weak_policy_path=str(act_base))  # other stats
    other.reset()
    assert other.select_action(_observation()).shape == (1, 2)
    act = _bid_policy(act_base)
    act.reset()
    with pytest.raises(ValueError, match="base type 'act' returns the same chunk"):
        act.select_action(_observation())
    with pytest.raises(ValueError, match="bid_replan_every must be an integer in \\[1, n_action_steps=8\\]"):
        DCDPConfig(base_policy_path=str(diffusion_base), execution="bid", bid_replan_every=9)
    with pytest.raises(ValueError, match="bid_weak_policy_path is read by execution='bid' only"):
        DCDPConfig(base_policy_path=str(diffusion_base), bid_weak_policy_path=str(diffusion_base))
    with pytest.raises(ValueError, match="execution='bid' plans on the tick"):
        DCDPConfig(base_policy_path=str(diffusion_base), execution="bid", inference_delay=1)


class _EchoPolicy:
    """A stand-in policy whose 4-step chunk repeats the (normalised) state it reads as its action."""

    def __init__(self) -> None:
        from types import SimpleNamespace

        self.config = SimpleNamespace(type="echo", chunk_size=4)

    def reset(self) -> None:
        pass

    def predict_action_chunk(self, batch):
        return batch["observation.state"].unsqueeze(1).repeat(1, 4, 1)


def test_a_weak_policy_on_other_statistics_is_fed_and_read_in_the_bases_units() -> None:
    """Observations are mapped into the weak policy's normalisation and its chunks back, exactly: an echo
    policy whose action and state share statistics returns our own normalised state."""
    from lerobot_dcdp.model.base_normalizer import BaseNormalizer
    from lerobot_dcdp.runtime.chunk_sources import RenormalizedSource

    def min_max(lo: list[float], hi: list[float]) -> BaseNormalizer:
        mm = {"min": torch.tensor(lo), "max": torch.tensor(hi)}
        return BaseNormalizer({"observation.state": ("MIN_MAX", mm), "action": ("MIN_MAX", mm)})

    ours, theirs = min_max([0.0, 0.0], [512.0, 512.0]), min_max([10.0, 20.0], [400.0, 480.0])
    source = RenormalizedSource(_EchoPolicy(), ours, theirs)
    x = ours("observation.state", torch.tensor([[100.0, 300.0]]))
    chunk = source.chunk(source.observe({"observation.state": x}), 4)
    torch.testing.assert_close(chunk, x.unsqueeze(1).repeat(1, 4, 1))
    fed = source.observe({"observation.state": x})["observation.state"]
    torch.testing.assert_close(fed, theirs("observation.state", torch.tensor([[100.0, 300.0]])))
    assert not torch.allclose(fed, x)  # the weak policy read its own normalisation, not ours


def test_bid_around_a_bare_base_is_loadable(diffusion_base) -> None:
    policy, pre, _ = load_dcdp(base=diffusion_base, execution="bid")
    assert policy.config.execution == "bid" and pre is not None


@pytest.mark.slow
def test_lerobot_eval_runs_bid(trained_corrector, diffusion_base, tmp_path) -> None:
    out = tmp_path / "eval"
    run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={trained_corrector}",
            "--policy.execution=bid",
            "--policy.bid_samples=3",
            f"--policy.bid_weak_policy_path={diffusion_base}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=1",
            "--env.obs_type=environment_state_agent_pos",
            "--env.episode_length=6",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=false",
            f"--output_dir={out}",
            "--policy.device=cpu",
        ],
        cwd=tmp_path,
    )
    assert json.loads((out / "eval_info.json").read_text())["overall"]["n_episodes"] == 2
