"""Tune one agent of the RL comparison on one task, with Optuna or Ray Tune's Optuna search.

``python -m benchmarks.tune --algo ppo --variant residual --task SDJLS-Macro-v0 --trials 40
--timesteps N --storage sqlite:///PATH.db`` runs an Optuna study: a TPE sampler over the
algorithm's search space (:data:`SEARCH_SPACE`, printed by ``--print-space``), a median pruner on
the learning curve, and SQLite storage, so that the same command resumes the study (``--trials``
is the study's total of finished trials: a study stopped at 25 of 40 runs 15 more; trials left
running by a killed process are retried once). ``--backend ray`` runs the trials as Ray Tune
trials through ``ray.tune.search.optuna.OptunaSearch`` on the same storage (``--address`` for a
cluster; by default a local instance of ``--workers`` CPUs), stopped early by Ray's
``MedianStoppingRule`` on the same learning curve.

A trial trains the agent (:func:`benchmarks.rl.train.train_run`, the comparison's environment
recipe) with the trial's hyperparameters for ``--timesteps`` steps on each of ``--seeds`` seeds
from :data:`TUNE_SEED0` on (seeds the comparison never uses, so that a tuned configuration is
retrained on fresh seeds 0-4). Its learning curve is scored at each point by
:func:`point_objective`: the episode cost minus the task's receding-horizon curve at the same
violation frequency (on the learning curve's own episodes, not the evaluation's), relative to the
RHC's cost at the task's ``xi``; riskier than the curve scores above 1, diverging above 2. The
trial's value is the mean over seeds of the points after 70% of training (lower is better).

Outputs under ``--out`` (default ``results/tune``; with ``--quick``, a new temporary folder): the
study database (unless ``--storage`` names another), ``runs/<task>/`` (the trials' kept runs) and
``<study>.json`` (the search space, every trial with its spending, and the best).
"""

from __future__ import annotations

import functools
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.core.cli import (
    filled,
    option,
    output_folder,
    parse_options,
    plain_name_error,
    script_parser,
)
from benchmarks.core.files import stable_floats, write_atomic
from benchmarks.core.logs import log
from benchmarks.core.stats import efficient_points
from benchmarks.rl import hyperparams as HP
from benchmarks.rl.backends import ray_init_kwargs
from benchmarks.rl.envs import get_task, task_settings
from benchmarks.rl.train import ALGOS, VARIANTS, CurvePoint, RunSpec, save_run, train_run
from benchmarks.rl.tune_summary import read_summary
from sdjls_gym import SUITE

__all__ = [
    "SEARCH_SPACE",
    "TUNE_SEED0",
    "Options",
    "Param",
    "main",
    "point_objective",
    "read_summary",
    "reference_curve",
    "suggest",
]

#: First seed of the tuning trials: the comparison trains seeds 0, 1, ...; tuning never does.
TUNE_SEED0 = 100
DEFAULT_OUT = Path("results/tune")
QUICK = {"trials": 3, "timesteps": 500, "curve_points": 3, "curve_episodes": 20}


@dataclass(frozen=True)
class Param:
    """One hyperparameter's range: ``"log"`` (log-uniform float in [low, high]), ``"float"``
    (uniform) or ``"cat"`` (one of ``choices``)."""

    kind: str
    low: float | None = None
    high: float | None = None
    choices: tuple[Any, ...] = ()

    def describe(self) -> str:
        if self.kind == "cat":
            return "one of " + ", ".join(str(c) for c in self.choices)
        scale = "log-uniform" if self.kind == "log" else "uniform"
        return f"{scale} in [{self.low:g}, {self.high:g}]"


#: Network sizes by name (Optuna's categorical choices are plain values).
NET_ARCHS: dict[str, list[int]] = {"64x64": [64, 64], "128x128": [128, 128],
                                   "256x256": [256, 256]}  # fmt: skip

