"""Reproduce section 6 of the paper (the macroeconomic example) and check its claims with numbers.

Run ``python -m benchmarks.reproduce_paper --help`` for the options. With the defaults it writes
to ``results/paper/``: the paper's figures (a sample mode sequence, its optimal cost J*_k, the
incomes of the Monte Carlo runs under individual and joint chance constraints and for
xi = 0.95, 0.5, 0.3), two figures beyond the paper (calibration of the violation frequency
against 1 - xi, and E||x_k||^2 against the Proposition 1 bound), ``summary.json`` (every
statistic), ``summary.csv`` (one line per configuration), ``summary_per_step.csv`` (one line per
configuration, step k and row) and ``REPORT.md``, whose every number is computed here.

Two sample sizes are used: ``--runs`` trajectories are drawn in the income figures (the paper
draws 50), and ``--stat-runs`` trajectories per configuration back every statistic and every
claim check (the claims compare frequencies that differ by about 0.02, which 50 runs cannot
resolve).
"""

from __future__ import annotations

import csv
import json
import re
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from benchmarks.core.cli import option, output_folder, parse_options, script_parser
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.montecarlo import Rollouts, rollout
from benchmarks.core.reference import paper_rhc
from benchmarks.core.stats import format_p, mean_ci, two_proportion_p, wilson
from benchmarks.core.versions import CORE_PACKAGES, package_versions
from benchmarks.paper.figures import KINDS, make_figures, row_labels
from controllers import verify_mean_square_bound
from sdjls_gym.systems.macro import ACTION_BOUND, HORIZON, PAPER_K, PAPER_RHC, macro

RHO_TOL = 1e-7  # rho below this counts as zero (solver round-off)
CALIBRATION_XIS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.99)


@dataclass
class Options:
    runs: int = option(50, "Monte Carlo runs drawn in the income figures (the paper draws 50)")
    stat_runs: int = option(
        2000,
        "runs per configuration behind every statistic, claim check and the calibration figure",
    )
    seed: int = option(0, "seed of the noise; the same seed gives the same files")
    out: Path = option(Path("results/paper"), "folder for figures, summary files and REPORT.md")
    no_progress: bool = option(False, "do not show progress bars")


def parse_args(argv: list[str] | None = None) -> Options:
    parser = script_parser(Options, "reproduce_paper", __doc__)
    opts = parse_options(parser, Options, argv)
    if opts.runs < 1:
        parser.error(f"--runs = {opts.runs}; expected a positive integer")
    if opts.stat_runs < 2:
        parser.error(
            f"--stat-runs = {opts.stat_runs}; expected an integer >= 2 (the intervals are over "
            "runs)"
        )
    opts.out = output_folder(parser, "--out", opts.out, quick=False, default=None,
                             script="reproduce_paper")  # fmt: skip
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


def _interval(lo: float, hi: float) -> list[float]:
    """A 95% interval for the files, rounded outwards to 6 decimals (the files stay small)."""
    return [
        float(np.clip(np.floor(lo * 1e6) / 1e6, 0.0, 1.0)),
        float(np.clip(np.ceil(hi * 1e6) / 1e6, 0.0, 1.0)),
    ]


SCHEMA = {
    "rows": "what a violation of row j of G x <= H_k means (row indices are 0-based)",
    "paper_configs, calibration.<kind>[]": "one configuration each; overall statistics pool "
    "runs x steps states, per_step[] holds one entry per checked state x_k (k = k_next = 1..steps)",
    "violation_any": "overall: count, freq and 95% Wilson interval (wilson95) of any-row violations",
    "violation_rows[j]": "overall: count, freq and wilson95 of row j",
    "per_step[].violation_any, .violation_any_count, .wilson95": "any-row frequency, count and "
    "its 95% Wilson interval over the runs at that step",
    "per_step[].violation_rows, .violation_rows_count, .violation_rows_wilson95": "per-row "
    "frequencies, counts and [low, high] 95% Wilson intervals at that step (lists over rows)",
    "rho_positive_share, rho_max": f"share of steps with rho_k > {RHO_TOL:g} and the largest rho_k",
    "episode_cost": "mean episode cost with a 95% Student-t interval (ci95)",
}


