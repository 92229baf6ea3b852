"""Does takeover data (DAgger-style: the learner drives, the expert is recorded from where it left) lift a
deterministic chunk regressor on static PushT? The 3 x 512 MLP of chunk_regressor.py (one frame, what
LeRobot's ACT reads) is fitted on the demonstrations, rolled out (seeds 100000.., n_action_steps 8), then each
round it drives TAKEOVERS episodes (seeds 50000 + 1000 * round.., lead steps 8..160 per lerobot_dcdp's
takeover recorder), the expert's recoveries are added and a fresh MLP is fitted on everything.

Usage: .venv/bin/python scripts/diagnostics/chunk_regressor_takeover.py TAKEOVERS ROUNDS EPISODES [WORKERS]
"""

import multiprocessing as mp
import pickle
import sys

import numpy as np
import torch
from chunk_regressor import H, fit_mlp, load_windows

STEPS = 3000


class MLPLead:
    """The MLP as an open-loop chunk policy: a new chunk every 8 steps."""

    def __init__(self, blob: bytes) -> None:
        self.net, self.xm, self.xs, self.am, self.asd = pickle.loads(blob)
        self.reset()

    def reset(self) -> None:
        self.t, self.chunk = 0, None

    def __call__(self, obs: dict) -> np.ndarray:
        if self.t % 8 == 0:
            x = np.concatenate([obs["agent_pos"], obs["environment_state"]]).astype(np.float32)
            with torch.no_grad():
                y = self.net(torch.tensor((x - self.xm) / self.xs)[None]).numpy()
            self.chunk = y.reshape(H, 2) * self.asd + self.am
        a = self.chunk[self.t % 8]
        self.t += 1
        return a.astype(np.float64)


def takeover(args: tuple[int, bytes]):
    from lerobot_dcdp.pusht.demos import run_episode
    from lerobot_dcdp.pusht.takeover import lead_steps_for

    torch.set_num_threads(1)
    seed, blob = args
    ep = run_episode(seed, lead=MLPLead(blob), lead_steps=lead_steps_for(seed, 8, 160))
    return (ep.state, ep.env_state, ep.action) if ep.success else None


def windows(eps) -> tuple[np.ndarray, np.ndarray]:
    x, y = [], []
    for s, e, a in eps:
        o = np.concatenate([s, e], 1)
        for t in range(len(a)):
            x.append(o[t])
            y.append(a[np.minimum(np.arange(t, t + H), len(a) - 1)])
    return np.asarray(x), np.asarray(y)


def score(blob: bytes, seeds) -> tuple[float, float, float]:
    from lerobot_dcdp.envs.pusht_perturbed import make_perturbed_env

    lead = MLPLead(blob)
    best, succ = [], []
    for seed in seeds:
        env = make_perturbed_env(obs_type="environment_state_agent_pos", max_episode_steps=300)
        obs, _ = env.reset(seed=seed)
        lead.reset()
        b, ok = 0.0, False
        for _ in range(300):
            obs, r, term, trunc, info = env.step(lead(obs))
            b, ok = max(b, r), ok or bool(info.get("is_success", False))
            if term or trunc or ok:
                break
        best.append(b)
        succ.append(ok)
        env.close()
    return float(np.mean(best)), float(np.std(best) / np.sqrt(len(best))), float(np.mean(succ))


def main() -> None:
    n_take, rounds, n_eval = (int(v) for v in sys.argv[1:4])
    workers = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    torch.manual_seed(0)
    x1, _, y, _, am, asd = load_windows()
    xm, xs = x1.mean(0), x1.std(0) + 1e-6
    x, yy = x1, y
    ctx = mp.get_context("spawn")
    blob = b""
    for rnd in range(rounds + 1):
        if rnd:
            args = [(50000 + 1000 * rnd + i, blob) for i in range(n_take)]
            with ctx.Pool(workers) as pool:
                eps = [e for e in pool.map(takeover, args) if e is not None]
            xn, yn = windows(eps)
            x, yy = np.concatenate([x, xn]), np.concatenate([yy, yn])
        torch.set_num_threads(workers)
        net, loss = fit_mlp(
            torch.tensor((x - xm) / xs), torch.tensor(((yy - am) / asd).reshape(-1, 2 * H)), STEPS
        )
        blob = pickle.dumps((net.eval(), xm, xs, am, asd))
        s, se, sr = score(blob, range(100000, 100000 + n_eval))
        added = f", {len(eps)} of {n_take} takeovers kept" if rnd else ""
        print(
            f"round {rnd}: {len(x)} frames{added}; train L1 {loss:.3f}; "
            f"score {s:.3f} +- {se:.3f} success {sr:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
