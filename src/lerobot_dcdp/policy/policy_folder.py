"""How a DCDP corrector lives in a folder and on the Hub: its base checked on load, recorded relative to the
folder it is saved into, pushed without the base, and its model card and weights hash.

``CorrectorFolder`` is a mixin of ``DCDPPolicy`` (``modeling_dcdp.py``), ahead of LeRobot's
``PreTrainedPolicy`` whose loading and saving it wraps.
"""

from __future__ import annotations

import os
from pathlib import Path

from lerobot.policies.pretrained import PreTrainedPolicy

from lerobot_dcdp.model.correction import state_dict_sha256
from lerobot_dcdp.policy.base_policy import portable_base_reference, resolve_base_reference
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig


class BaseMismatchError(ValueError):
    """The base policy found at load time is not the one the corrector was trained against."""


class CorrectorFolder:
    """Loading, saving and pushing a corrector whose frozen base is referenced, not stored."""

    def _adopt_base(self, base: PreTrainedPolicy) -> None:
        """Check ``base`` is the one the corrector was trained against (weights hash, type); record it."""
        config = self.config
        # base_location='remote': the weights are on the server's machine, there is no hash to check here
        digest = state_dict_sha256(base.state_dict()) if config.base_location == "local" else None
        if digest is not None and config.base_weights_sha256 is None:
            config.base_weights_sha256 = digest
        elif digest is not None and config.base_weights_sha256 != digest:
            raise BaseMismatchError(
                f"base_weights_sha256 mismatch: the corrector was trained against base weights "
                f"{config.base_weights_sha256[:12]}..., but base_policy_path={config.base_policy_path!r} "
                f"now holds {digest[:12]}...; retrain stage 1 or point base_policy_path at the original base"
            )
        if config.base_policy_type not in (None, base.config.type):
            raise BaseMismatchError(
                f"base_policy_type mismatch: recorded {config.base_policy_type!r}, found {base.config.type!r}"
            )
        config.base_policy_type = base.config.type
        config.normalization_mapping = dict(base.config.normalization_mapping)

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, *, config: DCDPConfig | None = None, **kwargs):
        # a config read from the folder names its base relative to that folder, whatever pretrained_path it
        # was saved with (a corrector loaded from one folder and saved to another records the first)
        read_here = config is None
        if config is None:
            config = DCDPConfig.from_pretrained(
                pretrained_name_or_path,
                **{
                    k: v
                    for k, v in kwargs.items()
                    if k in ("revision", "cache_dir", "local_files_only", "token")
                },
            )
        if (read_here or config.pretrained_path is None) and os.path.isdir(str(pretrained_name_or_path)):
            config.pretrained_path = pretrained_name_or_path
        kwargs["strict"] = True  # a corrector key that fails to load would silently leave a head at zero
        try:
            policy = super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)
        except RuntimeError as err:
            if "Missing key" not in str(err) and "Unexpected key" not in str(err):
                raise
            raise ValueError(
                f"corrector weights in {pretrained_name_or_path} do not match config.json "
                f"({str(err).strip().splitlines()[-1].strip()}): it was saved by another dcdp version or "
                "config; retrain it or restore the matching config.json"
            ) from err
        if policy.kernel is not None:
            policy.kernel.warm_up()  # its first load (or compile) must not stall the first control step
        return policy

    def _save_pretrained(self, save_directory, *args, **kwargs) -> None:
        """Save as LeRobot does, recording a local base relative to ``save_directory``."""
        cfg = self.config
        original = cfg.base_policy_path
        cfg.base_policy_path = portable_base_reference(original, cfg.pretrained_path, save_directory)
        try:
            super()._save_pretrained(save_directory, *args, **kwargs)
        finally:
            cfg.base_policy_path = original

    def push_model_to_hub(self, cfg, *args, **kwargs):
        """Push the corrector only; its config names the base by Hub id (``hub_base_policy_path`` when the
        base is a local folder), since a folder on this machine means nothing to whoever downloads it."""
        config = self.config
        local = Path(resolve_base_reference(config.base_policy_path, config.pretrained_path)).is_dir()
        if local and not config.hub_base_policy_path:
            raise ValueError(
                "cannot push a corrector whose base is the local folder "
                f"{config.base_policy_path!r}: push the base to the Hub first and name it with "
                "--policy.hub_base_policy_path=<user/base> (its weights hash is checked on every load)"
            )
        original = config.base_policy_path
        config.base_policy_path = config.hub_base_policy_path if local else original
        try:
            return super().push_model_to_hub(cfg, *args, **kwargs)
        finally:
            config.base_policy_path = original

    def generate_model_card(self, dataset_repo_id, model_type, license, tags, cfg=None, dataset_meta=None):
        """DCDP's own card (base reference and hash, measured numbers, eval command); built offline."""
        from lerobot_dcdp.policy.model_card import make_model_card

        return make_model_card(self.config, self.corrector_sha256(), dataset_repo_id, license, tags)

    def corrector_sha256(self) -> str:
        """Content hash of the corrector's weights, named as inside the corrector (as every version saved)."""
        return state_dict_sha256(self.corrector.state_dict())
