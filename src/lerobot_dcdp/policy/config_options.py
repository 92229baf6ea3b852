"""The options of :class:`~lerobot_dcdp.policy.configuration_dcdp.DCDPConfig`, one dataclass per concern.

``DCDPConfig`` inherits every group, so the options stay flat ``--policy.<name>`` flags and flat keys of a
saved ``config.json``, as in LeRobot's own policy configs. Each group is validated by the pure check of the
same concern in :mod:`lerobot_dcdp.policy.config_checks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ExecutionOptions:
    """The frozen base, the chunk and how it is executed.

    Args:
        base_policy_path: The frozen base policy: a local ``pretrained_model`` directory or a Hub repo id.
        base_policy_type: Type of the base (``diffusion``, ``act``, ...); recorded at stage 1.
        base_weights_sha256: Content hash of the base weights the corrector was trained against; recorded at
            stage 1 and verified on every load (a different base is refused).
        hub_base_policy_path: The base's Hub repo id, recorded instead of a local ``base_policy_path``
            when the corrector is pushed to the Hub (a pushed corrector cannot point at a folder on this
            machine; a push with a local base and no Hub id is refused).
        n_history: History length M of the observation bank (paper: M = 5). Must be >= 2.
        n_action_steps: Executed steps H per base chunk (paper: 8). Must not exceed the base's chunk.
        execution: ``dcdp`` (corrected chunks), ``open_loop`` (the base as LeRobot runs it, replanning every
            H steps), ``closed_loop`` (replan every step) or ``temporal_ensemble`` (replan every step, blend
            overlapping predictions).
            ``object_anchored`` is a training-free reference: the not-yet-executed part of the chunk is
            carried along with the rigid motion of the object seen in ``anchor_feature`` since the chunk
            was planned. ``bid`` samples several chunks at each decision and executes the one BID selects (see
            ``BidOptions``).
        inference_delay: Control steps d the base takes to answer (beyond the paper; default 0). A chunk
            that starts being used at step t was planned from the observation of step t-d (the first one, at
            t = 0, from step 0), and its entries for the steps already past are skipped, so the base must
            return n_action_steps + d actions. Every execution mode honours it; ``object_anchored`` and
            ``dcdp`` measure the change since that observation, which is what they correct.
        te_weight: Weight of the newest prediction in ``temporal_ensemble`` (authors: 0.5).
    """

    base_policy_path: str | None = None
    base_policy_type: str | None = None
    base_weights_sha256: str | None = None
    hub_base_policy_path: str | None = None
    n_history: int = 5
    n_action_steps: int = 8
    execution: str = "dcdp"
    inference_delay: int = 0
    te_weight: float = 0.5


@dataclass
class PlanningOptions:
    """When and where the base plans (on the tick or on a worker thread, here or on another machine), and the
    control rate.

    Args:
        planning: ``sync`` (default): the base plans on the control tick that needs the chunk. ``async``
            (``dcdp``, ``open_loop`` and ``object_anchored``): the base plans the next chunk on a worker
            thread from the observation of a tick shortly before the current chunk ends, while every tick
            returns its action at once; the new chunk is used from the tick after it is ready and the current
            chunk has run its ``n_action_steps`` (until then the current one keeps being executed, its last
            step held and corrected), its entries for the ticks past since its observation skipped, and the
            corrector measures the change since that observation. Only an episode's first chunk is planned
            on the tick.
        planning_clock: How ``async`` planning tells a chunk's age. ``wall`` (default; ``lerobot-rollout``):
            planning starts ``ceil(planning time / tick period) + 1`` ticks before the chunk ends (both
            measured as it runs) and a chunk is used once the worker returns it. ``steps`` (``lerobot-eval``,
            benchmarks: reproducible): planning starts ``inference_delay`` ticks before the chunk ends and
            its chunk is used exactly ``inference_delay`` ticks after its observation (the tick waits for the
            worker if it is slower), the same actions as ``planning=sync`` with that ``inference_delay``.
        planner_cpus: CPUs the ``async`` worker thread (the base) runs on, e.g. ``[1]`` (default None:
            wherever the scheduler puts it). While the worker lives, the thread that started it (the control
            loop) runs on the other CPUs the process may use, so the base never preempts a tick on a shared
            core.
        planner_priority: Scheduling of the ``async`` worker thread: ``normal`` (default) or ``idle`` (Linux
            ``SCHED_IDLE``: the base runs only while no other thread wants its CPU, so a control tick that
            wakes up takes the CPU from it at once, with or without ``planner_cpus``). Both apply to the
            worker that runs the base in this process; a remote base's client thread (``dcdp-robot-client``)
            only waits on the server.
        ticks_per_step: Control ticks per planned step: the control loop's rate over the rate the base was
            trained at (default 1; a 10 Hz base on a 30 Hz loop: 3). The policy computes an action (base,
            corrector, their observation histories) on every ``ticks_per_step``-th ``select_action`` call and
            returns the same action on the calls between, so a chunk lasts as long in time as in training
            instead of being run ``ticks_per_step`` times too fast. A client that feeds a planner itself
            (``dcdp-robot-client``) records an observation only on the calls that compute
            (``DCDPPolicy.holds_next_tick``).
        base_location: ``local`` (default): the base's weights are loaded here and it plans here. ``remote``:
            the base plans on another machine (``dcdp-robot-client`` with LeRobot's stock policy server):
            only its ``config.json`` and processor files are read here (not its weights, so their hash is
            not checked), and every chunk, an episode's first included, comes from the planner attached with
            ``DCDPPolicy.attach_planner`` (``planning='async'``).
    """

    planning: str = "sync"
    planning_clock: str = "wall"
    planner_cpus: list[int] | None = None
    planner_priority: str = "normal"
    ticks_per_step: int = 1
    base_location: str = "local"


@dataclass
class CorrectionOptions:
    """How the corrector corrects: its recipe, the object it may anchor to, the recorded-plan keys, the
    compiled path and the completion gate.

    Args:
        correction: How the corrector produces action s of a chunk. ``residual`` (default; ours, see
            docs/METHOD.md): ``a_s = plan_s + delta(z, plan_s, F_{t+s}, change since plan time, e_s)``
            with delta's last layer zero-initialised (a fresh corrector is exactly open loop). It trains on
            recorded corrections of stale chunks (a dataset with ``plan_feature``, from
            ``dcdp-record-corrections``) or, on plain demonstrations, on synthesised object motion (needs
            ``anchor_feature``; see the
            ``motion_*`` fields). ``reconstruct`` is the paper's recipe (``configs/policy/dcdp_paper.json``):
            the GRU decoder re-decodes the action from z and F_{t+s}, trained to reconstruct demonstration
            chunks; measured to make the base worse on PushT (docs/FINDINGS.md).
        anchor_feature: Observation key holding an object's keypoints as xy pairs, in the same frame as the
            first two action dims (PushT: ``observation.environment_state``). Needed by ``object_anchored``.
        keypoint_reader_path: Folder of a frame -> object-keypoints reader (``dcdp-fit-pixel-keypoints``): the
            pre-processor writes its estimate from the reader's camera to ``anchor_feature`` (or, without one,
            to the key the reader was fitted to), replacing any keypoints the observation holds, so the
            corrector, the anchoring and the gate run from pixels and the env or robot gives no keypoints.
            The corrector then reads the estimate and the other vectors, not the camera (unless
            ``observation_features`` names it). Read when the policy is built for training; a trained folder
            keeps the reader's weights in its pre-processor.
        plan_feature: Dataset key of the chunk the base planned at the chunk start, (L, A) raw actions, in
            recorded corrections (``residual`` training only; never read at inference).
        plan_step_feature: Dataset key of the step index s of a frame within its chunk (``residual``).
        plan_delay_feature: Dataset key of the delay d of a frame's chunk in recorded corrections: steps from
            the observation it was planned from to its first action (``dcdp-record-corrections
            --max-delay``); the plan-time frame is t-s-d. Absent from a dataset: d = 0.
        change_scale: Factor on the change of the (normalised) corrector inputs since plan time before the
            residual head sees it: that change is small next to the inputs' range.
        anchor_input: ``residual`` only: also give the head the ``object_anchored`` proposal for step s (the
            plan carried along with the anchor keypoints' rigid motion), as a change from ``plan_s``. The head
            still starts at zero (open loop) and learns how much of the proposal to take, and what else.
        compiled_kernel: ``residual`` on CPU: run each control step's corrector math as one compiled numba
            kernel (same actions as the modules within float rounding). ``auto`` uses it when it loads and
            falls back to the PyTorch path with one warning when numba cannot import, compile or cache it
            (cache location: ``$DCDP_KERNEL_CACHE``, default ``~/.cache/lerobot_dcdp/numba``); ``on`` raises
            instead of falling back; ``off`` never uses it.
        completion_gate: In ``dcdp`` and ``object_anchored`` (the modes that move the plan): scale each
            step's change of the plan by ``1 - p`` where ``p`` is a learned probability that the task is
            nearly done (``completion_gate.py``), so the final alignment runs the base's own plan. Fitted on
            demonstrations by ``dcdp-fit-completion-gate``, which sets it: after stage 1 (``--policy``), or
            around a bare base for the training-free anchoring (``--base``); ``lerobot-train`` leaves the gate
            as it is. ``false`` on a folder with a fitted gate (one that records ``completion_radius``) runs
            without it. Default False.
        completion_radius: The gate's "nearly done" it was fitted with: the object's keypoints
            (``anchor_feature``) within this mean distance (raw units) of their place on the demonstration's
            last frame. Recorded by ``dcdp-fit-completion-gate`` (by default 0.15 of the object's typical
            travel in the demonstrations); ``None`` before a gate is fitted.
        lead_steps: In ``dcdp`` and ``object_anchored`` (the base in this process): plan and act in a scene
            moved this many planned steps of the object's own recent motion ahead -- the object's keypoints
            (``anchor_feature``) and the robot's xy (``lead_state_feature``) moved together, the actions
            moved back by the current lead -- so a base that
            stops the object at its goal stops it upstream by the motion the world will add, and the world
            carries it in (``scene_lead.py``). 0 (default): off. ``dcdp-fit-completion-gate`` sets it to the
            folder's ``n_action_steps``.
        lead_window: Planned steps of the object's keypoint centroid's per-step displacements in which the
            world's motion is looked for. No lead before a window.
        lead_tolerance: A step repeats a displacement within this fraction of that displacement's length
            (0.05), plus ``lead_noise``.
        lead_repeats: The world's motion is the newest displacement that at least this many of the window's
            steps repeat, itself included (3); the robot's pushes vary from step to step and drop out.
        lead_noise: The object tracker's per-step noise in the keypoints' units, added to every tolerance
            (0: exact, as in simulation). ``dcdp-fit-completion-gate`` measures it on the demonstrations'
            still steps; without it a still object's jittering steps never repeat and the motion found last
            holds.
        lead_in_range: Shorten the lead, per axis, so that no led keypoint leaves the range its coordinate has
            in the base's training data (the base's saved min / max of ``anchor_feature``): the world cannot
            carry the object through the workspace's walls, and the base never saw it beyond them. Default
            True; a base whose statistics lack min / max needs ``false``.
        lead_state_feature: Observation key whose first two dims are the robot's xy in the keypoints' frame
            (the frame of the actions' first two dims), moved with the object by the lead. The base must read
            it and the anchor feature, and no image.
    """

    correction: str = "residual"
    anchor_feature: str | None = None
    keypoint_reader_path: str | None = None
    plan_feature: str = "observation.dcdp_plan"
    plan_step_feature: str = "observation.dcdp_plan_step"
    plan_delay_feature: str = "observation.dcdp_plan_delay"
    change_scale: float = 10.0
    anchor_input: bool = False
    compiled_kernel: str = "auto"
    completion_gate: bool = False
    completion_radius: float | None = None
    lead_steps: int = 0
    lead_window: int = 16
    lead_tolerance: float = 0.05
    lead_repeats: int = 3
    lead_noise: float = 0.0
    lead_in_range: bool = True
    lead_state_feature: str = "observation.state"


@dataclass
class SynthesisOptions:
    """Stage-1 samples on plain demonstrations: the synthesised object motion, and late chunks.

    Args:
        motion_max_speed: ``residual`` on plain demonstrations: the largest synthesised object speed, in the
            anchor keypoints' raw units per control step (speeds are drawn uniformly up to it, in any
            direction). ``None``: 0.6 % of the anchor keypoints' extent in the base's statistics per step
            (PushT: ~2.5 px/step).
        motion_max_turn_deg: ``residual`` on plain demonstrations: the largest synthesised turn rate of the
            object about its keypoint centroid, degrees per control step (uniform in [-max, max]).
        motion_static_fraction: ``residual`` on plain demonstrations: share of synthesised samples without
            motion, whose label is the plan itself (the corrector learns to leave a still scene alone).
        motion_label: ``residual`` on plain demonstrations: the motion a moving sample's label carries the
            plan with. ``observed`` (default): the object's whole rigid motion since plan time as the moved
            keypoints show it (the ``object_anchored`` rule, the object's own motion under the push included;
            still samples keep the plan: the gated teacher of the recorded recipe). ``added``: only the
            synthesised motion (measured to follow the drift alone, which scores below open loop:
            docs/FINDINGS.md). ``graded``: the synthesised motion plus a share of the object's own motion in
            the demonstration (its motion under the push) that grows linearly with how far the synthesised
            motion has carried the object's centroid, from none to all of it at ``motion_full_carry_at``: a
            slowly moving world keeps the plan's pushes, a fast one gets the ``observed`` label.
        motion_full_carry_at: ``motion_label=graded`` only: the displacement of the object's centroid by the
            synthesised motion (raw anchor units) from which the label carries the object's whole observed
            motion. ``None``: ``n_action_steps / 2`` steps of the largest synthesised speed.
        motion_min_carry_speed: ``residual`` on plain demonstrations: synthesised motions whose speed is
            below this (the object's centroid, raw anchor units per control step) keep the plan as their
            label, as still samples do: a world that moves the object this slowly is left to the base's own
            next plan. 0 (default): every synthesised motion is carried.
        motions_per_sample: ``residual`` on plain demonstrations: independent motions drawn per dataset
            sample (the batch is repeated this many times).
        train_max_delay: ``residual`` on plain demonstrations: chunks that arrive late. Each synthesised
            sample draws a delay d in [0, train_max_delay] (within the episode): the chunk was planned from
            the observation d steps before it started being executed (its first d entries skipped), so the
            corrector's plan-time frame is t-s-d while its step is s -- as ``inference_delay`` and
            ``planning='async'`` run it. On recorded corrections: the largest delay the dataset's
            ``plan_delay_feature`` may hold. Lengthens the observation window to max(M, H + train_max_delay).
    """

    motion_max_speed: float | None = None
    motion_max_turn_deg: float = 0.5
    motion_static_fraction: float = 0.25
    motion_label: str = "observed"
    motion_full_carry_at: float | None = None
    motion_min_carry_speed: float = 0.0
    motions_per_sample: int = 4
    train_max_delay: int = 0


@dataclass
class NetworkOptions:
    """The corrector's networks (paper Sec. 3) and the weights of its stage-1 loss terms.

    Args:
        backbone: Per-frame backbone: ``mlp`` for state/keypoint vectors, ``resnet18`` for images,
            ``base_encoder`` for images read by the frozen base's own trained image encoder (LeRobot diffusion
            or VQ-BeT; only a linear map on it is trained, nothing of it is saved with the corrector),
            ``auto``: ``mlp`` for vectors only; for a camera, ``base_encoder`` where the base lends one
            image encoder here (without ``image_backbone_weights``), else ``resnet18``; the trained folder
            saves the choice.
        observation_features: Observation keys the corrector reads; empty = every observation input of the
            dataset or env (the recorded plan keys excepted).
        feature_dim: Width of the per-frame tokens and of the dynamic feature F.
        state_hidden_dim: Hidden width of the MLP backbone.
        n_heads: Attention heads of the temporal self-attention and the diff cross-attention.
        image_backbone_weights: Optional local file with a torchvision ResNet18 ``state_dict`` (nothing is
            downloaded; random weights when unset).
        freeze_image_backbone: Keep the ResNet18 trunk frozen (authors: frozen ImageNet weights).
        alpha_init: Initial value of the learnable differential scale alpha (D = alpha (X_{k+1} - X_k)).
        use_temporal_attention: Ablation flag TA (paper Table 3).
        use_diff_cross_attention: Ablation flag DCA (paper Table 3).
        use_diff_loss: Ablation flag SSD: the self-supervised loss L_diff (paper Table 3).
        latent_dim: Size of the chunk latent z (authors' code: 2, the paper preset's value).
        encoder_hidden_dim: Hidden width of the chunk encoder E.
        decoder_hidden_dim: Hidden width of the correction head: the residual head's MLP (``residual``) or the
            GRU decoder D (``reconstruct``; authors' code: 128, the paper preset's value).
        step_embed_dim: Size of the step embedding e_s.
        kl_weight: lambda_KL of the stage-1 loss (authors' code: 1e-3).
        diff_weight: lambda_diff of the stage-1 loss (authors' code: 1e-3).
    """

    backbone: str = "auto"
    observation_features: list[str] = field(default_factory=list)
    feature_dim: int = 128
    state_hidden_dim: int = 128
    n_heads: int = 8
    image_backbone_weights: str | None = None
    freeze_image_backbone: bool = True
    alpha_init: float = 1.0
    use_temporal_attention: bool = True
    use_diff_cross_attention: bool = True
    use_diff_loss: bool = True
    latent_dim: int = 8
    encoder_hidden_dim: int = 128
    decoder_hidden_dim: int = 256
    step_embed_dim: int = 16
    kl_weight: float = 1e-3
    diff_weight: float = 1e-3


#: Every option group, in the order ``DCDPConfig`` inherits them.
@dataclass
class BidOptions:
    """``execution='bid'``: Bidirectional Decoding (Liu et al., ICLR 2025) over the frozen base, a
    training-free peer that samples at test time (``lerobot_dcdp.model.bid_selection``). Defaults: the
    authors' PushT settings.

    Args:
        bid_samples: Chunks sampled from the base at each decision (15); as many from the weak policy.
        bid_modes: The backward-coherence filter keeps ``bid_samples // bid_modes`` candidates of each policy
            (3).
        bid_decay: Weight ratio of consecutive steps in the backward coherence, the nearest step weighing most
            (0.5).
        bid_replan_every: Control steps between two decisions (1: every step, the authors' setting for a
            perturbed world; at most ``n_action_steps``); the chosen chunk is executed in between.
        bid_weak_policy_path: The weak reference policy whose samples the chosen chunk keeps away from (e.g.
            an early checkpoint of the base, with the base's statistics): a ``pretrained_model`` folder. None:
            backward coherence and the positive term only.
    """

    bid_samples: int = 15
    bid_modes: int = 3
    bid_decay: float = 0.5
    bid_replan_every: int = 1
    bid_weak_policy_path: str | None = None


OPTION_GROUPS = (
    ExecutionOptions,
    PlanningOptions,
    CorrectionOptions,
    SynthesisOptions,
    NetworkOptions,
    BidOptions,
)
