"""The scene lead: the object's motion from its track, the led scene, and the policy acting in it."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from helpers import env_observations, make_dcdp_policy

from lerobot_dcdp.model.base_normalizer import BaseNormalizer
from lerobot_dcdp.model.scene_lead import (
    SceneLead,
    check_lead_features,
    data_range,
    in_range_shift,
    lead_applies,
    moved_xy,
    repeated_motion,
    tracker_noise,
)
from lerobot_dcdp.policy.configuration_dcdp import DCDPConfig
from lerobot_dcdp.policy.processor_dcdp import make_dcdp_pre_post_processors

KEY = "observation.environment_state"


def test_repeated_motion_is_the_worlds_motion_also_where_pushes_are_the_majority() -> None:
    # two objects drifting (1, -0.5) and (0, 0) per step; the robot pushes them on 10 of 16 steps (a
    # sustained push: the per-coordinate median follows it), by a displacement that varies step to step
    world = torch.tensor([[1.0, -0.5], [0.0, 0.0]])
    steps = world.repeat(16, 1, 1)
    pushed = torch.arange(3, 13)
    steps[pushed] += torch.stack([torch.linspace(3.0, 4.0, 10), torch.linspace(2.0, 1.0, 10)], -1)[:, None]
    assert not torch.allclose(steps.median(0).values, world)  # the median follows the push
    motion, found = repeated_motion(steps, tolerance=0.05, repeats=3)
    torch.testing.assert_close(motion, world)
    assert found.tolist() == [True, True]
    # a change of the world's motion: the newest repeated displacement wins once it repeats 3 times
    turned = torch.cat([world.repeat(13, 1, 1), torch.tensor([[0.0, 1.0], [2.0, 0.0]]).repeat(3, 1, 1)])
    torch.testing.assert_close(repeated_motion(turned, 0.05, 3)[0], torch.tensor([[0.0, 1.0], [2.0, 0.0]]))
    torch.testing.assert_close(repeated_motion(turned, 0.05, 4)[0], world)  # 3 repeats are not 4
    # within the tolerance (a fraction of the motion's length) a noisy repeat counts, beyond it not
    noisy = torch.tensor([[[1.0, 0.0]], [[1.04, 0.0]], [[0.97, 0.0]]])
    torch.testing.assert_close(
        repeated_motion(noisy, 0.05, 3)[0], torch.tensor([[1.0033, 0.0]]), atol=1e-4, rtol=0
    )
    motion, found = repeated_motion(noisy, 0.02, 3)
    assert not found.item() and motion.abs().sum() == 0  # nothing repeats: no motion found
    # a still object seen by a jittering tracker: its steps repeat only within the noise
    jitter = torch.tensor([[[0.01, -0.02]], [[-0.015, 0.01]], [[0.02, 0.005]]])
    assert not repeated_motion(jitter, 0.05, 3)[1].item()
    motion, found = repeated_motion(jitter, 0.05, 3, noise=0.05)
    assert found.item() and motion.norm() < 0.01
    for bad in (torch.zeros(0, 2, 2), torch.zeros(4, 2, 3)):
        with pytest.raises(ValueError, match="W, B, 2"):
            repeated_motion(bad, 0.05, 3)


def test_tracker_noise_is_the_jitter_of_the_demonstrations_still_steps() -> None:
    # two episodes of an object pushed on every other stretch of 10 steps and still between, tracked exactly
    gen = torch.Generator().manual_seed(0)
    f64 = torch.float64
    pushes = (torch.arange(200) // 10 % 2 == 0).to(f64)[:, None] * torch.tensor([3.0, 1.0], dtype=f64)
    exact = pushes.cumsum(0)[:, None] + torch.tensor([[0.0, 0.0], [4.0, 2.0]], dtype=f64)  # (T, 2 points, 2)
    episodes = (torch.arange(200) >= 100).long()
    assert tracker_noise(exact, episodes) == 0.0  # a simulator's still steps are exact
    # the same track seen with jitter (sd 0.2 per coordinate): the noise covers two still steps' gap
    jittered = exact + 0.2 * torch.randn(200, 1, 2, generator=gen, dtype=f64)
    noise = tracker_noise(jittered, episodes)
    assert 0.3 < noise < 2.0  # about 4.6 x 1.07 x 0.2 = 0.98
    still = jittered.mean(1)[10:20].diff(dim=0)[:, None].float()  # a still stretch's steps (9, 1, 2)
    assert not repeated_motion(still, 0.05, 3)[1].item()  # without the noise its jitter never repeats
    motion, found = repeated_motion(still, 0.05, 3, noise=noise)
    assert found.item() and motion.norm() < 0.3  # with it: a still object, nearly no motion
    with pytest.raises(ValueError, match="points must be"):
        tracker_noise(exact[:, 0], episodes)
    with pytest.raises(ValueError, match="no episode has two frames"):
        tracker_noise(exact[:2], torch.tensor([0, 1]))


def _lead_config(**extra) -> SimpleNamespace:
    """A scene lead's config: 8 steps of the motion found in a 4-step window, plus ``extra``."""
    return SimpleNamespace(
        lead_steps=8, lead_window=4, lead_tolerance=0.05, lead_repeats=3, lead_noise=0.0, **extra
    )


