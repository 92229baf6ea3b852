"""``dcdp-benchmark``: every execution mode x every perturbation, 50 fixed seeds, one protocol.

For each corrector given with ``--model LABEL=DIR`` (default: the shipped diffusion, paper-recipe, ACT and
demonstrations-only correctors) the base it records is run as ``open_loop`` (H = 8), ``closed_loop`` (H = 1),
``temporal_ensemble`` (H = 1, 0.5), ``object_anchored`` (H = 8, when the corrector names an anchor feature),
``gated_anchored`` (``object_anchored`` with the folder's completion gate, when it has one) and ``dcdp``
(H = 8) on static PushT and under constant / random block drift of 0.5 to 2.5 px per step;
``--delays 0 2 4`` adds a base that answers d control steps late (``inference_delay``).
Seeds 100000.., 300 steps max, an episode ends on success (coverage > 0.95). Writes ``results/benchmark.json``
(finished cells are kept and not recomputed), the per-step latency at batch 1, a plot, side-by-side videos
and ``docs/RESULTS.md``.

``--protocol mild`` (issue 22) is the protocol where an episode can still succeed: static and constant /
random drift of 0.5, 0.75 and 1.0 px per step, 100 episodes per cell, the demonstrations-only correctors
with open loop, object anchoring and DCDP, the gated correctors and the gated anchorings, plus the ``expert``
row (the privileged scripted expert executing 8-step chunks, a ceiling), into its own
``results/benchmark_mild.json`` and ``docs/RESULTS_MILD.md``. Any flag given explicitly overrides the
protocol's value. A stored cell of another episode count is never replaced without ``--force``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lerobot_dcdp.benchmark import shipped_model
from lerobot_dcdp.benchmark.report import EXPERT, cell_key
from lerobot_dcdp.correction import state_dict_sha256

METHODS = ["open_loop", "closed_loop", "temporal_ensemble", "object_anchored", "gated_anchored", "dcdp"]
DEFAULT_MODELS = {
    "diffusion": shipped_model("pusht-dcdp-state"),
    "diffusion_paper_recipe": shipped_model("pusht-dcdp-state-paper-recipe"),
    "act": shipped_model("pusht-dcdp-act-state"),
    "diffusion_demos": shipped_model("pusht-dcdp-state-demos"),
    "act_demos": shipped_model("pusht-dcdp-act-state-demos"),
    "diffusion_demos_late": shipped_model("pusht-dcdp-state-demos-late"),
    "act_demos_late": shipped_model("pusht-dcdp-act-state-demos-late"),
    "diffusion_teleop": shipped_model("pusht-dcdp-state-teleop"),
    "diffusion_demos_late_gated": shipped_model("pusht-dcdp-state-demos-late-gated"),
    "act_demos_late_gated": shipped_model("pusht-dcdp-act-state-demos-late-gated"),
    # the bare bases with a completion gate (``dcdp-fit-completion-gate --base``): the gated anchoring
    "diffusion_anchored_gated": shipped_model("pusht-diffusion-state-anchored-gated"),
    "act_anchored_gated": shipped_model("pusht-act-state-anchored-gated"),
}
#: these correctors share their base with ``diffusion`` / ``act``: only their own DCDP row is run by default
DEFAULT_METHODS = {
    "diffusion_paper_recipe": ["dcdp"],
    "diffusion_demos": ["dcdp"],
    "act_demos": ["dcdp"],
    "diffusion_demos_late": ["dcdp"],
    "act_demos_late": ["dcdp"],
    "diffusion_teleop": ["dcdp"],
    "diffusion_demos_late_gated": ["dcdp"],
    "act_demos_late_gated": ["dcdp"],
    "diffusion_anchored_gated": ["gated_anchored"],
    "act_anchored_gated": ["gated_anchored"],
}
#: the mild protocol's models: the first two carry the base's rows (open loop, anchoring) too
MILD_MODELS = (
    "diffusion_demos",
    "act_demos",
    "diffusion_demos_late_gated",
    "act_demos_late_gated",
    "diffusion_anchored_gated",
    "act_anchored_gated",
)


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import torch

    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
    }


def git_commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def load_model(corrector_dir: str):
    """The corrector (with its base) and the processors saved beside it."""
    from lerobot.policies.factory import make_pre_post_processors

    import lerobot_policy_dcdp  # noqa: F401
    from lerobot_dcdp.modeling_dcdp import DCDPPolicy

    policy = DCDPPolicy.from_pretrained(corrector_dir)
    policy.eval()
    if not policy.config.completion_gate:  # a folder that turns its fitted gate off is run without one
        policy.completion_gate = None
    pre, post = make_pre_post_processors(policy.config, pretrained_path=corrector_dir)
    identity = {
        "corrector": corrector_dir,
        "corrector_sha256": policy.corrector_sha256(),
        "base": policy.config.base_policy_path,
        "base_type": policy.config.base_policy_type,
        "base_weights_sha256": policy.config.base_weights_sha256,
        "corrector_params": sum(p.numel() for p in policy.parameters()),
    }
    if policy.completion_gate is not None:  # not part of corrector_sha256: its own identity
        identity["completion_gate_sha256"] = state_dict_sha256(policy.completion_gate.state_dict())
    identity.update(lead_identity(policy.config))
    policy.folder_lead_steps = policy.config.lead_steps  # set_mode turns it off for the plain rule only
    return policy, pre, post, identity


def set_mode(policy, method: str, delay: int = 0) -> None:
    """Run ``policy`` as the benchmark's ``method``: an execution mode, ``object_anchored`` always the plain
    rule, ``gated_anchored`` the rule with the folder's completion gate; ``dcdp`` and ``gated_anchored``
    with the folder's scene lead (``lead_steps``; the other modes never lead)."""
    limit = policy.source.max_length - policy.config.n_action_steps
    if not 0 <= delay <= limit:
        raise ValueError(f"inference_delay {delay} is out of range for this base: 0..{limit}")
    if method == "gated_anchored" and policy.completion_gate is None:
        raise ValueError("gated_anchored needs a folder with a completion gate (dcdp-fit-completion-gate)")
    policy.config.execution = "object_anchored" if method == "gated_anchored" else method
    policy.config.completion_gate = policy.completion_gate is not None and method != "object_anchored"
    if not hasattr(policy, "folder_lead_steps"):  # load_model records it; else the first call does
        policy.folder_lead_steps = policy.config.lead_steps
    policy.config.lead_steps = policy.folder_lead_steps if method in ("dcdp", "gated_anchored") else 0
    policy.config.inference_delay = delay
    policy.config.ticks_per_step = 1  # lock-step: every env step is one planned step
    policy.reset()


