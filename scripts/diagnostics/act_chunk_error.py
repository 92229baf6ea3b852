"""An ACT checkpoint's chunk error (px) by chunk index on 600 demonstration frames, and a hold-still baseline.

Usage: .venv/bin/python scripts/diagnostics/act_chunk_error.py <pretrained_model dir>
"""

import sys

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.act.modeling_act import ACTPolicy
from lerobot.policies.factory import make_pre_post_processors

torch.set_num_threads(1)
p = sys.argv[1]
pol = ACTPolicy.from_pretrained(p).eval()
pre, post = make_pre_post_processors(pol.config, pretrained_path=p)
fps = 10
ds = LeRobotDataset(
    "local/pusht_expert", root="data/pusht_expert", delta_timestamps={"action": [i / fps for i in range(16)]}
)
rng = np.random.default_rng(0)
idx = rng.choice(len(ds), 600, replace=False)
errs = []
with torch.no_grad():
    for i in idx:
        f = ds[int(i)]
        b = {k: v.unsqueeze(0) for k, v in f.items() if isinstance(v, torch.Tensor)}
        bb = pre(dict(b))
        a = pol.predict_action_chunk(bb)  # normalized
        a = post(a)
        pad = f.get("action_is_pad")
        e = (a[0] - f["action"]).norm(dim=-1)
        if pad is not None:
            e[pad] = float("nan")
        errs.append(e.numpy())
errs = np.array(errs)
print("median px error by chunk index:", np.round(np.nanmedian(errs, 0), 1))
print("mean:", np.round(np.nanmean(errs, 0), 1))
# trivial baseline: action target = current agent position
base = []
for i in idx:
    f = ds[int(i)]
    e = (f["observation.state"][:2].unsqueeze(0) - f["action"]).norm(dim=-1)
    if f.get("action_is_pad") is not None:
        e[f["action_is_pad"]] = float("nan")
    base.append(e.numpy())
base = np.array(base)
print("hold-still baseline median:", np.round(np.nanmedian(base, 0), 1))
print("ACT median:", np.round(np.nanmedian(errs, 0), 1))
