"""Is one frame enough to predict the expert's chunk? MLP regression (L1), 1 vs 2 frames, error in px by chunk
index on held-out episodes (every 10th).

Usage: .venv/bin/python scripts/diagnostics/chunk_regressor_error.py [STEPS]
"""

import sys

import numpy as np
import torch
from chunk_regressor import H, fit_mlp, load_windows

torch.set_num_threads(1)
torch.manual_seed(0)
X1, X2, Y, E, am, asd = load_windows()
test = E % 10 == 0


def run(X, name):
    X = (X - X.mean(0)) / (X.std(0) + 1e-6)
    Xt = torch.tensor(X[~test])
    Yt = torch.tensor(((Y[~test] - am) / asd).reshape(-1, H * 2), dtype=torch.float32)
    Xv, Yv = torch.tensor(X[test]), Y[test]
    net, loss = fit_mlp(Xt, Yt, int(sys.argv[1]) if len(sys.argv) > 1 else 3000)
    with torch.no_grad():
        p = net(Xv).numpy().reshape(-1, H, 2) * asd + am
    err = np.linalg.norm(p - Yv, axis=-1)
    print(
        name,
        "train L1(norm)",
        round(loss, 3),
        "held-out median px by index",
        np.round(np.median(err, 0)[[0, 1, 3, 7, 15]], 1),
    )


run(X1, "1 frame")
run(X2, "2 frames")
