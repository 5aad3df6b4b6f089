"""Reproduce section 6 of the paper (the macroeconomic example) and check its claims with numbers.

Run ``python -m benchmarks.reproduce_paper --help`` for the options. With the defaults it writes
to ``results/paper/``: the paper's figures (a sample mode sequence, its optimal cost J*_k, the
incomes of the Monte Carlo runs under individual and joint chance constraints and for
xi = 0.95, 0.5, 0.3), two figures beyond the paper (calibration of the violation frequency
against 1 - xi, and E||x_k||^2 against the Proposition 1 bound), ``summary.json``,
``summary.csv`` and ``REPORT.md``, whose every number is computed here.

Two sample sizes are used: ``--runs`` trajectories are drawn in the income figures (the paper
draws 50), and ``--stat-runs`` trajectories per configuration back every statistic and every
claim check (the claims compare frequencies that differ by about 0.02, which 50 runs cannot
resolve).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from tqdm import tqdm

from benchmarks.montecarlo import Rollouts, mean_ci, paper_rhc, rollout, wilson
from controllers import verify_mean_square_bound
from sdjls_gym.systems.macro import ACTION_BOUND, HORIZON, PAPER_K, PAPER_RHC, macro

RHO_TOL = 1e-7  # rho below this counts as zero (solver round-off)
CALIBRATION_XIS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.99)
KINDS = ("individual", "joint", "bonferroni")


@dataclass
class Options:
    runs: int = field(
        default=50,
        metadata={"help": "Monte Carlo runs drawn in the income figures (the paper draws 50)"},
    )
    stat_runs: int = field(
        default=2000,
        metadata={
            "help": "runs per configuration behind every statistic, claim check and the calibration figure"
        },
    )
    seed: int = field(
        default=0, metadata={"help": "seed of the noise; the same seed gives the same files"}
    )
    out: Path = field(
        default=Path("results/paper"),
        metadata={"help": "folder for figures, summary files and REPORT.md"},
    )
    no_progress: bool = field(default=False, metadata={"help": "do not show progress bars"})


def parse_args(argv: list[str] | None = None) -> Options:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.reproduce_paper",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    for f in fields(Options):
        flag = "--" + f.name.replace("_", "-")
        if f.type in ("bool", bool):
            parser.add_argument(flag, action="store_true", help=f.metadata["help"])
        else:
            conv = {"int": int, "Path": Path}[
                f.type if isinstance(f.type, str) else f.type.__name__
            ]
            parser.add_argument(flag, type=conv, default=f.default, help=f.metadata["help"])
    ns = parser.parse_args(argv)
    opts = Options(**vars(ns))
    for name in ("runs", "stat_runs"):
        if getattr(opts, name) < 1:
            parser.error(
                f"--{name.replace('_', '-')} = {getattr(opts, name)}; expected a positive integer"
            )
    return opts


# ---------------------------------------------------------------------------- experiments
@dataclass
class Config:
    name: str
    constraint: str
    xi: float


PAPER_CONFIGS = [
    Config("individual_0.85", "individual", 0.85),
    Config("joint_0.85", "joint", 0.85),
    Config("individual_0.95", "individual", 0.95),
    Config("individual_0.5", "individual", 0.5),
    Config("individual_0.3", "individual", 0.3),
]


def summarize(cfg: Config, ro: Rollouts) -> dict[str, Any]:
    """The statistics of one configuration (see the module docstring of the report)."""
    runs, T = ro.rho.shape
    r = ro.violations.shape[-1]
    per_step_any = ro.any_violation.sum(axis=0)
    per_step_rows = ro.violations.sum(axis=0)  # (T, r)
    lo, hi = wilson(per_step_any, runs)
    total = runs * T
    overall_any = int(ro.any_violation.sum())
    overall_rows = ro.violations.sum(axis=(0, 1))
    cost_mean, cost_lo, cost_hi = mean_ci(ro.episode_cost)
    rows_lo, rows_hi = wilson(overall_rows, total)
    any_lo, any_hi = wilson(overall_any, total)
    return {
        "name": cfg.name,
        "constraint": cfg.constraint,
        "xi": cfg.xi,
        "runs": runs,
        "steps": T,
        "violation_any": {"freq": overall_any / total, "wilson95": [float(any_lo), float(any_hi)]},
        "violation_rows": [
            {
                "row": j,
                "freq": float(overall_rows[j] / total),
                "wilson95": [float(rows_lo[j]), float(rows_hi[j])],
            }
            for j in range(r)
        ],
        "per_step": [
            {
                "k_next": k + 1,
                "violation_any": float(per_step_any[k] / runs),
                "wilson95": [float(lo[k]), float(hi[k])],
                "violation_rows": (per_step_rows[k] / runs).tolist(),
            }
            for k in range(T)
        ],
        "rho_positive_share": float(np.mean(ro.rho > RHO_TOL)),
        "rho_max": float(ro.rho.max()),
        "episode_cost": {"mean": cost_mean, "ci95": [cost_lo, cost_hi]},
        "solver_fallbacks": int((~ro.status_ok).sum()),
        "max_abs_u": float(np.abs(ro.u).max()),
    }


def two_proportion_p(s1: int, n1: int, s2: int, n2: int) -> float:
    """One-sided p-value of H0: p1 <= p2 against p1 > p2 (pooled z-test)."""
    p = (s1 + s2) / (n1 + n2)
    se = np.sqrt(p * (1 - p) * (1 / n1 + 1 / n2))
    return float(stats.norm.sf((s1 / n1 - s2 / n2) / se)) if se > 0 else float(s1 / n1 <= s2 / n2)


def check_claims(s: dict[str, dict], ro: dict[str, Rollouts]) -> list[dict[str, Any]]:
    """One row per claim of section 6: what the paper says, what was measured, agreement."""

    def viol(name: str) -> tuple[int, int]:
        return int(ro[name].any_violation.sum()), ro[name].any_violation.size

    def pct(x: float) -> str:
        return f"{100 * x:.2f}%"

    claims = []
    ind, joint = s["individual_0.85"], s["joint_0.85"]
    claims.append(
        {
            "claim": "rho_k = 0 for all k (xi = 0.85, individual constraints)",
            "paper": "we obtain rho_k as zero for all k",
            "measured": f"max rho_k = {ind['rho_max']:.2e} over {ind['runs']} runs x {ind['steps']} steps",
            "agree": ind["rho_max"] <= RHO_TOL,
        }
    )
    row_ok = all(row["wilson95"][0] <= 1 - 0.85 for row in ind["violation_rows"])
    claims.append(
        {
            "claim": "occasional constraint violations (xi = 0.85, individual)",
            "paper": "one can observe occasional constraint violations",
            "measured": (
                f"any-row violation frequency {pct(ind['violation_any']['freq'])} "
                f"(95% CI {pct(ind['violation_any']['wilson95'][0])}-{pct(ind['violation_any']['wilson95'][1])}); "
                "per row "
                + ", ".join(pct(row["freq"]) for row in ind["violation_rows"])
                + " against the allowed 1 - xi = 15%"
            ),
            "agree": 0 < ind["violation_any"]["freq"] and row_ok,
        }
    )
    p_value = two_proportion_p(*viol("individual_0.85"), *viol("joint_0.85"))
    claims.append(
        {
            "claim": "fewer violations with joint than with individual constraints (xi = 0.85)",
            "paper": "more constraint violations with individual probabilistic constraints",
            "measured": (
                f"any-row frequency individual {pct(ind['violation_any']['freq'])}, joint "
                f"{pct(joint['violation_any']['freq'])} (one-sided two-proportion test p = {p_value:.2g})"
            ),
            "agree": joint["violation_any"]["freq"] < ind["violation_any"]["freq"]
            and p_value < 0.05,
        }
    )
    claims.append(
        {
            "claim": "rho_k > 0 for some k with joint constraints (xi = 0.85)",
            "paper": "we obtain rho_k > 0, for some k",
            "measured": f"rho_k > 0 at {pct(joint['rho_positive_share'])} of steps, max rho_k = {joint['rho_max']:.3f}",
            "agree": joint["rho_positive_share"] > 0,
        }
    )
    order = ["individual_0.3", "individual_0.5", "individual_0.85", "individual_0.95"]
    freqs = [s[name]["violation_any"]["freq"] for name in order]
    pairs_p = [two_proportion_p(*viol(a), *viol(b)) for a, b in zip(order, order[1:], strict=False)]
    claims.append(
        {
            "claim": "larger xi meets the target better",
            "paper": "the larger the level of constraint satisfaction xi, the better the incomes meet the required target",
            "measured": "any-row violation frequency at xi = 0.3, 0.5, 0.85, 0.95: "
            + ", ".join(pct(f) for f in freqs)
            + " (one-sided tests of each decrease: p = "
            + ", ".join(f"{p:.2g}" for p in pairs_p)
            + ")",
            "agree": all(a > b for a, b in zip(freqs, freqs[1:], strict=False))
            and max(pairs_p) < 0.05,
        }
    )
    low_xi = [s["individual_0.5"]["rho_max"], s["individual_0.3"]["rho_max"]]
    hi = s["individual_0.95"]
    claims.append(
        {
            "claim": "rho_k = 0 at xi = 0.5 and 0.3; rho_k > 0 for some k at xi = 0.95",
            "paper": "rho_k as zero, for all k, when xi is 0.5 and 0.3; rho_k > 0, for some k, when xi is 0.95",
            "measured": (
                f"max rho_k = {low_xi[0]:.1e} (xi = 0.5), {low_xi[1]:.1e} (xi = 0.3); at xi = 0.95 rho_k > 0 at "
                f"{pct(hi['rho_positive_share'])} of steps (max {hi['rho_max']:.3f})"
            ),
            "agree": max(low_xi) <= RHO_TOL and hi["rho_positive_share"] > 0,
        }
    )
    return claims


# ---------------------------------------------------------------------------- figures
def _band(ax, model, T: int) -> None:
    ks = np.arange(T + 1)
    H = model.H(ks)
    ax.plot(ks, -H[:, 0], "r-", lw=1.5, label="target band $H_k$")
    ax.plot(ks, H[:, 1], "r-", lw=1.5)


def _incomes(ax, model, ro: Rollouts, runs: int, title: str) -> None:
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
    ax.set_xlabel("k (quarters)")
    ax.set_ylabel("national income $x_k(2)$")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)


def make_figures(
    opts: Options, model, ro_fig: dict[str, Rollouts], calib: dict, ms: dict
) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = opts.out
    names = []

    def save(fig, name: str) -> None:
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        names.append(name)

    sample = ro_fig["individual_0.85"]
    T = sample.x.shape[1] - 1
    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    ax.step(np.arange(T + 1), sample.mode[0] + 1, where="post", color="k")
    ax.set_yticks([1, 2, 3], [f"{i + 1}: {nm}" for i, nm in enumerate(model.mode_names)])
    ax.set_xlabel("k (quarters)")
    ax.set_ylabel(r"mode $\theta_k$")
    ax.set_title("A sample evolution of $\\theta_k$ (fig. ex_mode)")
    ax.grid(alpha=0.3)
    save(fig, "fig_mode.png")

    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    ax.plot(np.arange(T), sample.J[0], "o-", color="C1")
    ax.set_xlabel("k (quarters)")
    ax.set_ylabel("$J_k^*$")
    ax.set_title("Optimal cost $J_k^*$ of the same sample (fig. ex_input)")
    ax.grid(alpha=0.3)
    save(fig, "fig_cost.png")

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    _incomes(
        axes[0],
        model,
        ro_fig["individual_0.85"],
        opts.runs,
        "Individual constraints, $\\xi=0.85$ (fig. ex_stateMC)",
    )
    _incomes(
        axes[1],
        model,
        ro_fig["joint_0.85"],
        opts.runs,
        "Joint constraints, $\\xi=0.85$ (fig. ex_state_joint)",
    )
    save(fig, "fig_income_individual_joint.png")

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    for ax, xi in zip(axes, (0.95, 0.5, 0.3), strict=True):
        _incomes(ax, model, ro_fig[f"individual_{xi}"], opts.runs, f"$\\xi = {xi}$")
    fig.suptitle("Individual constraints with different $\\xi$ (fig. eco_income_compare)")
    save(fig, "fig_income_xi.png")

    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="$y = 1 - \\xi$ (the guarantee)")
    for kind, color in zip(KINDS, ("C0", "C1", "C2"), strict=True):
        pts = calib[kind]
        x = np.array([1 - p["xi"] for p in pts])
        if kind == "individual":
            y = np.array([max(row["freq"] for row in p["violation_rows"]) for p in pts])
            label = "individual: largest per-row frequency"
        else:
            y = np.array([p["violation_any"]["freq"] for p in pts])
            label = f"{kind}: any-row frequency"
        feasible = np.array([p["rho_positive_share"] == 0 for p in pts])
        ax.plot(x, y, "-", color=color, lw=1, alpha=0.6)
        ax.plot(x[feasible], y[feasible], "o", color=color, label=label)
        ax.plot(x[~feasible], y[~feasible], "o", mfc="none", color=color)
    ax.plot(
        [],
        [],
        "o",
        mfc="none",
        color="gray",
        label="hollow: $\\rho_k > 0$ at some step (no guarantee)",
    )
    ax.set_xlabel("allowed violation probability $1 - \\xi$")
    ax.set_ylabel("observed violation frequency")
    ax.set_title(f"Calibration ({calib['runs']} runs x {T} steps per point)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    save(fig, "fig_calibration.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    ks = np.arange(T + 1)
    ax.semilogy(ks, ms["empirical"], "o-", label=f"Monte Carlo $E\\|x_k\\|^2$ ({ms['runs']} runs)")
    ax.semilogy(
        ks,
        ms["bound"],
        "-",
        color="C3",
        label="Proposition 1 bound $\\beta_1\\|x_0\\|^2 q^k + \\beta_2$",
    )
    ax.set_xlabel("k (quarters)")
    ax.set_ylabel("$E\\|x_k\\|^2$")
    ax.set_title("Mean-square bound (xi = 0.85, individual)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    save(fig, "fig_mean_square.png")
    return names


# ---------------------------------------------------------------------------- outputs
def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    header = [
        "name", "constraint", "xi", "runs", "steps", "violation_any", "violation_any_lo", "violation_any_hi",
        "violation_row_max", "rho_positive_share", "rho_max", "episode_cost_mean", "episode_cost_lo",
        "episode_cost_hi", "solver_fallbacks",
    ]  # fmt: skip
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for s in rows:
            w.writerow(
                [
                    s["name"],
                    s["constraint"],
                    s["xi"],
                    s["runs"],
                    s["steps"],
                    f"{s['violation_any']['freq']:.6f}",
                    f"{s['violation_any']['wilson95'][0]:.6f}",
                    f"{s['violation_any']['wilson95'][1]:.6f}",
                    f"{max(row['freq'] for row in s['violation_rows']):.6f}",
                    f"{s['rho_positive_share']:.6f}",
                    f"{s['rho_max']:.6g}",
                    f"{s['episode_cost']['mean']:.6g}",
                    f"{s['episode_cost']['ci95'][0]:.6g}",
                    f"{s['episode_cost']['ci95'][1]:.6g}",
                    s["solver_fallbacks"],
                ]  # fmt: skip
            )


def write_report(
    opts: Options, argv: list[str], summary: dict[str, Any], figures: list[str]
) -> str:
    cmd = "python -m benchmarks.reproduce_paper" + ("" if not argv else " " + " ".join(argv))
    lines = [
        "# Reproduction of section 6 (macroeconomic example)",
        "",
        f"Generated by `{cmd}`; every number below is computed by that command.",
        f"Statistics use {opts.stat_runs} runs x {HORIZON} steps per configuration (seed {opts.seed}); "
        f"the income figures draw the first {opts.runs} runs, as the paper draws 50.",
        "Violation frequencies count the states x_1 .. x_20 against the band H_k of their own time; "
        "overall intervals are 95% Wilson intervals that treat the steps as independent samples.",
        "",
        "## The paper's claims",
        "",
        "| # | claim | the paper says | measured | agree |",
        "|---|-------|----------------|----------|-------|",
    ]
    for i, c in enumerate(summary["claims"], 1):
        lines.append(
            f"| {i} | {c['claim']} | {c['paper']} | {c['measured']} | {'yes' if c['agree'] else '**no**'} |"
        )
    lines += [
        "",
        "## Configurations",
        "",
        "| configuration | runs | any-row violation (95% CI) | largest row | steps with rho>0 | max rho | mean episode cost (95% CI) |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary["paper_configs"]:
        va = s["violation_any"]
        lines.append(
            f"| {s['name']} | {s['runs']} | {va['freq']:.4f} ({va['wilson95'][0]:.4f}-{va['wilson95'][1]:.4f}) | "
            f"{max(row['freq'] for row in s['violation_rows']):.4f} | {s['rho_positive_share']:.4f} | {s['rho_max']:.3g} | "
            f"{s['episode_cost']['mean']:.1f} ({s['episode_cost']['ci95'][0]:.1f}-{s['episode_cost']['ci95'][1]:.1f}) |"
        )
    max_u = max(s["max_abs_u"] for s in summary["paper_configs"])
    lines += [
        "",
        f"Largest |u_k| applied in these runs: {max_u:.1f}, against the action bound "
        f"{ACTION_BOUND:g} of SDJLS-Macro-v0 (the controller never saturates).",
    ]
    ms = summary["mean_square"]
    lines += [
        "",
        "## Mean-square bound (Proposition 1)",
        "",
        f"Certificate for the paper's gains with |nu| <= {PAPER_RHC['nu_bound']:g}: q = {ms['q']:.4g}, "
        f"beta1 = {ms['beta1']:.4g}, beta2 = {ms['beta2']:.4g}. Largest ratio of the Monte Carlo E||x_k||^2 "
        f"(upper 95% limit) to the bound over k: {ms['max_ratio']:.3g} (below 1 means the bound holds).",
        "",
        "## Figures",
        "",
    ]
    captions = {
        "fig_mode.png": "A sample evolution of the mode (paper fig. ex_mode)",
        "fig_cost.png": "The optimal cost J*_k of the same sample (paper fig. ex_input)",
        "fig_income_individual_joint.png": "Incomes under individual and joint constraints (figs. ex_stateMC, ex_state_joint)",
        "fig_income_xi.png": "Incomes for xi = 0.95, 0.5, 0.3 (fig. eco_income_compare)",
        "fig_calibration.png": "Observed violation frequency against 1 - xi (beyond the paper)",
        "fig_mean_square.png": "E||x_k||^2 against the Proposition 1 bound (beyond the paper)",
    }
    for name in figures:
        lines += [f"![{captions[name]}]({name})", "", f"*{captions[name]}*", ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    opts.out.mkdir(parents=True, exist_ok=True)
    model = macro()
    T = HORIZON
    n_cfg = len(PAPER_CONFIGS) + len(KINDS) * len(CALIBRATION_XIS)
    bar = tqdm(
        total=n_cfg * T, desc="closed-loop Monte Carlo", unit="step", disable=opts.no_progress
    )

    ro: dict[str, Rollouts] = {}
    summaries: dict[str, dict] = {}
    for cfg in PAPER_CONFIGS:
        bar.set_postfix_str(cfg.name)
        runs = max(opts.runs, opts.stat_runs)
        ro[cfg.name] = rollout(
            model,
            paper_rhc(model, cfg.xi, cfg.constraint),
            runs,
            T,
            opts.seed,
            ACTION_BOUND,
            bar,
        )
        summaries[cfg.name] = summarize(cfg, ro[cfg.name])

    calib: dict[str, Any] = {"runs": opts.stat_runs}
    for kind in KINDS:
        calib[kind] = []
        for xi in CALIBRATION_XIS:
            bar.set_postfix_str(f"{kind} xi={xi}")
            cfg = Config(f"{kind}_{xi}", kind, xi)
            r = rollout(
                model,
                paper_rhc(model, xi, kind),
                opts.stat_runs,
                T,
                opts.seed + 1,
                ACTION_BOUND,
                bar,
            )
            calib[kind].append(summarize(cfg, r))
    bar.close()

    cert = verify_mean_square_bound(model, PAPER_K, nu_bound=PAPER_RHC["nu_bound"])
    sq = np.sum(ro["individual_0.85"].x ** 2, axis=-1)  # (runs, T+1)
    ks = np.arange(T + 1)
    emp = sq.mean(axis=0)
    emp_hi = np.array([mean_ci(sq[:, k])[2] for k in ks])
    bound = np.asarray(cert.bound(ks, model.x0), dtype=np.float64)
    mean_square = {
        "runs": int(sq.shape[0]),
        "empirical": emp.tolist(),
        "empirical_hi95": emp_hi.tolist(),
        "bound": bound.tolist(),
        "q": float(cert.q),
        "beta1": float(cert.beta1),
        "beta2": float(cert.beta2),
        "max_ratio": float(np.max(emp_hi / bound)),
    }

    ro_fig = {name: ro[name] for name in ro}
    figures = make_figures(opts, model, ro_fig, calib, mean_square)
    summary = {
        "command": "python -m benchmarks.reproduce_paper"
        + ("" if not argv else " " + " ".join(argv)),
        "options": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()},
        "paper_configs": [summaries[c.name] for c in PAPER_CONFIGS],
        "calibration": calib,
        "mean_square": mean_square,
        "claims": check_claims(summaries, ro),
        "figures": figures,
    }
    (opts.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    write_csv(
        opts.out / "summary.csv",
        summary["paper_configs"] + [p for kind in KINDS for p in calib[kind]],
    )
    (opts.out / "REPORT.md").write_text(write_report(opts, argv, summary, figures))
    agree = sum(c["agree"] for c in summary["claims"])
    print(f"{agree}/{len(summary['claims'])} claims of section 6 agree; wrote {opts.out}/REPORT.md")
    for c in summary["claims"]:
        print(f"  [{'ok' if c['agree'] else 'NO'}] {c['claim']}: {c['measured']}")
    return summary


if __name__ == "__main__":
    main()
