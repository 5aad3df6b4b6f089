"""The receding-horizon controller against stable-baselines3 agents on cost and violation frequency.

Run ``python -m benchmarks.compare_rl --help`` for the options. On ``SDJLS-Macro-v0`` it trains
PPO, SAC and TD3 (``--algos``) with ``--seeds`` seeds each in six variants (``--variants``): on
the reward alone (``reward``), with a violation penalty ``reward - beta * info["cost"]``
(``beta100``, ``beta1000``, ``beta10000``), as residual agents choosing ``nu`` on top of the
paper's gains (``residual``, beta = 1000), and with ``beta`` adapted by dual ascent towards a
violation frequency of ``1 - xi = 0.15`` (``lagrangian``). Every agent and every model-based
controller (:data:`MODEL_BASED_CURVES`, :data:`SINGLE_CONTROLLERS`) is then scored by
:func:`benchmarks.evaluate.evaluate` on the same ``--eval-episodes`` episodes (common random
numbers).

Outputs under ``--out`` (default ``results/rl/``; with ``--quick`` a temporary folder,
:data:`QUICK_OUT`): ``summary.json``, ``summary.csv``, the figures, ``REPORT.md`` (each written
atomically), and per training ``runs/<name>-<fingerprint>.json`` (learning curve, dual ascent,
training time) and ``.pt`` (the policy's state dict, 40-130 KB). A run is named by the fingerprint
of its whole configuration: a kept run of the same configuration is not trained again
(``--retrain`` trains anew), and a run of another configuration is kept beside it, never in its
place. The evaluation is not cached, so a change of the evaluation needs no training. The
trainings run in local processes or as Ray tasks (``--backend``, :mod:`benchmarks.backends`).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from benchmarks import rl_hyperparams as HP
from benchmarks.backends import BACKENDS, train_all
from benchmarks.evaluate import REFERENCE_XIS, check_evaluation, evaluate
from benchmarks.files import stable_floats, write_atomic
from benchmarks.montecarlo import multistep_rhc, paper_rhc, rollout
from benchmarks.rl_figures import make_figures
from benchmarks.rl_report import (
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
    write_report,
)
from benchmarks.rl_train import (
    ALGOS,
    VARIANTS,
    kept_run_path,
    load_policy,
    policy_path,
    run_specs,
)
from benchmarks.stats import curve_status, interval_check
from benchmarks.versions import package_versions
from controllers import (
    LinearFeedbackController,
    MJLSLQRController,
    UnconstrainedRecedingHorizonController,
    tightened_set_empty,
)
from sdjls_gym.systems.macro import HORIZON, PAPER_K, PAPER_RHC, macro

XI = PAPER_RHC["xi"]
XI_SWEEP = REFERENCE_XIS
INCOME_TRAJECTORIES = 30  # incomes drawn per panel of the income figure
DEFAULT_OUT = Path("results/rl")
#: Where ``--quick`` writes by default: outside the repository (a temporary folder).
QUICK_OUT = Path(tempfile.gettempdir()) / "sdjls-gym" / "compare_rl-quick"


# ----------------------------------------------------------------------------- controllers
@dataclass(frozen=True)
class ModelBasedCurve:
    """A model-based controller over a sweep of its level ``xi``: one point per level, named
    ``"<family> xi=<xi>"``. The first entry of :data:`MODEL_BASED_CURVES` is the reference that
    every controller's paired gap is measured against (:data:`benchmarks.evaluate.REFERENCE_XIS`).
    """

    family: str
    build: Callable[[Any, float], Any]  # (model, xi) -> controller
    xis: tuple[float, ...] = XI_SWEEP
    constraint: str | None = None  # for the share of steps with an empty tightened band
    color: str = "k"
    #: the levels scored with ``--quick`` (default: all of ``xis``), for a slow controller
    quick_xis: tuple[float, ...] | None = None
    #: whether every other controller's cost is also compared with this curve, paired over the
    #: episodes at the controller's own violation frequency (:func:`benchmarks.rl_report.against_curve`)
    compared_against: bool = False

    def levels(self, quick: bool) -> tuple[float, ...]:
        """The levels ``xi`` scored (:attr:`quick_xis` with ``--quick``)."""
        return self.quick_xis if quick and self.quick_xis is not None else self.xis


#: The model-based curves of the comparison; add a row to add a curve.
MODEL_BASED_CURVES: tuple[ModelBasedCurve, ...] = (
    ModelBasedCurve(
        "RHC individual",
        lambda m, xi: paper_rhc(m, xi, "individual"),
        constraint="individual",
        color="k",
    ),  # fmt: skip
    ModelBasedCurve(
        "RHC joint", lambda m, xi: paper_rhc(m, xi, "joint"), constraint="joint", color="0.45"
    ),  # fmt: skip
    # the multi-step controller (issue 21): a fully branched scenario tree of 3 stages; the
    # root's chance constraint is P3's, so the tightened band is the one-step curve's
    ModelBasedCurve(
        "RHC 3-step",
        lambda m, xi: multistep_rhc(m, xi, 3, "individual"),
        constraint="individual",
        color="C4",
        quick_xis=(0.5, 0.85, 0.95),
        compared_against=True,
    ),  # fmt: skip
)

#: The model-based controllers without a level: ``(name, family, build(model))``.
SINGLE_CONTROLLERS: tuple[tuple[str, str, Callable[[Any], Any]], ...] = (
    (
        "RHC unconstrained",
        "RHC unconstrained",
        lambda m: UnconstrainedRecedingHorizonController(
            m,
            PAPER_K,
            Psi=PAPER_RHC["Psi"],
            alpha=PAPER_RHC["alpha"],
            nu_bound=PAPER_RHC["nu_bound"],
            horizon=HORIZON,
        ),  # fmt: skip
    ),
    (
        "Linear feedback (nu = 0)",
        "Linear feedback",
        lambda m: LinearFeedbackController(m, PAPER_K, horizon=HORIZON),
    ),  # fmt: skip
    ("MJLS LQR", "MJLS LQR", lambda m: MJLSLQRController(m, "average", horizon=HORIZON)),
)


# ----------------------------------------------------------------------------- options
@dataclass
class Options:
    algos: list[str] = field(
        default_factory=lambda: list(ALGOS),
        metadata={"help": "stable-baselines3 algorithms to train", "nargs": "+", "choices": ALGOS},
    )
    variants: list[str] = field(
        default_factory=lambda: list(VARIANTS),
        metadata={"help": "training variants", "nargs": "+", "choices": VARIANTS},
    )
    timesteps: int | None = field(
        default=None,
        metadata={
            "help": "env steps per training run (default: per algorithm and variant, "
            "benchmarks/rl_hyperparams.py; "
            f"{HP.QUICK_TIMESTEPS} with --quick; N replaces them all)"
        },
    )
    seeds: int = field(default=3, metadata={"help": "training seeds per algorithm and variant"})
    eval_episodes: int = field(
        default=1000,
        metadata={"help": "evaluation episodes per controller and trained agent (one noise seed)"},
    )
    seed: int = field(default=0, metadata={"help": "noise seed of the evaluation episodes"})
    out: Path | None = field(
        default=None,
        metadata={
            "help": "folder for figures, summary files, REPORT.md and runs/ (*.json, *.pt); "
            f"default: {DEFAULT_OUT}, or {QUICK_OUT} with --quick (a smoke test never writes "
            "into the committed results)"
        },
    )
    workers: int = field(
        default=2,
        metadata={"help": "trainings run at once (processes, or the CPUs of a local Ray instance)"},
    )
    backend: str = field(
        default="process",
        metadata={
            "help": "where the trainings run: local processes or Ray tasks",
            "choices": BACKENDS,
        },  # fmt: skip
    )
    address: str | None = field(
        default=None,
        metadata={
            "help": "Ray cluster to join with --backend ray ('auto' after `ray start "
            "--head`); default: a local Ray instance of --workers CPUs"
        },  # fmt: skip
    )
    quick: bool = field(
        default=False,
        metadata={
            "help": f"smoke test: {HP.QUICK_TIMESTEPS} steps per run, 200 evaluation episodes, "
            "3 learning-curve points of 20 episodes"
        },
    )
    retrain: bool = field(
        default=False, metadata={"help": "train again even when runs/ has the trained run"}
    )
    no_progress: bool = field(default=False, metadata={"help": "do not show the progress bar"})


def parse_args(argv: list[str] | None = None) -> Options:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.compare_rl",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    for f in fields(Options):
        flag, meta = "--" + f.name.replace("_", "-"), f.metadata
        if f.type in ("bool", bool):
            parser.add_argument(flag, action="store_true", help=meta["help"])
        elif "nargs" in meta:
            parser.add_argument(flag, nargs="+", choices=meta["choices"],
                                default=f.default_factory(), help=meta["help"])  # fmt: skip
        elif "choices" in meta:
            parser.add_argument(flag, choices=meta["choices"], default=f.default, help=meta["help"])
        else:
            conv = {"out": Path, "address": str}.get(f.name, int)
            parser.add_argument(flag, type=conv, default=f.default, help=meta["help"])
    given = {a.split("=")[0] for a in (sys.argv[1:] if argv is None else argv)}
    opts = Options(**vars(parser.parse_args(argv)))
    if opts.quick and "--eval-episodes" not in given:
        opts.eval_episodes = 200
    for name in ("seeds", "workers"):
        if getattr(opts, name) < 1:
            parser.error(f"--{name} = {getattr(opts, name)}; expected a positive integer")
    try:  # evaluate()'s own limits, before hours of training
        check_evaluation(opts.eval_episodes, opts.seed)
    except ValueError as exc:
        text = str(exc).replace("episodes = ", "--eval-episodes = ", 1)
        parser.error(text.replace("seed = ", "--seed = ", 1))
    if opts.timesteps is not None and opts.timesteps < 1:
        parser.error(f"--timesteps = {opts.timesteps}; expected a positive integer")
    if opts.address is not None and opts.backend != "ray":
        parser.error(f"--address = {opts.address!r} needs --backend ray")
    if opts.out is None:
        opts.out = QUICK_OUT if opts.quick else DEFAULT_OUT
    elif opts.quick and _holds_a_full_comparison(opts.out):
        parser.error(
            f"--quick with --out {opts.out}: that folder holds the report of a full comparison, "
            "which a smoke test would replace; give another --out (or none: "
            f"--quick writes to {QUICK_OUT})"
        )
    opts.algos = list(dict.fromkeys(opts.algos))
    opts.variants = list(dict.fromkeys(opts.variants))
    return opts


def _holds_a_full_comparison(out: Path) -> bool:
    """Whether ``out/summary.json`` is the report of a run without ``--quick``."""
    try:
        options = json.loads((out / "summary.json").read_text())["options"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return isinstance(options, dict) and options.get("quick") is False


# ----------------------------------------------------------------------------- scoring
def empty_band_share(model: Any, xi: float, constraint: str) -> float:
    """Share of the (mode, next time) pairs of an episode at which the tightened band
    ``{y : G y <= H_{k+1} - t}`` is empty (:func:`controllers.tightened_set_empty`): there the
    QP is feasible only through its slack, whatever the state."""
    return float(
        np.mean([tightened_set_empty(model, xi, k, constraint) for k in range(1, HORIZON + 1)])
    )


def score_model_based(model: Any, opts: Options) -> list[ControllerResult]:
    out = []
    for curve in MODEL_BASED_CURVES:
        for xi in curve.levels(opts.quick):
            score = evaluate(curve.build(model, xi), episodes=opts.eval_episodes, seed=opts.seed)
            empty = (
                None if curve.constraint is None else empty_band_share(model, xi, curve.constraint)
            )
            out.append(ControllerResult(f"{curve.family} xi={xi:g}", curve.family, score, xi,
                                        curve.constraint, empty))  # fmt: skip
    for name, family, build in SINGLE_CONTROLLERS:
        score = evaluate(build(model), episodes=opts.eval_episodes, seed=opts.seed)
        out.append(ControllerResult(name, family, score))
    return out


def incomes(controller: Any, opts: Options) -> Any:
    """The first income trajectories ``x_k(2)`` (R, T + 1) on the evaluation episodes."""
    ro = rollout(macro(), controller, opts.eval_episodes, HORIZON, opts.seed)
    return ro.x[:INCOME_TRAJECTORIES, :, 1]


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> Summary:
    argv = sys.argv[1:] if argv is None else list(argv)
    opts = parse_args(argv)
    opts.out.mkdir(parents=True, exist_ok=True)

    def log(msg: str) -> None:
        tqdm.write(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr)

    model = macro()
    specs = run_specs(opts.algos, opts.variants, opts.seeds, opts.timesteps, opts.quick)
    log(f"{len(specs)} training runs: {', '.join(opts.algos)} x {', '.join(opts.variants)} x "
        f"{opts.seeds} seed(s)")  # fmt: skip
    run_dir = opts.out / "runs"
    trained = train_all(specs, run_dir, backend=opts.backend, workers=opts.workers,
                        address=opts.address, retrain=opts.retrain,
                        progress=not opts.no_progress, log=log)  # fmt: skip
    # every controller is scored after the training, in this process: the same machine load
    # for the decision times of all of them
    log(f"scoring the model-based controllers on {opts.eval_episodes} episodes")
    mb = score_model_based(model, opts)
    log(f"scoring the {len(specs)} trained agents on the same episodes")
    import torch

    torch.set_num_threads(1)  # as in training, and for the agents' decision times
    policies = {s.name: load_policy(s, policy_path(kept_run_path(run_dir, s))) for s in specs}
    runs = [
        RunResult(run, evaluate(policies[s.name], episodes=opts.eval_episodes, seed=opts.seed))
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
    figures = make_figures(opts.out, curves, singles, aggs, runs, status, panels,
                           model.H(range(HORIZON + 1)), XI)  # fmt: skip
    summary = Summary(
        command="python -m benchmarks.compare_rl" + ("" if not argv else " " + " ".join(argv)),
        options={k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()},
        versions=package_versions(),
        timesteps={
            a: {s.variant: s.timesteps for s in specs if s.algo == a and s.seed == 0}
            for a in opts.algos
        },  # fmt: skip
        hyperparams=hyperparams_record(opts.algos, opts.variants),
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
        opts.out / "summary.json", json.dumps(stable_floats(summary.to_json()), indent=1) + "\n"
    )
    write_csv(opts.out / "summary.csv", mb + aggs + runs)
    write_atomic(opts.out / "REPORT.md", write_report(summary, XI, MODEL_BASED_CURVES[0].family))
    log(f"wrote {opts.out}/REPORT.md")
    return summary


if __name__ == "__main__":
    main()
