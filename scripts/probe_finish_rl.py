"""Probe (issue 22): can residual RL learn the *finish* under drift when every episode starts near the goal?

RL2-RL4 ran whole episodes: most of each is transport, the finish is a few sparse successes at the end, and
RL4 traded the finish at rest for transport. Here every episode starts where the shipped gated corrector hands
the plan back to the base (its completion gate says "near", p > 0.5), each episode is about the finish only.

Subcommands:

- ``harvest``: run a gated corrector on seeds from ``--seed`` with a drift per seed (``drift_for_seed``) and
  store, per episode that gets near, the simulator state (agent position, block position and angle) on the
  first near step, in an ``.npz``.
- ``start``: write the starting policy for RL: an *ungated* corrector whose residual head's last layer is
  zeroed, i.e. the base's plan bit for bit (what the gated corrector executes near the goal).
- ``train``: ``dcdp-finetune-rl`` on that policy, every episode reset into a harvested state (the env's own
  reset, then the stored pose written into the simulator), drift re-drawn per training seed.
- ``eval``: success within ``--max-steps`` from held-out harvested states (each state with its own seed's
  drift; or a fixed ``--condition``) for any number of policies, on the same starts.

A probe, not a shipped path: it needs ``PushTEnv``'s bodies to set the state.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch


def sim_state(env) -> np.ndarray:
    u = env.unwrapped
    return np.array([*u.agent.position, *u.block.position, u.block.angle], dtype=np.float64)


class StartFrom(gym.Wrapper):
    """Reset as usual, then put the agent and the block where ``state`` says (velocities zero)."""

    def __init__(self, env, state: np.ndarray):
        super().__init__(env)
        self.state = state

    def reset(self, *, seed=None, options=None):
        _, info = self.env.reset(seed=seed, options=options)
        u = self.env.unwrapped
        u.agent.position = (float(self.state[0]), float(self.state[1]))
        u.agent.velocity = (0.0, 0.0)
        u.block.position = (float(self.state[2]), float(self.state[3]))
        u.block.angle = float(self.state[4])
        u.block.velocity = (0.0, 0.0)
        u.block.angular_velocity = 0.0
        return u.get_obs(), info


def harvest(args) -> None:
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.lockstep import run_lockstep
    from lerobot_dcdp.pusht.corrections import drift_for_seed, episode_env, load_policy

    policy, pre, post = load_policy(args.policy, None, "dcdp", "observation.environment_state")
    states, seeds_out, steps_out, outcome = [], [], [], []
    for begin in range(args.seed, args.seed + args.episodes, args.batch):
        seeds = list(range(begin, min(begin + args.batch, args.seed + args.episodes)))
        specs = [drift_for_seed(s, args.max_magnitude, args.static_fraction) for s in seeds]
        envs = [episode_env(None, spec, 300) for spec in specs]
        first = [None] * len(envs)
        t = [0]
        policy.reset()

        def act(obs, active, envs=envs, first=first, t=t):
            stacked = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
            batch = pre(dict(preprocess_observation(stacked)))
            near = policy.completion_gate(batch)
            for i in np.flatnonzero(active):
                if first[i] is None and float(near[i]) > 0.5:
                    first[i] = (sim_state(envs[i]), t[0])
            t[0] += 1
            return post(policy.select_action(batch)).cpu().numpy()

        result = run_lockstep(envs, seeds, act, 300)
        for env in envs:
            env.close()
        for i, s in enumerate(seeds):
            if first[i] is not None:
                states.append(first[i][0])
                seeds_out.append(s)
                steps_out.append(first[i][1])
                outcome.append(result.successes[i])
        print(f"seeds {seeds[0]}..{seeds[-1]}: {len(states)} near starts so far", flush=True)
    np.savez(
        args.out,
        states=np.stack(states),
        seeds=np.array(seeds_out),
        steps=np.array(steps_out),
        success=np.array(outcome),
        max_magnitude=args.max_magnitude,
        static_fraction=args.static_fraction,
    )
    print(json.dumps({"starts": len(states), "success_of_those": float(np.mean(outcome))}))


def make_start(args) -> None:
    from lerobot_dcdp.pusht.corrections import load_policy

    policy, pre, post = load_policy(args.policy, None, "dcdp", "observation.environment_state")
    if policy.config.completion_gate:
        raise SystemExit("start from an ungated corrector")
    with torch.no_grad():
        policy.corrector.residual.net[-1].weight.zero_()
        policy.corrector.residual.net[-1].bias.zero_()
    base = Path(args.policy) / policy.config.base_policy_path
    policy.config.base_policy_path = str(base.resolve())
    out = Path(args.out)
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    print(out)


def _patch_starts(bank: np.ndarray, first_seed: int) -> None:
    """Make the recorder's ``episode_env`` reset every episode into ``bank[(seed - first_seed) % n]``."""
    import lerobot_dcdp.pusht.corrections as corrections

    plain = corrections.episode_env

    class SeededStart(gym.Wrapper):
        def reset(self, *, seed=None, options=None):
            self.env.state = bank[(int(seed) - first_seed) % len(bank)]
            return self.env.reset(seed=seed, options=options)

    def episode_env(env_config, spec, max_steps):
        return SeededStart(StartFrom(plain(env_config, spec, max_steps), bank[0]))

    corrections.episode_env = episode_env


