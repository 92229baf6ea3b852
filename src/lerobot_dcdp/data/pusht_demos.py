"""``dcdp-pusht-demos``: record scripted-expert PushT demonstrations as a LeRobotDataset v3.

Every episode seed ``s`` gives one env reset and one expert run (the expert's RNG is seeded with ``s`` too),
so the dataset is a pure function of ``--seed`` and ``--episodes``. Only successful episodes are kept;
seeds are tried in order ``seed, seed+1, ...`` until ``--episodes`` successes. Demo seeds must stay below
the evaluation seeds of the protocol (100000 and up).

The dataset is written into a temporary sibling directory and moved into place only when complete.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_dcdp.data.atomic_dataset import staged_dir

EVAL_SEED_START = 100_000
FPS = 10
TASK = "Push the T-shaped block onto the T-shaped target."
IMAGE_SIZE = 96
MARKER = ".dcdp_pusht_demos"
IMAGE_STORAGES = ("video", "image")


@dataclass
class Episode:
    """One recorded expert episode (``T`` frames; ``success=False`` ones are not kept)."""

    seed: int
    success: bool
    state: np.ndarray  # (T, 2) agent position
    env_state: np.ndarray  # (T, 16) keypoints
    action: np.ndarray  # (T, 2)
    reward: np.ndarray  # (T,)
    success_flags: np.ndarray  # (T,)
    images: np.ndarray | None  # (T, 96, 96, 3) uint8


def features(images: bool, keypoints: bool = True, image_storage: str = "video") -> dict:
    """LeRobotDataset feature spec of the demonstrations (``keypoints=False`` drops environment_state).

    ``image_storage`` is ``"video"`` (mp4, small on disk, decoded per sample) or ``"image"`` (PNG frames in
    the parquet files: larger, but several times faster to load on a CPU box; see docs/FINDINGS.md).
    """
    if image_storage not in IMAGE_STORAGES:
        raise ValueError(f"image_storage must be one of {IMAGE_STORAGES}, got {image_storage!r}")
    feats = {
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "observation.environment_state": {
            "dtype": "float32",
            "shape": (16,),
            "names": [f"kp{i // 2}_{'xy'[i % 2]}" for i in range(16)],
        },
        "action": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }
    if not keypoints:
        del feats["observation.environment_state"]
    if images:
        feats["observation.image"] = {
            "dtype": image_storage,
            "shape": (IMAGE_SIZE, IMAGE_SIZE, 3),
            "names": ["height", "width", "channels"],
        }
    return feats


def _lead_in(env, obs: dict, lead: Callable[[dict], np.ndarray], lead_steps: int) -> np.ndarray | None:
    """Let ``lead`` drive ``env`` for ``lead_steps`` unrecorded steps (``obs`` is updated in place); returns
    its last command, or ``None`` when it solved the task (nothing left to demonstrate)."""
    if hasattr(lead, "reset"):
        lead.reset()
    prev = np.array(env.unwrapped.agent.position, dtype=float)
    for _ in range(lead_steps):
        prev = np.asarray(lead(obs), dtype=float)
        new_obs, _, _, _, info = env.step(prev)
        obs.update(new_obs)
        if info["is_success"]:
            return None
    return prev


def _record_expert(
    env, obs: dict, expert, prev: np.ndarray, images: bool, hold_steps: int, max_steps: int
) -> tuple[bool, dict[str, list]]:
    """Run ``expert`` from the env's current state for up to ``max_steps`` recorded steps, then ``hold_steps``
    still frames after a success (trailing ones that left the success state dropped); returns whether it
    succeeded and the recorded columns (``obs`` is updated in place)."""
    u = env.unwrapped
    cols: dict[str, list] = {k: [] for k in ("state", "env_state", "action", "reward", "success", "image")}

    def step(a) -> bool:
        cols["state"].append(obs["agent_pos"].astype(np.float32))
        cols["env_state"].append(obs["environment_state"].astype(np.float32))
        cols["action"].append(np.asarray(a, dtype=np.float32))
        if images:
            cols["image"].append(u._render(visualize=False))
        new_obs, r, _, _, info = env.step(np.asarray(a, dtype=np.float64))
        cols["reward"].append(np.float32(r))
        cols["success"].append(bool(info["is_success"]))
        obs.update(new_obs)
        return bool(info["is_success"])

    success = False
    while len(cols["action"]) < max_steps and not success:
        for a in expert.next_actions(env, prev):
            prev = np.asarray(a, dtype=float)
            if step(a):
                success = True
                break
            if len(cols["action"]) >= max_steps:
                break
    if success:
        # hold: the agent's target is where the agent is, every step (not its last push target)
        for _ in range(hold_steps):
            step(np.asarray(u.agent.position, dtype=float))
        # the episode ends in the success state: drop trailing hold frames whose step left it
        last = max(i for i, ok in enumerate(cols["success"]) if ok)
        for k in cols:
            del cols[k][last + 1 :]
    return success, cols


def run_episode(
    seed: int,
    images: bool = False,
    hold_steps: int = 3,
    max_steps: int = 300,
    expert_config=None,
    lead: Callable[[dict], np.ndarray] | None = None,
    lead_steps: int = 0,
) -> Episode:
    """One expert episode from env seed ``seed``; ``hold_steps`` still frames are recorded after success.

    With ``lead`` (e.g. a :class:`~lerobot_dcdp.data.takeover.PolicyLead`), ``lead`` drives the first
    ``lead_steps`` steps unrecorded and the expert takes over from the state it left; only the expert's part
    is recorded. An episode the lead solves itself comes back with ``success=False`` and no frames.
    """
    import gym_pusht  # noqa: F401
    import gymnasium as gym

    from lerobot_dcdp.sim.pusht_expert import ScriptedExpert

    env = gym.make(
        "gym_pusht/PushT-v0",
        obs_type="environment_state_agent_pos",
        max_episode_steps=(lead_steps if lead is not None else 0) + max_steps + hold_steps + 1,
        disable_env_checker=True,
    )
    expert = ScriptedExpert(expert_config, seed=seed)
    obs, _ = env.reset(seed=seed)
    try:
        prev = np.array(env.unwrapped.agent.position, dtype=float)
        if lead is not None:
            prev = _lead_in(env, obs, lead, lead_steps)
            if prev is None:  # the lead solved it: nothing left to demonstrate
                return Episode(
                    seed,
                    False,
                    *(np.zeros((0, n), np.float32) for n in (2, 16, 2)),
                    np.zeros(0, np.float32),
                    np.zeros(0, bool),
                    None,
                )
        success, cols = _record_expert(env, obs, expert, prev, images, hold_steps, max_steps)
    finally:
        env.close()
    return Episode(
        seed=seed,
        success=success,
        state=np.stack(cols["state"]),
        env_state=np.stack(cols["env_state"]),
        action=np.stack(cols["action"]),
        reward=np.asarray(cols["reward"], dtype=np.float32),
        success_flags=np.asarray(cols["success"], dtype=bool),
        images=np.stack(cols["image"]) if images else None,
    )


_LEADS: dict = {}  # per worker process: takeover policy path -> PolicyLead


def _worker(args: tuple[int, bool, int, int, tuple[str, int, int] | None]) -> Episode:
    seed, images, hold_steps, max_steps, takeover = args
    if takeover is None:
        return run_episode(seed, images, hold_steps, max_steps)
    from lerobot_dcdp.data.takeover import PolicyLead, lead_steps_for

    path, low, high = takeover
    if path not in _LEADS:
        if mp.current_process().name != "MainProcess":  # one thread per pool worker: they share the cores
            import torch

            torch.set_num_threads(1)
        _LEADS[path] = PolicyLead(path)
    return run_episode(
        seed, images, hold_steps, max_steps, lead=_LEADS[path], lead_steps=lead_steps_for(seed, low, high)
    )


def _check_arguments(
    root: Path,
    episodes: int,
    seed: int,
    images: bool,
    keypoints: bool,
    force: bool,
    takeover: tuple[str, int, int] | None,
) -> int:
    """Check :func:`record_demonstrations`' arguments (loading a takeover policy once, so a bad one fails
    before anything is written); returns how many seeds may be tried.

    Raises:
        ValueError: naming the bad argument.
    """
    if not keypoints and not images:
        raise ValueError(
            "keypoints=False needs images=True: the dataset would hold no observation of the block"
        )
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if takeover is not None:
        from lerobot_dcdp.data.takeover import PolicyLead

        path, low, high = takeover
        if not 0 <= low <= high:
            raise ValueError(f"takeover steps must satisfy 0 <= low <= high, got low={low} high={high}")
        if images:
            raise ValueError("takeover episodes are state-only; leave out images=True")
        # a bad path or a policy reading other inputs fails here, before anything is written; the loaded lead
        # is reused when the episodes run in this process (workers=1)
        _LEADS[path] = PolicyLead(path)
    max_tries = 2 * episodes + 10
    if seed + max_tries > EVAL_SEED_START:
        raise ValueError(
            f"seed={seed}: demonstration seeds {seed}..{seed + max_tries} would reach the evaluation seeds "
            f"(>= {EVAL_SEED_START}); pick a smaller --seed"
        )
    if root.exists() and any(root.iterdir()):
        if not (root / MARKER).is_file():
            raise ValueError(
                f"root={root} exists and is not an output of dcdp-pusht-demos (no {MARKER}); refusing to "
                "touch it: pick another --root"
            )
        if not force:
            raise ValueError(f"root={root} already exists; pass --force to overwrite it")
    return max_tries


def _add_episode(ds, ep: Episode, keypoints: bool, images: bool) -> None:
    """Add ``ep``'s frames to the dataset ``ds`` (``next.done`` on its last) and save the episode."""
    for t in range(len(ep.action)):
        frame = {
            "observation.state": ep.state[t],
            "action": ep.action[t],
            "next.reward": ep.reward[t : t + 1],
            "next.success": ep.success_flags[t : t + 1],
            "next.done": np.array([t == len(ep.action) - 1]),
            "task": TASK,
        }
        if keypoints:
            frame["observation.environment_state"] = ep.env_state[t]
        if images:
            frame["observation.image"] = ep.images[t]
        ds.add_frame(frame)
    ds.save_episode()


