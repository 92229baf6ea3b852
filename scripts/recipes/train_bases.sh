#!/usr/bin/env bash
# Trains the two shipped PushT base policies with the stock lerobot-train on CPU (seed 1000).
# Usage: scripts/recipes/train_bases.sh {diffusion|diffusion-continue|act|act-continue} [extra lerobot-train flags,
#        e.g. --resume=true]
#   diffusion-continue FROM: 10 000 more steps from the weights in FROM (a pretrained_model dir), lr 1e-4 cosine
#   act-continue FROM: 8 000 more steps from the ACT weights in FROM on $DATA (e.g. demonstrations merged with
#     takeover episodes, see models/README.md), lr 1e-4 as the ACT recipe
#   act-dagger: the shipped ACT base (models/pusht-act-state): 4 encoder / 2 decoder layers, no dropout, AdamW
#     peak 5e-4 with cosine decay, 12 000 steps, on the demonstrations merged with two rounds of takeover
#     episodes (DATA=data/pusht_act_dagger2 REPO=local/pusht_act_dagger2; how: models/README.md)
# Data: .venv/bin/dcdp-pusht-demos --root data/pusht_expert --episodes 500 --seed 0 --workers 2
set -euo pipefail
kind=$1; shift
DATA=${DATA:-data/pusht_expert}  # REPO: its repo id (default local/pusht_expert)
common=(--dataset.repo_id=${REPO:-local/pusht_expert} --dataset.root="$DATA" --policy.device=cpu --policy.push_to_hub=false
        --wandb.enable=false --num_workers=1 --seed=1000 --log_freq=200)
case $kind in
  diffusion)
    exec .venv/bin/lerobot-train --policy.type=diffusion "${common[@]}" \
      --policy.horizon=16 --policy.n_obs_steps=2 --policy.n_action_steps=8 --policy.drop_n_last_frames=7 \
      --policy.down_dims='[64,128,256]' --policy.diffusion_step_embed_dim=64 \
      --policy.noise_scheduler_type=DDIM --policy.num_train_timesteps=100 --policy.num_inference_steps=10 \
      --policy.normalization_mapping='{"VISUAL": "MEAN_STD", "STATE": "MIN_MAX", "ENV": "MIN_MAX", "ACTION": "MIN_MAX"}' \
      --policy.optimizer_lr=3e-4 --batch_size=64 --steps=10000 --save_freq=2000 \
      --output_dir=${OUT:-runs/diffusion_base} "$@" ;;
  diffusion-continue)
    from=$1; shift
    exec .venv/bin/lerobot-train --policy.path="$from" "${common[@]}" \
      --policy.optimizer_lr=1e-4 --batch_size=64 --steps=10000 --save_freq=2000 \
      --output_dir=${OUT:-runs/diffusion_base_continued} "$@" ;;
  act)
    # ENV: LeRobot's ACT mapping has no entry for environment_state, which would reach it raw (0..512 px)
    exec .venv/bin/lerobot-train --policy.type=act "${common[@]}" \
      --policy.normalization_mapping='{"VISUAL": "MEAN_STD", "STATE": "MEAN_STD", "ENV": "MEAN_STD", "ACTION": "MEAN_STD"}' \
      --policy.chunk_size=16 --policy.n_action_steps=8 --policy.dim_model=128 --policy.n_heads=4 \
      --policy.dim_feedforward=512 --policy.n_encoder_layers=2 --policy.n_decoder_layers=1 \
      --policy.n_vae_encoder_layers=2 --policy.latent_dim=16 --policy.optimizer_lr=1e-4 \
      --policy.pretrained_backbone_weights=null \
      --batch_size=64 --steps=10000 --save_freq=2000 \
      --output_dir=${OUT:-runs/act_base} "$@" ;;
  act-continue)
    from=$1; shift
    exec .venv/bin/lerobot-train --policy.path="$from" "${common[@]}" \
      --policy.optimizer_lr=1e-4 --batch_size=64 --steps=8000 --save_freq=2000 \
      --output_dir=${OUT:-runs/act_continued} "$@" ;;
  act-dagger)
    exec .venv/bin/lerobot-train --policy.type=act "${common[@]}" \
      --policy.normalization_mapping='{"VISUAL": "MEAN_STD", "STATE": "MEAN_STD", "ENV": "MEAN_STD", "ACTION": "MEAN_STD"}' \
      --policy.chunk_size=16 --policy.n_action_steps=8 --policy.dim_model=128 --policy.n_heads=4 \
      --policy.dim_feedforward=512 --policy.n_encoder_layers=4 --policy.n_decoder_layers=2 \
      --policy.n_vae_encoder_layers=2 --policy.latent_dim=16 --policy.pretrained_backbone_weights=null \
      --policy.dropout=0.0 --batch_size=64 --steps=12000 --save_freq=4000 \
      --use_policy_training_preset=false --optimizer.type=adamw --optimizer.lr=5e-4 \
      --optimizer.weight_decay=1e-4 --optimizer.grad_clip_norm=10 --scheduler.type=cosine_decay_with_warmup \
      --scheduler.num_warmup_steps=500 --scheduler.num_decay_steps=12000 --scheduler.peak_lr=5e-4 \
      --scheduler.decay_lr=1e-5 --output_dir=${OUT:-runs/act_dagger} "$@" ;;
  *) echo "usage: $0 {diffusion|diffusion-continue FROM|act|act-continue FROM|act-dagger}" >&2; exit 2 ;;
esac
