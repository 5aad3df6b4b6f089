"""The figures of ``python -m benchmarks.reproduce_paper`` (section 6 of the paper and two beyond)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.core.montecarlo import Rollouts

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

KINDS = ("individual", "joint", "bonferroni")


def row_labels(model) -> list[str]:
    """What a violation of each row of ``G x <= H_k`` means, e.g. ``x(2) below the band``."""
    labels = []
    for g in np.asarray(model.G, dtype=np.float64):
        (nz,) = np.nonzero(g)
        if len(nz) == 1:
            side = "below" if g[nz[0]] < 0 else "above"
            labels.append(f"x({nz[0] + 1}) {side} the band")
        else:
            labels.append("row of G x <= H_k")
    return labels


def _band(ax, model, T: int) -> None:
    ks = np.arange(T + 1)
    H = model.H(ks)
    ax.plot(ks, -H[:, 0], "r-", lw=1.5, label="target band $H_k$")
    ax.plot(ks, H[:, 1], "r-", lw=1.5)


def _time_axis(ax) -> None:
    """k is an integer (quarters): integer ticks only, preferably whole years (steps of 4)."""
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 4, 5, 10]))
    ax.set_xlabel("k (quarters)")


def _incomes(
    ax, model, ro: Rollouts, runs: int, title: str, legend: bool = True, ylabel: bool = True
) -> None:
    T = ro.x.shape[1] - 1
    ks = np.arange(T + 1)
    for i in range(min(runs, ro.runs)):
        ax.plot(
            ks,
            ro.x[i, :, 1],
            color="C0",
            lw=0.6,
            alpha=0.6,
            label="income $x_k(2)$" if i == 0 else None,
        )
    _band(ax, model, T)
    _time_axis(ax)
    if ylabel:
        ax.set_ylabel("national income $x_k(2)$")
    ax.set_title(title)
    if legend:
        ax.legend(loc="upper left")
    ax.grid(alpha=0.3)


def _calibration(fig, calib: dict, labels: list[str], T: int) -> None:
    """(a) each row's violation frequency, (b) the any-row frequency, against 1 - xi."""
    from matplotlib.lines import Line2D

    colors = dict(zip(KINDS, ("C0", "C1", "C2"), strict=True))
    row_style = (("o", "-"), ("^", ":"))
    axes = fig.subplots(1, 2)
    for ax in axes:
        ax.plot([0, 1], [0, 1], "k--", lw=1)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_aspect("equal")
        ax.set_xlabel("allowed violation probability $1 - \\xi$")
        ax.grid(alpha=0.3)

    def draw(ax, x, y, lo, hi, feasible, color, marker, ls, alpha=1.0) -> None:
        ax.plot(x, y, ls, color=color, lw=1, alpha=0.6 * alpha)
        ax.errorbar(x, y, yerr=[y - lo, hi - y], fmt="none", ecolor=color, alpha=alpha)
        ax.plot(x[feasible], y[feasible], marker, color=color, alpha=alpha, ms=6)
        ax.plot(x[~feasible], y[~feasible], marker, mfc="white", color=color, alpha=alpha, ms=6)

    for kind in KINDS:
        pts = calib[kind]
        x = np.array([1 - p["xi"] for p in pts])
        feasible = np.array([p["rho_positive_share"] == 0 for p in pts])
        for j, (marker, ls) in enumerate(row_style[: len(pts[0]["violation_rows"])]):
            rows = [p["violation_rows"][j] for p in pts]
            y = np.array([row["freq"] for row in rows])
            lo, hi = np.array([row["wilson95"] for row in rows]).T
            draw(axes[0], x, y, lo, hi, feasible, colors[kind], marker, ls)
        y = np.array([p["violation_any"]["freq"] for p in pts])
        lo, hi = np.array([p["violation_any"]["wilson95"] for p in pts]).T
        draw(
            axes[1],
            x,
            y,
            lo,
            hi,
            feasible,
            colors[kind],
            "s",
            "-",
            0.35 if kind == "individual" else 1.0,
        )

    guarantee = Line2D([], [], color="k", ls="--", lw=1, label="$y = 1 - \\xi$ (the guarantee)")
    hollow = Line2D(
        [],
        [],
        ls="none",
        marker="o",
        mfc="white",
        color="gray",
        label="hollow: $\\rho_k > 0$ (no guarantee)",
    )
    kind_handles = [Line2D([], [], color=colors[k], lw=2, label=k) for k in KINDS]
    row_handles = [
        Line2D([], [], color="k", marker=m, ls=ls, label=f"row {j}: {labels[j]}")
        for j, (m, ls) in enumerate(row_style[: len(labels)])
    ]
    axes[0].set_ylabel("observed per-row violation frequency")
    axes[0].set_title("(a) each row (guaranteed for all three kinds)")
    axes[0].legend(
        handles=[guarantee, *kind_handles, *row_handles, hollow], loc="upper left", fontsize=9
    )
    any_handles = [
        Line2D([], [], color=colors["joint"], marker="s", label="joint: any row"),
        Line2D([], [], color=colors["bonferroni"], marker="s", label="bonferroni: any row"),
        Line2D(
            [], [], color=colors["individual"], marker="s", alpha=0.35,
            label="individual: any row\n(not guaranteed, shown for reference)",
        ),
    ]  # fmt: skip
    axes[1].set_ylabel("observed any-row violation frequency")
    axes[1].set_title("(b) any row (guaranteed for joint, Bonferroni)")
    axes[1].legend(handles=[guarantee, *any_handles, hollow], loc="upper left", fontsize=9)
    fig.suptitle(
        f"Calibration: {calib['runs']} runs x {T} steps per point, bars are 95% Wilson intervals"
    )


