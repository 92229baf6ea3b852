"""``dcdp-robot-client``: the corrector on the robot's computer, the base in LeRobot's stock policy server.

On the base's machine (a copy made once by ``dcdp-serve-base``, see :mod:`lerobot_dcdp.deploy.serve_base`)::

    dcdp-serve-base --base models/pusht-diffusion-state --out /srv/served/pusht-diffusion-state
    python -m lerobot.async_inference.policy_server --host=0.0.0.0 --port=8080

On the robot's computer::

    dcdp-robot-client --server_address=base-host:8080 --robot.type=pusht_sim \\
        --policy.path=models/pusht-dcdp-state --base_path=/srv/served/pusht-diffusion-state \\
        --fps=10 --duration=30 --actions_per_chunk=16

Every tick (``1 / fps`` s) the client reads the robot, hands the raw observation to the
:class:`~lerobot_dcdp.deploy.remote_planner.RemotePlanner` (only on the ticks the policy computes when
``--policy.ticks_per_step`` > 1, so the base's frames keep its own rate), and asks the DCDP policy
(``planning=async``) for the corrected action of the chunk being executed: the policy corrects every action
with the newest observation and the observation its chunk was planned from; when the chunk nears its end it
submits the newest observation to the planner, which sends it to the server and returns the timed chunk
(LeRobot's ``TimedAction`` list, normalised back with the base's statistics). After ``--duration`` seconds the
client disconnects the robot and exits 0. A robot that starts episodes by itself (``pusht_sim`` with
``--robot.episode_steps``) does not tell the client: the policy is not reset at the boundary, and the
corrector reads the scene's jump as motion until its next chunk, as LeRobot's stock client keeps executing its
queue.

Flags follow LeRobot's ``RobotClientConfig`` (``lerobot/async_inference/configs.py``) where they mean the
same: ``--server_address``, ``--robot.*``, ``--fps``, ``--actions_per_chunk``, ``--chunk_size_threshold``,
``--task``, ``--policy_device`` (the server's device); the policy is the corrector, named the
``lerobot-rollout`` way (``--policy.path``, with ``--policy.*`` overrides), not ``--pretrained_name_or_path``
(that is ``--base_path`` here: the served base, as a path on the server's machine). LeRobot's
``aggregate_fn_name`` has no counterpart: a new chunk replaces the old one from the action planned for the
current tick on, and the corrector absorbs the change (no blending of overlapping chunks).
"""

# no ``from __future__ import annotations``: LeRobot's parser.wrap reads the config class from the
# annotation of _client's argument
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

from lerobot.configs import parser
from lerobot.configs.policies import PreTrainedConfig
from lerobot.robots import RobotConfig

logger = logging.getLogger(__name__)


@dataclass
class DCDPRobotClientConfig:
    """Flags of ``dcdp-robot-client``.

    Args:
        robot: The robot (``--robot.type=...`` and its flags).
        policy: The DCDP corrector (``--policy.path=<folder or Hub id>``; ``--policy.*`` overrides it).
        server_address: ``host:port`` of ``python -m lerobot.async_inference.policy_server``.
        base_path: The served base (``dcdp-serve-base``'s ``--out``) as a path on the server's machine;
            default: the corrector's base folder, for a server on this machine.
        base_config_dir: A local folder with the base's ``config.json`` and processor files (its weights are
            not read); default: the corrector's base.
        fps: Control ticks per second (the robot's control rate; also the server's timestamps assume its
            own ``--fps``).
        duration: Seconds to run (round(duration * fps) ticks); then the robot is disconnected and the client
            exits 0.
        actions_per_chunk: The most actions the server returns per chunk (at least the corrector's
            ``n_action_steps``; more lets a chunk that arrives late still cover a whole horizon).
        chunk_size_threshold: Fraction of the chunk still to execute when the next one is requested (LeRobot's
            meaning: ``remaining / chunk <= threshold``); ``None``: the policy's own wall-clock lead
            (``planning_clock='wall'``: planning time / tick period + 1 ticks).
        task: The task sent with every observation (language-conditioned bases); empty: none.
        policy_device: Device the server runs the base on.
        timeout_s: Deadline of each server call; the first connection waits as long for the server.
    """

    robot: RobotConfig
    policy: PreTrainedConfig | None = None
    server_address: str = "localhost:8080"
    base_path: str | None = None
    base_config_dir: str | None = None
    fps: int = 30
    duration: float = 30.0
    actions_per_chunk: int = 50
    chunk_size_threshold: float | None = None
    task: str = ""
    policy_device: str = "cpu"
    timeout_s: float = 60.0

    def __post_init__(self) -> None:
        policy_path = parser.get_path_arg("policy")
        if policy_path:
            overrides = parser.get_cli_overrides("policy") or []
            self.policy = PreTrainedConfig.from_pretrained(policy_path, cli_overrides=overrides)
            self.policy.pretrained_path = policy_path
        if self.fps <= 0 or self.duration <= 0 or self.actions_per_chunk < 1:
            raise ValueError(
                f"fps, duration and actions_per_chunk must be positive: {self.fps}, {self.duration}, "
                f"{self.actions_per_chunk}"
            )
        if self.chunk_size_threshold is not None and not 0 <= self.chunk_size_threshold <= 1:
            raise ValueError(f"chunk_size_threshold must be in [0, 1], got {self.chunk_size_threshold}")

    @classmethod
    def __get_path_fields__(cls) -> list[str]:
        """``--policy.path`` loads the corrector's config (LeRobot's parser)."""
        return ["policy"]


