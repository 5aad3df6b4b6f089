"""The figures of the suite comparison's report (:mod:`benchmarks.rl.suite_report`).

Per task: ``fig_<env id>_cost_violation.png`` (both model-based curves and the agents) and
``fig_<env id>_learning_curves.png``; across tasks: ``fig_aggregate.png`` (IQM and probabilities
of improvement per configuration), ``fig_profiles.png`` (rliable's performance profiles against
the one-step RHC and the 3-step tree) and ``fig_sample_efficiency.png`` (the IQM of the
normalized gap along training). Each is written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.figures import cost_violation_axes, errbars, interval_point, save_figure
from benchmarks.rl.figures import ALGO_COLORS, VARIANT_MARKERS
from benchmarks.rl.report import fmt_steps

__all__ = ["CONFIG_COLORS", "across_figures", "task_figures"]

#: One color per configuration of the suite (and any other, by its algorithm).
CONFIG_COLORS = {"ppo_reward": "C0", "ppo_residual": "C9", "ppo_lagrangian": "C3",
                 "sac_lagrangian": "C1", "td3_lagrangian": "C2"}  # fmt: skip
RHC_COLOR, TREE_COLOR = "k", "C4"


def _color(config: str) -> str:
    return CONFIG_COLORS.get(config, ALGO_COLORS.get(config.split("_")[0], "C7"))


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _steps_axis(ax: Any, first: float) -> None:
    """Env steps on a symmetric-log axis from 0 (the untrained policy), linear up to ``first``
    (the first point after it), labelled 1k, 200k, 1.2M."""
    from matplotlib.ticker import FuncFormatter

    ax.set_xscale("symlog", linthresh=max(float(first), 1.0))
    ax.set_xlim(left=0.0)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: fmt_steps(int(round(max(v, 0))))))


def task_figures(out: Path, r: Any) -> list[str]:
    """The cost-violation and learning-curve figures of one task's report
    (:class:`benchmarks.rl.suite_report.TaskReport`); returns their file names."""
    plt = _plt()
    names: list[str] = []
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for curve, color, label in ((r.rhc, RHC_COLOR, "one-step RHC"),
                                (r.tree, TREE_COLOR, "3-step tree")):  # fmt: skip
        pts = sorted((curve.point(i) for i in range(len(curve.xis))), key=lambda p: p["violation"])
        ax.plot([p["violation"] for p in pts], [p["cost_mean"] for p in pts], "-", color=color,
                lw=1.2, label=f"{label} ({curve.episodes} episodes), xi = "
                f"{min(curve.xis):g}..{max(curve.xis):g}")  # fmt: skip
        for p in pts:
            interval_point(ax, p["violation"], p["violation_wilson95"], p["cost_mean"],
                           p["cost_ci95"], fmt="o", ms=3.5, color=color)  # fmt: skip
    flat = {(s.algo, s.variant): s.flat for s in r.status}
    for a in r.aggregates:
        config = f"{a.algo}_{a.variant}"
        still = not flat.get((a.algo, a.variant), True)
        errbars(ax, a, fmt=VARIANT_MARKERS.get(a.variant, "o"), color=_color(config), ms=8,
                 mfc="none" if still else None,
                 label=f"{a.name} ({a.seeds} seed(s))" + (" (still learning)" if still else ""))  # fmt: skip
        for ag in r.agents:  # each seed, small
            if ag.config == config:
                s = ag.result.score
                ax.plot(s.violation, s.cost_mean, ".", color=_color(config), alpha=0.5)
    cost_violation_axes(
        ax, r.xi, f"{r.env_id}: agents (seeds pooled; dots: each seed) against both curves"
    )
    save_figure(fig, out, f"fig_{r.env_id}_cost_violation.png", names)

    fig, axes = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    ref = r.rhc.point(r.rhc.xis.index(r.xi))
    for config in dict.fromkeys(a.config for a in r.agents):
        curves = [a.run.learning_curve for a in r.agents if a.config == config]
        n = min(len(c) for c in curves)
        steps = np.array([p.timesteps for p in curves[0][:n]])
        for ax, key in zip(axes, ("episode_cost_median", "violation"), strict=True):
            vals = np.array([[getattr(p, key) for p in c[:n]] for c in curves])
            ax.plot(steps, vals.mean(axis=0), "-o", ms=3, color=_color(config),
                    label=f"{config} ({len(curves)} seed(s))")  # fmt: skip
            ax.fill_between(steps, vals.min(axis=0), vals.max(axis=0), color=_color(config),
                            alpha=0.15)  # fmt: skip
    axes[0].axhline(ref["cost_median"], color="k", ls="--", lw=1, label=f"RHC xi={r.xi:g}")
    axes[1].axhline(1 - r.xi, color="r", ls=":", lw=1, label="1 - xi")
    axes[0].set_yscale("log")
    axes[0].set_ylabel("median episode cost (curve episodes)")
    axes[1].set_ylabel("violation frequency")
    axes[1].set_ylim(-0.02, 1.02)
    axes[1].set_xlabel("training env steps (mean over seeds, band min to max)")
    first = [p.timesteps for a in r.agents for p in a.run.learning_curve if p.timesteps > 0]
    _steps_axis(axes[1], min(first, default=1000))
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    axes[0].set_title(f"{r.env_id}: learning curves")
    save_figure(fig, out, f"fig_{r.env_id}_learning_curves.png", names)
    return names


def across_figures(out: Path, across: list[Any], efficiency: dict[str, dict[str, list]],
                   reports: list[Any]) -> list[str]:  # fmt: skip
    """The figures across tasks (:class:`benchmarks.rl.suite_report.ConfigAcross` per
    configuration, :func:`~benchmarks.rl.suite_report.sample_efficiency`); returns their names."""
    plt = _plt()
    names: list[str] = []
    fig, axes = plt.subplots(1, 2, figsize=(13, 0.6 * len(across) + 2.5))
    y = np.arange(len(across))
    for i, c in enumerate(across):
        for ax, a, dy, color, what in (
            (axes[0], c.bounded_rhc, -0.12, RHC_COLOR, "one-step RHC"),
            (axes[0], c.bounded_tree, 0.12, TREE_COLOR, "3-step tree"),
            (axes[1], c.bounded_rhc, -0.12, RHC_COLOR, "one-step RHC"),
            (axes[1], c.bounded_tree, 0.12, TREE_COLOR, "3-step tree"),
        ):
            if a is None:
                continue
            if ax is axes[0]:
                p, (lo, hi) = a.iqm_gap, a.iqm_gap_ci95
            else:
                p, (lo, hi) = a.probability_of_improvement, a.probability_of_improvement_ci95
            ax.errorbar(p, y[i] + dy, xerr=[[max(p - lo, 0)], [max(hi - p, 0)]], fmt="o",
                        color=color, capsize=3, label=f"against the {what}" if i == 0 else None)  # fmt: skip
    for ax in axes:
        ax.set_yticks(y, [f"{c.config}\n({len(c.bounded_seeds)} x {len(c.bounded_tasks)})"
                          for c in across], fontsize=8)  # fmt: skip
        ax.invert_yaxis()
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        if handles:
            ax.legend(fontsize=8)
    axes[0].axvline(0, color="k", lw=1)
    axes[0].set_xscale("symlog", linthresh=10.0)
    axes[0].set_xlabel("IQM of the bounded gaps, % of the curve's cost (95% CI)")
    axes[0].set_title("IQM across tasks, every run (seeds x tasks per configuration)")
    axes[1].axvline(0.5, color="0.5", ls=":", lw=1)
    axes[1].set_xlim(-0.02, 1.02)
    axes[1].set_xlabel("probability of improvement (95% CI)")
    axes[1].set_title("P(agent cheaper than the curve at its violation frequency)")
    save_figure(fig, out, "fig_aggregate.png", names)

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    for ax, key, what in ((axes[0], "bounded_rhc", "one-step RHC"),
                          (axes[1], "bounded_tree", "3-step tree")):  # fmt: skip
        profiles = {c.config: getattr(c, key) for c in across if getattr(c, key) is not None}
        if not profiles:
            ax.set_axis_off()
            continue
        from rliable import plot_utils

        a0 = next(iter(profiles.values()))
        plot_utils.plot_performance_profiles(
            {k: a.profile for k, a in profiles.items()}, a0.profile_taus,
            performance_profile_cis={k: a.profile_ci95 for k, a in profiles.items()},
            colors={k: _color(k) for k in profiles}, ax=ax,
            xlabel=rf"improvement over the {what}, % ($\tau$)",
            ylabel=r"fraction of runs x tasks with improvement $> \tau$",
        )  # fmt: skip
        ax.legend(fontsize=8)
        ax.set_title(f"Performance profiles against the {what} (rliable)")
    save_figure(fig, out, "fig_profiles.png", names)

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for config, e in efficiency.items():
        steps = np.array(e["steps"], dtype=np.float64)
        lo = np.array([c[0] for c in e["ci95"]])
        hi = np.array([c[1] for c in e["ci95"]])
        ax.plot(steps, e["iqm"], "-o", ms=3, color=_color(config), label=config)
        ax.fill_between(steps, lo, hi, color=_color(config), alpha=0.15)
    ax.axhline(0, color="k", lw=1, label="one-step RHC")
    ax.set_yscale("symlog", linthresh=10.0)
    ax.set_ylabel("IQM of the bounded gap, % (95% CI)")
    ax.set_xlabel("training env steps (points that every run of the configuration has)")
    first = [s for e in efficiency.values() for s in e["steps"] if s > 0]
    _steps_axis(ax, min(first, default=1000))
    ax.grid(alpha=0.3, which="both")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)
    ax.set_title(f"Sample efficiency across {len(reports)} task(s): IQM along training, every run")
    save_figure(fig, out, "fig_sample_efficiency.png", names)
    return names
