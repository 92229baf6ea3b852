"""The privileged ``drift_offset`` teacher as a policy: the base's open-loop chunk plus the drift the env
applied since plan time (+ lookahead x the last step's drift). lookahead < 0: plain open loop (sanity check).

Usage: .venv/bin/python scripts/diagnostics/teacher_drift_offset.py PERTURBATION MAGNITUDE EPISODES LOOKAHEAD
"""

import sys

import numpy as np
import torch
from lerobot.envs.utils import preprocess_observation

from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env
from lerobot_dcdp.pusht.corrections import load_policy

torch.set_num_threads(1)
pert, mag, n, look = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
policy, pre, post = load_policy(
    None, "models/pusht-diffusion-state", "open_loop", "observation.environment_state"
)
envs = [
    make_perturbed_env(
        obs_type="environment_state_agent_pos", max_episode_steps=300, perturbation=pert, magnitude=mag
    )
    for _ in range(n)
]
seeds = list(range(100000, 100000 + n))
obs = [e.reset(seed=s)[0] for e, s in zip(envs, seeds, strict=True)]
torch.manual_seed(0)
policy.reset()
seen = np.zeros((n, 2))
at_plan = np.zeros((n, 2))
last = np.zeros((n, 2))
best = np.zeros(n)
succ = np.zeros(n, bool)
active = np.ones(n, bool)
for _ in range(300):
    batch = pre(preprocess_observation({k: np.stack([o[k] for o in obs]) for k in obs[0]}))
    a = post(policy.select_action(batch)).numpy()
    if policy.last_step == 0:
        at_plan = seen.copy()
    corr = (seen - at_plan + look * last) * (look >= 0)  # look < 0: open loop
    for i in np.flatnonzero(active):
        o, r, term, trunc, info = envs[i].step(a[i] + corr[i])
        obs[i] = o
        off = info["perturbation_offset"]
        seen[i] += off
        last[i] = off
        best[i] = max(best[i], r)
        succ[i] |= bool(info.get("is_success", False))
        if term or trunc or succ[i]:
            active[i] = False
    if not active.any():
        break
print(
    f"{pert} {mag} lookahead {look}: score {best.mean():.3f} +- {best.std() / np.sqrt(n):.3f} "
    f"success {succ.mean():.2f}"
)
