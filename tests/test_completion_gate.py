"""The completion gate: labels from demonstrations, the gated action, and ``dcdp-fit-completion-gate``."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.model.completion_gate import (
    build_gate,
    completion_labels,
    gate_applies,
    gated_action,
    travel_scale,
)
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors


def test_labels_mark_the_frames_near_their_episodes_last_frame() -> None:
    # two episodes of one keypoint pair each moving along x: 0, 15, 30 then 100, 95, 60, 50
    xs = torch.tensor([0.0, 15.0, 30.0, 100.0, 95.0, 60.0, 50.0])
    points = torch.stack([torch.stack([xs, torch.zeros(7)], -1), torch.stack([xs, torch.ones(7)], -1)], 1)
    episodes = torch.tensor([3, 3, 3, 7, 7, 7, 7])
    near = completion_labels(points, episodes, radius=20.0)
    assert near.tolist() == [False, True, True, False, False, True, True]
    with pytest.raises(ValueError, match="radius"):
        completion_labels(points, episodes, radius=0.0)
    with pytest.raises(ValueError, match="episode_index"):
        completion_labels(points, episodes[:3], radius=1.0)


def test_travel_scale_is_the_median_episodes_farthest_distance_to_its_end() -> None:
    # farthest distances to the end: 30 (episode 3), 50 (episode 7), 10 (episode 9) -> median 30
    xs = torch.tensor([0.0, 15.0, 30.0, 100.0, 95.0, 60.0, 50.0, 4.0, 14.0, 10.0, 4.0])
    points = torch.stack([xs, torch.zeros(11)], -1)[:, None]
    episodes = torch.tensor([3, 3, 3, 7, 7, 7, 7, 9, 9, 9, 9])
    assert travel_scale(points, episodes) == pytest.approx(30.0)
    # a fraction of it labels the same frames whatever the unit (pixels or metres)
    for unit in (1.0, 0.001):
        near = completion_labels(points * unit, episodes, 0.6 * travel_scale(points * unit, episodes))
        assert near.tolist() == [False, True, True, False, False, True, True, True, True, True, True]
    with pytest.raises(ValueError, match="does not move"):
        travel_scale(torch.zeros(4, 1, 2), torch.tensor([0, 0, 1, 1]))


def test_gated_action_keeps_the_plan_where_near() -> None:
    plan, action = torch.zeros(3, 2), torch.ones(3, 2)
    out = gated_action(plan, action, torch.tensor([1.0, 0.0, 0.25]))
    torch.testing.assert_close(out, torch.tensor([[0.0, 0.0], [1.0, 1.0], [0.75, 0.75]]))
    chunk = gated_action(torch.zeros(3, 4, 2), torch.ones(3, 4, 2), torch.tensor([1.0, 0.0, 0.25]))
    torch.testing.assert_close(chunk[:, 2], out)  # every step of a chunk scaled alike


def _gated_policy(diffusion_base, demo_root, bias: float):
    policy = make_dcdp_policy(
        diffusion_base,
        demo_root,
        correction="residual",
        latent_dim=4,
        n_action_steps=4,
        anchor_feature="observation.environment_state",
        completion_gate=True,
    ).eval()
    torch.manual_seed(1)
    with torch.no_grad():  # a corrector that moves the plan
        for p in policy.corrector.residual.parameters():
            p.add_(0.05 * torch.randn_like(p))
        last = policy.completion_gate.net[-1]
        last.weight.zero_()
        last.bias.fill_(bias)  # p(near) = sigmoid(bias) everywhere
    return policy


def _episode(policy, observations) -> tuple[torch.Tensor, torch.Tensor]:
    """Actions and the base's planned actions at the same steps."""
    torch.manual_seed(3)
    policy.reset()
    actions, plans = [], []
    for o in observations:
        actions.append(policy.select_action(dict(o)))
        plans.append(policy.planned_chunk[:, policy.last_step].clone())
    return torch.stack(actions), torch.stack(plans)


def test_a_gate_that_says_done_runs_the_plan_and_one_that_says_not_corrects(diffusion_base, demo_root):
    near = _gated_policy(diffusion_base, demo_root, bias=30.0)
    far = _gated_policy(diffusion_base, demo_root, bias=-30.0)
    pre, _ = make_dcdp_pre_post_processors(near.config)
    observations = [pre(dict(o)) for o in env_observations(2, 10)]
    actions, plans = _episode(near, observations)
    torch.testing.assert_close(actions, plans)
    far_actions, far_plans = _episode(far, observations)
    torch.testing.assert_close(far_plans, plans)  # same base, same plans
    far.completion_gate = None  # the same corrector ungated
    ungated, _ = _episode(far, observations)
    torch.testing.assert_close(far_actions, ungated, atol=1e-6, rtol=0)
    assert (ungated - plans).abs().max() > 1e-3  # the corrector does correct


