"""The compiled per-step kernel (step_kernel.py) computes what the corrector's modules compute."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_dcdp.model.dynamics import DynamicFeatureExtractor, FrameEncoder
from lerobot_dcdp.model.residual import ResidualHead
from lerobot_dcdp.runtime.step_kernel import pack_weights, residual_step, supports

N_STATE, M, D, HEADS, H, A, HIDDEN = 7, 4, 16, 4, 6, 2, 24


def _modules(temporal: bool, cross: bool, seed: int = 0):
    torch.manual_seed(seed)
    frames = FrameEncoder({"observation.state": 3, "observation.environment_state": 4}, [], D, 20)
    extractor = DynamicFeatureExtractor(M, D, HEADS, 0.7, temporal, cross)
    head = ResidualHead(H, A, 3, D, 2 * N_STATE, HIDDEN, 5)
    with torch.no_grad():  # every weight non-trivial, the standardisation too
        for m in (frames, extractor, head):
            for p in m.parameters():
                p.add_(0.1 * torch.randn_like(p))
        head.net[-1].weight.mul_(0.1)  # corrections of a trained head's size (float32 rounding is relative)
        frames.state_shift.copy_(torch.randn(N_STATE))
        frames.state_scale.copy_(torch.rand(N_STATE) + 0.5)
    return frames.eval(), extractor.eval(), head.eval()


def _eager(frames, extractor, head, x, bank, at_plan, terms_s, w_step, plan_s, half, scale):
    """The straightforward path of DCDPPolicy.select_action for one residual step."""
    token, vec = frames.encode({"observation.state": x[:, :3], "observation.environment_state": x[:, 3:]})
    bank = torch.cat([bank[:, 1:], token.unsqueeze(1)], dim=1)
    feature, _ = extractor(bank)
    delta = head.step(terms_s, feature, scale * (vec - at_plan), w_step)
    return plan_s + delta * half, bank, vec


@pytest.mark.parametrize("temporal,cross", [(True, True), (False, True), (True, False), (False, False)])
@pytest.mark.parametrize("batch", [1, 3])
@torch.no_grad()
def test_kernel_equals_the_modules(temporal: bool, cross: bool, batch: int) -> None:
    frames, extractor, head = _modules(temporal, cross)
    scale = 10.0
    w = pack_weights(frames, extractor, head, scale)
    g = torch.Generator().manual_seed(1)
    x = 3 * torch.randn(batch, N_STATE, generator=g)
    bank = torch.randn(batch, M, D, generator=g)
    at_plan = torch.randn(batch, N_STATE, generator=g)
    plan = torch.rand(batch, H, A, generator=g) * 2 - 1
    z = torch.randn(batch, 3, generator=g)
    terms, w_step = head.chunk_terms(z, plan, at_plan)
    half = torch.tensor([0.7, 1.3])
    w_step_kernel = w_step.T.contiguous().numpy()  # the kernel's (out, in) layout
    for s in range(H):
        args = (x, bank, at_plan, terms[:, s], w_step, plan[:, s], half, scale)
        expected = _eager(frames, extractor, head, *args)
        got = residual_step(w, x, bank, at_plan, terms[:, s], w_step_kernel, plan[:, s], half.numpy())
        for e, o in zip(expected, got, strict=True):
            assert o.shape == e.shape and o.dtype == torch.float32
            torch.testing.assert_close(o, e, rtol=1e-6, atol=1e-6)  # float32 rounding, other sum order
        moved = (expected[0] - plan[:, s]).abs().max()
        assert 1e-2 < moved < 2, moved  # the head moves the plan (a real check) by action-sized amounts
        x, bank = x + 0.5 * torch.randn(batch, N_STATE, generator=g), got[1]


def test_kernel_follows_new_weights_after_repacking() -> None:
    frames, extractor, head = _modules(True, True)
    w = pack_weights(frames, extractor, head, 1.0)
    with torch.no_grad():
        head.net[-1].bias.add_(1.0)
    w2 = pack_weights(frames, extractor, head, 1.0)
    args = (torch.zeros(1, N_STATE), torch.zeros(1, M, D), torch.zeros(1, N_STATE), torch.zeros(1, HIDDEN))
    rest = (np.zeros((HIDDEN, D + N_STATE), np.float32), torch.zeros(1, A), np.ones(A, np.float32))
    a1, a2 = residual_step(w, *args, *rest)[0], residual_step(w2, *args, *rest)[0]
    torch.testing.assert_close(a2 - a1, torch.ones(1, A), rtol=0, atol=1e-6)


def test_kernel_refuses_what_it_does_not_cover() -> None:
    frames, extractor, head = _modules(True, True)
    layer = torch.nn.TransformerEncoderLayer
    gelu, post_norm = DynamicFeatureExtractor(M, D, HEADS), DynamicFeatureExtractor(M, D, HEADS)
    gelu.temporal = layer(D, HEADS, 2 * D, 0.0, "gelu", batch_first=True, norm_first=True)
    post_norm.temporal = layer(D, HEADS, 2 * D, 0.0, batch_first=True, norm_first=False)
    assert supports(frames, extractor)
    for other in (gelu, post_norm):
        assert not supports(frames, other)
        with pytest.raises(ValueError, match="ReLU, norm_first"):
            pack_weights(frames, other, head, 1.0)
    images = FrameEncoder({}, ["observation.image"], D, 20)
    assert not supports(images, extractor)


_FALLBACK = """
import logging, sys, torch
logging.basicConfig(level=logging.INFO)
from lerobot_dcdp.policy.modeling_dcdp import DCDPPolicy
p = DCDPPolicy.from_pretrained(sys.argv[1])
p.eval().reset()
torch.manual_seed(0)
obs = {"observation.state": torch.tensor([[200.0, 300.0]]) / 512 * 2 - 1,
       "observation.environment_state": torch.linspace(-0.5, 0.5, 16).unsqueeze(0)}
acts = [p.select_action(dict(obs)) for _ in range(10)]
print("KERNEL", p.kernel._supported, "ACTIONS", torch.cat(acts).sum().item())
"""


@pytest.mark.slow
def test_unwritable_kernel_cache_falls_back_to_pytorch(tmp_path) -> None:
    """A cache folder that cannot be created: the shipped corrector still loads and acts (PyTorch path, one
    warning); with a writable cache it runs the kernel; both give the same actions."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    shipped = Path(__file__).parents[1] / "models" / "pusht-dcdp-state"
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    runs = {}
    for name, cache in (("broken", blocker / "cache"), ("ok", tmp_path / "cache")):
        proc = subprocess.run(
            [sys.executable, "-c", _FALLBACK, str(shipped)],
            env={**env, "DCDP_KERNEL_CACHE": str(cache), "OMP_NUM_THREADS": "1"},
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[name] = (proc.stdout.split("KERNEL")[-1].split(), proc.stderr)
    (kernel_broken, _, total_broken), err_broken = runs["broken"]
    (kernel_ok, _, total_ok), err_ok = runs["ok"]
    assert kernel_broken == "False" and err_broken.count("compiled per-step kernel is unavailable") == 1
    assert kernel_ok == "True" and "kernel ready in" in err_ok
    assert float(total_broken) == pytest.approx(float(total_ok), abs=1e-4)
