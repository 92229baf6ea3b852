#!/usr/bin/env bash
# The paper's own recipe on images (issue 49, item 4): the reconstruction corrector (configs/policy/dcdp_paper.json)
# trained on static image demonstrations, reading the camera only. The paper freezes an ImageNet ResNet18, which
# cannot be downloaded here; its stand-in is the frozen base's own trained image encoder
# (--policy.backbone=base_encoder: only a linear map on its features is trained).
#   1. the base encoder's features per frame as a column (dcdp-precompute-base-features: training then reads
#      vectors; the trained folder encodes the camera itself at run time);
#   2. stage 1 with the stock lerobot-train, 3 000 steps as the keypoint paper-recipe folder.
# Usage: scripts/recipes/make_image_paper_recipe.sh <base dir> <output dir> [extra lerobot-train flags]
# Env: DATA (data/pusht_image: the image base's demonstrations), STEPS (3000).
# Then copy <output dir>/checkpoints/last/pretrained_model next to the base (models/README.md).
set -euo pipefail
base=$1; out=$2; shift 2
data=${DATA:-data/pusht_image}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} HF_HUB_OFFLINE=1
enc=${data}_enc_$(sha256sum "$base/model.safetensors" | cut -c1-12)  # the features of this base's weights
[ -d "$enc" ] || .venv/bin/dcdp-precompute-base-features --base "$base" --repo-id local/pusht_image \
  --root "$data" --out-repo-id local/pusht_image_enc --out-root "$enc" --drop-cameras
exec .venv/bin/lerobot-train --config_path=configs/policy/dcdp_paper.json \
  --policy.base_policy_path="$base" --dataset.repo_id=local/pusht_image_enc --dataset.root="$enc" \
  --policy.backbone=base_encoder --policy.observation_features='["observation.image"]' \
  --steps="${STEPS:-3000}" --save_freq=1000 --num_workers=1 --output_dir="$out" "$@"
