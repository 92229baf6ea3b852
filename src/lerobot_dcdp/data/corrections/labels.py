"""The hindsight teachers' labels of one recorded episode (pure functions of its recorded columns).

- ``object_anchored`` (:func:`anchored_labels`): the planned action carried along with the least-squares rigid
  motion of the block keypoints since plan time (the policy's training-free ``object_anchored`` mode),
  measured ``lookahead`` steps later (hindsight: the recorded future is known, so ``lookahead > 0`` labels the
  action that anticipates where the block will be; a learned corrector must predict that from its history).
  ``anchored_when_drifting`` uses the same labels, weighted per episode by the recorder.
- ``drift_offset`` (:func:`drift_offset_labels`, privileged: it reads the offsets the env applied): ``plan_s``
  translated by the drift alone, summed from plan time to the observation ``lookahead`` steps after this one.
  The drift is a pure translation of the block (``pusht_perturbed``), so this is the exact exogenous part of
  the block's motion: the push-induced motion the plan already expects is left alone, in every episode,
  static or not.
"""

from __future__ import annotations

import numpy as np
import torch


def plan_time(steps: np.ndarray, delays: np.ndarray | None) -> np.ndarray:
    """Index of the observation each frame's chunk was planned from: t - s - d."""
    t = np.arange(len(steps))
    plan_idx = t - steps - (0 if delays is None else np.asarray(delays))
    if (plan_idx < 0).any():
        raise ValueError(
            "a frame's chunk starts before the episode (plan_step + delay larger than its index)"
        )
    return plan_idx


def anchored_labels(
    plans: np.ndarray,
    steps: np.ndarray,
    keypoints: np.ndarray,
    lookahead: int,
    delays: np.ndarray | None = None,
) -> np.ndarray:
    """Teacher actions of one episode: ``plan_s`` moved with the block's rigid motion from plan time to
    ``t + lookahead`` (clamped to the episode's last observation).

    Args:
        plans: (T, H, A) raw chunk as planned, per frame; steps: (T,) s of each frame.
        keypoints: (T + 1, N, 2) raw keypoints of every observation, the one after the last step included.
        lookahead: steps ahead of t at which the block pose is taken (0: the current observation).
        delays: (T,) each frame's chunk delay d (plan time t-s-d); None: 0.
    """
    from lerobot_dcdp.model.correction import anchor_actions, rigid_fit_2d

    t_len = len(steps)
    t = np.arange(t_len)
    plan_idx = plan_time(steps, delays)
    target = np.minimum(t + lookahead, len(keypoints) - 1)
    kp = torch.as_tensor(keypoints, dtype=torch.float64)
    rot, tr = rigid_fit_2d(kp[plan_idx], kp[target])
    plan_s = torch.as_tensor(plans[t, steps], dtype=torch.float64)
    return anchor_actions(plan_s, rot, tr).numpy().astype(np.float32)


def drift_offset_labels(
    plans: np.ndarray,
    steps: np.ndarray,
    offsets: np.ndarray,
    lookahead: int,
    delays: np.ndarray | None = None,
) -> np.ndarray:
    """Teacher actions of one episode: ``plan_s`` translated by the drift the env applied between the plan's
    observation and observation ``t + lookahead`` (clamped to the episode's last observation).

    Args:
        plans: (T, H, A) raw chunk as planned, per frame; steps: (T,) s of each frame.
        offsets: (T, 2) block translation the env applied in each step (``info["perturbation_offset"]``);
            observation t has seen the offsets of steps 0..t-1.
        lookahead: observations ahead of t whose drift is included (0: what observation t has seen).
        delays: (T,) each frame's chunk delay d (plan time t-s-d); None: 0.
    """
    t_len = len(steps)
    t = np.arange(t_len)
    plan_idx = plan_time(steps, delays)
    if offsets.shape != (t_len, 2):
        raise ValueError(f"offsets must be ({t_len}, 2), one per step, got {offsets.shape}")
    seen = np.concatenate([np.zeros((1, 2)), np.cumsum(offsets, axis=0)])  # drift seen by obs 0..T
    target = np.minimum(t + lookahead, t_len)
    return (plans[t, steps] + seen[target] - seen[plan_idx]).astype(np.float32)
