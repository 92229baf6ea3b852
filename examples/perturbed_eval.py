"""Score vs drift: evaluate a policy on ``pusht_perturbed`` over a sweep of drift magnitudes and plot it.

Any LeRobot policy directory works (a DCDP corrector, or a plain Diffusion / ACT base); a corrector can be
run in several execution modes (``--modes``). Each point is the benchmark's score: the mean over episodes
of max_t clip(coverage_t / 0.95, 0, 1), with the benchmark's rollout loop and seeds.

Example::

    python examples/perturbed_eval.py models/pusht-dcdp-state --modes open_loop dcdp \\
        --magnitudes 0 1 2 3 --episodes 20 --out runs/score_vs_drift.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.pyplot as plt  # noqa: E402
from lerobot.configs import PreTrainedConfig  # noqa: E402
from lerobot.policies.factory import get_policy_class, make_pre_post_processors  # noqa: E402

import lerobot_policy_dcdp  # noqa: E402, F401  (registers `dcdp` and `pusht_perturbed`)
from lerobot_dcdp.benchmark.rollout import Condition, rollout  # noqa: E402
from lerobot_dcdp.policy.configuration_dcdp import EXECUTION_MODES  # noqa: E402


def sweep(
    policy_dir: Path,
    magnitudes: list[float],
    modes: list[str] | None = None,
    perturbation: str = "constant",
    episodes: int = 10,
    max_steps: int = 300,
    seed_start: int = 100_000,
    obs_type: str = "environment_state_agent_pos",
) -> dict[str, list[float]]:
    """Score of the policy at every drift magnitude (px per step), per execution mode.

    Args:
        policy_dir: A pretrained policy directory.
        magnitudes: Drift magnitudes; 0 is the static task.
        modes: DCDP execution modes to compare (``None``: the policy as saved); only for ``dcdp`` policies.
        perturbation: ``constant`` or ``random`` drift.
        episodes: Episodes per point (seeds ``seed_start``.., the same for every point).
        max_steps: Step limit of an episode.
        seed_start: First seed.
        obs_type: gym-pusht observations the policy reads (``pixels_agent_pos`` for image policies).

    Returns:
        ``{mode or "policy": [score per magnitude]}``.
    """
    cfg = PreTrainedConfig.from_pretrained(policy_dir)
    if modes and cfg.type != "dcdp":
        raise ValueError(f"--modes needs a dcdp policy; {policy_dir} is a {cfg.type!r} policy")
    policy = get_policy_class(cfg.type).from_pretrained(policy_dir)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(policy_dir))
    seeds = list(range(seed_start, seed_start + episodes))

    scores: dict[str, list[float]] = {}
    for mode in modes or [None]:
        if mode is not None:
            policy.config.execution = mode
        label = mode or "policy"
        scores[label] = []
        for m in magnitudes:
            condition = Condition(f"{perturbation}_{m}", perturbation if m > 0 else "none", m)
            result = rollout(
                policy, preprocessor, postprocessor, condition, seeds, max_steps=max_steps, obs_type=obs_type
            )
            scores[label].append(result.score)
            solved = f"{result.success_rate:.0%} solved"
            print(f"{label:18s} drift {m:4.1f} px/step: score {result.score:.3f}, {solved}")
    return scores


def plot(magnitudes: list[float], scores: dict[str, list[float]], out: Path, title: str) -> None:
    """One line per mode: score against drift magnitude."""
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for label, ys in scores.items():
        ax.plot(magnitudes, ys, marker="o", label=label)
    ax.set(xlabel="block drift (px per control step)", ylabel="score", ylim=(0, 1.02), title=title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("policy", type=Path, help="pretrained policy directory")
    p.add_argument("--magnitudes", type=float, nargs="+", default=[0.0, 1.0, 2.0, 3.0])
    p.add_argument("--modes", nargs="+", choices=EXECUTION_MODES, default=None, help="dcdp policies only")
    p.add_argument("--perturbation", choices=["constant", "random"], default="constant")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--max-steps", type=int, default=300)
    p.add_argument("--seed-start", type=int, default=100_000)
    p.add_argument(
        "--obs-type",
        choices=["environment_state_agent_pos", "pixels_agent_pos"],
        default="environment_state_agent_pos",
    )
    p.add_argument("--out", type=Path, default=Path("score_vs_drift.png"), help="plot (PNG); scores: .json")
    args = p.parse_args(argv)
    if not (args.policy / "config.json").is_file():
        p.error(f"{args.policy} is not a pretrained policy directory (no config.json)")
    if any(m < 0 for m in args.magnitudes):
        p.error(f"--magnitudes must be >= 0, got {args.magnitudes}")
    if args.episodes < 1 or args.max_steps < 1:
        p.error("--episodes and --max-steps must be >= 1")

    scores = sweep(
        args.policy,
        args.magnitudes,
        args.modes,
        args.perturbation,
        args.episodes,
        args.max_steps,
        args.seed_start,
        args.obs_type,
    )
    plot(args.magnitudes, scores, args.out, f"{args.policy.name}, {args.perturbation} drift")
    args.out.with_suffix(".json").write_text(json.dumps({"magnitudes": args.magnitudes, "scores": scores}))
    print(f"plot: {args.out}")


if __name__ == "__main__":
    main()