#: The search space of each algorithm, written once: learning rate, network size, batch, and
#: the exploration parameter (PPO's entropy bonus and initial log-std, SAC's target-network rate,
#: TD3's action noise and target smoothing noise); :data:`DUAL_SPACE` adds the Lagrangian's dual
#: step. The defaults of :mod:`benchmarks.rl.hyperparams` are inside every range.
SEARCH_SPACE: dict[str, dict[str, Param]] = {
    "ppo": {
        "learning_rate": Param("log", 3e-5, 3e-3),
        "net_arch": Param("cat", choices=tuple(NET_ARCHS)),
        "batch_size": Param("cat", choices=(64, 128, 256, 512)),
        "n_steps": Param("cat", choices=(128, 256, 512)),
        "ent_coef": Param("cat", choices=(0.0, 1e-4, 1e-3, 1e-2)),
        "log_std_init": Param("float", -3.0, -1.0),
    },
    "sac": {
        "learning_rate": Param("log", 1e-4, 3e-3),
        "net_arch": Param("cat", choices=tuple(NET_ARCHS)),
        "batch_size": Param("cat", choices=(64, 128, 256, 512)),
        "tau": Param("cat", choices=(0.002, 0.005, 0.01, 0.02)),
    },
    "td3": {
        "learning_rate": Param("log", 1e-4, 3e-3),
        "net_arch": Param("cat", choices=tuple(NET_ARCHS)),
        "batch_size": Param("cat", choices=(64, 128, 256, 512)),
        "noise_std": Param("log", 0.02, 0.3),
        "target_policy_noise": Param("log", 0.05, 0.4),
    },
}
#: The Lagrangian variant's dual step, as a factor of the task's default ``lr_dual``.
DUAL_SPACE: dict[str, Param] = {"lr_dual_factor": Param("log", 0.1, 10.0)}


def space(algo: str, variant: str) -> dict[str, Param]:
    """The search space of ``algo`` in ``variant``."""
    return {**SEARCH_SPACE[algo], **(DUAL_SPACE if variant == "lagrangian" else {})}


def describe_space(algo: str, variant: str) -> list[str]:
    """The search space as lines of text (``--print-space`` and the study's summary)."""
    return [f"{name}: {p.describe()}" for name, p in space(algo, variant).items()]


def suggest(trial: Any, algo: str, variant: str) -> dict[str, Any]:
    """The trial's hyperparameters, drawn by Optuna's ``trial.suggest_*`` from :func:`space`."""
    out: dict[str, Any] = {}
    for name, p in space(algo, variant).items():
        if p.kind == "cat":
            out[name] = trial.suggest_categorical(name, list(p.choices))
        else:
            out[name] = trial.suggest_float(name, p.low, p.high, log=p.kind == "log")
    return out


def overrides(params: dict[str, Any], task: str) -> tuple[tuple[str, Any], ...]:
    """A trial's parameters as :attr:`benchmarks.rl.train.RunSpec.overrides`."""
    out: list[tuple[str, Any]] = []
    for name, value in sorted(params.items()):
        if name == "net_arch":
            out.append(("net_arch", list(NET_ARCHS[value])))
        elif name == "lr_dual_factor":
            out.append(("lr_dual", float(value) * task_settings(task).lagrangian()["lr_dual"]))
        elif isinstance(value, (bool, np.bool_)):
            out.append((name, bool(value)))
        elif isinstance(value, (int, np.integer)):
            out.append((name, int(value)))
        else:
            out.append((name, float(value)))
    return tuple(out)


