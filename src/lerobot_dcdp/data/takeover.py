"""A pretrained LeRobot policy driving PushT for the first steps of a recorded expert episode (DAgger-style
takeover data).

A chunk regressor trained on expert demonstrations drifts into states no demonstration visits and stalls
there (``scripts/diagnostics/act_stall_neighbours.py`` in git, commit 7706bc7). Recording the expert *from the
states the policy reaches* adds demonstrations of how to recover from them: the policy drives an episode for a
seeded number of steps, then the scripted expert takes over and is recorded to success. This is one round of
DAgger (Ross et al., 2011) with the expert's own continuation as the label, so the result is an ordinary
LeRobotDataset of consecutive frames that stock ``lerobot-train`` reads (merge it with the demonstrations
using ``lerobot-edit-dataset --operation.type merge``).
"""

from __future__ import annotations

import numpy as np

#: what ``gym_pusht`` (obs_type ``environment_state_agent_pos``) gives, as LeRobot features
_ENV_FEATURES = ("observation.environment_state", "observation.state")


class PolicyLead:
    """A pretrained state-based policy as a callable ``gym_pusht observation -> action``.

    Args:
        path: A ``pretrained_model`` directory (config, weights and saved processors) of any registered policy
            type whose inputs are ``observation.state`` and/or ``observation.environment_state``.

    Raises:
        ValueError: ``path`` holds no policy config, or the policy reads an input this env does not give.
    """

    def __init__(self, path: str) -> None:
        from lerobot.envs.utils import preprocess_observation
        from lerobot.policies.factory import make_pre_post_processors

        from lerobot_dcdp.policy.base_policy import load_base_policy

        self._to_batch = preprocess_observation  # imported once here, not on every control step

        try:
            self.policy = load_base_policy(path, device="cpu")
        except ValueError as e:
            raise ValueError(f"takeover policy {path!r}: {e}") from e
        unknown = sorted(set(self.policy.config.input_features) - set(_ENV_FEATURES))
        if unknown:
            raise ValueError(
                f"takeover policy {path!r} reads {unknown}; a takeover lead must read only "
                f"{list(_ENV_FEATURES)} (state-based PushT)"
            )
        self.pre, self.post = make_pre_post_processors(self.policy.config, pretrained_path=path)

    def reset(self) -> None:
        self.policy.reset()

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        import torch

        with torch.inference_mode():  # as lerobot-eval: env observation -> batch -> processors -> policy
            action = self.post(self.policy.select_action(self.pre(self._to_batch(obs))))
        return action[0].numpy().astype(np.float64)


def lead_steps_for(seed: int, low: int, high: int) -> int:
    """Steps the lead drives episode ``seed``: uniform in ``[low, high]``, a pure function of the seed."""
    return int(np.random.default_rng([seed, 7]).integers(low, high + 1))
