#!/usr/bin/env bash
# A corrector trained from teleoperated corrections (the person-in-the-loop path, HG-DAgger style), with the
# scripted `pusht_expert` teleoperator standing in for the person:
#   1. record 200 training episodes (seeds 0..199, random/constant block drift of U[0, 2.5] px/step, 10 %
#      without drift): the teleoperator drives (--execution teacher) and its actions label every frame; the
#      frozen base plans its chunk every 8 steps from the same observations (what the person corrected);
#   2. stage 1 with the stock lerobot-train (CPU, seed 1000): residual head reading the block keypoints (with the
#      agent position too it learns to extrapolate the agent's own motion: docs/ANALYSIS.md, T1) -> <output dir>.
#      This is models/pusht-dcdp-state-teleop (T2), which does not help yet.
# Usage: scripts/make_teleop_corrector.sh [base dir] [output dir] [extra lerobot-train flags]
# Env: EPISODES (200), STEPS (1000), DATA (data/pusht_teleop), EXECUTION (teacher; open_loop: the base drives
#      and the person only labels), REPLAN (8: the teleoperator's steps between plans), FEATURES (the keypoints),
#      FOLLOW (false; true: --teleop.follow_block, the person anticipates the block's drift: worse, ANALYSIS T6).
set -euo pipefail
base=${1:-models/pusht-diffusion-state}; out=${2:-runs/dcdp_teleop}; shift $(( $# > 2 ? 2 : $# ))
data=${DATA:-data/pusht_teleop}
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
if [ ! -f "$data/.dcdp_corrections" ]; then
  .venv/bin/dcdp-record-corrections --root "$data" --repo-id local/pusht_teleop --base "$base" --seed 0 \
    --episodes "${EPISODES:-200}" --teacher teleop --teleop.type=pusht_expert \
    --teleop.replan_every="${REPLAN:-8}" --teleop.follow_block="${FOLLOW:-false}" --execution "${EXECUTION:-teacher}" --batch-size 50
fi
.venv/bin/lerobot-train --config_path=configs/policy/dcdp_pusht_residual.json \
  --policy.base_policy_path="$base" --dataset.repo_id=local/pusht_teleop --dataset.root="$data" \
  --policy.observation_features="${FEATURES:-[\"observation.environment_state\"]}" \
  --num_workers=2 --steps="${STEPS:-1000}" --save_freq=250 --output_dir="$out" "$@"
