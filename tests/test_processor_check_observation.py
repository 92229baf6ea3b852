"""``dcdp_check_observation``: a feature of the wrong shape is named before LeRobot's normaliser sees it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from helpers import env_observations, make_dcdp_config
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline, ProcessorStepRegistry

import lerobot_policy_dcdp  # noqa: F401  (registers the steps, as LeRobot's plugin discovery does)
from lerobot_dcdp.policy.processor_check_observation import CheckObservationProcessorStep
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors
from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep

ROOT = Path(__file__).resolve().parents[1]
DCDP_FOLDERS = sorted(
    p.parent for p in (ROOT / "models").glob("*/config.json") if json.loads(p.read_text())["type"] == "dcdp"
)
STATE, ENV = "observation.state", "observation.environment_state"
NAMED = r"observation 'observation.environment_state' has shape \(2, 15\), expected \(\.\.\., 16\)"


def narrowed(obs: dict) -> dict:
    """``obs`` with a 15-wide environment state (one keypoint coordinate dropped)."""
    return {**obs, ENV: obs[ENV][..., :15]}


def test_registered_under_its_name() -> None:
    assert ProcessorStepRegistry.get("dcdp_check_observation") is CheckObservationProcessorStep


def test_the_policy_pre_processor_names_a_feature_of_the_wrong_width(diffusion_base, demo_root) -> None:
    """The pre-processor the policy is built with: split, then the check, then the base's own steps; a
    15-wide environment state for a 16-wide policy is one ValueError naming the feature and both shapes,
    not the normaliser's ``RuntimeError: The size of tensor a (15) must match ...``."""
    config = make_dcdp_config(diffusion_base, demo_root)
    pre, _ = make_dcdp_pre_post_processors(config)
    assert [type(s) for s in pre.steps[:2]] == [SplitStateProcessorStep, CheckObservationProcessorStep]
    assert pre.steps[1].shapes == {STATE: (2,), ENV: (16,)}
    obs = env_observations(2, 1)[0]
    pre(dict(obs))  # the observation as the env gives it passes
    with pytest.raises(ValueError, match=NAMED):
        pre(narrowed(obs))


@pytest.mark.parametrize("folder", DCDP_FOLDERS, ids=lambda p: p.name)
def test_every_shipped_corrector_checks_as_lerobot_eval_loads_it(folder: Path) -> None:
    """``lerobot-eval --policy.path=<folder>`` loads the folder's own ``policy_preprocessor.json``: the check
    is its second step (after the split), declares the folder's input features, and names a bad feature;
    a robot's flattened 18-wide state still passes (it is split first)."""
    pre = PolicyProcessorPipeline.from_pretrained(folder, "policy_preprocessor.json")
    assert [type(s) for s in pre.steps[:2]] == [SplitStateProcessorStep, CheckObservationProcessorStep]
    features = json.loads((folder / "config.json").read_text())["input_features"]
    assert pre.steps[1].shapes == {k: tuple(f["shape"]) for k, f in features.items()}
    obs = env_observations(2, 1)[0]
    flat = torch.cat([obs[STATE], obs[ENV]], dim=-1)
    split, whole = pre({STATE: flat}), pre(dict(obs))
    assert all(torch.equal(split[k], whole[k]) for k in (STATE, ENV))
    with pytest.raises(ValueError, match=NAMED):
        pre(narrowed(obs))


@pytest.mark.slow
def test_a_checkpoint_lerobot_train_saved_names_a_feature_of_the_wrong_width(trained_corrector) -> None:
    """The pre-processor lerobot-eval builds from a lerobot-train checkpoint (LeRobot's factory, from the
    folder) checks before it normalises."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(trained_corrector)
    pre, _ = make_pre_post_processors(cfg, pretrained_path=str(trained_corrector))
    assert isinstance(pre.steps[1], CheckObservationProcessorStep)
    obs = env_observations(2, 1)[0]
    pre(dict(obs))
    with pytest.raises(ValueError, match=NAMED):
        pre(narrowed(obs))


@pytest.mark.parametrize("lead", [(), (2,), (2, 3)], ids=["unbatched", "batch", "batch-time"])
def test_leading_dimensions_are_free_and_values_pass_untouched(lead: tuple[int, ...]) -> None:
    step = CheckObservationProcessorStep(shapes={STATE: (2,), "observation.image": (3, 4, 4)})
    obs = {STATE: torch.randn(*lead, 2), "observation.image": torch.rand(*lead, 3, 4, 4)}
    out = step.observation(dict(obs))
    assert all(out[k] is obs[k] for k in obs)
    with pytest.raises(
        ValueError, match=r"'observation.image' has shape \(.*4, 4, 3\), expected \(\.\.\., 3, 4, 4\)"
    ):
        step.observation({**obs, "observation.image": obs["observation.image"].transpose(-1, -3)})
    with pytest.raises(ValueError, match=r"'observation.state' has shape \(3,\), expected \(\.\.\., 2\)"):
        step.observation({STATE: torch.zeros(3)})
    with pytest.raises(ValueError, match="'observation.state' is not an array"):
        step.observation({STATE: [0.0, 1.0]})


def test_missing_and_undeclared_keys_pass() -> None:
    """A key the observation lacks is left to the policy's own check (a later step may rename keys)."""
    step = CheckObservationProcessorStep(shapes={STATE: (2,), ENV: (16,)})
    obs = {STATE: torch.zeros(1, 2), "observation.other": torch.zeros(1, 5)}
    assert step.observation(dict(obs)).keys() == obs.keys()


def test_from_features_and_config_round_trip(tmp_path: Path) -> None:
    features = {
        STATE: PolicyFeature(type=FeatureType.STATE, shape=(2,)),
        ENV: PolicyFeature(type=FeatureType.ENV, shape=(16,)),
        "observation.dcdp_plan": PolicyFeature(type=FeatureType.STATE, shape=(16, 2)),
        "action": PolicyFeature(type=FeatureType.ACTION, shape=(2,)),
    }
    step = CheckObservationProcessorStep.from_features(features, skip=("observation.dcdp_plan",))
    assert step.shapes == {STATE: (2,), ENV: (16,)}
    assert CheckObservationProcessorStep.from_features({}) is None
    pipe = PolicyProcessorPipeline(steps=[step], name="policy_preprocessor")
    pipe.save_pretrained(tmp_path)
    saved = json.loads((tmp_path / "policy_preprocessor.json").read_text())["steps"]
    assert saved == [
        {"registry_name": "dcdp_check_observation", "config": {"shapes": {STATE: [2], ENV: [16]}}}
    ]
    loaded = PolicyProcessorPipeline.from_pretrained(tmp_path, "policy_preprocessor.json")
    assert loaded.steps[0].shapes == step.shapes
    with pytest.raises(ValueError, match="needs a shape of dimensions >= 1"):
        CheckObservationProcessorStep(shapes={STATE: (0,)})