def test_fit_cli_writes_a_corrector_whose_gate_knows_the_episode_ends(diffusion_base, demo_root, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.train.fit_completion_gate import gate_data, main

    policy = make_dcdp_policy(
        diffusion_base,
        demo_root,
        correction="residual",
        latent_dim=4,
        anchor_feature="observation.environment_state",
    )
    src = tmp_path / "corrector"
    policy.save_pretrained(src)
    out = tmp_path / "gated"
    argv = ["--policy", str(src), "--repo-id", "local/test", "--root", str(demo_root), "--out", str(out)]
    main([*argv, "--steps", "1500", "--radius", "30", "--val-fraction", "0"])  # two episodes: fit both
    loaded = DCDPPolicy.from_pretrained(str(out))
    assert loaded.config.completion_gate and loaded.config.completion_radius == 30
    assert loaded.config.lead_steps == policy.config.n_action_steps  # the scene lead by default
    assert json.loads((out / "config.json").read_text())["base_policy_path"] != str(diffusion_base)
    for name, tensor in policy.corrector.state_dict().items():  # the corrector itself unchanged
        torch.testing.assert_close(loaded.corrector.state_dict()[name], tensor)
    x, episodes, points = gate_data(loaded, LeRobotDataset("local/test", root=demo_root))
    near = completion_labels(points, episodes, 30.0)
    assert 0 < near.float().mean() < 1
    with torch.no_grad():
        guess = loaded.completion_gate.logit(x) > 0
    # it learned the demonstrations' end, not a constant: right on most frames of both kinds
    assert guess[near].float().mean() > 0.8 and (~guess[~near]).float().mean() > 0.8
    with pytest.raises(SystemExit, match="exists"):
        main(argv)
    # by default the radius is a fraction of the demonstrations' own travel, recorded in the config
    main(
        [
            *argv[:-1],
            str(tmp_path / "gated_default"),
            "--steps",
            "10",
            "--val-fraction",
            "0",
            "--lead-steps",
            "0",
        ]
    )
    recorded = DCDPPolicy.from_pretrained(str(tmp_path / "gated_default")).config
    assert recorded.completion_radius == pytest.approx(0.15 * travel_scale(points, episodes))
    assert recorded.lead_steps == 0
    with pytest.raises(SystemExit, match="lead-steps must be >= 0"):
        main([*argv[:-1], str(tmp_path / "bad"), "--lead-steps", "-1"])
    with pytest.raises(SystemExit, match="radius-fraction"):
        main([*argv[:-1], str(tmp_path / "bad"), "--radius-fraction", "1.5"])


def _moved(policy, observation: dict, dx: float) -> dict:
    """``observation`` (normalised) with the block's keypoints moved ``dx`` raw units along x."""
    key = "observation.environment_state"
    raw = policy.normalizer(key, observation[key], inverse=True)
    shift = torch.tensor([dx, 0.0]).repeat(raw.shape[-1] // 2)
    return {**observation, key: policy.normalizer(key, raw + shift)}


def test_the_gate_leaves_the_anchoring_as_planned_where_near(diffusion_base, demo_root) -> None:
    near, far = (_gated_policy(diffusion_base, demo_root, bias) for bias in (30.0, -30.0))
    pre, _ = make_dcdp_pre_post_processors(near.config)
    first = pre(dict(env_observations(2, 1)[0]))
    for policy in (near, far):
        policy.config.execution = "object_anchored"
    outputs = {}
    for name, policy, gate_on in (("near", near, True), ("far", far, True), ("near_off", near, False)):
        policy.config.completion_gate = gate_on
        policy.reset()
        torch.manual_seed(0)
        policy.select_action(dict(first))
        action = policy.select_action(_moved(policy, first, 10.0))
        plan = policy.planned_chunk[:, 1]
        outputs[name] = (policy.normalizer("action", action, inverse=True), plan)
    # the block moved +10 px since plan time: far from completion the rule carries the plan +10 px along x
    action, plan = outputs["far"]
    want = near.normalizer("action", plan, inverse=True) + torch.tensor([10.0, 0.0])
    torch.testing.assert_close(action, want, atol=1e-3, rtol=0)
    # near completion the plan runs as planned (same base, same seed: the same plan)
    action, plan = outputs["near"]
    torch.testing.assert_close(plan, outputs["far"][1])
    torch.testing.assert_close(action, near.normalizer("action", plan, inverse=True), atol=1e-3, rtol=0)
    # completion_gate=false on a folder with a gate: the plain rule, gate or not
    torch.testing.assert_close(outputs["near_off"][0], want, atol=1e-3, rtol=0)


def test_fit_cli_around_a_bare_base_writes_a_gated_anchoring_folder(
    diffusion_base, demo_root, tmp_path
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.model.scene_lead import tracker_noise
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors
    from lerobot_dcdp.train.fit_completion_gate import gate_data, main

    key = "observation.environment_state"
    data = ["--repo-id", "local/test", "--root", str(demo_root)]
    out = tmp_path / "anchored"
    argv = ["--base", str(diffusion_base), "--anchor-feature", key, *data, "--out", str(out)]
    main([*argv, "--steps", "1500", "--radius", "30", "--val-fraction", "0"])
    loaded = DCDPPolicy.from_pretrained(str(out)).eval()
    cfg = loaded.config
    assert cfg.execution == "object_anchored" and cfg.anchor_feature == key
    assert cfg.n_action_steps == 8  # the base's own
    assert (cfg.lead_steps, cfg.lead_window) == (8, 16)  # the scene lead: one executed chunk
    assert cfg.completion_gate and cfg.completion_radius == 30
    assert json.loads((out / "config.json").read_text())["base_policy_path"] != str(diffusion_base)
    assert (out / "policy_preprocessor.json").is_file() and (out / "policy_postprocessor.json").is_file()
    # the gate learned the demonstrations' end
    x, episodes, points = gate_data(loaded, LeRobotDataset("local/test", root=demo_root))
    near = completion_labels(points, episodes, 30.0)
    with torch.no_grad():
        guess = loaded.completion_gate.logit(x) > 0
    assert guess[near].float().mean() > 0.8 and (~guess[~near]).float().mean() > 0.8
    assert cfg.lead_noise == tracker_noise(points, episodes)  # the lead's noise from the same frames
    # completion_gate=false (e.g. --policy.completion_gate=false) loads the folder and runs the gate off
    off = cfg.__class__.from_pretrained(str(out))
    off.completion_gate = False
    unplugged = DCDPPolicy.from_pretrained(str(out), config=off)
    assert unplugged.completion_gate is not None and not unplugged.gate_applies
    assert loaded.gate_applies
    # its corrector never trained: run as dcdp it is exactly the base's plan
    pre, _ = make_dcdp_pre_post_processors(cfg)
    cfg.execution = "dcdp"
    loaded.reset()
    torch.manual_seed(0)
    for o in env_observations(2, 6):
        action = loaded.select_action(pre(dict(o)))
        torch.testing.assert_close(action, loaded.planned_chunk[:, loaded.last_step])
    # one clear error for each bad call, and nothing written
    for bad, message in (
        (["--base", str(diffusion_base), *data], "--anchor-feature"),
        (["--base", str(diffusion_base), "--anchor-feature", "observation.nope", *data], "observation.nope"),
        (["--policy", str(out), "--anchor-feature", key, *data], "go with --base"),
        (["--base", str(diffusion_base), "--anchor-feature", key, *data, "--n-action-steps", "99"], "--base"),
        (
            [
                "--base",
                str(diffusion_base),
                "--anchor-feature",
                key,
                "--repo-id",
                "x",
                "--root",
                str(tmp_path),
            ],
            "--root",
        ),
    ):
        with pytest.raises(SystemExit, match=message):
            main([*bad, "--out", str(tmp_path / "bad"), "--steps", "1"])
        assert not (tmp_path / "bad").exists()


def test_a_fitted_gate_is_built_and_applies_only_where_on_and_moving_the_plan() -> None:
    from types import SimpleNamespace

    dims = {"observation.environment_state": 4}
    for on, radius, built in ((True, None, True), (False, 20.0, True), (False, None, False)):
        config = SimpleNamespace(completion_gate=on, completion_radius=radius)
        assert (build_gate(config, dims) is not None) == built
    gate = build_gate(SimpleNamespace(completion_gate=True, completion_radius=None), dims)
    for execution, on, applies in (
        ("dcdp", True, True),
        ("object_anchored", True, True),
        ("open_loop", True, False),
        ("closed_loop", True, False),
        ("object_anchored", False, False),
    ):
        assert gate_applies(gate, SimpleNamespace(completion_gate=on, execution=execution)) == applies
    assert not gate_applies(None, SimpleNamespace(completion_gate=True, execution="dcdp"))