def record_demonstrations(
    root: str | Path,
    repo_id: str = "local/pusht_expert",
    episodes: int = 200,
    seed: int = 0,
    images: bool = False,
    workers: int = 1,
    hold_steps: int = 3,
    max_steps: int = 300,
    force: bool = False,
    progress: bool = True,
    keypoints: bool = True,
    takeover: tuple[str, int, int] | None = None,
    image_storage: str = "video",
) -> dict:
    """Write ``episodes`` successful expert episodes to a LeRobotDataset v3 at ``root``.

    ``takeover=(policy_path, low, high)`` records takeover episodes instead: the pretrained state-based policy
    at ``policy_path`` drives each episode for ``low..high`` steps (seeded per episode, unrecorded), then the
    expert takes over and is recorded to success (see :mod:`lerobot_dcdp.data.takeover`). Episodes the policy
    solves on its own are skipped. ``image_storage`` is how ``images`` are stored (:func:`features`).

    Returns:
        Summary dict: kept/tried episodes, frames, seeds used.

    Raises:
        ValueError: bad arguments, demo seeds reaching the evaluation seeds, or an existing ``root``
            without ``force``.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from tqdm import tqdm

    root = Path(root)
    max_tries = _check_arguments(root, episodes, seed, images, keypoints, force, takeover)
    with staged_dir(root) as tmp_root:
        ds = LeRobotDataset.create(
            repo_id=repo_id,
            fps=FPS,
            features=features(images, keypoints, image_storage),
            root=tmp_root,
            robot_type="pusht",
            use_videos=True,
        )
        kept, tried, frames, seeds = 0, 0, 0, []
        ctx = mp.get_context("spawn")
        pool = ctx.Pool(workers) if workers > 1 else None
        bar = tqdm(total=episodes, desc="expert episodes", disable=not progress)
        try:
            args = ((s, images, hold_steps, max_steps, takeover) for s in range(seed, seed + max_tries))
            for ep in pool.imap(_worker, args) if pool else map(_worker, args):
                tried += 1
                if not ep.success:
                    continue
                _add_episode(ds, ep, keypoints, images)
                kept, frames = kept + 1, frames + len(ep.action)
                seeds.append(ep.seed)
                bar.update(1)
                if kept == episodes:
                    break
        finally:
            bar.close()
            if pool:
                pool.terminate()
        ds.finalize()
        if kept < episodes:
            raise ValueError(f"only {kept} of {tried} expert episodes succeeded; wanted {episodes}")
        lead = "" if takeover is None else f" takeover={takeover[0]} steps={takeover[1]}..{takeover[2]}"
        (tmp_root / MARKER).write_text(f"episodes={kept} seed={seed}{lead}\n")
    return {"episodes": kept, "tried": tried, "frames": frames, "seeds": seeds, "root": str(root)}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="dcdp-pusht-demos", description=__doc__.splitlines()[0])
    p.add_argument("--root", required=True, help="output directory of the dataset")
    p.add_argument(
        "--repo-id", default="local/pusht_expert", help="the dataset's repo id (default: %(default)s)"
    )
    p.add_argument("--episodes", type=int, default=200, help="successful episodes to keep")
    p.add_argument("--images", action="store_true", help="also record a 96x96 observation.image video")
    p.add_argument(
        "--image-storage",
        choices=IMAGE_STORAGES,
        default="video",
        help="how --images frames are stored: mp4 video (default: small, and faster to load on an idle box; "
        "docs/FINDINGS.md) or PNG frames",
    )
    p.add_argument(
        "--no-keypoints",
        action="store_true",
        help="leave out observation.environment_state (an image-only dataset)",
    )
    p.add_argument("--seed", type=int, default=0, help="first env seed (must stay below 100000)")
    p.add_argument(
        "--workers", type=int, default=2, help="processes running episodes in parallel (default: %(default)s)"
    )
    p.add_argument("--hold-steps", type=int, default=3, help="still frames recorded after success")
    p.add_argument("--force", action="store_true", help="overwrite an existing --root")
    p.add_argument(
        "--takeover-policy",
        help="pretrained_model dir of a state-based policy that drives each episode first; the expert takes "
        "over and only its part is recorded (DAgger-style recovery data)",
    )
    p.add_argument(
        "--takeover-steps",
        type=int,
        nargs=2,
        default=(8, 160),
        metavar=("LOW", "HIGH"),
        help="the policy drives LOW..HIGH steps (seeded per episode) before the expert takes over",
    )
    a = p.parse_args(argv)
    try:
        info = record_demonstrations(
            a.root,
            a.repo_id,
            a.episodes,
            a.seed,
            a.images,
            a.workers,
            a.hold_steps,
            force=a.force,
            keypoints=not a.no_keypoints,
            takeover=None if a.takeover_policy is None else (a.takeover_policy, *a.takeover_steps),
            image_storage=a.image_storage,
        )
    except ValueError as e:
        sys.exit(f"dcdp-pusht-demos: error: {e}")
    print(
        f"wrote {info['episodes']} episodes ({info['frames']} frames, {info['tried']} tried) "
        f"to {info['root']}"
    )


if __name__ == "__main__":
    main()
