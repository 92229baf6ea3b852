"""Can a deterministic chunk regressor (MLP, L1) drive static PushT? 1 frame (what LeRobot's ACT reads)
vs 2 frames (+ the change since the previous one). Trained on all demonstrations, rolled out open loop with
n_action_steps 8 on seeds 100000...

Usage: .venv/bin/python scripts/diagnostics/chunk_regressor_rollout.py FRAMES STEPS EPISODES
"""

import sys

import numpy as np
import torch
from chunk_regressor import H, fit_mlp, load_windows

from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env

torch.set_num_threads(1)
torch.manual_seed(0)
frames = int(sys.argv[1])
steps = int(sys.argv[2])
X1, X2, Y, _, am, asd = load_windows()
X = X1 if frames == 1 else X2
xm, xs = X.mean(0), X.std(0) + 1e-6
net, loss = fit_mlp(torch.tensor((X - xm) / xs), torch.tensor(((Y - am) / asd).reshape(-1, 2 * H)), steps)
net.eval()
scores = []
succ = []
for seed in range(100000, 100000 + int(sys.argv[3])):
    env = make_perturbed_env(obs_type="environment_state_agent_pos", max_episode_steps=300)
    o, _ = env.reset(seed=seed)
    cur = np.concatenate([o["agent_pos"], o["environment_state"]]).astype(np.float32)
    prev = cur
    best = 0.0
    ok = False
    k = 0
    chunk = None
    for _ in range(300):
        if k % 8 == 0:
            x = cur if frames == 1 else np.concatenate([cur, cur - prev])
            with torch.no_grad():
                chunk = net(torch.tensor((x - xm) / xs)[None]).numpy().reshape(H, 2) * asd + am
            k = 0
        o, r, term, trunc, info = env.step(chunk[k])
        k += 1
        prev, cur = cur, np.concatenate([o["agent_pos"], o["environment_state"]]).astype(np.float32)
        best = max(best, r)
        ok = ok or info.get("is_success", False)
        if term or trunc or ok:
            break
    scores.append(best)
    succ.append(ok)
    env.close()
print(
    f"frames={frames} steps={steps} train L1 {loss:.3f} score {np.mean(scores):.3f} "
    f"+- {np.std(scores) / np.sqrt(len(scores)):.3f} success {np.mean(succ):.2f}"
)
