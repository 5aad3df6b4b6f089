"""Tuned against default: the runs retrained with a ``benchmarks.rl.tune`` study's best
hyperparameters against the suite's runs of the same task, algorithm and variant.

``python -m benchmarks.tuned_report --tuned results/tune/STUDY.json [...]`` reads, for each
study summary, the kept runs of the configuration on seeds 0 .. ``--seeds - 1``, at the budget
the study tuned at, twice: with the suite's default hyperparameters and with the study's best
overrides (the runs that
``python -m benchmarks.compare_rl --tasks TASK --configs ALGO_VARIANT --tuned STUDY.json
--train-only`` trains into the same ``--runs`` folder; the tuning's own seeds start at
:data:`benchmarks.rl.tune.TUNE_SEED0`, so these seeds are fresh). Both groups are scored as the
suite's report scores a task (:func:`benchmarks.rl.suite_report.score_task`: the same
evaluation episodes, the paired gaps to the one-step RHC curve and to the 3-step tree's curve
with their 95% intervals; the tree's level runs read from and kept in ``tree_levels`` beside
``--runs``, the suite comparison's store) and compared with rliable (:func:`benchmarks.core.aggregate.compare_gaps`:
the IQM difference of the gaps and the probability that a tuned run has the lower gap, each with
its stratified-bootstrap 95% interval). A group in which a run has no gap (diverged, or outside
a curve's range) is not summarized: the table says why, as the suite's report does.

Writes ``TUNED.md`` and ``tuned.json`` to ``--out`` (default ``results/tune``; with
``--quick``, a new temporary folder, and the quick budgets of ``compare_rl --quick``, whose runs
``--runs`` names).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.aggregate import AGGREGATE_RESAMPLES, compare_gaps, iqm_interval
from benchmarks.core.cli import output_folder
from benchmarks.core.commands import prog
from benchmarks.core.evaluate import check_evaluation
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.logs import log
from benchmarks.core.tree_levels import TREE_STORE, LevelStore
from benchmarks.rl import compare as compare_rl
from benchmarks.rl.runs import check_kept_runs
from benchmarks.rl.suite_report import (
    QUICK_RESAMPLES,
    AgentScore,
    kept_runs,
    score_task,
)
from benchmarks.rl.suite_tables import gap_text
from benchmarks.rl.train import RunSpec, run_specs
from benchmarks.rl.tune_summary import read_summary

__all__ = ["DEFAULT_OUT", "compare_study", "main"]

DEFAULT_OUT = Path("results/tune")
#: The gaps compared: to the one-step RHC curve and to the 3-step tree's curve.
WHICH = (("rhc", "one-step RHC"), ("tree", "3-step tree"))


def _trial_states(summary: dict[str, Any]) -> dict[str, int]:
    """How many of the study's trials ended in each state (COMPLETE, PRUNED, ...)."""
    states: dict[str, int] = {}
    for trial in summary.get("trials", []):
        state = str(trial.get("state", "?"))
        states[state] = states.get(state, 0) + 1
    return states


def _spent(summary: dict[str, Any]) -> dict[str, Any]:
    """What a study spent: its trials' env steps (as recorded; a trial that recorded none: all
    seeds' budget if complete, else its last learning-curve step, where pruning stops a trial
    during its first seed), the sum of the finished trials' wall times and of the CPU times
    they recorded (older trials recorded neither). Ray Tune numbers a pruned
    trial's points by iteration, not step: its studies' pruned trials count only if recorded."""
    settings = summary["settings"]
    budget = int(settings.get("timesteps") or 0) * int(settings.get("seeds") or 1)
    trials = summary.get("trials", [])
    steps = 0
    for t in trials:
        if t.get("env_steps") is not None:
            steps += int(t["env_steps"])
        elif t.get("state") == "COMPLETE":
            steps += budget
        else:
            steps += max((int(k) for k in t.get("intermediate", {})), default=0)
    # finished trials only: a failed one was left running by a killed or stopped process, and
    # its stamps span the stop
    done = [t for t in trials if t.get("state") in ("COMPLETE", "PRUNED")]
    walls = [t["wall_s"] for t in done if t.get("wall_s") is not None]
    cpus = [t["cpu_s"] for t in done if t.get("cpu_s") is not None]
    return {"env_steps": steps, "wall_h": sum(walls) / 3600, "wall_trials": len(walls),
            "cpu_h": sum(cpus) / 3600, "cpu_trials": len(cpus), "trials": len(trials)}  # fmt: skip