def test_the_motion_found_last_holds_through_a_window_of_pushes() -> None:
    lead = SceneLead(_lead_config(lead_in_range=False), normalizer=None)
    drift, centroid = torch.tensor([[0.5, 0.0]]), torch.zeros(1, 2)
    shifts = []
    for step in range(12):  # 6 steps of drift, then 6 of a push that varies (no step repeats another)
        centroid = centroid + drift + (step >= 6) * torch.tensor([[1.0 + 0.3 * step, 2.0]])
        shifts.append(lead.observe(centroid[:, None].repeat(1, 3, 1)))
    assert shifts[3].abs().sum() == 0  # before a window has been seen: no lead
    for shift in shifts[4:]:  # the drift once found, and held while the push leaves nothing repeated
        torch.testing.assert_close(shift, 8 * drift)
    track, motion = list(lead._track), lead._motion.clone()
    # a query (record=False) answers with the held motion and leaves the track as it was
    query = lead.observe((centroid + torch.tensor([[5.0, 5.0]]))[:, None].repeat(1, 3, 1), record=False)
    torch.testing.assert_close(query, 8 * drift)  # its one step repeats nothing: the held motion
    assert torch.equal(torch.stack(lead._track), torch.stack(track))
    torch.testing.assert_close(lead._motion, motion)  # a query changes neither track nor motion
    torch.testing.assert_close(lead.observe(centroid[:, None].repeat(1, 3, 1)), 8 * drift)
    lead.reset()
    assert lead.observe(centroid[:, None].repeat(1, 3, 1)).abs().sum() == 0


def test_in_range_shift_shortens_the_lead_at_the_datas_edge_and_never_reverses_it() -> None:
    low = torch.tensor([[0.0, 0.0], [10.0, 0.0]])  # each keypoint coordinate has its own range
    high = torch.tensor([[100.0, 50.0], [100.0, 60.0]])
    points = torch.tensor([[[90.0, 20.0], [30.0, 55.0]], [[50.0, 25.0], [50.0, 30.0]]])  # (B=2, N=2, 2)
    shift = torch.tensor([[20.0, -30.0], [-5.0, 4.0]])
    # first scene: x may move up by 10 (the first keypoint's room), y down by 20 (the first's); the second
    # scene has room for its whole shift
    torch.testing.assert_close(
        in_range_shift(points, shift, low, high), torch.tensor([[10.0, -20.0], [-5.0, 4.0]])
    )
    # a keypoint already beyond its range is not pulled back in: no further out, and no move back either
    outside = torch.tensor([[[105.0, 20.0], [30.0, 30.0]]])
    torch.testing.assert_close(
        in_range_shift(outside, torch.tensor([[6.0, 3.0]]), low, high), torch.tensor([[0.0, 3.0]])
    )
    torch.testing.assert_close(
        in_range_shift(outside, torch.tensor([[-6.0, 3.0]]), low, high), torch.tensor([[-6.0, 3.0]])
    )


