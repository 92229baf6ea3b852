#!/usr/bin/env bash
# An image corrector: the object's keypoints read from the camera by a small reader in the pre-processor, and the
# demonstrations recipe (synthesised block motion) on them. Nothing at run time reads the simulator's keypoints.
#   1. demonstrations with frames and the simulator's keypoints (the reader's targets; training time only);
#   2. the frame -> keypoints reader (dcdp-fit-pixel-keypoints), held-out error printed;
#   3. its estimate per frame as a column (dcdp-precompute-keypoints --drop-cameras: training reads vectors);
#   4. stage 1 with the stock lerobot-train: configs/policy/dcdp_demos.json with the estimate as the anchor and
#      the only corrector input, the reader in the pre-processor (--policy.keypoint_reader_path).
# Usage: scripts/recipes/make_image_corrector.sh <base dir> <output dir> [extra lerobot-train flags]
# Env: DATA (data/pusht_image_kp), READER (runs/pusht_keypoint_reader), SPEED (motion_max_speed, px/step: the
#      keypoint base's default, 0.6 % of its keypoint extent), STEPS (1000).
# Then copy <output dir>/checkpoints/last/pretrained_model next to the base (models/README.md).
set -euo pipefail
base=$1; out=$2; shift 2
data=${DATA:-data/pusht_image_kp}; reader=${READER:-runs/pusht_keypoint_reader}
export OMP_NUM_THREADS=1 HF_HUB_OFFLINE=1
[ -d "$data" ] || .venv/bin/dcdp-pusht-demos --root "$data" --repo-id local/pusht_image_kp --episodes 120 \
  --seed 20000 --images --workers 2
[ -d "$reader" ] || .venv/bin/dcdp-fit-pixel-keypoints --repo-id local/pusht_image_kp --root "$data" \
  --out "$reader" --steps 4000 --val-episodes 12
[ -d "${data}_est" ] || .venv/bin/dcdp-precompute-keypoints --reader "$reader" --repo-id local/pusht_image_kp \
  --root "$data" --out-repo-id local/pusht_image_kp_est --out-root "${data}_est" \
  --output-key observation.kp_estimate --drop-cameras
exec .venv/bin/lerobot-train --config_path=configs/policy/dcdp_demos.json \
  --policy.base_policy_path="$base" --dataset.repo_id=local/pusht_image_kp_est --dataset.root="${data}_est" \
  --policy.anchor_feature=observation.kp_estimate --policy.observation_features='["observation.kp_estimate"]' \
  --policy.keypoint_reader_path="$reader" --policy.motion_max_speed="${SPEED:-2.6894208984375}" \
  --steps="${STEPS:-1000}" --save_freq=250 --output_dir="$out" "$@"
