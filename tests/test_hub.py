"""Pushing a corrector to the Hub (HfApi calls recorded into a local folder) and loading it back."""

from __future__ import annotations

import fnmatch
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from helpers import make_dcdp_policy
from huggingface_hub import HfApi
from safetensors.torch import load_file

from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors


@pytest.fixture
def fake_hub(tmp_path, monkeypatch):
    """Record create_repo/upload_folder; uploaded files land in tmp_path/hub/<repo_id>."""
    hub, calls = tmp_path / "hub", []

    def create_repo(self, repo_id, **kwargs):
        calls.append(("create_repo", repo_id))
        return SimpleNamespace(repo_id=repo_id)

    def upload_folder(self, repo_id, folder_path, allow_patterns=None, ignore_patterns=None, **kwargs):
        names = []
        for f in sorted(Path(folder_path).rglob("*")):
            rel = str(f.relative_to(folder_path))
            if not f.is_file() or (
                allow_patterns and not any(fnmatch.fnmatch(rel, p) for p in allow_patterns)
            ):
                continue
            if ignore_patterns and any(fnmatch.fnmatch(rel, p) for p in ignore_patterns):
                continue
            (hub / repo_id / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(f, hub / repo_id / rel)
            names.append(rel)
        calls.append(("upload_folder", repo_id, names))
        return SimpleNamespace(
            commit_url=f"local://{repo_id}", oid="0", repo_url=SimpleNamespace(url=repo_id)
        )

    monkeypatch.setattr(HfApi, "create_repo", create_repo)
    monkeypatch.setattr(HfApi, "upload_folder", upload_folder)
    return hub, calls


def test_push_uploads_the_corrector_only_and_it_loads_back(diffusion_base, demo_root, fake_hub) -> None:
    from lerobot.configs.default import DatasetConfig
    from lerobot.configs.train import TrainPipelineConfig

    hub, calls = fake_hub
    policy = make_dcdp_policy(diffusion_base, demo_root)
    policy.config.repo_id = "user/dcdp-tiny"
    cfg = TrainPipelineConfig(
        dataset=DatasetConfig(repo_id="local/test", root=str(demo_root)), policy=policy.config
    )
    with pytest.raises(ValueError, match="hub_base_policy_path"):
        policy.push_model_to_hub(cfg)  # the base is a folder on this machine only
    assert not calls
    policy.config.hub_base_policy_path = "user/tiny-base"
    policy.push_model_to_hub(cfg)
    assert policy.config.base_policy_path == str(diffusion_base)
    pre, post = make_dcdp_pre_post_processors(policy.config)
    pre.push_to_hub("user/dcdp-tiny")
    post.push_to_hub("user/dcdp-tiny")

    uploaded = sorted({n for c in calls if c[0] == "upload_folder" for n in c[2]})
    assert {
        "config.json",
        "model.safetensors",
        "README.md",
        "train_config.json",
        "policy_preprocessor.json",
        "policy_postprocessor.json",
    } <= set(uploaded)
    repo = hub / "user/dcdp-tiny"
    weights = load_file(repo / "model.safetensors")
    base_keys = set(load_file(diffusion_base / "model.safetensors"))
    assert weights and not set(weights) & base_keys
    assert set(weights) == set(policy.state_dict())
    card = (repo / "README.md").read_text()
    assert policy.config.base_weights_sha256 in card and "lerobot-eval --policy.path=user/dcdp-tiny" in card

    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig

    stored = DCDPConfig.from_pretrained(repo)
    assert stored.base_policy_path == "user/tiny-base"
    # exactly the uploaded files; no Hub here, so the base's Hub id is overridden with its local copy
    stored.base_policy_path = str(diffusion_base)
    loaded = DCDPPolicy.from_pretrained(repo, config=stored)
    for k, v in policy.state_dict().items():
        assert torch.equal(v, loaded.state_dict()[k])
    assert loaded.config.base_weights_sha256 == policy.config.base_weights_sha256


def test_model_card_says_whether_a_completion_gate_is_fitted() -> None:
    from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
    from lerobot_dcdp.policy.model_card import make_model_card

    plain = DCDPConfig(base_policy_path="x/y", device="cpu")
    assert "completion gate" not in str(make_model_card(plain, "0" * 64, "local/test"))
    gated = DCDPConfig(base_policy_path="x/y", device="cpu", completion_gate=True, completion_radius=21.24)
    card = str(make_model_card(gated, "0" * 64, "local/test"))
    assert "completion gate: fitted on demonstrations (radius 21.24 in the object keypoints' units)" in card