def test_the_lead_stays_within_the_bases_data_range_and_needs_its_statistics() -> None:
    stats = {"min": torch.tensor([0.0, 0.0, 0.0, 0.0]), "max": torch.tensor([100.0, 100.0, 100.0, 90.0])}
    normalizer = BaseNormalizer({KEY: ("MIN_MAX", stats)})
    low, high = data_range(normalizer, KEY)
    assert low.shape == high.shape == (2, 2) and high[1].tolist() == [100.0, 90.0]
    config = _lead_config(lead_in_range=True, anchor_feature=KEY)
    lead, drift = SceneLead(config, normalizer), torch.tensor([[1.0, 2.0]])
    pair = torch.tensor([[0.0, 0.0], [10.0, 10.0]])  # the object's two keypoints around its centroid
    start = torch.tensor([[40.0, 50.0]])
    for step in range(6):  # drifting towards the top of the data's range; the lead is found at step 4
        shift = lead.observe(start + step * drift + pair[None])
    # 8 x (1, 2) = (8, 16) unclipped; the second keypoint's y is at 50 + 10 + 10 = 70, 20 below its 90
    torch.testing.assert_close(shift, torch.tensor([[8.0, 16.0]]))
    for step in range(6, 16):
        shift = lead.observe(start + step * drift + pair[None])
    # at step 15 that y is 90: no room left up y, x (65 + 10 = 75 of 100) keeps its whole lead
    torch.testing.assert_close(shift, torch.tensor([[8.0, 0.0]]))
    config.lead_in_range = False
    torch.testing.assert_close(lead.observe(start + 15 * drift + pair[None], record=False), 8 * drift)
    # a base whose statistics hold no min / max: one clear error naming the feature and the way out
    bare = BaseNormalizer({KEY: ("MEAN_STD", {"mean": torch.zeros(4), "std": torch.ones(4)})})
    with pytest.raises(
        ValueError, match=r"lead_in_range needs the min / max of 'observation.environment_state'"
    ):
        data_range(bare, KEY)
    with pytest.raises(ValueError, match="lead_in_range=false"):
        check_lead_features(
            SimpleNamespace(anchor_feature=KEY, lead_state_feature="observation.state", lead_in_range=True),
            {KEY: _feature((4,)), "observation.state": _feature((2,))},
            bare,
        )


def _feature(shape: tuple[int, ...]):
    from lerobot.configs.types import FeatureType, PolicyFeature

    return PolicyFeature(type=FeatureType.STATE, shape=shape)


def test_moved_xy_moves_every_keypoint_or_the_robots_xy_only() -> None:
    x = torch.arange(6.0).reshape(1, 6)
    shift = torch.tensor([[10.0, 20.0]])
    assert moved_xy(x, shift, pairs=True).tolist() == [[10.0, 21.0, 12.0, 23.0, 14.0, 25.0]]
    assert moved_xy(x, shift, pairs=False).tolist() == [[10.0, 21.0, 2.0, 3.0, 4.0, 5.0]]


def test_the_lead_is_checked_and_applies_in_the_modes_that_move_the_plan() -> None:
    base = {"base_policy_path": "some/base", "device": "cpu", "push_to_hub": False}
    with pytest.raises(ValueError, match="lead_steps must be an int >= 0"):
        DCDPConfig(**base, lead_steps=-1)
    with pytest.raises(ValueError, match="lead_window must be an int >= 2"):
        DCDPConfig(**base, lead_window=1)
    with pytest.raises(ValueError, match="lead_tolerance must be >= 0"):
        DCDPConfig(**base, lead_tolerance=-0.1)
    with pytest.raises(ValueError, match="lead_repeats must be an int >= 2"):
        DCDPConfig(**base, lead_repeats=1)
    with pytest.raises(ValueError, match="lead_noise must be >= 0"):
        DCDPConfig(**base, lead_noise=-1.0)
    with pytest.raises(ValueError, match=r"lead_repeats \(17\) must be <= lead_window \(16\)"):
        DCDPConfig(**base, lead_repeats=17, lead_steps=8, anchor_feature=KEY)
    DCDPConfig(**base, lead_window=2)  # a folder without a lead never checks repeats against its window
    with pytest.raises(ValueError, match="lead_steps needs anchor_feature"):
        DCDPConfig(**base, lead_steps=8)
    config = DCDPConfig(**base, lead_steps=8, anchor_feature=KEY)
    for execution, applies in (("dcdp", True), ("object_anchored", True), ("open_loop", False)):
        config.execution = execution
        assert lead_applies(config) is applies
    config.base_location = "remote"  # a remote base plans from the robot's own observation: no lead
    assert not lead_applies(config)
    config.base_location = "local"
    config.lead_steps = 0
    assert not lead_applies(config)


def _moving(observations: list[dict], velocity: torch.Tensor) -> list[dict]:
    """Raw observations whose block keypoints move ``velocity`` (2,) more each step."""
    return [
        {**o, KEY: (o[KEY].reshape(o[KEY].shape[0], -1, 2) + t * velocity).reshape(o[KEY].shape)}
        for t, o in enumerate(observations)
    ]


