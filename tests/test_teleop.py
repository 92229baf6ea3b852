"""The person-in-the-loop and teacher-policy paths of stage 1: the ``pusht_expert`` teleoperator behind
LeRobot's interface, and ``dcdp-record-corrections --teacher=teleop|policy`` feeding the real CLIs."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import tiny_train_flags

from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
from lerobot_dcdp.sim.teleoperators import PushTExpert, PushTExpertConfig
from lerobot_dcdp.sim.teleoperators.pusht_expert import block_pose_from_keypoints

BIN = Path(sys.executable).parent
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run(args, capture_output=True, text=True, timeout=600, env=ENV, cwd=cwd)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-6000:]
    return proc


def _feedback(obs: dict) -> dict:
    fb = dict(zip(AGENT_NAMES, obs["agent_pos"].tolist(), strict=True))
    fb.update(zip(KEYPOINT_NAMES, obs["environment_state"].tolist(), strict=True))
    return fb


def _evaluate_one_episode(ckpt: Path, *env_flags: str, cwd: Path) -> None:
    """One 10-step episode of the stock lerobot-eval with keypoint observations; it must report it."""
    evaluation = cwd / "eval"
    run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={ckpt}",
            *env_flags,
            "--env.obs_type=environment_state_agent_pos",
            "--env.episode_length=10",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            "--policy.device=cpu",
            f"--output_dir={evaluation}",
        ],
        cwd=cwd,
    )
    assert json.loads((evaluation / "eval_info.json").read_text())["overall"]["n_episodes"] == 1


def test_block_pose_is_recovered_from_its_keypoints() -> None:
    from lerobot_dcdp.sim.pusht_geometry import keypoints

    rng = np.random.default_rng(0)
    for _ in range(20):
        pose = np.array([*rng.uniform(50, 450, 2), rng.uniform(-math.pi, math.pi)])
        fit = block_pose_from_keypoints(keypoints(pose))
        assert np.allclose(fit[:2], pose[:2], atol=1e-9)
        assert abs((fit[2] - pose[2] + math.pi) % (2 * math.pi) - math.pi) < 1e-9
    with pytest.raises(ValueError, match="8 block keypoints"):
        block_pose_from_keypoints(np.zeros((7, 2)))


def test_config_and_feedback_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="replan_every must be >= 1"):
        PushTExpertConfig(replan_every=0)
    teleop = PushTExpert(PushTExpertConfig())
    assert str(teleop) == "pusht_expert PushTExpert"
    teleop.connect()
    with pytest.raises(RuntimeError, match=r"call send_feedback\(observation\) before get_action"):
        teleop.get_action()
    with pytest.raises(ValueError, match="missing .*kp0_x.pos"):
        teleop.send_feedback({"x.pos": 1.0, "y.pos": 2.0})
    teleop.disconnect()


def test_the_scripted_teleoperator_completes_a_static_episode_from_observations_alone() -> None:
    """It sees only the observation (keypoints, agent position) through send_feedback, sends smooth
    targets (at most max_step apart) and completes the task."""
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env

    cfg = PushTExpertConfig(replan_every=8)
    env = make_perturbed_env(obs_type="environment_state_agent_pos", max_episode_steps=300)
    obs, _ = env.reset(seed=100_000)
    with PushTExpert(cfg) as teleop:
        previous, success = None, False
        for _ in range(300):
            teleop.send_feedback(_feedback(obs))
            action = teleop.get_action()
            assert set(action) == set(AGENT_NAMES)
            target = np.array([action["x.pos"], action["y.pos"]])
            if previous is not None:
                assert np.linalg.norm(target - previous) <= cfg.max_step + 1e-6
            previous = target
            obs, _, terminated, truncated, info = env.step(target)
            if info["is_success"] or terminated or truncated:
                success = bool(info["is_success"])
                break
        assert success and teleop.plans >= 2
    env.close()


def test_follow_deviation_carries_a_target_with_the_blocks_rigid_motion() -> None:
    from lerobot_dcdp.sim.pusht_geometry import keypoints
    from lerobot_dcdp.sim.teleoperators.pusht_expert import follow_deviation

    predicted, observed = np.array([200.0, 150.0, 0.3]), np.array([215.0, 140.0, 0.3 + math.pi / 2])
    # a point fixed to the block (one of its corners) lands on the same corner of the observed block
    corner_before, corner_after = keypoints(predicted)[2], keypoints(observed)[2]
    assert np.allclose(follow_deviation(corner_before, predicted, observed), corner_after, atol=1e-9)
    target = np.array([10.0, 20.0])
    assert np.allclose(follow_deviation(target, predicted, predicted), target)
    with pytest.raises(ValueError, match="follow_block must be true or false"):
        PushTExpertConfig(follow_block="yes")


def test_the_exact_sim_drifts_the_block_as_the_perturbed_env_does() -> None:
    """``ExactSim.drift`` moves the block by that many px before every step, clipped at the arena."""
    from lerobot_dcdp.sim.pusht_expert import ExactSim

    sim = ExactSim()
    sim.set_state((60.0, 60.0), (0.0, 0.0), np.array([300.0, 300.0, 0.0]))
    sim.drift = np.array([2.0, -1.0])
    poses = sim.run([np.array([60.0, 60.0])] * 5)
    assert np.allclose([p[:2] for p in poses], [[300 + 2 * k, 300 - k] for k in range(1, 6)], atol=1e-6)
    sim.set_state((60.0, 60.0), (0.0, 0.0), np.array([440.0, 300.0, 0.0]))  # bar ends at x = 500
    sim.drift = np.array([2.0, 0.0])
    assert sim.run([np.array([60.0, 60.0])] * 5)[-1][0] == pytest.approx(502.0 - 60.0)


def test_a_following_teleoperator_estimates_the_drift_and_leaves_a_still_scene_alone() -> None:
    """With ``follow_block`` the expert learns the block's drift from what its own pushes do not explain
    (constant 2 px/step at 45 degrees: (1.41, 1.41) px/step) and plans with it; on a still scene the estimate
    stays at zero and the targets stay within a pixel of the plain expert's; without the flag it assumes no
    drift."""
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env

    def drive(follow: bool, magnitude: float, steps: int) -> tuple[np.ndarray, list[np.ndarray]]:
        env = make_perturbed_env(
            obs_type="environment_state_agent_pos",
            max_episode_steps=300,
            perturbation="constant" if magnitude else "none",
            magnitude=magnitude,
            direction_deg=45.0,
        )
        obs, _ = env.reset(seed=100_000)
        targets = []
        with PushTExpert(PushTExpertConfig(replan_every=8, follow_block=follow)) as teleop:
            for _ in range(steps):
                teleop.send_feedback(_feedback(obs))
                action = teleop.get_action()
                targets.append(np.array([action["x.pos"], action["y.pos"]]))
                obs, *_ = env.step(targets[-1])
            estimate = teleop.drift_estimate
        env.close()
        return estimate, targets

    drift = 2.0 * np.array([math.cos(math.pi / 4), math.sin(math.pi / 4)])
    estimate, _ = drive(True, 2.0, 17)  # two plans after the first: the estimate is set at each
    assert np.allclose(estimate, drift, atol=0.05)
    assert np.allclose(drive(False, 2.0, 17)[0], 0.0)
    still, followed = drive(True, 0.0, 24)
    assert np.abs(still).max() < 0.05
    _, plain = drive(False, 0.0, 24)
    gaps = [np.abs(a - b).max() for a, b in zip(followed, plain, strict=True)]
    # in contact the plan's prediction (from an agent velocity estimated from two positions) is off by < 1 px
    assert max(gaps) < 1.5 and float(np.mean(gaps)) < 0.3


def test_teleoperator_is_discovered_like_the_robot() -> None:
    """LeRobot's plugin discovery and teleoperator factory build it from ``--teleop.type=pusht_expert``."""
    code = (
        "from lerobot.utils.import_utils import register_third_party_plugins as r; r();"
        "import draccus;"
        "from lerobot.teleoperators.config import TeleoperatorConfig;"
        "from lerobot.teleoperators.utils import make_teleoperator_from_config;"
        "cfg = draccus.decode(TeleoperatorConfig, {'type': 'pusht_expert', 'replan_every': 4});"
        "t = make_teleoperator_from_config(cfg);"
        "print(type(t).__name__, t.config.replan_every, sorted(t.action_features))"
    )
    proc = run([sys.executable, "-c", code], cwd=Path.cwd())
    assert proc.stdout.split()[-4:] == ["PushTExpert", "4", "['x.pos',", "'y.pos']"]


