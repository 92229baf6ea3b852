"""Planning on another machine: the base runs in LeRobot's stock policy server, the corrector runs here.

:class:`RemotePlanner` offers :class:`~lerobot_dcdp.runtime.planner.BackgroundPlanner`'s interface
(``submit`` /
``pending`` / ``t_obs`` / ``take`` / ``cancel`` / ``close``, jobs with ``.chunk``, ``.t_obs``, ``.seconds``,
``.context``), so ``DCDPPolicy``'s asynchronous path can plan with it unchanged, but each chunk is planned by
``python -m lerobot.async_inference.policy_server`` over gRPC, with LeRobot's own protocol (its
``services_pb2_grpc`` stub, ``RemotePolicyConfig``, ``TimedObservation``, ``TimedAction``):

1. ``connect()``: ``Ready`` (the server forgets earlier clients' state), then ``SendPolicyInstructions``
   with a pickled ``RemotePolicyConfig`` naming the served base *as a path on the server's machine* (a copy
   made by ``dcdp-serve-base``), the robot's features (``lerobot_features``, as LeRobot's ``RobotClient``
   builds them) and ``actions_per_chunk``. The server loads the base then.
2. per chunk, on a worker thread: ``SendObservations`` streams a pickled ``TimedObservation`` (the *raw* robot
   observation of control step ``t_obs``, ``timestep=t_obs``, ``must_go=True`` so the server's similarity
   filter never drops it), then ``GetActions`` returns a pickled ``list[TimedAction]``: the base's chunk
   from that observation, one action per control step, ``timestep = t_obs + i``, ``timestamp = observation
   timestamp + i / server fps``, each action ``(A,)`` *un-normalised* by the base's post-processor (the
   server squeezes a batch of one). An empty reply means the server failed on (and logged) the observation.
3. the chunk is normalised back to the base's normalised space with the base's saved action statistics
   (``correction.normalize``, the inverse of the server's unnormaliser up to float rounding) and returned
   as ``(1, L, A)``, ``L = min(actions_per_chunk, what the base returns, length asked)``.

The server builds the base's input from raw robot values, not from the policy's normalised batch, so the
planner needs the robot's observation of every control step: call :meth:`RemotePlanner.observe` with
``robot.get_observation()`` once per tick *before* ``policy.select_action`` (with the policy's
``ticks_per_step`` > 1 only on the ticks it computes, ``not policy.holds_next_tick``); ``submit`` ignores
``prepared`` and ``snapshot`` (it reads only the batch size and device from ``prepared``) and sends the newest
observed frame, with the ``n_obs_steps - 1`` frames before it packed into ``observation.state`` for a base
that reads a history (``dcdp_state_history`` on the server side).
"""

from __future__ import annotations

import pickle  # nosec B403: LeRobot's protocol pickles its messages
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import grpc
import torch
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedAction, TimedObservation
from lerobot.transport import services_pb2, services_pb2_grpc  # type: ignore[attr-defined]
from lerobot.transport.utils import grpc_channel_options, send_bytes_in_chunks
from lerobot.utils.constants import ACTION, OBS_STATE, OBS_STR
from lerobot.utils.feature_utils import hw_to_dataset_features
from torch import Tensor

from lerobot_dcdp.model.correction import check_normalization, normalize
from lerobot_dcdp.runtime.planner import OneJobWorker, PlannedChunk


class RemotePlanningError(RuntimeError):
    """The policy server could not be reached, refused the base, or returned no chunk."""


@dataclass
class RemoteChunk(PlannedChunk):
    """A :class:`~lerobot_dcdp.runtime.planner.PlannedChunk` from the server, with what it sent as is.

    Attributes:
        raw: ``(1, L, A)`` the actions as the server returned them (un-normalised).
        timesteps: The server's ``TimedAction.timestep`` of each action (``t_obs + i``).
        timestamps: The server's ``TimedAction.timestamp`` of each action (observation time + i / its fps).
    """

    raw: Tensor | None = None
    timesteps: list[int] = field(default_factory=list)
    timestamps: list[float] = field(default_factory=list)


