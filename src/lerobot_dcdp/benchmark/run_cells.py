"""Running the benchmark's cells: one model folder's rollouts (every method x condition x delay that is not
already stored), its batch-1 latency and videos, and the privileged expert's ceiling row."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_dcdp.benchmark.cell_checkpoint import CellCheckpoint
from lerobot_dcdp.benchmark.cells import EXPERT, cell_key
from lerobot_dcdp.benchmark.modes import load_model, obs_type, runs, set_mode
from lerobot_dcdp.benchmark.protocols import model_methods
from lerobot_dcdp.benchmark.results_file import ResultsFile, fresh_cell, fresh_expert_cell
from lerobot_dcdp.benchmark.videos import stash_frames, write_videos


@dataclass
class LoadedModel:
    """A model folder as the benchmark runs it.

    Attributes:
        label: Its name in the results (``--model LABEL=DIR``).
        policy: The loaded DCDP policy (corrector and base).
        pre: Its pre-processor.
        post: Its post-processor.
        ident: Its identity (``load_model``), recorded in every cell.
    """

    label: str
    policy: Any
    pre: Any
    post: Any
    ident: dict


def run_model(
    a: argparse.Namespace, store: ResultsFile, label: str, path: str, seeds: list[int], conds: dict
) -> None:
    """Every missing cell of one model folder, then its latency (when asked) and its videos.

    Each cell is merged into the results file as soon as it is done; its finished batches are kept on disk
    meanwhile, so a cut-off run resumes a cell at its next batch (``CellCheckpoint``).

    Args:
        a: The parsed command line (``parse_args``).
        store: The results file.
        label: The model's name.
        path: Its folder.
        seeds: The episode seeds of every cell.
        conds: ``{condition name: Condition}``.
    """
    from tqdm import tqdm

    policy, pre, post, ident = load_model(path, getattr(a, "device", None))
    model = LoadedModel(label, policy, pre, post, ident)
    store.results.setdefault("models", {})[label] = ident
    methods = [m for m in model_methods(a, label) if runs(m, policy)]
    todo = [
        (m, c, d)
        for d in a.delays
        for c in a.conditions
        for m in methods
        if a.force
        or not fresh_cell(store.results["cells"].get(cell_key(label, m, c, d)), ident, seeds, a.max_steps)
    ]
    video_dir = store.path.parent / "videos"
    bar = tqdm(total=len(todo) * a.max_steps, desc=f"{label}: rollouts", unit="step")
    for method, cname, delay in todo:
        key = cell_key(label, method, cname, delay)
        checkpoint = CellCheckpoint(store.path, key, cell_settings(a, model, seeds, delay))
        cell = run_cell(a, model, method, conds[cname], seeds, delay, video_dir, checkpoint)
        bar.update(a.max_steps)
        store.results["cells"][key] = cell
        store.save()
        checkpoint.clear()
    bar.close()
    if a.latency_steps > 0:
        time_latency(a, store.results["latency"], model, methods, seeds, conds["static"])
        store.save()
    write_videos(video_dir, label)


def cell_settings(a: argparse.Namespace, model: LoadedModel, seeds: list[int], delay: int) -> dict:
    """What a cell's batches depend on besides its key: a stored batch is reused only under the same."""
    return {
        "identity": model.ident,
        "seeds": seeds,
        "batch_size": a.batch_size,
        "max_steps": a.max_steps,
        "delay": delay,
        "bid_weak_policy": getattr(a, "bid_weak", {}).get(model.label),
        "device": getattr(a, "device", None),
    }


