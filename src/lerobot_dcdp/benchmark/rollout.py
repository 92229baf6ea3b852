"""Batched PushT rollouts of one policy (any execution mode) under one perturbation, with per-step timing.

The loop is the one ``lerobot-eval`` runs -- env observation -> ``preprocess_observation`` -> pre-processor ->
``select_action`` -> post-processor -> ``env.step`` -- over a list of envs stepped in lock-step. An env that
succeeded (coverage > 0.95) or hit the step limit stops; the policy keeps its batch (the finished env's
last observation is repeated) so every env of the batch sees the same policy state machine.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch


@dataclass
class Condition:
    """A perturbation setting of the protocol."""

    name: str
    perturbation: str = "none"
    magnitude: float = 0.0

    def env_kwargs(self) -> dict:
        return {"perturbation": self.perturbation, "magnitude": self.magnitude}


CONDITIONS = [
    Condition("static"),
    Condition("constant_0.5", "constant", 0.5),
    Condition("random_0.5", "random", 0.5),
    Condition("constant_0.75", "constant", 0.75),
    Condition("random_0.75", "random", 0.75),
    Condition("constant_1.0", "constant", 1.0),
    Condition("random_1.0", "random", 1.0),
    Condition("constant_1.5", "constant", 1.5),
    Condition("random_1.5", "random", 1.5),
    Condition("constant_2.0", "constant", 2.0),
    Condition("random_2.0", "random", 2.0),
    Condition("constant_2.5", "constant", 2.5),
    Condition("random_2.5", "random", 2.5),
]
#: The main protocol's conditions (``dcdp-benchmark``'s default; 0.75 px/step belongs to the mild protocol).
MAIN_CONDITIONS = [c.name for c in CONDITIONS if c.magnitude != 0.75]
#: The mild protocol (mild drift): at rest and the drifts where an episode can still succeed.
MILD_CONDITIONS = ["static"] + [f"{k}_{m}" for m in (0.5, 0.75, 1.0) for k in ("constant", "random")]
#: Steps of each plan the privileged expert executes before it re-plans (the bases' chunk length H).
EXPERT_CHUNK = 8


@dataclass
class RolloutResult:
    seeds: list[int]
    successes: list[bool]
    max_rewards: list[float]
    steps: list[int]
    step_times_ms: list[float] = field(default_factory=list)
    frames: dict[int, list[np.ndarray]] = field(default_factory=dict)

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.successes)) if self.successes else float("nan")

    @property
    def score(self) -> float:
        """The paper's score: mean over episodes of max_t clip(coverage_t / 0.95, 0, 1)."""
        return float(np.mean(self.max_rewards)) if self.max_rewards else float("nan")


def _stack_obs(obs_list: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([o[k] for o in obs_list]) for k in obs_list[0]}