def summarize(cfg: Config, ro: Rollouts, seed: int) -> dict[str, Any]:
    """The statistics of one configuration.

    Overall frequencies pool the ``runs x T`` checked states (their Wilson intervals treat the
    steps as independent samples); per-step frequencies are over the ``runs`` independent
    episodes, so their Wilson intervals are exact binomial intervals.
    """
    runs, T = ro.rho.shape
    r = ro.violations.shape[-1]
    per_step_any = ro.any_violation.sum(axis=0)  # (T,)
    per_step_rows = ro.violations.sum(axis=0)  # (T, r)
    any_lo, any_hi = wilson(per_step_any, runs)
    step_rows_lo, step_rows_hi = wilson(per_step_rows, runs)  # (T, r) each
    total = runs * T
    overall_any = int(ro.any_violation.sum())
    overall_rows = ro.violations.sum(axis=(0, 1))
    cost_mean, cost_lo, cost_hi = mean_ci(ro.episode_cost)
    rows_lo, rows_hi = wilson(overall_rows, total)
    all_lo, all_hi = wilson(overall_any, total)
    return {
        "name": cfg.name,
        "constraint": cfg.constraint,
        "xi": cfg.xi,
        "seed": seed,
        "runs": runs,
        "steps": T,
        "violation_any": {
            "count": overall_any,
            "freq": overall_any / total,
            "wilson95": _interval(all_lo, all_hi),
        },
        "violation_rows": [
            {
                "row": j,
                "count": int(overall_rows[j]),
                "freq": float(overall_rows[j] / total),
                "wilson95": _interval(rows_lo[j], rows_hi[j]),
            }
            for j in range(r)
        ],
        "per_step": [
            {
                "k_next": k + 1,
                "violation_any": float(per_step_any[k] / runs),
                "wilson95": _interval(any_lo[k], any_hi[k]),
                "violation_any_count": int(per_step_any[k]),
                "violation_rows": (per_step_rows[k] / runs).tolist(),
                "violation_rows_count": per_step_rows[k].tolist(),
                "violation_rows_wilson95": [
                    _interval(step_rows_lo[k, j], step_rows_hi[k, j]) for j in range(r)
                ],
            }
            for k in range(T)
        ],
        "rho_positive_share": float(np.mean(ro.rho > RHO_TOL)),
        "rho_max": float(ro.rho.max()),
        "episode_cost": {"mean": cost_mean, "ci95": [cost_lo, cost_hi]},
        "solver_fallbacks": int((~ro.status_ok).sum()),
        "max_abs_u": float(np.abs(ro.u).max()),
    }


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
                f"{pct(joint['violation_any']['freq'])} (one-sided two-proportion test {format_p(p_value)})"
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
            + " (one-sided tests of each decrease: "
            + ", ".join(format_p(p) for p in pairs_p)
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


# ---------------------------------------------------------------------------- outputs
_NUMBER_LIST = re.compile(r"\[\s*(-?[0-9][-+.eE0-9]*(?:,\s*-?[0-9][-+.eE0-9]*)*)\s*\]")


def dump_json(data: Any) -> str:
    """Indented JSON with each list of numbers on one line (the file stays small and readable),
    floats at the digits that are the same on every machine (:func:`benchmarks.core.files.stable_floats`)."""

    def one_line(m: re.Match) -> str:
        return "[" + ", ".join(item.strip() for item in m.group(1).split(",")) + "]"

    return _NUMBER_LIST.sub(one_line, json.dumps(stable_floats(data), indent=1)) + "\n"


