"""The base on another machine: ``RemotePlanner`` against LeRobot's stock policy server on loopback.

The ACT test starts the real CLI (``python -m lerobot.async_inference.policy_server``) in a subprocess; the
diffusion test serves LeRobot's own ``PolicyServer`` class in this process (as its ``serve()`` does), so
that one seed gives the server's sampler and the local base the same noise. Both drive the ``pusht_sim``
robot in lock-step and compare every chunk with the one the shipped base computes locally from the same
observations (what ``DCDPPolicy`` gets from ``ChunkSource``). The last test runs ``dcdp-robot-client`` against
the stock CLI for 3 s.
"""

from __future__ import annotations

import ast
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from concurrent import futures
from pathlib import Path

import grpc
import pytest
import torch
from lerobot.policies.utils import build_inference_frame
from lerobot.processor import PolicyProcessorPipeline
from lerobot.processor.converters import batch_to_transition, transition_to_batch
from lerobot.utils.constants import OBS_STR
from lerobot.utils.feature_utils import hw_to_dataset_features

import lerobot_policy_dcdp  # noqa: F401  (registers the plugin's types)
from lerobot_dcdp.deploy.remote_planner import RemotePlanner, RemotePlanningError, remote_features
from lerobot_dcdp.deploy.serve_base import (
    HISTORY_STEP_CLASS,
    SPLIT_STEP_CLASS,
    make_server_base,
    served_steps,
)
from lerobot_dcdp.policy.base_policy import load_base_policy
from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep
from lerobot_dcdp.policy.processor_state_history import StateHistoryProcessorStep
from lerobot_dcdp.runtime.chunk_sources import ChunkSource
from lerobot_dcdp.sim.robots import PushTSim, PushTSimConfig