@torch.no_grad()
@torch.random.fork_rng(devices=[])  # the seeding below leaves the caller's global RNG as it was
def rollout(
    policy,
    preprocessor,
    postprocessor,
    condition: Condition,
    seeds: list[int],
    max_steps: int = 300,
    obs_type: str = "environment_state_agent_pos",
    render_seeds: tuple[int, ...] = (),
    env_kwargs: dict | None = None,
) -> RolloutResult:
    """Run ``len(seeds)`` episodes in one batch; returns per-episode results and per-step policy times."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env
    from lerobot_dcdp.sim.lockstep import run_lockstep

    envs = [
        make_perturbed_env(
            obs_type=obs_type,
            max_episode_steps=max_steps,
            render_mode="rgb_array",
            **{**condition.env_kwargs(), **(env_kwargs or {})},
        )
        for _ in seeds
    ]
    frames: dict[int, list[np.ndarray]] = {s: [] for s in seeds if s in render_seeds}
    index = {i: s for i, s in enumerate(seeds) if s in frames}
    times: list[float] = []
    # the policy's own randomness (diffusion noise) is seeded per batch, as lerobot-eval --seed does:
    # the same command gives the same numbers
    torch.manual_seed(seeds[0])
    policy.reset()

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        if not times:  # the first frame of each rendered episode, after its reset
            for i, s in index.items():
                frames[s].append(envs[i].render())
        batch = preprocess_observation(_stack_obs(obs))
        t0 = time.perf_counter()
        action = postprocessor(policy.select_action(preprocessor(batch)))
        times.append((time.perf_counter() - t0) * 1e3)
        return action.cpu().numpy()

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        if i in index:
            frames[index[i]].append(envs[i].render())

    out = run_lockstep(envs, list(seeds), act, max_steps, on_step)
    for env in envs:
        env.close()
    return RolloutResult(
        seeds=list(seeds),
        successes=out.successes,
        max_rewards=out.max_rewards,
        steps=out.steps,
        step_times_ms=times,
        frames=frames,
    )


def expert_identity(chunk: int = EXPERT_CHUNK) -> dict:
    """What an expert cell was computed with (its reuse key in the results file)."""
    from dataclasses import asdict

    from lerobot_dcdp.sim.pusht_expert import ExpertConfig

    cfg = asdict(ExpertConfig(max_exec=chunk))
    cfg.pop("contacts")
    return {
        # the name it had when the stored cells were computed (a reuse key, kept stable across moves)
        "expert": "lerobot_dcdp.pusht.expert.ScriptedExpert",
        "privileged": "reads the simulator's true state and re-plans on an exact copy of its physics",
        "chunk": chunk,
        "config": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
    }


def expert_rollout(
    condition: Condition,
    seeds: list[int],
    max_steps: int = 300,
    chunk: int = EXPERT_CHUNK,
    env_kwargs: dict | None = None,
) -> RolloutResult:
    """The privileged scripted expert (:class:`~lerobot_dcdp.sim.pusht_expert.ScriptedExpert`) on each seed.

    The expert reads the simulator's true state (block pose and velocities, agent position and velocity),
    plans a push primitive on an exact copy of the physics, executes at most ``chunk`` steps of it and
    plans again from the state it reached: a chunked policy with a perfect model of the static world and no
    knowledge of the drift. It is the ceiling row of the benchmark, not a deployable policy. Episodes end
    as in :func:`rollout` (success, or ``max_steps``); the expert's RNG (used only to escape when no push
    improves the pose) is seeded with the episode seed.

    Args:
        condition: The perturbation.
        seeds: One episode per seed.
        max_steps: Step limit of an episode.
        chunk: Steps of each plan executed before re-planning.
        env_kwargs: Overrides of the condition's env arguments.

    Returns:
        Per-episode results; ``step_times_ms`` holds each episode's planning time per control step.
    """
    from lerobot_dcdp.sim.envs.pusht_perturbed import make_perturbed_env
    from lerobot_dcdp.sim.pusht_expert import ExpertConfig, ScriptedExpert

    if chunk < 1:
        raise ValueError(f"the expert's chunk must be >= 1 step, got {chunk}")
    from lerobot_dcdp.sim.lockstep import run_lockstep

    envs = [
        make_perturbed_env(
            obs_type="environment_state_agent_pos",
            max_episode_steps=max_steps,
            **{**condition.env_kwargs(), **(env_kwargs or {})},
        )
        for _ in seeds
    ]
    experts = [ScriptedExpert(ExpertConfig(max_exec=chunk), seed=seed) for seed in seeds]
    queues: list[list] = [[] for _ in seeds]  # each expert's plan still to execute
    prev: list[np.ndarray | None] = [None] * len(seeds)  # each env's last target (the agent at reset)
    planning = np.zeros(len(seeds))

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        out = np.zeros((len(seeds), 2))
        for i in np.flatnonzero(active):
            if prev[i] is None:
                prev[i] = np.array(envs[i].unwrapped.agent.position, dtype=float)
            if not queues[i]:
                t0 = time.perf_counter()
                queues[i] = list(experts[i].next_actions(envs[i], prev[i]))
                planning[i] += time.perf_counter() - t0
            prev[i] = np.asarray(queues[i].pop(0), dtype=float)
            out[i] = prev[i]
        return out

    result = run_lockstep(envs, list(seeds), act, max_steps)
    for env in envs:
        env.close()
    successes, max_rewards, steps = result.successes, result.max_rewards, result.steps
    times = [1e3 * p / max(n, 1) for p, n in zip(planning, steps, strict=True)]
    return RolloutResult(
        seeds=list(seeds), successes=successes, max_rewards=max_rewards, steps=steps, step_times_ms=times
    )