def _group(agents: list[AgentScore], resamples: int) -> dict[str, Any]:
    """Per-seed rows of one group and, per curve, the IQM of its gaps (None, with the reasons,
    when a run has none)."""
    agents = sorted(agents, key=lambda a: a.run.seed)  # rows and gaps in the order of seeds
    rows = []
    for a in agents:
        s = a.result.score
        rows.append({"seed": a.run.seed, "cost_mean": s.cost_mean, "violation": s.violation,
                     "diverged": s.diverged, "rhc": gap_text(a.gap, a.reason),
                     "tree": gap_text(a.tree_gap, a.tree_reason)})  # fmt: skip
    out: dict[str, Any] = {"rows": rows}
    for which, _ in WHICH:  # every run counts: its bounded gap (the worst value when it failed)
        if not agents:
            out[which] = {"gaps": None, "left_out": ["no kept run"], "no_gap_seeds": []}
            continue
        values = np.array([[a.bounded if which == "rhc" else a.tree.value] for a in agents])
        iqm, ci = iqm_interval(values, resamples)
        out[which] = {"gaps": values[:, 0].tolist(), "iqm": iqm, "iqm_ci95": ci}
    return out


def study_specs(path: Path, seeds: int,
                quick: bool) -> tuple[dict[str, Any], list[RunSpec], list[RunSpec]]:  # fmt: skip
    """The study summary at ``path``, and the runs of its configuration on ``seeds`` seeds at
    the budget it tuned at: with the default hyperparameters, and with its best overrides."""
    key, overrides, summary = read_summary(path)
    task, algo, variant = key
    pair = [(algo, variant)]
    budget = {key: summary["settings"]["timesteps"]}  # both groups at the study's budget
    default = run_specs(pair, seeds, None, quick, [task], tuned_timesteps=budget)
    tuned = run_specs(pair, seeds, None, quick, [task], tuned={key: overrides},
                      tuned_timesteps=budget)  # fmt: skip
    return summary, default, tuned


def compare_study(path: Path, run_dir: Path, seeds: int, episodes: int,
                  seed: int | tuple[int, ...], quick: bool,
                  log: Any = print) -> dict[str, Any]:  # fmt: skip
    """The comparison of one study's tuned runs with the default ones (see the module
    docstring): the study, both groups and, per curve, rliable's comparison or why there is
    none."""
    summary, default, tuned = study_specs(path, seeds, quick)
    task, algo, variant = default[0].task, default[0].algo, default[0].variant
    specs: list[RunSpec] = [*default, *tuned]
    records = kept_runs(specs, run_dir)
    log(f"{task} {algo}_{variant}: {sum(r is not None for r in records)} of {len(specs)} "
        f"run(s) kept in {run_dir}; scoring on {episodes} episodes")  # fmt: skip
    # the tree's level runs kept beside the runs (the suite comparison's, for results/rl_suite)
    store = LevelStore(run_dir.parent / TREE_STORE)
    report = score_task(task, list(zip(specs, records, strict=True)), run_dir, episodes, seed,
                        quick, log, store)  # fmt: skip
    tuned_ids = {id(r) for r in records[len(default) :] if r is not None}
    groups = {
        "default": [a for a in report.agents if id(a.run) not in tuned_ids],
        "tuned": [a for a in report.agents if id(a.run) in tuned_ids],
    }
    resamples = QUICK_RESAMPLES if quick else AGGREGATE_RESAMPLES
    out: dict[str, Any] = {
        "study": str(path),
        "task": task,
        "config": f"{algo}_{variant}",
        "overrides": dict(tuned[0].overrides),
        "trials": _trial_states(summary),
        "best_trial": summary["best"].get("number"),
        "budget": {k: summary["settings"].get(k) for k in ("timesteps", "seeds")},
        "search_space": list(summary.get("search_space", [])),
        "spent": _spent(summary),
        "seeds": list(range(seeds)),
        "missing": {
            name: [s.seed for s, r in zip(group, recs, strict=True) if r is None]
            for name, group, recs in (
                ("default", default, records[: len(default)]),
                ("tuned", tuned, records[len(default) :]),
            )
        },
        "groups": {name: _group(agents, resamples) for name, agents in groups.items()},
    }
    for which, _ in WHICH:
        t, d = out["groups"]["tuned"][which], out["groups"]["default"][which]
        if t["gaps"] is None or d["gaps"] is None:
            out[f"compare_{which}"] = None
            continue
        out[f"compare_{which}"] = compare_gaps(np.array(t["gaps"])[:, None],
                                               np.array(d["gaps"])[:, None], resamples)  # fmt: skip
    return out


