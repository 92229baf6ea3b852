"""Tests of the ``pusht_perturbed`` env: the block-drift wrapper, its LeRobot config, ``lerobot-eval``."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import draccus
import gymnasium as gym
import numpy as np
import pytest
from lerobot.envs.configs import EnvConfig

from lerobot_dcdp.sim.envs.pusht_perturbed import (
    DEFAULT_DIRECTIONS_DEG,
    GYM_ID,
    BlockPerturbation,
    PushTPerturbedEnvConfig,
    make_perturbed_env,
)
from lerobot_dcdp.sim.pusht_geometry import ARENA_HI, ARENA_LO, block_vertices

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
OBS = "environment_state_agent_pos"
LOW_CORNER = (40.0, 40.0)
HIGH_CORNER = (470.0, 470.0)


def _env(**kwargs) -> gym.Env:
    return make_perturbed_env(obs_type=OBS, **kwargs)


def _place(
    env: gym.Env, agent=LOW_CORNER, block=(300.0, 300.0), angle: float = 0.0, seed: int | None = 0
) -> tuple:
    """Reset with the agent parked in a corner and the block at ``block`` (body origin), angle ``angle``."""
    return env.reset(seed=seed, options={"reset_to_state": [*agent, *block, angle]})


def _block_xy(env: gym.Env) -> np.ndarray:
    return np.array(env.unwrapped.block.position, dtype=float)


def _unit(deg: float) -> np.ndarray:
    return np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])


@pytest.mark.parametrize(
    ("direction_deg", "magnitude"), [(45.0, 1.0), (0.0, 0.5), (-135.0, 3.0), (90.0, 2.0)]
)
def test_constant_drift_per_step_equals_magnitude(direction_deg: float, magnitude: float) -> None:
    env = _env(perturbation="constant", magnitude=magnitude, direction_deg=direction_deg)
    _place(env)
    park = np.array(LOW_CORNER)  # the agent holds its corner, far from the block
    for _ in range(10):
        before = _block_xy(env)
        _, _, _, _, info = env.step(park)
        drift = _block_xy(env) - before
        assert np.linalg.norm(drift) == pytest.approx(magnitude, abs=1e-9)
        np.testing.assert_allclose(drift, magnitude * _unit(direction_deg), atol=1e-9)
        np.testing.assert_allclose(info["perturbation_offset"], drift, atol=1e-9)
        assert info["perturbation_direction_deg"] == direction_deg
        assert not info["perturbation_clipped"]
        assert info["n_contacts"] == 0
    env.close()


def test_none_mode_is_static_and_reports_zero_offset() -> None:
    env = _env(perturbation="none", magnitude=5.0)
    _, info = _place(env)
    assert math.isnan(info["perturbation_direction_deg"])
    before = _block_xy(env)
    for _ in range(5):
        _, _, _, _, info = env.step(np.array(LOW_CORNER))
        np.testing.assert_array_equal(info["perturbation_offset"], np.zeros(2))
    np.testing.assert_allclose(_block_xy(env), before, atol=1e-9)
    env.close()


def test_random_direction_changes_only_at_multiples_of_resample_every() -> None:
    every, n_steps, magnitude = 5, 60, 0.5
    env = _env(perturbation="random", magnitude=magnitude, resample_every=every)
    _, info = _place(env, seed=123)
    dirs = [info["perturbation_direction_deg"]]
    for _ in range(n_steps):
        before = _block_xy(env)
        _, _, _, _, info = env.step(np.array(LOW_CORNER))
        d = info["perturbation_direction_deg"]
        assert d in DEFAULT_DIRECTIONS_DEG
        np.testing.assert_allclose(_block_xy(env) - before, magnitude * _unit(d), atol=1e-9)
        dirs.append(d)
    step_dirs = dirs[1:]  # step_dirs[t] = direction used by step t (0-based)
    assert step_dirs[0] == dirs[0]  # the direction drawn at reset is used from step 0
    for t in range(1, n_steps):
        if t % every != 0:
            assert step_dirs[t] == step_dirs[t - 1], f"direction changed at step {t}"
    changes = [t for t in range(1, n_steps) if step_dirs[t] != step_dirs[t - 1]]
    assert changes and all(t % every == 0 for t in changes)
    env.close()


def _offset_sequence(env: gym.Env, seed: int | None, n: int = 40) -> np.ndarray:
    env.reset(seed=seed)
    out = []
    for _ in range(n):
        out.append(env.step(np.array([256.0, 256.0]))[4]["perturbation_offset"])
    return np.array(out)


def test_perturbation_sequence_is_a_function_of_the_seed() -> None:
    env = _env(perturbation="random", magnitude=1.0, resample_every=3)
    a = _offset_sequence(env, 7)
    b = _offset_sequence(env, 8)
    a2 = _offset_sequence(env, 7)
    np.testing.assert_array_equal(a, a2)
    assert not np.allclose(a, b)
    # Without a seed the stream continues (it does not restart from the last seed).
    c = _offset_sequence(env, None)
    assert not np.allclose(a, c)
    # A fresh env with the same seed agrees too.
    np.testing.assert_array_equal(_offset_sequence(_env(perturbation="random", resample_every=3), 7), a)
    env.close()


@pytest.mark.parametrize(
    ("direction_deg", "agent"),
    [(0.0, LOW_CORNER), (45.0, LOW_CORNER), (90.0, LOW_CORNER), (-135.0, HIGH_CORNER)],
)
def test_block_never_leaves_the_arena(direction_deg: float, agent: tuple[float, float]) -> None:
    env = _env(perturbation="constant", magnitude=4.0, direction_deg=direction_deg)
    _place(env, agent=agent, block=(256.0, 200.0), angle=0.3)
    clipped = []
    for _ in range(150):  # 600 px of requested drift
        _, _, _, _, info = env.step(np.array(agent))
        verts = block_vertices(tuple(env.unwrapped.block.position), float(env.unwrapped.block.angle))
        assert verts.min() >= ARENA_LO - 1e-6 and verts.max() <= ARENA_HI + 1e-6
        clipped.append(info["perturbation_clipped"])
    assert clipped[-1] and not clipped[0]
    assert np.linalg.norm(info["perturbation_offset"]) < 4.0
    env.close()


def test_coverage_reward_and_success_match_a_fresh_computation() -> None:
    env = _env(perturbation="constant", magnitude=0.25, direction_deg=0.0)
    _place(env)
    base = env.unwrapped
    base.block.angle = math.pi / 4  # exact goal pose: angle first, then position
    base.block.position = (256.0, 256.0)
    coverages = []
    for _ in range(40):
        obs, reward, terminated, _, info = env.step(np.array(LOW_CORNER))
        fresh = base._get_coverage()
        assert info["coverage"] == pytest.approx(fresh, abs=1e-12)
        assert reward == pytest.approx(float(np.clip(fresh / 0.95, 0.0, 1.0)), abs=1e-12)
        assert info["is_success"] == (fresh > 0.95) == terminated
        np.testing.assert_allclose(info["block_pose"][:2], _block_xy(env), atol=1e-9)
        verts = block_vertices(tuple(base.block.position), float(base.block.angle))
        np.testing.assert_allclose(obs["environment_state"].reshape(8, 2), verts, atol=1e-6)
        coverages.append(fresh)
    assert coverages[0] > 0.95 and coverages[-1] < 0.95  # drift pushes it off the goal
    env.close()


def test_gymnasium_check_env_and_registered_id() -> None:
    from gym_pusht.envs.pusht import PushTEnv
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(
            BlockPerturbation(PushTEnv(obs_type=OBS), perturbation="random", magnitude=1.0, resample_every=2),
            skip_render_check=True,
        )
    env = gym.make(GYM_ID, obs_type=OBS, perturbation="constant", magnitude=1.0)
    assert env.spec.max_episode_steps == 300
    assert env.get_wrapper_attr("task_description")
    assert isinstance(env.unwrapped, PushTEnv)
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "field_name"),
    [
        ({"perturbation": "sideways"}, "perturbation"),
        ({"magnitude": -1.0}, "magnitude"),
        ({"magnitude": float("nan")}, "magnitude"),
        ({"direction_deg": float("inf")}, "direction_deg"),
        ({"resample_every": 0}, "resample_every"),
        ({"directions_deg": []}, "directions_deg"),
        ({"directions_deg": [0.0, float("nan")]}, "directions_deg"),
        ({"episode_length": 0}, "episode_length"),
    ],
)
def test_config_validation_names_the_field(kwargs: dict, field_name: str) -> None:
    with pytest.raises(ValueError, match=field_name):
        PushTPerturbedEnvConfig(**kwargs)
    if field_name != "episode_length":
        from gym_pusht.envs.pusht import PushTEnv

        with pytest.raises(ValueError, match=field_name):
            BlockPerturbation(PushTEnv(obs_type=OBS), **kwargs)


@dataclass
class _EnvOnly:
    env: EnvConfig


def test_cli_flags_and_config_files_parse() -> None:
    cfg = draccus.parse(
        _EnvOnly,
        args=[
            "--env.type=pusht_perturbed",
            "--env.perturbation=random",
            "--env.magnitude=2",
            "--env.resample_every=25",
            "--env.directions_deg=[0,90]",
            f"--env.obs_type={OBS}",
            "--env.episode_length=100",
        ],
    ).env
    assert isinstance(cfg, PushTPerturbedEnvConfig) and cfg.type == "pusht_perturbed"
    kw = cfg.gym_kwargs
    assert kw["max_episode_steps"] == 100 and kw["obs_type"] == OBS
    assert kw["perturbation"] == "random" and kw["magnitude"] == 2.0 and kw["directions_deg"] == (0.0, 90.0)
    assert "observation.environment_state" in {cfg.features_map[k] for k in cfg.features}

    expected = {
        "pusht_static": ("none", None),
        "pusht_constant_0.5": ("constant", 0.5),
        "pusht_random_0.5": ("random", 0.5),
        "pusht_constant_1.0": ("constant", 1.0),
        "pusht_random_1.0": ("random", 1.0),
    }
    for stem, (mode, magnitude) in expected.items():
        path = REPO / "configs" / "env" / f"{stem}.json"
        env_cfg = draccus.parse(_EnvOnly, config_path=path, args=[]).env
        assert isinstance(env_cfg, PushTPerturbedEnvConfig), stem
        assert env_cfg.perturbation == mode, stem
        if magnitude is not None:
            assert env_cfg.magnitude == magnitude, stem


def test_sync_vector_env_structure() -> None:
    cfg = PushTPerturbedEnvConfig(obs_type=OBS, perturbation="constant", magnitude=1.0, episode_length=5)
    envs = cfg.create_envs(n_envs=2, use_async_envs=False)
    assert list(envs) == ["pusht_perturbed"] and list(envs["pusht_perturbed"]) == [0]
    vec = envs["pusht_perturbed"][0]
    assert isinstance(vec, gym.vector.SyncVectorEnv)
    _, info = vec.reset(seed=[1, 2], options={"lerobot_new_rollout": True})
    assert list(vec.call("task_description")) == [BlockPerturbation.task_description] * 2
    assert list(vec.call("_max_episode_steps")) == [5, 5]
    _, _, _, _, info = vec.step(np.full((2, 2), 256.0))
    assert info["perturbation_offset"].shape == (2, 2) and "is_success" in info
    # Success reaches the rollout via `info["is_success"]` (NEXT_STEP autoreset), then the sub-env freezes.
    park = np.array([LOW_CORNER, LOW_CORNER])
    vec.reset(
        seed=[1, 2], options={"lerobot_new_rollout": True, "reset_to_state": [*LOW_CORNER, 300, 300, 0]}
    )
    block = vec.envs[0].unwrapped.block
    block.angle, block.position = math.pi / 4, (256.0, 256.0)  # exact goal pose in sub-env 0
    _, _, terminated, _, info = vec.step(park)
    assert terminated.tolist() == [True, False] and info["is_success"].tolist() == [True, False]
    frozen = tuple(block.position)
    for _ in range(3):
        vec.step(park)
    assert tuple(block.position) == frozen  # no more drift: the finished sub-env is frozen
    vec.close()


# --------------------------------------------------------------------------------------------------------
# End to end: the real `lerobot-eval` CLI, plugin discovered by LeRobot itself, async (forkserver) envs.


@pytest.fixture(scope="module")
def tiny_diffusion_base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from helpers import make_tiny_base

    root = tmp_path_factory.mktemp("pusht_env") / "demos"
    subprocess.run(
        [str(BIN / "dcdp-pusht-demos"), "--root", str(root), "--episodes", "2", "--workers", "1"],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return make_tiny_base("diffusion", root.parent / "base", root)


@pytest.mark.slow
def test_lerobot_eval_cli_async(tiny_diffusion_base: Path, tmp_path: Path) -> None:
    out = tmp_path / "eval"
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [
            str(BIN / "lerobot-eval"),
            f"--policy.path={tiny_diffusion_base}",
            "--env.type=pusht_perturbed",
            "--env.perturbation=constant",
            "--env.magnitude=1",
            f"--env.obs_type={OBS}",
            "--env.episode_length=20",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            "--eval.use_async_envs=true",
            f"--output_dir={out}",
        ],
        capture_output=True,
        text=True,
        timeout=540,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    info = json.loads((out / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 2
    (task,) = info["per_task"]
    assert task["task_group"] == "pusht_perturbed"
    assert len(task["metrics"]["max_rewards"]) == len(task["metrics"]["successes"]) == 2