def make_policy(cfg: DCDPRobotClientConfig):
    """The DCDP corrector, planning asynchronously on the remote base (``base_location='remote'``): only the
    base's ``config.json`` and processor files are read here (``--base_config_dir``, default the corrector's
    base folder), never its weights."""
    from lerobot_dcdp.policy.loader import load_dcdp

    if cfg.policy is None or cfg.policy.pretrained_path is None:
        raise ValueError("--policy.path is required (the DCDP corrector)")
    if cfg.policy.type != "dcdp":
        raise ValueError(f"--policy.path must be a dcdp corrector, got type {cfg.policy.type!r}")
    cfg.policy.planning, cfg.policy.base_location = "async", "remote"
    if cfg.base_config_dir:
        cfg.policy.base_policy_path = str(Path(cfg.base_config_dir).resolve())
    return load_dcdp(cfg.policy.pretrained_path, config=cfg.policy).policy


def ticks_of(cfg: DCDPRobotClientConfig) -> int:
    """The control ticks a run takes: ``duration`` seconds at ``fps``, at least one."""
    return max(1, round(cfg.duration * cfg.fps))


def _drive(
    cfg: DCDPRobotClientConfig, policy, robot, planner, pre, post, device
) -> tuple[list[float], list[float]]:
    """The control loop, ``round(cfg.duration * cfg.fps)`` ticks: every ``1 / fps`` s read ``robot``, show the
    planner the raw observation (on the ticks the policy computes) and send the corrected action (the batch on
    ``device``). The count of ticks is fixed; a tick that overruns its period delays the next ones.

    Returns:
        Each tick's seconds, and the robot's own share of them (reading it, sending it the action).
    """
    import torch
    from lerobot.policies.utils import build_inference_frame, make_robot_action
    from lerobot.utils.constants import ACTION, OBS_STR
    from lerobot.utils.feature_utils import hw_to_dataset_features

    obs_features = hw_to_dataset_features(robot.observation_features, OBS_STR, use_video=False)
    act_features = hw_to_dataset_features(robot.action_features, ACTION, use_video=False)
    period = 1.0 / cfg.fps
    tick_s: list[float] = []
    robot_s: list[float] = []
    for _ in range(ticks_of(cfg)):
        start = time.perf_counter()
        raw = robot.get_observation()
        read = time.perf_counter() - start
        if not policy.holds_next_tick:  # --policy.ticks_per_step: the base's frames at its own rate
            planner.observe(raw)
        batch = pre(build_inference_frame(dict(raw), device, obs_features, task=cfg.task or None))
        with torch.no_grad():
            action = post(policy.select_action(batch))
        command = make_robot_action(action, act_features)
        sent = time.perf_counter()
        robot.send_action(command)
        spent = time.perf_counter() - start
        tick_s.append(spent)
        robot_s.append(read + start + spent - sent)
        time.sleep(max(0.0, period - spent))
    return tick_s, robot_s


