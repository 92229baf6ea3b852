"""``dcdp-finetune-rl``: residual reinforcement learning on a trained residual corrector (PPO; ResiP, Ankile
et al. 2024; Policy Decorator, Yuan et al. 2024).

The base stays frozen and plans, batched across ``--envs`` parallel envs, once per chunk, exactly as at
deployment (``execution='dcdp'``, synchronous planning). The corrector's residual head is the actor: a
Gaussian around its delta, the executed delta bounded to ``--max-deviation`` around the starting corrector's
(:mod:`lerobot_dcdp.train.residual_exploration`); the frame encoder, extractor and chunk encoder stay frozen.
The reward is the env's own, as increments (``--reward=progress``, default: the return is the episode's last
reward, so an episode that ends early on success is not paid less) or as is (``raw``), plus
``--success-bonus`` on the step that succeeds. The loss is PPO's clipped surrogate plus ``--kl-weight`` times
the KL divergence to the starting corrector's Gaussian (same noise): it keeps the corrector near where it
started. A critic (:class:`~lerobot_dcdp.train.residual_exploration.ValueCritic`) is trained beside it, alone
for the first ``--critic-warmup`` iterations (:mod:`lerobot_dcdp.train.residual_ppo`).

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
import inspect
import json
import os
import re
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from lerobot_dcdp.train.residual_exploration import ResidualExploration
from lerobot_dcdp.train.residual_ppo import ResidualPPO, Rollout, shaped_rewards

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
        from lerobot_dcdp.data.pusht_demos import EVAL_SEED_START

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


#: Config fields RL runs with its own values; a checkpoint keeps the corrector's.
RUN_SETTINGS = ("execution", "planning", "inference_delay", "anchor_feature")


def load_corrector(path: str | Path):
    """The corrector at ``path`` in ``dcdp`` mode on the eager path (every step calls its residual head),
    with only its residual head trainable, its processors, and its own values of :data:`RUN_SETTINGS` (what
    its checkpoints save); it loads with :func:`~lerobot_dcdp.policy.loader.load_dcdp`.

    Raises:
        ValueError: the corrector is configured for a device other than the CPU, or is not a ``residual``
            one.
    """
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
    from lerobot_dcdp.policy.loader import load_dcdp

    saved = DCDPConfig.from_pretrained(str(path))
    if saved.device not in (None, "cpu"):
        raise ValueError(
            f"{path} is configured for device {saved.device!r}; dcdp-finetune-rl runs on CPU (its rollouts "
            "are CPU-bound simulation): save the corrector with device='cpu'"
        )
    if saved.correction != "residual":  # before loading: a folder of another corrector may lack processors
        raise ValueError(
            f"{path} holds a correction={saved.correction!r} corrector: residual RL fine-tunes a "
            "residual head (train one with --policy.correction=residual first)"
        )
    settings = {name: getattr(saved, name) for name in RUN_SETTINGS}
    policy, pre, post = load_dcdp(path, execution="dcdp", anchor_feature="observation.environment_state")
    policy.config.planning, policy.config.inference_delay = "sync", 0  # the base plans on the tick, on time
    policy.corrector.fast_inference = False
    policy.requires_grad_(False)
    policy.corrector.residual.requires_grad_(True)
    return policy, pre, post, settings


def rollout_env(env_config, spec, max_steps: int):
    """One training episode's gym env, ``max_steps`` long: ``pusht_perturbed`` with the episode's drawn drift
    (``env_config`` ``None``: keypoint observations; a ``pusht_perturbed`` config: its own fields, its
    ``episode_length`` replaced by ``max_steps``), any other LeRobot env type as its ``--env.*`` flags
    configure it (:func:`~lerobot_dcdp.data.corrections.episode_env`)."""
    from lerobot_dcdp.data.corrections import episode_env

    return episode_env(env_config, spec, max_steps)


@torch.no_grad()
def collect(policy, pre, post, explore: ResidualExploration, seeds, specs, env_config, max_steps) -> Rollout:
    """Run one batch of episodes (:func:`rollout_env`, in lock-step) with exploration and return their
    transitions."""
    from lerobot.envs.utils import preprocess_observation

    from lerobot_dcdp.sim.lockstep import run_lockstep

    envs = [rollout_env(env_config, spec, max_steps) for spec in specs]
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
    """Run residual RL, or with ``resume`` continue ``cfg.output_dir``'s last checkpoint with its saved
    settings (only ``iterations`` is taken from ``cfg``).

    Returns:
        The last checkpoint folder.

    Raises:
        ValueError: no ``cfg.policy`` (without ``resume``), bad ``--env.*`` flags or a corrector RL cannot
            fine-tune.
        FileNotFoundError: ``resume`` without a checkpoint.
        FileExistsError: a new run into an output folder that already holds checkpoints.
    """
    from lerobot_dcdp.data.corrections import drift_for_seed, parse_env_args

    out = Path(cfg.output_dir)
    cfg, state, (policy, pre, post, settings) = _start(cfg, out, resume)
    env_config = parse_env_args(cfg.env_args)
    generator = torch.Generator().manual_seed(cfg.seed)
    ppo = ResidualPPO(policy, cfg, generator)
    if state is not None:
        ppo.load_state_dict(state)
        generator.set_state(state["generator"])
    out.mkdir(parents=True, exist_ok=True)
    env_steps = 0 if state is None else state["env_steps"]
    final = out / "checkpoints" / "last"
    for iteration in range(0 if state is None else state["iteration"] + 1, cfg.iterations):
        began = time.perf_counter()
        seeds = [cfg.seed + iteration * cfg.envs + i for i in range(cfg.envs)]
        specs = [drift_for_seed(s, cfg.max_magnitude, cfg.static_fraction) for s in seeds]
        torch.manual_seed(cfg.seed * 1_000_003 + iteration)  # the base's sampling noise
        rollout = collect(policy, pre, post, ppo.explore, seeds, specs, env_config, cfg.max_steps)
        lengths = rollout.episode_lengths()
        rewards = shaped_rewards(rollout, cfg, lengths, rollout.success_steps(lengths))
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


def _start(cfg: RLConfig, out: Path, resume: bool) -> tuple[RLConfig, dict | None, tuple]:
    """The settings a run goes on with, the saved RL state (``None`` for a new run) and
    :func:`load_corrector`'s ``(policy, pre, post, settings)``: the starting corrector's for a new run (whose
    stale log is removed), the last checkpoint's for ``resume`` (its log cut back to that checkpoint)."""
    last = out / "checkpoints" / "last"
    if resume:
        if not (last / "rl_state.pt").is_file():
            raise FileNotFoundError(
                f"--resume: no checkpoint at {last.resolve()} (run without --resume first)"
            )
        state = torch.load(last / "rl_state.pt", weights_only=False)
        saved = RLConfig(**state["config"])
        cfg = RLConfig(**{**asdict(saved), "iterations": cfg.iterations})
        loaded = load_corrector(last / "pretrained_model")
        _keep_log_lines(out / "log.jsonl", state["iteration"])
        return cfg, state, loaded
    if not cfg.policy:
        raise ValueError("--policy=<trained residual corrector folder> is required (or --resume)")
    if (out / "checkpoints").exists():
        raise FileExistsError(
            f"{(out / 'checkpoints').resolve()} exists: pass --resume to continue it or pick another "
            "--output-dir"
        )
    loaded = load_corrector(cfg.policy)
    (out / "log.jsonl").unlink(missing_ok=True)  # a run cut off before its first checkpoint
    return cfg, None, loaded