def _tiny_policy(diffusion_base, demo_root, **overrides):
    """A tiny residual policy around the test base, 4-step chunks, anchored to the block keypoints."""
    return make_dcdp_policy(
        diffusion_base,
        demo_root,
        **{
            "correction": "residual",
            "latent_dim": 4,
            "n_action_steps": 4,
            "anchor_feature": KEY,
            **overrides,
        },
    ).eval()


def _actions(policy, observations: list[dict]) -> torch.Tensor:
    pre, post = make_dcdp_pre_post_processors(policy.config)
    torch.manual_seed(3)
    policy.reset()
    return torch.stack([post(policy.select_action(pre(dict(o)))) for o in observations])


@pytest.mark.parametrize("execution", ["object_anchored", "dcdp"])
def test_the_policy_acts_in_the_led_scene_and_moves_its_actions_back(diffusion_base, demo_root, execution):
    window, lead, velocity = 4, 3, torch.tensor([1.5, -0.75])
    # the lead as found (the test demonstrations' range is narrow; the range's clip has its own tests)
    policy = _tiny_policy(
        diffusion_base, demo_root, execution=execution, lead_window=window, lead_in_range=False
    )
    torch.manual_seed(1)
    with torch.no_grad():  # a corrector that moves the plan
        for p in policy.corrector.residual.parameters():
            p.add_(0.05 * torch.randn_like(p))
    observations = _moving(env_observations(2, 1) * 10, velocity)  # the world moves the block, nobody pushes
    policy.config.lead_steps = lead
    observe, shifts = policy.lead.observe, []
    policy.lead.observe = lambda points, record=True: shifts.append(observe(points, record)) or shifts[-1]
    led = _actions(policy, observations)
    # the object's motion is read from its track: no lead until a window of it is seen, then lead x velocity
    for t, shift in enumerate(shifts):
        want = lead * velocity if t >= window else torch.zeros(2)
        torch.testing.assert_close(shift, want.expand(2, 2), atol=1e-3, rtol=0)
    # by hand: the lead off, the observations moved by the same shifts (block and robot), actions moved back
    policy.config.lead_steps = 0
    led_by_hand = [
        {
            "observation.state": o["observation.state"] + shift,
            KEY: (o[KEY].reshape(2, -1, 2) + shift[:, None]).reshape(2, -1),
        }
        for o, shift in zip(observations, shifts, strict=True)
    ]
    by_hand = _actions(policy, led_by_hand)
    policy.config.lead_steps = lead
    torch.testing.assert_close(led, by_hand - torch.stack(shifts), atol=1e-3, rtol=0)
    assert (led[window:] - _actions_without_lead(policy, observations)[window:]).abs().max() > 1.0
    # the baselines never lead: open loop is the same with and without it
    policy.config.execution = "open_loop"
    torch.testing.assert_close(_actions(policy, observations), _actions_without_lead(policy, observations))


def _actions_without_lead(policy, observations: list[dict]) -> torch.Tensor:
    kept, policy.config.lead_steps = policy.config.lead_steps, 0
    try:
        return _actions(policy, observations)
    finally:
        policy.config.lead_steps = kept


def test_a_lead_needs_the_robots_xy_among_the_observations(diffusion_base, demo_root) -> None:
    with pytest.raises(ValueError, match="lead_state_feature 'observation.velocity' is not among the base's"):
        _tiny_policy(diffusion_base, demo_root, lead_steps=4, lead_state_feature="observation.velocity")


def test_predict_action_chunk_plans_in_the_led_scene_and_leaves_the_track(diffusion_base, demo_root):
    window, velocity = 4, torch.tensor([2.0, 1.0])
    policy = _tiny_policy(diffusion_base, demo_root, lead_steps=4, lead_window=window)
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    observations = [pre(dict(o)) for o in _moving(env_observations(2, 1) * 9, velocity)]
    torch.manual_seed(0)
    policy.reset()
    for o in observations[:8]:
        policy.select_action(dict(o))
    track = list(policy.lead._track)
    torch.manual_seed(1)
    chunk = policy.predict_action_chunk(dict(observations[8]))
    assert all(torch.equal(a, b) for a, b in zip(track, policy.lead._track, strict=True))  # a query
    torch.manual_seed(1)
    action = policy.select_action(dict(observations[8]))  # step 8 starts a chunk: the same plan
    torch.testing.assert_close(chunk[:, 0], action)
    policy.config.lead_steps = 0
    torch.manual_seed(1)
    unled = policy.predict_action_chunk(dict(observations[8]))
    assert (unled - chunk).abs().max() > 1e-2  # the lead moved the queried chunk


