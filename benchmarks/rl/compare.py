"""Receding-horizon controllers against stable-baselines3 agents, on the tasks of the suite.

Run ``python -m benchmarks.compare_rl --help`` for the options. Three presets (``--preset``):

* ``suite`` (the default): on every task of ``sdjls_gym.SUITE`` (``--tasks``), the five
  configurations of :data:`benchmarks.rl.hyperparams.SUITE_CONFIGS` (PPO on the reward alone,
  PPO residual on ``nu`` over the task's gains ``K``, and the Lagrangian PPO, SAC and TD3, whose
  penalty follows the violation frequency towards the task's ``1 - xi``), 5 seeds each, with
  the budgets of :data:`~benchmarks.rl.hyperparams.SUITE_TIMESTEPS`, into ``results/rl_suite``;
* ``macro``: the comparison of ``results/rl``: the macro task, PPO, SAC and TD3 in six variants
  (``--algos``, ``--variants``: the reward alone, the penalties ``beta100``, ``beta1000``,
  ``beta10000``, ``residual``, ``lagrangian``), 3 seeds, the budgets of
  :func:`~benchmarks.rl.hyperparams.timesteps`, scored with the model-based controllers
  (:data:`MODEL_BASED_CURVES`, :data:`SINGLE_CONTROLLERS`) by
  :func:`benchmarks.evaluate.evaluate` on the same ``--eval-episodes`` episodes (common random
  numbers);
* ``hidden``: every task with the mode hidden (``observe="state"``), PPO on the
  state-only observation, sb3-contrib's recurrent PPO and PPO fed the mode filter's belief,
  each on the reward alone and Lagrangian (:data:`benchmarks.rl.hyperparams.HIDDEN_CONFIGS`,
  named ``ppo_state_reward``, ``recurrent_ppo_state_lagrangian``, ``ppo_belief_reward``, ...),
  5 seeds, the budgets of :data:`~benchmarks.rl.hyperparams.HIDDEN_TIMESTEPS`, into
  ``results/hidden``; scored by the hidden wing (``python -m benchmarks.hidden``) against the
  oracle (the task's RHC seeing the mode) and the model-based hidden-mode controllers.

Each training environment is :func:`benchmarks.rl.envs.make_train_env` of its task and variant.
``--train-only`` trains and keeps the runs and stops before any scoring; ``--score-only`` trains
nothing and scores the runs kept so far. Without them, a comparison on the macro task alone
writes the full report (``summary.json``, ``summary.csv``, the figures, ``REPORT.md``, each
written atomically); on other tasks :func:`benchmarks.rl.suite_report.report_suite` scores each
agent on its task against the task's one-step RHC and 3-step tree curves, with rliable's
statistics across the tasks, and names the runs that are missing.

Per training, ``runs/<task>/<name>-<fingerprint>.json`` (learning curve, dual ascent, training
and CPU time) and ``.pt`` (the policy's state dict, 40-130 KB). A run is named by the fingerprint
of its whole configuration, task included: a kept run of the same configuration is not trained
again (``--retrain`` trains anew; an interrupted command resumes from the finished runs), and a
run of another configuration is kept beside it, never in its place. The evaluation is not
cached, so a change of the evaluation needs no training. The trainings run in local processes
or as Ray tasks (``--backend``, :mod:`benchmarks.rl.backends`).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.cli import (
    filled,
    one_of,
    option,
    output_folder,
    parse_options,
    script_parser,
)
from benchmarks.core.evaluate import REFERENCE_XIS, check_evaluation, evaluate
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.logs import log
from benchmarks.core.montecarlo import rollout
from benchmarks.core.stats import curve_status, interval_check
from benchmarks.core.versions import package_versions
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.backends import BACKENDS, train_all
from benchmarks.rl.envs import (
    AGENT_ALGOS,
    MACRO,
    OBSERVATIONS,
    comparison_env_kwargs,
    config_name,
    parse_config,
)
from benchmarks.rl.figures import make_figures
from benchmarks.rl.macro_controllers import (
    MODEL_BASED_CURVES,
    SINGLE_CONTROLLERS,
    empty_band_share,
)
from benchmarks.rl.macro_report import write_report
from benchmarks.rl.report import (
    ControllerResult,
    RunResult,
    Summary,
    against_best_agent,
    against_curve,
    aggregate,
    best_agent,
    best_config,
    comparable,
    hyperparams_record,
    write_csv,
)
from benchmarks.rl.runs import check_kept_runs
from benchmarks.rl.suite_report import kept_runs, report_suite
from benchmarks.rl.train import (
    ALGOS,
    VARIANTS,
    kept_run_path,
    load_policy,
    policy_path,
    run_specs,
)
from benchmarks.rl.tune_summary import read_summary
from sdjls_gym import SUITE
from sdjls_gym.systems.macro import HORIZON, PAPER_RHC, macro

XI = PAPER_RHC["xi"]
XI_SWEEP = REFERENCE_XIS
INCOME_TRAJECTORIES = 30  # incomes drawn per panel of the income figure
#: The presets: their tasks, configurations, seeds, budgets and output folder.
PRESETS: dict[str, dict[str, Any]] = {
    "suite": {
        "tasks": list(SUITE),
        "configs": [f"{a}_{v}" for a, v in HP.SUITE_CONFIGS],
        "seeds": HP.SUITE_SEEDS,
        "budgets": "suite",
        "out": Path("results/rl_suite"),
    },
    "macro": {
        "tasks": [MACRO],
        "configs": [f"{a}_{v}" for a in ALGOS for v in VARIANTS],
        "seeds": 3,
        "budgets": "macro",
        "out": Path("results/rl"),
    },
    "hidden": {
        "tasks": list(SUITE),
        "configs": [config_name(*c) for c in HP.HIDDEN_CONFIGS],
        "seeds": HP.HIDDEN_SEEDS,
        "budgets": "hidden",
        "out": Path("results/hidden"),
    },
}
DEFAULT_OUT = PRESETS["suite"]["out"]
#: Every ``--configs`` value: ``<algo>_<variant>`` (the mode observed) and
#: ``<algo>_<observation>_<variant>`` (the mode hidden; the recurrent PPO only so).
CONFIGS = tuple(f"{a}_{v}" for a in ALGOS for v in VARIANTS) + tuple(
    config_name(a, v, o) for o in OBSERVATIONS[1:] for a in AGENT_ALGOS for v in VARIANTS
)


# ----------------------------------------------------------------------------- options
@dataclass
class Options:
    preset: str = option(
        "suite",
        "defaults of --tasks, --configs, --seeds, the budgets and --out: 'suite' "
        "(every task, the 5 configurations of rl_hyperparams.SUITE_CONFIGS, 5 seeds, "
        "results/rl_suite), 'macro' (the comparison of results/rl: the macro task, 3 "
        "algorithms x 6 variants, 3 seeds) or 'hidden' (every task with the mode hidden: "
        "the 6 configurations of rl_hyperparams.HIDDEN_CONFIGS, 5 seeds, results/hidden, "
        "scored by python -m benchmarks.hidden)",
        choices=tuple(PRESETS),
    )
    tasks: list[str] | None = option(
        None, **one_of("suite env ids to train on (default: the preset's)", SUITE, "TASK")
    )
    configs: list[str] | None = option(
        None, **one_of("configurations <algo>_<variant> (default: the preset's)", CONFIGS, "CONFIG")
    )
    algos: list[str] | None = option(
        None,
        **one_of(
            "with --variants: train every algorithm in every variant (instead of "
            "--configs); one alone combines with all variants / all algorithms",
            ALGOS,
            "ALGO",
        ),
    )
    variants: list[str] | None = option(
        None, **one_of("training variants (see --algos)", VARIANTS, "VARIANT")
    )
    timesteps: int | None = option(
        None,
        "env steps per training run (default: the preset's budgets, "
        "benchmarks/rl_hyperparams.py; "
        f"{HP.QUICK_TIMESTEPS} with --quick; N replaces them all)",
    )
    seeds: int | None = option(None, "training seeds per configuration (default: the preset's)")
    eval_episodes: int = option(
        1000, "evaluation episodes per controller and trained agent, per noise seed"
    )
    seed: int = option(0, "first noise seed of the evaluation episodes")
    eval_seeds: int = option(
        3, "evaluation noise seeds, --seed, --seed + 1, ... (their episodes pooled; 1 with --quick)"
    )
    out: Path | None = option(
        None,
        "folder for figures, summary files, REPORT.md and runs/ (*.json, *.pt); "
        "default: the preset's (results/rl_suite, results/rl), or a new temporary folder "
        "with --quick (a smoke test never writes into the committed results)",
    )
    workers: int = option(
        2,
        "trainings run at once (processes, or the CPUs of a local Ray instance); when "
        "scoring, the 3-step tree's level runs at once (each kept in <out>/tree_levels, so an "
        "interrupted scoring resumes)",
    )
    backend: str = option(
        "process", "where the trainings run: local processes or Ray tasks", choices=BACKENDS
    )
    address: str | None = option(
        None,
        "Ray cluster to join with --backend ray ('auto' after `ray start "
        "--head`); default: a local Ray instance of --workers CPUs",
    )
    quick: bool = option(
        False,
        f"smoke test: {HP.QUICK_TIMESTEPS} steps per run, 200 evaluation episodes, "
        "3 learning-curve points of 20 episodes",
    )
    train_only: bool = option(
        False,
        "train and keep the runs, then stop: no scoring, no report (rerun without "
        "it to score the kept runs)",
    )
    score_only: bool = option(
        False,
        "train nothing: score the runs kept so far; the report names the missing "
        "ones (per task, configuration and seed)",
    )
    tuned: list[Path] | None = option(
        None,
        "summaries of benchmarks.rl.tune studies (<out>/<study>.json): their best "
        "hyperparameters replace the defaults of that task's configuration, trained at the "
        "study's budget unless --timesteps (seeds from 0: never the tuning's); with "
        "--train-only (then python -m benchmarks.tuned_report), --out or --quick",
        metavar="STUDY.json",
    )
    retrain: bool = option(False, "train again even when runs/ has the trained run")
    no_progress: bool = option(False, "do not show the progress bar")

    def config_pairs(self) -> list[tuple[str, str]]:
        """The ``(algo, variant)`` pairs of :attr:`configs`."""
        return [parse_config(c)[:2] for c in self.configs or []]

    def config_keys(self) -> list[tuple[str, str, str]]:
        """The ``(algo, variant, observation)`` of :attr:`configs`."""
        return [parse_config(c) for c in self.configs or []]

    def hides_mode(self) -> bool:
        """Some configuration observes the state without the mode (the hidden wing scores it)."""
        return any(o != "mode" for _, _, o in self.config_keys())


def parse_args(argv: list[str] | None = None) -> Options:
    parser = script_parser(Options, "compare_rl", __doc__)
    given = {a.split("=")[0] for a in (sys.argv[1:] if argv is None else argv)}
    opts = parse_options(parser, Options, argv)
    preset = PRESETS[opts.preset]
    if opts.quick and "--eval-episodes" not in given:
        opts.eval_episodes = 200
    if opts.quick and "--eval-seeds" not in given:
        opts.eval_seeds = 1
    _resolve_configs(parser, opts, preset)
    _check_numbers(parser, opts)
    _check_modes(parser, opts)
    _check_hidden_seeds(parser, opts, given)
    _check_preset_output(parser, opts, preset)
    opts.out = output_folder(parser, "--out", opts.out, quick=opts.quick, default=preset["out"],
                             script="compare_rl")  # fmt: skip
    if opts.score_only:  # every kept run loads before a minute of scoring
        try:
            check_kept_runs(specs_of(opts), opts.out / "runs")
        except (TypeError, ValueError) as exc:
            parser.error(f"--score-only: {' '.join(str(exc).split())}")
    return opts


def _resolve_configs(parser: argparse.ArgumentParser, opts: Options, preset: dict) -> None:
    """Fill in :attr:`Options.configs` (from ``--configs``, or every ``--algos`` in every
    ``--variants``, or the preset's), the algorithms and variants they name, the tasks and the
    seeds."""
    if opts.configs is not None and (opts.algos is not None or opts.variants is not None):
        parser.error("--configs with --algos/--variants: give the configurations one way")
    if opts.algos is not None or opts.variants is not None:
        algos = opts.algos if opts.algos is not None else list(ALGOS)
        variants = opts.variants if opts.variants is not None else list(VARIANTS)
        opts.configs = [f"{a}_{v}" for a in dict.fromkeys(algos) for v in dict.fromkeys(variants)]
    opts.configs = list(dict.fromkeys(opts.configs or preset["configs"]))
    opts.algos = list(dict.fromkeys(a for a, _ in opts.config_pairs()))
    opts.variants = list(dict.fromkeys(v for _, v in opts.config_pairs()))
    opts.tasks = list(dict.fromkeys(opts.tasks or preset["tasks"]))
    if opts.seeds is None:
        opts.seeds = preset["seeds"]


def _check_numbers(parser: argparse.ArgumentParser, opts: Options) -> None:
    """The counts positive, and the evaluation within :func:`evaluate`'s own limits, before
    hours of training."""
    for name in ("seeds", "workers"):
        if getattr(opts, name) < 1:
            parser.error(f"--{name} = {getattr(opts, name)}; expected a positive integer")
    if opts.eval_seeds < 1:
        parser.error(f"--eval-seeds = {opts.eval_seeds}; expected a positive integer")
    try:
        check_evaluation(opts.eval_episodes, opts.seed)  # --seed itself, then every seed's
        check_evaluation(opts.eval_episodes, evaluation_seeds(opts))
    except ValueError as exc:
        text = str(exc).replace("episodes = ", "--eval-episodes = ", 1)
        parser.error(text.replace("seed = ", "--seed = ", 1))
    if opts.timesteps is not None and opts.timesteps < 1:
        parser.error(f"--timesteps = {opts.timesteps}; expected a positive integer")


def _check_modes(parser: argparse.ArgumentParser, opts: Options) -> None:
    """The backend's options, the modes that exclude each other, the tuned studies readable."""
    if opts.address is not None and opts.backend != "ray":
        parser.error(f"--address = {opts.address!r} needs --backend ray")
    if opts.score_only and (opts.train_only or opts.retrain):
        parser.error("--score-only with --train-only or --retrain: give one of them")
    try:
        tuned_studies(opts.tuned)
    except ValueError as exc:
        parser.error(str(exc))


def _check_hidden_seeds(parser: argparse.ArgumentParser, opts: Options, given: set[str]) -> None:
    """The hidden wing scores on its own noise seeds (``benchmarks.hidden.EVAL_SEEDS``): other
    ones asked for with the mode hidden are refused, not ignored."""
    if opts.train_only or not opts.hides_mode():
        return
    from benchmarks.hidden import EVAL_SEEDS

    asked = tuple(range(opts.seed, opts.seed + opts.eval_seeds))
    if given & {"--seed", "--eval-seeds"} and asked != EVAL_SEEDS:
        parser.error(
            f"--seed {opts.seed} --eval-seeds {opts.eval_seeds} (noise seeds {asked}) with the "
            f"mode hidden: its scoring (python -m benchmarks.hidden) uses the noise seeds "
            f"{EVAL_SEEDS}, benchmarks.hidden.EVAL_SEEDS; leave --seed and --eval-seeds out"
        )


def _check_preset_output(parser: argparse.ArgumentParser, opts: Options, preset: dict) -> None:
    """A report written into the preset's folder replaces its committed report of all the runs:
    only the preset's own runs may write it."""
    into_preset = not (opts.train_only or opts.quick) and opts.out is None
    if opts.tuned and into_preset:  # the tuned runs' report in place of the default runs'
        parser.error(
            "--tuned without --train-only or --out: the report would replace the default "
            "runs' report in the preset's folder; train with --train-only and compare with "
            "python -m benchmarks.tuned_report, or give --out"
        )
    partial = [flag for flag, differs in (
        ("--tasks", set(filled("tasks", opts.tasks)) != set(preset["tasks"])),
        ("--configs (or --algos/--variants)",
         set(filled("configs", opts.configs)) != set(preset["configs"])),
        ("--seeds", opts.seeds != preset["seeds"]),
        ("--timesteps", opts.timesteps is not None),
    ) if differs]  # fmt: skip
    if partial and into_preset:
        parser.error(
            f"{', '.join(partial)} other than the preset's ({opts.preset!r}) without --out: the "
            f"report of these runs would replace the full report in {preset['out']}; give --out "
            "(or --train-only to train into the preset's runs)"
        )
    if opts.score_only and opts.quick and opts.out is None:
        parser.error("--score-only --quick needs --out, the folder of the quick runs to score "
                     "(each --quick run writes into a new temporary folder)")  # fmt: skip


def tuned_studies(paths: list[Path] | None) -> dict[tuple[str, str, str], tuple[tuple, int]]:
    """``(task, algo, variant) -> (overrides, timesteps)`` of each ``benchmarks.rl.tune`` summary
    in ``paths``: its best trial's hyperparameters and the budget it tuned at (a tuned
    configuration is retrained, and compared with the default one, at that budget)."""
    out: dict[tuple[str, str, str], tuple[tuple, int]] = {}
    for path in paths or []:
        try:
            key, overrides, summary = read_summary(path)
        except ValueError as exc:
            raise ValueError(f"--tuned {exc}") from None
        if key in out:
            raise ValueError(f"--tuned {path}: a second study of {key}")
        out[key] = (overrides, summary["settings"]["timesteps"])  # checked by read_summary
    return out


def specs_of(opts: Options) -> list[Any]:
    """The runs of ``opts`` (:func:`benchmarks.rl.train.run_specs`)."""
    studies = tuned_studies(opts.tuned)
    return run_specs(opts.config_keys(), filled("seeds", opts.seeds), opts.timesteps, opts.quick,
                     filled("tasks", opts.tasks), PRESETS[opts.preset]["budgets"],
                     {key: o for key, (o, _) in studies.items()},
                     {key: steps for key, (_, steps) in studies.items()})  # fmt: skip


# ----------------------------------------------------------------------------- scoring
def evaluation_seeds(opts: Options) -> tuple[int, ...]:
    """The evaluation's noise seeds: ``--seed``, ``--seed + 1``, ... (``--eval-seeds`` of them)."""
    return tuple(range(opts.seed, opts.seed + opts.eval_seeds))


def score_model_based(model: Any, opts: Options) -> list[ControllerResult]:
    out = []
    for curve in MODEL_BASED_CURVES:
        for xi in curve.levels(opts.quick):
            score = evaluate(curve.build(model, xi), episodes=opts.eval_episodes,
                             seed=evaluation_seeds(opts), env_id=MACRO,
                             env_kwargs=comparison_env_kwargs(MACRO))  # fmt: skip
            empty = (
                None if curve.constraint is None else empty_band_share(model, xi, curve.constraint)
            )
            out.append(ControllerResult(f"{curve.family} xi={xi:g}", curve.family, score, xi,
                                        curve.constraint, empty))  # fmt: skip
    for name, family, build in SINGLE_CONTROLLERS:
        score = evaluate(build(model), episodes=opts.eval_episodes, seed=evaluation_seeds(opts),
                         env_id=MACRO, env_kwargs=comparison_env_kwargs(MACRO))  # fmt: skip
        out.append(ControllerResult(name, family, score))
    return out


def incomes(controller: Any, opts: Options) -> Any:
    """The first income trajectories ``x_k(2)`` (R, T + 1) on the evaluation episodes."""
    bound = comparison_env_kwargs(MACRO)["action_bound"]
    ro = rollout(macro(), controller, opts.eval_episodes, HORIZON, opts.seed, bound)
    return ro.x[:INCOME_TRAJECTORIES, :, 1]


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> Summary | dict[str, Any] | None:
    """Train (and, without ``--train-only``, score) as the options say.

    Returns the macro comparison's :class:`~benchmarks.rl.report.Summary` (``--tasks`` the
    macro task alone), the suite report's summary dict (other tasks,
    :func:`benchmarks.rl.suite_report.report_suite`), or None (``--train-only``).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    out, tasks, configs = (
        filled("out", opts.out),
        filled("tasks", opts.tasks),
        filled("configs", opts.configs),
    )
    if opts.quick:
        log(f"--quick: writing to {out}")
    out.mkdir(parents=True, exist_ok=True)
    specs = specs_of(opts)
    log(f"{len(specs)} training runs: {len(tasks)} task(s) x {', '.join(configs)} x "
        f"{opts.seeds} seed(s)")  # fmt: skip
    run_dir = out / "runs"
    trained: list[Any]
    if opts.score_only:  # what is kept; the report names the rest
        trained = kept_runs(specs, run_dir)
    else:
        trained = train_all(specs, run_dir, backend=opts.backend, workers=opts.workers,
                            address=opts.address, retrain=opts.retrain,
                            progress=not opts.no_progress, log=log)  # fmt: skip
    if opts.train_only:
        log(f"--train-only: {len(trained)} run(s) kept in {run_dir}; no scoring")
        return None
    if opts.hides_mode():  # the mode hidden: its own wing
        from benchmarks.hidden import main as hidden_main

        return hidden_main(hidden_argv(opts, run_dir))
    if opts.tasks != [MACRO]:
        return report_suite(specs, trained, run_dir, opts, argv, log)
    if None in trained:
        missing = ", ".join(s.name for s, r in zip(specs, trained, strict=True) if r is None)
        raise SystemExit(f"--score-only: the macro comparison needs every run; missing: {missing}")
    return report_macro(specs, trained, run_dir, opts, argv)


def hidden_argv(opts: Options, run_dir: Path) -> list[str]:
    """``python -m benchmarks.hidden``'s options for the runs of ``opts`` (its evaluation
    seeds are its own constant, ``benchmarks.hidden.EVAL_SEEDS``: ``--seed`` is not passed, and
    other seeds are refused by :func:`parse_args`)."""
    argv = ["--runs", str(run_dir), "--out", str(opts.out), "--episodes", str(opts.eval_episodes),
            "--seeds", str(opts.seeds), "--tasks", *filled("tasks", opts.tasks),
            "--configs", *filled("configs", opts.configs), "--workers", str(opts.workers)]  # fmt: skip
    if opts.timesteps is not None:
        argv += ["--timesteps", str(opts.timesteps)]
    return argv + (["--quick"] if opts.quick else [])


def report_macro(specs: list[Any], trained: list[Any], run_dir: Path, opts: Options,
                 argv: list[str]) -> Summary:  # fmt: skip
    """The comparison on the macro task: every agent and model-based controller scored on the
    same episodes; summary.json, summary.csv, the figures and REPORT.md."""
    model, out = macro(), filled("out", opts.out)
    algos, variants = filled("algos", opts.algos), filled("variants", opts.variants)
    # every controller is scored after the training, in this process: the same machine load
    # for the decision times of all of them
    log(f"scoring the model-based controllers on {opts.eval_episodes} episodes")
    mb = score_model_based(model, opts)
    log(f"scoring the {len(specs)} trained agents on the same episodes")
    import torch

    torch.set_num_threads(1)  # as in training, and for the agents' decision times
    policies = {
        s.name: load_policy(s, policy_path(filled(f"the run {s.name}", kept_run_path(run_dir, s))))
        for s in specs
    }
    runs = [
        RunResult(
            run,
            evaluate(
                policies[s.name],
                episodes=opts.eval_episodes,
                seed=evaluation_seeds(opts),
                env_id=MACRO,
                env_kwargs=comparison_env_kwargs(MACRO),
            ),
        )  # fmt: skip
        for s, run in zip(specs, trained, strict=True)
    ]
    aggs = aggregate(runs)
    best, best_row = best_agent(aggs, runs, 1 - XI), best_config(aggs, 1 - XI)
    reference = next(r for r in mb if r.name == f"{MODEL_BASED_CURVES[0].family} xi={XI:g}")
    panels = [(f"RHC individual, xi = {XI:g}", reference.score,
               incomes(MODEL_BASED_CURVES[0].build(model, XI), opts))]  # fmt: skip
    if best is not None:
        panels.append((f"best agent: {best.name}", best.score, incomes(policies[best.name], opts)))
    status = curve_status([r.run for r in runs])
    curves = [(c.family, c.color, [r for r in mb if r.family == c.family])
              for c in MODEL_BASED_CURVES]  # fmt: skip
    singles = [r for r in mb if r.xi is None]
    figures = make_figures(out, curves, singles, aggs, runs, status, panels,
                           model.H(np.arange(HORIZON + 1)), XI)  # fmt: skip
    summary = Summary(
        command="python -m benchmarks.compare_rl" + ("" if not argv else " " + " ".join(argv)),
        options={k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()},
        versions=package_versions(),
        timesteps={
            a: {s.variant: s.timesteps for s in specs if s.algo == a and s.seed == specs[0].seed}
            for a in algos
        },  # fmt: skip
        hyperparams=hyperparams_record(algos, variants),
        model_based=mb,
        rl_runs=runs,
        rl_aggregates=aggs,
        learning_curves=status,
        violation_interval_check=interval_check([(r.name, r.score) for r in mb + runs]),
        best_config=None if best is None else f"{best.run.algo.upper()} {best.run.variant}",
        best_config_comparable=bool(best_row is not None and comparable(best_row, 1 - XI)),
        best_agent=None if best is None else best.name,
        against_best_agent=against_best_agent(mb, best),
        against_curves={
            c.family: against_curve(
                [r for r in mb if r.family == c.family],
                [r for r in mb if r.family != c.family] + runs,
            )
            for c in MODEL_BASED_CURVES
            if c.compared_against
        },  # fmt: skip
        figures=figures,
    )
    # atomic (write, then rename), as the runs are: an interrupted run never leaves half a file
    write_atomic(
        out / "summary.json", json.dumps(stable_floats(summary.to_json()), indent=1) + "\n"
    )
    write_csv(out / "summary.csv", mb + aggs + runs)
    write_atomic(out / "REPORT.md", write_report(summary, XI, MODEL_BASED_CURVES[0].family))
    log(f"wrote {out}/REPORT.md")
    return summary


if __name__ == "__main__":
    main()
