"""``backbone='base_encoder'``: the corrector reads cameras through the frozen base's own image encoder."""

from __future__ import annotations

import pytest
import torch
from helpers import make_tiny_base, policy_features, training_batches

from lerobot_dcdp.model.dynamics import BaseEncoderBackbone, ImageBackbone
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy


def _config(base, root, **overrides) -> DCDPConfig:
    inp, out, _ = policy_features(root)
    params = dict(
        feature_dim=16,
        n_heads=2,
        encoder_hidden_dim=16,
        decoder_hidden_dim=16,
        correction="reconstruct",
        backbone="base_encoder",
        observation_features=["observation.image"],
    )
    params.update(overrides)
    return DCDPConfig(
        base_policy_path=str(base), input_features=inp, output_features=out, device="cpu", **params
    )


def test_the_corrector_reads_frames_through_the_bases_frozen_encoder(image_demo_root, tmp_path) -> None:
    base = make_tiny_base("diffusion", tmp_path / "base", image_demo_root, images=True, crop_shape=(84, 84))
    _, _, stats = policy_features(image_demo_root)
    torch.manual_seed(0)
    policy = DCDPPolicy(_config(base, image_demo_root), dataset_stats=stats)
    backbone = policy.corrector.frame_encoder.image
    assert isinstance(backbone, BaseEncoderBackbone)
    assert backbone._encoder is policy.base.diffusion.rgb_encoder[0]  # one camera, separate encoders
    # only the linear map on the encoder's 64 features is the corrector's: nothing of the encoder is saved
    assert tuple(backbone.proj.weight.shape) == (16, 64)
    encoder_size = sum(p.numel() for p in backbone._encoder.parameters())
    assert sum(v.numel() for v in policy.state_dict().values()) < encoder_size
    assert not any("image._encoder" in k or "rgb_encoder" in k for k in policy.state_dict())
    frozen = {k: v.clone() for k, v in policy.base.diffusion.rgb_encoder.state_dict().items()}
    batch = next(training_batches(policy, image_demo_root, batch_size=4))
    policy.train()
    loss, _ = policy.forward(batch)
    loss.backward()
    assert backbone.proj.weight.grad is not None and backbone.proj.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in policy.base.diffusion.rgb_encoder.parameters())
    after = policy.base.diffusion.rgb_encoder.state_dict()
    assert all(torch.equal(frozen[k], after[k]) for k in frozen)
    # the tokens follow the frame
    img = batch["observation.image"][:, 0]
    assert not torch.allclose(backbone(img), backbone(img.flip(-1)))


def test_auto_reads_a_camera_through_the_bases_encoder(image_demo_root, tmp_path) -> None:
    """backbone='auto' with a camera: the base's trained encoder (a random ResNet18 carries nothing of the
    block's motion: scripts/encoder_probe.py), saved as the folder's choice; a ResNet18 for a base without
    one encoder, or when ResNet18 weights are given."""
    import json

    import torchvision

    _, _, stats = policy_features(image_demo_root)
    diffusion = make_tiny_base("diffusion", tmp_path / "d", image_demo_root, images=True, crop_shape=(84, 84))
    policy = DCDPPolicy(_config(diffusion, image_demo_root, backbone="auto"), dataset_stats=stats)
    assert isinstance(policy.corrector.frame_encoder.image, BaseEncoderBackbone)
    policy.save_pretrained(tmp_path / "corrector")
    assert json.loads((tmp_path / "corrector" / "config.json").read_text())["backbone"] == "base_encoder"
    act = make_tiny_base("act", tmp_path / "act", image_demo_root, images=True)
    policy = DCDPPolicy(_config(act, image_demo_root, backbone="auto"), dataset_stats=stats)
    assert isinstance(policy.corrector.frame_encoder.image, ImageBackbone)
    weights = tmp_path / "resnet18.pt"
    torch.save(torchvision.models.resnet18(weights=None).state_dict(), weights)
    config = _config(diffusion, image_demo_root, backbone="auto", image_backbone_weights=str(weights))
    assert isinstance(DCDPPolicy(config, dataset_stats=stats).corrector.frame_encoder.image, ImageBackbone)


