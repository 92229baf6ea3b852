"""``dcdp-precompute-plans``: the base's chunk per frame as a dataset column, and stage 1 reading it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers import make_dcdp_policy, training_batches

from lerobot_dcdp.data.precompute_plans import main, precompute_plans

KEY = "observation.dcdp_plan"


@pytest.fixture(scope="module")
def plans_root(act_base, demo_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("plans") / "ds"
    precompute_plans(str(act_base), "local/test", demo_root, "local/test", out, episodes_per_batch=2)
    return out


def test_the_column_is_the_base_chunk_of_each_frame(act_base, demo_root, plans_root) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_dcdp.policy.base_policy import load_base_policy

    ds = LeRobotDataset("local/test", root=plans_root)
    original = LeRobotDataset("local/test", root=demo_root)
    assert ds.meta.total_frames == original.meta.total_frames
    assert tuple(ds.meta.features[KEY]["shape"]) == (16 * 2,)
    base = load_base_policy(str(act_base), "cpu")
    pre, post = make_pre_post_processors(base.config, pretrained_path=str(act_base))
    # ACT reads one frame: its chunk at any frame is its prediction from that frame alone
    for i in (0, 5, ds.meta.total_frames - 1):
        frame = original[i]
        batch = pre({k: frame[k].unsqueeze(0) for k in base.config.input_features})
        with torch.no_grad():
            chunk = base.predict_action_chunk(batch)
        raw = post(chunk)
        np.testing.assert_allclose(ds[i][KEY].numpy(), raw.reshape(-1).numpy(), atol=1e-4)
        for key in ("observation.state", "action"):  # the rest is copied unchanged
            torch.testing.assert_close(ds[i][key], frame[key])


def test_stage_one_takes_the_base_plan_from_plan_time(act_base, plans_root) -> None:
    policy = make_dcdp_policy(
        act_base,
        plans_root,
        correction="residual",
        anchor_feature="observation.environment_state",
        observation_features=["observation.environment_state"],
        motion_static_fraction=1.0,
        motions_per_sample=1,
    )
    batch = next(training_batches(policy, plans_root, batch_size=8))
    assert batch[KEY].shape[1:] == (8, 32)  # the column at every frame of the window
    torch.manual_seed(0)
    sample = policy.corrector.samples.synthesised(batch)
    plan, step, target = sample.plan, sample.step, sample.target
    rows = torch.arange(len(step))
    expected = policy.normalizer("action", batch[KEY].reshape(8, 8, 16, 2)[rows, 7 - step][:, :8])
    torch.testing.assert_close(plan, expected)
    torch.testing.assert_close(target, plan[rows, step])  # a still scene keeps the base's plan


def test_cli_refuses_an_existing_output(act_base, demo_root, plans_root, capsys) -> None:
    with pytest.raises(SystemExit, match="exists"):
        main(
            [
                *("--base", str(act_base), "--repo-id", "local/test", "--root", str(demo_root)),
                *("--out-repo-id", "local/test", "--out-root", str(plans_root)),
            ]
        )