def _summary(tick_s: list[float], robot_s: list[float], planner, period: float) -> dict[str, float]:
    """:func:`run`'s counters from the ticks' seconds, the robot's share of them and the planner's counts."""
    import numpy as np

    ticks = np.asarray(tick_s) * 1000
    after_first = ticks[1:] if len(ticks) > 1 else ticks
    policy_ms = ticks - np.asarray(robot_s) * 1000
    policy_after_first = policy_ms[1:] if len(ticks) > 1 else policy_ms
    return {
        "ticks": len(ticks),
        "chunks": planner.chunks_taken,
        "late_ticks": int((ticks > 1000 * period).sum()),
        "mean_tick_ms": float(ticks.mean()) if len(ticks) else 0.0,
        "p99_tick_ms": float(np.percentile(after_first, 99)) if len(ticks) else 0.0,
        "max_tick_ms": float(after_first.max()) if len(ticks) else 0.0,
        "p99_policy_ms": float(np.percentile(policy_after_first, 99)) if len(ticks) else 0.0,
        "max_policy_ms": float(policy_after_first.max()) if len(ticks) else 0.0,
        "mean_plan_ms": 1000 * planner.plan_seconds / max(planner.chunks_taken, 1),
    }


def run(cfg: DCDPRobotClientConfig, policy=None, robot=None) -> dict[str, float]:
    """Drive ``robot`` with ``policy`` for ``cfg.duration`` seconds, the base planning on the server.

    Args:
        cfg: The flags.
        policy: A DCDP policy (``planning='async'``); default: :func:`make_policy`.
        robot: A robot; default: made from ``cfg.robot`` and connected here (and disconnected at the end).

    Returns:
        Counters of the run: ``ticks``, ``chunks`` (from the server), ``late_ticks`` (ticks longer than
        ``1 / fps``), ``mean_tick_ms``, ``p99_tick_ms`` and ``max_tick_ms`` (both after the first tick, which
        waits for the first chunk), ``p99_policy_ms`` and ``max_policy_ms`` (the same ticks without the
        robot's own time in ``get_observation`` and ``send_action``, where a simulated robot steps its world),
        ``mean_plan_ms`` (round trips to the server).

    Raises:
        ValueError: ``--actions_per_chunk`` below the corrector's ``n_action_steps`` (or a bad ``--policy``).
    """
    import torch
    from lerobot.robots import make_robot_from_config

    from lerobot_dcdp.deploy.remote_planner import RemotePlanner
    from lerobot_dcdp.policy.base_policy import resolve_base_reference
    from lerobot_dcdp.policy.loader import folder_processors

    policy = make_policy(cfg) if policy is None else policy
    pcfg = policy.config
    if pcfg.n_action_steps > cfg.actions_per_chunk:
        raise ValueError(
            f"--actions_per_chunk={cfg.actions_per_chunk} is below the corrector's n_action_steps="
            f"{pcfg.n_action_steps}: every chunk would be padded with its last action"
        )
    base_dir = cfg.base_config_dir or resolve_base_reference(pcfg.base_policy_path, pcfg.pretrained_path)
    device = torch.device(pcfg.device or "cpu")
    pre, post = folder_processors(pcfg, pcfg.pretrained_path, str(device))
    own_robot = robot is None
    if own_robot:
        robot = make_robot_from_config(cfg.robot)
        robot.connect()
    planner = RemotePlanner.from_base_dir(
        cfg.server_address,
        base_dir,
        robot.observation_features,
        base_path=cfg.base_path or str(Path(base_dir).resolve()),
        actions_per_chunk=cfg.actions_per_chunk,
        policy_device=cfg.policy_device,
        task=cfg.task or None,
        timeout_s=cfg.timeout_s,
    )
    try:
        planner.connect()  # the server loads the base before the clock starts
        lead = None
        if cfg.chunk_size_threshold is not None:  # LeRobot's meaning: remaining / chunk <= threshold
            lead = max(1, math.ceil(cfg.chunk_size_threshold * pcfg.n_action_steps))
        policy.attach_planner(planner, lead)
        tick_s, robot_s = _drive(cfg, policy, robot, planner, pre, post, device)
    finally:
        planner.close()
        if own_robot:
            robot.disconnect()
    summary = _summary(tick_s, robot_s, planner, 1.0 / cfg.fps)
    logger.info("dcdp-robot-client: %s", summary)
    return summary


@parser.wrap()
def _client(cfg: DCDPRobotClientConfig) -> dict[str, float]:
    return run(cfg)


def main() -> None:
    """``dcdp-robot-client`` (exits 0 after ``--duration`` seconds)."""
    from lerobot.utils.import_utils import register_third_party_plugins
    from lerobot.utils.utils import init_logging

    init_logging()
    register_third_party_plugins()  # the robot's plugin (and this one: the dcdp policy, pusht_sim)
    print(_client())


if __name__ == "__main__":
    main()