def test_where_the_gate_keeps_the_plan_it_is_moved_back_by_the_current_lead(diffusion_base, demo_root):
    """The documented choice: each action is moved back by the lead of its own step, also where the
    completion gate leaves the plan as planned (so the lead's first window, filled mid-chunk, moves it)."""
    window, lead, velocity = 5, 3, torch.tensor([1.5, -0.75])  # the lead starts at step 5: mid-chunk
    policy = _tiny_policy(
        diffusion_base,
        demo_root,
        execution="object_anchored",
        completion_gate=True,
        lead_steps=lead,
        lead_window=window,
    )
    with torch.no_grad():  # a gate that says "nearly done" everywhere
        last = policy.completion_gate.net[-1]
        last.weight.zero_()
        last.bias.fill_(30.0)
    observe, shifts = policy.lead.observe, []
    policy.lead.observe = lambda points, record=True: shifts.append(observe(points, record)) or shifts[-1]
    pre, _ = make_dcdp_pre_post_processors(policy.config)
    torch.manual_seed(3)
    policy.reset()
    for t, o in enumerate(_moving(env_observations(2, 1) * 10, velocity)):
        action = policy.normalizer("action", policy.select_action(pre(dict(o))), inverse=True)
        plan = policy.normalizer("action", policy.planned_chunk[:, policy.last_step], inverse=True)
        torch.testing.assert_close(action, plan - shifts[t], atol=1e-3, rtol=0)
        assert bool(shifts[t].abs().sum() > 0) is (t >= window)


def test_the_fit_leads_by_default_where_the_base_can_be_led_and_refuses_an_explicit_lead_it_cannot():
    from types import SimpleNamespace

    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_dcdp.train.fit_completion_gate import set_lead

    state = PolicyFeature(type=FeatureType.STATE, shape=(2,))
    keypoints = PolicyFeature(type=FeatureType.ENV, shape=(16,))
    image = PolicyFeature(type=FeatureType.VISUAL, shape=(3, 96, 96))

    ranged = ("MIN_MAX", {"min": torch.zeros(16), "max": torch.full((16,), 512.0)})

    def folder(base_inputs: dict, anchor: str | None = KEY, stats: tuple = ranged) -> SimpleNamespace:
        config = SimpleNamespace(
            anchor_feature=anchor,
            n_action_steps=8,
            lead_steps=0,
            lead_in_range=True,
            lead_state_feature="observation.state",
        )
        return SimpleNamespace(
            config=config,
            base=SimpleNamespace(config=SimpleNamespace(input_features=base_inputs)),
            normalizer=BaseNormalizer({KEY: stats}),
        )

    led = folder({"observation.state": state, KEY: keypoints})
    assert set_lead(led, None) == "scene lead 8 steps" and led.config.lead_steps == 8
    assert set_lead(led, 0) == "no scene lead" and led.config.lead_steps == 0
    pixels = folder({"observation.state": state, KEY: keypoints, "observation.image": image})
    assert set_lead(pixels, None).startswith("no scene lead") and pixels.config.lead_steps == 0
    with pytest.raises(ValueError, match="images"):
        set_lead(pixels, 4)
    no_state = folder({KEY: keypoints})
    assert set_lead(no_state, None).startswith("no scene lead (lead_state_feature")
    no_anchor = folder({"observation.state": state}, anchor=None)
    assert set_lead(no_anchor, None).startswith("no scene lead") and no_anchor.config.lead_steps == 0
    with pytest.raises(ValueError, match="anchor_feature"):
        set_lead(no_anchor, 4)
    # a base whose statistics lack the keypoints' min / max: no default lead, an explicit one refused
    unranged = folder(
        {"observation.state": state, KEY: keypoints},
        stats=("MEAN_STD", {"mean": torch.zeros(16), "std": torch.ones(16)}),
    )
    assert set_lead(unranged, None).startswith("no scene lead (lead_in_range needs the min / max")
    with pytest.raises(ValueError, match="lead_in_range=false"):
        set_lead(unranged, 8)
    unranged.config.lead_in_range = False  # led without the range, as asked
    assert set_lead(unranged, 8) == "scene lead 8 steps"