REPO = Path(__file__).resolve().parents[1]
ACT, DIFFUSION = REPO / "models" / "pusht-act-state", REPO / "models" / "pusht-diffusion-state"
FPS = 10  # pusht_sim's control rate


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def stock_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The stock CLI on a free loopback port (its log and ``logs/`` in a temporary folder)."""
    work = tmp_path_factory.mktemp("server")
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    cmd = [sys.executable, "-m", "lerobot.async_inference.policy_server", "--host=127.0.0.1"]
    cmd += [f"--port={port}", f"--fps={FPS}", "--inference_latency=0"]
    with open(work / "server.log", "w") as log:
        proc = subprocess.Popen(cmd, cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[PushTSim]:
    sim = PushTSim(PushTSimConfig(calibration_dir=tmp_path / "calib", seed=3, realtime=False))
    sim.connect()
    yield sim
    sim.disconnect()


def local_pre(base, path: Path) -> PolicyProcessorPipeline:
    """The corrector's pre-processor for ``base``: ``dcdp_split_state`` then the base's own pipeline."""
    pre = PolicyProcessorPipeline.from_pretrained(
        str(path),
        "policy_preprocessor.json",
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    split = SplitStateProcessorStep.from_features(base.config.input_features)
    return PolicyProcessorPipeline(
        steps=[split, *pre.steps], to_transition=batch_to_transition, to_output=transition_to_batch
    )


def drive(
    robot: PushTSim, planner: RemotePlanner, base_dir: Path, ticks: int, submit_at: set[int], seed=None
) -> list:
    """Run the robot for ``ticks`` lock-step ticks; at each tick in ``submit_at`` plan remotely and locally
    from that tick's observation (and history); the robot follows the newest remote chunk. Returns
    ``[(remote job, local chunk, the local base's observation queues)]``."""
    base = load_base_policy(str(base_dir), "cpu")
    source, pre = ChunkSource(base), local_pre(base, base_dir)
    source.reset()
    features = hw_to_dataset_features(robot.observation_features, OBS_STR, use_video=False)
    pairs, job = [], None
    for t in range(ticks):
        raw = robot.get_observation()
        planner.observe(raw)
        prepared = source.observe(pre(build_inference_frame(dict(raw), torch.device("cpu"), features)))
        if t in submit_at:
            if seed is not None:
                torch.manual_seed(seed + t)
            planner.submit(t, prepared, None, 12, context=("ctx", t))
            assert planner.pending and planner.t_obs == t
            job = planner.take(wait=True)
            assert not planner.pending
            if seed is not None:
                torch.manual_seed(seed + t)
            pairs.append((job, source.chunk(prepared, min(12, source.max_length)), source.snapshot()))
        x, y = job.raw[0, min(t - job.t_obs, job.raw.shape[1] - 1)].tolist() if job else (256.0, 256.0)
        robot.send_action({"x.pos": x, "y.pos": y})
    return pairs


def test_served_copy_layout(tmp_path: Path) -> None:
    out = make_server_base(DIFFUSION, tmp_path / "served")
    steps = json.loads((out / "policy_preprocessor.json").read_text())["steps"]
    assert [s.get("class") for s in steps[:2]] == [HISTORY_STEP_CLASS, SPLIT_STEP_CLASS]
    assert steps[0]["config"] == {"n_obs_steps": 2, "width": 18}
    assert "registry_name" not in steps[0] and "registry_name" not in steps[1]
    assert json.loads((out / "config.json").read_text())["n_action_steps"] == 16 - 2 + 1
    assert (out / "model.safetensors").read_bytes() == (DIFFUSION / "model.safetensors").read_bytes()
    # again over an existing copy: replaced, and our steps are not added twice
    make_server_base(out, tmp_path / "served")
    assert len(json.loads((out / "policy_preprocessor.json").read_text())["steps"]) == len(steps)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left
    act = make_server_base(ACT, tmp_path / "act")
    act_steps = json.loads((act / "policy_preprocessor.json").read_text())["steps"]
    assert act_steps[0].get("class") == SPLIT_STEP_CLASS and "class" not in act_steps[1]  # no history
    with pytest.raises(ValueError, match="config.json"):
        make_server_base(tmp_path / "nowhere", tmp_path / "x")


def test_history_step_and_features() -> None:
    step = StateHistoryProcessorStep(n_obs_steps=2, width=3)
    two = {"observation.state": torch.arange(6.0).reshape(1, 6)}
    assert step.observation(two)["observation.state"].tolist() == [[[0, 1, 2], [3, 4, 5]]]
    one = step.observation({"observation.state": torch.tensor([[7.0, 8, 9]])})["observation.state"]
    assert one.tolist() == [[[7, 8, 9], [7, 8, 9]]]
    with pytest.raises(ValueError, match="expected 2 frames of 3"):
        step.observation({"observation.state": torch.zeros(1, 4)})
    feats = remote_features({"a.pos": float, "b.pos": float}, n_obs_steps=3)
    assert feats["observation.state"]["names"] == ["a.pos@t-2", "b.pos@t-2", "a.pos@t-1", "b.pos@t-1"] + [
        "a.pos",
        "b.pos",
    ]
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    cams = DiffusionConfig(
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(2,)),
            "observation.images.top": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 96, 96)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(2,))},
    )
    with pytest.raises(ValueError, match="image history"):
        served_steps(cams)


def test_act_on_the_stock_server(stock_server: str, robot: PushTSim, tmp_path: Path) -> None:
    # the shipped base as saved: the server cannot feed it the robot's 18-wide state
    plain = RemotePlanner.from_base_dir(stock_server, ACT, robot.observation_features, timeout_s=60)
    plain.observe(robot.get_observation())
    plain.submit(0, {}, None, 8)
    with pytest.raises(RemotePlanningError, match="returned no actions"):
        plain.take(wait=True)
    plain.close()

    served = make_server_base(ACT, tmp_path / "act")
    planner = RemotePlanner.from_base_dir(
        stock_server, served, robot.observation_features, actions_per_chunk=12, timeout_s=60
    )
    try:
        pairs = drive(robot, planner, ACT, ticks=6, submit_at={0, 2, 5})
    finally:
        planner.close()
    assert len(pairs) == 3
    for (job, local, _), t in zip(pairs, (0, 2, 5), strict=True):
        assert job.t_obs == t and job.context == ("ctx", t) and job.seconds > 0
        assert job.chunk.shape == local.shape == (1, 12, 2)
        torch.testing.assert_close(job.chunk, local, atol=1e-5, rtol=1e-5)
        assert job.timesteps == list(range(t, t + 12))
        steps = torch.tensor(job.timestamps, dtype=torch.float64).diff()  # Unix time: float64
        torch.testing.assert_close(steps, torch.full_like(steps, 1 / FPS), atol=1e-4, rtol=0)
    # a cancelled request is waited for and dropped; the planner stays usable, then closes
    planner.observe(robot.get_observation())
    planner.submit(9, {}, None, 4)
    planner.cancel()
    assert not planner.pending and planner.take(wait=True) is None
    with pytest.raises(RemotePlanningError, match="no robot observation"):
        planner.submit(10, {}, None, 4)  # cancel() forgot the frames (a new episode)
    planner.close()