def test_a_base_without_one_image_encoder_is_refused_by_name(image_demo_root, tmp_path) -> None:
    base = make_tiny_base("act", tmp_path / "act", image_demo_root, images=True)
    with pytest.raises(ValueError, match="base type 'act' has none"):
        DCDPPolicy(_config(base, image_demo_root))
    with pytest.raises(ValueError, match="backbone='base_encoder' needs an image observation feature"):
        _config(base, image_demo_root, observation_features=["observation.state"]).validate_features()


def test_features_encoded_beforehand_stand_in_for_the_frames(image_demo_root, tmp_path) -> None:
    """dcdp-precompute-base-features writes the base encoder's features of each frame (as normalised by the
    base's pre-processor); a training batch holding them gives the tokens and the loss the frames give."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_dcdp.data.precompute_base_features import main as precompute

    base = make_tiny_base("diffusion", tmp_path / "base", image_demo_root, images=True, crop_shape=(84, 84))
    out = tmp_path / "enc"
    precompute(
        ["--base", str(base), "--repo-id", "local/img", "--root", str(image_demo_root)]
        + ["--out-repo-id", "local/img_enc", "--out-root", str(out)]
    )
    ds = LeRobotDataset("local/img_enc", root=out)
    assert list(ds.meta.features["observation.image.base_encoded"]["shape"]) == [64]
    assert "observation.image" in ds.meta.features  # the frames stay: the corrector reads them at run time
    with pytest.raises(SystemExit, match="exists"):
        precompute(
            ["--base", str(base), "--repo-id", "local/img", "--root", str(image_demo_root)]
            + ["--out-repo-id", "local/img_enc", "--out-root", str(out)]
        )
    _, _, stats = policy_features(out)
    torch.manual_seed(0)
    policy = DCDPPolicy(_config(base, out), dataset_stats=stats)
    assert "observation.image.base_encoded" not in policy.config.input_features  # never asked of an env
    batch = next(training_batches(policy, out, batch_size=4))
    frames = {k: v for k, v in batch.items() if k != "observation.image.base_encoded"}
    enc = policy.corrector.frame_encoder
    assert torch.allclose(
        enc(policy.corrector.frames(batch)), enc(policy.corrector.frames(frames)), atol=1e-4
    )
    losses = []
    for b in (batch, frames):
        torch.manual_seed(1)
        losses.append(policy.forward(b)[0])
    assert torch.allclose(losses[0], losses[1], atol=1e-5)
    # without the frames, the column alone trains the corrector
    torch.manual_seed(1)
    cached = {k: v for k, v in batch.items() if k != "observation.image"}
    assert torch.allclose(policy.forward(cached)[0], losses[1], atol=1e-5)
    # --drop-cameras: the copy holds no frame; the corrector declares the base's camera, trains on the column
    dropped = tmp_path / "enc_dropped"
    precompute(
        ["--base", str(base), "--repo-id", "local/img", "--root", str(image_demo_root)]
        + ["--out-repo-id", "local/img_enc2", "--out-root", str(dropped), "--drop-cameras"]
    )
    assert "observation.image" not in LeRobotDataset("local/img_enc2", root=dropped).meta.features
    torch.manual_seed(0)
    slim = DCDPPolicy(_config(base, dropped), dataset_stats=stats)
    assert tuple(slim.config.input_features["observation.image"].shape) == (3, 96, 96)
    slim.load_state_dict(policy.state_dict())
    slim_batch = next(training_batches(slim, dropped, batch_size=4))
    assert "observation.image" not in slim_batch
    torch.manual_seed(1)
    assert torch.isfinite(slim.forward(slim_batch)[0])
