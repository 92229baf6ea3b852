#!/usr/bin/env bash
# Stock lerobot-eval of a policy on unperturbed PushT: EPISODES (default 100) episodes, seeds 100000.., batch 50,
# CPU. OBS_TYPE: the env's observation type (default environment_state_agent_pos; an image base:
# pixels_agent_pos).
# Usage: scripts/recipes/eval_base.sh <pretrained_model dir> <output dir>   -> prints pc_success and avg_max_reward
set -euo pipefail
OMP_NUM_THREADS=1 .venv/bin/lerobot-eval --policy.path="$1" --env.type=pusht \
  --env.obs_type="${OBS_TYPE:-environment_state_agent_pos}" --eval.n_episodes="${EPISODES:-100}" \
  --eval.batch_size=50 --eval.use_async_envs=false --seed=100000 --policy.device=cpu --output_dir="$2" > "$2.log" 2>&1
.venv/bin/python -c "import json,sys; o=json.load(open(sys.argv[1]))['overall']; \
print(f\"pc_success={o['pc_success']:.1f} avg_max_reward={o['avg_max_reward']:.3f} n={o['n_episodes']}\")" \
  "$2/eval_info.json"