@pytest.fixture
def in_process_server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """LeRobot's ``PolicyServer`` served on a free loopback port in this process, as its ``serve()`` does."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    monkeypatch.chdir(tmp_path)  # importing it makes logs/ in the working directory and resets logging
    from lerobot.async_inference.configs import PolicyServerConfig
    from lerobot.async_inference.policy_server import PolicyServer
    from lerobot.transport import services_pb2_grpc

    root.handlers[:], root.level = handlers, level
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=4))
    config = PolicyServerConfig(host="127.0.0.1", port=1, fps=FPS, inference_latency=0.0)
    services_pb2_grpc.add_AsyncInferenceServicer_to_server(PolicyServer(config), server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        yield f"127.0.0.1:{port}"
    finally:
        server.stop(grace=None)


def test_diffusion_history_on_the_server(in_process_server: str, robot: PushTSim, tmp_path: Path) -> None:
    served = make_server_base(DIFFUSION, tmp_path / "diffusion")
    planner = RemotePlanner.from_base_dir(
        in_process_server, served, robot.observation_features, actions_per_chunk=12, timeout_s=60
    )
    assert planner.n_obs_steps == 2
    planner.connect()  # the server loads the base now, not between the seed and the sample
    try:
        pairs = drive(robot, planner, DIFFUSION, ticks=5, submit_at={0, 3}, seed=1234)
    finally:
        planner.close()
    for job, local, _ in pairs:
        assert job.chunk.shape == local.shape == (1, 12, 2)  # 12 of the 15 the served copy returns
        torch.testing.assert_close(job.chunk, local, atol=1e-4, rtol=1e-4)
    # the second chunk's two frames differ (the agent moved): the server saw the same history as the base
    first, second = pairs[1][2]["observation.state"]
    assert (first - second).abs().max() > 1e-3


@pytest.mark.slow
def test_robot_client_cli(stock_server: str, tmp_path: Path) -> None:
    """``dcdp-robot-client`` drives ``pusht_sim`` for 3 s with the ACT corrector, the base on the server; the
    client reads the base's config and processors only (a folder without its weights)."""
    served = make_server_base(ACT, tmp_path / "act")
    config_only = tmp_path / "act_config_only"
    shutil.copytree(ACT, config_only, ignore=shutil.ignore_patterns("model.safetensors"))
    cmd = [str(Path(sys.executable).parent / "dcdp-robot-client"), f"--server_address={stock_server}"]
    cmd += ["--robot.type=pusht_sim", "--robot.seed=5", f"--robot.calibration_dir={tmp_path / 'calib'}"]
    cmd += [f"--policy.path={REPO / 'models' / 'pusht-dcdp-act-state'}", "--policy.compiled_kernel=off"]
    cmd += [f"--base_path={served}", f"--base_config_dir={config_only}", "--fps=10", "--duration=3"]
    cmd += ["--actions_per_chunk=16"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    done = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = ast.literal_eval(done.stdout.strip().splitlines()[-1])
    assert summary["ticks"] == 30 and summary["chunks"] >= 2, summary  # 3 s at 10 fps: a fixed tick count
    # the tick without the robot's own time (the sim steps its world in send_action) is part of the tick
    assert 0 < summary["max_policy_ms"] <= summary["max_tick_ms"], summary
    assert 0 < summary["p99_policy_ms"] <= summary["p99_tick_ms"] + 1e-9, summary
