"""Object anchoring (pure math and execution mode), recorded corrections, and the residual corrector."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers import env_observations, make_dcdp_policy, training_batches

from lerobot_dcdp.model.correction import (
    action_range,
    anchor_actions,
    check_normalization,
    normalize,
    rigid_fit_2d,
    unnormalize,
)


def _rotation(deg: float) -> torch.Tensor:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return torch.tensor([[c, -s], [s, c]], dtype=torch.float64)


# ---------------------------------------------------------------- pure math
def test_rigid_fit_recovers_known_motions() -> None:
    g = torch.Generator().manual_seed(0)
    p = torch.rand(4, 8, 2, generator=g, dtype=torch.float64) * 300
    angles, shifts = [0.0, 30.0, -90.0, 179.0], torch.tensor([[0, 0], [5, -3], [-40, 12], [1.5, 2.5]])
    rot = torch.stack([_rotation(a) for a in angles])
    q = p @ rot.transpose(1, 2) + shifts.unsqueeze(1).double()
    r_hat, t_hat = rigid_fit_2d(p, q)
    torch.testing.assert_close(r_hat, rot, atol=1e-9, rtol=0)
    torch.testing.assert_close(t_hat, shifts.double(), atol=1e-9, rtol=0)
    # a planned action moves with the object: (100, 50) rotated by 30 degrees about the origin, then shifted
    a = torch.tensor([[100.0, 50.0]] * 4, dtype=torch.float64)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    expected = torch.tensor([100 * c - 50 * s + 5, 100 * s + 50 * c - 3], dtype=torch.float64)
    torch.testing.assert_close(anchor_actions(a, r_hat, t_hat)[1], expected)
    torch.testing.assert_close(anchor_actions(a, r_hat, t_hat)[0], a[0])
    torch.testing.assert_close(
        anchor_actions(a.unsqueeze(1), r_hat, t_hat)[:, 0], anchor_actions(a, r_hat, t_hat)
    )


def test_rigid_fit_is_identity_for_a_still_object_and_least_squares_under_noise() -> None:
    p = torch.rand(3, 8, 2, dtype=torch.float64) * 500
    r_hat, t_hat = rigid_fit_2d(p, p.clone())
    torch.testing.assert_close(r_hat, torch.eye(2, dtype=torch.float64).expand(3, 2, 2), atol=1e-12, rtol=0)
    torch.testing.assert_close(t_hat, torch.zeros(3, 2, dtype=torch.float64), atol=1e-9, rtol=0)
    chunk = torch.rand(3, 8, 3, dtype=torch.float64)
    torch.testing.assert_close(anchor_actions(chunk, r_hat, t_hat), chunk, atol=1e-9, rtol=0)
    # noisy target: the fitted motion's residual is no larger than that of the true motion
    q = p @ _rotation(10).T + torch.tensor([3.0, 4.0], dtype=torch.float64)
    q_noisy = q + 0.5 * torch.randn_like(q)
    r_hat, t_hat = rigid_fit_2d(p, q_noisy)
    fit = ((p @ r_hat.transpose(1, 2) + t_hat.unsqueeze(1) - q_noisy) ** 2).sum()
    true = ((q - q_noisy) ** 2).sum()
    assert fit <= true + 1e-9


def test_anchor_actions_keeps_extra_dims_and_rejects_bad_shapes() -> None:
    rot, t = _rotation(90).expand(1, 2, 2), torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    out = anchor_actions(torch.tensor([[1.0, 0.0, 7.0]], dtype=torch.float64), rot, t)
    torch.testing.assert_close(out, torch.tensor([[1.0, 3.0, 7.0]], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"\(B, N, 2\)"):
        rigid_fit_2d(torch.zeros(2, 4, 3), torch.zeros(2, 4, 3))


@pytest.mark.parametrize("mode", ["MIN_MAX", "MEAN_STD", "IDENTITY", "QUANTILES", "QUANTILE10"])
def test_normalize_round_trip(mode: str) -> None:
    stats = {
        "min": torch.tensor([0.0, 10.0]),
        "max": torch.tensor([512.0, 30.0]),
        "mean": torch.tensor([256.0, 20.0]),
        "std": torch.tensor([100.0, 2.0]),
        "q01": torch.tensor([10.0, 11.0]),
        "q99": torch.tensor([500.0, 29.0]),
        "q10": torch.tensor([50.0, 12.0]),
        "q90": torch.tensor([450.0, 28.0]),
    }
    x = torch.tensor([[0.0, 10.0], [512.0, 30.0], [100.0, 25.0]])
    torch.testing.assert_close(unnormalize(normalize(x, stats, mode), stats, mode), x)
    if mode == "MIN_MAX":
        torch.testing.assert_close(normalize(x, stats, mode)[:2], torch.tensor([[-1.0, -1.0], [1.0, 1.0]]))
    if mode == "QUANTILES":  # LeRobot's rule: q01 -> -1, q99 -> 1
        q = torch.stack([stats["q01"], stats["q99"]])
        torch.testing.assert_close(normalize(q, stats, mode), torch.tensor([[-1.0, -1.0], [1.0, 1.0]]))
        # the action range of a quantile-normalised base is its recorded min/max, normalised the same way
        lo, hi = action_range(stats, mode, 2)
        torch.testing.assert_close(lo, normalize(stats["min"], stats, mode))
        torch.testing.assert_close(hi, normalize(stats["max"], stats, mode))
    with pytest.raises(ValueError, match="SOMETHING_ELSE"):
        normalize(x, stats, "SOMETHING_ELSE")
    with pytest.raises(ValueError, match="'observation.x'.*SOMETHING_ELSE"):
        check_normalization("observation.x", "SOMETHING_ELSE", stats)
    if mode == "QUANTILE10":
        with pytest.raises(ValueError, match=r"lack \['q10'\]"):
            check_normalization("action", mode, {"q90": stats["q90"]})


def test_anchored_labels_follow_the_block_with_lookahead() -> None:
    from lerobot_dcdp.data.corrections import anchored_labels

    kp0 = np.random.default_rng(0).uniform(100, 400, (8, 2))
    # the block translates by (2, -1) per step; 5 observations (4 steps + the final one)
    kps = np.stack([kp0 + np.array([2.0, -1.0]) * t for t in range(5)])
    plans = np.repeat(np.arange(8 * 2, dtype=np.float32).reshape(1, 8, 2), 4, axis=0)
    steps = np.array([0, 1, 2, 0])  # the last frame starts a new chunk
    got = anchored_labels(plans, steps, kps, lookahead=0)
    expected = plans[np.arange(4), steps] + np.array([[0, 0], [2, -1], [4, -2], [0, 0]])
    np.testing.assert_allclose(got, expected, atol=1e-4)
    got = anchored_labels(plans, steps, kps, lookahead=2)  # frame 3 looks at kp[4] (clamped end), plan at 3
    expected = plans[np.arange(4), steps] + np.array([[4, -2], [6, -3], [8, -4], [2, -1]])
    np.testing.assert_allclose(got, expected, atol=1e-4)
    with pytest.raises(ValueError, match="starts before the episode"):
        anchored_labels(plans, np.array([1, 2, 3, 4]), kps, 0)
    # a late chunk (delay 1 on the last two frames): planned one observation earlier, carried one step more
    got = anchored_labels(plans, steps, kps, lookahead=0, delays=np.array([0, 0, 0, 1]))
    expected = plans[np.arange(4), steps] + np.array([[0, 0], [2, -1], [4, -2], [2, -1]])
    np.testing.assert_allclose(got, expected, atol=1e-4)
    with pytest.raises(ValueError, match="plan_step \\+ delay"):
        anchored_labels(plans, steps, kps, 0, delays=np.array([1, 0, 0, 0]))


def test_drift_offset_labels_add_only_the_applied_drift() -> None:
    from lerobot_dcdp.data.corrections import drift_offset_labels

    plans = np.repeat(np.arange(8 * 2, dtype=np.float32).reshape(1, 8, 2), 5, axis=0)
    steps = np.array([0, 1, 2, 0, 1])  # the fourth frame starts a new chunk
    offsets = np.array([[1.0, 0.0], [0.0, 2.0], [3.0, 0.0], [0.0, 0.0], [5.0, 5.0]])
    plan_s = plans[np.arange(5), steps]
    # obs t has seen offsets 0..t-1, since the plan's observation t - s
    got = drift_offset_labels(plans, steps, offsets, lookahead=0)
    np.testing.assert_allclose(got - plan_s, [[0, 0], [1, 0], [1, 2], [0, 0], [0, 0]])
    # lookahead 1 adds the step the action acts in; the end is clamped to the last observation
    got = drift_offset_labels(plans, steps, offsets, lookahead=1)
    np.testing.assert_allclose(got - plan_s, [[1, 0], [1, 2], [4, 2], [0, 0], [5, 5]])
    got = drift_offset_labels(plans, steps, offsets, lookahead=3)
    np.testing.assert_allclose(got[3] - plan_s[3], [5, 5])
    with pytest.raises(ValueError, match="one per step"):
        drift_offset_labels(plans, steps, offsets[:4], 0)
    with pytest.raises(ValueError, match="starts before the episode"):
        drift_offset_labels(plans, np.array([1, 2, 3, 4, 5]), offsets, 0)


def test_drift_offset_teacher_labels_drift_not_pushing(diffusion_base) -> None:
    """Recorded with the env: a static episode's labels are its plans even while the agent pushes the block;
    a drifting one's labels are its plans moved by exactly the drift seen since plan time."""
    from lerobot_dcdp.data.corrections import DriftSpec, load_policy, rollout_corrections

    kp = "observation.environment_state"
    policy, pre, post = load_policy(None, str(diffusion_base), "object_anchored", kp)
    none = DriftSpec("none", 0.0, 0.0, (0.0,), 25)
    drift = DriftSpec("constant", 1.5, 90.0, (90.0,), 25)
    static_ep, drift_ep = rollout_corrections(
        policy, pre, post, [11, 11], [none, drift], max_steps=12, lookahead=0, teacher="drift_offset"
    )
    for ep in (static_ep, drift_ep):
        assert len(ep["step"]) == 12 and ep["step"].max() == policy.config.n_action_steps - 1
    plan_s = static_ep["plan"][np.arange(12), static_ep["step"]]
    assert np.array_equal(static_ep["label"], plan_s)
    plan_s = drift_ep["plan"][np.arange(12), drift_ep["step"]]
    # the block starts far from the walls: every step's offset is the full (0, 1.5)
    np.testing.assert_allclose(drift_ep["label"] - plan_s, np.outer(drift_ep["step"], [0.0, 1.5]), atol=1e-4)