@pytest.mark.slow
def test_teleoperated_corrections_train_and_evaluate_through_the_clis(diffusion_base, tmp_path) -> None:
    """dcdp-record-corrections with the scripted teleoperator driving (HG-DAgger's person), then the stock
    lerobot-train and lerobot-eval on what it recorded."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    data = tmp_path / "teleop"
    proc = run(
        [
            str(BIN / "dcdp-record-corrections"),
            f"--root={data}",
            "--repo-id=local/teleop",
            f"--base={diffusion_base}",
            "--teacher=teleop",
            "--teleop.type=pusht_expert",
            "--teleop.replan_every=4",
            "--execution=teacher",
            "--episodes=2",
            "--batch-size=2",
            "--max-steps=12",
        ],
        cwd=tmp_path,
    )
    assert "--dataset.repo_id=local/teleop" in proc.stdout
    ds = LeRobotDataset("local/teleop", root=data)
    assert ds.meta.total_episodes == 2
    labels = torch.stack([ds[i]["action"] for i in range(len(ds))])
    executed = torch.stack([ds[i]["executed_action"] for i in range(len(ds))])
    assert torch.equal(labels, executed)  # the person drove: what was sent is the label
    plans = torch.stack(
        [
            ds[i]["observation.dcdp_plan"].reshape(-1, 2)[int(ds[i]["observation.dcdp_plan_step"])]
            for i in range(len(ds))
        ]
    )
    assert (labels - plans).norm(dim=-1).mean() > 1.0  # the labels are the person's, not the base's plan

    out = tmp_path / "train"
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={diffusion_base}",
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
            f"--output_dir={out}",
            *tiny_train_flags("local/teleop", data),
        ],
        cwd=tmp_path,
    )
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    assert json.loads((ckpt / "config.json").read_text())["correction"] == "residual"
    _evaluate_one_episode(ckpt, "--env.type=pusht_perturbed", "--env.perturbation=constant", cwd=tmp_path)


def test_a_teacher_policy_labels_every_step_with_its_own_action(diffusion_base, act_base, tmp_path) -> None:
    """--teacher=policy: the labels are exactly the teacher policy's select_action on the recorded
    observations (ACT is deterministic), and with execution=teacher they are what was executed."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    from lerobot_dcdp.data.corrections import record_corrections

    root = tmp_path / "taught"
    record_corrections(
        root,
        "local/taught",
        base_path=str(diffusion_base),
        episodes=1,
        seed=3,
        teacher="policy",
        teacher_policy=str(act_base),
        execution="teacher",
        batch_size=1,
        max_steps=10,
        progress=False,
    )
    ds = LeRobotDataset("local/taught", root=root)
    cfg = PreTrainedConfig.from_pretrained(act_base)
    teacher = get_policy_class(cfg.type).from_pretrained(act_base, config=cfg).eval()
    pre, post = make_pre_post_processors(cfg, pretrained_path=str(act_base))
    teacher.reset()
    for i in range(len(ds)):
        item = ds[i]
        obs = {k: item[k].unsqueeze(0) for k in ("observation.state", "observation.environment_state")}
        with torch.no_grad():
            expected = post(teacher.select_action(pre(obs)))[0]
        torch.testing.assert_close(item["action"], expected, atol=1e-4, rtol=0)
        torch.testing.assert_close(item["executed_action"], item["action"])


