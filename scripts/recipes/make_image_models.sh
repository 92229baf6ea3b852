#!/usr/bin/env bash
# Every folder of the image protocol (dcdp-benchmark --protocol image), in order, around one image base checkpoint:
#   models/pusht-diffusion-image                  the base (the checkpoint, copied)
#   models/pusht-dcdp-image                       make_image_corrector.sh (keypoint reader + demonstrations recipe)
#   models/pusht-dcdp-image-gated                 the same with a completion gate on the reader's estimate
#   models/pusht-dcdp-image-paper-recipe          make_image_paper_recipe.sh (reconstruction, the base's encoder)
#   models/pusht-diffusion-image-anchored-gated   the privileged reference: the bare base, gated anchoring fed the
#                                                 simulator's keypoints (an env that reports them; reports only)
# A folder that exists is kept. Each corrector is checkpoints/last/pretrained_model of its run, with its
# base_policy_path pointed at ../pusht-diffusion-image (checkpoints record it relative to themselves).
# Usage: scripts/recipes/make_image_models.sh <image base checkpoint's pretrained_model>
# Env: RUNS (runs), DATA_KP (data/pusht_image_kp: frames + keypoints, the reader's and the gates' data),
#      DATA (data/pusht_image: the base's demonstrations), READER (runs/pusht_keypoint_reader), STEPS (the
#      corrector's, 1000), PAPER_STEPS (3000).
# Then: .venv/bin/dcdp-benchmark --protocol image
set -euo pipefail
ckpt=$1
runs=${RUNS:-runs}; kp=${DATA_KP:-data/pusht_image_kp}; M=models; base=$M/pusht-diffusion-image
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1} HF_HUB_OFFLINE=1

ship() {  # ship <pretrained_model folder> <name under models/>: copied whole, then renamed into place
  [ -d "$M/$2" ] && return
  rm -rf "$M/$2.partial" && cp -r "$1" "$M/$2.partial"
  .venv/bin/python - "$M/$2.partial/config.json" <<'EOF'
import json, sys
path = sys.argv[1]
cfg = json.load(open(path))
if "base_policy_path" in cfg:
    cfg["base_policy_path"] = "../pusht-diffusion-image"
    json.dump(cfg, open(path, "w"), indent=4)
EOF
  mv "$M/$2.partial" "$M/$2"
}

ship "$ckpt" pusht-diffusion-image
[ -d "$M/pusht-dcdp-image" ] || {
  DATA="$kp" STEPS="${STEPS:-1000}" scripts/recipes/make_image_corrector.sh "$base" "$runs/dcdp_image"
  ship "$runs/dcdp_image/checkpoints/last/pretrained_model" pusht-dcdp-image
}
[ -d "$M/pusht-dcdp-image-gated" ] || .venv/bin/dcdp-fit-completion-gate --policy "$M/pusht-dcdp-image" \
  --repo-id local/pusht_image_kp_est --root "${kp}_est" --out "$M/pusht-dcdp-image-gated"
[ -d "$M/pusht-dcdp-image-paper-recipe" ] || {
  DATA="${DATA:-data/pusht_image}" STEPS="${PAPER_STEPS:-3000}" \
    scripts/recipes/make_image_paper_recipe.sh "$base" "$runs/dcdp_image_paper"
  ship "$runs/dcdp_image_paper/checkpoints/last/pretrained_model" pusht-dcdp-image-paper-recipe
}
[ -d "$M/pusht-diffusion-image-anchored-gated" ] || .venv/bin/dcdp-fit-completion-gate --base "$base" \
  --anchor-feature observation.environment_state --repo-id local/pusht_image_kp --root "$kp" \
  --out "$M/pusht-diffusion-image-anchored-gated"
du -sh "$M"/pusht-*image*
