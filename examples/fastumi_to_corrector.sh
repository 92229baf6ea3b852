#!/usr/bin/env bash
# FastUMI episodes -> LeRobotDataset -> (ACT base, unless you bring one) -> DCDP corrector, with the stock CLIs.
#
# Usage: examples/fastumi_to_corrector.sh <fastumi dir> <work dir> [base pretrained_model dir]
#   <fastumi dir>: <task>/episode_<idx>.hdf5 files (or episode_<idx>.hdf5), see docs/FASTUMI.md
#   <work dir>:    gets data/ (the dataset), act/ (the base, if trained here) and dcdp/ (the corrector)
#   base:          a chunking policy already trained on this dataset's features (skips the ACT training)
# Settings (environment variables, defaults in brackets):
#   STEPS [5000] corrector steps, BASE_STEPS [20000] base steps, BATCH [32], IMAGE_SIZE [224] frame side,
#   ACTION [absolute] or delta (dcdp-fastumi-to-lerobot --action), DEVICE [cpu] or cuda,
#   BASE_FLAGS / DCDP_FLAGS: extra lerobot-train flags for the base / corrector (e.g. smaller models).
# Run inside the project's virtualenv (the commands are its console scripts).
set -euo pipefail
[ $# -ge 2 ] || { sed -n '4,7p' "$0" >&2; exit 2; }
input=$1; work=$2; base=${3:-}
STEPS=${STEPS:-5000}; BASE_STEPS=${BASE_STEPS:-20000}; BATCH=${BATCH:-32}; DEVICE=${DEVICE:-cpu}
data=$work/data

# 1. convert: every episode is validated first; the dataset appears only when complete
dcdp-fastumi-to-lerobot --input "$input" --repo-id local/fastumi --root "$data" \
  --image-size "${IMAGE_SIZE:-224}" --action "${ACTION:-absolute}"

common=(--dataset.repo_id=local/fastumi "--dataset.root=$data" "--policy.device=$DEVICE"
  --policy.push_to_hub=false --wandb.enable=false "--batch_size=$BATCH")

# 2. a chunking base (ACT on the wrist camera(s) + TCP pose), unless one was given
if [ -z "$base" ]; then
  # shellcheck disable=SC2086  # BASE_FLAGS is a list of flags
  lerobot-train --policy.type=act "${common[@]}" "--steps=$BASE_STEPS" "--save_freq=$BASE_STEPS" \
    "--output_dir=$work/act" ${BASE_FLAGS:-}
  base=$work/act/checkpoints/last/pretrained_model
fi

# 3. the DCDP corrector around the frozen base (images -> ResNet18 frame encoder, chosen automatically)
# shellcheck disable=SC2086  # DCDP_FLAGS is a list of flags
lerobot-train --policy.type=dcdp "--policy.base_policy_path=$base" "${common[@]}" "--steps=$STEPS" \
  "--save_freq=$STEPS" "--output_dir=$work/dcdp" ${DCDP_FLAGS:-}

echo "corrector: $work/dcdp/checkpoints/last/pretrained_model (base: $base)"
