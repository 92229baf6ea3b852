"""The compiled per-step kernel (step_kernel.py) computes what the corrector's modules compute."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_dcdp.dynamics import DynamicFeatureExtractor, FrameEncoder
from lerobot_dcdp.residual import ResidualHead
from lerobot_dcdp.step_kernel import pack_weights, residual_step, supports

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
