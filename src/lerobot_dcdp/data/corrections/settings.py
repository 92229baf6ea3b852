"""The settings of one ``dcdp-record-corrections`` recording, checked when they are made.

``execution`` picks who drives the env: ``object_anchored`` (the anchoring), ``open_loop`` (the base),
``dcdp`` (a trained corrector: a DAgger round, visiting the states the learner visits) or ``teacher`` (the
``teleop`` / ``policy`` teacher's own actions: the person drives). ``teacher`` picks who labels each step
(:mod:`.labels` for the hindsight teachers, :mod:`.teachers` for the online ones).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from lerobot_dcdp.data.pusht_demos import EVAL_SEED_START

if TYPE_CHECKING:
    from lerobot.envs.configs import EnvConfig
    from lerobot.teleoperators.config import TeleoperatorConfig

EXECUTIONS = ("object_anchored", "open_loop", "dcdp", "teacher")
TEACHERS = ("object_anchored", "anchored_when_drifting", "drift_offset", "expert", "teleop", "policy")
#: Teachers that label each step online from the current observation (the others label in hindsight).
ONLINE_TEACHERS = ("expert", "teleop", "policy")


@dataclass(frozen=True)
class RecordingSettings:
    """What :func:`~lerobot_dcdp.data.corrections.recorder.record_corrections` records, and where.

    Args:
        root: Output folder of the LeRobotDataset (an existing one must be an earlier output of this command).
        repo_id: Repo id the dataset is written under.
        policy_path: A trained DCDP corrector (its base plans the chunks); exactly one of this and
            ``base_path``.
        base_path: A bare chunking base policy (``pretrained_model`` folder).
        episodes: Episodes to record (>= 1).
        seed: First episode seed; seeds ``seed..seed + episodes - 1`` must stay below the evaluation seeds.
        execution: Who drives the env, one of :data:`EXECUTIONS`.
        teacher: Who labels each step, one of :data:`TEACHERS`.
        lookahead: Hindsight teachers: the block pose (or drift) is taken this many steps later (>= 0).
        max_magnitude: ``pusht_perturbed``: drift magnitude ~ U[0, this] px/step (>= 0).
        static_fraction: ``pusht_perturbed``: share of episodes without drift, in [0, 1].
        batch_size: Envs rolled out together (>= 1).
        max_steps: Step limit of an episode (>= 1).
        force: Overwrite an earlier output at ``root``.
        progress: Show a progress bar.
        ramp: ``anchored_when_drifting``: the share of the correction grows linearly with the episode's drift
            magnitude, full from this many px/step on (0: full for any drift; >= 0).
        teleop_config: ``teacher='teleop'``: a LeRobot ``TeleoperatorConfig`` (one teleoperator per env).
        teacher_policy: ``teacher='policy'``: a ``pretrained_model`` folder of any LeRobot policy.
        env_config: A LeRobot ``EnvConfig``; ``None``: ``pusht_perturbed`` with keypoint observations.
            ``pusht_perturbed`` episodes get the drift drawn per episode, any other env type runs as
            configured.
        anchor_feature: Observation key of the object's xy keypoints (the anchoring teachers).
        max_delay: Late chunks D: the base of episode ``seed + k`` answers d = k mod (D + 1) steps late
            (``inference_delay``; the first chunk of an episode is on time; >= 0).

    Raises:
        ValueError: naming the bad field (or the pair of fields that do not go together).
    """

    root: str | Path
    repo_id: str = "local/pusht_corrections"
    policy_path: str | None = None
    base_path: str | None = None
    episodes: int = 200
    seed: int = 0
    execution: str = "object_anchored"
    teacher: str = "object_anchored"
    lookahead: int = 0
    max_magnitude: float = 2.5
    static_fraction: float = 0.1
    batch_size: int = 50
    max_steps: int = 300
    force: bool = False
    progress: bool = True
    ramp: float = 0.0
    teleop_config: TeleoperatorConfig | None = None
    teacher_policy: str | Path | None = None
    env_config: EnvConfig | None = None
    anchor_feature: str = "observation.environment_state"
    max_delay: int = 0

    def __post_init__(self) -> None:
        self._check_choices()
        self._check_teacher_inputs()
        self._check_ranges()

    @property
    def drifting(self) -> bool:
        """Whether the env is ``pusht_perturbed`` (the default), whose episodes get a drift drawn per seed."""
        from lerobot_dcdp.sim.envs.pusht_perturbed import PushTPerturbedEnvConfig

        return self.env_config is None or isinstance(self.env_config, PushTPerturbedEnvConfig)

    @property
    def seeds(self) -> list[int]:
        """The episode seeds, one per episode."""
        return list(range(self.seed, self.seed + self.episodes))

    def _check_choices(self) -> None:
        if self.execution not in EXECUTIONS:
            raise ValueError(f"execution must be one of {EXECUTIONS}, got {self.execution!r}")
        if self.teacher not in TEACHERS:
            raise ValueError(f"teacher must be one of {TEACHERS}, got {self.teacher!r}")
        if self.episodes < 1 or self.batch_size < 1 or self.max_steps < 1:
            raise ValueError(
                "episodes, batch_size, max_steps must be >= 1, "
                f"got {self.episodes}, {self.batch_size}, {self.max_steps}"
            )
        if self.ramp < 0:
            raise ValueError(f"ramp must be >= 0, got {self.ramp}")

    def _check_teacher_inputs(self) -> None:
        teacher = self.teacher
        if teacher == "teleop" and self.teleop_config is None:
            raise ValueError(
                "teacher='teleop' needs a teleoperator: --teleop.type=<type> (e.g. pusht_expert)"
            )
        if teacher == "policy" and self.teacher_policy is None:
            raise ValueError("teacher='policy' needs --teacher-policy=<pretrained_model folder>")
        if teacher != "teleop" and self.teleop_config is not None:
            raise ValueError(f"--teleop.* is given but teacher={teacher!r}: pass --teacher=teleop")
        if teacher != "policy" and self.teacher_policy is not None:
            raise ValueError(f"--teacher-policy is given but teacher={teacher!r}: pass --teacher=policy")
        if teacher == "drift_offset" and not self.drifting:
            raise ValueError(
                f"teacher='drift_offset' reads the drift pusht_perturbed applies; env type "
                f"{self.env_config.type!r} has none (use object_anchored, policy or teleop)"
            )
        if self.execution == "teacher" and teacher not in ONLINE_TEACHERS:
            raise ValueError(
                f"execution='teacher' lets the teacher drive, which needs teacher in {ONLINE_TEACHERS}; "
                f"teacher={teacher!r} drives with execution='object_anchored'"
            )

    def _check_ranges(self) -> None:
        if self.lookahead < 0:
            raise ValueError(f"lookahead must be >= 0, got {self.lookahead}")
        if self.max_delay < 0:
            raise ValueError(f"max_delay must be >= 0 control steps, got {self.max_delay}")
        if not self.max_magnitude >= 0 or not 0.0 <= self.static_fraction <= 1.0:
            raise ValueError(
                "max_magnitude must be >= 0 and static_fraction in [0, 1], "
                f"got {self.max_magnitude}, {self.static_fraction}"
            )
        if self.seed < 0 or self.seed + self.episodes > EVAL_SEED_START:
            raise ValueError(
                f"seeds {self.seed}..{self.seed + self.episodes - 1} must stay in [0, {EVAL_SEED_START}): "
                "the evaluation seeds are never trained on"
            )