def protocols() -> dict[str, dict]:
    """The named protocols: the defaults ``--protocol`` fills in for every flag not given explicitly."""
    from lerobot_dcdp.benchmark.rollout import MAIN_CONDITIONS, MILD_CONDITIONS

    return {
        "main": {
            "models": None,  # DEFAULT_MODELS
            "model_methods": DEFAULT_METHODS,  # these share their base with another: their DCDP row only
            "methods": METHODS,
            "conditions": MAIN_CONDITIONS,
            "episodes": 50,
            "latency_steps": 300,
            "videos": 2,
            "out": "results/benchmark.json",
            "report": "docs/RESULTS.md",
            "realtime": "results/realtime",  # the real-time summaries the report shows (issue 23)
        },
        "mild": {
            "models": {k: DEFAULT_MODELS[k] for k in MILD_MODELS},
            # the others: every method
            "model_methods": {k: DEFAULT_METHODS[k] for k in MILD_MODELS[2:]},
            "methods": ["open_loop", "object_anchored", "gated_anchored", "dcdp", EXPERT],
            "conditions": MILD_CONDITIONS,
            "episodes": 100,
            "latency_steps": 0,
            "videos": 0,
            "out": "results/benchmark_mild.json",
            "report": "docs/RESULTS_MILD.md",
            "realtime": None,
        },
    }


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line, with ``--protocol``'s values for the flags not given.

    Raises:
        SystemExit: on a bad flag (argparse's message).
    """
    from lerobot_dcdp.benchmark.rollout import CONDITIONS, EXPERT_CHUNK

    presets = protocols()
    p = argparse.ArgumentParser(prog="dcdp-benchmark", description=__doc__.splitlines()[0])
    p.add_argument(
        "--protocol",
        choices=sorted(presets),
        default="main",
        help="main: 50 episodes, every drift (default); mild: issue 22's 100 episodes at 0-1 px/step "
        "(own results file and report)",
    )
    p.add_argument(
        "--model",
        action="append",
        default=None,
        metavar="LABEL=DIR",
        help="a corrector checkpoint to benchmark (repeatable); default: the protocol's shipped ones",
    )
    p.add_argument(
        "--methods",
        nargs="+",
        default=None,
        choices=METHODS + [EXPERT],
        help=f"'{EXPERT}': the privileged scripted expert (true state, chunks of --expert-chunk), once per "
        "condition",
    )
    p.add_argument("--conditions", nargs="+", default=None, choices=[c.name for c in CONDITIONS])
    p.add_argument(
        "--delays", nargs="+", type=int, default=[0], help="inference delays d (control steps) to run"
    )
    p.add_argument("--episodes", type=int, default=None, help="per cell (main: 50, mild: 100)")
    p.add_argument("--expert-episodes", type=int, default=None, help="per expert cell (default: --episodes)")
    p.add_argument("--expert-chunk", type=int, default=EXPERT_CHUNK, help="steps the expert runs per plan")
    p.add_argument("--seed-start", type=int, default=100_000)
    p.add_argument("--max-steps", type=int, default=300)
    p.add_argument("--batch-size", type=int, default=50, help="envs rolled out together")
    p.add_argument("--latency-steps", type=int, default=None, help="batch-1 steps timed per method (0: skip)")
    p.add_argument("--latency-rounds", type=int, default=10, help="episodes per method, interleaved")
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    p.add_argument("--videos", type=int, default=None, help="side-by-side open_loop|dcdp videos to render")
    p.add_argument("--out", default=None, help="results file (main: results/benchmark.json)")
    p.add_argument(
        "--report",
        default=None,
        help="generated report (main: docs/RESULTS.md; with --out: the results file's name with .md)",
    )
    p.add_argument("--force", action="store_true", help="recompute finished cells (and replace any cell)")
    a = p.parse_args(argv)
    preset = presets[a.protocol]
    if a.out is not None and a.report is None:  # a screen of one's own never rewrites the shipped report
        a.report = str(Path(a.out).with_suffix(".md"))
    for key in ("methods", "conditions", "episodes", "latency_steps", "videos", "out", "report"):
        if getattr(a, key) is None:
            setattr(a, key, preset[key])
    a.realtime = preset["realtime"]
    if a.expert_episodes is None:
        a.expert_episodes = a.episodes
    for key in ("episodes", "expert_episodes", "expert_chunk"):
        if getattr(a, key) < 1:
            p.error(f"--{key.replace('_', '-')} must be >= 1")
    a.models = (
        dict(m.split("=", 1) for m in a.model)
        if a.model
        else {k: v for k, v in (preset["models"] or DEFAULT_MODELS).items() if Path(v).is_dir()}
    )
    # explicit correctors run every requested method; the protocol's own, those it names for them
    a.model_methods = {} if a.model else preset["model_methods"]
    return a


def model_methods(a: argparse.Namespace, label: str) -> list[str]:
    """The base/corrector methods run for ``label`` (before ``runs`` checks what the folder can run)."""
    return [m for m in a.methods if m != EXPERT and m in a.model_methods.get(label, METHODS)]


def episode_conflicts(cells: dict, wanted: dict[str, int]) -> list[str]:
    """Stored cells that a run asking ``wanted`` (cell key -> episodes) would replace by a different count."""
    return [
        f"{key} ({cells[key].get('episodes')} episodes stored, {n} asked)"
        for key, n in wanted.items()
        if key in cells and cells[key].get("episodes") != n
    ]


def main(argv: list[str] | None = None) -> None:
    from tqdm import tqdm

    from lerobot_dcdp.benchmark.report import write_report
    from lerobot_dcdp.benchmark.rollout import CONDITIONS, rollout

    a = parse_args(argv)

    import torch

    torch.set_num_threads(a.threads)
    models = a.models
    run_expert = EXPERT in a.methods
    if not models and any(m != EXPERT for m in a.methods):
        sys.exit("dcdp-benchmark: error: no corrector found; pass --model LABEL=DIR")
    out = Path(a.out)
    results = json.loads(out.read_text()) if out.exists() else {"cells": {}, "latency": {}}
    results.setdefault("cells", {})
    results.setdefault("latency", {})
    seeds = list(range(a.seed_start, a.seed_start + a.episodes))
    expert_seeds = list(range(a.seed_start, a.seed_start + a.expert_episodes))
    wanted = {
        cell_key(label, m, c, d): len(seeds)
        for label in models
        for m in model_methods(a, label)
        for c in a.conditions
        for d in a.delays
    }
    if run_expert:
        wanted.update({cell_key(EXPERT, EXPERT, c): len(expert_seeds) for c in a.conditions})
    conflicts = [] if a.force else episode_conflicts(results["cells"], wanted)
    if conflicts:
        sys.exit(
            f"dcdp-benchmark: error: {out} holds cells of another episode count, which this run would "
            "replace: "
            + "; ".join(conflicts[:5])
            + (" ..." if len(conflicts) > 5 else "")
            + ". Write to another file (--out, --report) or pass --force to replace them."
        )
    results["command"] = "dcdp-benchmark " + " ".join(argv if argv is not None else sys.argv[1:])
    results["machine"] = machine()
    results["git_commit"] = git_commit()
    conds = {c.name: c for c in CONDITIONS}
    video_dir = out.parent / "videos"

    loaded = copy.deepcopy(results)

    def save() -> None:
        """Merge this run's cells into the file on disk (other benchmarks may write meanwhile)."""
        import fcntl

        out.parent.mkdir(parents=True, exist_ok=True)
        with open(out.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            disk = json.loads(out.read_text()) if out.exists() else {}
            merged = merge_results(disk, results, loaded)
            results.update(merged)
            loaded.update(copy.deepcopy(merged))
            tmp = out.with_suffix(".json.tmp")
            tmp.write_text(json.dumps(results, indent=1))
            tmp.replace(out)

    for label, path in models.items():
        if not model_methods(a, label):
            continue
        policy, pre, post, ident = load_model(path)
        results.setdefault("models", {})[label] = ident
        methods = [m for m in model_methods(a, label) if runs(m, policy)]
        todo = [
            (m, c, d)
            for d in a.delays
            for c in a.conditions
            for m in methods
            if a.force
            or not _fresh(results["cells"].get(cell_key(label, m, c, d)), ident, seeds, a.max_steps)
        ]
        bar = tqdm(total=len(todo) * a.max_steps, desc=f"{label}: rollouts", unit="step")
        for method, cname, delay in todo:
            render = (
                tuple(seeds[: a.videos])
                if method in ("open_loop", "dcdp") and cname != "static" and not delay
                else ()
            )
            set_mode(policy, method, delay)
            t0 = time.perf_counter()
            res = []
            for i in range(0, len(seeds), a.batch_size):
                res.append(
                    rollout(
                        policy,
                        pre,
                        post,
                        conds[cname],
                        seeds[i : i + a.batch_size],
                        a.max_steps,
                        render_seeds=render,
                    )
                )
            bar.update(a.max_steps)
            cell = {
                "model": label,
                "method": method,
                "condition": cname,
                "inference_delay": delay,
                **conds[cname].env_kwargs(),
                "episodes": len(seeds),
                "seeds": [seeds[0], seeds[-1]],
                "max_steps": a.max_steps,
                "success_rate": float(np.mean([s for r in res for s in r.successes])),
                "score": float(np.mean([m for r in res for m in r.max_rewards])),
                "mean_steps": float(np.mean([s for r in res for s in r.steps])),
                "successes": [bool(s) for r in res for s in r.successes],
                "max_rewards": [round(m, 5) for r in res for m in r.max_rewards],
                "batched_step_ms_mean": float(np.mean([t for r in res for t in r.step_times_ms])),
                "wall_s": round(time.perf_counter() - t0, 1),
                "identity": ident,
            }
            results["cells"][cell_key(label, method, cname, delay)] = cell
            frames = {s: f for r in res for s, f in r.frames.items()}
            if frames:
                _stash_frames(video_dir, label, method, cname, frames)
            save()
        bar.close()
        if a.latency_steps > 0:
            # latency is compared within one run: re-time every method when any of them is stale; the
            # methods take turns episode by episode (static seeds 100000..) so they share machine state
            stale = a.force or not all(
                _fresh(results["latency"].get(f"{label}|{m}"), ident, seeds[:1], a.latency_steps)
                and results["latency"][f"{label}|{m}"].get("rounds") == a.latency_rounds
                for m in methods
            )
            times: dict[str, list[float]] = {m: [] for m in methods}
            for rnd in range(a.latency_rounds if stale else 0):
                for method in methods:
                    set_mode(policy, method)
                    seed = seeds[rnd % len(seeds)]
                    r = rollout(policy, pre, post, conds["static"], [seed], a.latency_steps)
                    times[method] += r.step_times_ms[1:] if len(r.step_times_ms) > 1 else r.step_times_ms
            for method in methods if stale else []:
                t = np.array(times[method])
                results["latency"][f"{label}|{method}"] = {
                    "model": label,
                    "method": method,
                    "batch": 1,
                    "steps": int(len(t)),
                    "mean_ms": float(t.mean()),
                    "p95_ms": float(np.percentile(t, 95)),
                    "seeds": seeds[: a.latency_rounds],
                    "rounds": a.latency_rounds,
                    "max_steps": a.latency_steps,
                    "identity": ident,
                }
            save()
        _write_videos(video_dir, label)
    if run_expert:
        run_expert_cells(a, results, conds, expert_seeds, save)
    write_report(results, Path(a.report), out, Path(a.realtime) if a.realtime else None)
    print(f"wrote {out} and {a.report}")


def run_expert_cells(
    a: argparse.Namespace, results: dict, conds: dict, seeds: list[int], save: Callable[[], None]
) -> None:
    """The ``expert`` row: the privileged scripted expert on every requested condition (no corrector, no
    base; one cell per condition, shared by every model's table)."""
    from tqdm import tqdm

    from lerobot_dcdp.benchmark.rollout import expert_identity, expert_rollout

    ident = expert_identity(a.expert_chunk)
    cells = results["cells"]
    todo = [
        c
        for c in a.conditions
        if a.force or not _fresh_expert(cells.get(cell_key(EXPERT, EXPERT, c)), ident, seeds, a.max_steps)
    ]
    for cname in tqdm(todo, desc="expert: rollouts", unit="cell"):
        t0 = time.perf_counter()
        r = expert_rollout(conds[cname], seeds, a.max_steps, chunk=a.expert_chunk)
        results["cells"][cell_key(EXPERT, EXPERT, cname)] = {
            "model": EXPERT,
            "method": EXPERT,
            "condition": cname,
            "inference_delay": 0,
            **conds[cname].env_kwargs(),
            "episodes": len(seeds),
            "seeds": [seeds[0], seeds[-1]],
            "max_steps": a.max_steps,
            "success_rate": r.success_rate,
            "score": r.score,
            "mean_steps": float(np.mean(r.steps)),
            "successes": [bool(s) for s in r.successes],
            "max_rewards": [round(m, 5) for m in r.max_rewards],
            "planning_ms_per_step_mean": float(np.mean(r.step_times_ms)),
            "wall_s": round(time.perf_counter() - t0, 1),
            "identity": ident,
        }
        save()


def _fresh_expert(cell: dict | None, ident: dict, seeds: list[int], max_steps: int) -> bool:
    """A stored expert cell is reused only for the same expert settings, seeds and step limit."""
    return bool(
        cell
        and cell.get("identity") == ident
        and cell.get("seeds", [None])[0] == seeds[0]
        and cell.get("max_steps") == max_steps
        and cell.get("episodes") == len(seeds)
    )


def merge_results(disk: dict, ours: dict, loaded: dict) -> dict:
    """The ``cells``/``latency``/``models`` tables to write: what is on disk now, overridden only by entries
    this run changed since it read the file (``loaded``), so that two benchmarks writing other cells of the
    same file side by side never put back each other's stale copies."""
    merged = {}
    for k in ("cells", "latency", "models"):
        before = loaded.get(k, {})
        changed = {key: v for key, v in ours.get(k, {}).items() if before.get(key) != v}
        merged[k] = {**disk.get(k, {}), **changed}
    return merged


def runs(method: str, policy) -> bool:
    """Whether ``policy``'s folder can run ``method``: the anchorings need an anchor feature, the gated one a
    fitted completion gate."""
    if method == "object_anchored":
        return bool(policy.config.anchor_feature)
    if method == "gated_anchored":
        return bool(policy.config.anchor_feature) and policy.completion_gate is not None
    return True


#: a folder's scene lead in its identity, with the value a cell recorded without it ran with (a cell without
#: a tolerance ran the median motion of the first scene lead; one without a noise, none)
LEAD_IDENTITY = {
    "lead_steps": 0,
    "lead_window": 0,
    "lead_state_feature": "observation.state",
    "lead_tolerance": None,
    "lead_repeats": None,
    "lead_noise": 0.0,
}


def lead_identity(config) -> dict:
    """A folder's scene lead as its cells record it (its DCDP and gated rows run with it; pure): every
    ``LEAD_IDENTITY`` key from ``config``, or nothing where it does not lead."""
    return {key: getattr(config, key) for key in LEAD_IDENTITY} if config.lead_steps else {}


def _fresh(cell: dict | None, ident: dict, seeds: list[int], max_steps: int) -> bool:
    """A stored cell is reused only for the same corrector (DCDP), gate and scene lead (DCDP, gated
    anchoring), base, seeds and step limit."""
    if not cell:
        return False
    i = cell.get("identity", {})
    method = cell.get("method")
    # the baselines never call the corrector or the gate: for them only the base has to be the same
    same_corrector = method not in ("dcdp", None) or i.get("corrector_sha256") == ident["corrector_sha256"]
    led = method in ("dcdp", "gated_anchored", None)
    same_gate = not led or i.get("completion_gate_sha256") == ident.get("completion_gate_sha256")
    same_lead = not led or all(i.get(k, d) == ident.get(k, d) for k, d in LEAD_IDENTITY.items())
    return (
        same_corrector
        and same_gate
        and same_lead
        and i.get("base_weights_sha256") == ident["base_weights_sha256"]
        and cell.get("seeds", [None])[0] == seeds[0]
        and cell.get("max_steps") == max_steps
        and cell.get("episodes", len(seeds)) == len(seeds)
    )


def _stash_frames(video_dir: Path, label: str, method: str, cname: str, frames: dict) -> None:
    import cv2

    video_dir.mkdir(parents=True, exist_ok=True)
    for seed, fr in frames.items():
        small = np.stack([cv2.resize(f, (256, 256), interpolation=cv2.INTER_AREA) for f in fr])
        np.save(video_dir / f".{label}_{method}_{cname}_{seed}.npy", small)


def _write_videos(video_dir: Path, label: str) -> None:
    """Side by side: open loop (left) | DCDP (right), same seed and perturbation."""
    from lerobot.utils.io_utils import write_video

    for left in sorted(video_dir.glob(f".{label}_open_loop_*.npy")):
        right = left.with_name(left.name.replace("_open_loop_", "_dcdp_"))
        if not right.exists():
            continue
        a, b = np.load(left), np.load(right)
        n = max(len(a), len(b))
        a = np.concatenate([a, np.repeat(a[-1:], n - len(a), 0)])
        b = np.concatenate([b, np.repeat(b[-1:], n - len(b), 0)])
        name = left.name[1:].replace("_open_loop_", "_openloop_vs_dcdp_").replace(".npy", ".mp4")
        write_video(str(video_dir / name), list(np.concatenate([a, b], axis=2)), fps=10)
        left.unlink()
        right.unlink()


if __name__ == "__main__":
    main()