# ---------------------------------------------------------------- execution mode object_anchored
def _normalised(policy, n_envs: int, steps: int) -> list[dict]:
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    pre, _ = make_dcdp_pre_post_processors(policy.config)
    return [pre(dict(o)) for o in env_observations(n_envs, steps)]


def test_object_anchored_needs_an_anchor(diffusion_base, demo_root) -> None:
    with pytest.raises(ValueError, match="anchor_feature"):
        make_dcdp_policy(diffusion_base, demo_root, execution="object_anchored")
    with pytest.raises(ValueError, match="xy keypoints"):
        make_dcdp_policy(
            diffusion_base, demo_root, execution="object_anchored", anchor_feature="observation.state"
        )  # 2 values: one point only


def test_object_anchored_is_open_loop_while_the_object_stands_still_and_follows_it(
    diffusion_base, demo_root
) -> None:
    kw = dict(anchor_feature="observation.environment_state")
    anchored = make_dcdp_policy(diffusion_base, demo_root, execution="object_anchored", **kw).eval()
    plain = make_dcdp_policy(diffusion_base, demo_root, execution="open_loop", **kw).eval()
    first = _normalised(plain, 2, 1)[0]
    still = [dict(first) for _ in range(8)]
    torch.manual_seed(0)
    a = torch.stack([anchored.select_action(dict(o)) for o in still])
    torch.manual_seed(0)
    b = torch.stack([plain.select_action(dict(o)) for o in still])
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    # the block moves by +10 px in x (raw) after plan time: every later action moves by +10 px too
    key = "observation.environment_state"
    raw = anchored.normalizer(key, first[key], inverse=True)
    moved = dict(first)
    moved[key] = anchored.normalizer(key, raw + torch.tensor([10.0, 0.0]).repeat(8))
    anchored.reset()
    torch.manual_seed(0)
    anchored.select_action(dict(first))
    got = anchored.normalizer("action", anchored.select_action(moved), inverse=True)
    want = anchored.normalizer("action", anchored.planned_chunk[:, 1], inverse=True) + torch.tensor(
        [10.0, 0.0]
    )
    torch.testing.assert_close(got, want, atol=1e-3, rtol=0)


