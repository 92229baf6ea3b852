"""``dcdp-finetune-rl``: residual reinforcement learning on a trained residual corrector (PPO; ResiP, Ankile
et al. 2024; Policy Decorator, Yuan et al. 2024).

The base stays frozen and plans, batched across ``--envs`` parallel envs, once per chunk, exactly as at
deployment (``execution='dcdp'``, synchronous planning). The corrector's residual head is the actor: a
Gaussian around its delta, the executed delta bounded to ``--max-deviation`` around the starting corrector's
(:mod:`lerobot_dcdp.residual_exploration`); the frame encoder, extractor and chunk encoder stay frozen. The
reward is the env's own, as increments (``--reward=progress``, default: the return is the episode's last
reward, so an episode that ends early on success is not paid less) or as is (``raw``), plus
``--success-bonus`` on the step that succeeds. The loss is PPO's clipped surrogate plus ``--kl-weight`` times
the KL divergence to the starting corrector's Gaussian (same noise): it keeps the corrector near where it
started. A critic (:class:`~lerobot_dcdp.residual_exploration.ValueCritic`) is trained beside it, alone for
the first ``--critic-warmup`` iterations.

Any LeRobot gym env with a reward runs (``--env.type=<type> --env.<field>=<value>``); the default is
``pusht_perturbed`` with a drift drawn per episode (``--max-magnitude``, ``--static-fraction``), on training
seeds (``--seed`` upwards, below the evaluation seeds). Every ``--save-every`` iterations a checkpoint is
written atomically, LeRobot's layout: ``<output-dir>/checkpoints/<iteration>/pretrained_model`` (loads with
``--policy.path`` like any corrector) and ``rl_state.pt`` (critic, optimisers, noise, counters), with
``checkpoints/last`` pointing at the newest; ``--resume`` continues from it. ``<output-dir>/log.jsonl`` has
one line per iteration: env steps, wall time, return, success rate, best reward, losses.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.ppo import clipped_policy_loss, gaussian_log_prob, generalized_advantages, progress_rewards
from lerobot_dcdp.residual_exploration import ResidualExploration, ValueCritic, critic_input

REWARDS = ("progress", "raw")


@dataclass
class RLConfig:
    """Settings of one ``dcdp-finetune-rl`` run.

    Args:
        policy: The trained residual corrector to start from (a ``pretrained_model`` folder).
        output_dir: Where checkpoints and the log go.
        iterations: PPO iterations (each: ``envs`` episodes, then ``epochs`` passes over their steps).
        envs: Parallel envs per iteration (the base plans for all of them in one batch).
        max_steps: Step limit of an episode.
        seed: First training seed (episode seeds run upwards from it; they must stay below the evaluation
            seeds, 100000).
        max_magnitude: ``pusht_perturbed``: drift magnitude ~ U[0, this] px/step.
        static_fraction: ``pusht_perturbed``: share of episodes without drift.
        reward: ``progress`` (the env's reward as increments) or ``raw``.
        success_bonus: Added to the reward of the step that succeeds (``info["is_success"]``).
        gamma: Discount.
        lam: GAE lambda.
        epochs: Passes over an iteration's steps.
        minibatch: Steps per gradient step.
        lr: Learning rate of the residual head and the noise scale.
        critic_lr: Learning rate of the critic.
        clip: PPO's ratio clip.
        init_std: Starting exploration noise (standard deviation in the [-1, 1] action range).
        min_std: Floor of the learned noise.
        max_deviation: Bound on the executed delta around the starting corrector's, [-1, 1] action range.
        kl_weight: Weight of the KL divergence to the starting corrector.
        critic_warmup: Iterations that train the critic only.
        save_every: Checkpoint period in iterations (the last iteration is always saved).
        env_args: LeRobot's ``--env.type=<type> --env.<field>=<value>`` flags (empty: ``pusht_perturbed``).
    """

    policy: str = ""
    output_dir: str = "runs/dcdp_rl"
    iterations: int = 50
    envs: int = 16
    max_steps: int = 300
    seed: int = 0
    max_magnitude: float = 2.5
    static_fraction: float = 0.1
    reward: str = "progress"
    success_bonus: float = 1.0
    gamma: float = 0.99
    lam: float = 0.95
    epochs: int = 4
    minibatch: int = 1024
    lr: float = 3e-5
    critic_lr: float = 3e-4
    clip: float = 0.2
    init_std: float = 0.01
    min_std: float = 1e-3
    max_deviation: float = 0.06
    kl_weight: float = 0.1
    critic_warmup: int = 1
    save_every: int = 5
    env_args: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        from lerobot_dcdp.pusht.demos import EVAL_SEED_START

        if self.reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {self.reward!r}")
        for name in ("iterations", "envs", "max_steps", "epochs", "minibatch", "save_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("init_std", "min_std", "max_deviation", "lr", "critic_lr", "clip"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.kl_weight < 0 or self.critic_warmup < 0 or self.success_bonus < 0:
            raise ValueError(
                f"kl_weight, critic_warmup and success_bonus must be >= 0, got {self.kl_weight}, "
                f"{self.critic_warmup}, {self.success_bonus}"
            )
        if self.init_std < self.min_std:
            raise ValueError(f"init_std ({self.init_std}) must be >= min_std ({self.min_std})")
        if not 0 <= self.gamma <= 1 or not 0 <= self.lam <= 1:
            raise ValueError(f"gamma and lam must lie in [0, 1], got {self.gamma}, {self.lam}")
        last_seed = self.seed + self.iterations * self.envs
        if self.seed < 0 or last_seed > EVAL_SEED_START:
            raise ValueError(
                f"training seeds {self.seed}..{last_seed - 1} must stay in [0, {EVAL_SEED_START}) (the "
                "evaluation seeds start there): lower --seed, --iterations or --envs"
            )


@dataclass
class Rollout:
    """One iteration's transitions, episodes laid end to end (the layout GAE expects)."""

    inputs: tuple[torch.Tensor, ...]
    mean: torch.Tensor
    sample: torch.Tensor
    elapsed: torch.Tensor
    rewards: torch.Tensor
    dones: torch.Tensor
    successes: list[bool]
    max_rewards: list[float]


#: Config fields RL runs with its own values; a checkpoint keeps the corrector's.
RUN_SETTINGS = ("execution", "planning", "inference_delay", "anchor_feature")


def load_corrector(path: str | Path):
    """The corrector at ``path`` in ``dcdp`` mode on the eager path (every step calls its residual head),
    its processors, and its own values of :data:`RUN_SETTINGS` (what its checkpoints save)."""
    from lerobot_dcdp.configuration_dcdp import DCDPConfig
    from lerobot_dcdp.pusht.corrections import load_policy

    saved = DCDPConfig.from_pretrained(str(path))
    if saved.device not in (None, "cpu"):
        raise ValueError(
            f"{path} is configured for device {saved.device!r}; dcdp-finetune-rl runs on CPU (its rollouts "
            "are CPU-bound simulation): save the corrector with device='cpu'"
        )
    settings = {name: getattr(saved, name) for name in RUN_SETTINGS}
    policy, pre, post = load_policy(str(path), None, "dcdp", "observation.environment_state")
    if policy.config.correction != "residual":
        raise ValueError(
            f"{path} holds a correction={policy.config.correction!r} corrector: residual RL fine-tunes a "
            "residual head (train one with --policy.correction=residual first)"
        )
    policy.config.planning, policy.config.inference_delay = "sync", 0  # the base plans on the tick, on time
    policy.corrector.fast_inference = False
    policy.requires_grad_(False)
    policy.corrector.residual.requires_grad_(True)
    return policy, pre, post, settings


@torch.no_grad()
def collect(policy, pre, post, explore: ResidualExploration, seeds, specs, env_config, max_steps) -> Rollout:
    """Run one batch of episodes with exploration and return their transitions."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.lockstep import run_lockstep
    from lerobot_dcdp.pusht.corrections import episode_env

    envs = [episode_env(env_config, spec, max_steps) for spec in specs]
    n = len(envs)
    rows: list[list[tuple]] = [[] for _ in range(n)]
    rewards: list[list[float]] = [[] for _ in range(n)]
    policy.reset()
    t = [0]

    def act(obs: list[dict], active: np.ndarray) -> np.ndarray:
        stacked = {k: np.stack([o[k] for o in obs]) for k in obs[0]}
        batch = pre(dict(preprocess_observation(stacked)))
        explore.active = True
        try:
            action = post(policy.select_action(batch)).cpu().numpy()
        finally:
            explore.active = False
        call = explore.take()
        for i in np.flatnonzero(active):
            rows[i].append((tuple(a[i] for a in call.inputs), call.mean[i], call.sample[i], t[0] / max_steps))
        t[0] += 1
        return action

    def on_step(i: int, o: dict, reward: float, info: dict) -> None:
        rewards[i].append(reward)

    try:
        result = run_lockstep(envs, list(seeds), act, max_steps, on_step)
    finally:
        for env in envs:
            env.close()
    flat = [r for ep in rows for r in ep]
    if not flat:
        raise RuntimeError("the rollout took no step: check --max-steps and the env")
    n_inputs = len(flat[0][0])
    return Rollout(
        inputs=tuple(torch.stack([r[0][k] for r in flat]) for k in range(n_inputs)),
        mean=torch.stack([r[1] for r in flat]),
        sample=torch.stack([r[2] for r in flat]),
        elapsed=torch.tensor([r[3] for r in flat], dtype=torch.float32),
        rewards=torch.cat([torch.tensor(r, dtype=torch.float32) for r in rewards]),
        dones=torch.cat([torch.arange(len(r)) == len(r) - 1 for r in rewards]),
        successes=result.successes,
        max_rewards=result.max_rewards,
    )


def shaped_rewards(rollout: Rollout, cfg: RLConfig, episode_lengths: list[int], success_steps: list[int]):
    """The reward PPO optimises, per transition (see the module docstring)."""
    out, start = [], 0
    for length, success_at in zip(episode_lengths, success_steps, strict=True):
        r = rollout.rewards[start : start + length]
        r = progress_rewards(r) if cfg.reward == "progress" else r.clone()
        if success_at >= 0:
            r[success_at] += cfg.success_bonus
        out.append(r)
        start += length
    return torch.cat(out)


class ResidualPPO:
    """The actor (the corrector's residual head and the noise scale), the critic and their optimisers."""

    def __init__(self, policy, cfg: RLConfig, generator: torch.Generator) -> None:
        self.cfg = cfg
        self.policy = policy
        head = policy.corrector.residual
        action_dim = head.net[-1].out_features
        self.log_std = torch.nn.Parameter(torch.full((action_dim,), math.log(cfg.init_std)))
        self.explore = ResidualExploration(head, self.log_std, cfg.max_deviation, generator)
        self.horizon = policy.config.n_action_steps
        self.critic: ValueCritic | None = None
        self.actor_opt = torch.optim.Adam([*head.parameters(), self.log_std], lr=cfg.lr)
        self.critic_opt: torch.optim.Optimizer | None = None

    def _ensure_critic(self, rollout: Rollout) -> None:
        if self.critic is None:
            dim = critic_input(tuple(a[:1] for a in rollout.inputs), self.horizon, rollout.elapsed[:1]).shape[
                -1
            ]
            self.critic = ValueCritic(dim)
            self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=self.cfg.critic_lr)

    def update(self, rollout: Rollout, rewards: torch.Tensor, train_actor: bool, generator) -> dict:
        """PPO epochs over one rollout; returns the mean losses."""
        cfg = self.cfg
        self._ensure_critic(rollout)
        x = critic_input(rollout.inputs, self.horizon, rollout.elapsed)
        with torch.no_grad():
            values = self.critic(x)
            old_log_prob = gaussian_log_prob(rollout.sample, rollout.mean, self.log_std)
        advantages, returns = generalized_advantages(rewards, values, rollout.dones, cfg.gamma, cfg.lam)
        advantages = (advantages - advantages.mean()) / advantages.std().clamp_min(1e-8)
        head, n = self.explore.head, len(rewards)
        sums = {"policy_loss": 0.0, "kl_to_start": 0.0, "value_loss": 0.0}
        count = 0
        for _ in range(cfg.epochs):
            order = torch.randperm(n, generator=generator)
            for begin in range(0, n, cfg.minibatch):
                idx = order[begin : begin + cfg.minibatch]
                value_loss = ((self.critic(x[idx]) - returns[idx]) ** 2).mean()
                self.critic_opt.zero_grad()
                value_loss.backward()
                self.critic_opt.step()
                sums["value_loss"] += value_loss.item()
                if train_actor:
                    inputs = tuple(a[idx] for a in rollout.inputs)
                    mean = head(*inputs)
                    log_prob = gaussian_log_prob(rollout.sample[idx], mean, self.log_std)
                    policy_loss = clipped_policy_loss(log_prob, old_log_prob[idx], advantages[idx], cfg.clip)
                    with torch.no_grad():
                        start = self.explore.start(*inputs)
                    # KL(N(mean, s) || N(start, s)) with the same noise s; s is held fixed here, or the
                    # penalty could be lowered by raising the noise instead of staying near the start
                    kl = (((mean - start) / self.log_std.detach().exp()) ** 2).sum(-1).mean() / 2
                    loss = policy_loss + cfg.kl_weight * kl
                    self.actor_opt.zero_grad()
                    loss.backward()
                    self.actor_opt.step()
                    with torch.no_grad():
                        self.log_std.clamp_(min=math.log(cfg.min_std))
                    sums["policy_loss"] += policy_loss.item()
                    sums["kl_to_start"] += kl.item()
                count += 1
        out = {k: v / max(count, 1) for k, v in sums.items()}
        out["noise_std"] = self.log_std.exp().mean().item()
        return out

    def state_dict(self) -> dict:
        return {
            "log_std": self.log_std.detach().clone(),
            "start_head": self.explore.start.state_dict(),
            "critic": None if self.critic is None else self.critic.state_dict(),
            "critic_input_dim": None if self.critic is None else self.critic.net[0].normalized_shape[0],
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": None if self.critic_opt is None else self.critic_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            self.log_std.copy_(state["log_std"])
        self.explore.start.load_state_dict(state["start_head"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        if state["critic"] is not None:
            self.critic = ValueCritic(state["critic_input_dim"])
            self.critic.load_state_dict(state["critic"])
            self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=self.cfg.critic_lr)
            self.critic_opt.load_state_dict(state["critic_opt"])


def save_checkpoint(
    out: Path, iteration: int, policy, pre, post, ppo: ResidualPPO, extra: dict, settings: dict
) -> Path:
    """Write ``checkpoints/<iteration>`` whole (a temporary folder renamed into place), then point ``last``
    at it; the saved config carries the corrector's own ``settings`` (:data:`RUN_SETTINGS`)."""
    checkpoints = out / "checkpoints"
    checkpoints.mkdir(parents=True, exist_ok=True)
    final = checkpoints / f"{iteration:06d}"
    tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=checkpoints))
    tmp.chmod(0o755)  # mkdtemp's 0700 would hide the checkpoint from other users
    try:
        model = tmp / "pretrained_model"
        running = {name: getattr(policy.config, name) for name in settings}
        for name, value in settings.items():
            setattr(policy.config, name, value)
        try:
            policy.save_pretrained(model)
        finally:
            for name, value in running.items():
                setattr(policy.config, name, value)
        pre.save_pretrained(model)
        post.save_pretrained(model)
        torch.save({**ppo.state_dict(), **extra}, tmp / "rl_state.pt")
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    link = checkpoints / ".last-tmp"
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(final.name)
    os.replace(link, checkpoints / "last")
    return final


def finetune(cfg: RLConfig, resume: bool = False, progress: bool = True) -> Path:
    """Run (or, with ``resume``, continue with the saved settings; only ``iterations`` is taken from ``cfg``)
    residual RL; returns the last checkpoint folder."""
    from lerobot_dcdp.pusht.corrections import drift_for_seed, parse_env_args

    out = Path(cfg.output_dir)
    last = out / "checkpoints" / "last"
    state, start_iteration = None, 0
    if resume:
        if not (last / "rl_state.pt").is_file():
            raise FileNotFoundError(
                f"--resume: no checkpoint at {last.resolve()} (run without --resume first)"
            )
        state = torch.load(last / "rl_state.pt", weights_only=False)
        saved = RLConfig(**state["config"])
        cfg = RLConfig(**{**asdict(saved), "iterations": cfg.iterations})
        start_iteration = state["iteration"] + 1
        policy, pre, post, settings = load_corrector(last / "pretrained_model")
        _keep_log_lines(out / "log.jsonl", state["iteration"])
    else:
        if not cfg.policy:
            raise ValueError("--policy=<trained residual corrector folder> is required (or --resume)")
        if (out / "checkpoints").exists():
            raise FileExistsError(
                f"{(out / 'checkpoints').resolve()} exists: pass --resume to continue it or pick another "
                "--output-dir"
            )
        policy, pre, post, settings = load_corrector(cfg.policy)
        (out / "log.jsonl").unlink(missing_ok=True)  # a run cut off before its first checkpoint
    env_config = parse_env_args(cfg.env_args)
    generator = torch.Generator().manual_seed(cfg.seed)
    ppo = ResidualPPO(policy, cfg, generator)
    if state is not None:
        ppo.load_state_dict(state)
        generator.set_state(state["generator"])
    out.mkdir(parents=True, exist_ok=True)
    env_steps = 0 if state is None else state["env_steps"]
    final = last
    for iteration in range(start_iteration, cfg.iterations):
        began = time.perf_counter()
        seeds = [cfg.seed + iteration * cfg.envs + i for i in range(cfg.envs)]
        specs = [drift_for_seed(s, cfg.max_magnitude, cfg.static_fraction) for s in seeds]
        torch.manual_seed(cfg.seed * 1_000_003 + iteration)  # the base's sampling noise
        rollout = collect(policy, pre, post, ppo.explore, seeds, specs, env_config, cfg.max_steps)
        lengths = [int(n) for n in _episode_lengths(rollout.dones)]
        success_at = _success_steps(rollout, lengths)
        rewards = shaped_rewards(rollout, cfg, lengths, success_at)
        losses = ppo.update(rollout, rewards, iteration >= cfg.critic_warmup, generator)
        env_steps += len(rewards)
        line = {
            "iteration": iteration,
            "env_steps": env_steps,
            "seconds": round(time.perf_counter() - began, 2),
            "success": float(np.mean(rollout.successes)),
            "max_reward": float(np.mean(rollout.max_rewards)),
            "return": float(rewards.sum() / len(lengths)),
            **{k: round(v, 6) for k, v in losses.items()},
        }
        with open(out / "log.jsonl", "a") as f:
            f.write(json.dumps(line) + "\n")
        if progress:
            print(json.dumps(line), flush=True)
        if (iteration + 1) % cfg.save_every == 0 or iteration == cfg.iterations - 1:
            extra = {
                "config": asdict(cfg),
                "iteration": iteration,
                "env_steps": env_steps,
                "generator": generator.get_state(),
            }
            final = save_checkpoint(out, iteration, policy, pre, post, ppo, extra, settings)
    ppo.explore.remove()
    return final


def _keep_log_lines(log: Path, last_iteration: int) -> None:
    """Drop the log lines of iterations after ``last_iteration`` (logged, cut off before their checkpoint)."""
    if log.is_file():
        lines = [x for x in log.read_text().splitlines() if json.loads(x)["iteration"] <= last_iteration]
        log.write_text("".join(line + "\n" for line in lines))


def _episode_lengths(dones: torch.Tensor) -> list[int]:
    ends = torch.nonzero(dones).flatten().tolist()
    return [e - s for s, e in zip([-1, *ends[:-1]], ends, strict=True)]


def _success_steps(rollout: Rollout, lengths: list[int]) -> list[int]:
    """Per episode, the index of the step that succeeded (-1: none): lock-step ends an episode on success."""
    return [n - 1 if ok else -1 for n, ok in zip(lengths, rollout.successes, strict=True)]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-finetune-rl", description=__doc__.splitlines()[0])
    defaults = RLConfig()
    p.add_argument("--policy", default="", help="the trained residual corrector to start from")
    p.add_argument("--output-dir", default=defaults.output_dir)
    p.add_argument("--resume", action="store_true", help="continue <output-dir>/checkpoints/last")
    for name, value in asdict(defaults).items():
        if name in ("policy", "output_dir", "env_args"):
            continue
        flag = "--" + name.replace("_", "-")
        if name == "reward":
            p.add_argument(flag, default=value, choices=REWARDS)
        else:
            p.add_argument(flag, type=type(value), default=value)
    p.epilog = (
        "LeRobot's env flags pick the env: --env.type=<type> --env.<field>=<value> (default pusht_perturbed "
        "with keypoint observations and a drift drawn per episode). See the module docstring for the method."
    )
    a, rest = p.parse_known_args(argv)
    torch.set_num_threads(1)
    try:
        unknown = [x for x in rest if not x.startswith("--env.")]
        if unknown:
            raise ValueError(f"unrecognized arguments: {' '.join(unknown)}")
        values = {k: v for k, v in vars(a).items() if k != "resume"}
        cfg = RLConfig(**values, env_args=rest)
        final = finetune(cfg, resume=a.resume)
    except (ValueError, FileNotFoundError, FileExistsError) as e:
        p.error(str(e))
    print(f"last checkpoint: {final}/pretrained_model (load it with --policy.path=...)")


if __name__ == "__main__":
    main()