def train(args, rest: list[str]) -> None:
    from lerobot_dcdp import finetune_rl

    bank = np.load(args.bank)["states"]
    _patch_starts(bank, args.seed)
    finetune_rl.main([*rest, f"--seed={args.seed}"])


def _eval_drift(condition: str, seed: int, data):
    """The drift of one evaluation start: ``condition`` (e.g. ``constant_0.5``) or the start's own seed's."""
    from lerobot_dcdp.pusht.corrections import DriftSpec, drift_for_seed

    if not condition:
        return drift_for_seed(seed, float(data["max_magnitude"]), float(data["static_fraction"]))
    kind, mag = condition.rsplit("_", 1)
    if kind == "static":
        return DriftSpec("none", 0.0, 0.0, (0.0,), 50)
    direction = float(np.random.default_rng([seed, 3]).uniform(0, 360))
    return DriftSpec(kind, float(mag), direction, (0.0, 90.0, 180.0, 270.0, 45.0), 50)


def _run(policy, pre, post, envs, seeds: list[int], max_steps: int) -> list[bool]:
    """One lock-step batch of ``policy`` on ``envs``; their successes (the envs are closed)."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.lockstep import run_lockstep

    policy.reset()

    def act(obs, active):
        stacked = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
        batch = pre(dict(preprocess_observation(stacked)))
        return post(policy.select_action(batch)).cpu().numpy()

    try:
        return run_lockstep(envs, seeds, act, max_steps).successes
    finally:
        for env in envs:
            env.close()


def evaluate(args) -> None:
    from lerobot_dcdp.pusht.corrections import episode_env, load_policy

    data = np.load(args.bank)
    states, seeds = data["states"][: args.n], data["seeds"][: args.n]
    out = {}
    for label_path in args.policies:
        label, path = label_path.split("=", 1)
        policy, pre, post = load_policy(path, None, "dcdp", "observation.environment_state")
        wins = []
        for begin in range(0, len(states), args.batch):
            idx = list(range(begin, min(begin + args.batch, len(states))))
            specs = [_eval_drift(args.condition, int(seeds[i]), data) for i in idx]
            envs = [
                StartFrom(episode_env(None, sp, args.max_steps), states[i])
                for sp, i in zip(specs, idx, strict=True)
            ]
            torch.manual_seed(12345 + begin)
            wins += _run(policy, pre, post, envs, [int(seeds[i]) + 500_000 for i in idx], args.max_steps)
        out[label] = {"success": float(np.mean(wins)), "n": len(wins), "wins": [bool(w) for w in wins]}
        print(label, f"{np.mean(wins):.3f} of {len(wins)}", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(out))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    h = sub.add_parser("harvest")
    h.add_argument("--policy", required=True)
    h.add_argument("--seed", type=int, default=60000)
    h.add_argument("--episodes", type=int, default=400)
    h.add_argument("--batch", type=int, default=50)
    h.add_argument("--max-magnitude", type=float, default=1.0)
    h.add_argument("--static-fraction", type=float, default=0.25)
    h.add_argument("--out", required=True)
    s = sub.add_parser("start")
    s.add_argument("--policy", required=True)
    s.add_argument("--out", required=True)
    t = sub.add_parser("train")
    t.add_argument("--bank", required=True)
    t.add_argument("--seed", type=int, default=0, help="first training seed (also indexes the bank)")
    e = sub.add_parser("eval")
    e.add_argument("--bank", required=True)
    e.add_argument("--n", type=int, default=200)
    e.add_argument("--batch", type=int, default=50)
    e.add_argument("--max-steps", type=int, default=120)
    e.add_argument("--condition", default="", help="e.g. constant_0.5 (default: each start's own drift)")
    e.add_argument("--out", default="")
    e.add_argument("policies", nargs="+", help="label=path")
    args, rest = p.parse_known_args()
    if args.cmd == "harvest":
        harvest(args)
    elif args.cmd == "start":
        make_start(args)
    elif args.cmd == "train":
        train(args, rest)
    else:
        evaluate(args)


if __name__ == "__main__":
    main()
