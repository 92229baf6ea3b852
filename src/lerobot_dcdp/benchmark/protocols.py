"""The benchmark's protocols: the methods, the shipped correctors it runs by default, which rows each of
them runs, and the ``main`` and ``mild`` presets that ``--protocol`` fills the unset flags from."""

from __future__ import annotations

import argparse

from lerobot_dcdp.benchmark import shipped_model
from lerobot_dcdp.benchmark.cells import EXPERT

METHODS = [
    "open_loop",
    "closed_loop",
    "temporal_ensemble",
    "object_anchored",
    "gated_anchored",
    "dcdp",
    "bid",
]
#: the methods a protocol runs unless ``--methods`` names others: BID (30 sampled chunks per control step,
#: ~25 min of one CPU core per 10 drifting episodes here) only on request, e.g. ``--methods bid``
PRESET_METHODS = [m for m in METHODS if m != "bid"]
#: BID's weak reference policy per model label (an early checkpoint of the model's base, same statistics)
BID_WEAK = {
    "diffusion": shipped_model("pusht-diffusion-state-weak"),
    "diffusion_demos": shipped_model("pusht-diffusion-state-weak"),
}
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
#: the image protocol's models: the image corrector (its anchoring reads the keypoint reader, from pixels),
#: the same with a completion gate on the reader's estimate, the paper's recipe on images (reconstruction
#: through the base's encoder), and the privileged reference (the bare image base, gated anchoring fed the
#: simulator's keypoints); a folder not built yet is skipped
IMAGE_MODELS = {
    "image": shipped_model("pusht-dcdp-image"),
    "image_gated": shipped_model("pusht-dcdp-image-gated"),
    "image_paper_recipe": shipped_model("pusht-dcdp-image-paper-recipe"),
    "image_privileged_gated": shipped_model("pusht-diffusion-image-anchored-gated"),
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


def protocols() -> dict[str, dict]:
    """The named protocols: the defaults ``--protocol`` fills in for every flag not given explicitly.

    Returns:
        ``{"main": preset, "mild": preset}``; a preset's ``models`` of ``None`` means ``DEFAULT_MODELS``.
    """
    from lerobot_dcdp.benchmark.rollout import MAIN_CONDITIONS, MILD_CONDITIONS

    return {
        "main": {
            "models": None,  # DEFAULT_MODELS
            "model_methods": DEFAULT_METHODS,  # these share their base with another: their DCDP row only
            "methods": PRESET_METHODS,
            "conditions": MAIN_CONDITIONS,
            "episodes": 50,
            "latency_steps": 300,
            "videos": 2,
            "out": "results/benchmark.json",
            "report": "docs/RESULTS.md",
            "realtime": "results/realtime",  # the real-time summaries the report shows
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
        "image": {
            "models": IMAGE_MODELS,
            "model_methods": {
                "image_gated": ["dcdp"],
                "image_paper_recipe": ["dcdp"],
                "image_privileged_gated": ["gated_anchored"],
            },
            "methods": ["open_loop", "closed_loop", "object_anchored", "gated_anchored", "dcdp"],
            "conditions": ["static", "constant_0.5", "constant_2.0", "random_2.0"],
            "episodes": 100,
            "latency_steps": 300,
            "videos": 2,
            "out": "results/benchmark_image.json",
            "report": "docs/RESULTS_IMAGE.md",
            "realtime": None,
        },
    }


def model_methods(a: argparse.Namespace, label: str) -> list[str]:
    """The base/corrector methods run for ``label`` (before ``runs`` checks what the folder can run)."""
    return [m for m in a.methods if m != EXPERT and m in a.model_methods.get(label, METHODS)]
