"""Tiny, offline building blocks for the tests: datasets, random-init bases, DCDP configs and batches, and
the real CLIs run as a user runs them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.utils.feature_utils import dataset_to_policy_features


def policy_features(root: Path) -> tuple[dict, dict, dict]:
    meta = LeRobotDatasetMetadata("local/test", root=root)
    feats = dataset_to_policy_features(meta.features)
    out = {k: f for k, f in feats.items() if f.type is FeatureType.ACTION}
    inp = {k: f for k, f in feats.items() if k not in out}
    return inp, out, meta.stats


#: Where the CLIs of this environment live (``lerobot-train``, ``lerobot-eval``, ``dcdp-*``).
BIN = Path(sys.executable).parent
#: The environment every CLI runs in: offline, one thread.
CLI_ENV = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}


def run(args: list[str], cwd: Path, ok: bool = True) -> subprocess.CompletedProcess:
    """Run a CLI in :data:`CLI_ENV` (at most 10 min); ``ok``: assert it succeeded, else show its output."""
    proc = subprocess.run(args, capture_output=True, text=True, timeout=600, env=CLI_ENV, cwd=cwd)
    if ok:
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-6000:]
    return proc


#: ``lerobot-rollout`` on a simulated clock (written out by :func:`sim_clock_rollout`).
SIM_CLOCK_ROLLOUT = """
\"\"\"``lerobot-rollout`` on a simulated clock: LeRobot's control loops (base and episodic strategies) and the
``pusht_sim`` robot read a clock that advances only when a loop sleeps, by exactly what it sleeps, so every
tick takes exactly 1 / fps and how many ticks a duration holds cannot depend on the machine's load.\"\"\"
import sys
import time
import types

import lerobot.rollout.strategies.base as base
import lerobot.rollout.strategies.episodic as episodic
from lerobot.scripts.lerobot_rollout import main

import lerobot_dcdp.sim.robots.pusht_sim as pusht_sim


class SimClock:
    def __init__(self):
        self.ns = 0  # integer nanoseconds: ticks of 1 / fps add up exactly

    def perf_counter(self):
        return self.ns / 1e9

    def sleep(self, seconds):
        self.ns += max(0, round(seconds * 1e9))


clock = SimClock()
shim = types.SimpleNamespace(perf_counter=clock.perf_counter, sleep=clock.sleep, time=time.time)
for module in (base, episodic):
    module.time, module.precise_sleep = shim, clock.sleep
pusht_sim.time = shim  # PushTSim takes its real-time clock from here when it is built
sys.argv[0] = "lerobot-rollout"
sys.exit(main())
"""


def sim_clock_rollout(folder: Path) -> Path:
    """Write an executable ``lerobot-rollout`` on a simulated clock (:data:`SIM_CLOCK_ROLLOUT`) into
    ``folder``; it takes ``lerobot-rollout``'s flags."""
    path = folder / "lerobot-rollout-sim-clock"
    path.write_text(f"#!{sys.executable}\n{SIM_CLOCK_ROLLOUT}")
    path.chmod(0o755)
    return path


def corrector_train_args(
    base: Path, data: Path, out: Path, steps: int, save_freq: int, batch: int = 8
) -> list[str]:
    """``lerobot-train`` arguments of a tiny stage-1 run (the command a user types, shrunk)."""
    return [
        str(BIN / "lerobot-train"),
        "--policy.type=dcdp",
        f"--policy.base_policy_path={base}",
        "--dataset.repo_id=local/test",
        f"--dataset.root={data}",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        f"--output_dir={out}",
        f"--steps={steps}",
        f"--batch_size={batch}",
        f"--save_freq={save_freq}",
        "--log_freq=1",
        "--num_workers=0",
        "--wandb.enable=false",
        "--policy.feature_dim=32",
        "--policy.n_heads=4",
        # plain demonstrations + the default residual correction: stage 1 synthesises the block's motion
        "--policy.anchor_feature=observation.environment_state",
    ]


def train_corrector(base: Path, data: Path, out: Path, steps: int = 6, extra: tuple[str, ...] = ()) -> Path:
    """Train a tiny corrector around ``base`` with ``lerobot-train``; its last ``pretrained_model`` folder."""
    run([*corrector_train_args(base, data, out, steps, steps), *extra], cwd=out.parent)
    return out / "checkpoints" / "last" / "pretrained_model"


