"""Is one frame enough to predict the expert's chunk? MLP regression (L1), 1 vs 2 frames, error in px by chunk
index on held-out episodes (every 10th).

Usage: .venv/bin/python scripts/diagnostics/chunk_regressor_error.py [STEPS]
"""

import glob
import sys

import numpy as np
import pandas as pd
import torch

torch.set_num_threads(1)
torch.manual_seed(0)
df = pd.concat([pd.read_parquet(f) for f in sorted(glob.glob("data/pusht_expert/data/*/*.parquet"))])
st = np.stack(df["observation.state"].values)
env = np.stack(df["observation.environment_state"].values)
act = np.stack(df["action"].values)
ep = df["episode_index"].values
obs = np.concatenate([st, env], 1).astype(np.float32)
H = 16
X1, X2, Y, E = [], [], [], []
for e in np.unique(ep):
    i = np.flatnonzero(ep == e)
    o, a = obs[i], act[i]
    prev = np.concatenate([o[:1], o[:-1]])
    for t in range(len(i)):
        idx = np.minimum(np.arange(t, t + H), len(i) - 1)
        X1.append(o[t])
        X2.append(np.concatenate([o[t], o[t] - prev[t]]))
        Y.append(a[idx])
        E.append(e)
X1, X2, Y, E = map(np.asarray, (X1, X2, Y, E))
mu, sd = X1.mean(0), X1.std(0) + 1e-6
am, asd = act.mean(0), act.std(0)
test = E % 10 == 0


def run(X, name):
    X = (X - X.mean(0)) / (X.std(0) + 1e-6)
    Xt, Yt = (
        torch.tensor(X[~test]),
        torch.tensor(((Y[~test] - am) / asd).reshape(-1, H * 2), dtype=torch.float32),
    )
    Xv, Yv = torch.tensor(X[test]), Y[test]
    net = torch.nn.Sequential(
        torch.nn.Linear(X.shape[1], 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, H * 2),
    )
    opt = torch.optim.AdamW(net.parameters(), 1e-3)
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 3000
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        b = torch.randint(0, len(Xt), (256,))
        loss = (net(Xt[b]) - Yt[b]).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    with torch.no_grad():
        p = net(Xv).numpy().reshape(-1, H, 2) * asd + am
    err = np.linalg.norm(p - Yv, axis=-1)
    print(
        name,
        "train L1(norm)",
        round(loss.item(), 3),
        "held-out median px by index",
        np.round(np.median(err, 0)[[0, 1, 3, 7, 15]], 1),
    )


run(X1, "1 frame")
run(X2, "2 frames")
