"""The ``pusht_sim`` robot: LeRobot's robot contract, the drift, real-time stepping, and stock
``lerobot-rollout`` sessions on it."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from helpers import sim_clock_rollout
from lerobot.robots import RobotConfig, make_robot_from_config
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

import lerobot_policy_dcdp  # noqa: F401  (registers the plugin's types, as LeRobot's discovery does)
from lerobot_dcdp.sim.robots import PushTSim, PushTSimConfig
from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def make(tmp_path: Path, **kwargs) -> PushTSim:
    return PushTSim(PushTSimConfig(calibration_dir=tmp_path / "calib", **kwargs))


def test_registered_for_lerobot(tmp_path: Path) -> None:
    assert RobotConfig.get_choice_class("pusht_sim") is PushTSimConfig
    robot = make_robot_from_config(PushTSimConfig(calibration_dir=tmp_path))
    assert isinstance(robot, PushTSim) and robot.name == robot.robot_type == "pusht_sim"


def test_robot_contract(tmp_path: Path) -> None:
    robot = make(tmp_path)
    # features are known before connecting, and are what the PushT datasets hold
    assert list(robot.observation_features) == [*AGENT_NAMES, *KEYPOINT_NAMES]
    assert len(KEYPOINT_NAMES) == 16 and set(robot.observation_features.values()) == {float}
    assert robot.action_features == {"x.pos": float, "y.pos": float}
    assert robot.is_calibrated and not robot.is_connected
    for call in (
        robot.get_observation,
        lambda: robot.send_action({"x.pos": 1, "y.pos": 1}),
        robot.disconnect,
    ):
        with pytest.raises(DeviceNotConnectedError):
            call()

    with robot:
        assert robot.is_connected
        with pytest.raises(DeviceAlreadyConnectedError):
            robot.connect()
        obs = robot.get_observation()
        assert list(obs) == list(robot.observation_features)
        assert all(isinstance(v, float) and 0 <= v <= 512 for v in obs.values())
        sent = robot.send_action({"x.pos": 600.0, "y.pos": -5.0, "kp0_x.pos": 1.0})  # extra keys ignored
        assert sent == {"x.pos": 512.0, "y.pos": 0.0}  # clipped to the arena
        assert robot.actions_sent == robot.sim_steps == 1
    assert not robot.is_connected


@pytest.mark.parametrize(
    ("action", "message"),
    [({"x.pos": 1.0}, "missing \\['y.pos'\\]"), ({"x.pos": float("nan"), "y.pos": 1}, "finite")],
)
def test_bad_action_is_refused(tmp_path: Path, action: dict, message: str) -> None:
    with make(tmp_path) as robot, pytest.raises(ValueError, match=message):
        robot.send_action(action)


def test_bad_config_is_refused() -> None:
    with pytest.raises(ValueError, match="perturbation must be one of"):
        PushTSimConfig(perturbation="sideways")
    with pytest.raises(ValueError, match="magnitude"):
        PushTSimConfig(magnitude=-1.0)
    with pytest.raises(ValueError, match="seed"):
        PushTSimConfig(seed="zero")
    with pytest.raises(ValueError, match="episode_steps must be an integer >= 1"):
        PushTSimConfig(episode_steps=0)
    with pytest.raises(ValueError, match="episodes_path needs episode_steps"):
        PushTSimConfig(episodes_path="episodes.jsonl")
    with pytest.raises(ValueError, match="end_on_success must be true or false"):
        PushTSimConfig(episode_steps=10, end_on_success="no")


def test_lockstep_drift_moves_the_block(tmp_path: Path) -> None:
    """Lock-step: one control step per action; a constant drift away from the agent moves the block by
    exactly ``magnitude`` px per step (seed 0: the agent starts to the right of the block)."""
    with make(tmp_path, perturbation="constant", magnitude=2.0, direction_deg=180.0, realtime=False) as robot:
        x0, y0, _ = robot.block_pose
        obs = robot.get_observation()
        hold = {k: obs[k] for k in AGENT_NAMES}
        for _ in range(5):
            robot.send_action(hold)
        x1, y1, _ = robot.block_pose
        assert robot.sim_steps == 5
        assert (x1 - x0, y1 - y0) == pytest.approx((-10.0, 0.0), abs=1e-6)
        kp = np.array([robot.get_observation()[k] for k in KEYPOINT_NAMES]).reshape(8, 2)
        kp0 = np.array([obs[k] for k in KEYPOINT_NAMES]).reshape(8, 2)
        assert kp - kp0 == pytest.approx(np.tile([-10.0, 0.0], (8, 1)), abs=1e-6)


def test_episodes_end_and_the_next_starts_from_the_next_seed(tmp_path: Path) -> None:
    """With ``episode_steps`` the robot runs the benchmark's protocol by itself: an episode ends after that
    many steps, is recorded (in memory and as one JSON line), and the scene jumps to a fresh episode from the
    next seed."""
    log = tmp_path / "out" / "episodes.jsonl"
    kw = {"perturbation": "constant", "magnitude": 1.0, "realtime": False}
    with make(tmp_path, seed=7, episode_steps=4, episodes_path=str(log), **kw) as robot:
        hold = {k: robot.get_observation()[k] for k in AGENT_NAMES}
        for _ in range(10):
            robot.send_action(hold)
        assert robot.sim_steps == 10
        assert [(e["episode"], e["seed"], e["steps"]) for e in robot.episodes] == [(0, 7, 4), (1, 8, 4)]
        after_two = robot.get_observation()
        with make(tmp_path, seed=9, **kw) as fresh:  # the third episode is seed 9 after 2 steps
            fresh.send_action(hold), fresh.send_action(hold)
            assert after_two == pytest.approx(fresh.get_observation())
        for e in robot.episodes:
            assert 0.0 <= e["score"] <= 1.0 and e["success"] is False
            assert e["score"] == pytest.approx(min(e["max_coverage"] / 0.95, 1.0))
        assert [json.loads(line) for line in log.read_text().splitlines()] == robot.episodes
        assert robot.mean_score() == pytest.approx(np.mean([e["score"] for e in robot.episodes]))


def test_an_episode_ends_at_success(tmp_path: Path) -> None:
    """``end_on_success``: the block put on the goal pose succeeds on the first step, which ends the episode
    (one step long, score 1); with ``end_on_success=False`` it runs its full length."""
    for end_on_success, steps in ((True, 1), (False, 3)):
        with make(tmp_path, seed=1, episode_steps=3, end_on_success=end_on_success, realtime=False) as robot:
            sim = robot._env.unwrapped  # the block on gym-pusht's goal pose (256, 256, 45 deg), the agent far
            sim.block.angle, sim.block.position, sim.agent.position = np.pi / 4, (256.0, 256.0), (60.0, 60.0)
            assert robot.block_pose == pytest.approx((256.0, 256.0, np.pi / 4))
            for _ in range(3):
                robot.send_action({"x.pos": 60.0, "y.pos": 60.0})
            first = robot.episodes[0]
            assert (first["steps"], first["success"], first["score"]) == (steps, True, 1.0)


def test_realtime_world_runs_on_while_the_controller_is_late(tmp_path: Path) -> None:
    now = [100.0]  # a controlled clock: the result cannot depend on the machine's load
    with make(tmp_path, realtime=True) as robot:
        robot.clock = lambda: now[0]
        hold = {k: robot.get_observation()[k] for k in AGENT_NAMES}
        robot.send_action(hold)  # first action: one step, starts the clock
        assert (robot.sim_steps, robot.late_actions) == (1, 0)
        now[0] += 0.32  # 3.2 control steps late
        robot.send_action(hold)
        assert (robot.late_actions, robot.sim_steps, robot.held_steps) == (1, 4, 2)
        robot.send_action(hold)  # right away: no step due, the action is superseded
        assert (robot.sim_steps, robot.superseded_actions) == (4, 1)
        now[0] += 0.1  # on time
        robot.send_action(hold)
        assert (robot.sim_steps, robot.late_actions, robot.superseded_actions) == (5, 1, 1)


@pytest.mark.slow
def test_rollout_records_the_shipped_corrector(tmp_path: Path) -> None:
    """A session of stock ``lerobot-rollout`` on a simulated clock: LeRobot's episodic strategy drives the
    shipped DCDP corrector on the drifting sim (lock-step, 5 Hz, 2 s: exactly 10 ticks) and records it, one
    frame per action. LeRobot records the robot's 18 scalar features as one ``observation.state`` (agent
    xy, then the keypoints); the corrector's own pre-processor splits such a frame into its two inputs."""
    fps, seconds, root = 5, 2, tmp_path / "rec"
    corrector = REPO / "models" / "pusht-dcdp-state"
    args = [
        str(sim_clock_rollout(tmp_path)),
        *("--robot.type=pusht_sim", "--robot.perturbation=constant", "--robot.magnitude=2.0"),
        "--robot.realtime=false",
        f"--robot.calibration_dir={tmp_path / 'calib'}",
        f"--policy.path={corrector}",
        "--policy.execution=dcdp",
        f"--fps={fps}",
        "--strategy.type=episodic",
        "--dataset.repo_id=local/rollout_pusht",
        f"--dataset.root={root}",
        f"--dataset.fps={fps}",
        "--dataset.num_episodes=1",
        f"--dataset.episode_time_s={seconds}",
        "--dataset.single_task=Push the T onto the target",
        "--dataset.push_to_hub=false",
        "--return_to_initial_position=false",
        "--play_sounds=false",
    ]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=300, env=ENV, cwd=tmp_path)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-4000:]
    sent = int(re.search(r"PushTSim disconnected: actions=(\d+)", log).group(1))

    info = json.loads((root / "meta" / "info.json").read_text())
    feats = info["features"]
    assert (info["fps"], info["robot_type"], info["total_episodes"]) == (fps, "pusht_sim", 1)
    assert feats["observation.state"]["names"] == [*AGENT_NAMES, *KEYPOINT_NAMES]
    assert feats["action"]["names"] == list(AGENT_NAMES)
    assert info["total_frames"] == sent == fps * seconds

    import torch
    from lerobot.datasets import LeRobotDataset
    from lerobot.processor import PolicyProcessorPipeline

    ds = LeRobotDataset("local/rollout_pusht", root=root)
    state = torch.stack([ds[i]["observation.state"] for i in range(len(ds))])
    actions = torch.stack([ds[i]["action"] for i in range(len(ds))])
    assert (state[-1, 2:] - state[0, 2:]).abs().max() > 1.0  # the block moved (drift and/or pushing)
    assert ((actions >= 0) & (actions <= 512)).all()
    # what the corrector's pre-processor makes of the recorded frames: its two inputs, normalised
    pre = PolicyProcessorPipeline.from_pretrained(corrector, "policy_preprocessor.json")
    flat = pre({"observation.state": state})
    split = pre({"observation.state": state[:, :2], "observation.environment_state": state[:, 2:]})
    for key in ("observation.state", "observation.environment_state"):
        assert torch.equal(flat[key], split[key])


