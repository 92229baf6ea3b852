"""The recorded corrections as a LeRobotDataset v3, written atomically into a folder marked as this command's.

Per frame the dataset holds

- every vector observation the policy and its base read (raw; PushT: ``observation.state``,
  ``observation.environment_state``);
- ``observation.dcdp_plan`` (L * A,) and ``observation.dcdp_plan_step`` (1,): the chunk as the base planned
  it at the chunk start (flattened, so LeRobot's ``merge_datasets`` can aggregate DAgger rounds), and the
  step s of this frame in it;
- ``observation.dcdp_plan_delay`` (1,): the chunk's delay d, steps from the observation it was planned from
  to its first action;
- ``action``: the teacher's action for step s; ``executed_action``: what was actually sent to the env;
- ``next.reward``, ``next.success``, ``next.done``.

The folder is built beside ``root`` and replaces it only when the recording completes; the marker file
:data:`MARKER` in it lets a later run with ``force`` overwrite it (and refuse any other folder).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from lerobot_dcdp.data.atomic_dataset import staged_dir

MARKER = ".dcdp_corrections"

#: Names of PushT's vector observations (the ``pusht`` datasets'), kept when a recording holds them.
PUSHT_NAMES = {
    "observation.state": ["x", "y"],
    "observation.environment_state": [f"kp{i // 2}_{'xy'[i % 2]}" for i in range(16)],
}


def features(plan_length: int, action_dim: int = 2, observations: dict | None = None) -> dict:
    """LeRobotDataset feature spec of recorded corrections (``observations``: key -> shape of the stored
    observations as the policy reads them; default PushT's agent position and block keypoints). A camera,
    shape (C, H, W), is stored as a video of (H, W, C) frames."""
    observations = observations or {"observation.state": (2,), "observation.environment_state": (16,)}
    spec = {}
    for key, shape in observations.items():
        if len(shape) == 3:
            c, h, w = shape
            spec[key] = {"dtype": "video", "shape": (h, w, c), "names": ["height", "width", "channels"]}
            continue
        names = PUSHT_NAMES.get(key)
        spec[key] = {
            "dtype": "float32",
            "shape": tuple(shape),
            "names": names if names is not None and (len(names),) == tuple(shape) else None,
        }
    xy = ["x", "y"] if action_dim == 2 else None
    return {
        **spec,
        # flat (L * A,): LeRobot's merge_datasets cannot copy a 2-D column (the policy reshapes it)
        "observation.dcdp_plan": {"dtype": "float32", "shape": (plan_length * action_dim,), "names": None},
        "observation.dcdp_plan_step": {"dtype": "float32", "shape": (1,), "names": None},
        "observation.dcdp_plan_delay": {"dtype": "float32", "shape": (1,), "names": None},
        "action": {"dtype": "float32", "shape": (action_dim,), "names": xy},
        "executed_action": {"dtype": "float32", "shape": (action_dim,), "names": xy},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }


def check_root(root: Path, force: bool) -> None:
    """Refuse an existing, non-empty ``root`` that is not an earlier output of this command, or is one
    without ``force``.

    Raises:
        ValueError: naming ``root`` and why it is refused.
    """
    if root.exists() and any(root.iterdir()):
        if not (root / MARKER).is_file():
            raise ValueError(
                f"root={root} exists and is not an output of dcdp-record-corrections; refusing it"
            )
        if not force:
            raise ValueError(f"root={root} already exists; pass --force to overwrite it")


@contextmanager
def corrections_dataset(root: Path, repo_id: str, fps: int, spec: dict, marker: str) -> Iterator:
    """An empty LeRobotDataset (feature ``spec``) built in a staging folder; on a clean exit it is finalized,
    marked (``marker``: the text of its :data:`MARKER` file) and moved to ``root``, replacing what was there.
    On an exception ``root`` is left as it was."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with staged_dir(root) as tmp_root:
        ds = LeRobotDataset.create(
            repo_id=repo_id,
            fps=fps,
            features=spec,
            root=tmp_root,
            robot_type="pusht",
            use_videos=any(f["dtype"] == "video" for f in spec.values()),
        )
        yield ds
        ds.finalize()
        (tmp_root / MARKER).write_text(marker)


def write_episode(ds, ep: dict, task: str) -> None:
    """Append one recorded episode (a :func:`~.rollout.rollout_corrections` result) to ``ds``."""
    n = len(ep["step"])
    for t in range(n):
        ds.add_frame(
            {
                **{k: v[t] for k, v in ep["obs"].items()},
                "observation.dcdp_plan": ep["plan"][t].reshape(-1),
                "observation.dcdp_plan_step": np.array([ep["step"][t]], dtype=np.float32),
                "observation.dcdp_plan_delay": np.array([ep["delay"][t]], dtype=np.float32),
                "action": ep["label"][t],
                "executed_action": ep["exec"][t],
                "next.reward": ep["reward"][t : t + 1],
                "next.success": ep["success"][t : t + 1],
                "next.done": np.array([t == n - 1]),
                "task": task,
            }
        )
    ds.save_episode()
