#!/usr/bin/env bash
# The shipped PushT corrector (models/pusht-dcdp-state), end to end with its exact flags:
#   1. record stale chunks of the frozen base + the teacher's corrections (200 training episodes, seeds
#      0..199, random/constant block drift of U[0, 2.5] px/step, 30 % without drift); the teacher
#      `anchored_when_drifting` carries the plan with the block's motion in drifting episodes and leaves it
#      alone (open loop drives) in the others (docs/ANALYSIS.md, attempts 6 and 11);
#   2. stage 1 with the stock lerobot-train (CPU, seed 1000): residual head reading block keypoints and the
#      agent position (it has to tell drift from its own pushing).
# Usage: scripts/make_residual_corrector.sh [base dir] [output dir] [extra lerobot-train flags]
# Env: TEACHER (anchored_when_drifting), STATIC_FRACTION (0.3), FEATURES (keypoints + agent), EPISODES (200),
#      STEPS (1000), DATA (data/pusht_corrections). The issue-9 corrector (attempt 5): TEACHER=object_anchored
#      STATIC_FRACTION=0.1 FEATURES='["observation.environment_state"]'.
# Then copy <output dir>/checkpoints/last/pretrained_model next to the base and point its config's
# base_policy_path at the base relative to it (saved checkpoints record it relative to themselves).
set -euo pipefail
base=${1:-models/pusht-diffusion-state}; out=${2:-runs/dcdp_residual}; shift $(( $# > 2 ? 2 : $# ))
data=${DATA:-data/pusht_corrections}
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
.venv/bin/dcdp-record-corrections --root "$data" --repo-id local/pusht_corrections --base "$base" \
  --episodes "${EPISODES:-200}" --seed 0 --teacher "${TEACHER:-anchored_when_drifting}" \
  --static-fraction "${STATIC_FRACTION:-0.3}" --force
exec .venv/bin/lerobot-train --config_path=configs/policy/dcdp_pusht_residual.json \
  --policy.base_policy_path="$base" --dataset.repo_id=local/pusht_corrections --dataset.root="$data" \
  --policy.observation_features="${FEATURES:-[\"observation.environment_state\",\"observation.state\"]}" \
  --num_workers=2 --steps="${STEPS:-1000}" --output_dir="$out" "$@"
