"""What a fresh clone ships: every model under models/ loads (from any working directory) and runs every
execution mode, and every config under configs/ parses."""

from __future__ import annotations

import json
from pathlib import Path

import draccus
import pytest
import torch
from helpers import env_observations

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted(p.parent for p in (ROOT / "models").glob("*/config.json"))
CORRECTORS = [p for p in MODELS if json.loads((p / "config.json").read_text())["type"] == "dcdp"]


def test_models_are_small_and_complete() -> None:
    total = sum(f.stat().st_size for f in (ROOT / "models").rglob("*") if f.is_file())
    assert total <= 150 * 2**20, f"models/ holds {total / 2**20:.1f} MB (limit 150 MB)"
    assert CORRECTORS, "no shipped corrector found"
    for m in MODELS:
        for name in (
            "config.json",
            "model.safetensors",
            "policy_preprocessor.json",
            "policy_postprocessor.json",
        ):
            assert (m / name).is_file(), f"{m.name} lacks {name}"


@pytest.mark.parametrize("corrector", CORRECTORS, ids=lambda p: p.name)
def test_shipped_corrector_runs_every_mode_from_another_directory(corrector, tmp_path, monkeypatch) -> None:
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    saved = json.loads((corrector / "config.json").read_text())
    stored = saved["base_policy_path"]
    assert not Path(stored).is_absolute(), "a shipped corrector names its base relative to itself"
    monkeypatch.chdir(tmp_path)  # not the repository root
    policy = DCDPPolicy.from_pretrained(corrector).eval()
    pre, post = make_dcdp_pre_post_processors(policy.config)
    obs = [pre(dict(o)) for o in env_observations(2, 10)]
    modes = ["open_loop", "closed_loop", "temporal_ensemble", "dcdp"]
    if policy.config.anchor_feature:
        modes.append("object_anchored")
    plans = {}
    for mode in modes:
        policy.config.execution = mode
        policy.reset()
        torch.manual_seed(0)
        actions = torch.stack([post(policy.select_action(dict(o))) for o in obs])
        assert actions.shape == (10, 2, 2) and torch.isfinite(actions).all(), mode
        assert (actions > -50).all() and (actions < 600).all(), f"{mode}: actions leave the PushT arena"
        plans[mode] = actions
    if saved.get("completion_gate"):  # the gated folders lead the scene by one executed chunk
        assert policy.config.lead_steps == policy.config.n_action_steps
    if corrector.name.endswith("-anchored-gated"):
        # a bare base's gated anchoring (dcdp-fit-completion-gate --base): a gate, a corrector that never
        # trained (exactly the plan) ...
        assert saved["execution"] == "object_anchored" and policy.completion_gate is not None
        torch.testing.assert_close(plans["dcdp"], plans["open_loop"])
    else:
        # ... else a corrector that changes the open-loop actions (it is not an untrained identity) ...
        assert not torch.equal(plans["dcdp"], plans["open_loop"])
    # ... and every mode starts from the same first chunk: step 0 of open loop = step 0 of closed loop
    torch.testing.assert_close(plans["closed_loop"][0], plans["open_loop"][0])


@pytest.mark.parametrize("path", sorted((ROOT / "configs").rglob("*.json")), ids=lambda p: p.name)
def test_every_config_parses(path: Path) -> None:
    from lerobot.configs.train import TrainPipelineConfig
    from lerobot.envs.configs import EnvConfig

    import lerobot_policy_dcdp  # noqa: F401

    content = json.loads(path.read_text())
    if "policy" in content:
        cfg = draccus.parse(
            TrainPipelineConfig,
            config_path=str(path),
            args=["--policy.base_policy_path=models/pusht-diffusion-state", "--dataset.repo_id=local/x"],
        )
        assert cfg.policy.type == "dcdp" and cfg.policy.n_action_steps >= 1
    else:
        import lerobot_dcdp.sim.envs  # noqa: F401  (registers pusht_perturbed)

        cfg = draccus.decode(EnvConfig, content["env"])
        assert cfg.type == content["env"]["type"]
        for key, value in content["env"].items():
            if key != "type":
                assert getattr(cfg, key) == value, key


@pytest.mark.parametrize("corrector", CORRECTORS, ids=lambda p: p.name)
def test_shipped_checkpoint_loads_unchanged(corrector, tmp_path) -> None:
    """Every shipped file loads in the key layout it was saved with (with or without the ``corrector.``
    prefix): every stored tensor lands in its module, the corrector hash is the file's, and a re-saved copy
    (current layout) gives the same actions."""
    from safetensors.torch import load_file

    from lerobot_dcdp.model.correction import state_dict_sha256
    from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
    from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

    # older shipped files keep the layout they were saved with (no ``corrector.`` prefix); newer ones have it
    raw = load_file(corrector / "model.safetensors")
    gate = "completion_gate."  # a fitted completion gate's weights, beside the corrector's
    stored = {k.removeprefix("corrector."): v for k, v in raw.items() if not k.startswith(gate)}
    stored_gate = {k.removeprefix(gate): v for k, v in raw.items() if k.startswith(gate)}
    policy = DCDPPolicy.from_pretrained(corrector).eval()
    loaded = policy.corrector.state_dict()
    assert set(stored) == set(loaded), "the shipped file and the corrector disagree on names"
    for key, value in stored.items():
        assert torch.equal(loaded[key], value), key
    assert policy.corrector_sha256() == state_dict_sha256(stored)
    assert (policy.completion_gate is not None) == bool(stored_gate) == policy.config.completion_gate
    if stored_gate:
        loaded_gate = policy.completion_gate.state_dict()
        assert set(loaded_gate) == set(stored_gate)
        assert all(torch.equal(loaded_gate[k], v) for k, v in stored_gate.items())

    policy.save_pretrained(tmp_path)
    assert all(k.startswith(("corrector.", gate)) for k in load_file(tmp_path / "model.safetensors"))
    again = DCDPPolicy.from_pretrained(tmp_path).eval()
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    obs = [pre(dict(o)) for o in env_observations(1, 3)]
    runs = []
    for p in (policy, again):  # a diffusion base draws noise: the same seed for both
        p.reset()
        torch.manual_seed(0)
        runs.append(torch.stack([p.select_action(dict(o)) for o in obs]))
    torch.testing.assert_close(runs[1], runs[0], rtol=0, atol=0)
