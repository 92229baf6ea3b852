"""Every validation error names the bad field."""

from __future__ import annotations

import json

import pytest
from helpers import make_dcdp_config, make_dcdp_policy

from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig


def test_missing_base_is_refused() -> None:
    with pytest.raises(ValueError, match="base_policy_path"):
        DCDPConfig(device="cpu")


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("n_history", 1),
        ("execution", "sometimes"),
        ("n_action_steps", 0),
        ("te_weight", 0.0),
        ("backbone", "vit"),
        ("kl_weight", -1.0),
        ("motion_label", "pushed"),
        ("motion_full_carry_at", 0.0),
        ("motion_min_carry_speed", -1.0),
        ("completion_radius", 0.0),
        ("planner_cpus", []),
        ("planner_cpus", [1, 1]),
        ("planner_cpus", [-1]),
        ("planner_cpus", [1]),  # needs planning='async'
        ("planner_priority", "low"),
        ("planner_priority", "idle"),  # needs planning='async'
        ("ticks_per_step", 0),
        ("base_location", "remote"),  # needs planning='async'
        ("compiled_kernel", "yes"),
        ("change_scale", 0.0),
        ("anchor_input", True),  # needs an anchor_feature
        ("motion_max_speed", -1.0),
        ("motions_per_sample", 0),
        ("train_max_delay", -1),
        ("latent_dim", 0),
        ("n_heads", 3),  # feature_dim 128 is not divisible by 3
    ],
)
def test_bad_values_name_the_field(field: str, value) -> None:
    with pytest.raises(ValueError, match=field):
        DCDPConfig(base_policy_path="x/y", device="cpu", **{field: value})


def test_async_planning_refuses_a_mode_that_replans_every_step() -> None:
    with pytest.raises(ValueError, match="planning='async' applies to the chunk modes"):
        DCDPConfig(base_policy_path="x/y", device="cpu", planning="async", execution="closed_loop")


def test_each_check_reads_options_of_the_config() -> None:
    """The option-group checks take their options by name: every name is a DCDPConfig field."""
    import dataclasses
    import inspect

    from lerobot_dcdp.policy import config_checks

    names = {f.name for f in dataclasses.fields(DCDPConfig)}
    for check in config_checks.CHECKS:
        assert set(inspect.signature(check).parameters) <= names, check.__name__


def test_delta_indices_cover_history_and_executed_chunk() -> None:
    cfg = DCDPConfig(base_policy_path="x/y", device="cpu", n_history=5, n_action_steps=8)
    assert cfg.correction == "residual"  # the recipe that helps is the default
    # residual: one control step t, the history t-7 .. t (plan time t-s for s < 8) and the actions around it
    assert cfg.observation_delta_indices == list(range(-7, 1))
    assert cfg.action_delta_indices == list(range(-7, 8))
    paper = DCDPConfig(base_policy_path="x/y", device="cpu", correction="reconstruct")
    assert paper.observation_delta_indices == list(range(-4, 8))
    assert paper.action_delta_indices == list(range(8))
    opt = cfg.get_optimizer_preset()
    assert (opt.lr, opt.weight_decay, opt.grad_clip_norm) == (1e-3, 1e-4, 1.0)


def test_horizon_longer_than_base_chunk(diffusion_base, demo_root) -> None:
    with pytest.raises(ValueError, match="n_action_steps=9 exceeds the base's chunk") as err:
        make_dcdp_policy(diffusion_base, demo_root, n_action_steps=9)
    assert "--policy.n_action_steps between 1 and 8" in str(err.value)


def test_execution_typo_suggests_the_closest_mode() -> None:
    with pytest.raises(ValueError, match="did you mean 'closed_loop'"):
        DCDPConfig(base_policy_path="x/y", device="cpu", execution="closed-loop")
    with pytest.raises(ValueError, match="did you mean 'residual'"):
        DCDPConfig(base_policy_path="x/y", device="cpu", correction="residul")


def test_unknown_base_path(demo_root, tmp_path) -> None:
    with pytest.raises(ValueError, match="base_policy_path"):
        make_dcdp_policy(tmp_path / "nowhere" / "deep" / "x", demo_root)


def test_a_relative_base_missing_here_names_the_folder_and_the_fix(demo_root, tmp_path, monkeypatch) -> None:
    """``models/x`` looks like a Hub id: offline, the error names where it looked and what to pass."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(ValueError, match="is not a local pretrained_model directory") as err:
        make_dcdp_policy("models/pusht-diffusion-state", demo_root)
    msg = str(err.value)
    assert (
        str((tmp_path / "models" / "pusht-diffusion-state").resolve()) in msg
        and "Fix: pass the base's absolute path" in msg
    )


def test_feature_mismatch_names_the_feature(diffusion_base, demo_root) -> None:
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    cfg = make_dcdp_config(diffusion_base, demo_root)
    cfg.input_features["observation.environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(10,))
    with pytest.raises(ValueError, match="observation.environment_state"):
        DCDPPolicy(cfg)
    cfg = make_dcdp_config(diffusion_base, demo_root)
    del cfg.input_features["observation.environment_state"]
    with pytest.raises(ValueError, match="observation.environment_state") as err:
        DCDPPolicy(cfg)
    assert "Fix: train on a dataset that records 'observation.environment_state'" in str(err.value)
    cfg = make_dcdp_config(diffusion_base, demo_root)
    cfg.output_features["action"] = PolicyFeature(type=FeatureType.ACTION, shape=(3,))
    with pytest.raises(ValueError, match="action"):
        DCDPPolicy(cfg)


def test_changed_base_weights_are_refused(diffusion_base, demo_root) -> None:
    from lerobot_dcdp.policy.modeling_dcdp import BaseMismatchError

    cfg = make_dcdp_config(diffusion_base, demo_root, base_weights_sha256="0" * 64)
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy

    with pytest.raises(BaseMismatchError, match="base_weights_sha256 mismatch"):
        DCDPPolicy(cfg)


def test_a_column_nothing_reads_is_not_asked_of_the_env(diffusion_base, demo_root) -> None:
    """A dataset column outside the base's, the corrector's and the anchoring's inputs (e.g. recorded
    keypoints that a keypoint reader's estimate stands in for) leaves the policy's features, its split and
    its check."""
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    extra = {
        "observation.kp_recorded": PolicyFeature(type=FeatureType.ENV, shape=(16,)),
        "observation.dcdp_plan_step": PolicyFeature(type=FeatureType.STATE, shape=(1,)),
    }
    observed = ["observation.state", "observation.environment_state"]
    cfg = make_dcdp_config(diffusion_base, demo_root, observation_features=observed)
    cfg.input_features = {**cfg.input_features, **extra}
    DCDPPolicy(cfg)
    assert sorted(cfg.input_features) == sorted(observed)
    pre, _ = make_dcdp_pre_post_processors(cfg)
    names = [type(s).__name__ for s in pre.steps]
    assert "SplitStateProcessorStep" in names and "CheckObservationProcessorStep" in names
    assert "observation.kp_recorded" not in json.dumps([s.get_config() for s in pre.steps], default=str)
    # with every observation read (no observation_features), the extra column is a corrector input
    cfg = make_dcdp_config(diffusion_base, demo_root)
    cfg.input_features = {**cfg.input_features, **extra}
    DCDPPolicy(cfg)
    assert "observation.kp_recorded" in cfg.input_features
    assert "observation.dcdp_plan_step" not in cfg.input_features
