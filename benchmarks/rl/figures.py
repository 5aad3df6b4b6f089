"""The RL comparison's figures (written into the output folder)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.figures import errbars
from benchmarks.core.score_table import fmt_steps
from benchmarks.core.stats import CurveStatus
from benchmarks.rl.report import Aggregate, ControllerResult, RunResult, curve_xi
from benchmarks.rl.train import VARIANTS

ALGO_COLORS = {"ppo": "C0", "sac": "C1", "td3": "C2"}
VARIANT_MARKERS = dict(zip(VARIANTS, ("o", "v", "^", "<", "*", "X"), strict=True))
SINGLE_MARKERS = ("s", "D", "P", "h", "8")


def shared_legend_entries(axes: Any) -> tuple[list[Any], list[str]]:
    """The labelled artists of every panel in ``axes``, one entry per label, first seen first."""
    entries: dict[str, Any] = {}
    for ax in list(np.ravel(axes)):
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    return list(entries.values()), list(entries)


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _steps_format() -> Any:
    """Env steps as 200k, 1.2M: matplotlib's plain labels of 100000..800000 run into each other."""
    from matplotlib.ticker import FuncFormatter

    return FuncFormatter(lambda v, _: ("-" if v < 0 else "") + fmt_steps(int(round(abs(v)))))


def _save(fig: Any, out: Path, name: str, names: list[str]) -> None:
    fig.tight_layout()
    fig.savefig(out / name, dpi=110)
    _plt().close(fig)
    names.append(name)


def make_figures(
    out: Path,
    curves: list[tuple[str, str, list[ControllerResult]]],
    singles: list[ControllerResult],
    aggs: list[Aggregate],
    runs: list[RunResult],
    status: list[CurveStatus],
    incomes: list[tuple[str, Any, np.ndarray]],
    band: np.ndarray,
    xi: float,
) -> list[str]:
    """Write the figures; return their file names.

    ``curves``: ``(family, color, points)`` of each model-based curve (the first is the
    reference); ``singles``: the other model-based controllers; ``incomes``: ``(title, score,
    trajectories (R, T + 1))`` per panel of the income figure; ``band``: ``H_k`` (T + 1, 2).
    """
    names: list[str] = []
    cost_violation_figure(out, curves, singles, aggs, status, xi, names)
    ref = next((r for r in curves[0][2] if r.xi == xi), None)
    learning_curves_figure(out, runs, ref, xi, names)
    lagrangian_figure(out, runs, xi, names)
    income_figure(out, incomes, band, names)
    return names


def cost_violation_figure(out: Path, curves: list[tuple[str, str, list[ControllerResult]]],
                          singles: list[ControllerResult], aggs: list[Aggregate],
                          status: list[CurveStatus], xi: float, names: list[str]) -> None:  # fmt: skip
    """``fig_cost_violation.png``: everything (log scale), and a zoom on the stable ones."""
    plt = _plt()
    zoom_max = 3.0 * max(p.score.cost_mean for _, _, pts in curves for p in pts)
    flat = {(c.algo, c.variant): c.flat for c in status}
    fig, axes = plt.subplots(1, 2, figsize=(17.5, 6))
    for panel, ax in enumerate(axes):
        keep = (lambda s: True) if panel == 0 else (lambda s: s.cost_mean <= zoom_max)
        for i, (family, color, pts) in enumerate(curves):
            pts = sorted(pts, key=curve_xi)
            ax.plot([r.score.violation for r in pts], [r.score.cost_mean for r in pts], "-",
                    color=color, lw=1.2, label=f"{family}, xi = {pts[0].xi:g}..{pts[-1].xi:g}")  # fmt: skip
            for r in pts:
                errbars(ax, r.score, fmt="o", color=color, ms=4)
                if i == 0 and r.xi in (0.3, 0.5, 0.7, 0.85, 0.99):
                    ax.annotate(f"xi={r.xi:g}", (r.score.violation, r.score.cost_mean),
                                textcoords="offset points", xytext=(3, 6), fontsize=7)  # fmt: skip
        for r, marker in zip(singles, SINGLE_MARKERS, strict=False):
            if keep(r.score):
                errbars(ax, r.score, fmt=marker, color="C7", ms=7, label=r.name)
        for a in aggs:
            if keep(a):
                still = not flat.get((a.algo, a.variant), True)  # hollow: not flat yet
                errbars(ax, a, fmt=VARIANT_MARKERS.get(a.variant, "o"),
                         color=ALGO_COLORS.get(a.algo, "C3"), ms=8, mfc="none" if still else None,
                         label=a.name + (" (still learning)" if still else ""))  # fmt: skip
        ax.axvline(1 - xi, color="r", ls=":", lw=1, label=f"1 - xi = {1 - xi:.2f}")
        ax.set_xlim(-0.02, 1.02)
        ax.set_xlabel("per-step violation frequency (95% Wilson interval)")
        ax.grid(alpha=0.3, which="both")
        if panel == 0:
            ax.set_yscale("log")
            ax.set_ylabel("mean episode cost (95% interval), log scale")
            ax.set_title("All controllers (trained agents: seeds pooled)")
        else:
            ax.set_ylabel("mean episode cost (95% interval)")
            ax.set_title(f"Zoom: mean episode cost <= {zoom_max:.3g}")
    # one legend for both panels: the full panel holds marks (diverging agents) that the zoom
    # leaves out, and every mark of a committed figure is named
    handles, labels = shared_legend_entries(axes)
    fig.legend(handles, labels, fontsize=6.5, ncol=1, loc="center left", bbox_to_anchor=(0.80, 0.5))
    fig.suptitle(
        "Cost against violations: model-based curves over xi, one point per other controller"
    )
    fig.tight_layout(rect=(0, 0, 0.80, 1))
    fig.savefig(out / "fig_cost_violation.png", dpi=110)
    plt.close(fig)
    names.append("fig_cost_violation.png")