@pytest.mark.slow
def test_rollout_deadlines_script(tmp_path: Path) -> None:
    """scripts/rollout_deadlines.sh runs a 2 s rollout on the real-time robot and tabulates LeRobot's deadline
    warnings and the robot's summary. On a simulated clock every tick takes exactly 1 / fps: 20 ticks, none
    late, no step held or action superseded (logs with misses: test_rollout_deadlines_parsing)."""
    out = tmp_path / "deadlines"
    env = {**ENV, "LEROBOT_ROLLOUT": str(sim_clock_rollout(tmp_path)), "MODES": "open_loop", "DURATION": "2"}
    env |= {"FPS": "10", "OUT": str(out)}
    proc = subprocess.run(
        ["bash", "scripts/rollout_deadlines.sh"],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    row = next(
        line for line in (out / "summary.md").read_text().splitlines() if line.startswith("| open_loop")
    )
    _, mode, ticks, misses, pct, slowest, held, superseded, coverage, episodes, score, _ = (
        c.strip() for c in row.split("|")
    )
    log = (out / "open_loop.log").read_text()
    counts = (int(ticks), int(misses), float(pct), slowest, int(held), int(superseded))
    assert counts == (20, 0, 0.0, "-", 0, 0)
    assert log.count("Record loop is running slower") == 0 and "late_actions=0" in log
    assert 0.0 <= float(coverage) <= 1.0
    ended = log.count("PushTSim episode ")  # the robot's line per finished episode (one on early success)
    assert int(episodes) == ended and (score == "-") == (ended == 0)


def _fake_rollout(tmp_path: Path, log_lines: list[str]) -> Path:
    """A stand-in for lerobot-rollout that prints fixed log lines (the script only reads its log)."""
    fake = tmp_path / "fake-rollout"
    body = "\n".join(f"echo {json.dumps(line)}" for line in log_lines)
    fake.write_text(f"#!/usr/bin/env bash\n{body}\n")
    fake.chmod(0o755)
    return fake


def _run_deadlines(env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        ["bash", "scripts/rollout_deadlines.sh"], capture_output=True, text=True, env=env, cwd=REPO
    )


SUMMARY = (
    "INFO pusht_sim.py:131 PushTSim disconnected: actions=20 sim_steps=21 late_actions=0 held_steps=1 "
    "superseded_actions=0 max_coverage=0.412 success=False"
)
SLOW = "WARNING base.py:99 Record loop is running slower ({hz} Hz) than the target FPS (10 Hz)."


@pytest.mark.parametrize(
    ("warnings", "misses", "slowest_ms", "episodes"),
    [
        ([], 0, "-", ""),
        ([SLOW.format(hz="8.1"), SLOW.format(hz="4.0")], 2, "250", ""),
        ([], 0, "-", " episodes=3 mean_score=0.815"),
    ],
)
def test_rollout_deadlines_parsing(
    tmp_path: Path, warnings: list[str], misses: int, slowest_ms: str, episodes: str
) -> None:
    """The row counts LeRobot's slow-loop warnings (none is a valid outcome) and reads the robot's line
    (finished episodes and their mean score when the robot reports any)."""
    out = tmp_path / "out"
    log = [*warnings, SUMMARY + episodes]
    env = {**ENV, "LEROBOT_ROLLOUT": str(_fake_rollout(tmp_path, log)), "MODES": "dcdp"}
    proc = _run_deadlines(env | {"OUT": str(out)})
    assert proc.returncode == 0, proc.stderr
    row = next(line for line in proc.stdout.splitlines() if line.startswith("| dcdp"))
    cells = [c.strip() for c in row.split("|")[1:-1]]
    scored = ["3", "0.815"] if episodes else ["0", "-"]
    counts = ["20", str(misses), f"{100 * misses / 20:.1f}", slowest_ms, "1", "0", "0.412"]
    assert cells == ["dcdp", *counts, *scored]


def test_rollout_deadlines_needs_robot_summary(tmp_path: Path) -> None:
    """A log without the robot's disconnect line is an error naming the log, not a half-written row."""
    out = tmp_path / "out"
    env = {**ENV, "LEROBOT_ROLLOUT": str(_fake_rollout(tmp_path, ["nothing useful"])), "MODES": "dcdp"}
    proc = _run_deadlines(env | {"OUT": str(out)})
    assert proc.returncode == 1 and "PushTSim disconnected" in proc.stderr and "dcdp.log" in proc.stderr
    assert "| dcdp" not in (out / "summary.md").read_text()


def test_the_robot_is_named_not_none(tmp_path: Path) -> None:
    """LeRobot prints a robot as "<id> <class>": an unnamed sim robot is "pusht_sim PushTSim"."""
    assert str(make(tmp_path)) == "pusht_sim PushTSim"
    assert str(make(tmp_path, id="left")) == "left PushTSim"