def _configurations(summary: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """``(study, configuration summary)`` for the paper's runs, then the calibration grid."""
    calib = summary["calibration"]
    return [("paper", s) for s in summary["paper_configs"]] + [
        ("calibration", p) for kind in KINDS for p in calib[kind]
    ]


def write_csv(path: Path, summary: dict[str, Any]) -> int:
    """``summary.csv``: one line per configuration (overall statistics); returns the line count.

    ``study`` is ``paper`` (the five configurations of section 6, seed ``--seed``) or
    ``calibration`` (the grid of the calibration figure, seed ``--seed + 1``): both hold a
    configuration named e.g. ``individual_0.85``.
    """
    configs = _configurations(summary)
    r = len(configs[0][1]["violation_rows"])
    per_row = [f"violation_row{j}{end}" for j in range(r) for end in ("", "_lo", "_hi")]
    header = [
        "study", "configuration", "constraint", "xi", "seed", "runs", "steps",
        "violation_any", "violation_any_lo", "violation_any_hi", *per_row, "violation_row_max",
        "rho_positive_share", "rho_max", "episode_cost_mean", "episode_cost_lo", "episode_cost_hi",
        "solver_fallbacks",
    ]  # fmt: skip
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for study, s in configs:
            rows = s["violation_rows"]
            w.writerow(
                [
                    study,
                    s["name"],
                    s["constraint"],
                    s["xi"],
                    s["seed"],
                    s["runs"],
                    s["steps"],
                    f"{s['violation_any']['freq']:.6f}",
                    f"{s['violation_any']['wilson95'][0]:.6f}",
                    f"{s['violation_any']['wilson95'][1]:.6f}",
                    *(f"{v:.6f}" for row in rows for v in (row["freq"], *row["wilson95"])),
                    f"{max(row['freq'] for row in rows):.6f}",
                    f"{s['rho_positive_share']:.6f}",
                    f"{s['rho_max']:.6g}",
                    f"{s['episode_cost']['mean']:.6g}",
                    f"{s['episode_cost']['ci95'][0]:.6g}",
                    f"{s['episode_cost']['ci95'][1]:.6g}",
                    s["solver_fallbacks"],
                ]  # fmt: skip
            )
    return len(configs)


PER_STEP_HEADER = [
    "study", "configuration", "constraint", "xi", "runs", "k", "row", "violations", "frequency",
    "wilson95_lo", "wilson95_hi",
]  # fmt: skip


def write_per_step_csv(path: Path, summary: dict[str, Any]) -> int:
    """``summary_per_step.csv``, long format: one line per (configuration, k, row or ``any``).

    ``k`` is the time of the checked state x_k (1..T, ``k_next`` in summary.json); ``row`` is the
    row of ``G x <= H_k`` (0-based, as in summary.json) or ``any``; ``violations`` counts the
    runs whose x_k violates it, ``frequency = violations / runs``, with its 95% Wilson interval
    over the independent runs. Returns the number of lines written (without the header).
    """
    n = 0
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(PER_STEP_HEADER)
        for study, s in _configurations(summary):
            head = [study, s["name"], s["constraint"], s["xi"], s["runs"]]
            for step in s["per_step"]:
                by_row = (
                    step["violation_rows_count"],
                    step["violation_rows"],
                    step["violation_rows_wilson95"],
                )
                cells: list[tuple[int | str, Any, Any, Any]] = [
                    (j, *cell) for j, cell in enumerate(zip(*by_row, strict=True))
                ]
                cells.append(
                    ("any", step["violation_any_count"], step["violation_any"], step["wilson95"])
                )
                for row, count, freq, (lo, hi) in cells:
                    w.writerow(
                        [*head, step["k_next"], row, count, f"{freq:.6f}", f"{lo:.6f}", f"{hi:.6f}"]
                    )
                    n += 1
    return n


def write_report(
    opts: Options,
    summary: dict[str, Any],
    figures: list[str],
    n_configs: int,
    n_per_step: int,
) -> str:
    cmd = summary["command"]
    lines = [
        "# Reproduction of section 6 (macroeconomic example)",
        "",
        f"Generated by `{cmd}`; every number below is computed by that command.",
        f"Statistics use {opts.stat_runs} runs x {HORIZON} steps per configuration (seed {opts.seed}); "
        f"the income figures draw the first {opts.runs} runs, as the paper draws 50.",
        "Violation frequencies count the states x_1 .. x_20 against the band H_k of their own time; "
        "overall intervals are 95% Wilson intervals that treat the steps as independent samples, "
        "per-step intervals are 95% Wilson intervals over the independent runs.",
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
        "## Files",
        "",
        "- `summary.json`: every statistic; `schema` explains the keys. Per configuration: "
        "`violation_any` and `violation_rows[j]` (count, freq, wilson95), `per_step[]` with "
        "`violation_any`, `violation_any_count`, `wilson95` (any row) and `violation_rows`, "
        "`violation_rows_count`, `violation_rows_wilson95` (each row), `rho_positive_share`, "
        "`rho_max`, `episode_cost` (mean, ci95), `runs`.",
        f"- `summary.csv`: one line per configuration ({n_configs} lines and a header): overall any-row and "
        "per-row violation frequencies with Wilson bounds, rho, episode cost. `study` is `paper` "
        "(section 6 configurations) or `calibration` (the grid of the calibration figure).",
        f"- `summary_per_step.csv`: long format, one line per (configuration, k, row) "
        f"({n_per_step} lines and a header): `k` is the time of the checked state x_k, `row` is "
        + ", ".join(f"`{j}` ({label})" for j, label in enumerate(summary["rows"]))
        + " or `any`; `violations`, `frequency`, `wilson95_lo`, `wilson95_hi`.",
        "",
        "## Figures",
        "",
    ]
    captions = {
        "fig_mode.png": "A sample evolution of the mode (paper fig. ex_mode)",
        "fig_cost.png": "The optimal cost J*_k of the same sample (paper fig. ex_input)",
        "fig_income_individual_joint.png": "Incomes under individual and joint constraints (figs. ex_stateMC, ex_state_joint)",
        "fig_income_xi.png": "Incomes for xi = 0.95, 0.5, 0.3 (fig. eco_income_compare)",
        "fig_calibration.png": "Observed per-row (a) and any-row (b) violation frequency against 1 - xi (beyond the paper)",
        "fig_mean_square.png": "E||x_k||^2 against the Proposition 1 bound (beyond the paper)",
    }
    for name in figures:
        lines += [f"![{captions[name]}]({name})", "", f"*{captions[name]}*", ""]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """``python -m benchmarks.reproduce_paper``: the runs, figures, summaries and ``REPORT.md``
    of section 6 into ``--out``; see the module docstring and ``--help``."""
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
        summaries[cfg.name] = summarize(cfg, ro[cfg.name], opts.seed)

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
            calib[kind].append(summarize(cfg, r, opts.seed + 1))
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
    figures = make_figures(opts.out, opts.runs, model, ro_fig, calib, mean_square)
    # what the numbers depend on: --no-progress changes only the display, not the files
    argv = [a for a in argv if a != "--no-progress"]
    summary = {
        "command": "python -m benchmarks.reproduce_paper"
        + ("" if not argv else " " + " ".join(argv)),
        "options": {
            k: str(v) if isinstance(v, Path) else v
            for k, v in asdict(opts).items()
            if k != "no_progress"
        },  # fmt: skip
        "versions": package_versions(CORE_PACKAGES),  # never an optional extra's
        "rows": row_labels(model),
        "schema": SCHEMA,
        "paper_configs": [summaries[c.name] for c in PAPER_CONFIGS],
        "calibration": calib,
        "mean_square": mean_square,
        "claims": check_claims(summaries, ro),
        "figures": figures,
    }
    summary = stable_floats(summary)  # what the files hold, the report's numbers included
    write_atomic(opts.out / "summary.json", dump_json(summary))
    n_configs = write_csv(opts.out / "summary.csv", summary)
    n_per_step = write_per_step_csv(opts.out / "summary_per_step.csv", summary)
    write_atomic(
        opts.out / "REPORT.md", write_report(opts, summary, figures, n_configs, n_per_step)
    )
    agree = sum(c["agree"] for c in summary["claims"])
    print(f"{agree}/{len(summary['claims'])} claims of section 6 agree; wrote {opts.out}/REPORT.md")
    for c in summary["claims"]:
        print(f"  [{'ok' if c['agree'] else 'NO'}] {c['claim']}: {c['measured']}")
    return summary


if __name__ == "__main__":
    main()