def _summary_cell(group: dict[str, Any]) -> str:
    if group["gaps"] is None:
        seeds = group.get("no_gap_seeds")
        if not seeds:
            return "none: no kept run"
        return f"none: no gap for seed(s) {', '.join(map(str, seeds))} (see the rows)"
    lo, hi = group["iqm_ci95"]
    return f"{group['iqm']:+.1f} ({lo:+.1f} to {hi:+.1f})"


def _states_text(states: dict[str, int]) -> str:
    total = sum(states.values())
    return f"{total} (" + ", ".join(f"{n} {k.lower()}" for k, n in sorted(states.items())) + ")"


def _compare_cell(c: dict[str, Any] | None) -> list[str]:
    if c is None:
        return ["-", "-"]
    lo, hi = c["iqm_difference_ci95"]
    plo, phi = c["probability_of_improvement_ci95"]
    return [f"{c['iqm_difference']:+.1f} ({lo:+.1f} to {hi:+.1f})",
            f"{c['probability_of_improvement']:.2f} ({plo:.2f} to {phi:.2f})"]  # fmt: skip


def write_markdown(results: list[dict[str, Any]], command: str, episodes: int) -> str:
    """``TUNED.md``: per study, the runs of both groups and rliable's comparison."""
    lines = [
        "# Tuned against default",
        "",
        f"Generated by `{command}`. Each study's best hyperparameters, retrained on fresh seeds "
        "(the tuning used seeds from 100 on), against the suite's default runs of the same "
        f"configuration on the same seeds, all scored on the same {episodes} evaluation "
        "episodes per noise seed (common random numbers; the seeds in tuned.json's command) "
        "within the agents' action bound. Rows: gaps at equal risk in % of the curve's cost at "
        "the run's violation frequency (negative: cheaper), with their 95% interval over "
        "episodes. Comparisons: every run counts, by its bounded gap (the worst value +100 for "
        "a run that diverged or is riskier than the curve); IQM over seeds with rliable's "
        "stratified-bootstrap 95% interval; 'P(tuned better)': the probability that a tuned run "
        "has a lower bounded gap than a default one.",
    ]
    for r in results:
        lines += ["", f"## {r['task']}, {r['config']}", "",
                  f"Study `{r['study']}`: trials {_states_text(r['trials'])} of "
                  f"{r['budget']['timesteps']} steps x {r['budget']['seeds']} seed(s); best "
                  f"trial {r['best_trial']}: `{json.dumps(r['overrides'], sort_keys=True)}`."]  # fmt: skip
        sp = r["spent"]
        lines += ["", f"Spent: {sp['env_steps'] / 1e6:.2f}M env steps over its {sp['trials']} "
                  "trials (a pruned trial's up to where it stopped); their wall times sum to "
                  f"{sp['wall_h']:.2f} h ({sp['wall_trials']} trials; one torch thread each, so "
                  "their CPU time is at most this)"
                  + (f"; the {sp['cpu_trials']} trials that recorded their CPU time used "
                     f"{sp['cpu_h']:.2f} CPU-hours" if sp["cpu_trials"] else "") + "."]  # fmt: skip
        if r["search_space"]:
            lines += ["", "Search space (`python -m benchmarks.tune --algo ALGO --variant VARIANT "
                      "--print-space`):", "", *[f"- {line}" for line in r["search_space"]]]  # fmt: skip
        for name in ("default", "tuned"):
            if r["missing"][name]:
                lines += ["", f"Missing {name} runs: seeds {r['missing'][name]}."]
        lines += ["", "| group | seed | mean cost | violation | diverged | gap to one-step RHC "
                  "(%) | gap to 3-step tree (%) |", "|---|---|---|---|---|---|---|"]  # fmt: skip
        for name in ("default", "tuned"):
            for row in r["groups"][name]["rows"]:
                lines.append(f"| {name} | {row['seed']} | {row['cost_mean']:.1f} | "
                             f"{row['violation']:.3f} | {row['diverged']} | {row['rhc']} | "
                             f"{row['tree']} |")  # fmt: skip
        lines += ["", "| against | IQM bounded gap, default | IQM bounded gap, tuned | "
                  "tuned - default (IQM) | "
                  "P(tuned better) |", "|---|---|---|---|---|"]  # fmt: skip
        for which, label in WHICH:
            g = r["groups"]
            lines.append("| " + " | ".join([label, _summary_cell(g["default"][which]),
                                            _summary_cell(g["tuned"][which]),
                                            *_compare_cell(r[f"compare_{which}"])]) + " |")  # fmt: skip
    return "\n".join(lines) + "\n"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The options; a parser error (exit 2) names a bad one before any scoring."""
    parser = argparse.ArgumentParser(
        prog=prog("tuned_report"),
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--tuned", type=Path, nargs="+", required=True, metavar="STUDY.json",
                        help="summaries of benchmarks.rl.tune studies (<out>/<study>.json)")  # fmt: skip
    parser.add_argument("--runs", type=Path, default=None,
                        help="the kept runs (default results/rl_suite/runs; needed with --quick: "
                        "the runs/ of the folder compare_rl --quick wrote into)")  # fmt: skip
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. SEEDS - 1 per group")
    parser.add_argument("--eval-episodes", type=int, default=None,
                        help="evaluation episodes (default 1000, 200 with --quick)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="first noise seed of the evaluation")
    parser.add_argument("--eval-seeds", type=int, default=None,
                        help="evaluation noise seeds --seed, --seed + 1, ..., their episodes "
                        "pooled (default 3, 1 with --quick)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=None,
                        help=f"folder of TUNED.md and tuned.json (default {DEFAULT_OUT}, a new "
                        "temporary folder with --quick)")  # fmt: skip
    parser.add_argument("--quick", action="store_true",
                        help="the quick budgets of compare_rl --quick (a smoke test)")  # fmt: skip
    opts = parser.parse_args(argv)
    if opts.seeds < 1:
        parser.error(f"--seeds = {opts.seeds}; expected a positive integer")
    if opts.eval_episodes is None:
        opts.eval_episodes = 200 if opts.quick else 1000
    if opts.eval_seeds is None:
        opts.eval_seeds = 1 if opts.quick else 3
    if opts.eval_seeds < 1:
        parser.error(f"--eval-seeds = {opts.eval_seeds}; expected a positive integer")
    opts.noise_seeds = tuple(range(opts.seed, opts.seed + opts.eval_seeds))
    try:  # evaluate()'s own limits, and the study summaries, before any scoring
        check_evaluation(opts.eval_episodes, opts.seed)  # --seed itself, then every seed's
        check_evaluation(opts.eval_episodes, opts.noise_seeds)
    except ValueError as exc:
        text = str(exc).replace("episodes = ", "--eval-episodes = ", 1)
        parser.error(text.replace("seed = ", "--seed = ", 1))
    try:
        compare_rl.tuned_studies(opts.tuned)
    except ValueError as exc:
        parser.error(str(exc))
    if opts.runs is None and opts.quick:
        parser.error("--quick needs --runs: the runs/ folder of a compare_rl --quick run (each "
                     "writes into a new temporary folder, printed at its start)")  # fmt: skip
    opts.runs = Path("results/rl_suite/runs") if opts.runs is None else opts.runs
    try:  # every kept run loads before any scoring
        for path in opts.tuned:
            _, default, tuned = study_specs(path, opts.seeds, opts.quick)
            check_kept_runs([*default, *tuned], opts.runs)
    except (TypeError, ValueError) as exc:
        parser.error(" ".join(str(exc).split()))
    opts.out = output_folder(parser, "--out", opts.out, quick=opts.quick, default=DEFAULT_OUT,
                             script="tuned_report")  # fmt: skip
    return opts


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    """Compare each study of ``--tuned`` (:func:`compare_study`), write ``tuned.json`` and
    ``TUNED.md`` to ``--out``, and return the comparisons."""
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    import torch

    torch.set_num_threads(1)  # as in training

    if opts.quick:
        log(f"--quick: writing to {opts.out}")
    results = [compare_study(p, opts.runs, opts.seeds, opts.eval_episodes, opts.noise_seeds,
                             opts.quick, log) for p in opts.tuned]  # fmt: skip
    command = "python -m benchmarks.tuned_report" + ("" if not argv else " " + " ".join(argv))
    opts.out.mkdir(parents=True, exist_ok=True)
    write_atomic(opts.out / "tuned.json",
                 json.dumps(stable_floats({"command": command, "studies": results}), indent=1))  # fmt: skip
    write_atomic(opts.out / "TUNED.md", write_markdown(results, command, opts.eval_episodes))
    log(f"wrote {opts.out / 'TUNED.md'}")
    return results


if __name__ == "__main__":
    main()
