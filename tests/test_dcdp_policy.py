"""The DCDP policy on tiny random-init bases: stage-1 loss, checkpoints, execution modes, caching."""

from __future__ import annotations

import itertools

import pytest
import torch
from helpers import env_observations, make_dcdp_policy, training_batches
from lerobot.policies.factory import get_policy_class
from safetensors.torch import load_file

from lerobot_dcdp.model.correction import from_unit_range, sliding_windows, temporal_ensemble_step
from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors


def normalised_observations(policy, n_envs: int, steps: int, seed: int = 0) -> list[dict]:
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    return [pre(o) for o in env_observations(n_envs, steps, seed)]


def load_base(path):
    from lerobot.configs.policies import PreTrainedConfig

    cfg = PreTrainedConfig.from_pretrained(path)
    return get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()


def test_base_is_frozen_and_outside_the_module(diffusion_base, demo_root) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root)
    n_base = sum(1 for _ in policy.base.parameters())
    assert n_base > 0
    assert not any(k.startswith(("_base", "base", "diffusion")) for k in policy.state_dict())
    assert all(not p.requires_grad for p in policy.base.parameters())
    policy.train()
    assert policy.training and not policy.base.training
    ids = {id(p) for p in policy.parameters()}
    assert not ids & {id(p) for p in policy.base.parameters()}
    assert len(policy.config.base_weights_sha256) == 64 and policy.config.base_policy_type == "diffusion"


@pytest.mark.parametrize(
    "ablation",
    [{}, {"use_temporal_attention": False}, {"use_diff_cross_attention": False}, {"use_diff_loss": False}],
)
def test_stage1_loss_falls(diffusion_base, demo_root, ablation) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root, **ablation)
    batches = training_batches(policy, demo_root, batch_size=32)
    fixed = next(batches)
    policy.eval()
    with torch.no_grad():
        before, parts = policy(fixed)
    assert set(parts) >= {"recon_loss", "kl_loss", "diff_loss"}
    opt = torch.optim.AdamW(policy.get_optim_params(), lr=3e-3)
    policy.train()
    for batch in itertools.islice(batches, 25):
        loss, _ = policy(batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    with torch.no_grad():
        after, _ = policy(fixed)
    assert after < 0.6 * before, (before, after)


def test_padding_is_masked(diffusion_base, demo_root) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root).eval()
    batch = next(training_batches(policy, demo_root, batch_size=8))
    batch["action_is_pad"] = torch.zeros_like(batch["action_is_pad"])
    batch["action_is_pad"][:, 4:] = True
    with torch.no_grad():
        ref, _ = policy(batch)
        batch["action"] = batch["action"].clone()
        batch["action"][:, 4:] += 100.0  # padded targets must not matter ... except through the encoder input
        policy.corrector.encoder.net[-1].weight.data.zero_()  # make z independent of the chunk for this check
        policy.corrector.encoder.net[-1].bias.data.zero_()
        a, _ = policy(batch)
        batch["action"][:, 4:] -= 100.0
        b, _ = policy(batch)
    assert torch.equal(a, b) and not torch.equal(a, ref)


def test_save_load_round_trip_is_exact(diffusion_base, demo_root, tmp_path) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root)
    policy.save_pretrained(tmp_path)
    saved = load_file(tmp_path / "model.safetensors")
    assert set(saved) == set(policy.state_dict())
    base_keys = set(policy.base.state_dict())
    assert not set(saved) & base_keys
    # no base weights hide under other names either (values compared, not just names)
    base_tensors = [  # trained/random weights; constant tensors (zero biases, ones) say nothing
        t for t in policy.base.state_dict().values() if t.numel() > 16 and t.float().std() > 0
    ]
    for name, t in saved.items():
        assert not any(t.shape == b.shape and torch.equal(t, b) for b in base_tensors), name
    assert sum(t.numel() for t in saved.values()) == sum(t.numel() for t in policy.state_dict().values())
    loaded = DCDPPolicy.from_pretrained(tmp_path)
    for k, v in policy.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k]), k
    assert loaded.config.base_weights_sha256 == policy.config.base_weights_sha256
    obs = normalised_observations(policy, 2, 10)
    policy.eval().reset()
    loaded.reset()
    for o in obs:
        torch.manual_seed(1)
        a = policy.select_action(dict(o))
        torch.manual_seed(1)
        assert torch.equal(a, loaded.select_action(dict(o)))


@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_open_loop_reproduces_the_base(kind, diffusion_base, act_base, demo_root) -> None:
    base_dir = diffusion_base if kind == "diffusion" else act_base
    policy = make_dcdp_policy(base_dir, demo_root, execution="open_loop").eval()
    reference = load_base(base_dir)
    obs = normalised_observations(policy, 2, 20)
    torch.manual_seed(0)
    reference.reset()
    expected = [reference.select_action(dict(o)) for o in obs]
    torch.manual_seed(0)
    policy.reset()
    got = [policy.select_action(dict(o)) for o in obs]
    for e, g in zip(expected, got, strict=True):
        assert torch.equal(e, g)