def make_figures(
    out: Path, runs: int, model, ro_fig: dict[str, Rollouts], calib: dict, ms: dict
) -> list[str]:
    """Write the figures of section 6 and the two beyond it into ``out``; their file names.

    ``runs``: trajectories drawn per income panel; ``calib``: the calibration grid's summaries
    per constraint kind; ``ms``: the mean-square data (``empirical``, ``bound``, ``runs``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    style: dict[RcKeyType, Any] = {
        "font.size": 11,
        "axes.titlesize": 12,
        "axes.labelsize": 11,
        "legend.fontsize": 10,
        "xtick.labelsize": 10,
        "ytick.labelsize": 10,
    }

    def save(fig, name: str) -> None:
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        names.append(name)

    with plt.rc_context(style):
        sample = ro_fig["individual_0.85"]
        T = sample.x.shape[1] - 1
        save(_mode_figure(model, sample, T), "fig_mode.png")
        save(_cost_figure(sample, T), "fig_cost.png")
        save(_income_figure(model, ro_fig, runs), "fig_income_individual_joint.png")
        save(_income_xi_figure(model, ro_fig, runs), "fig_income_xi.png")
        fig = plt.figure(figsize=(11, 6), layout="constrained")
        _calibration(fig, calib, row_labels(model), T)
        save(fig, "fig_calibration.png")
        save(_mean_square_figure(ms, T), "fig_mean_square.png")
    return names


def _mode_figure(model, sample: Rollouts, T: int) -> Any:
    """A sample evolution of the mode (fig. ex_mode)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.4), layout="constrained")
    ax.step(np.arange(T + 1), sample.mode[0] + 1, where="post", color="k")
    ax.set_yticks([1, 2, 3], [f"{i + 1}: {nm}" for i, nm in enumerate(model.mode_names)])
    _time_axis(ax)
    ax.set_ylabel(r"mode $\theta_k$")
    ax.set_title("A sample evolution of $\\theta_k$ (fig. ex_mode)")
    ax.grid(alpha=0.3)
    return fig


def _cost_figure(sample: Rollouts, T: int) -> Any:
    """The optimal cost of the same sample (fig. ex_input)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.4), layout="constrained")
    ax.plot(np.arange(T), sample.J[0], "o-", color="C1")
    _time_axis(ax)
    ax.set_ylabel("$J_k^*$")
    ax.set_title("Optimal cost $J_k^*$ of the same sample (fig. ex_input)")
    ax.grid(alpha=0.3)
    return fig


def _income_figure(model, ro_fig: dict[str, Rollouts], runs: int) -> Any:
    """Incomes under individual and joint constraints at xi = 0.85 (figs. ex_stateMC,
    ex_state_joint)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.9), sharey=True, layout="constrained")
    _incomes(
        axes[0],
        model,
        ro_fig["individual_0.85"],
        runs,
        "Individual, $\\xi=0.85$ (fig. ex_stateMC)",
    )
    _incomes(
        axes[1],
        model,
        ro_fig["joint_0.85"],
        runs,
        "Joint, $\\xi=0.85$ (fig. ex_state_joint)",
        legend=False,
        ylabel=False,
    )
    return fig


def _income_xi_figure(model, ro_fig: dict[str, Rollouts], runs: int) -> Any:
    """Incomes under individual constraints at three xi (fig. eco_income_compare)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(10, 3.9), sharey=True, layout="constrained")
    for i, (ax, xi) in enumerate(zip(axes, (0.95, 0.5, 0.3), strict=True)):
        _incomes(
            ax,
            model,
            ro_fig[f"individual_{xi}"],
            runs,
            f"$\\xi = {xi}$",
            legend=i == 0,
            ylabel=i == 0,
        )
    fig.suptitle("Individual constraints with different $\\xi$ (fig. eco_income_compare)")
    return fig


def _mean_square_figure(ms: dict, T: int) -> Any:
    """The Monte Carlo mean square against Proposition 1's bound."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), layout="constrained")
    ks = np.arange(T + 1)
    ax.semilogy(ks, ms["empirical"], "o-", label=f"Monte Carlo $E\\|x_k\\|^2$ ({ms['runs']} runs)")
    ax.semilogy(
        ks,
        ms["bound"],
        "-",
        color="C3",
        label="Proposition 1 bound $\\beta_1\\|x_0\\|^2 q^k + \\beta_2$",
    )
    _time_axis(ax)
    ax.set_ylabel("$E\\|x_k\\|^2$")
    ax.set_title("Mean-square bound ($\\xi = 0.85$, individual)")
    ax.legend(fontsize=9)
    ax.grid(alpha=0.3, which="both")
    return fig
