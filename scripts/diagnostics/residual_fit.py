"""How much of its labels' correction a residual corrector explains: recon MSE vs the plan's gap (unit range).

Usage: .venv/bin/python scripts/diagnostics/residual_fit.py <corrector> <corrections root> [batches]
"""

import sys

import numpy as np
import torch

sys.path.insert(0, "tests")
from helpers import training_batches

from lerobot_dcdp.modeling_dcdp import DCDPPolicy

torch.set_num_threads(1)
pol = DCDPPolicy.from_pretrained(sys.argv[1]).eval()
g = training_batches(pol, sys.argv[2], batch_size=256, seed=1)
r, p = [], []
with torch.no_grad():
    for _ in range(int(sys.argv[3]) if len(sys.argv) > 3 else 8):
        loss, d = pol._residual_loss(next(g))
        r.append(d["recon_loss"])
        p.append(d["plan_gap"])
print(f"recon {np.mean(r):.6f} plan_gap {np.mean(p):.6f} explained {1 - np.mean(r) / np.mean(p):.2f}")
