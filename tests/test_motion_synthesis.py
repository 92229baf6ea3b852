"""Stage 1 on plain demonstrations: synthesised object motion (pure math) and the residual loss on it."""

from __future__ import annotations

import itertools
import math

import pytest
import torch
from helpers import make_dcdp_policy, training_batches

from lerobot_dcdp.model.correction import anchor_actions, rigid_fit_2d
from lerobot_dcdp.model.motion_synthesis import draw_motions, keypoint_extent, move_window

KEY = "observation.environment_state"


def test_move_window_is_identity_at_plan_time_and_constant_velocity_around_it() -> None:
    g = torch.Generator().manual_seed(0)
    kp = torch.rand(3, 8, 4, 2, generator=g, dtype=torch.float64) * 400
    plan_index = torch.tensor([7, 4, 0])
    velocity = torch.tensor([[2.0, 0.0], [0.0, -1.5], [1.0, 1.0]], dtype=torch.float64)
    turn = torch.zeros(3, dtype=torch.float64)
    moved, rot, t = move_window(kp, plan_index, velocity, turn)
    for b in range(3):
        torch.testing.assert_close(moved[b, plan_index[b]], kp[b, plan_index[b]])
        for j in range(8):
            expected = kp[b, j] + (j - plan_index[b]) * velocity[b]
            torch.testing.assert_close(moved[b, j], expected)
    # the label's motion is the one of the last frame: (7 - plan_index) steps of velocity
    torch.testing.assert_close(rot, torch.eye(2, dtype=torch.float64).expand(3, 2, 2))
    torch.testing.assert_close(t, (7 - plan_index).unsqueeze(-1).double() * velocity)


def test_rotation_turns_about_the_plan_time_centroid_and_the_label_is_the_fitted_motion() -> None:
    kp = torch.tensor([[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]], dtype=torch.float64)
    kp = kp.unsqueeze(1).repeat(1, 5, 1, 1) + 100.0  # a still square, 5 frames
    rate = math.radians(3.0)
    moved, rot, t = move_window(
        kp, torch.tensor([2]), torch.tensor([[1.0, -2.0]]).double(), torch.tensor([rate], dtype=torch.float64)
    )
    # rigid: distances between keypoints unchanged; the centroid moves by j * v only
    for j in range(5):
        torch.testing.assert_close(torch.cdist(moved[0, j], moved[0, j]), torch.cdist(kp[0, j], kp[0, j]))
        torch.testing.assert_close(
            moved[0, j].mean(0), kp[0, j].mean(0) + (j - 2) * torch.tensor([1.0, -2.0]).double()
        )
    # what the object_anchored rule would estimate from plan time to now is the label's motion
    r_fit, t_fit = rigid_fit_2d(kp[:, 2], moved[:, -1])
    torch.testing.assert_close(r_fit, rot)
    torch.testing.assert_close(t_fit, t)
    assert math.isclose(math.atan2(rot[0, 1, 0].item(), rot[0, 0, 0].item()), 2 * rate, rel_tol=1e-9)
    action = torch.tensor([[120.0, 90.0]], dtype=torch.float64)
    torch.testing.assert_close(anchor_actions(action, rot, t), anchor_actions(action, r_fit, t_fit))


def test_draw_motions_respects_ranges_and_the_static_share() -> None:
    g = torch.Generator().manual_seed(1)
    v, w = draw_motions(4000, 2.5, 0.1, 0.25, generator=g)
    speed = v.norm(dim=-1)
    assert speed.max() <= 2.5 + 1e-6 and w.abs().max() <= 0.1 + 1e-7
    still = (speed == 0) & (w == 0)
    assert 0.2 < still.float().mean() < 0.3
    angles = torch.atan2(v[~still, 1], v[~still, 0])
    assert (angles > 0).float().mean() == pytest.approx(0.5, abs=0.05)  # every direction
    v0, w0 = draw_motions(50, 2.5, 0.1, 1.0, generator=g)
    assert not v0.any() and not w0.any()
    v1, _ = draw_motions(10, 2.5, 0.1, 0.25, generator=torch.Generator().manual_seed(3))
    v2, _ = draw_motions(10, 2.5, 0.1, 0.25, generator=torch.Generator().manual_seed(3))
    torch.testing.assert_close(v1, v2)


def test_keypoint_extent_from_min_max_or_std() -> None:
    stats = {"min": torch.tensor([0.0, 10.0, 5.0, 0.0]), "max": torch.tensor([100.0, 20.0, 50.0, 400.0])}
    assert keypoint_extent(stats) == 400.0
    assert keypoint_extent({"std": torch.tensor([1.0, 2.0])}) == 8.0
    with pytest.raises(ValueError, match="motion_max_speed"):
        keypoint_extent({})


# ---------------------------------------------------------------- the residual loss on plain demonstrations
def _policy(diffusion_base, demo_root, **overrides):
    return make_dcdp_policy(
        diffusion_base,
        demo_root,
        correction="residual",
        anchor_feature=KEY,
        observation_features=[KEY],
        **overrides,
    )


