"""``dcdp_split_state``: a robot's flattened ``observation.state`` cut back into the policy's inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import env_observations
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import PolicyProcessorPipeline, ProcessorStepRegistry
from lerobot.processor.converters import batch_to_transition, transition_to_batch

import lerobot_policy_dcdp  # noqa: F401  (registers the step, as LeRobot's plugin discovery does)
from lerobot_dcdp.policy.processor_split_state import SplitStateProcessorStep

ROOT = Path(__file__).resolve().parents[1]
CORRECTORS = [ROOT / "models" / m for m in ("pusht-dcdp-state", "pusht-dcdp-state-paper-recipe")]
CORRECTORS.append(ROOT / "models" / "pusht-dcdp-act-state")
STATE, ENV = "observation.state", "observation.environment_state"
FEATURES = {
    STATE: PolicyFeature(type=FeatureType.STATE, shape=(2,)),
    ENV: PolicyFeature(type=FeatureType.ENV, shape=(16,)),
}


def step() -> SplitStateProcessorStep:
    return SplitStateProcessorStep(splits=[(STATE, 2), (ENV, 16)])


def pipeline(*steps) -> PolicyProcessorPipeline:
    return PolicyProcessorPipeline(
        steps=list(steps),
        name="policy_preprocessor",
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )


def test_registered_under_its_name() -> None:
    assert ProcessorStepRegistry.get("dcdp_split_state") is SplitStateProcessorStep


@pytest.mark.parametrize("lead", [(), (1,), (4, 2)], ids=["unbatched", "batch", "batch-time"])
def test_splits_a_flattened_state(lead: tuple[int, ...]) -> None:
    flat = torch.arange(np.prod(lead, dtype=int) * 18, dtype=torch.float32).reshape(*lead, 18)
    out = pipeline(step())({STATE: flat, "task": "push"})
    assert {k for k in out if k.startswith("observation.")} == {STATE, ENV} and out["task"] == "push"
    assert torch.equal(out[STATE], flat[..., :2]) and torch.equal(out[ENV], flat[..., 2:])
    # numpy arrays too (the step runs before LeRobot's tensor conversion in some callers)
    arr = flat.numpy()
    got = step().observation({STATE: arr})
    assert np.array_equal(got[STATE], arr[..., :2]) and np.array_equal(got[ENV], arr[..., 2:])


def test_already_split_is_a_no_op() -> None:
    obs = env_observations(2, 1)[0]
    out = pipeline(step())(dict(obs))
    assert {k for k in out if k.startswith("observation.")} == obs.keys()
    assert all(out[k] is obs[k] for k in obs)  # the very same tensors: bit-identical


def test_wrong_size_is_one_clear_error() -> None:
    with pytest.raises(ValueError, match=r"has 17 values .* observation.state \(2\) \+ .*\(16\) = 18"):
        step().observation({STATE: torch.zeros(1, 17)})
    # keys separate, but the state is too wide: no silent pass to the normaliser
    with pytest.raises(ValueError, match=r"has 18 values .* given separately it must hold 2"):
        step().observation({STATE: torch.zeros(1, 18), ENV: torch.zeros(1, 16)})
    with pytest.raises(ValueError, match="splits must start with observation.state"):
        SplitStateProcessorStep(splits=[(ENV, 16), (STATE, 2)])


def test_an_env_without_the_keypoints_names_the_obs_type_to_use() -> None:
    """A state corrector run in an env that reports pixels + agent position only (PushT pixels_agent_pos)."""
    with pytest.raises(ValueError, match=r"does not report observation.environment_state") as err:
        step().observation({STATE: torch.zeros(1, 2)})
    assert "--env.obs_type=environment_state_agent_pos" in str(err.value)


def test_without_state_passes_through() -> None:
    obs = {"observation.image": torch.zeros(1, 3, 4, 4)}
    assert step().observation(dict(obs)).keys() == obs.keys()


def test_from_features() -> None:
    # state first, then the other 1-D STATE/ENV inputs in the policy's order; images are not vectors
    feats = {
        ENV: FEATURES[ENV],
        "observation.image": PolicyFeature(type=FeatureType.VISUAL, shape=(3, 96, 96)),
        STATE: FEATURES[STATE],
    }
    assert SplitStateProcessorStep.from_features(feats).splits == [(STATE, 2), (ENV, 16)]
    assert SplitStateProcessorStep.from_features({STATE: FEATURES[STATE]}) is None  # nothing to split into
    assert SplitStateProcessorStep.from_features({ENV: FEATURES[ENV]}) is None


def test_transform_features() -> None:
    flat = {PipelineFeatureType.OBSERVATION: {STATE: PolicyFeature(type=FeatureType.STATE, shape=(18,))}}
    out = step().transform_features(flat)[PipelineFeatureType.OBSERVATION]
    assert out == FEATURES
    split = {PipelineFeatureType.OBSERVATION: dict(FEATURES)}
    assert step().transform_features(split) == split


def test_survives_save_and_load(tmp_path: Path) -> None:
    pipe = pipeline(step())
    pipe.save_pretrained(tmp_path)
    saved = json.loads((tmp_path / "policy_preprocessor.json").read_text())
    assert saved["steps"] == [
        {"registry_name": "dcdp_split_state", "config": {"splits": [[STATE, 2], [ENV, 16]]}}
    ]
    loaded = PolicyProcessorPipeline.from_pretrained(
        tmp_path, "policy_preprocessor.json", to_transition=batch_to_transition, to_output=transition_to_batch
    )
    assert len(loaded.steps) == 1 and loaded.steps[0].splits == step().splits
    flat = torch.randn(3, 18)
    a, b = pipe({STATE: flat}), loaded({STATE: flat})
    assert all(torch.equal(a[k], b[k]) for k in (STATE, ENV))


@pytest.mark.parametrize("corrector", CORRECTORS, ids=lambda p: p.name)
def test_shipped_and_factory_pre_processors_start_with_the_step(corrector: Path) -> None:
    """What ``lerobot-rollout --policy.path=<corrector>`` loads, and what the factory builds for it (the
    processors ``lerobot-train`` saves), both split the 18-wide robot state into exactly the same
    normalised inputs as the separate keys give."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    cfg = PreTrainedConfig.from_pretrained(corrector)
    cfg.pretrained_path = corrector
    shipped, _ = make_pre_post_processors(cfg, pretrained_path=str(corrector))
    built, _ = make_dcdp_pre_post_processors(cfg)
    obs = env_observations(1, 3)
    for pre in (shipped, built):
        assert isinstance(pre.steps[0], SplitStateProcessorStep) and pre.steps[0].splits == step().splits
        assert sum(isinstance(s, SplitStateProcessorStep) for s in pre.steps) == 1
        for o in obs:
            split = pre(dict(o))
            flat = pre({STATE: torch.cat([o[STATE], o[ENV]], dim=-1)})
            assert all(torch.equal(split[k], flat[k]) for k in (STATE, ENV))
    assert shipped.get_config() == built.get_config()
