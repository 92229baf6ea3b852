"""The correcting person (``pusht_nudge``): it passes the robot's command on a still scene, carries it with
the block once the world moves the block, and feeds ``dcdp-record-corrections --teacher=teleop``."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lerobot_dcdp.sim.robots.pusht_sim import AGENT_NAMES, KEYPOINT_NAMES
from lerobot_dcdp.sim.teleoperators import PushTExpert, PushTExpertConfig, PushTNudge, PushTNudgeConfig
from lerobot_dcdp.sim.teleoperators.pusht_nudge import CHUNK_STEP, COMMAND_NAMES, carried


def _feedback(obs: dict, command: np.ndarray, chunk_step: int) -> dict:
    fb = dict(zip(AGENT_NAMES, obs["agent_pos"].tolist(), strict=True))
    fb.update(zip(KEYPOINT_NAMES, obs["environment_state"].tolist(), strict=True))
    fb.update(zip(COMMAND_NAMES, np.asarray(command, dtype=float).tolist(), strict=True))
    fb[CHUNK_STEP] = chunk_step
    return fb


def _env(magnitude: float):
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env

    return make_perturbed_env(
        obs_type="environment_state_agent_pos",
        max_episode_steps=300,
        perturbation="constant" if magnitude else "none",
        magnitude=magnitude,
        direction_deg=45.0,
    )


def test_config_and_feedback_errors_name_the_problem() -> None:
    for field, value in (("notice_speed", -1.0), ("contact_margin", -2.0), ("smoothing", 0.0)):
        with pytest.raises(ValueError, match=field):
            PushTNudgeConfig(**{field: value})
    with PushTNudge(PushTNudgeConfig()) as person:
        with pytest.raises(RuntimeError, match=r"send_feedback\(observation\) before get_action"):
            person.get_action()
        with pytest.raises(ValueError, match=r"missing \['command.x.pos'"):
            person.send_feedback(dict.fromkeys(AGENT_NAMES + KEYPOINT_NAMES, 1.0))
        obs = {"agent_pos": np.zeros(2), "environment_state": np.arange(16.0)}
        with pytest.raises(ValueError, match="chunk_step must be >= 0"):
            person.send_feedback(_feedback(obs, np.zeros(2), -1))


def test_a_still_scene_passes_the_command_even_while_the_robot_pushes_the_block() -> None:
    """The scripted expert pushes the block for 60 steps without drift: the block moves (by the pushes), but
    never while the agent is away from it, so the person never notices and sends the command unchanged."""
    env = _env(0.0)
    obs, _ = env.reset(seed=100_000)
    start = obs["environment_state"].copy()
    with PushTExpert(PushTExpertConfig()) as driver, PushTNudge(PushTNudgeConfig()) as person:
        for t in range(60):
            driver.send_feedback(_feedback(obs, np.zeros(2), 0))
            sent = driver.get_action()
            command = np.array([sent[k] for k in AGENT_NAMES])
            person.send_feedback(_feedback(obs, command, t % 8))
            action = person.get_action()
            assert [action[k] for k in AGENT_NAMES] == command.tolist()
            obs, *_ = env.step(command)
        assert person.block_speed == 0.0 and not person.noticing
    env.close()
    assert np.abs(obs["environment_state"] - start).max() > 5.0  # the pushes did move the block


def test_a_drifting_block_is_noticed_and_the_command_carried_with_it_since_the_chunk_began() -> None:
    """Constant drift of 2 px/step at 45 degrees, the agent parked away from the block: the person's speed
    estimate rises past ``notice_speed`` and each command comes back moved by the block's displacement since
    the step its chunk was planned (a pure translation here)."""
    env = _env(2.0)
    obs, _ = env.reset(seed=100_000)
    park = np.array([40.0, 470.0])  # a corner the block drifts away from
    assert np.linalg.norm(obs["agent_pos"] - park) > 0  # the agent travels there first, then waits
    noticed_at, reference = None, None
    with PushTNudge(PushTNudgeConfig(notice_speed=0.3)) as person:
        for t in range(40):
            step = t % 8
            if step == 0:
                reference = obs["environment_state"].reshape(-1, 2).copy()
            person.send_feedback(_feedback(obs, park, step))
            action = np.array([person.get_action()[k] for k in AGENT_NAMES])
            if person.noticing:
                noticed_at = t if noticed_at is None else noticed_at
                moved = obs["environment_state"].reshape(-1, 2).mean(0) - reference.mean(0)
                np.testing.assert_allclose(action, park + moved, atol=1e-6)
                if step > 0:
                    assert np.linalg.norm(action - park) == pytest.approx(2.0 * step, abs=0.1)
            else:
                assert action.tolist() == park.tolist()
            obs, *_ = env.step(park)  # the robot holds its own command (the person only labels)
        assert person.block_speed == pytest.approx(2.0, abs=0.05)
    env.close()
    assert noticed_at is not None and noticed_at <= 3


def test_carried_is_the_rigid_motion_of_the_keypoints() -> None:
    from lerobot_dcdp.sim.pusht_geometry import keypoints

    then = keypoints(np.array([200.0, 200.0, 0.3]))
    now = keypoints(np.array([230.0, 190.0, 0.3 + math.pi / 6]))
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    rotation = np.array([[c, -s], [s, c]])
    point = np.array([120.0, 260.0])
    expected = rotation @ (point - then.mean(0)) + now.mean(0)
    np.testing.assert_allclose(carried(point, then, now), expected, atol=1e-9)


def test_recorded_labels_are_the_command_carried_when_drifting_and_the_plan_at_rest(
    diffusion_base, tmp_path
) -> None:
    """dcdp-record-corrections --teacher=teleop --teleop.type=pusht_nudge --execution=teacher: the recorder
    shows the person the plan's action and its chunk step, so on drifting episodes each label is the planned
    action carried with the keypoints since the chunk's first frame (or the plan itself before the person
    notices), and it is what the robot executed; on a still episode every label is the plan."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.corrections import record_corrections

    def record(name: str, seed: int, static_fraction: float):
        root = tmp_path / name
        record_corrections(
            root,
            f"local/{name}",
            base_path=str(diffusion_base),
            episodes=2,
            seed=seed,
            teacher="teleop",
            teleop_config=PushTNudgeConfig(),
            execution="teacher",
            static_fraction=static_fraction,
            batch_size=2,
            max_steps=20,
            progress=False,
        )
        ds = LeRobotDataset(f"local/{name}", root=root)
        return [ds[i] for i in range(len(ds))]

    def plan_action(item) -> torch.Tensor:
        return item["observation.dcdp_plan"].reshape(-1, 2)[int(item["observation.dcdp_plan_step"])]

    still = record("still", 0, 1.0)
    for item in still:
        torch.testing.assert_close(item["action"], plan_action(item), atol=1e-4, rtol=0)

    drifting = record("drifting", 1, 0.0)  # seeds 1 and 2 drift at 1.18 and 1.37 px/step
    carried_frames = 0
    for i, item in enumerate(drifting):
        torch.testing.assert_close(item["executed_action"], item["action"])  # the person's command drove
        step = int(item["observation.dcdp_plan_step"])
        first = drifting[i - step]
        assert int(first["episode_index"]) == int(item["episode_index"])
        planned = plan_action(item)
        if torch.allclose(item["action"], planned, atol=1e-4):
            continue
        expected = carried(
            planned.numpy(),
            first["observation.environment_state"].reshape(-1, 2).numpy(),
            item["observation.environment_state"].reshape(-1, 2).numpy(),
        )
        expected = torch.as_tensor(expected, dtype=torch.float32)
        torch.testing.assert_close(item["action"], expected, atol=1e-3, rtol=0)
        carried_frames += 1
    assert carried_frames >= len(drifting) // 3


def test_the_correcting_person_is_discovered_like_the_robot() -> None:
    """LeRobot's plugin discovery and teleoperator factory build it from ``--teleop.type=pusht_nudge``."""
    import subprocess
    import sys

    code = (
        "from lerobot.utils.import_utils import register_third_party_plugins as r; r();"
        "import draccus;"
        "from lerobot.teleoperators.config import TeleoperatorConfig;"
        "from lerobot.teleoperators.utils import make_teleoperator_from_config;"
        "cfg = draccus.decode(TeleoperatorConfig, {'type': 'pusht_nudge', 'notice_speed': 0.5});"
        "t = make_teleoperator_from_config(cfg);"
        "print(type(t).__name__, t.config.notice_speed, sorted(t.feedback_features)[:2])"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split()[-4:] == ["PushTNudge", "0.5", "['chunk_step',", "'command.x.pos']"]