# ---------------------------------------------------------------- recorded corrections + residual corrector
def _record_drifting(diffusion_base, root, episodes: int, **kw) -> dict:
    """Tiny recording around ``diffusion_base``: every episode drifts (3 px/step at most), 24 steps each."""
    from lerobot_dcdp.data.corrections import record_corrections

    return record_corrections(
        root,
        "local/test",
        base_path=str(diffusion_base),
        episodes=episodes,
        seed=5,
        max_magnitude=3.0,
        static_fraction=0.0,
        batch_size=episodes,
        max_steps=24,
        progress=False,
        **kw,
    )


@pytest.fixture(scope="module")
def corrections_root(diffusion_base, tmp_path_factory):
    root = tmp_path_factory.mktemp("corr") / "pusht_corrections"
    assert _record_drifting(diffusion_base, root, episodes=3)["frames"] > 0
    return root


def test_recorded_corrections_hold_the_stale_plan_and_the_teacher(corrections_root) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import drift_for_seed

    ds = LeRobotDataset("local/test", root=corrections_root)
    assert {"observation.dcdp_plan", "observation.dcdp_plan_step", "action", "executed_action"} <= set(
        ds.features
    )
    assert ds.meta.total_episodes == 3
    assert all(drift_for_seed(s, 3.0, 0.0).perturbation != "none" for s in (5, 6, 7))
    plan = torch.stack([ds[i]["observation.dcdp_plan"] for i in range(24)]).reshape(24, -1, 2)  # flat (L*A,)
    step = torch.stack([ds[i]["observation.dcdp_plan_step"] for i in range(24)]).reshape(-1).long()
    action = torch.stack([ds[i]["action"] for i in range(24)])
    executed = torch.stack([ds[i]["executed_action"] for i in range(24)])
    assert step.tolist() == [t % 8 for t in range(24)]
    # within a chunk the plan is the one made at its start; the teacher executed its own labels
    assert torch.equal(plan[1], plan[0]) and not torch.equal(plan[8], plan[0])
    torch.testing.assert_close(action, executed, atol=1e-3, rtol=0)
    # at plan time the teacher takes the plan as it is; later the block has drifted and so has the label
    torch.testing.assert_close(action[0], plan[0, 0], atol=1e-3, rtol=0)
    # the block only drifts here (constant, seed 5): the label moves by the drift since plan time, s * m px
    gaps = (action - plan[torch.arange(24), step]).norm(dim=-1)
    magnitude = drift_for_seed(5, 3.0, 0.0).magnitude
    torch.testing.assert_close(gaps, step.float() * magnitude, atol=2e-3, rtol=0)


