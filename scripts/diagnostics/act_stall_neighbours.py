"""Where a deterministic ACT base stalls on static PushT, and how close the demonstrations come to that
state.

Rolls the checkpoint out on seeds 100000..100009 (stock select_action, n_action_steps as trained); at the
first stall (agent moved < 1.5 px over 16 steps, after step 40, not solved) prints the policy's chunk relative
to the agent and the 12 nearest demonstration frames (standardised agent + keypoints): their distance
and where their expert went (5th action relative to the agent).

Usage: .venv/bin/python scripts/diagnostics/act_stall_neighbours.py <pretrained_model dir> [dataset root]
"""

import sys

import numpy as np
import torch
from chunk_regressor import load_windows
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors

from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env

torch.set_num_threads(1)
path = sys.argv[1]
pol = ACTPolicy.from_pretrained(path).eval()
pre, post = make_pre_post_processors(pol.config, pretrained_path=path)
x1, _, y, eps, _, _ = load_windows(*sys.argv[2:3])
xm, xs = x1.mean(0), x1.std(0)
z = (x1 - xm) / xs
for seed in range(100000, 100010):
    env = make_perturbed_env(obs_type="environment_state_agent_pos", max_episode_steps=300)
    obs, _ = env.reset(seed=seed)
    pol.reset()
    hist, best = [], 0.0
    for t in range(300):
        batch = {
            "observation.state": torch.tensor(obs["agent_pos"], dtype=torch.float32)[None],
            "observation.environment_state": torch.tensor(obs["environment_state"], dtype=torch.float32)[
                None
            ],
        }
        action = post(pol.select_action(pre(batch)))[0].numpy()
        hist.append(obs["agent_pos"].copy())
        obs, r, _, _, info = env.step(action)
        best = max(best, r)
        if info.get("is_success"):
            break
        if t > 40 and np.linalg.norm(hist[-1] - hist[-17]) < 1.5:
            x = np.concatenate([obs["agent_pos"], obs["environment_state"]])
            d = np.linalg.norm(z - (x - xm) / xs, axis=1)
            nn = np.argsort(d)[:12]
            print(
                f"seed {seed} stall t={t} best={best:.2f} agent={obs['agent_pos'].round(0)} "
                f"nearest demo frames at {d[nn[0]]:.2f}..{d[nn[-1]]:.2f} std"
            )
            with torch.no_grad():
                chunk = post(pol.predict_action_chunk(pre(batch)))[0].numpy()
            print(
                "  policy chunk - agent, index 0/4/15:",
                (chunk[[0, 4, 15]] - obs["agent_pos"]).round(0).tolist(),
            )
            print("  nearest demos' 5th action - agent:", (y[nn, 4] - x1[nn, :2]).round(0).tolist())
            print("  from episodes", eps[nn].tolist())
            break
    env.close()
