#!/usr/bin/env bash
# A corrector from plain demonstrations alone (no simulator, no recorded plan): stage 1 with the stock
# lerobot-train on the PushT expert demonstrations; the residual head learns to carry the base's plan along
# with synthesised rigid motions of the block keypoints (configs/policy/dcdp_demos.json, docs/METHOD.md).
# Usage: scripts/recipes/make_demos_corrector.sh [base dir] [output dir] [extra lerobot-train flags]
# Env: DATA (data/pusht_expert), REPO (local/pusht_expert), STEPS (the config's 2000).
# Data: .venv/bin/dcdp-pusht-demos --root data/pusht_expert --repo-id local/pusht_expert --episodes 200 --seed 0
# Then copy <output dir>/checkpoints/last/pretrained_model next to the base (models/README.md).
set -euo pipefail
base=${1:-models/pusht-diffusion-state}; out=${2:-runs/dcdp_demos}; shift $(( $# > 2 ? 2 : $# ))
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
if [ -f "$out/checkpoints/last/pretrained_model/train_config.json" ]; then  # a cut-off run resumes
  exec .venv/bin/lerobot-train --resume=true \
    --config_path="$out/checkpoints/last/pretrained_model/train_config.json" "$@"
fi
exec .venv/bin/lerobot-train --config_path=configs/policy/dcdp_demos.json \
  --policy.base_policy_path="$base" --dataset.repo_id="${REPO:-local/pusht_expert}" \
  --dataset.root="${DATA:-data/pusht_expert}" --steps="${STEPS:-2000}" --output_dir="$out" "$@"