def test_still_scenes_keep_the_plan_and_moving_ones_move_it(diffusion_base, demo_root) -> None:
    policy = _policy(diffusion_base, demo_root, motion_static_fraction=1.0)
    batch = next(training_batches(policy, demo_root, batch_size=8))
    policy.train()
    torch.manual_seed(0)
    _, info = policy.forward(batch)
    assert info["synthesised"] == 1.0 and info["plan_gap"] == 0.0
    policy.config.motion_static_fraction = 0.0
    policy.config.motion_max_speed = 5.0
    _, info = policy.forward(batch)
    assert info["plan_gap"] > 0.0


@pytest.mark.parametrize("label", ["observed", "added", "graded"])
def test_synthesised_target_carries_the_plan_with_the_object(diffusion_base, demo_root, label) -> None:
    """What the loss trains toward: the demonstration's action at t carried along with the object's rigid
    motion since plan time -- ``observed``: the whole motion the moved keypoints show (the object_anchored
    rule, pushes included); ``added``: only the synthesised motion (between the demonstration's frame t and
    the moved one); ``graded``: the ``added`` target moved toward the ``observed`` one by the share of the
    way the synthesised motion carried the centroid toward ``motion_full_carry_at``."""
    policy = _policy(
        diffusion_base,
        demo_root,
        motion_static_fraction=0.0,
        motion_max_speed=4.0,
        motion_max_turn_deg=2.0,
        motions_per_sample=2,
        motion_label=label,
        motion_full_carry_at=10.0,
    )
    batch = next(training_batches(policy, demo_root, batch_size=6))
    torch.manual_seed(3)
    sample = policy.corrector.samples.synthesised(batch)
    moved, plan, step, target, valid = sample.batch, sample.plan, sample.step, sample.target, sample.valid
    assert plan.shape == (12, 8, 2) and step.shape == (12,) and target.shape == (12, 2)
    assert valid.all()
    kp = policy.normalizer(KEY, moved[KEY], inverse=True)
    kp = kp.reshape(*kp.shape[:2], -1, 2)
    rows = torch.arange(12)
    k = kp.shape[1]
    original = batch[KEY].repeat_interleave(2, 0)
    before = policy.normalizer(KEY, original, inverse=True).reshape(kp.shape)
    added = rigid_fit_2d(before[:, -1], kp[:, -1])
    assert ((added[1].norm(dim=-1) > 1e-3) == (step > 0)).all()  # no motion yet at the plan's own step
    raw = policy.normalizer("action", plan[rows, step], inverse=True)
    with_added = anchor_actions(raw, *added)
    with_whole = anchor_actions(raw, *rigid_fit_2d(kp[rows, k - 1 - step], kp[:, -1]))
    share = {"added": torch.zeros(12), "observed": torch.ones(12)}.get(label)
    if share is None:
        share = ((kp[:, -1].mean(1) - before[:, -1].mean(1)).norm(dim=-1) / 10.0).clamp(0, 1)
        assert (share > 0.05).any() and (share < 0.95).any() and (share[step == 0] == 0).all()
    expected = policy.normalizer("action", with_added + share.unsqueeze(-1) * (with_whole - with_added))
    torch.testing.assert_close(target, expected, atol=1e-4, rtol=1e-4)
    if label == "graded":  # a share strictly between the two labels where the push moved the object
        assert not torch.allclose(target, policy.normalizer("action", with_whole), atol=1e-4)
    # the plan's step s is the demonstration's action at t (index H-1 of actions t-H+1 .. t+H-1)
    actions = batch["action"].repeat_interleave(2, 0)
    torch.testing.assert_close(plan[rows, step], actions[:, 7])
    # the plan-time frame is the demonstration's own
    torch.testing.assert_close(moved[KEY][rows, k - 1 - step], original[rows, k - 1 - step])


def test_motions_slower_than_the_carry_speed_keep_the_plan(diffusion_base, demo_root) -> None:
    """``motion_min_carry_speed``: a sample whose synthesised speed (the centroid's shift per step since plan
    time) is below it is labelled with the plan itself, as a still scene; a faster one with the plan carried
    along with the object's whole observed motion, as without the option."""
    policy = _policy(
        diffusion_base,
        demo_root,
        motion_static_fraction=0.0,
        motion_max_speed=4.0,
        motion_max_turn_deg=0.0,
        motions_per_sample=4,
        motion_min_carry_speed=2.0,
    )
    batch = next(training_batches(policy, demo_root, batch_size=6))
    torch.manual_seed(3)
    sample = policy.corrector.samples.synthesised(batch)
    step, target = sample.step, sample.target
    kp = policy.normalizer(KEY, sample.batch[KEY], inverse=True)
    kp = kp.reshape(*kp.shape[:2], -1, 2)
    before = policy.normalizer(KEY, batch[KEY].repeat_interleave(4, 0), inverse=True).reshape(kp.shape)
    rows, k = torch.arange(24), kp.shape[1]
    speed = (kp[:, -1].mean(1) - before[:, -1].mean(1)).norm(dim=-1) / step.clamp_min(1)
    slow, fast = (step > 0) & (speed < 2.0), (step > 0) & (speed >= 2.0)
    assert slow.any() and fast.any()
    raw = policy.normalizer("action", sample.plan[rows, step], inverse=True)
    whole = anchor_actions(raw, *rigid_fit_2d(kp[rows, k - 1 - step], kp[:, -1]))
    expected = torch.where(fast.unsqueeze(-1), whole, raw)
    torch.testing.assert_close(target, policy.normalizer("action", expected), atol=1e-4, rtol=1e-4)
    assert not torch.allclose(target[fast], sample.plan[rows, step][fast], atol=1e-3)