def test_closed_loop_and_temporal_ensemble_match_offline(act_base, demo_root) -> None:
    reference = load_base(act_base)
    obs = normalised_observations(make_dcdp_policy(act_base, demo_root), 3, 12)
    chunks = [reference.predict_action_chunk(dict(o)) for o in obs]
    closed = make_dcdp_policy(act_base, demo_root, execution="closed_loop").eval()
    closed.reset()
    for o, c in zip(obs, chunks, strict=True):
        assert torch.equal(closed.select_action(dict(o)), c[:, 0])
    te = make_dcdp_policy(act_base, demo_root, execution="temporal_ensemble", te_weight=0.5).eval()
    te.reset()
    plan = None
    for o, c in zip(obs, chunks, strict=True):
        # offline: blend by hand, 0.5 new + 0.5 previous estimate of the same step
        if plan is None:
            plan = c.clone()
        else:
            new = c.clone()
            new[:, :-1] = 0.5 * c[:, :-1] + 0.5 * plan[:, 1:]
            plan = new
        torch.testing.assert_close(te.select_action(dict(o)), plan[:, 0], rtol=0, atol=1e-6)
    assert torch.equal(temporal_ensemble_step(None, chunks[0], 0.5), chunks[0])


def test_dcdp_step_equals_offline_chunk_decoding(act_base, demo_root) -> None:
    """Cached per-frame tokens + one GRU step per control step == decoding the chunk from full windows,
    with the history bank padded by the first frame exactly as training samples are padded."""
    policy = make_dcdp_policy(act_base, demo_root, n_history=4).eval()
    H, M = policy.config.n_action_steps, policy.config.n_history
    obs = normalised_observations(policy, 3, 2 * H)
    policy.reset()
    online = torch.stack([policy.select_action(dict(o)) for o in obs], dim=1)  # (B, 2H, A)
    reference = load_base(act_base)
    with torch.no_grad():
        keys = policy.corrector.frame_keys
        frames = torch.stack([policy.corrector.frame_encoder({k: o[k] for k in keys}) for o in obs], dim=1)
        frames = torch.cat([frames[:, :1].expand(-1, M - 1, -1), frames], dim=1)
        windows = sliding_windows(frames, M)  # (B, 2H, M, d)
        feats = torch.stack([policy.corrector.extractor(windows[:, s])[0] for s in range(2 * H)], dim=1)
        for c in range(2):
            chunk = reference.predict_action_chunk(dict(obs[c * H]))[:, :H]
            z = policy.corrector.encode_chunk(chunk)
            dec = from_unit_range(
                policy.corrector.decoder(z, feats[:, c * H : (c + 1) * H]),
                policy.corrector.action_low,
                policy.corrector.action_high,
            )
            torch.testing.assert_close(online[:, c * H : (c + 1) * H], dec, rtol=1e-5, atol=1e-5)


def test_batch_of_three_and_reset(act_base, demo_root) -> None:
    policy = make_dcdp_policy(act_base, demo_root).eval()
    obs = normalised_observations(policy, 3, 10, seed=5)
    policy.reset()
    first = [policy.select_action(dict(o)) for o in obs]
    assert all(a.shape == (3, 2) for a in first)
    assert policy.state.bank.shape == (3, policy.config.n_history, policy.config.feature_dim)
    policy.reset()
    assert policy.state.bank is None and policy.state.step == 0
    again = [policy.select_action(dict(o)) for o in obs]
    for a, b in zip(first, again, strict=True):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="observation.environment_state"):
        policy.select_action({"observation.state": obs[0]["observation.state"]})
    chunk = policy.predict_action_chunk(dict(obs[0]))
    assert chunk.shape == (3, policy.config.n_action_steps, 2)


@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_predict_action_chunk_is_a_query(kind, diffusion_base, act_base, demo_root) -> None:
    """It plans from the given observation and leaves the policy's state alone: interleaving it with
    select_action changes no action, and it equals the chunk a fresh policy starts from that observation."""
    base_dir = diffusion_base if kind == "diffusion" else act_base
    policy = make_dcdp_policy(base_dir, demo_root, anchor_feature="observation.environment_state").eval()
    obs = normalised_observations(policy, 2, 12)
    torch.manual_seed(0)
    policy.reset()
    plain = [policy.select_action(dict(o)) for o in obs]
    torch.manual_seed(0)
    policy.reset()
    mixed = []
    for i, o in enumerate(obs):
        state = torch.get_rng_state()
        if i % 3 == 1:
            policy.predict_action_chunk(dict(o))
            torch.set_rng_state(state)  # the diffusion base draws noise: keep select_action's stream
        mixed.append(policy.select_action(dict(o)))
    for a, b in zip(plain, mixed, strict=True):
        assert torch.equal(a, b)
    for execution in ("dcdp", "object_anchored", "open_loop"):  # each mode's own first action
        policy.config.execution = execution
        policy.reset()
        torch.manual_seed(1)
        chunk = policy.predict_action_chunk(dict(obs[0]))
        policy.reset()
        torch.manual_seed(1)
        first = policy.select_action(dict(obs[0]))
        torch.testing.assert_close(chunk[:, 0], first)


def test_corrector_weights_load_strictly(diffusion_base, demo_root, tmp_path) -> None:
    from safetensors.torch import save_file

    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual")
    policy.save_pretrained(tmp_path)
    weights = load_file(tmp_path / "model.safetensors")
    dropped = sorted(k for k in weights if k.startswith("corrector.residual."))[-1]
    save_file({k: v for k, v in weights.items() if k != dropped}, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match=f"corrector weights.*{dropped}"):
        DCDPPolicy.from_pretrained(tmp_path)
    save_file({**weights, "decoder.extra": torch.zeros(2)}, tmp_path / "model.safetensors")
    with pytest.raises(ValueError, match="decoder.extra"):
        DCDPPolicy.from_pretrained(tmp_path)
    save_file(weights, tmp_path / "model.safetensors")
    DCDPPolicy.from_pretrained(tmp_path)  # the untouched file loads
