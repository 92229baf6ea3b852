#!/usr/bin/env bash
# The shipped PushT corrector (models/pusht-dcdp-state), end to end with its exact flags:
#   1. record stale chunks of the frozen base + the teacher's corrections (200 training episodes, seeds
#      0..199, random/constant block drift of U[0, 2.5] px/step, 30 % without drift); the teacher
#      `anchored_when_drifting` carries the plan with the block's motion in drifting episodes and leaves it
#      alone (open loop drives) in the others (docs/FINDINGS.md, "Recorded corrections");
#   2. stage 1 with the stock lerobot-train (CPU, seed 1000): residual head reading block keypoints and the
#      agent position (it has to tell drift from its own pushing) -> <output dir>;
#   3. one DAgger round (DAGGER=1, the default): the corrector of step 2 drives 200 more episodes (seeds
#      200..399), the same teacher labels them, and a fresh corrector is trained on those alone with the same
#      flags -> <output dir>_dagger, the shipped one (attempt 12).
# Usage: scripts/recipes/make_residual_corrector.sh [base dir] [output dir] [extra lerobot-train flags]
# Env: TEACHER (anchored_when_drifting), STATIC_FRACTION (0.3), FEATURES (keypoints + agent), EPISODES (200),
#      STEPS (1000), DATA (data/pusht_corrections; the DAgger round writes ${DATA}_dagger), DAGGER (1 or 0),
#      RECORD_FLAGS (extra dcdp-record-corrections flags, e.g. "--max-delay 4 --execution open_loop" with the
#      lerobot-train flag --policy.train_max_delay=4: chunks up to 4 steps late, the base driving; see
#      docs/FINDINGS.md).
#      The issue-9 corrector (attempt 5): TEACHER=object_anchored STATIC_FRACTION=0.1
#      FEATURES='["observation.environment_state"]' DAGGER=0.
# Then copy the last run's checkpoints/last/pretrained_model next to the base and point its config's
# base_policy_path at the base relative to it (saved checkpoints record it relative to themselves).
set -euo pipefail
base=${1:-models/pusht-diffusion-state}; out=${2:-runs/dcdp_residual}; shift $(( $# > 2 ? 2 : $# ))
data=${DATA:-data/pusht_corrections}
episodes=${EPISODES:-200}
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
labels=(--repo-id local/pusht_corrections --episodes "$episodes" --teacher "${TEACHER:-anchored_when_drifting}"
        --static-fraction "${STATIC_FRACTION:-0.3}" --force ${RECORD_FLAGS:-})
train() {  # train <dataset root> <output dir> [extra flags]
  local root=$1 dir=$2; shift 2
  .venv/bin/lerobot-train --config_path=configs/policy/dcdp_pusht_residual.json \
    --policy.base_policy_path="$base" --dataset.repo_id=local/pusht_corrections --dataset.root="$root" \
    --policy.observation_features="${FEATURES:-[\"observation.environment_state\",\"observation.state\"]}" \
    --num_workers=2 --steps="${STEPS:-1000}" --output_dir="$dir" "$@"
}
.venv/bin/dcdp-record-corrections --root "$data" --base "$base" --seed 0 "${labels[@]}"
train "$data" "$out" "$@"
if [ "${DAGGER:-1}" = 1 ]; then
  .venv/bin/dcdp-record-corrections --root "${data}_dagger" --policy "$out/checkpoints/last/pretrained_model" \
    --execution dcdp --seed "$episodes" "${labels[@]}"
  train "${data}_dagger" "${out}_dagger" "$@"
fi
