"""``dcdp-record-corrections``: stale chunks and a teacher's corrections of them, as a LeRobotDataset v3.

The training signal of the ``residual`` corrector (docs/METHOD.md): the frozen base runs as it does at
deployment -- one chunk every H steps -- on PushT with the T block drifting (``pusht_perturbed``, the default;
``--env.type=<any registered LeRobot env>`` with its ``--env.*`` flags runs that env as configured), and every
executed step is labelled with what a teacher would do with the stale chunk. Per frame the dataset holds

- every vector observation the policy and its base read (raw; PushT: ``observation.state``,
  ``observation.environment_state``);
- ``observation.dcdp_plan`` (L * A,) and ``observation.dcdp_plan_step`` (1,): the chunk as the base planned
  it at the chunk start (flattened, so LeRobot's ``merge_datasets`` can aggregate DAgger rounds), and the
  step s of this frame in it;
- ``observation.dcdp_plan_delay`` (1,): the chunk's delay d, steps from the observation it was planned from
  to its first action (``--max-delay D``: episode k's base answers d = k mod (D + 1) steps late, as
  ``--policy.inference_delay`` runs it; train with ``--policy.train_max_delay >= D``);
- ``action``: the teacher's action for step s; ``executed_action``: what was actually sent to the env;
- ``next.reward``, ``next.success``, ``next.done``.

Teachers:

- ``object_anchored``: the planned action carried along with the least-squares rigid motion of the block
  keypoints since plan time (the policy's training-free ``object_anchored`` mode), measured ``lookahead``
  steps later (hindsight: the recorded future is known, so ``lookahead > 0`` labels the action that
  anticipates where the block will be; a learned corrector must predict that from its history).
- ``anchored_when_drifting`` (privileged: it knows the episode's drift): the same, but in episodes without
  drift the label is the plan itself -- where only the pusher moves the block, the chunk needs no correction
  (anchoring would add the block's push-induced motion to a plan that already expects it) -- and those
  episodes are driven open loop (unless ``execution`` is ``dcdp``). The student has to tell drift from
  pushing from its observations. ``--ramp r``: the share of the correction grows linearly with the
  episode's drift magnitude, full from r px/step on.
- ``drift_offset`` (privileged: it reads the offsets the env applied): ``plan_s`` translated by the drift
  alone, summed from plan time to the observation ``lookahead`` steps after this one. The drift is a pure
  translation of the block (``pusht_perturbed``), so this is the exact exogenous part of the block's motion:
  the push-induced motion the plan already expects is left alone, in every episode, static or not. The
  student has to tell drift from pushing from its observations.
- ``expert`` (privileged, PushT): the scripted expert re-planning every 8 steps from the block's exact pose
  (read from its keypoints): the registered ``pusht_expert`` teleoperator with its defaults, as a labeller.
  With ``--execution dcdp`` the learner drives and the expert labels the states it visits (DAgger); record
  each round to its own dataset and aggregate them with LeRobot's ``merge_datasets`` (the plan column is flat
  so the stock merge copies it).
- ``teleop``: a LeRobot teleoperator's action for the current observation (``--teleop.type=...`` and its
  ``--teleop.*`` flags): a person's corrections, HG-DAgger style. Two scripted stand-ins for the person are
  registered (:mod:`lerobot_dcdp.sim.teleoperators`): ``pusht_nudge`` corrects the robot's own command
  (shown to it with its chunk step) by carrying it with the block once the world moves the block;
  ``pusht_expert`` drives with pushes of its own. They see the scene through ``send_feedback`` (the
  ``pusht_sim`` observation names). One teleoperator per parallel env.
- ``policy``: a teacher policy's action for the current observation (``--teacher-policy=<pretrained_model
  dir>``, any LeRobot policy type, with its own processors): a privileged or bigger policy.

``execution`` picks who drives the env: ``object_anchored`` (the anchoring), ``open_loop`` (the base),
``dcdp`` (a trained corrector: a DAgger round, visiting the states the learner visits) or ``teacher`` (the
``teleop`` / ``policy`` teacher's own actions: the person drives).

Drift per episode is drawn from the episode's seed: none with probability ``static_fraction``, else constant
(direction uniform on the circle) or random (5 directions drawn uniformly, redrawn every 25/50/100 steps),
with a magnitude uniform in ``[0, max_magnitude]`` px/step. Seeds must stay below the evaluation seeds
(100000..).

Modules: :mod:`.drift` (the drift per episode, the env), :mod:`.labels` (the hindsight teachers' labels),
:mod:`.teachers` (the online teachers), :mod:`.settings` (:class:`RecordingSettings`, checked),
:mod:`.rollout` (the base rolled out as deployed, each step labelled), :mod:`.writer` (the dataset, its
features and its folder marker), :mod:`.recorder` (:func:`record_corrections`: all of it) and :mod:`.cli`
(``dcdp-record-corrections``).
"""

from lerobot_dcdp.data.corrections.cli import main, parse_env_args, parse_teleop_args
from lerobot_dcdp.data.corrections.drift import DriftSpec, drift_for_seed, drift_specs, episode_env
from lerobot_dcdp.data.corrections.labels import anchored_labels, drift_offset_labels, plan_time
from lerobot_dcdp.data.corrections.recorder import record, record_corrections
from lerobot_dcdp.data.corrections.rollout import (
    label_weight,
    load_policy,
    recorded_keys,
    rollout_corrections,
)
from lerobot_dcdp.data.corrections.settings import EXECUTIONS, ONLINE_TEACHERS, TEACHERS, RecordingSettings
from lerobot_dcdp.data.corrections.teachers import PolicyTeacher, TeleopTeacher, make_online_teacher
from lerobot_dcdp.data.corrections.writer import MARKER, PUSHT_NAMES, features

__all__ = [
    "EXECUTIONS",
    "MARKER",
    "ONLINE_TEACHERS",
    "PUSHT_NAMES",
    "TEACHERS",
    "DriftSpec",
    "PolicyTeacher",
    "RecordingSettings",
    "TeleopTeacher",
    "anchored_labels",
    "drift_for_seed",
    "drift_offset_labels",
    "drift_specs",
    "episode_env",
    "features",
    "label_weight",
    "load_policy",
    "main",
    "make_online_teacher",
    "parse_env_args",
    "parse_teleop_args",
    "plan_time",
    "record",
    "record_corrections",
    "recorded_keys",
    "rollout_corrections",
]
