"""The hidden setting's figures: per task, cost against violation of every design with the
oracle's curve, and across tasks, each design's IQM of the bounded gaps of its kept runs to the
oracle's curves (every run counts: +100 for a diverged run or one riskier than the curve)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from benchmarks.core.figures import cost_violation_axes, interval_point, save_figure
from benchmarks.core.frontier import WORST_GAP
from benchmarks.hidden.score import BELIEF, CE, TaskResult
from benchmarks.hidden.summary import DesignAcross

__all__ = ["across_figure", "task_figure"]

#: Colours and markers of the model-based designs; the agents' configurations take the others.
STYLE = {CE: ("C0", "s"), BELIEF: ("C3", "D")}
AGENT_COLORS = ("C1", "C2", "C4", "C5", "C6", "C8", "C9")


def _plt() -> object:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def task_figure(out: Path, r: TaskResult) -> list[str]:
    """``fig_<task>_cost_violation.png``: the oracle's curve (its point at the task's xi a star),
    the controllers, each agent configuration's seeds (small) and their median (large); a
    design with a diverged episode is drawn hollow. Returns the file names."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5.5))  # type: ignore[attr-defined]
    pts = sorted(r.curve, key=lambda p: p["violation"])
    ax.plot([p["violation"] for p in pts], [max(p["cost_mean"], 1e-12) for p in pts], "-",
            color="k", lw=1.2, label=f"oracle's curve (RHC seeing the mode), xi = "
            f"{min(p['xi'] for p in pts):g}..{max(p['xi'] for p in pts):g}")  # fmt: skip
    for d in r.designs:
        hollow = {"mfc": "none"} if d.diverged else {}
        if d.kind == "oracle":
            interval_point(ax, d.violation, d.violation_wilson95, d.cost_mean, d.cost_ci95,
                           fmt="*", ms=13, color="k", label=f"oracle at xi = {r.xi:g}")  # fmt: skip
        elif d.kind == "controller":
            color, marker = STYLE.get(d.configuration, ("C7", "o"))
            interval_point(ax, d.violation, d.violation_wilson95, d.cost_mean, d.cost_ci95,
                           fmt=marker, ms=8, color=color, label=d.name
                           + (f" ({d.diverged} diverged)" if d.diverged else ""), **hollow)  # fmt: skip
    configs = list(dict.fromkeys(d.configuration for d in r.of("agent")))
    for i, config in enumerate(configs):
        rows = [d for d in r.of("agent") if d.configuration == config]
        color = AGENT_COLORS[i % len(AGENT_COLORS)]
        for d in rows:
            ax.plot(d.violation, d.cost_mean, "o" if not d.diverged else "x", color=color,
                    alpha=0.5, ms=4)  # fmt: skip
        bounded = sum(d.diverged == 0 for d in rows)
        vs = sorted(d.violation for d in rows)
        cs = sorted(d.cost_mean for d in rows)
        ax.plot(vs[len(vs) // 2], cs[len(cs) // 2], "o", ms=9, color=color,
                mfc=None if bounded == len(rows) else "none",
                label=f"{config}: median of {len(rows)} seed(s), {bounded} bounded")  # fmt: skip
    cost_violation_axes(ax, r.xi, f"{r.env_id}, mode hidden (hollow, x: episodes diverged)")
    names: list[str] = []
    save_figure(fig, out, f"fig_{r.env_id}_cost_violation.png", names)
    return names


def across_figure(out: Path, across: Sequence[DesignAcross]) -> list[str]:
    """``fig_across_tasks.png``: each design's IQM of its bounded gaps to the oracle's curves
    (every kept run counts, :func:`benchmarks.core.frontier.bounded_gap`) with its 95% interval,
    and the (seeds x tasks) runs it covers (empty when no design has a kept run)."""
    rows = [a for a in across if a.aggregate is not None]
    if not rows:
        return []
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(rows) + 1.5))  # type: ignore[attr-defined]
    for i, a in enumerate(rows):
        g = a.aggregate
        assert g is not None
        lo, hi = g.iqm_gap_ci95
        ax.errorbar(g.iqm_gap, i, xerr=[[max(g.iqm_gap - lo, 0)], [max(hi - g.iqm_gap, 0)]],
                    fmt="o", capsize=3, color="k")  # fmt: skip
    ax.set_yticks(range(len(rows)))
    labels = [f"{a.configuration} ({len(a.seeds) or 1} seed(s) x {len(a.tasks)} task(s))"
              for a in rows]  # fmt: skip
    ax.set_yticklabels(labels, fontsize=8)
    ax.axvline(0.0, color="r", ls=":", lw=1)
    ax.set_xlabel(
        f"IQM of the bounded gaps to the oracle's curve, % of its cost (95% "
        f"interval)\n+{WORST_GAP:g}: a diverged run or one riskier than the curve"
    )
    ax.set_title("The price of the hidden mode across tasks, every run counts (rliable)")
    ax.grid(alpha=0.3)
    names: list[str] = []
    save_figure(fig, out, "fig_across_tasks.png", names)
    return names
