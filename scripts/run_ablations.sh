#!/usr/bin/env bash
# Paper Table 3: stage 1 retrained with one component off at a time, on top of the shipped recipe
# (block-keypoint features, latent 8). Every run uses the same 3000-step cosine schedule as the shipped
# corrector; the comparison is made at the step-2000 checkpoints of all four runs (same schedule so far).
# Usage: scripts/run_ablations.sh train   -> trains runs/ablate_{no_ta,no_dca,no_ssd}
#        scripts/run_ablations.sh eval    -> dcdp-benchmark on static and constant 0.5 at step 2000
set -euo pipefail
RECIPE=(--policy.observation_features='["observation.environment_state"]' --policy.latent_dim=8)
case ${1:-} in
  train)
    for v in no_ta:use_temporal_attention no_dca:use_diff_cross_attention no_ssd:use_diff_loss; do
      name=${v%%:*}; flag=${v#*:}
      STEPS=3000 OMP_NUM_THREADS=1 nohup scripts/train_corrector.sh models/pusht-diffusion-state "runs/ablate_$name" \
        "${RECIPE[@]}" "--policy.$flag=false" > "runs_ablate_$name.log" 2>&1 &
    done
    wait ;;
  eval)
    ck=checkpoints/002000/pretrained_model
    OMP_NUM_THREADS=1 .venv/bin/dcdp-benchmark --methods dcdp --conditions static constant_0.5 --latency-steps 0 \
      --videos 0 --out results/ablation.json --report docs/ABLATION_RESULTS.md \
      --model full@2000=runs/dcdp_diffusion/$ck --model no_TA@2000=runs/ablate_no_ta/$ck \
      --model no_DCA@2000=runs/ablate_no_dca/$ck --model no_SSD@2000=runs/ablate_no_ssd/$ck ;;
  *) echo "usage: $0 {train|eval}" >&2; exit 2 ;;
esac
