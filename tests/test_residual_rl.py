"""Residual RL (``dcdp-finetune-rl``): the PPO arithmetic, the exploration hook, and a tiny run through the
command whose checkpoint resumes and runs under the stock lerobot-eval."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest
import torch
from helpers import env_observations, make_dcdp_policy
from test_teleop import BIN, ENV, _evaluate_one_episode, run

from lerobot_dcdp.train.ppo import (
    clipped_policy_loss,
    gaussian_log_prob,
    generalized_advantages,
    progress_rewards,
)


def test_generalized_advantages_match_a_hand_computed_buffer_and_stop_at_episode_ends() -> None:
    rewards = torch.tensor([1.0, 0.0, 2.0, 1.0])
    values = torch.tensor([0.5, 0.25, 1.0, 0.0])
    dones = torch.tensor([False, True, False, True])
    gamma, lam = 0.9, 0.5
    adv, ret = generalized_advantages(rewards, values, dones, gamma, lam)
    # episode 2: delta_3 = 1 - 0 = 1; delta_2 = 2 + 0.9 * 0 - 1 = 1; A_2 = 1 + 0.45 * 1
    # episode 1 (nothing bootstrapped from episode 2): delta_1 = 0 - 0.25; delta_0 = 1 + 0.9 * 0.25 - 0.5
    d1, d0 = -0.25, 1 + 0.9 * 0.25 - 0.5
    expected = torch.tensor([d0 + 0.45 * d1, d1, 1 + 0.45, 1.0])
    torch.testing.assert_close(adv, expected)
    torch.testing.assert_close(ret, expected + values)
    with pytest.raises(ValueError, match="must end with a finished episode"):
        generalized_advantages(rewards, values, torch.tensor([False, True, False, False]), gamma, lam)
    with pytest.raises(ValueError, match="equal 1-D shapes"):
        generalized_advantages(rewards, values[:3], dones, gamma, lam)


def test_progress_rewards_sum_to_the_last_reward() -> None:
    rewards = torch.tensor([0.1, 0.4, 0.3, 0.9])
    shaped = progress_rewards(rewards)
    torch.testing.assert_close(shaped, torch.tensor([0.1, 0.3, -0.1, 0.6]))
    assert math.isclose(shaped.sum().item(), 0.9, abs_tol=1e-6)


def test_gaussian_log_prob_and_the_clipped_surrogate() -> None:
    mean, log_std, x = torch.tensor([[0.0, 1.0]]), torch.tensor([-1.0, 0.5]), torch.tensor([[0.3, -0.2]])
    expected = torch.distributions.Normal(mean, log_std.exp()).log_prob(x).sum(-1)
    torch.testing.assert_close(gaussian_log_prob(x, mean, log_std), expected)
    # a ratio already past 1 + clip with a positive advantage gets no gradient; inside the range it does
    old = torch.zeros(2)
    logp = torch.tensor([math.log(1.5), math.log(1.1)], requires_grad=True)
    clipped_policy_loss(logp, old, torch.ones(2), clip=0.2).backward()
    assert logp.grad[0] == 0 and logp.grad[1] < 0


def _residual_corrector(diffusion_base: Path, demo_root: Path, out: Path, **overrides) -> Path:
    """A tiny residual corrector (head trained a little, so it is not all zero) saved with its processors."""
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", n_action_steps=4, **overrides)
    with torch.no_grad():
        policy.corrector.residual.net[-1].weight.normal_(0, 0.01)
    policy.save_pretrained(out)
    pre, post = make_dcdp_pre_post_processors(policy.config)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return out


def test_exploration_samples_around_the_head_bounded_by_the_starting_corrector(
    diffusion_base, demo_root, tmp_path
) -> None:
    from lerobot_dcdp.train.finetune_rl import load_corrector
    from lerobot_dcdp.train.residual_exploration import ResidualExploration

    policy, pre, _, _ = load_corrector(_residual_corrector(diffusion_base, demo_root, tmp_path / "c"))
    head, half = policy.corrector.residual, policy.corrector.action_half_range
    obs = [pre(dict(o)) for o in env_observations(2, 6)]
    torch.manual_seed(0)  # the base's sampling noise: the same chunks in every pass
    plain = [policy.select_action(dict(o)) for o in obs]
    explore = ResidualExploration(
        head, torch.full((2,), math.log(0.5)), 0.05, torch.Generator().manual_seed(0)
    )
    explore.active = True
    policy.reset()
    torch.manual_seed(0)
    for o, a in zip(obs, plain, strict=True):
        action = policy.select_action(dict(o))
        call = explore.take()
        explore.active = False
        torch.testing.assert_close(head(*call.inputs), call.mean)  # the inputs recompute the mean
        explore.active = True
        moved = (action - a) / half
        # noise of std 0.5 is clipped to the bound around the (unchanged) starting head's delta
        assert moved.abs().max() <= 0.05 + 1e-5 and moved.abs().max() > 0.04
        assert not torch.equal(call.sample, call.mean)
    with pytest.raises(RuntimeError, match="one residual-head call per control step"):
        explore.take()
    explore.remove()
    policy.reset()
    torch.manual_seed(0)
    torch.testing.assert_close(policy.select_action(dict(obs[0])), plain[0])


def test_finetune_changes_only_the_residual_head_is_reproducible_and_resumes(
    diffusion_base, demo_root, tmp_path
) -> None:
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.train.finetune_rl import RLConfig, finetune

    # saved to run open loop with a late base: RL runs it as dcdp on time, its checkpoints keep what was saved
    start = _residual_corrector(
        diffusion_base, demo_root, tmp_path / "start", execution="open_loop", inference_delay=1
    )
    settings = dict(policy=str(start), envs=2, max_steps=12, minibatch=8, save_every=1, critic_warmup=0)
    settings.update(lr=1e-2, init_std=0.1, max_deviation=0.2)
    a = finetune(RLConfig(output_dir=str(tmp_path / "a"), iterations=2, **settings), progress=False)
    assert a.name == "000001" and (tmp_path / "a" / "checkpoints" / "last").resolve() == a.resolve()
    before = DCDPPolicy.from_pretrained(start).state_dict()
    after = DCDPPolicy.from_pretrained(a / "pretrained_model").state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and all(k.startswith("corrector.residual.") for k in changed)
    saved = json.loads((a / "pretrained_model" / "config.json").read_text())
    assert (saved["execution"], saved["inference_delay"], saved["planning"]) == ("open_loop", 1, "sync")

    # the same command gives the same weights; a cut-off run resumed gives them too
    b = finetune(RLConfig(output_dir=str(tmp_path / "b"), iterations=1, **settings), progress=False)
    assert b.name == "000000"
    with pytest.raises(FileExistsError, match="pass --resume"):
        finetune(RLConfig(output_dir=str(tmp_path / "b"), iterations=2, **settings), progress=False)
    b = finetune(
        RLConfig(output_dir=str(tmp_path / "b"), iterations=2, **settings), resume=True, progress=False
    )
    resumed = DCDPPolicy.from_pretrained(b / "pretrained_model").state_dict()
    for k in changed:
        torch.testing.assert_close(resumed[k], after[k])
    lines = [json.loads(x) for x in (tmp_path / "b" / "log.jsonl").read_text().splitlines()]
    assert [x["iteration"] for x in lines] == [0, 1] and lines[1]["env_steps"] > lines[0]["env_steps"] > 0


def test_config_errors_name_the_fix(diffusion_base, demo_root, tmp_path) -> None:
    from lerobot_dcdp.train.finetune_rl import RLConfig, finetune, load_corrector

    with pytest.raises(ValueError, match="training seeds .* lower --seed"):
        RLConfig(seed=99_990, iterations=2, envs=8)
    with pytest.raises(ValueError, match="reward must be one of"):
        RLConfig(reward="dense")
    with pytest.raises(FileNotFoundError, match="run without --resume first"):
        finetune(RLConfig(output_dir=str(tmp_path / "none")), resume=True)
    paper = make_dcdp_policy(diffusion_base, demo_root, correction="reconstruct")
    paper.save_pretrained(tmp_path / "paper")
    with pytest.raises(ValueError, match="fine-tunes a residual head"):
        load_corrector(tmp_path / "paper")


@pytest.mark.slow
def test_the_command_on_a_stock_lerobot_env_and_its_checkpoint_under_lerobot_eval(
    diffusion_base, demo_root, tmp_path
) -> None:
    """``dcdp-finetune-rl`` on LeRobot's own ``pusht`` env (any env with a reward), then the stock
    lerobot-eval runs the checkpoint with --policy.path."""
    start = _residual_corrector(diffusion_base, demo_root, tmp_path / "start")
    command = [
        str(BIN / "dcdp-finetune-rl"),
        f"--policy={start}",
        f"--output-dir={tmp_path / 'rl'}",
        "--iterations=1",
        "--envs=2",
        "--max-steps=8",
        "--env.type=pusht",
    ]
    bad = subprocess.run([*command, "--bogus=1"], capture_output=True, text=True, timeout=600, env=ENV)
    assert bad.returncode != 0 and "unrecognized arguments: --bogus=1" in bad.stderr
    proc = run([*command, "--env.obs_type=environment_state_agent_pos"], cwd=tmp_path)
    assert "load it with --policy.path" in proc.stdout
    ckpt = tmp_path / "rl" / "checkpoints" / "last" / "pretrained_model"
    _evaluate_one_episode(ckpt, "--env.type=pusht_perturbed", "--env.perturbation=constant", cwd=tmp_path)
