#!/usr/bin/env bash
# FastUMI episodes -> LeRobotDataset -> (ACT base, unless you bring one) -> DCDP corrector, with the stock CLIs.
#
# What a FastUMI user can train. FastUMI records the wrist camera(s) and the gripper's pose, not the pose of the
# object being handled. The corrector that helps (correction=residual, the default) learns from
#   - an object's xy keypoints among the observations (ANCHOR=<observation key>): stage 1 synthesises the
#     object's motion on these demonstrations (docs/METHOD.md); FastUMI data has none unless you add them;
#   - or a person's corrections of the frozen base on the robot (HG-DAgger style): record a session with
#     `lerobot-rollout --strategy.type=dagger` and turn it into a corrections dataset with
#     `dcdp-dagger-to-corrections --base <base> ...` (docs/METHOD.md), then train on that with lerobot-train.
#     Correct, do not drive: move the robot's own motion where the object went, let it run where nothing moved
#     (a person driving with their own motions gives labels a corrector cannot use: docs/FINDINGS.md, "Teleoperated corrections").
# Without ANCHOR the script converts the data, trains the base, and stops, saying so; it does not train the
# paper's reconstruction recipe (measured to make bases worse: docs/FINDINGS.md). Add it yourself with
# DCDP_FLAGS=--policy.correction=reconstruct ANCHOR=none if you want that row anyway.
#
# Usage: examples/fastumi_to_corrector.sh <fastumi dir> <work dir> [base pretrained_model dir]
#   <fastumi dir>: <task>/episode_<idx>.hdf5 files (or episode_<idx>.hdf5), see docs/FASTUMI.md
#   <work dir>:    gets data/ (the dataset), act/ (the base, if trained here) and dcdp/ (the corrector)
#   base:          a chunking policy already trained on this dataset's features (skips the ACT training)
# Settings (environment variables, defaults in brackets):
#   ANCHOR [unset] observation key of the object's xy keypoints (or "none" with a correction in DCDP_FLAGS),
#   STEPS [5000] corrector steps, BASE_STEPS [20000] base steps, BATCH [32], IMAGE_SIZE [224] frame side,
#   ACTION [absolute] or delta (dcdp-fastumi-to-lerobot --action), DEVICE [cpu] or cuda,
#   BASE_FLAGS / DCDP_FLAGS: extra lerobot-train flags for the base / corrector (e.g. smaller models).
# Run inside the project's virtualenv (the commands are its console scripts).
set -euo pipefail
[ $# -ge 2 ] || { sed -n '/^# Usage:/,/^#   base:/p' "$0" >&2; exit 2; }
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

# 3. the DCDP corrector around the frozen base
if [ -z "${ANCHOR:-}" ]; then
  echo "base: $base"
  echo "no corrector trained: this data holds no object keypoints (set ANCHOR=<observation key> if it does);"
  echo "see the header of $0 for what a corrector needs"
  exit 0
fi
anchor=()
[ "$ANCHOR" = none ] || anchor=("--policy.anchor_feature=$ANCHOR" "--policy.observation_features=[\"$ANCHOR\"]")
# shellcheck disable=SC2086  # DCDP_FLAGS is a list of flags
lerobot-train --policy.type=dcdp "--policy.base_policy_path=$base" "${common[@]}" "${anchor[@]}" \
  "--steps=$STEPS" "--save_freq=$STEPS" "--output_dir=$work/dcdp" ${DCDP_FLAGS:-}

echo "corrector: $work/dcdp/checkpoints/last/pretrained_model (base: $base)"