def learning_curves_figure(out: Path, runs: list[RunResult], ref: ControllerResult | None,
                           xi: float, names: list[str]) -> None:  # fmt: skip
    """``fig_learning_curves.png``: per algorithm, each variant's median cost and violation
    frequency along training (mean over seeds, band min to max), against the RHC at ``xi``."""
    algos = list(dict.fromkeys(r.run.algo for r in runs))
    if not algos:
        return
    plt = _plt()
    fig, axes = plt.subplots(2, len(algos), figsize=(4.6 * len(algos), 7), squeeze=False)
    for j, algo in enumerate(algos):
        for variant in VARIANTS:
            rs = [r.run for r in runs if (r.run.algo, r.run.variant) == (algo, variant)]
            lcs = [r.learning_curve for r in rs if r.learning_curve]
            if not lcs:
                continue
            n = min(len(c) for c in lcs)
            steps = np.array([p.timesteps for p in lcs[0][:n]])
            for i, key in enumerate(("episode_cost_median", "violation")):
                vals = np.array([[getattr(p, key) for p in c[:n]] for c in lcs])
                ax = axes[i, j]
                (line,) = ax.plot(steps, vals.mean(axis=0), "-o", ms=3, label=variant)
                ax.fill_between(steps, vals.min(axis=0), vals.max(axis=0),
                                color=line.get_color(), alpha=0.15)  # fmt: skip
        if ref is not None:
            axes[0, j].axhline(ref.score.cost_median, color="k", ls="--", lw=1,
                               label=f"RHC xi={xi:g}")  # fmt: skip
            axes[1, j].axhline(ref.score.violation, color="k", ls="--", lw=1,
                               label=f"RHC xi={xi:g}")  # fmt: skip
        axes[0, j].set_yscale("log")
        axes[0, j].set_title(f"{algo.upper()}: median episode cost (eval)")
        axes[1, j].set_title(f"{algo.upper()}: violation frequency (eval)")
        axes[1, j].set_ylim(-0.02, 1.02)
        for i in range(2):
            axes[i, j].set_xlabel("training env steps")
            axes[i, j].xaxis.set_major_formatter(_steps_format())
            axes[i, j].grid(alpha=0.3, which="both")
        axes[0, j].legend(fontsize=7)
    _save(fig, out, "fig_learning_curves.png", names)


def lagrangian_figure(out: Path, runs: list[RunResult], xi: float, names: list[str]) -> None:
    """``fig_lagrangian_beta.png``: the dual ascent of every Lagrangian run."""
    lag = [r.run for r in runs if r.run.variant == "lagrangian" and r.run.dual_ascent]
    if not lag:
        return
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for run in lag:
        at = [p.timesteps for p in run.dual_ascent]
        color, label = ALGO_COLORS.get(run.algo, "C3"), f"{run.algo.upper()} seed {run.seed}"
        axes[0].plot(at, [p.beta for p in run.dual_ascent], color=color, alpha=0.8,
                     label=label)  # fmt: skip
        axes[1].plot(at, [p.freq for p in run.dual_ascent], color=color, alpha=0.8,
                     label=label)  # fmt: skip
        axes[1].plot(at, [p.train_freq for p in run.dual_ascent], color=color, alpha=0.35,
                     ls="--")  # fmt: skip
    axes[1].axhline(1 - xi, color="r", ls=":", label="target 1 - xi")
    axes[0].set_ylabel("beta")
    axes[0].set_yscale("symlog", linthresh=1000.0)
    axes[1].set_ylabel("violation frequency\n(dashed: exploring policy)")
    for ax in axes:
        ax.set_xlabel("training env steps")
        ax.xaxis.set_major_formatter(_steps_format())
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    fig.suptitle("Lagrangian variant: dual ascent on beta")
    _save(fig, out, "fig_lagrangian_beta.png", names)


def income_figure(out: Path, incomes: list[tuple[str, Any, np.ndarray]], band: np.ndarray,
                  names: list[str]) -> None:  # fmt: skip
    """``fig_income.png``: the first income trajectories of each panel's controller."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(incomes), figsize=(5.5 * len(incomes), 3.8), sharey=True,
                             squeeze=False)  # fmt: skip
    ks = np.arange(band.shape[0])
    for ax, (title, score, trajectories) in zip(axes[0], incomes, strict=True):
        for i, traj in enumerate(trajectories):
            ax.plot(ks, traj, color="C0", lw=0.6, alpha=0.6,
                    label="income $x_k(2)$" if i == 0 else None)  # fmt: skip
        ax.plot(ks, -band[:, 0], "r-", lw=1.5, label="target band")
        ax.plot(ks, band[:, 1], "r-", lw=1.5)
        ax.set_title(f"{title}\nviolations {score.violation:.3f}, cost {score.cost_mean:.4g}",
                     fontsize=9)  # fmt: skip
        ax.set_xlabel("k (quarters)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[0, 0].set_ylabel("national income $x_k(2)$")
    axes[0, 0].set_ylim(min(-5.0, float(np.min(band[:, 1])) - 10), float(band[-1, 1]) + 10)
    _save(fig, out, "fig_income.png", names)
