#!/usr/bin/env bash
# Stage 1: trains a DCDP corrector for a shipped base with the stock lerobot-train (CPU, seed 1000).
# Usage: scripts/recipes/train_corrector.sh <base dir> <output dir> [extra lerobot-train flags]
# e.g.   scripts/recipes/train_corrector.sh models/pusht-diffusion-state runs/dcdp_diffusion
set -euo pipefail
base=$1; out=$2; shift 2
exec .venv/bin/lerobot-train --policy.type=dcdp --policy.base_policy_path="$base" \
  --dataset.repo_id=local/pusht_expert --dataset.root="${DATA:-data/pusht_expert}" \
  --policy.device=cpu --policy.push_to_hub=false --wandb.enable=false --num_workers=1 --seed=1000 \
  --policy.optimizer_lr=3e-4 --batch_size=64 --steps=${STEPS:-5000} --save_freq=1000 --log_freq=250 \
  --output_dir="$out" "$@"
