"""Can a deterministic chunk regressor (MLP, L1) drive static PushT? 1 frame (what LeRobot's ACT reads)
vs 2 frames (+ the change since the previous one). Trained on all demonstrations, rolled out open loop with
n_action_steps 8 on seeds 100000...

Usage: .venv/bin/python scripts/diagnostics/chunk_regressor_rollout.py FRAMES STEPS EPISODES
"""

import glob
import sys

import numpy as np
import pandas as pd
import torch

from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env

torch.set_num_threads(1)
torch.manual_seed(0)
df = pd.concat([pd.read_parquet(f) for f in sorted(glob.glob("data/pusht_expert/data/*/*.parquet"))])
obs = np.concatenate(
    [np.stack(df["observation.state"].values), np.stack(df["observation.environment_state"].values)], 1
).astype(np.float32)
act = np.stack(df["action"].values).astype(np.float32)
ep = df["episode_index"].values
H = 16
frames = int(sys.argv[1])
steps = int(sys.argv[2])
X, Y = [], []
for e in np.unique(ep):
    i = np.flatnonzero(ep == e)
    o, a = obs[i], act[i]
    prev = np.concatenate([o[:1], o[:-1]])
    for t in range(len(i)):
        idx = np.minimum(np.arange(t, t + H), len(i) - 1)
        X.append(o[t] if frames == 1 else np.concatenate([o[t], o[t] - prev[t]]))
        Y.append(a[idx])
X, Y = np.asarray(X), np.asarray(Y)
xm, xs, am, asd = X.mean(0), X.std(0) + 1e-6, act.mean(0), act.std(0)
Xt = torch.tensor((X - xm) / xs)
Yt = torch.tensor(((Y - am) / asd).reshape(-1, 2 * H))
net = torch.nn.Sequential(
    torch.nn.Linear(X.shape[1], 512),
    torch.nn.GELU(),
    torch.nn.Linear(512, 512),
    torch.nn.GELU(),
    torch.nn.Linear(512, 512),
    torch.nn.GELU(),
    torch.nn.Linear(512, 2 * H),
)
opt = torch.optim.AdamW(net.parameters(), 1e-3)
sch = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
for _ in range(steps):
    b = torch.randint(0, len(Xt), (256,))
    loss = (net(Xt[b]) - Yt[b]).abs().mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    sch.step()
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
    f"frames={frames} steps={steps} train L1 {loss.item():.3f} score {np.mean(scores):.3f} "
    f"+- {np.std(scores) / np.sqrt(len(scores)):.3f} success {np.mean(succ):.2f}"
)
