"""The figures of the suite's model-based references (written into the output folder)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.figures import cost_violation_axes, errbars, save_figure

COLORS = {"RHC individual": "k", "RHC joint": "0.55", "RHC 3-step": "C4",
          "Linear feedback": "C1", "MJLS LQ": "C2"}  # fmt: skip
MARKERS = {"Linear feedback": "s", "MJLS LQ": "D"}


def make_figures(out: Path, refs: list[Any], aggs: dict[str, Any]) -> list[str]:
    """Write ``fig_<env id>.png`` per task and ``fig_aggregate.png``; return the file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.core.aggregate import SuiteAggregate

    names: list[str] = []

    for t in refs:
        fig, ax = plt.subplots(figsize=(7.5, 5))
        for family in ("RHC individual", "RHC joint", "RHC 3-step"):
            pts = sorted((p for p in t.points if p.family == family), key=lambda p: p.xi)
            text = f"{family} ({pts[0].episodes} episodes), xi = {pts[0].xi:g}..{pts[-1].xi:g}"
            ax.plot([p.violation for p in pts], [p.cost_mean for p in pts], "-",
                    color=COLORS[family], lw=1.2, label=text)  # fmt: skip
            for p in pts:
                errbars(ax, p, fmt="o", color=COLORS[family], ms=3.5)
                if family == "RHC individual" and p.xi == t.xi:
                    ax.annotate(f"xi={p.xi:g}", (p.violation, p.cost_mean), fontsize=7,
                                textcoords="offset points", xytext=(4, 6))  # fmt: skip
        for family, marker in MARKERS.items():
            p = t.at(family)
            errbars(ax, p, fmt=marker, color=COLORS[family], ms=7, label=family)
        title = f"{t.env_id}: n={t.n}, m={t.m}, N={t.N}, r={t.r}, horizon {t.horizon}"
        cost_violation_axes(ax, t.xi, title)
        save_figure(fig, out, f"fig_{t.env_id}.png", names)

    # across tasks: each controller's gap per task, and rliable's performance profiles
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8))
    ax = axes[0]
    tasks = [t.env_id for t in refs]
    families = list(aggs)
    for j, family in enumerate(families):
        y = np.arange(len(tasks)) + 0.15 * (j - (len(families) - 1) / 2)
        label: str | None = family
        for yi, t in zip(y, refs, strict=True):
            p = t.at(family)
            if p.gap is None:
                continue
            # a percentile interval need not contain the point (e.g. 0)
            g, (lo, hi) = p.gap.percent()
            ax.errorbar(g, yi, xerr=[[max(g - lo, 0.0)], [max(hi - g, 0.0)]],
                        fmt=MARKERS.get(family, "o"), color=COLORS[family], ms=5, capsize=2,
                        label=label)  # fmt: skip
            label = None
        a = aggs[family]
        if isinstance(a, SuiteAggregate):
            ax.axvline(a.iqm_gap, color=COLORS[family], ls="--", lw=1,
                       label=f"{family}: IQM {a.iqm_gap:+.1f}%")  # fmt: skip
    ax.axvline(0.0, color="k", lw=1)
    ax.set_yticks(np.arange(len(tasks)), tasks, fontsize=8)
    ax.set_xscale("symlog", linthresh=10.0)
    ticks = [-300, -100, -30, -10, -5, 0, 5, 10, 30, 100, 300]
    ax.set_xticks(ticks, [f"{v:+d}" if v else "0" for v in ticks], fontsize=8)
    ax.invert_yaxis()  # the suite's order, top to bottom
    ax.set_xlabel("gap to the one-step RHC curve, % of its cost (95% CI); missing: outside")
    ax.set_title("Each controller at the task's level xi (and the baselines)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    profiles = {f: a for f, a in aggs.items() if isinstance(a, SuiteAggregate)}
    if profiles:
        from rliable import plot_utils

        a0 = next(iter(profiles.values()))
        plot_utils.plot_performance_profiles(
            {f: a.profile for f, a in profiles.items()}, a0.profile_taus,
            performance_profile_cis={f: a.profile_ci95 for f, a in profiles.items()},
            colors={f: COLORS[f] for f in profiles}, ax=axes[1],
            xlabel=r"improvement over the one-step RHC, % ($\tau$)",
            ylabel=r"fraction of tasks with improvement $> \tau$",
        )  # fmt: skip
        axes[1].legend(fontsize=8)
        axes[1].set_title("Performance profiles (rliable; controllers with a gap on every task)")
    else:
        axes[1].set_axis_off()
    save_figure(fig, out, "fig_aggregate.png", names)
    return names