def test_the_expert_teacher_labels_the_learners_states_with_the_scripted_experts_actions(
    diffusion_base, tmp_path
) -> None:
    """--teacher=expert: the base drives (a DAgger round) and every label is what the scripted expert sends
    for that observation; the expert's targets are its own, not the plan."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import record_corrections

    root = tmp_path / "expert"
    record_corrections(
        root,
        "local/expert",
        base_path=str(diffusion_base),
        episodes=1,
        seed=4,
        teacher="expert",
        execution="open_loop",
        batch_size=1,
        max_steps=10,
        progress=False,
    )
    ds = LeRobotDataset("local/expert", root=root)
    items = [ds[i] for i in range(len(ds))]
    labels = torch.stack([x["action"] for x in items])
    executed = torch.stack([x["executed_action"] for x in items])
    expert = PushTExpert(PushTExpertConfig())
    expert.connect()
    for item, label in zip(items, labels, strict=True):
        state, keypoints = item["observation.state"], item["observation.environment_state"]
        feedback = dict(zip(AGENT_NAMES, state.tolist(), strict=True))
        feedback.update(zip(KEYPOINT_NAMES, keypoints.tolist(), strict=True))
        expert.send_feedback(feedback)
        sent = expert.get_action()
        torch.testing.assert_close(label, torch.tensor([sent[k] for k in AGENT_NAMES]), atol=1e-4, rtol=0)
    expert.disconnect()
    assert (labels - executed).norm(dim=-1).mean() > 1.0  # the base drove; the expert only labelled
    with pytest.raises(ValueError, match="pass --teacher=teleop"):
        record_corrections(
            tmp_path / "b", base_path=str(diffusion_base), teacher="expert", teleop_config=PushTExpertConfig()
        )


def test_recorder_flag_errors_name_the_fix(diffusion_base, tmp_path) -> None:
    from lerobot_dcdp.data.corrections import TeleopTeacher, parse_teleop_args, record_corrections

    teacher = TeleopTeacher(PushTExpertConfig(), 1)  # shown the scene: an env without keypoints is refused
    try:
        with pytest.raises(ValueError, match=r"not \['environment_state'\]: .*--env.obs_type=environment_st"):
            teacher.check_observation({"pixels", "agent_pos"})
        teacher.check_observation({"agent_pos", "environment_state"})
    finally:
        teacher.close()

    with pytest.raises(ValueError, match="needs a teleoperator: --teleop.type"):
        record_corrections(tmp_path / "a", base_path=str(diffusion_base), teacher="teleop", episodes=1)
    with pytest.raises(ValueError, match="needs --teacher-policy"):
        record_corrections(tmp_path / "a", base_path=str(diffusion_base), teacher="policy", episodes=1)
    with pytest.raises(ValueError, match="execution='teacher' lets the teacher drive"):
        record_corrections(tmp_path / "a", base_path=str(diffusion_base), execution="teacher", episodes=1)
    with pytest.raises(ValueError, match="holds no config.json"):
        record_corrections(
            tmp_path / "a", base_path=str(diffusion_base), teacher="policy", teacher_policy=str(tmp_path)
        )
    with pytest.raises(ValueError, match="need --teleop.type=<one of: .*pusht_expert"):
        parse_teleop_args(["--teleop.replan_every=3"])
    with pytest.raises(ValueError, match="unrecognized arguments: --tele.type=x"):
        parse_teleop_args(["--tele.type=x"])
    assert parse_teleop_args(["--teleop.type=pusht_expert", "--teleop.seed=5"]).seed == 5


@pytest.mark.slow
def test_any_lerobot_env_and_a_teacher_policy_through_the_clis(diffusion_base, act_base, tmp_path) -> None:
    """--env.type picks any registered LeRobot env (here LeRobot's own ``pusht``, no drift) and
    --teacher=policy labels with another policy; the recording trains with lerobot-train and runs with
    lerobot-eval."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    data = tmp_path / "stock_env"
    record = [
        str(BIN / "dcdp-record-corrections"),
        f"--root={data}",
        "--repo-id=local/stock",
        f"--base={diffusion_base}",
        "--teacher=policy",
        f"--teacher-policy={act_base}",
        "--episodes=2",
        "--batch-size=2",
        "--max-steps=10",
        "--env.type=pusht",
    ]
    bad = subprocess.run(record, capture_output=True, text=True, timeout=600, env=ENV, cwd=tmp_path)
    assert bad.returncode != 0 and "--env.obs_type=environment_state_agent_pos" in bad.stderr
    assert not data.exists()
    run([*record, "--env.obs_type=environment_state_agent_pos"], cwd=tmp_path)
    ds = LeRobotDataset("local/stock", root=data)
    assert ds.meta.total_episodes == 2 and ds.meta.fps == 10
    assert ds.meta.features["observation.environment_state"]["names"][0] == "kp0_x"
    out = tmp_path / "train"
    run(
        [
            str(BIN / "lerobot-train"),
            "--policy.type=dcdp",
            f"--policy.base_policy_path={diffusion_base}",
            "--policy.feature_dim=32",
            "--policy.n_heads=4",
            f"--output_dir={out}",
            *tiny_train_flags("local/stock", data),
        ],
        cwd=tmp_path,
    )
    _evaluate_one_episode(out / "checkpoints" / "last" / "pretrained_model", "--env.type=pusht", cwd=tmp_path)
