"""``dcdp-record-corrections``: stale chunks and a teacher's corrections of them, as a LeRobotDataset v3.

The command line of :func:`~lerobot_dcdp.data.corrections.recorder.record`: its own flags make the
:class:`~lerobot_dcdp.data.corrections.settings.RecordingSettings`, LeRobot's ``--env.*`` flags the env and
``--teleop.*`` flags the ``teleop`` teacher; it prints where the dataset went and the ``lerobot-train``
command that trains a corrector on it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from lerobot_dcdp.data.corrections.recorder import record
from lerobot_dcdp.data.corrections.settings import EXECUTIONS, TEACHERS, RecordingSettings


def _parse_choice(args: list[str], name: str, base):
    """``--<name>.type=<type> --<name>.<field>=<value>`` flags as a ``base`` (a draccus ChoiceRegistry)
    config; ``None`` without flags."""
    from dataclasses import make_dataclass

    import draccus

    import lerobot_dcdp.sim  # noqa: F401  (registers pusht_perturbed, pusht_sim and the PushT teleoperators)

    if not args:
        return None
    if not any(x.startswith(f"--{name}.type=") for x in args):
        known = ", ".join(sorted(base.get_known_choices()))
        raise ValueError(f"--{name}.* flags need --{name}.type=<one of: {known}>")
    args_class = make_dataclass(f"{name.title()}Args", [(name, base)])
    try:
        return getattr(draccus.parse(config_class=args_class, args=args), name)
    except (draccus.utils.ParsingError, SystemExit, ValueError) as err:
        cause = err.__cause__ or err
        raise ValueError(f"bad --{name}.* flags ({' '.join(args)}): {cause}") from err


def parse_teleop_args(args: list[str]):
    """LeRobot's ``--teleop.type=<type> --teleop.<field>=<value>`` flags as a ``TeleoperatorConfig`` (``None``
    when there are none); any other leftover flag is an error naming it."""
    from lerobot.teleoperators.config import TeleoperatorConfig

    unknown = [x for x in args if not x.startswith("--teleop.")]
    if unknown:
        raise ValueError(f"unrecognized arguments: {' '.join(unknown)}")
    return _parse_choice(args, "teleop", TeleoperatorConfig)


def parse_env_args(args: list[str]):
    """LeRobot's ``--env.type=<type> --env.<field>=<value>`` flags as an ``EnvConfig`` (``None``: none)."""
    from lerobot.envs.configs import EnvConfig

    return _parse_choice([x for x in args if x.startswith("--env.")], "env", EnvConfig)


def build_parser() -> argparse.ArgumentParser:
    """The parser of the command's own flags (LeRobot's ``--env.*`` / ``--teleop.*`` flags are left over)."""
    p = argparse.ArgumentParser(prog="dcdp-record-corrections", description=__doc__.splitlines()[0])
    p.add_argument("--root", required=True, help="output directory of the dataset")
    p.add_argument(
        "--repo-id", default="local/pusht_corrections", help="repo id the dataset is written under"
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--policy", help="a trained DCDP corrector (its base plans the chunks)")
    src.add_argument("--base", help="a bare chunking base policy (pretrained_model dir)")
    p.add_argument("--execution", default="object_anchored", choices=EXECUTIONS, help="who drives the env")
    p.add_argument("--teacher", default="object_anchored", choices=TEACHERS, help="who labels each step")
    p.add_argument(
        "--ramp",
        type=float,
        default=0.0,
        help="anchored_when_drifting: full correction from this drift magnitude on, linear below (0: any)",
    )
    p.add_argument(
        "--lookahead", type=int, default=0, help="hindsight: block pose taken this many steps later"
    )
    p.add_argument("--episodes", type=int, default=200, help="episodes to record")
    p.add_argument("--seed", type=int, default=0, help="first episode seed (episodes must stay below 100000)")
    p.add_argument("--max-magnitude", type=float, default=2.5, help="drift magnitude ~ U[0, this] px/step")
    p.add_argument("--static-fraction", type=float, default=0.1, help="share of episodes without drift")
    p.add_argument("--batch-size", type=int, default=50, help="envs rolled out together")
    p.add_argument("--max-steps", type=int, default=300, help="step limit of an episode")
    p.add_argument(
        "--max-delay",
        type=int,
        default=0,
        help="late chunks: episode k's base answers k mod (D + 1) steps late (train with "
        "--policy.train_max_delay >= D; record with --execution open_loop, docs/METHOD.md)",
    )
    p.add_argument("--force", action="store_true", help="overwrite an earlier output at --root")
    p.add_argument(
        "--teacher-policy",
        default=None,
        help="teacher=policy: a pretrained_model folder of any LeRobot policy",
    )
    p.add_argument(
        "--anchor-feature",
        default="observation.environment_state",
        help="observation key of the object's xy keypoints (the anchoring teachers)",
    )
    p.epilog = (
        "LeRobot's env flags pick the env: --env.type=<type> --env.<field>=<value> (default pusht_perturbed "
        "with keypoint observations and a drift drawn per episode). teacher=teleop takes LeRobot's "
        "teleoperator flags: --teleop.type=<type> (e.g. pusht_expert) and --teleop.<field>=<value>"
    )
    return p


def _settings(a: argparse.Namespace, env_config, teleop_config) -> RecordingSettings:
    """The recording the parsed flags ask for."""
    return RecordingSettings(
        root=a.root,
        repo_id=a.repo_id,
        policy_path=a.policy,
        base_path=a.base,
        episodes=a.episodes,
        seed=a.seed,
        execution=a.execution,
        teacher=a.teacher,
        lookahead=a.lookahead,
        max_magnitude=a.max_magnitude,
        static_fraction=a.static_fraction,
        batch_size=a.batch_size,
        max_steps=a.max_steps,
        force=a.force,
        ramp=a.ramp,
        teleop_config=teleop_config,
        teacher_policy=a.teacher_policy,
        env_config=env_config,
        anchor_feature=a.anchor_feature,
        max_delay=a.max_delay,
    )


def _report(info: dict, a: argparse.Namespace) -> str:
    """Where the dataset went, how large the corrections are, and how to train a corrector on it."""
    root = Path(info["root"]).resolve()
    base = a.base or f"<the base of {a.policy}>"
    return (
        f"wrote {info['episodes']} episodes ({info['frames']} frames) to {root} as repo id {a.repo_id}; "
        f"teacher correction mean {info['mean_correction_px']:.2f} px, "
        f"p90 {info['p90_correction_px']:.2f} px\n"
        f"train a corrector on it:\n  lerobot-train --policy.type=dcdp --policy.base_policy_path={base} "
        f"--policy.anchor_feature=observation.environment_state --dataset.repo_id={a.repo_id} "
        f"--dataset.root={root} --batch_size=128 --steps=1000 --policy.push_to_hub=false "
        + (f"--policy.train_max_delay={a.max_delay} " if a.max_delay else "")
        + "--output_dir=runs/dcdp"
    )


def main(argv: list[str] | None = None) -> None:
    p = build_parser()
    a, rest = p.parse_known_args(argv)
    torch.set_num_threads(1)
    try:
        env_config = parse_env_args(rest)
        teleop = parse_teleop_args([x for x in rest if not x.startswith("--env.")])
    except ValueError as e:
        p.error(str(e))
    try:
        info = record(_settings(a, env_config, teleop))
    except ValueError as e:
        sys.exit(f"dcdp-record-corrections: error: {e}")
    print(_report(info, a))


if __name__ == "__main__":
    main()