@pytest.fixture(scope="module")
def late_corrections_root(diffusion_base, tmp_path_factory):
    """Recorded with ``max_delay=3``: episode k's chunks after its first arrive k mod 4 steps late."""
    root = tmp_path_factory.mktemp("late") / "pusht_corrections"
    _record_drifting(diffusion_base, root, episodes=4, max_delay=3)
    return root


def test_late_recorded_chunks_hold_their_delay_and_labels_from_plan_time(late_corrections_root) -> None:
    """Each frame stores its chunk's delay d. The hindsight anchoring label carries the plan from the
    observation s + d steps back and equals what the policy's own anchoring executed with that late chunk
    (from its delayed plan-time keypoints); carrying from s steps back instead gives other labels."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import anchored_labels

    ds = LeRobotDataset("local/test", root=late_corrections_root)
    episodes = ds.hf_dataset["episode_index"]
    for k in range(4):
        frames = [ds[i] for i, e in enumerate(episodes) if int(e) == k]
        step = torch.stack([f["observation.dcdp_plan_step"] for f in frames]).reshape(-1).long()
        delay = torch.stack([f["observation.dcdp_plan_delay"] for f in frames]).reshape(-1).long()
        assert step.tolist() == [t % 8 for t in range(24)]
        assert delay.tolist() == [0] * 8 + [k] * 16  # the first chunk is planned on time
        action = torch.stack([f["action"] for f in frames])
        torch.testing.assert_close(
            action, torch.stack([f["executed_action"] for f in frames]), atol=1e-3, rtol=0
        )
        if k:
            plan = torch.stack([f["observation.dcdp_plan"] for f in frames]).reshape(24, -1, 2).numpy()
            kps = torch.stack([f["observation.environment_state"] for f in frames]).reshape(24, -1, 2).numpy()
            on_time = anchored_labels(plan, step.numpy(), kps, 0)  # ignoring the delay
            assert np.abs(on_time[8:] - action[8:].numpy()).max() > 0.5


def test_training_on_late_chunks_takes_each_samples_plan_time_frame(
    diffusion_base, late_corrections_root
) -> None:
    """The anchoring proposal built in the loss from the sample's plan-time frame t-s-d reproduces the
    recorded label exactly (ignoring the delay column would not); a delay above train_max_delay is refused."""
    kw = dict(anchor_input=True, anchor_feature="observation.environment_state")
    policy = _residual_policy(diffusion_base, late_corrections_root, train_max_delay=3, **kw).eval()
    batches = training_batches(policy, late_corrections_root, batch_size=64)
    for _ in range(2):
        _, parts = policy(next(batches))
        assert parts["plan_gap"] > 1e-5 and parts["anchor_gap"] < 1e-9
    short = _residual_policy(diffusion_base, late_corrections_root, **kw).eval()
    with pytest.raises(ValueError, match="train_max_delay"):
        short(next(training_batches(short, late_corrections_root, batch_size=96)))


def test_correction_stats_tabulates_label_sizes_per_delay(late_corrections_root) -> None:
    """scripts/correction_stats.py gives one row per recorded delay (0..3 here); an on-time chunk's first step
    is labelled with the plan itself (0.0 px), a late chunk's first step already carries the drift."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "correction_stats.py"
    out = subprocess.run(
        [sys.executable, str(script), str(late_corrections_root)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    rows = {
        int(line.split("|")[1]): line.split("|")
        for line in out.splitlines()
        if line[:3] in {"| 0", "| 1", "| 2", "| 3"}
    }
    assert sorted(rows) == [0, 1, 2, 3]
    first_step = {d: float(row[5].split("/")[0]) for d, row in rows.items()}
    assert first_step[0] == 0.0
    assert all(first_step[d] > 0.5 for d in (1, 2, 3))
    assert "4 episodes (0 with every label the plan)" in out


def test_record_corrections_refuses_eval_seeds_and_foreign_folders(diffusion_base, tmp_path) -> None:
    from lerobot_dcdp.data.corrections import record_corrections

    with pytest.raises(ValueError, match="evaluation seeds"):
        record_corrections(tmp_path / "x", base_path=str(diffusion_base), episodes=2, seed=99_999)
    with pytest.raises(ValueError, match="max_delay must be >= 0"):
        record_corrections(tmp_path / "x", base_path=str(diffusion_base), episodes=2, max_delay=-1)
    with pytest.raises(ValueError, match="actions per chunk"):
        record_corrections(tmp_path / "x", base_path=str(diffusion_base), episodes=2, max_delay=1000)
    assert not (tmp_path / "x").exists()
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "precious.txt").write_text("keep me")
    with pytest.raises(ValueError, match="not an output of dcdp-record-corrections"):
        record_corrections(tmp_path / "home", base_path=str(diffusion_base), episodes=1, force=True)
    assert (tmp_path / "home" / "precious.txt").read_text() == "keep me"


def _residual_policy(diffusion_base, corrections_root, **kw):
    return make_dcdp_policy(
        diffusion_base,
        corrections_root,
        correction="residual",
        latent_dim=4,
        observation_features=["observation.environment_state"],
        **kw,
    )


def test_fresh_residual_corrector_is_open_loop_bit_for_bit(diffusion_base, corrections_root) -> None:
    policy = _residual_policy(diffusion_base, corrections_root).eval()
    assert "observation.dcdp_plan" not in policy.config.input_features
    obs = _normalised(policy, 2, 20)
    torch.manual_seed(3)
    policy.config.execution = "open_loop"
    policy.reset()
    expected = [policy.select_action(dict(o)) for o in obs]
    torch.manual_seed(3)
    policy.config.execution = "dcdp"
    policy.reset()
    got = [policy.select_action(dict(o)) for o in obs]
    for e, g in zip(expected, got, strict=True):
        assert torch.equal(e, g)


def test_fresh_residual_with_anchor_input_is_open_loop_and_sees_the_proposal(
    diffusion_base, corrections_root
) -> None:
    policy = _residual_policy(
        diffusion_base, corrections_root, anchor_input=True, anchor_feature="observation.environment_state"
    ).eval()
    obs = _normalised(policy, 2, 12)
    torch.manual_seed(3)
    policy.config.execution = "open_loop"
    policy.reset()
    expected = [policy.select_action(dict(o)) for o in obs]
    torch.manual_seed(3)
    policy.config.execution = "dcdp"
    policy.reset()
    got = [policy.select_action(dict(o)) for o in obs]
    for e, g in zip(expected, got, strict=True):
        assert torch.equal(e, g)
    assert (
        policy.state.z is not None
        and policy.state.at_plan is not None
        and policy.state.anchor_plan is not None
    )


def test_residual_loss_falls_and_stage2_matches_training(diffusion_base, corrections_root) -> None:
    torch.manual_seed(0)
    policy = _residual_policy(diffusion_base, corrections_root, optimizer_lr=3e-3)
    assert policy.config.observation_delta_indices == list(range(-7, 1))
    batches = training_batches(policy, corrections_root, batch_size=32)
    opt = torch.optim.Adam(policy.get_optim_params(), lr=3e-3)
    first = None
    policy.train()
    for _ in range(60):
        loss, parts = policy(next(batches))
        first = first if first is not None else parts
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()
    with torch.no_grad():
        _, last = policy(next(batches))
    # a fresh residual reproduces the plan: its error is the plan's gap to the teacher; training closes it
    assert first["recon_loss"] == pytest.approx(first["plan_gap"], rel=1e-4)
    assert last["recon_loss"] < 0.5 * last["plan_gap"]
    # the trained corrector now moves the plan at stage 2, and only inside a chunk's later steps
    obs = _normalised(policy, 2, 9)
    torch.manual_seed(0)
    acts = [policy.select_action(dict(o)) for o in obs]
    plan = policy.planned_chunk
    assert not torch.equal(acts[5], plan[:, 5])


def test_residual_training_without_recorded_plans_says_what_to_do(diffusion_base, demo_root) -> None:
    policy = make_dcdp_policy(diffusion_base, demo_root, correction="residual", latent_dim=4)
    batch = next(training_batches(policy, demo_root, batch_size=4))
    with pytest.raises(ValueError, match="dcdp-record-corrections"):
        policy(batch)


def test_gated_teacher_leaves_chunks_alone_without_drift(diffusion_base, tmp_path) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import record_corrections

    root = tmp_path / "gated"
    record_corrections(
        root,
        "local/test",
        base_path=str(diffusion_base),
        episodes=2,
        seed=11,
        static_fraction=1.0,
        teacher="anchored_when_drifting",
        batch_size=2,
        max_steps=12,
        progress=False,
    )
    ds = LeRobotDataset("local/test", root=root)
    for i in range(len(ds)):
        item = ds[i]
        s = int(item["observation.dcdp_plan_step"].item())
        planned = item["observation.dcdp_plan"].reshape(-1, 2)[s]
        assert torch.equal(item["action"], planned) and torch.equal(item["executed_action"], planned)


def test_training_sample_pairs_each_frame_with_its_own_plan_step(diffusion_base, corrections_root) -> None:
    """The teacher here is the anchoring itself: the proposal built in the loss from the sample's plan-time
    frame, plan and step must reproduce the recorded label exactly (misaligned frames/steps would not)."""
    policy = _residual_policy(
        diffusion_base, corrections_root, anchor_input=True, anchor_feature="observation.environment_state"
    ).eval()
    batches = training_batches(policy, corrections_root, batch_size=64)
    for _ in range(2):
        batch = next(batches)
        _, parts = policy(batch)
        assert parts["plan_gap"] > 1e-5  # the block drifted: the labels differ from the plan ...
        assert parts["anchor_gap"] < 1e-9  # ... exactly as the rigid motion since plan time says


@pytest.mark.parametrize("delay", [0, 3])
def test_per_chunk_terms_give_the_straightforward_actions(diffusion_base, corrections_root, delay) -> None:
    """The per-step fast path (head terms summed once per chunk) == the head's plain forward, within 1e-6."""
    policy = _residual_policy(diffusion_base, corrections_root, inference_delay=delay).eval()
    torch.manual_seed(7)
    with torch.no_grad():  # a corrector that moves the plan: every part of the head matters
        for p in policy.corrector.residual.parameters():
            p.add_(0.05 * torch.randn_like(p))
    obs = _normalised(policy, 2, 20)
    runs = {}
    for fast in (True, False):
        policy.fast_inference = fast
        torch.manual_seed(3)
        policy.reset()
        runs[fast] = torch.stack([policy.select_action(dict(o)) for o in obs])
        assert (policy.state.terms is not None) == fast
        assert (policy.state.kernel is not None) == (fast and delay == 0)  # the compiled per-step kernel
    assert (runs[True] - runs[False]).abs().max() <= 1e-6
    with torch.no_grad():  # new weights (a training step, a reload): the fast path must follow them
        policy.corrector.residual.net[-1].bias.add_(0.1)
    for fast in (True, False):
        policy.fast_inference = fast
        torch.manual_seed(3)
        policy.reset()
        runs[fast] = torch.stack([policy.select_action(dict(o)) for o in obs])
    assert (runs[True] - runs[False]).abs().max() <= 1e-6
    with torch.no_grad():
        policy.corrector.residual.net[-1].bias.sub_(0.1)
    policy.config.execution = "open_loop"
    torch.manual_seed(3)
    policy.reset()
    open_loop = torch.stack([policy.select_action(dict(o)) for o in obs])
    moved = (runs[True] - open_loop).abs().max()
    assert 1e-2 < moved < 2.0, moved  # a real correction, within the action range


def test_compiled_step_refuses_a_batch_that_changed_mid_chunk(diffusion_base, corrections_root) -> None:
    policy = _residual_policy(diffusion_base, corrections_root).eval()
    two, one = _normalised(policy, 2, 2), _normalised(policy, 1, 1)
    policy.reset()
    for o in two:  # a planning step and one step on the compiled kernel
        policy.select_action(dict(o))
    assert policy.state.kernel is not None and policy.state.step == 2
    with pytest.raises(ValueError, match=r"expected \(batch, features\) = \(2, 16\)"):
        policy.select_action(dict(one[0]))
    assert policy.state.step == 2  # nothing advanced
    policy.reset()
    assert policy.select_action(dict(one[0])).shape[0] == 1  # a new episode may change the batch


def test_recorded_rounds_merge_with_lerobots_own_merge(diffusion_base, corrections_root, tmp_path) -> None:
    """DAgger rounds aggregate with the stock merge_datasets (the plan is stored flat), and the merged data
    trains the residual corrector."""
    from lerobot.datasets.dataset_tools import merge_datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import record_corrections

    other = tmp_path / "round2"
    record_corrections(
        other,
        "local/test",
        base_path=str(diffusion_base),
        episodes=1,
        seed=20,
        batch_size=1,
        max_steps=10,
        progress=False,
    )
    rounds = [LeRobotDataset("local/test", root=r) for r in (corrections_root, other)]
    merged = merge_datasets(rounds, output_repo_id="local/test", output_dir=tmp_path / "merged")
    assert merged.meta.total_episodes == 4
    assert merged.meta.total_frames == sum(d.meta.total_frames for d in rounds)
    last = merged[merged.meta.total_frames - 1]
    torch.testing.assert_close(
        last["observation.dcdp_plan"], rounds[1][rounds[1].meta.total_frames - 1]["observation.dcdp_plan"]
    )
    policy = _residual_policy(diffusion_base, tmp_path / "merged")
    loss, info = policy.forward(next(training_batches(policy, tmp_path / "merged", batch_size=8)))
    assert torch.isfinite(loss) and info["synthesised"] == 0.0


def test_the_kernel_follows_writes_through_param_data(diffusion_base, corrections_root) -> None:
    """Writes through ``param.data`` bump no tensor version: the kernel's packed weights still follow them."""
    policy = _residual_policy(diffusion_base, corrections_root).eval()
    obs = _normalised(policy, 2, 12)
    policy.corrector.residual.net[-1].bias.data.add_(0.1)  # a moving corrector, written through .data
    runs = {}
    for fast in (True, False):
        policy.fast_inference = fast
        torch.manual_seed(3)
        policy.reset()
        runs[fast] = torch.stack([policy.select_action(dict(o)) for o in obs])
        assert (policy.state.kernel is not None) == fast
    assert (runs[True] - runs[False]).abs().max() <= 1e-6
    policy.corrector.residual.net[-1].bias.data.sub_(0.2)
    for fast in (True, False):
        policy.fast_inference = fast
        torch.manual_seed(3)
        policy.reset()
        runs[fast] = torch.stack([policy.select_action(dict(o)) for o in obs])
    assert (runs[True] - runs[False]).abs().max() <= 1e-6


def test_recording_leaves_the_callers_random_state_alone(diffusion_base) -> None:
    from lerobot_dcdp.data.corrections import DriftSpec, load_policy, rollout_corrections

    policy, pre, post = load_policy(None, str(diffusion_base), "open_loop", "observation.environment_state")
    spec = DriftSpec("constant", 1.0, 0.0, (0.0,), 50)
    torch.manual_seed(123)
    before = torch.random.get_rng_state()
    first = rollout_corrections(policy, pre, post, [4], [spec], 6, 0)[0]
    assert torch.equal(torch.random.get_rng_state(), before)
    again = rollout_corrections(policy, pre, post, [4], [spec], 6, 0)[0]
    assert np.array_equal(first["plan"], again["plan"])  # seeded inside, from the episode seed
