#!/usr/bin/env bash
# Trains the shipped image base (models/pusht-diffusion-image) with the stock lerobot-train on CPU.
# LeRobot's PushT image recipe (96x96 frames, random 84x84 crop, ResNet18 from scratch with GroupNorm, horizon 16,
# 8 executed), made cheaper for two CPU cores: 1 observation step (the encoder, ~75 % of an update, runs on half the
# frames) and the keypoint base's 64-128-256 U-Net, batch 32: ~1.0 s per update instead of 2.1 s (docs/FINDINGS.md).
# 40 000 updates of 32 samples: the samples of LeRobot's 20 000 at batch 64 (58 % on its published curve).
# Usage: scripts/recipes/train_image_base.sh [extra lerobot-train flags]
#   resume a cut-off run:  .venv/bin/lerobot-train --resume=true \
#       --config_path=$OUT/checkpoints/last/pretrained_model/train_config.json
# Data (no keypoints: the base reads observation.image + observation.state only):
#   .venv/bin/dcdp-pusht-demos --root $DATA --repo-id local/pusht_image --episodes 200 --seed 0 \
#       --images --no-keypoints --workers 2
set -euo pipefail
DATA=${DATA:-data/pusht_image}
OUT=${OUT:-runs/image_base}
# 2 threads that sleep when they wait (PASSIVE): 1.3 s per update on an idle box, 2.0 s beside another 1-thread job;
# OpenMP's default spinning made that 36 s (docs/FINDINGS.md, "From pixels")
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2} OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE} GOMP_SPINCOUNT=${GOMP_SPINCOUNT:-0}
exec .venv/bin/lerobot-train --policy.type=diffusion \
  --dataset.repo_id=${REPO:-local/pusht_image} --dataset.root="$DATA" \
  --policy.device=cpu --policy.push_to_hub=false --wandb.enable=false --num_workers=1 --seed=1000 \
  --policy.horizon=16 --policy.n_obs_steps=1 --policy.n_action_steps=8 --policy.drop_n_last_frames=8 \
  --policy.down_dims='[64,128,256]' --policy.diffusion_step_embed_dim=64 --policy.pretrained_backbone_weights=null --policy.use_group_norm=true \
  --policy.crop_shape='[84,84]' --policy.noise_scheduler_type=DDIM --policy.num_train_timesteps=100 \
  --policy.num_inference_steps=10 --batch_size=32 --steps=${STEPS:-40000} --save_freq=${SAVE_FREQ:-500} --log_freq=100 \
  --output_dir="$OUT" "$@"