# ----------------------------------------------------------------------------- objective
@functools.lru_cache(maxsize=16)
def reference_curve(task: str, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """The task's receding-horizon controller over ``benchmarks.evaluate.REFERENCE_XIS`` on
    ``episodes`` episodes from noise seed ``seed``: ``(violations (P,), mean costs (P,),
    cost at the task's xi)`` of its efficient points (:func:`benchmarks.core.stats.efficient_points`),
    sorted by violation frequency."""
    from benchmarks.core.evaluate import REFERENCE_XIS, resolve_env, rollout_statistics
    from benchmarks.core.montecarlo import rollout
    from controllers import RecedingHorizonController

    t = get_task(task)
    env = resolve_env(task, dict(t.env_kwargs))
    points = []
    for xi in sorted({*REFERENCE_XIS, float(t.rhc["xi"])}):
        ctrl = RecedingHorizonController(t.model, t.K, horizon=t.horizon, **{**t.rhc, "xi": xi})
        ro = rollout(t.model, ctrl, episodes, t.horizon, seed, env.action_bound, None,
                     env.divergence_bound)  # fmt: skip
        s = rollout_statistics(ro, env.divergence_bound)
        points.append((s["violation"], s["cost_mean"], xi))
    ref = next(c for v, c, xi in points if xi == float(t.rhc["xi"]))
    viols, costs = np.array([p[0] for p in points]), np.array([p[1] for p in points])
    keep = efficient_points(viols, costs)  # sorted by violation frequency
    return viols[keep], costs[keep], float(ref)


def point_objective(
    point: CurvePoint, episodes: int, curve: tuple[np.ndarray, np.ndarray, float]
) -> float:
    """One learning-curve point's score, lower is better.

    Without a diverged episode and no riskier than the curve's riskiest efficient point: the
    mean episode cost minus the curve's cost at the point's violation frequency (the curve's
    safest point's below its range), relative to the RHC's cost at the task's ``xi``, capped at
    0.99. Riskier than every efficient point of the curve: 1 + the excess frequency. With
    diverged episodes: 2 + their share.
    """
    viols, costs, ref = curve
    if point.diverged > 0:
        return 2.0 + point.diverged / episodes
    if point.violation > viols[-1]:
        return 1.0 + float(point.violation - viols[-1])
    gap = (point.episode_cost_mean - float(np.interp(point.violation, viols, costs))) / ref
    return min(float(gap), 0.99)


def late_value(curve: list[CurvePoint], episodes: int, reference: Any) -> float:
    """The mean :func:`point_objective` of the points after 70% of training (at least one)."""
    last = curve[-1].timesteps
    late = [p for p in curve if p.timesteps > 0.7 * last] or curve[-1:]
    return float(np.mean([point_objective(p, episodes, reference) for p in late]))


# ----------------------------------------------------------------------------- options
@dataclass
class Options:
    algo: str = option("ppo", "algorithm", choices=ALGOS)
    variant: str = option("residual", "variant", choices=VARIANTS)
    task: str = option("SDJLS-Macro-v0", "suite env id", choices=SUITE)
    trials: int | None = option(
        None,
        f"finished trials the study holds at the end (default 40; {QUICK['trials']} with --quick)",
    )
    timesteps: int | None = option(
        None,
        "env steps per trial and seed (default: the suite's budget of the "
        f"configuration; {QUICK['timesteps']} with --quick)",
    )
    seeds: int = option(1, f"seeds per trial (from {TUNE_SEED0} on)")
    storage: str | None = option(None, "Optuna storage URL (default: sqlite:///<out>/studies.db)")
    study_name: str | None = option(
        None,
        "study name, a plain name: <out>/<study>.json is its summary (default: "
        "<task>-<algo>-<variant>-<timesteps>-<seeds>s)",
    )
    out: Path | None = option(
        None,
        f"folder for the study database, runs/ and <study>.json (default: "
        f"{DEFAULT_OUT}, or a new temporary folder with --quick)",
    )
    backend: str = option(
        "optuna",
        "run the trials in this process (optuna) or as Ray Tune trials (ray)",
        choices=("optuna", "ray"),
    )
    address: str | None = option(None, "Ray cluster to join with --backend ray")
    workers: int = option(1, "trials at once with --backend ray (a local instance's CPUs)")
    seed: int = option(0, "seed of the TPE sampler")
    quick: bool = option(
        False,
        f"smoke test: {QUICK['trials']} trials of {QUICK['timesteps']} steps, "
        f"{QUICK['curve_points']} learning-curve points of {QUICK['curve_episodes']} "
        "episodes",
    )
    print_space: bool = option(False, "print the search space and exit")
    no_progress: bool = option(False, "do not log each trial")

    @property
    def curve_points(self) -> int:
        return QUICK["curve_points"] if self.quick else HP.LEARNING_CURVE["points"]

    @property
    def curve_episodes(self) -> int:
        return QUICK["curve_episodes"] if self.quick else HP.LEARNING_CURVE["episodes"]


def parse_args(argv: list[str] | None = None) -> Options:
    parser = script_parser(Options, "tune", __doc__)
    opts = parse_options(parser, Options, argv)
    for name in ("trials", "timesteps", "seeds", "workers"):
        value = getattr(opts, name)
        if value is not None and value < 1:
            parser.error(f"--{name} = {value}; expected a positive integer")
    if opts.seed < 0:
        parser.error(f"--seed = {opts.seed}; expected an integer >= 0")
    if opts.address is not None and opts.backend != "ray":
        parser.error(f"--address = {opts.address!r} needs --backend ray")
    if opts.trials is None:
        opts.trials = QUICK["trials"] if opts.quick else 40
    if opts.timesteps is None:
        opts.timesteps = (QUICK["timesteps"] if opts.quick
                          else HP.suite_timesteps(opts.task, opts.algo, opts.variant))  # fmt: skip
    if opts.study_name is not None and (error := plain_name_error("--study-name", opts.study_name)):
        parser.error(error)
    if opts.storage is not None and not opts.storage.startswith(("sqlite:///", "postgresql",
                                                                 "mysql")):  # fmt: skip
        parser.error(
            f"--storage = {opts.storage!r}; expected an Optuna RDB URL, e.g. sqlite:///PATH.db"
        )
    if opts.storage is not None and opts.storage.startswith("sqlite:///"):  # its folder too
        output_folder(parser, "--storage", Path(opts.storage[len("sqlite:///") :]).parent,
                      quick=opts.quick, default=None, script="tune")  # fmt: skip
    quick = opts.quick and not opts.print_space  # a new folder only for a run that writes
    opts.out = output_folder(parser, "--out", opts.out, quick=quick, default=DEFAULT_OUT,
                             script="tune")  # fmt: skip
    opts.out = opts.out.resolve()  # Ray's trials run in folders of their own
    if opts.storage is None:
        opts.storage = f"sqlite:///{(opts.out / 'studies.db').resolve()}"
    if opts.study_name is None:
        opts.study_name = f"{opts.task}-{opts.algo}-{opts.variant}-{opts.timesteps}-{opts.seeds}s"
    return opts


# ----------------------------------------------------------------------------- trials
def study_attrs(opts: Options) -> dict[str, Any]:
    """What a study's trials depend on; a study is resumed only with the same."""
    return {"algo": opts.algo, "variant": opts.variant, "task": opts.task,
            "timesteps": opts.timesteps, "seeds": opts.seeds, "curve_points": opts.curve_points,
            "curve_episodes": opts.curve_episodes}  # fmt: skip


def run_trial(params: dict[str, Any], opts: Options, report: Any = None) -> tuple[float, list[str]]:
    """Train the trial's agent on each seed; its value and the kept runs' file names.

    ``report(value, timesteps)`` is called at each learning-curve point of the first seed (an
    exception it raises, a pruning, ends the trial)."""
    reference = reference_curve(opts.task, opts.curve_episodes, HP.LEARNING_CURVE["seed"])
    timesteps, out = filled("timesteps", opts.timesteps), filled("out", opts.out)
    values, names = [], []
    for i in range(opts.seeds):
        spec = RunSpec(opts.algo, opts.variant, TUNE_SEED0 + i, timesteps, opts.curve_points,
                       opts.curve_episodes, HP.LEARNING_CURVE["seed"], opts.task,
                       overrides(params, opts.task))  # fmt: skip

        def on_point(point: CurvePoint, first: bool = i == 0) -> None:
            if report is not None and first and point.timesteps > 0:
                report(point_objective(point, opts.curve_episodes, reference), point.timesteps)

        record, policy = train_run(spec, on_curve_point=on_point)
        names.append(save_run(out / "runs", record, policy).name)
        values.append(late_value(record.learning_curve, opts.curve_episodes, reference))
    return float(np.mean(values)), names


def _storage(url: str, heartbeat: bool = True) -> Any:
    """The RDB storage at ``url``, with heartbeats (``Study.optimize`` only; Ray Tune tracks its
    own trials): a trial left running by a killed process is marked failed after 3 minutes
    without one and retried once (Optuna's own hook)."""
    import warnings

    import optuna
    from optuna.storages import RDBStorage, RetryHeartbeatStaleTrialCallback

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if not heartbeat:
        return RDBStorage(url)
    with warnings.catch_warnings():  # the heartbeat is "experimental" in Optuna 5
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        retry = RetryHeartbeatStaleTrialCallback(max_retry=1)
        return RDBStorage(url, heartbeat_interval=60, grace_period=180,
                          heartbeat_stale_trial_callback=retry)  # fmt: skip


def load_study(opts: Options) -> Any:
    """The study of ``opts`` (created, or loaded from its storage) with the TPE sampler seeded by
    ``--seed`` and the number of trials already in it, and the median pruner."""
    import optuna

    warmup = int(0.3 * filled("timesteps", opts.timesteps))
    pruner = optuna.pruners.MedianPruner(n_startup_trials=1 if opts.quick else 5,
                                         n_warmup_steps=warmup)  # fmt: skip
    study = optuna.create_study(study_name=opts.study_name, storage=_storage(filled("storage", opts.storage)),
                                direction="minimize", load_if_exists=True, pruner=pruner)  # fmt: skip
    attrs = study_attrs(opts)
    kept = {k: study.user_attrs[k] for k in attrs if k in study.user_attrs}
    if kept and kept != attrs:
        raise ValueError(
            f"study {opts.study_name!r} in {opts.storage} was run with {kept}, not {attrs}; "
            "give another --study-name"
        )
    for key, value in attrs.items():
        study.set_user_attr(key, value)
    study.sampler = optuna.samplers.TPESampler(seed=opts.seed * 100_003 + len(study.trials))
    return study


def finished(study: Any) -> int:
    import optuna

    done = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    return len(study.get_trials(deepcopy=False, states=done))


def optimize_optuna(study: Any, opts: Options, log: Any) -> None:
    """Trials in this process until the study holds ``opts.trials`` finished ones."""
    import optuna

    def objective(trial: Any) -> float:
        params = suggest(trial, opts.algo, opts.variant)
        reached = [0]  # the first seed's last reported step: where a pruned trial stopped

        def report(value: float, step: int) -> None:
            reached[0] = step
            trial.report(value, step)
            if trial.should_prune():
                raise optuna.TrialPruned(f"pruned at {step} steps (value {value:.4g})")

        t0, c0, steps = time.perf_counter(), time.process_time(), None
        try:
            value, names = run_trial(params, opts, report)
            steps = filled("timesteps", opts.timesteps) * opts.seeds
        finally:  # a pruned trial's spending too
            trial.set_user_attr("wall_s", time.perf_counter() - t0)
            trial.set_user_attr("cpu_s", time.process_time() - c0)
            trial.set_user_attr("env_steps", reached[0] if steps is None else steps)
        trial.set_user_attr("runs", names)
        return value

    def logged(study: Any, trial: Any) -> None:
        log(f"trial {trial.number}: {trial.state.name} value {trial.value} {trial.params}")

    trials = filled("trials", opts.trials)
    todo = trials - finished(study)
    if todo <= 0:
        log(f"study {opts.study_name} already holds {finished(study)} finished trials")
        return
    stop = optuna.study.MaxTrialsCallback(
        trials, states=(optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    )
    study.optimize(objective, n_trials=todo, callbacks=[stop, logged], catch=())


def _define_by_run(trial: Any, algo: str, variant: str) -> None:
    """OptunaSearch's define-by-run space: draw the parameters, return no constants."""
    suggest(trial, algo, variant)


def _ray_trainable(config: dict[str, Any], opts: dict[str, Any]) -> None:
    """A Ray Tune trial: :func:`run_trial` with the parameters OptunaSearch drew."""
    from ray import tune

    o = Options(**{**opts, "out": Path(opts["out"])})
    value, _ = run_trial(config, o, lambda v, t: tune.report({"objective": v, "timesteps": t}))
    steps = filled("timesteps", o.timesteps) * o.seeds + 1
    tune.report({"objective": value, "timesteps": steps, "final": True})


def optimize_ray(study: Any, opts: Options, log: Any) -> None:
    """The trials as Ray Tune trials: OptunaSearch on the study's storage (TPE), Ray's
    MedianStoppingRule on the learning curve (a trial it stops is recorded with its last
    point's score)."""
    try:
        import ray
        from ray import tune
        from ray.tune.schedulers import MedianStoppingRule
        from ray.tune.search.optuna import OptunaSearch
    except ImportError as exc:
        raise ImportError(
            f'--backend ray needs Ray Tune ({exc}): pip install -e ".[cluster]"'
        ) from None
    trials, timesteps = filled("trials", opts.trials), filled("timesteps", opts.timesteps)
    storage, out = filled("storage", opts.storage), filled("out", opts.out)
    todo = trials - finished(study)
    if todo <= 0:
        log(f"study {opts.study_name} already holds {finished(study)} finished trials")
        return
    ray.init(**ray_init_kwargs(opts.workers, opts.address))

    # by their module's name, not __main__'s (python -m benchmarks.tune): Ray's workers import them
    from benchmarks.rl.tune import _define_by_run, _ray_trainable

    try:
        searcher = OptunaSearch(
            space=functools.partial(_define_by_run, algo=opts.algo, variant=opts.variant),
            metric="objective", mode="min", study_name=opts.study_name,
            storage=_storage(storage, heartbeat=False), sampler=study.sampler,
        )  # fmt: skip
        scheduler = MedianStoppingRule(time_attr="timesteps", metric="objective", mode="min",
                                       grace_period=int(0.3 * timesteps),
                                       min_samples_required=1 if opts.quick else 5)  # fmt: skip
        plain = {k: str(v) if isinstance(v, Path) else v for k, v in asdict(opts).items()}
        tuner = tune.Tuner(
            tune.with_resources(tune.with_parameters(_ray_trainable, opts=plain), {"cpu": 1}),
            tune_config=tune.TuneConfig(search_alg=searcher, scheduler=scheduler,
                                        num_samples=todo, max_concurrent_trials=opts.workers),
            run_config=tune.RunConfig(name=opts.study_name, verbose=0,
                                      storage_path=str((out / "ray").resolve())),
        )  # fmt: skip
        tuner.fit()
    finally:
        ray.shutdown()


# ----------------------------------------------------------------------------- summary
def _trial_times(trial: Any) -> dict[str, float | None]:
    """A finished trial's wall time (Optuna's stamps), its CPU time and env steps where it
    recorded them (``optimize_optuna`` records both; older trials and Ray's do not)."""
    start, end, attrs = trial.datetime_start, trial.datetime_complete, trial.user_attrs
    wall = None if start is None or end is None else (end - start).total_seconds()
    return {"wall_s": wall, "cpu_s": attrs.get("cpu_s"), "env_steps": attrs.get("env_steps")}


def summarize(study: Any, opts: Options) -> dict[str, Any]:
    """The study as ``<out>/<study>.json`` holds it: settings, space, trials, best."""
    import optuna

    trials = [
        {"number": t.number, "state": t.state.name, "value": t.value, "params": t.params,
         "intermediate": {str(k): v for k, v in sorted(t.intermediate_values.items())},
         "runs": t.user_attrs.get("runs", []), **_trial_times(t)}
        for t in study.get_trials(deepcopy=False)
    ]  # fmt: skip
    complete = [t for t in study.get_trials(deepcopy=False)
                if t.state == optuna.trial.TrialState.COMPLETE]  # fmt: skip
    best = min(complete, key=lambda t: t.value) if complete else None
    return {
        "study": opts.study_name,
        "storage": opts.storage,
        "settings": study_attrs(opts),
        "search_space": describe_space(opts.algo, opts.variant),
        "trials": trials,
        "best": None if best is None else {"number": best.number, "value": best.value,
                                           "params": best.params,
                                           "overrides": dict(overrides(best.params, opts.task))},
    }  # fmt: skip


def main(argv: list[str] | None = None) -> dict[str, Any] | None:
    """Run ``python -m benchmarks.tune`` with ``argv``: tune one agent on one task, resuming
    the study in ``--storage``; return the study's summary (None with ``--print-space``)."""
    opts = parse_args(argv)
    say = (lambda msg: None) if opts.no_progress else log
    if opts.print_space:
        print("\n".join(describe_space(opts.algo, opts.variant)))
        return None
    out = filled("out", opts.out)
    if opts.quick:
        print(f"--quick: writing to {out}", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    study = load_study(opts)
    say(f"study {opts.study_name} ({opts.storage}): {finished(study)} of {opts.trials} trials "
        f"finished; {opts.algo} {opts.variant} on {opts.task}, {opts.timesteps} steps x "
        f"{opts.seeds} seed(s) per trial")  # fmt: skip
    (optimize_ray if opts.backend == "ray" else optimize_optuna)(study, opts, say)
    summary = summarize(load_study(opts), opts)
    path = out / f"{opts.study_name}.json"
    write_atomic(path, json.dumps(stable_floats(summary), indent=1, default=str) + "\n")
    best = summary["best"]
    say(f"wrote {path}; best: " + ("-" if best is None else f"trial {best['number']}, value "
                                  f"{best['value']:.4g}, {best['params']}"))  # fmt: skip
    return summary


if __name__ == "__main__":
    main()
