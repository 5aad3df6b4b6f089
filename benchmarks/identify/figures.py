"""The figures of ``results/identify/``: the learning curves beside the agents', and the
identification errors.

``fig_learning_curves.png``: a panel per task, the gap to the true-model RHC's curve at equal
risk (%, symmetric-log axis) against environment steps (log axis; a cross at the left edge: an
agent's untrained policy, 0 steps): identify + RHC's median over the seeds with its interquartile band (black),
each agent configuration's median over its seeds (the colors of ``results/rl_suite``'s
figures), the +5% line and the same design on the true model (dotted). A median without a gap
(see :mod:`benchmarks.identify.summary`) is not drawn. ``fig_identification_errors.png``: the
median errors of ``[A B]`` (relative), of the noise covariances (relative) and of the transition
matrices (largest entry) against the steps, a panel per task.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.figures import save_figure
from benchmarks.identify.report import LEARNER
from benchmarks.identify.steps import WITHIN

__all__ = ["CONFIG_COLORS", "GAP_LIMITS", "write_figures"]

#: The agents' colors, as in ``results/rl_suite``'s figures.
CONFIG_COLORS = {"ppo_reward": "C0", "ppo_residual": "C9", "ppo_lagrangian": "C3",
                 "sac_lagrangian": "C1", "td3_lagrangian": "C2"}  # fmt: skip
#: The gap axis (%); a gap beyond it is drawn at its edge.
GAP_LIMITS = (-100.0, 1e4)


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panels(count: int) -> tuple[Any, Any]:
    plt = _plt()
    cols = min(count, 3)
    rows = max(1, math.ceil(count / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 4.2 * rows), squeeze=False)
    for ax in axes.ravel()[count:]:
        ax.set_axis_off()
    return fig, axes.ravel()


def _clip(values: list[float | None]) -> np.ndarray:
    lo, hi = GAP_LIMITS
    return np.array([np.nan if v is None else min(max(v, lo), hi) for v in values])


def _top(values: list[float | None]) -> np.ndarray:
    """The upper quartile for a band: no gap (+inf) is the axis' top."""
    return np.array([GAP_LIMITS[1] if v is None else min(v, GAP_LIMITS[1]) for v in values])


def _learning_panel(ax: Any, t: dict[str, Any]) -> None:
    curve = t["learner"]["curve"]
    steps = np.array([c["steps"] for c in curve], dtype=np.float64)
    left = t["grid"][0] / 2
    for config, a in t["agents"].items():
        color = CONFIG_COLORS.get(config, "C7")
        trained = [c for c in a["curve"] if c["steps"] > 0]
        ax.plot([c["steps"] for c in trained], _clip([c["median"] for c in trained]), "-o", ms=3,
                lw=1.2, color=color, label=f"{config} ({len(a['seeds'])})")  # fmt: skip
        untrained = [c["median"] for c in a["curve"] if c["steps"] == 0]
        ax.plot([left] * len(untrained), _clip(untrained), "x", ms=6, color=color)
    q25 = _clip([c["q25"] for c in curve])
    ok = ~np.isnan(q25)
    ax.fill_between(steps[ok], q25[ok], _top([c["q75"] for c in curve])[ok], color="k",
                    alpha=0.15, lw=0)  # fmt: skip
    ax.plot(steps, _clip([c["median"] for c in curve]), "-", color="k", lw=2,
            label=f"{LEARNER} ({len(t['seeds'])})")  # fmt: skip
    ax.axhline(WITHIN, color="r", ls="--", lw=1, label=f"+{WITHIN:g}%")
    ax.axhline(0.0, color="k", lw=0.8)
    oracle = t["true_model_design"]["gap"]
    if oracle is not None:
        ax.axhline(oracle, color="0.4", ls=":", lw=1.2, label="same design, true model")
    ax.set_yscale("symlog", linthresh=10.0)
    ax.set_ylim(*GAP_LIMITS)
    ax.set_xscale("log")
    ax.set_xlim(left / 1.5, None)
    ax.grid(alpha=0.3, which="both")
    ax.set_title(t["env_id"], fontsize=10)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("gap to the true-model RHC, % (median)")


def _errors_panel(ax: Any, t: dict[str, Any]) -> None:
    curve = t["learner"]["curve"]
    steps = np.array([c["steps"] for c in curve], dtype=np.float64)
    for key, label, color in (("error_AB_median", "[A B], relative", "C0"),
                              ("error_cov_median", "noise covariance, relative", "C1"),
                              ("error_P_median", "P_in, P_out: largest entry", "C2")):  # fmt: skip
        values = np.array([np.nan if c[key] is None else c[key] for c in curve])
        ax.plot(steps, values, "-o", ms=2.5, color=color, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.set_title(t["env_id"], fontsize=10)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("identification error (median over seeds)")


def write_figures(out: Path, tasks: list[dict[str, Any]]) -> list[str]:
    """Both figures of the task summaries ``tasks``; returns their file names."""
    names: list[str] = []
    fig, axes = _panels(len(tasks))
    for ax, t in zip(axes, tasks, strict=False):
        _learning_panel(ax, t)
    handles, labels = axes[0].get_legend_handles_labels()
    below = axes[min(len(tasks), 3) // 2 + (len(tasks) - 1) // 3 * 3]  # bottom row, middle
    below.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=8,
                 ncol=4)  # fmt: skip
    fig.suptitle(f"{LEARNER} against the agents: gap at equal risk along the environment steps "
                 "(band: interquartile range over the seeds)", fontsize=11)  # fmt: skip
    save_figure(fig, out, "fig_learning_curves.png", names)
    fig, axes = _panels(len(tasks))
    for ax, t in zip(axes, tasks, strict=False):
        _errors_panel(ax, t)
    axes[0].legend(fontsize=7)
    save_figure(fig, out, "fig_identification_errors.png", names)
    return names