def history_name(name: str, lag: int) -> str:
    """The raw-observation key under which the value of feature ``name`` ``lag`` steps ago is sent."""
    return f"{name}@t-{lag}"


def remote_features(observation_features: Mapping[str, Any], n_obs_steps: int = 1) -> dict[str, dict]:
    """The ``lerobot_features`` the server builds the observation from.

    LeRobot's ``map_robot_keys_to_lerobot_features`` (the robot's scalar features in one
    ``observation.state``, each camera as ``observation.images.<name>``), with ``observation.state``
    holding ``n_obs_steps`` frames, oldest first: the older ones under :func:`history_name` keys.
    """
    feats = hw_to_dataset_features(dict(observation_features), OBS_STR, use_video=False)
    if n_obs_steps > 1 and OBS_STATE in feats:
        names = list(feats[OBS_STATE]["names"])
        packed = [history_name(n, lag) for lag in range(n_obs_steps - 1, 0, -1) for n in names] + names
        feats[OBS_STATE] = {**feats[OBS_STATE], "shape": (len(packed),), "names": packed}
    return feats


class RemotePlanner(OneJobWorker):
    """At most one chunk request to a LeRobot policy server at a time, on one worker thread.

    Args:
        server_address: ``host:port`` of ``python -m lerobot.async_inference.policy_server``.
        base_path: The served base (``dcdp-serve-base``'s output) as a path on the server's machine.
        policy_type: The base's type (``act``, ``diffusion``, ...).
        observation_features: The robot's ``observation_features`` (name -> ``float`` or image shape).
        action_stats: ``(mode, stats)`` of the base's action normaliser
            (``lerobot_dcdp.policy.base_policy.load_base_stats(...)["action"]``); ``("IDENTITY", {})`` for
            none.
        n_obs_steps: Frames the base reads; the server copy must unflatten as many (``dcdp-serve-base``).
        actions_per_chunk: The most actions the server returns per chunk (LeRobot's ``actions_per_chunk``).
        policy_device: Device the server runs the base on.
        task: Sent as the observation's ``task`` (language-conditioned bases); ``None``: not sent.
        rename_map: LeRobot's ``rename_map`` for the server's pre-processor.
        timeout_s: Deadline of each server call (seconds); the first connection waits as long for the server.
    """

    thread_name = "dcdp-remote-planner"

    def __init__(
        self,
        server_address: str,
        base_path: str,
        policy_type: str,
        observation_features: Mapping[str, Any],
        action_stats: tuple[str, Mapping[str, Tensor]],
        n_obs_steps: int = 1,
        actions_per_chunk: int = 50,
        policy_device: str = "cpu",
        task: str | None = None,
        rename_map: dict[str, str] | None = None,
        timeout_s: float = 60.0,
    ) -> None:
        if n_obs_steps < 1 or actions_per_chunk < 1:
            raise ValueError(
                f"n_obs_steps and actions_per_chunk must be >= 1: {n_obs_steps}, {actions_per_chunk}"
            )
        mode, stats = action_stats
        check_normalization(ACTION, str(mode), dict(stats))
        self._mode = str(mode)
        self._stats = {k: torch.as_tensor(v, dtype=torch.float32).reshape(-1) for k, v in stats.items()}
        self.server_address = server_address
        self.n_obs_steps = int(n_obs_steps)
        self.timeout_s = float(timeout_s)
        self.task = task
        self.features = remote_features(observation_features, self.n_obs_steps)
        one_frame = hw_to_dataset_features(dict(observation_features), OBS_STR, use_video=False)
        #: the robot's scalar features, in ``observation.state`` order (their history is packed)
        self._state_names: list[str] = list(one_frame.get(OBS_STATE, {}).get("names", []))
        self.policy_config = RemotePolicyConfig(
            policy_type,
            str(base_path),
            self.features,
            int(actions_per_chunk),
            policy_device,
            dict(rename_map or {}),
        )
        self._frames: deque[dict[str, Any]] = deque(maxlen=self.n_obs_steps)
        self._channel: grpc.Channel | None = None
        self._stub: Any = None
        self._connect_lock = threading.Lock()
        super().__init__()
        #: chunks taken since construction, and the wall time their requests took (seconds)
        self.chunks_taken = 0
        self.plan_seconds = 0.0

    @classmethod
    def from_base_dir(
        cls,
        server_address: str,
        base_dir: str | Path,
        observation_features: Mapping[str, Any],
        base_path: str | None = None,
        **kwargs: Any,
    ) -> RemotePlanner:
        """A planner for the base whose ``config.json`` and processor files are in ``base_dir`` (weights are
        not read: the served copy or the base folder without ``model.safetensors`` will do).

        Args:
            server_address: ``host:port`` of the policy server.
            base_dir: Local folder with the base's ``config.json``, ``policy_preprocessor.json`` and
                ``policy_postprocessor.json`` (and their ``.safetensors`` statistics).
            observation_features: The robot's ``observation_features``.
            base_path: The served base on the server's machine; default ``base_dir`` (same machine).
            **kwargs: The remaining :class:`RemotePlanner` arguments.
        """
        import lerobot.policies  # noqa: F401  (registers every policy config type)
        from lerobot.configs.policies import PreTrainedConfig

        from lerobot_dcdp.policy.base_policy import load_base_stats

        config = PreTrainedConfig.from_pretrained(str(base_dir))
        action = load_base_stats(str(base_dir)).get(ACTION, ("IDENTITY", {}))
        kwargs.setdefault("n_obs_steps", int(getattr(config, "n_obs_steps", 1) or 1))
        return cls(
            server_address,
            base_path or str(Path(base_dir).resolve()),
            config.type,
            observation_features,
            action,
            **kwargs,
        )

    # ------------------------------------------------------------------ connection
    def connect(self) -> None:
        """Open the channel and have the server load the base (once; later calls return at once).

        Raises:
            RemotePlanningError: No server answered within ``timeout_s``, or it refused the base (its
                message, e.g. a missing folder or processor step, is included).
        """
        with self._connect_lock:
            if self._stub is not None:
                return
            channel = grpc.insecure_channel(self.server_address, grpc_channel_options())
            try:
                grpc.channel_ready_future(channel).result(timeout=self.timeout_s)
            except grpc.FutureTimeoutError as err:
                channel.close()
                raise RemotePlanningError(
                    f"no policy server answered at {self.server_address} within {self.timeout_s:.0f} s; "
                    "start one there: python -m lerobot.async_inference.policy_server --host=HOST --port=PORT"
                ) from err
            stub = services_pb2_grpc.AsyncInferenceStub(channel)
            try:
                stub.Ready(services_pb2.Empty(), timeout=self.timeout_s)
                setup = services_pb2.PolicySetup(data=pickle.dumps(self.policy_config))
                stub.SendPolicyInstructions(setup, timeout=self.timeout_s)
            except grpc.RpcError as err:
                channel.close()
                raise RemotePlanningError(
                    f"the policy server at {self.server_address} could not load "
                    f"{self.policy_config.pretrained_name_or_path!r} ({self.policy_config.policy_type}): "
                    f"{err.details() if hasattr(err, 'details') else err}. Serve a copy made by "
                    "dcdp-serve-base and pass its path on the server's machine"
                ) from err
            self._channel, self._stub = channel, stub

    # ------------------------------------------------------------------ observations
    def observe(self, raw: Mapping[str, Any]) -> None:
        """Record the robot's observation of the current control step (``robot.get_observation()``); call it
        every tick, before ``policy.select_action``."""
        self._frames.append(dict(raw))

    def _observation(self) -> dict[str, Any]:
        """The raw observation sent for the newest frame, older frames packed under :func:`history_name`."""
        if not self._frames:
            raise RemotePlanningError(
                "RemotePlanner.submit: no robot observation recorded; call planner.observe(robot "
                "observation) every control step before policy.select_action"
            )
        frames = list(self._frames)
        obs = dict(frames[-1])
        for lag in range(1, self.n_obs_steps):
            past = frames[max(len(frames) - 1 - lag, 0)]  # an episode's first steps repeat the oldest frame
            for name in self._state_names:
                obs[history_name(name, lag)] = past[name]
        if self.task is not None:
            obs["task"] = self.task
        return obs

    # ------------------------------------------------------------------ BackgroundPlanner's interface
    def submit(
        self,
        t_obs: int,
        prepared: dict[str, Tensor],
        snapshot: dict | None,
        length: int,
        context=None,
        finish: Callable[[Tensor], Any] | None = None,
    ) -> None:
        """Ask the server for ``length`` actions from step ``t_obs``'s robot observation (the newest one given
        to :meth:`observe`). ``prepared`` only tells the batch size (must be 1) and the device the chunk is
        returned on; ``snapshot`` is not used (the history is the observed frames); ``finish(chunk)`` runs
        on the worker once the chunk arrived (the taken chunk's ``prepared``). One job at a time."""
        tensors = [v for v in prepared.values() if isinstance(v, Tensor)]
        if any(v.ndim and v.shape[0] != 1 for v in tensors):
            raise ValueError(
                f"RemotePlanner plans for one robot (batch 1); got batch {[tuple(v.shape) for v in tensors]}"
            )
        device = tensors[0].device if tensors else torch.device("cpu")
        timed = TimedObservation(
            timestamp=time.time(), timestep=int(t_obs), observation=self._observation(), must_go=True
        )
        if self.pending:  # before the observation is sent
            raise RuntimeError("a chunk is already being planned: take() it first")
        self._start(t_obs, context, self._plan, timed, int(length), device, finish)

    def _plan(self, timed: TimedObservation, length: int, device: torch.device, finish=None) -> tuple:
        self.connect()
        started = time.perf_counter()
        step = timed.get_timestep()
        try:
            payload = send_bytes_in_chunks(pickle.dumps(timed), services_pb2.Observation, silent=True)
            self._stub.SendObservations(payload, timeout=self.timeout_s)
            reply = self._stub.GetActions(services_pb2.Empty(), timeout=self.timeout_s)
        except grpc.RpcError as err:
            raise RemotePlanningError(
                f"policy server {self.server_address}: observation #{step} failed: "
                f"{err.details() if hasattr(err, 'details') else err}"
            ) from err
        seconds = time.perf_counter() - started
        if not reply.data:
            raise RemotePlanningError(
                f"the policy server at {self.server_address} returned no actions for observation #{step}: it "
                "failed on it (its log says why: 'Error in StreamActions: ...') or another client took it"
            )
        actions: list[TimedAction] = pickle.loads(reply.data)  # nosec B301: LeRobot's protocol
        if not actions or actions[0].get_timestep() != step:
            got = actions[0].get_timestep() if actions else None
            raise RemotePlanningError(f"the policy server answered observation #{got}, not #{step}")
        raw = torch.stack([torch.as_tensor(a.get_action()) for a in actions]).to(torch.float32)
        if raw.ndim != 2:
            raise RemotePlanningError(
                f"the policy server sent actions of shape {tuple(raw.shape[1:])}, not (A,)"
            )
        chunk = normalize(raw, self._stats, self._mode)[:length].unsqueeze(0).to(device)
        return (
            chunk,
            seconds,
            raw[:length].unsqueeze(0),
            [a.get_timestep() for a in actions[:length]],
            [a.get_timestamp() for a in actions[:length]],
            None if finish is None else finish(chunk),
        )

    def take(self, wait: bool) -> RemoteChunk | None:
        """The pending chunk if it arrived (``wait``: block until it does), else ``None``; a failure of the
        request is raised here (:class:`RemotePlanningError`)."""
        done = self._finished(wait)
        if done is None:
            return None
        (chunk, seconds, raw, timesteps, timestamps, finished), t_obs, context = done
        self.chunks_taken += 1
        self.plan_seconds += seconds
        return RemoteChunk(chunk, t_obs, context, seconds, finished, raw, timesteps, timestamps)

    def cancel(self) -> None:
        """Drop the pending chunk and the observed frames (a new episode); a request already running is waited
        for (at most ``timeout_s`` per call) and its chunk or error discarded."""
        self._frames.clear()
        super().cancel()

    def close(self) -> None:
        """Drop the pending chunk, stop the worker thread and close the channel (the server keeps running)."""
        super().close()
        with self._connect_lock:
            if self._channel is not None:
                self._channel.close()
            self._channel, self._stub = None, None
