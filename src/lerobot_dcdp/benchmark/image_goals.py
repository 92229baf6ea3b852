"""The image protocol's goals (issue 49) as one table: the image base at rest, the corrector that reads pixels
against its base's open loop, and against the privileged rule (the same base, gated anchoring fed the
simulator's keypoints)."""

from __future__ import annotations

from lerobot_dcdp.benchmark.cells import baseline_cell, cell_key
from lerobot_dcdp.benchmark.stats import paired_diff

#: what a corrector reads when it reads pixels only (the env's observation type of its cells)
PIXELS_ONLY = "pixels_agent_pos"
#: the image base at rest
BASE_SUCCESS, BASE_SCORE = 0.50, 0.90
#: the corrector minus open loop, score, at 2.0 px/step (constant and random)
DRIFT_GAIN = 0.15
#: ... at rest: score and success points
REST_SCORE, REST_POINTS = -0.01, -3.0
#: moonshot: within this score of the privileged gated anchoring at 2.0 px/step
MOONSHOT = -0.05
DRIFTS = ("constant_2.0", "random_2.0")


def _pixel_labels(results: dict) -> list[str]:
    """The models whose DCDP cells ran on pixels and the agent position only, in the order first seen."""
    labels = [
        c["model"]
        for c in results["cells"].values()
        if c["method"] == "dcdp" and c.get("obs_type") == PIXELS_ONLY
    ]
    return list(dict.fromkeys(labels))


def _privileged_label(results: dict, label: str) -> str | None:
    """A model on ``label``'s base whose gated anchoring read the simulator's keypoints."""
    models = results.get("models", {})
    base = models.get(label, {}).get("base_weights_sha256")
    for c in results["cells"].values():
        if (
            c["method"] == "gated_anchored"
            and c.get("obs_type") != PIXELS_ONLY
            and c["model"] != label
            and models.get(c["model"], {}).get("base_weights_sha256") == base
        ):
            return c["model"]
    return None


def _row(goal: str, measured: str, margin: float | None, digits: int) -> str:
    verdict = "-" if margin is None else f"{'met' if margin >= 0 else '**missed**'} ({margin:+.{digits}f})"
    return f"| {goal} | {measured} | {verdict} |"


def image_goals(results: dict) -> str:
    """Issue 49's goals for each model whose DCDP read pixels only, each goal measured or ``-`` where its
    cells are missing.

    Args:
        results: The benchmark JSON.

    Returns:
        The tables with their explanations; empty when no DCDP cell read pixels only.
    """
    return "\n\n".join(_model_goals(results, label) for label in _pixel_labels(results))


def _model_goals(results: dict, label: str) -> str:
    """:func:`image_goals`' table for ``label``."""
    cells = results["cells"]

    def get(method: str, condition: str, model: str = label) -> dict | None:
        return baseline_cell(results, model, method, condition)

    def diff(new: dict | None, old: dict | None, key: str, scale: float = 1.0) -> tuple[str, float | None]:
        if not new or not old:
            return "-", None
        d, se = paired_diff(new, old, key)
        return f"{scale * d:+.3f} ± {scale * se:.3f}", scale * d

    lines = [
        f"`{label}` reads the camera and the agent position only; differences are paired over the seeds "
        "(± their standard error). Margin = measured - goal (>= 0: met).",
        "",
        "| goal | measured | verdict |",
        "|---|---|---|",
    ]
    base = get("open_loop", "static")
    if base:
        lines.append(
            _row(
                f"image base at rest: success >= {BASE_SUCCESS:.0%}",
                f"{base['success_rate']:.0%}",
                base["success_rate"] - BASE_SUCCESS,
                2,
            )
        )
        lines.append(
            _row(
                f"image base at rest: score >= {BASE_SCORE:.2f}",
                f"{base['score']:.3f}",
                base["score"] - BASE_SCORE,
                3,
            )
        )
    for c in DRIFTS:
        text, d = diff(get("dcdp", c), get("open_loop", c), "max_rewards")
        lines.append(
            _row(
                f"{c}: DCDP - open loop >= +{DRIFT_GAIN:.2f} score",
                text,
                None if d is None else d - DRIFT_GAIN,
                3,
            )
        )
    text, d = diff(get("dcdp", "static"), base, "max_rewards")
    lines.append(
        _row(
            f"static: DCDP - open loop >= {REST_SCORE:+.2f} score",
            text,
            None if d is None else d - REST_SCORE,
            3,
        )
    )
    text, d = diff(get("dcdp", "static"), base, "successes", 100.0)
    lines.append(
        _row(
            f"static: DCDP - open loop >= {REST_POINTS:+.0f} success points",
            text,
            None if d is None else d - REST_POINTS,
            1,
        )
    )
    text, d = diff(get("dcdp", "constant_0.5"), get("open_loop", "constant_0.5"), "successes", 100.0)
    lines.append(_row("constant_0.5: DCDP success >= open loop (points)", text, d, 1))
    privileged = _privileged_label(results, label)
    for c in DRIFTS:
        ref = cells.get(cell_key(privileged, "gated_anchored", c)) if privileged else None
        text, d = diff(get("dcdp", c), ref, "max_rewards")
        lines.append(
            _row(
                f"moonshot, {c}: DCDP - privileged gated anchoring >= {MOONSHOT:+.2f} score",
                text,
                None if d is None else d - MOONSHOT,
                3,
            )
        )
    return "\n".join(lines)
