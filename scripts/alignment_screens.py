"""Screens: can the final alignment under drift come from fresher or forward-looking chunks? (diagnosis aids)

Each screen runs one benchmark condition (same envs, seeds and seeding as ``near_misses.py``) and prints score
and success per setting:

- ``horizon``: ``open_loop`` with the base replanning every ``H`` steps (``n_action_steps``; the benchmark's
  8 is the reference). Fresher chunks in the final alignment, at the cost of the chunk's temporal consistency.
- ``extrapolate``: ``open_loop`` where the base plans from an observation whose object features
  (``observation.environment_state``) are moved ``lead`` steps ahead along their motion over the last ``k``
  steps (the base aims where the object will be).
- ``lead``: ``object_anchored`` carrying the plan to where the object will be ``lead`` steps on (its motion
  over the last step) instead of where it is now (the agent's controller lags its command).
- ``gate_share``: ``dcdp`` with a completion-gated corrector that keeps this share of its correction where the
  gate says "nearly done" (0: the shipped gate, the plan itself there; 1: no gate).
- ``ensemble``: ``temporal_ensemble`` (the base plans its whole chunk every step; plans averaged with weight
  ``te_weight`` = the setting on the newest): a finish from fresh plans that keeps the chunks' consistency?
- ``gate_drift`` (privileged): ``dcdp`` with a completion-gated corrector where, as far as the gate fires, the
  plan is moved by this share of the drift the env applied since plan time (read from the env's
  ``perturbation_offset``): does a finish that follows the world's motion alone, not the push, finish more?
- ``drift_lead`` (privileged): the plain ``object_anchored`` rule with every action moved ``lead`` steps of
  the env's own drift (the world's motion on the newest step, never the push): does leading on the world's
  velocity beat the rule at fast drift?
- ``gated_horizon``: a folder's gated anchoring (``gated_anchored``) executing H steps per chunk: does a
  longer chunk, kept closed-loop by the rule, complete more?
- ``goal_lead``: a method (``--method``, default ``gated_anchored``) run on a scene moved ``lead`` steps of
  the object's motion ahead (agent and object together), its actions moved back: the base leaves the object
  that far upstream of the goal, for the drift to carry it in (a still-scene finish settles downstream of the
  goal under drift). ``--velocity true`` (privileged): the env's own drift; ``median``: the median per-step
  motion of the object's keypoint centroid over ``--window`` steps (the first scene lead); ``repeated``: the
  newest per-step motion that ``--repeats`` steps of the window repeat within ``--tolerance`` x its length
  (what ``scene_lead.py`` builds in, the last one found held). The screen leads by hand; the folder's own
  ``lead_steps`` is turned off.
- ``tracker_jitter``: ``--method`` with the folder's own lead where the object's keypoints are seen with
  Gaussian jitter (``--jitter`` px, a tracker's noise), the lead's ``lead_noise`` = the setting: does the lead
  survive a noisy tracker, and does the noise floor matter?
- ``gate_anchor``: ``object_anchored`` (the training-free rule) with a corrector's completion gate applied at
  this strength (0: the plain rule; 1: the plan itself where the gate says "nearly done"): is the learned
  corrector, gated, better than its analytic teacher gated the same way?
- ``lead_length``: ``--method`` (default ``gated_anchored``) with the folder's scene lead set to the setting
  in steps, its shift optionally capped at ``--lead-cap`` (raw units): does a lead longer than one chunk
  finish more in some drift directions, and in all of them?
- ``world_carry``: the folder's gated anchoring where, as far as the gate fires, the kept plan is moved by the
  setting's share of the lead's own estimate of the world's motion x the steps since plan time (the
  non-privileged ``gate_drift``): does the robot get out of the drifting object's way at the finish?
- ``goal_integral`` (privileged): ``--method`` with the folder's lead plus an integral term that grows, near
  the env's goal, with the object's offset from the goal along the world's motion (gain = the setting): a lead
  that finds the base's own steady-state offset in a pressed finish?
- ``time_skip``: ``--method`` executing each chunk from its entry k (the setting) on, the base planning on
  time from this step's observation: the part of a late base (``--delay``) that is not staleness. Does acting
  k steps further along the plan (the agent's controller lags its command) finish more?
- ``lead_in_range``: ``--method`` with the folder's lead, ``lead_in_range`` set by the setting (1: its shift
  shortened so that no led keypoint leaves its coordinate's range in the base's training data, the
  normaliser's min / max; 0: the lead before it; 2: as 1, and the robot's led xy kept inside its own range
  too): does the lead cost at fast drift come from showing the base a scene beyond the arena's walls?

Usage: .venv/bin/python scripts/alignment_screens.py --screen horizon --settings 8 4 2 1
           [--policy models/pusht-dcdp-state-demos-late-gated] [--condition constant_0.5] [--episodes 100]
       --screen extrapolate --settings 0 4 8 [--k 4];  --screen lead --settings 0 2 4
       --screen gate_share --settings 0 0.25 0.5;  --screen gate_drift --settings 0 1
       --screen ensemble --settings 0.5 0.1;  --screen gate_anchor --settings 0 1
       --screen drift_lead --settings 0 1 2 --condition constant_2.0 --episodes 50
       --screen gated_horizon --settings 8 12 16 --policy models/pusht-act-state-anchored-gated
       --screen goal_lead --settings 0 8 --velocity median --window 16 [--method gated_anchored]
       --screen tracker_jitter --settings 0 2.5 --jitter 0.5 --method gated_anchored
       Screens run a folder with its own scene lead unless ``--lead-steps`` says otherwise (the screens
       recorded before the lead existed: ``--lead-steps 0``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def _rollout(args: argparse.Namespace, method: str, lead_steps: int | None = None) -> tuple:
    """``near_misses.condition_rollout`` for the screen's folder, condition, episodes and first seed, with
    ``lead_steps`` (None: ``--lead-steps``, itself None for the folder's own lead)."""
    from near_misses import condition_rollout

    lead = args.lead_steps if lead_steps is None else lead_steps
    return condition_rollout(
        args.policy, args.condition, args.episodes, method, args.seed_start, lead_steps=lead, delay=args.delay
    )


def _every(method: str, args: argparse.Namespace, steps: float):
    """``method`` executing ``steps`` steps per chunk."""
    policy, _, act, envs, seeds = _rollout(args, method)
    policy.config.n_action_steps = int(steps)
    policy.reset()
    return act, envs, seeds


def horizon(args: argparse.Namespace, steps: float):
    """``open_loop`` replanning every ``steps`` steps."""
    return _every("open_loop", args, steps)


def gated_horizon(args: argparse.Namespace, steps: float):
    """``gated_anchored`` (the folder's rule with its completion gate) executing ``steps`` steps per chunk."""
    return _every("gated_anchored", args, steps)


def extrapolate(args: argparse.Namespace, lead: float):
    """``open_loop`` planning from object features moved ``lead`` steps along their recent motion."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.benchmark.rollout import _stack_obs
    from lerobot_dcdp.benchmark.run import load_model

    policy, post, _, envs, seeds = _rollout(args, "open_loop")
    _, pre, _, _ = load_model(args.policy)
    history = []

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        stacked = _stack_obs(obs)
        x = stacked["environment_state"].astype(np.float64)
        history.append(x)
        if lead and len(history) > args.k:
            velocity = (history[-1] - history[-1 - args.k]) / args.k
            stacked = {**stacked, "environment_state": (x + lead * velocity).astype(np.float32)}
        return post(policy.select_action(pre(preprocess_observation(stacked)))).cpu().numpy()

    return act, envs, seeds


def lead(args: argparse.Namespace, steps: float):
    """``object_anchored`` carrying the plan to the object's pose ``steps`` steps on."""
    policy, _, act, envs, seeds = _rollout(args, "object_anchored")
    anchored = policy.modes["object_anchored"]
    previous = {}

    def carried(state, step, batch):
        now = anchored.anchor.points(batch)
        last, previous["points"] = previous.get("points"), now
        if last is not None and steps:
            now = now + steps * (now - last)
        return anchored.anchor.carry(state.chunk[:, step], state.anchor_plan, now)

    anchored.act = carried
    return act, envs, seeds


def gate_share(args: argparse.Namespace, share: float):
    """``dcdp`` keeping ``share`` of the correction where the completion gate fires."""
    import lerobot_dcdp.modeling_dcdp as modeling
    from lerobot_dcdp.completion_gate import gated_action

    policy, _, act, envs, seeds = _rollout(args, "dcdp")
    if policy.completion_gate is None:
        raise SystemExit(f"{args.policy} has no completion gate")
    modeling.gated_action = lambda plan, action, near: gated_action(plan, action, (1.0 - share) * near)
    return act, envs, seeds


def ensemble(args: argparse.Namespace, weight: float):
    """``temporal_ensemble`` with ``te_weight`` = ``weight``."""
    policy, _, act, envs, seeds = _rollout(args, "temporal_ensemble")
    policy.config.te_weight = weight
    return act, envs, seeds


def gate_drift(args: argparse.Namespace, share: float):
    """``dcdp`` (gated) plus ``share`` x the env's drift since plan time, as far as the gate fires."""
    import lerobot_dcdp.modeling_dcdp as modeling
    from lerobot_dcdp.completion_gate import gated_action

    policy, _, corrected, envs, seeds = _rollout(args, "dcdp")
    if policy.completion_gate is None:
        raise SystemExit(f"{args.policy} has no completion gate")
    near = {}

    def recording(plan, action, p):
        near["p"] = p.detach().cpu().numpy()
        return gated_action(plan, action, p)

    modeling.gated_action = recording
    drift = np.zeros((len(seeds), 2))  # the env's summed drift up to the newest observation
    at_plan = np.zeros((len(seeds), 2))

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = corrected(obs, active)
        if policy.last_step == 0:  # this observation planned the chunk (sync planning, no delay)
            at_plan[:] = drift
        return action + share * near["p"][:, None] * (drift - at_plan)

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        drift[i] += info["perturbation_offset"]

    return act, envs, seeds, on_step


def drift_lead(args: argparse.Namespace, lead: float):
    """``object_anchored`` (plain) with every action moved ``lead`` steps of the env's own drift ahead
    (privileged: the world's per-step motion read from the env, never the agent's push)."""
    policy, _, anchored, envs, seeds = _rollout(args, "object_anchored")
    policy.config.completion_gate = False  # the plain rule, whatever the folder holds
    velocity = np.zeros((len(seeds), 2))  # the drift the env applied on the newest step

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        return anchored(obs, active) + lead * velocity

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        velocity[i] = info["perturbation_offset"]

    return act, envs, seeds, on_step


def goal_lead(args: argparse.Namespace, lead: float):
    """``--method`` on the scene moved ``lead`` steps of the object's motion ahead, actions moved back."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.benchmark.rollout import _stack_obs
    from lerobot_dcdp.benchmark.run import load_model
    from lerobot_dcdp.scene_lead import repeated_motion

    # the lead by hand here: the folder's own off
    policy, post, _, envs, seeds = _rollout(args, args.method, 0)

    _, pre, _, _ = load_model(args.policy)
    velocity = np.zeros((len(seeds), 2))  # the drift the env applied on the newest step

    history = []  # the object's keypoint centroid per step (observed estimate)

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        stacked = _stack_obs(obs)
        if args.velocity in ("median", "repeated"):
            history.append(stacked["environment_state"].reshape(len(obs), -1, 2).mean(1))
            if len(history) > args.window:
                steps = np.diff(np.stack(history[-args.window - 1 :]), axis=0)  # (W, B, 2)
                if args.velocity == "median":
                    velocity[:] = np.median(steps, axis=0)
                else:  # the newest repeated displacement; where none, the last estimate holds
                    motion, found = repeated_motion(torch.from_numpy(steps), args.tolerance, args.repeats)
                    velocity[found.numpy()] = motion[found].numpy()
        shift = lead * velocity
        moved = {
            "agent_pos": stacked["agent_pos"] + shift,
            "environment_state": (
                stacked["environment_state"].reshape(len(obs), -1, 2) + shift[:, None]
            ).reshape(len(obs), -1),
        }
        return post(policy.select_action(pre(preprocess_observation(moved)))).cpu().numpy() - shift

    def on_step(i: int, obs: dict, reward: float, info: dict) -> None:
        if args.velocity == "true":
            velocity[i] = info["perturbation_offset"]

    return act, envs, seeds, on_step


def tracker_jitter(args: argparse.Namespace, noise: float):
    """``--method`` with the folder's own lead, the object's keypoints seen with Gaussian jitter
    (``--jitter`` px per coordinate per step, seeded) and the lead's ``lead_noise`` set to ``noise``."""
    policy, _, run, envs, seeds = _rollout(args, args.method)
    policy.config.lead_noise = noise
    rng = np.random.default_rng(0)

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        seen = []
        for o in obs:
            jitter = rng.normal(0.0, args.jitter, size=o["environment_state"].shape)
            seen.append({**o, "environment_state": (o["environment_state"] + jitter).astype(np.float32)})
        return run(seen, active)

    return act, envs, seeds


def still_world(args: argparse.Namespace, on: float):
    """``--method`` (an anchoring) with the folder's own lead where, with ``on``, the rule leaves the plan as
    planned once the lead has found the world still (a repeated zero step): the carry with the object's whole
    motion only while the world moves it (the demonstrations label's rule, run time)."""
    policy, _, act, envs, seeds = _rollout(args, args.method)
    anchored = policy.modes["object_anchored"]
    rule = anchored.act

    def carried_while_moving(state, step, batch):
        carried, plan = rule(state, step, batch), state.chunk[:, step]
        motion = policy.lead._motion
        if not on or motion is None or motion.shape[0] != plan.shape[0]:
            return carried
        still = (motion == 0).all(-1) & (len(policy.lead._track) > policy.config.lead_window)
        return torch.where(still[:, None], plan, carried)

    anchored.act = carried_while_moving
    return act, envs, seeds


def gate_anchor(args: argparse.Namespace, strength: float):
    """``object_anchored`` with the corrector's completion gate at ``strength``."""
    from lerobot_dcdp.completion_gate import gated_action

    policy, _, act, envs, seeds = _rollout(args, "object_anchored")
    if policy.completion_gate is None:
        raise SystemExit(f"{args.policy} has no completion gate")
    anchored = policy.modes["object_anchored"]
    rule = anchored.act

    def gated(state, step, batch):
        return gated_action(
            state.chunk[:, step], rule(state, step, batch), strength * policy.completion_gate(batch)
        )

    anchored.act = gated
    return act, envs, seeds


def lead_length(args: argparse.Namespace, steps: float):
    """``--method`` with the scene lead set to ``steps``, its shift capped at ``--lead-cap`` where given."""
    policy, _, act, envs, seeds = _rollout(args, args.method, int(steps))
    if args.lead_cap is not None:
        observe = policy.lead.observe

        def capped(points, record=True):
            shift = observe(points, record)
            return shift * (args.lead_cap / shift.norm(dim=-1, keepdim=True).clamp_min(1e-9)).clamp(max=1.0)

        policy.lead.observe = capped
    return act, envs, seeds


def world_carry(args: argparse.Namespace, share: float):
    """The folder's gated anchoring with the kept plan moved by ``share`` x the lead's world motion x the
    steps since plan time, as far as the gate fires."""
    import lerobot_dcdp.modeling_dcdp as modeling
    from lerobot_dcdp.completion_gate import gated_action

    policy, _, anchored, envs, seeds = _rollout(args, "gated_anchored")
    near = {}

    def recording(plan, action, p):
        near["p"] = p.detach().cpu().numpy()
        return gated_action(plan, action, p)

    modeling.gated_action = recording

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        action = anchored(obs, active)
        motion = policy.lead._motion
        if motion is None:
            return action
        return action + share * near["p"][:, None] * policy.last_step * motion.cpu().numpy()

    return act, envs, seeds


def goal_integral(args: argparse.Namespace, gain: float):
    """``--method`` with the folder's lead plus an integral term (privileged: the env's goal pose): while the
    object's keypoint centroid is within ``--radius`` of the goal's and the world moves it, the lead grows by
    ``gain`` x the centroid's offset from the goal along the world's motion (+: downstream), clamped to
    [-lead (``--grow-only``: 0), ``--radius``]: does a lead that finds the base's own steady-state offset
    finish everywhere? (``--held``, ``--steady``: only in a held or steady finish.)"""
    from lerobot_dcdp.pusht.geometry import GOAL_KP

    policy, _, act, envs, seeds = _rollout(args, args.method)
    goal = torch.as_tensor(GOAL_KP.mean(0))
    extra = torch.zeros(len(seeds), dtype=torch.float64)
    observe = policy.lead.observe
    chunk = policy.config.n_action_steps
    centroids: list[torch.Tensor] = []
    alongs: list[torch.Tensor] = []

    def integrated(points, record=True):
        shift = observe(points, record)
        speed = shift.norm(dim=-1)
        if not record or shift.shape[0] != extra.shape[0]:
            return shift
        heading = shift / speed.clamp_min(1e-9)[:, None]
        centroid = points.mean(1).double()
        centroids.append(centroid)
        offset = centroid - goal
        near = (offset.norm(dim=-1) < args.radius) & (speed > 0)
        if args.held:  # only while the object makes less than half the world's progress over a chunk
            moved = (centroid - centroids[max(0, len(centroids) - 1 - chunk)]).norm(dim=-1)
            world = chunk * speed.double() / max(policy.config.lead_steps, 1)
            near &= (len(centroids) > chunk) & (moved < 0.5 * world)
        along = (offset * heading.double()).sum(-1)
        alongs.append(along)
        if args.steady is not None:  # only where the offset along the motion held still over two chunks
            recent = torch.stack(alongs[-2 * chunk :])
            near &= (len(alongs) >= 2 * chunk) & (recent.std(0) < args.steady)
        extra.add_(torch.where(near, gain * along, torch.zeros_like(extra)))
        floor = torch.zeros_like(extra) if args.grow_only else -speed.double()
        extra.copy_(torch.minimum(torch.maximum(extra, floor), torch.full_like(extra, args.radius)))
        return shift + (extra[:, None] * heading.double()).to(shift.dtype)

    policy.lead.observe = integrated
    return act, envs, seeds


def lead_in_range(args: argparse.Namespace, clip: float):
    """``--method`` with the folder's scene lead and ``lead_in_range`` set by the setting (1: the lead
    shortened so that no led keypoint leaves its coordinate's range in the base's data, as built; 0: not)."""
    policy, _, act, envs, seeds = _rollout(args, args.method)
    policy.config.lead_in_range = bool(clip)
    if clip == 2:  # the robot's xy kept inside its own range too (lead_state_feature's first two dims)
        from lerobot_dcdp.scene_lead import in_range_shift

        lead, cfg = policy.lead, policy.config
        _, stats = policy.normalizer.stats[cfg.lead_state_feature]
        low, high = stats["min"][:2].reshape(1, 2), stats["max"][:2].reshape(1, 2)
        observe, robot = lead.observe, {}

        def enter(batch, record=True):
            state = policy.normalizer(cfg.lead_state_feature, batch[cfg.lead_state_feature], inverse=True)
            robot["xy"] = state[:, None, :2]
            return type(lead).enter(lead, batch, record)

        def observe_both(points, record=True):
            shift = observe(points, record)
            xy = robot["xy"].to(points)
            return in_range_shift(xy, shift, low.to(points), high.to(points))

        lead.enter, lead.observe = enter, observe_both
    return act, envs, seeds


def time_skip(args: argparse.Namespace, k: float):
    """``--method`` with every chunk used from its entry ``k`` on, planned on time: the folder's chunk source
    asked for ``k`` more actions, the first ``k`` dropped (the plan-time references stay this step's)."""
    if args.delay:
        raise SystemExit("time_skip plans on time: leave --delay at 0")
    policy, _, act, envs, seeds = _rollout(args, args.method)
    source, skip = policy.source, int(k)
    chunk = source.chunk

    def skipped(prepared, length=None):
        length = source.chunk_length if length is None else length
        return chunk(prepared, min(length + skip, source.max_length))[:, skip:]

    if skip:
        source.chunk = skipped
    return act, envs, seeds


SCREENS = {
    "horizon": horizon,
    "extrapolate": extrapolate,
    "lead": lead,
    "gate_share": gate_share,
    "ensemble": ensemble,
    "gate_drift": gate_drift,
    "gate_anchor": gate_anchor,
    "drift_lead": drift_lead,
    "gated_horizon": gated_horizon,
    "goal_lead": goal_lead,
    "tracker_jitter": tracker_jitter,
    "still_world": still_world,
    "lead_length": lead_length,
    "world_carry": world_carry,
    "goal_integral": goal_integral,
    "lead_in_range": lead_in_range,
    "time_skip": time_skip,
}


def main() -> None:
    from lerobot_dcdp.lockstep import run_lockstep

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--screen", choices=sorted(SCREENS), required=True)
    p.add_argument("--settings", type=float, nargs="+", required=True, help="H, or the lead in steps")
    p.add_argument("--policy", default="models/pusht-dcdp-state-demos-late-gated")
    p.add_argument("--condition", default="constant_0.5")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed-start", type=int, default=100_000, help="the first seed (the tables: 100000)")
    p.add_argument("--delay", type=int, default=0, help="the base answers this many control steps late")
    p.add_argument("--lead-cap", type=float, help="lead_length: the largest shift (raw units)")
    p.add_argument("--radius", type=float, default=21.2, help="goal_integral: px around the goal it acts in")
    p.add_argument(
        "--grow-only", action="store_true", help="goal_integral: the lead only lengthens (floor 0)"
    )
    p.add_argument(
        "--steady", type=float, help="goal_integral: only where the offset's s.d. over two chunks is below"
    )
    p.add_argument(
        "--held",
        action="store_true",
        help="goal_integral: integrate only while the object is held against the world",
    )
    p.add_argument(
        "--lead-steps",
        type=int,
        help="override the folder's scene lead (the screens before it existed ran with none: 0)",
    )
    p.add_argument("--method", default="gated_anchored", help="the execution method (goal_lead and others)")
    p.add_argument(
        "--velocity",
        choices=["true", "median", "repeated"],
        default="true",
        help="goal_lead: the env's drift (privileged), the median or the repeated per-step object motion",
    )
    p.add_argument("--window", type=int, default=16, help="goal_lead --velocity median|repeated: steps")
    p.add_argument("--jitter", type=float, default=0.5, help="tracker_jitter: px per coordinate per step")
    p.add_argument("--tolerance", type=float, default=0.05, help="goal_lead --velocity repeated")
    p.add_argument("--repeats", type=int, default=3, help="goal_lead --velocity repeated")
    p.add_argument("--k", type=int, default=4, help="extrapolate: steps the object's velocity is taken over")
    a = p.parse_args()
    torch.set_num_threads(1)
    scores = {}
    for setting in a.settings:
        started = time.time()
        act, envs, seeds, *on_step = SCREENS[a.screen](a, setting)
        out = run_lockstep(envs, seeds, act, 300, *on_step)
        for env in envs:
            env.close()
        scores[setting] = np.asarray(out.max_rewards, dtype=float)
        print(
            f"{a.policy} {a.condition} {a.screen}={setting:g}: score {np.mean(out.max_rewards):.3f} "
            f"success {100 * np.mean(out.successes):.0f} % ({time.time() - started:.0f} s)",
            flush=True,
        )
    first = a.settings[0]
    for setting in a.settings[1:]:  # every setting against the first, on the same seeds
        d = scores[setting] - scores[first]
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
        print(f"{a.screen}={setting:g} - {a.screen}={first:g}: score {d.mean():+.3f} ± {se:.3f} (paired)")


if __name__ == "__main__":
    main()