def make_tiny_base(kind: str, out_dir: Path, dataset_root: Path, seed: int = 0, **overrides) -> Path:
    """Save a random-init diffusion or ACT policy (with its processors) as a pretrained_model dir."""
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(seed)
    inp, out, stats = policy_features(dataset_root)
    inp = {k: v for k, v in inp.items() if v.type is not FeatureType.VISUAL or overrides.pop("images", False)}
    if kind == "diffusion":
        from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
        from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

        params = dict(
            n_obs_steps=2,
            horizon=16,
            n_action_steps=8,
            down_dims=(16, 32),
            diffusion_step_embed_dim=16,
            noise_scheduler_type="DDIM",
            num_inference_steps=3,
            num_train_timesteps=20,
            drop_n_last_frames=7,
            pretrained_backbone_weights=None,
            kernel_size=3,
            n_groups=4,
        )
        params.update(overrides)
        cfg = DiffusionConfig(
            input_features=inp, output_features=out, device="cpu", push_to_hub=False, **params
        )
        policy = DiffusionPolicy(cfg)
    elif kind == "act":
        from lerobot.policies.act.configuration_act import ACTConfig
        from lerobot.policies.act.modeling_act import ACTPolicy

        params = dict(
            chunk_size=16,
            n_action_steps=8,
            dim_model=32,
            n_heads=2,
            dim_feedforward=64,
            n_encoder_layers=1,
            n_decoder_layers=1,
            latent_dim=8,
            n_vae_encoder_layers=1,
            pretrained_backbone_weights=None,
        )
        params.update(overrides)
        cfg = ACTConfig(input_features=inp, output_features=out, device="cpu", push_to_hub=False, **params)
        policy = ACTPolicy(cfg)
    else:
        raise ValueError(kind)
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    out_dir.mkdir(parents=True, exist_ok=True)
    policy.save_pretrained(out_dir)
    pre.save_pretrained(out_dir)
    post.save_pretrained(out_dir)
    return out_dir


def make_dcdp_config(base: Path, dataset_root: Path, **overrides):
    """A tiny DCDPConfig wired to ``base`` with the features of ``dataset_root``."""
    import lerobot_policy_dcdp  # noqa: F401
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig

    inp, out, _ = policy_features(dataset_root)
    inp = {k: v for k, v in inp.items() if v.type is not FeatureType.VISUAL}
    # the paper's decoder path unless a test asks for correction="residual" (the config's default)
    params = dict(
        feature_dim=32,
        n_heads=4,
        state_hidden_dim=32,
        encoder_hidden_dim=32,
        decoder_hidden_dim=32,
        correction="reconstruct",
    )
    params.update(overrides)
    return DCDPConfig(
        base_policy_path=str(base),
        input_features=inp,
        output_features=out,
        device="cpu",
        push_to_hub=False,
        **params,
    )


def make_dcdp_policy(base: Path, dataset_root: Path, seed: int = 0, **overrides):
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    torch.manual_seed(seed)
    _, _, stats = policy_features(dataset_root)
    return DCDPPolicy(make_dcdp_config(base, dataset_root, **overrides), dataset_stats=stats)


def training_batches(policy, dataset_root: Path, batch_size: int = 16, seed: int = 0):
    """Endless normalised training batches with the policy's delta timestamps, through its processors."""
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    cfg = policy.config
    meta = LeRobotDatasetMetadata("local/test", root=dataset_root)
    dt = resolve_delta_timestamps(cfg, meta)  # as lerobot-train builds its dataset
    ds = LeRobotDataset("local/test", root=dataset_root, delta_timestamps=dt)
    pre, _ = make_dcdp_pre_post_processors(cfg)
    gen = torch.Generator().manual_seed(seed)
    while True:
        for batch in torch.utils.data.DataLoader(ds, batch_size=batch_size, shuffle=True, generator=gen):
            yield pre(batch)


def env_observations(n_envs: int, steps: int, seed: int = 0) -> list[dict]:
    """Raw observations of gym-pusht rollouts under random actions, as LeRobot's env wrapper names them."""
    import gym_pusht  # noqa: F401
    import gymnasium as gym
    import numpy as np

    envs = [gym.make("gym_pusht/PushT-v0", obs_type="environment_state_agent_pos") for _ in range(n_envs)]
    obs = [e.reset(seed=seed + i)[0] for i, e in enumerate(envs)]
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        out.append(
            {
                "observation.state": torch.tensor(
                    np.stack([o["agent_pos"] for o in obs]), dtype=torch.float32
                ),
                "observation.environment_state": torch.tensor(
                    np.stack([o["environment_state"] for o in obs]), dtype=torch.float32
                ),
            }
        )
        obs = [e.step(rng.uniform(100, 400, 2))[0] for e in envs]
    return out


def tiny_train_flags(repo_id: str, root: Path, steps: int = 2, batch: int = 4) -> list[str]:
    """The ``lerobot-train`` flags every tiny offline CLI run shares (local dataset, CPU, no Hub, no W&B)."""
    return [
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={root}",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--wandb.enable=false",
        "--num_workers=0",
        f"--batch_size={batch}",
        f"--steps={steps}",
        f"--save_freq={steps}",
    ]