def _keep_log_lines(log: Path, last_iteration: int) -> None:
    """Drop the log lines of iterations after ``last_iteration`` (logged, cut off before their checkpoint)."""
    if log.is_file():
        lines = [x for x in log.read_text().splitlines() if json.loads(x)["iteration"] <= last_iteration]
        log.write_text("".join(line + "\n" for line in lines))


def field_help() -> dict[str, str]:
    """Each :class:`RLConfig` field's description, read from the ``Args:`` section of its docstring (the
    flags' help)."""
    args = inspect.cleandoc(RLConfig.__doc__ or "").split("Args:", 1)[-1]
    out: dict[str, str] = {}
    name = None
    for line in args.splitlines():
        entry = re.match(r"^    (\w+): (.*)$", line)
        if entry:
            name = entry[1]
            out[name] = entry[2]
        elif name is not None and line.strip():
            out[name] += " " + line.strip()
    return {k: v.replace("``", "").replace("%", "%%") for k, v in out.items()}


def build_parser() -> argparse.ArgumentParser:
    """``dcdp-finetune-rl``'s flags: ``--policy``, ``--output-dir``, ``--resume`` and one per other
    :class:`RLConfig` field (LeRobot's ``--env.*`` flags are left over, see :func:`main`)."""
    p = argparse.ArgumentParser(prog="dcdp-finetune-rl", description=__doc__.splitlines()[0])
    defaults, helps = RLConfig(), field_help()
    p.add_argument("--policy", default="", help="the trained residual corrector to start from")
    p.add_argument(
        "--output-dir",
        default=defaults.output_dir,
        help="where checkpoints and log.jsonl go (default: %(default)s)",
    )
    p.add_argument("--resume", action="store_true", help="continue <output-dir>/checkpoints/last")
    for name, value in asdict(defaults).items():
        if name in ("policy", "output_dir", "env_args"):
            continue
        flag, text = "--" + name.replace("_", "-"), helps[name] + " (default: %(default)s)"
        if name == "reward":
            p.add_argument(flag, default=value, choices=REWARDS, help=text)
        else:
            p.add_argument(flag, type=type(value), default=value, help=text)
    p.epilog = (
        "LeRobot's env flags pick the env: --env.type=<type> --env.<field>=<value> (default pusht_perturbed "
        "with keypoint observations and a drift drawn per episode; an episode's step limit is --max-steps). "
        "See the module docstring for the method."
    )
    return p


def main(argv: list[str] | None = None) -> None:
    """``dcdp-finetune-rl``: parse the flags (LeRobot's ``--env.*`` among them), run :func:`finetune` and
    print the last checkpoint; a bad flag or setting exits with argparse's error."""
    p = build_parser()
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
