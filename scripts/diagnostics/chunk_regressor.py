"""Shared by chunk_regressor_error.py and chunk_regressor_rollout.py: the demonstrations as (frame, chunk)
windows and a 3 x 512 MLP fitted to them with an L1 loss."""

import glob

import numpy as np
import pandas as pd
import torch

H = 16  # chunk length, as the bases


def load_windows(root: str = "data/pusht_expert"):
    """Per frame: the observation (agent + keypoints), the same + its change since the previous frame, the
    next H actions (padded with the episode's last), the episode index; and the actions' mean and std."""
    df = pd.concat([pd.read_parquet(f) for f in sorted(glob.glob(f"{root}/data/*/*.parquet"))])
    obs = np.concatenate(
        [np.stack(df["observation.state"].values), np.stack(df["observation.environment_state"].values)], 1
    ).astype(np.float32)
    act = np.stack(df["action"].values).astype(np.float32)
    ep = df["episode_index"].values
    x1, x2, y, eps = [], [], [], []
    for e in np.unique(ep):
        i = np.flatnonzero(ep == e)
        o, a = obs[i], act[i]
        prev = np.concatenate([o[:1], o[:-1]])
        for t in range(len(i)):
            x1.append(o[t])
            x2.append(np.concatenate([o[t], o[t] - prev[t]]))
            y.append(a[np.minimum(np.arange(t, t + H), len(i) - 1)])
            eps.append(e)
    return (*map(np.asarray, (x1, x2, y, eps)), act.mean(0), act.std(0))


def fit_mlp(x: torch.Tensor, y: torch.Tensor, steps: int) -> tuple[torch.nn.Module, float]:
    """AdamW 1e-3, cosine, batches of 256, L1; returns the net and its last batch loss."""
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, 512),
        torch.nn.GELU(),
        torch.nn.Linear(512, y.shape[1]),
    )
    opt = torch.optim.AdamW(net.parameters(), 1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        b = torch.randint(0, len(x), (256,))
        loss = (net(x[b]) - y[b]).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net, loss.item()