def run_cell(
    a: argparse.Namespace,
    model: LoadedModel,
    method: str,
    cond: Any,
    seeds: list[int],
    delay: int,
    video_dir: Path,
    checkpoint: CellCheckpoint | None = None,
) -> dict:
    """Roll out one cell in batches of ``--batch-size`` and stash its rendered frames.

    The first ``--videos`` seeds are rendered for open loop and DCDP on a drifting condition without delay
    (the side-by-side videos); such a cell is always rolled out whole. Any other cell resumes after the
    batches ``checkpoint`` holds and adds each batch to it as it finishes.

    Args:
        a: The parsed command line.
        model: The folder that runs.
        method: The row (``set_mode``).
        cond: The condition (a ``rollout.Condition``).
        seeds: The episode seeds.
        delay: The inference delay in control steps.
        video_dir: Where rendered frames are stashed.
        checkpoint: Where its finished batches are kept (``None``: nowhere).

    Returns:
        The cell as stored in the results JSON.
    """
    from lerobot_dcdp.benchmark.rollout import rollout

    render = (
        tuple(seeds[: a.videos])
        if method in ("open_loop", "dcdp") and cond.name != "static" and not delay
        else ()
    )
    set_mode(model.policy, method, delay)
    weak = getattr(a, "bid_weak", {}).get(model.label) if method == "bid" else None
    model.policy.use_bid_reference(weak)
    if render:
        checkpoint = None
    res, wall_before = checkpoint.load() if checkpoint else ([], 0.0)
    t0 = time.perf_counter()
    for i in range(len(res) * a.batch_size, len(seeds), a.batch_size):
        res.append(
            rollout(
                model.policy,
                model.pre,
                model.post,
                cond,
                seeds[i : i + a.batch_size],
                a.max_steps,
                obs_type=obs_type(model.policy),
                render_seeds=render,
            )
        )
        if checkpoint:
            checkpoint.save(res, wall_before + time.perf_counter() - t0)
    cell = {
        "model": model.label,
        "method": method,
        "condition": cond.name,
        "inference_delay": delay,
        **cond.env_kwargs(),
        "obs_type": obs_type(model.policy),
        "episodes": len(seeds),
        "seeds": [seeds[0], seeds[-1]],
        "max_steps": a.max_steps,
        "success_rate": float(np.mean([s for r in res for s in r.successes])),
        "score": float(np.mean([m for r in res for m in r.max_rewards])),
        "mean_steps": float(np.mean([s for r in res for s in r.steps])),
        "successes": [bool(s) for r in res for s in r.successes],
        "max_rewards": [round(m, 5) for r in res for m in r.max_rewards],
        "batched_step_ms_mean": float(np.mean([t for r in res for t in r.step_times_ms])),
        "wall_s": round(wall_before + time.perf_counter() - t0, 1),
        "batch_size": a.batch_size,
        "identity": model.ident,
    }
    if method == "bid":
        cell["bid_weak_policy"] = weak
    frames = {s: f for r in res for s, f in r.frames.items()}
    if frames:
        stash_frames(video_dir, model.label, method, cond.name, frames)
    return cell


def time_latency(
    a: argparse.Namespace,
    latency: dict,
    model: LoadedModel,
    methods: list[str],
    seeds: list[int],
    static: Any,
) -> None:
    """Time every method's per-step latency at batch 1 on static PushT into ``latency``.

    Latency is compared within one run: every method is re-timed when any of them is stale (or with
    ``--force``); the methods take turns episode by episode (seeds from the first) so they share machine
    state. The first step of an episode (one-off allocations) is left out.

    Args:
        a: The parsed command line (``--latency-steps``, ``--latency-rounds``).
        latency: The results' ``latency`` table (``label|method`` -> entry), updated in place.
        model: The folder that runs.
        methods: The methods to time.
        seeds: The cells' seeds (round ``r`` uses ``seeds[r % len(seeds)]``).
        static: The static condition.
    """
    from lerobot_dcdp.benchmark.rollout import rollout

    label = model.label
    stale = a.force or not all(
        fresh_cell(latency.get(f"{label}|{m}"), model.ident, seeds[:1], a.latency_steps)
        and latency[f"{label}|{m}"].get("rounds") == a.latency_rounds
        for m in methods
    )
    if not stale:
        return
    times: dict[str, list[float]] = {m: [] for m in methods}
    for rnd in range(a.latency_rounds):
        for method in methods:
            set_mode(model.policy, method)
            seed = seeds[rnd % len(seeds)]
            r = rollout(
                model.policy, model.pre, model.post, static, [seed], a.latency_steps, obs_type(model.policy)
            )
            times[method] += r.step_times_ms[1:] if len(r.step_times_ms) > 1 else r.step_times_ms
    for method in methods:
        t = np.array(times[method])
        latency[f"{label}|{method}"] = {
            "model": label,
            "method": method,
            "batch": 1,
            "steps": int(len(t)),
            "mean_ms": float(t.mean()),
            "p95_ms": float(np.percentile(t, 95)),
            "seeds": seeds[: a.latency_rounds],
            "rounds": a.latency_rounds,
            "max_steps": a.latency_steps,
            "identity": model.ident,
        }


def run_expert_cells(
    a: argparse.Namespace, results: dict, conds: dict, seeds: list[int], save: Callable[[], None]
) -> None:
    """The ``expert`` row: the privileged scripted expert on every requested condition (no corrector, no
    base; one cell per condition, shared by every model's table).

    Args:
        a: The parsed command line (``--conditions``, ``--max-steps``, ``--expert-chunk``, ``--force``).
        results: The results, whose ``cells`` receive the expert's.
        conds: ``{condition name: Condition}``.
        seeds: The expert's episode seeds.
        save: Called after each cell (merges it into the results file).
    """
    from tqdm import tqdm

    from lerobot_dcdp.benchmark.rollout import expert_identity, expert_rollout

    ident = expert_identity(a.expert_chunk)
    cells = results["cells"]
    todo = [
        c
        for c in a.conditions
        if a.force or not fresh_expert_cell(cells.get(cell_key(EXPERT, EXPERT, c)), ident, seeds, a.max_steps)
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