def test_the_corrector_learns_to_follow_synthesised_motion(diffusion_base, demo_root) -> None:
    policy = _policy(diffusion_base, demo_root, motion_max_speed=4.0, optimizer_lr=3e-3)
    optimizer = policy.config.get_optimizer_preset().build(policy.get_optim_params())
    policy.train()
    torch.manual_seed(0)
    gaps, losses = [], []
    for batch in itertools.islice(training_batches(policy, demo_root, batch_size=32), 150):
        loss, info = policy.forward(batch)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        gaps.append(info["plan_gap"])
        losses.append(info["recon_loss"])
    # a fresh head is open loop (loss == plan gap); after training it explains most of the motion
    assert losses[0] == pytest.approx(gaps[0], rel=1e-5)
    assert sum(losses[-20:]) < 0.5 * sum(gaps[-20:])


def test_plain_demonstrations_without_an_anchor_name_the_fix(diffusion_base, demo_root) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual")
    batch = next(training_batches(policy, demo_root, batch_size=4))
    with pytest.raises(ValueError, match="--policy.anchor_feature=") as err:
        policy.forward(batch)
    assert "dcdp-record-corrections" in str(err.value) and "dcdp_paper.json" in str(err.value)


def test_synthesis_refuses_an_anchor_the_corrector_does_not_read(diffusion_base, demo_root) -> None:
    policy = make_dcdp_policy(
        diffusion_base,
        demo_root,
        correction="residual",
        anchor_feature=KEY,
        observation_features=["observation.state"],
    )
    batch = next(training_batches(policy, demo_root, batch_size=4))
    with pytest.raises(ValueError, match="observation_features"):
        policy.forward(batch)


def test_late_chunks_are_synthesised_from_an_older_plan_time_frame(diffusion_base, demo_root) -> None:
    """``train_max_delay``: a sample's chunk was planned d steps before it started being executed, so its
    plan-time frame is t-s-d (where the synthesised motion is the identity and the label's motion starts),
    the step is still s, and the loss reads its reference there."""
    policy = _policy(
        diffusion_base,
        demo_root,
        motion_static_fraction=0.0,
        motion_max_speed=4.0,
        motions_per_sample=4,
        train_max_delay=3,
    )
    assert policy.config.observation_delta_indices == list(range(-10, 1))  # K = max(M, H + 3) = 11
    batch = next(training_batches(policy, demo_root, batch_size=16))
    torch.manual_seed(0)
    sample = policy.corrector.samples.synthesised(batch)
    delay = sample.age - sample.step
    assert (delay >= 0).all() and (delay <= 3).all() and len(set(delay.tolist())) == 4  # every delay drawn
    kp = policy.normalizer(KEY, sample.batch[KEY], inverse=True)
    kp = kp.reshape(*kp.shape[:2], -1, 2)
    rows, k = torch.arange(len(delay)), kp.shape[1]
    original = policy.normalizer(KEY, batch[KEY].repeat_interleave(4, 0), inverse=True).reshape(kp.shape)
    then = k - 1 - sample.age
    torch.testing.assert_close(kp[rows, then], original[rows, then])  # identity at the plan-time frame
    moved_one_later = kp[rows, (then + 1).clamp_max(k - 1)] - original[rows, (then + 1).clamp_max(k - 1)]
    assert (moved_one_later.norm(dim=-1).amax(-1)[sample.age > 0] > 1e-4).all()  # the motion starts there
    rot, t = rigid_fit_2d(kp[rows, then], kp[:, -1])
    raw = policy.normalizer("action", sample.plan[rows, sample.step], inverse=True)
    expected = policy.normalizer("action", anchor_actions(raw, rot, t))
    torch.testing.assert_close(sample.target, expected, atol=1e-4, rtol=1e-4)
    # the executed entry s of a late demonstration chunk is still the demonstration's action at t
    torch.testing.assert_close(sample.plan[rows, sample.step], batch["action"].repeat_interleave(4, 0)[:, 7])
    loss, _ = policy.forward(batch)
    assert torch.isfinite(loss)
