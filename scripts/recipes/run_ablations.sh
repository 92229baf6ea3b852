#!/usr/bin/env bash
# Paper Table 3: stage 1 retrained with one component off at a time, on top of the shipped recipe
# (block-keypoint features, latent 8). Every run uses the same 3000-step cosine schedule as the shipped
# corrector; the comparison is made at the step-$AT checkpoints of all four runs (same schedule so far;
# AT=1000 by default: each ablation run is stopped once its step-$AT checkpoint is written).
# Usage: scripts/recipes/run_ablations.sh train   -> trains runs/ablate_{no_ta,no_dca,no_ssd}
#        scripts/recipes/run_ablations.sh eval    -> dcdp-benchmark on static and constant 0.5 at step $AT
set -euo pipefail
AT=${AT:-1000}
CK=$(printf "checkpoints/%06d/pretrained_model" "$AT")
RECIPE=(--policy.observation_features='["observation.environment_state"]' --policy.latent_dim=8)
case ${1:-} in
  train)
    declare -A PIDS
    for v in no_ta:use_temporal_attention no_dca:use_diff_cross_attention no_ssd:use_diff_loss; do
      name=${v%%:*}; flag=${v#*:}
      STEPS=3000 OMP_NUM_THREADS=1 nohup scripts/recipes/train_corrector.sh models/pusht-diffusion-state "runs/ablate_$name" \
        "${RECIPE[@]}" "--policy.$flag=false" > "runs_ablate_$name.log" 2>&1 &
      PIDS[$name]=$!   # the run this script started (train_corrector.sh execs lerobot-train)
    done
    for name in no_ta no_dca no_ssd; do   # stop each run once its step-$AT checkpoint is complete
      until [ -f "runs/ablate_$name/$CK/model.safetensors" ] && [ -L "runs/ablate_$name/checkpoints/last" ] \
            && [ "$(readlink -f runs/ablate_$name/checkpoints/last)" = "$(readlink -f "runs/ablate_$name/$CK/..")" ]; do
        sleep 5
      done
      kill "${PIDS[$name]}" 2>/dev/null || true   # only the process this script started
    done ;;
  eval)
    ck=$CK
    OMP_NUM_THREADS=1 .venv/bin/dcdp-benchmark --methods dcdp --conditions static constant_0.5 --latency-steps 0 \
      --videos 0 --out results/ablation.json --report docs/ABLATION_RESULTS.md \
      --model full@$AT=runs/dcdp_diffusion/$ck --model no_TA@$AT=runs/ablate_no_ta/$ck \
      --model no_DCA@$AT=runs/ablate_no_dca/$ck --model no_SSD@$AT=runs/ablate_no_ssd/$ck ;;
  *) echo "usage: $0 {train|eval}" >&2; exit 2 ;;
esac
