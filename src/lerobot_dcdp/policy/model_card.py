"""The Hub model card of a corrector: what DCDP is, the base it corrects, measured numbers, how to run it."""

from __future__ import annotations

import json
from pathlib import Path

from huggingface_hub import ModelCard, ModelCardData


def benchmark_rows(corrector_sha256: str, results_path: str | Path = "results/benchmark.json") -> list[str]:
    """Markdown rows of every benchmark cell measured with exactly this corrector (empty if none)."""
    path = Path(results_path)
    if not path.exists():
        return []
    cells = json.loads(path.read_text()).get("cells", {}).values()
    rows = [
        f"| {c['method']} | {c['condition']} | {100 * c['success_rate']:.0f} % | {c['score']:.3f} "
        f"| {c['episodes']} |"
        for c in cells
        if c.get("identity", {}).get("corrector_sha256") == corrector_sha256
    ]
    return (
        ["| mode | perturbation | success | score | episodes |", "|---|---|---|---|---|", *rows]
        if rows
        else []
    )


_HOW = {
    "residual": "a residual head that adds a learned correction to the planned action",
    "reconstruct": "a GRU decoder that re-decodes the action (the paper's recipe)",
}


def make_model_card(
    config,
    corrector_sha256: str,
    dataset_repo_id: str,
    license: str | None = None,
    tags: list[str] | None = None,
) -> ModelCard:
    """A model card built locally (no Hub round trip, unlike ``ModelCard.validate``)."""
    data = ModelCardData(
        license=license or "apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted(set(tags or []) | {"robotics", "lerobot", "dcdp", str(config.base_policy_type)}),
        model_name="dcdp",
        datasets=dataset_repo_id,
    )
    repo = config.repo_id or "<this repo>"
    rows = benchmark_rows(corrector_sha256)
    numbers = "\n".join(rows) if rows else "Not benchmarked yet: run `dcdp-benchmark --model NAME=<dir>`."
    gate = (
        f"- completion gate: fitted on demonstrations (radius {config.completion_radius:.4g} in the object "
        "keypoints' units): the base's own plan runs uncorrected where the object is nearly where "
        "demonstrations end\n"
        if config.completion_gate and config.completion_radius is not None
        else ""
    )
    if config.lead_steps:
        gate += (
            f"- scene lead: plans and acts in the scene moved {config.lead_steps} steps of the object's own "
            f"motion ahead (the newest displacement {config.lead_repeats} of the last {config.lead_window} "
            "steps repeat), its actions moved back\n"
        )
    text = f"""
# DCDP corrector for a frozen `{config.base_policy_type}` policy

DCDP ("Closed-Loop Action Chunks with Dynamic Corrections for Training-Free Diffusion Policy") keeps a
pretrained chunking policy frozen and adds a small corrector: a dynamic feature extractor over the last
{config.n_history} observations and a chunk encoder, with {_HOW[config.correction]}, for every action of the
base's chunk ({config.n_action_steps} executed steps) at every control step from the newest observations.
This repository holds **the corrector only** ({config.type} plugin `lerobot_policy_dcdp`); the base is loaded
from its own reference.

- base policy: `{config.base_policy_path}` (type `{config.base_policy_type}`)
- base weights sha256: `{config.base_weights_sha256}` (verified at load; a different base is refused)
- trained on: `{dataset_repo_id}`
{gate}
## Measured (`dcdp-benchmark`, PushT, seeds 100000..)

{numbers}

## Run it

```bash
pip install lerobot_policy_dcdp   # the plugin; LeRobot discovers it
lerobot-eval --policy.path={repo} --env.type=pusht_perturbed --env.perturbation=constant \\
    --env.magnitude=0.5 --env.obs_type=environment_state_agent_pos --eval.n_episodes=50 \\
    --eval.batch_size=10 --eval.use_async_envs=false
lerobot-eval --policy.path={repo} ... --policy.execution=open_loop   # the base alone
```
"""
    return ModelCard(f"---\n{data.to_yaml()}\n---\n{text}")
