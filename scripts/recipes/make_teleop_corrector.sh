#!/usr/bin/env bash
# A corrector trained from teleoperated corrections (the person-in-the-loop path, HG-DAgger style), with a
# scripted teleoperator standing in for the person:
#   1. record 200 training episodes (seeds 0..199, random/constant block drift of U[0, 2.5] px/step, STATIC of
#      them without drift): the teleoperator drives (--execution teacher) and its actions label every frame; the
#      frozen base plans its chunk every 8 steps from the same observations (what the person corrected);
#   2. stage 1 with the stock lerobot-train (CPU, seed 1000) -> <output dir>.
# TELEOP picks the person:
#   pusht_nudge  (default) corrects the robot's own command: carries it with the block once the world moves the
#                block (docs/FINDINGS.md, "Teleoperated corrections"); the head reads the keypoints and the agent position.
#   pusht_expert drives with its own pushes (T1-T6: another policy's actions; does not help); the head reads the
#                keypoints only (with the agent position it extrapolates the agent's own motion: docs/FINDINGS.md).
#                This made models/pusht-dcdp-state-teleop (T2).
# Usage: scripts/recipes/make_teleop_corrector.sh [base dir] [output dir] [extra lerobot-train flags]
# Env: TELEOP (pusht_nudge), EPISODES (200), STEPS (1000), DATA (data/<teleop>), STATIC (share of episodes
#      without drift: 0.3 for pusht_nudge, 0.1 for pusht_expert), EXECUTION (teacher; open_loop: the base drives
#      and the person only labels), FEATURES (the head's inputs, per TELEOP above); pusht_expert only: REPLAN (8:
#      the teleoperator's steps between plans), FOLLOW (false; true: --teleop.follow_block: worse, docs/FINDINGS.md).
set -euo pipefail
base=${1:-models/pusht-diffusion-state}; out=${2:-runs/dcdp_teleop}; shift $(( $# > 2 ? 2 : $# ))
teleop=${TELEOP:-pusht_nudge}
case "$teleop" in
  pusht_nudge)
    flags=(--teleop.type=pusht_nudge); static=${STATIC:-0.3}
    features=${FEATURES:-[\"observation.environment_state\",\"observation.state\"]} ;;
  pusht_expert)
    flags=(--teleop.type=pusht_expert --teleop.replan_every="${REPLAN:-8}" --teleop.follow_block="${FOLLOW:-false}")
    static=${STATIC:-0.1}; features=${FEATURES:-[\"observation.environment_state\"]} ;;
  *) echo "TELEOP must be pusht_nudge or pusht_expert, got $teleop" >&2; exit 2 ;;
esac
data=${DATA:-data/$teleop}
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
if [ ! -f "$data/.dcdp_corrections" ]; then
  .venv/bin/dcdp-record-corrections --root "$data" --repo-id "local/$teleop" --base "$base" --seed 0 \
    --episodes "${EPISODES:-200}" --teacher teleop "${flags[@]}" --static-fraction "$static" \
    --execution "${EXECUTION:-teacher}" --batch-size 50
fi
.venv/bin/lerobot-train --config_path=configs/policy/dcdp_pusht_residual.json \
  --policy.base_policy_path="$base" --dataset.repo_id="local/$teleop" --dataset.root="$data" \
  --policy.observation_features="$features" \
  --num_workers=2 --steps="${STEPS:-1000}" --save_freq=250 --output_dir="$out" "$@"
