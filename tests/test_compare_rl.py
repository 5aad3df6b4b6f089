"""``python -m benchmarks.compare_rl --quick`` end to end, its run files, and its report's records.

The end-to-end fixture trains every algorithm in every kind of variant (reward alone, a fixed
penalty, residual, Lagrangian) for about a thousand steps (about 30 s on one core) and checks the
files, the summary's schema, that every number is finite and that the paper's controller is in
the table. The tests assert numbers and files, never the wording of the report.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from benchmarks.core.files import stable_floats  # noqa: E402
from benchmarks.core.versions import PACKAGES  # noqa: E402
from benchmarks.rl import compare as compare_rl  # noqa: E402
from benchmarks.rl import hyperparams as HP  # noqa: E402
from benchmarks.rl import train as rl_train  # noqa: E402
from benchmarks.rl.backends import train_all  # noqa: E402
from benchmarks.rl.report import CSV_HEADER, best_agent, best_config  # noqa: E402

ARGS = [
    "--quick",
    "--tasks", "SDJLS-Macro-v0",
    "--algos", "ppo", "sac", "td3",
    "--variants", "reward", "beta1000", "residual", "lagrangian",
    "--seeds", "1",
    "--timesteps", "1050",
    "--eval-episodes", "200",
    "--workers", "1",
    "--no-progress",
]  # fmt: skip

FIGURES = {
    "fig_cost_violation.png",
    "fig_learning_curves.png",
    "fig_lagrangian_beta.png",
    "fig_income.png",
}


def _finite(value) -> bool:
    """Every number inside ``value`` (nested dicts and lists) is finite."""
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    if isinstance(value, float):
        return math.isfinite(value)
    return True


def _check_score(name: str, s: dict) -> None:
    assert s["cost_ci95"][0] <= s["cost_mean"] <= s["cost_ci95"][1], name
    assert 0.0 <= s["violation_wilson95"][0] <= s["violation"] <= s["violation_wilson95"][1] <= 1
    assert s["violation_episode_t95"][0] <= s["violation"] <= s["violation_episode_t95"][1], name
    assert 0 <= s["diverged"] <= s["episodes"]
    assert s["decision_time_batched_s"] > 0 and s["decision_time_single_s"] > 0
    assert _finite(s), name


def _numbers(score) -> dict:
    """A score's statistics without its decision times (which are measured anew)."""
    d = score.to_dict(per_episode=True)
    return {k: v for k, v in d.items() if not k.startswith("decision_time")}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rl")
    summary = compare_rl.main([*ARGS, "--out", str(out)])
    return out, summary


def test_quick_run_writes_every_output(quick_run):
    out, _ = quick_run
    for name in ("summary.csv", "summary.json", "REPORT.md", *FIGURES):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert len(list((out / "runs" / "SDJLS-Macro-v0").glob("*.json"))) == 3 * 4
    # small files only: no checkpoint ever lands in the output folder
    assert all(p.stat().st_size < 1_000_000 for p in out.rglob("*"))
    assert not list(out.rglob("*.zip")) and not list(out.rglob("*.pkl"))


def test_quick_run_summary_schema(quick_run):
    out, returned = quick_run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"].startswith("python -m benchmarks.compare_rl --quick")
    assert set(summary["versions"]) == {"python", *PACKAGES} and all(summary["versions"].values())
    assert set(summary["figures"]) == FIGURES
    assert summary["hyperparams"]["algorithms"]["ppo"]["n_steps"] == HP.PPO["n_steps"]

    names = {r["name"] for r in summary["model_based"]}
    assert {f"RHC individual xi={xi:g}" for xi in compare_rl.XI_SWEEP} <= names
    assert {f"RHC joint xi={xi:g}" for xi in compare_rl.XI_SWEEP} <= names
    assert {"RHC unconstrained", "Linear feedback (nu = 0)", "MJLS LQR"} <= names
    for row in summary["model_based"]:
        _check_score(row["name"], row["score"])
        assert row["score"]["episodes"] == 200 and row["score"]["steps"] == 20

    runs = summary["rl_runs"]
    assert {(r["algo"], r["variant"]) for r in runs} == {
        (a, v)
        for a in ("ppo", "sac", "td3")
        for v in ("reward", "beta1000", "residual", "lagrangian")
    }
    for r in runs:
        _check_score(r["name"], r["score"])
        assert r["score"]["episodes"] == 200  # the same episodes as the model-based controllers
        assert r["timesteps"] >= 1050
        curve = r["learning_curve"]
        assert curve[0]["timesteps"] == 0 and len(curve) == 4
        assert [p["timesteps"] for p in curve] == sorted(p["timesteps"] for p in curve)
        gap = r["score"]["curve_gap"]
        if gap is not None:  # the paired gap to the RHC curve, where it is a fair reference
            assert r["score"]["diverged"] == 0
            assert gap["ci95"][0] <= gap["mean"] <= gap["ci95"][1]
            assert gap["mean"] == pytest.approx(r["score"]["cost_mean"] - gap["curve_cost"])
        if r["variant"] == "lagrangian":
            assert r["dual_ascent"], r["name"]
            # beta <- max(0, beta + lr_dual * (freq - (1 - xi))), freq from the evaluation
            # episodes of the deterministic policy (a multiple of 1 / (episodes x 20 steps))
            lag, prev = HP.LAGRANGIAN, HP.LAGRANGIAN["beta0"]
            for p in r["dual_ascent"]:
                step = lag["lr_dual"] * (p["freq"] - (1 - lag["xi"]))
                assert p["beta"] == pytest.approx(max(0.0, prev + step), rel=1e-12, abs=1e-9)
                assert 0 <= p["train_freq"] <= 1
                count = p["freq"] * lag["episodes"] * 20
                assert count == pytest.approx(round(count), abs=1e-6)
                prev = p["beta"]
            assert r["final_beta"] == prev != HP.LAGRANGIAN["beta0"]
        else:
            assert not r["dual_ascent"]
        # the training time counts the evaluations made during training
        assert 0.0 < r["eval_time_s"] < r["train_time_s"] == r["wall_time_s"], r["name"]
        assert r["cpu_time_s"] > 0.0

    aggs = summary["rl_aggregates"]
    assert len(aggs) == 12
    by_config = {(r["algo"], r["variant"]): r for r in runs}
    for a in aggs:
        assert a["cost_ci95"][0] >= 0.0  # a cost: the interval stops at 0
        # one seed: the interval is that seed's over episodes, not a zero-width one
        assert a["cost_ci95"] == by_config[(a["algo"], a["variant"])]["score"]["cost_ci95"]
        assert a["violation"] == by_config[(a["algo"], a["variant"])]["score"]["violation"]
    assert summary["best_agent"] in {r["name"] for r in runs}
    best = next(r for r in runs if r["name"] == summary["best_agent"])
    assert summary["best_config"] == f"{best['algo'].upper()} {best['variant']}"
    assert {d["name"] for d in summary["against_best_agent"]} == names
    assert {s["algo"] for s in summary["learning_curves"]} == {"ppo", "sac", "td3"}
    assert summary["timesteps"] == {  # --timesteps overrides every per-variant default budget
        a: {v: 1050 for v in ("reward", "beta1000", "residual", "lagrangian")}
        for a in ("ppo", "sac", "td3")
    }
    assert summary["violation_interval_check"]["stable"]["rows"] >= 1
    assert returned.model_based[0].name == summary["model_based"][0]["name"]


def test_quick_run_csv_and_report(quick_run):
    out, summary = quick_run
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == CSV_HEADER
    kinds = [r["kind"] for r in rows]
    assert kinds.count("rl-seed") == 12 and kinds.count("rl-aggregate") == 12
    assert kinds.count("model-based") == len(summary.model_based)
    by_name = {r["name"]: r for r in rows}
    for m in summary.model_based + summary.rl_runs:
        row = by_name[m.name]
        assert float(row["episode_cost_mean"]) == pytest.approx(m.score.cost_mean, rel=1e-5)
        assert float(row["violation"]) == pytest.approx(m.score.violation, abs=1e-6)
        lo, hi = float(row["violation_episode_lo"]), float(row["violation_episode_hi"])
        assert lo <= float(row["violation"]) <= hi
    for r in rows:
        if r["kind"] == "rl-aggregate":
            assert r["violation_episode_lo"] == r["violation_episode_hi"] == ""
    report = (out / "REPORT.md").read_text()
    assert summary.command in report
    tables = [line for line in report.splitlines() if line.startswith("| ")]
    first = {line.split(" | ")[0][2:] for line in tables}
    assert {"RHC individual xi=0.85", "TD3 residual", "ppo_residual_s0"} <= first
    for fig in FIGURES:
        assert f"]({fig})" in report


@pytest.mark.slow  # reruns the --quick comparison (about 15 s)
def test_rerun_reuses_finished_trainings(quick_run):
    out, first = quick_run
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").rglob("*")}
    again = compare_rl.main([*ARGS, "--out", str(out)])
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").rglob("*")} == stamps
    assert [_numbers(r.score) for r in again.rl_runs] == [_numbers(r.score) for r in first.rl_runs]


def test_policies_are_kept_small_and_fit_their_architecture(quick_run):
    """Each run keeps its policy (tens of KB); it loads strictly into the rebuilt policy."""
    out, summary = quick_run
    opts = compare_rl.parse_args([*ARGS, "--out", str(out)])  # no new quick folder
    specs = compare_rl.specs_of(opts)
    assert {s.name for s in specs} == {r.name for r in summary.rl_runs}
    obs = np.random.default_rng(0).uniform(-1, 1, (64, 6)).astype(np.float32)
    for spec in specs:
        folder = out / "runs" / spec.task
        path = rl_train.policy_path(rl_train.run_path(folder, spec.name, spec.fingerprint()))
        assert 0 < path.stat().st_size < 500_000, spec.name
        a, _ = rl_train.load_policy(spec, path).agent.predict(obs, deterministic=True)
        assert a.shape == (64, 1) and np.all(np.abs(a) <= 1.0), spec.name


@pytest.mark.parametrize("algo", rl_train.ALGOS)
def test_reloaded_policy_equals_the_trained_agent(tmp_path, algo):
    """The saved state dict, rebuilt by load_policy, acts as the agent did (weights perturbed
    first, so that a policy left at its initialization could not pass by accident)."""
    import torch

    spec = rl_train.RunSpec(algo, "residual", 0, 300, 1, 5, 1)
    agent = rl_train.build_agent(spec, [lambda: rl_train._train_env(spec)])
    with torch.no_grad():
        for p in agent.policy.parameters():
            p.add_(0.3 * torch.randn_like(p))
    torch.save(agent.policy.state_dict(), tmp_path / "p.pt")
    obs = np.random.default_rng(1).uniform(-1, 1, (32, 6)).astype(np.float32)
    expected, _ = agent.predict(obs, deterministic=True)
    got, _ = rl_train.load_policy(spec, tmp_path / "p.pt").agent.predict(obs, deterministic=True)
    np.testing.assert_array_equal(got, expected)
    assert np.ptp(expected) > 0.01  # the actions depend on the observation


def _copy(quick_run, tmp_path) -> Path:
    out = tmp_path / "rl"
    shutil.copytree(quick_run[0], out)
    return out


@pytest.mark.slow  # reruns the --quick comparison (about 15 s)
def test_rescoring_needs_no_training(quick_run, tmp_path):
    """More evaluation episodes: the kept runs are rescored, not trained again."""
    out, first = _copy(quick_run, tmp_path), quick_run[1]
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").rglob("*")}
    args = [a if a != "200" else "300" for a in ARGS]  # --eval-episodes 300
    again = compare_rl.main([*args, "--out", str(out)])
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").rglob("*")} == stamps
    assert {r.score.episodes for r in again.rl_runs + again.model_based} == {300}
    for a, b in zip(first.rl_runs, again.rl_runs, strict=True):
        assert a.run.learning_curve == b.run.learning_curve


@pytest.mark.slow  # reruns the --quick comparison (about 15 s)
def test_a_run_without_its_policy_is_trained_again(quick_run, tmp_path):
    out = _copy(quick_run, tmp_path)
    (victim,) = (out / "runs").rglob("td3_reward_s0-*.pt")
    victim.unlink()
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").rglob("*.json")}
    compare_rl.main([*ARGS, "--out", str(out)])
    assert victim.exists()
    changed = {
        p.name for p in (out / "runs").rglob("*.json") if p.stat().st_mtime_ns != stamps[p.name]
    }
    assert changed == {victim.with_suffix(".json").name}


def test_old_run_files_without_cpu_time_still_load(tmp_path):
    """Run files written before ``cpu_time_s`` and ``eval_time_s`` existed (most of the
    committed ones) are reused, their missing times None."""
    spec = rl_train.RunSpec("ppo", "residual", 0, 300, 1, 5, 1)
    record = rl_train.RunRecord(spec.name, "ppo", "residual", 0, spec.fingerprint(),
                                spec.config(), 300, 1.0, 1.0, 1000.0, [], [])  # fmt: skip
    data = record.to_json()
    del data["cpu_time_s"], data["eval_time_s"]
    path = rl_train.run_path(tmp_path / spec.task, spec.name, spec.fingerprint())
    path.parent.mkdir()
    path.write_text(json.dumps(data))
    rl_train.policy_path(path).write_bytes(b"x")
    loaded = rl_train.load_run(tmp_path, spec)
    assert loaded.cpu_time_s is None and loaded.final_beta == 1000.0
    other = rl_train.RunSpec("ppo", "residual", 0, 301, 1, 5, 1)  # another budget
    rl_train.run_path(tmp_path / spec.task, other.name, spec.fingerprint()).write_text(
        json.dumps(data)
    )
    assert rl_train.load_run(tmp_path, other) is None


def test_committed_runs_match_the_current_configuration():
    """Every kept policy of the committed comparison is reused by its command (``--preset
    macro``; its fingerprint before the suite matches): regenerating results/rl/ needs no
    training."""
    opts = compare_rl.parse_args(["--preset", "macro"])
    assert opts.out == Path("results/rl") and opts.tasks == ["SDJLS-Macro-v0"]
    specs = compare_rl.specs_of(opts)
    root = Path(compare_rl.__file__).resolve().parents[2]
    assert all(rl_train.load_run(root / "results/rl/runs", s) is not None for s in specs)
    # in the layout that names a run by its configuration (issue 28: a run of another
    # configuration must land beside a kept run, never in its place)
    for s in specs:
        path = rl_train.kept_run_path(root / "results/rl/runs", s)
        expected = rl_train.run_path(root / "results/rl/runs", s.name, s.legacy_fingerprint())
        assert path == expected
    assert len(list((root / "results/rl/runs").iterdir())) == 2 * len(specs) == 108


@pytest.mark.slow  # reruns the --quick comparison (about 15 s)
def test_cost_violation_figure_marks_agents_still_learning(quick_run, tmp_path, monkeypatch):
    """Agents whose curve is not flat get a hollow marker and a "(still learning)" label."""
    from matplotlib.axes import Axes

    out = _copy(quick_run, tmp_path)
    calls = []
    real = Axes.errorbar

    def spy(self, *args, **kw):
        calls.append((kw.get("label"), kw.get("mfc")))
        return real(self, *args, **kw)

    real_status = compare_rl.curve_status

    def mixed_status(runs):  # a quick run's short curves may all judge alike: force one of each
        return [dataclasses.replace(s, flat=i == 0) for i, s in enumerate(real_status(runs))]

    monkeypatch.setattr(Axes, "errorbar", spy)
    monkeypatch.setattr(compare_rl, "curve_status", mixed_status)
    summary = compare_rl.main([*ARGS, "--out", str(out)])
    flat = {(c.algo, c.variant): c.flat for c in summary.learning_curves}
    assert set(flat.values()) == {True, False}
    for row in summary.rl_aggregates:
        still = not flat[(row.algo, row.variant)]
        label = row.name + (" (still learning)" if still else "")
        marks = [mfc for lab, mfc in calls if lab == label]
        assert marks, label  # drawn in at least the full panel
        assert all((mfc == "none") == still for mfc in marks), (label, marks)


# ------------------------------------------------------------------ budgets and options
def test_default_budgets_per_variant():
    """The per-variant budgets override the per-algorithm ones, and only where they are listed."""
    pairs = [(a, v) for a in rl_train.ALGOS for v in rl_train.VARIANTS]
    specs = rl_train.run_specs(pairs, 3, None, False, budgets="macro")
    assert len(specs) == 3 * 6 * 3
    for s in specs:
        assert s.timesteps == HP.TIMESTEPS_VARIANT.get((s.algo, s.variant), HP.TIMESTEPS[s.algo])
    for (algo, variant), n in HP.TIMESTEPS_VARIANT.items():
        assert algo in rl_train.ALGOS and variant in rl_train.VARIANTS
        assert n > HP.TIMESTEPS[algo], (algo, variant)  # an override only ever adds training
    quick = rl_train.run_specs([("ppo", "reward")], 1, None, True)
    assert {s.timesteps for s in quick} == {HP.QUICK_TIMESTEPS}


def test_variant_hyperparameters_change_only_their_variant(monkeypatch):
    """HYPERPARAMS_VARIANT replaces the listed entries for one (algo, variant): the agent is built
    with them, the run's fingerprint changes (so the kept run is trained again), the other
    variants and the module's dicts are untouched."""
    before = copy.deepcopy(HP.HYPERPARAMS)
    base = [rl_train.RunSpec("sac", v, 0, 1000, 1, 5, 0) for v in ("reward", "beta1000")]
    prints = [s.fingerprint() for s in base]
    monkeypatch.setattr(HP, "HYPERPARAMS_VARIANT", {("sac", "reward"): {"learning_rate": 2e-5}})
    assert HP.hyperparams("sac", "reward") == {**HP.SAC, "learning_rate": 2e-5}
    assert HP.hyperparams("sac", "beta1000") == HP.SAC
    assert HP.HYPERPARAMS == before
    assert base[0].fingerprint() != prints[0] and base[1].fingerprint() == prints[1]
    lrs = [rl_train.build_agent(s, [lambda s=s: rl_train._train_env(s)]).learning_rate
           for s in base]  # fmt: skip
    assert lrs == [2e-5, HP.SAC["learning_rate"]]


def test_linear_learning_rate_schedule_reaches_the_agent(monkeypatch):
    """``lin_<r>`` becomes SB3's schedule: r at the start, r/4 with a quarter left, 0 at the end
    and after it; bad rates are refused with the value in the message."""
    schedule = HP.learning_rate("lin_1e-3")
    assert [schedule(p) for p in (1.0, 0.25, 0.0, -0.05)] == pytest.approx([1e-3, 2.5e-4, 0, 0])
    assert HP.learning_rate(3e-4) == 3e-4
    for bad in ("lin_", "lin_abc", "lin_-1e-3", "lin_nan", "cos_1e-3", 0, -1e-3, float("inf"),
                True):  # fmt: skip
        with pytest.raises(ValueError, match="learning_rate = "):
            HP.learning_rate(bad)
    monkeypatch.setattr(
        HP, "HYPERPARAMS_VARIANT", {("sac", "reward"): {"learning_rate": "lin_2e-3"}}
    )
    spec = rl_train.RunSpec("sac", "reward", 0, 1000, 1, 5, 0)
    agent = rl_train.build_agent(spec, [lambda: rl_train._train_env(spec)])
    assert agent.lr_schedule(1.0) == pytest.approx(2e-3)
    assert agent.lr_schedule(0.5) == pytest.approx(1e-3)
    json.dumps(spec.config())  # the entry stays text in the run's configuration


def test_trainings_start_longest_first(tmp_path, monkeypatch):
    """train_all starts the runs by estimated training time, longest first; the records keep the
    order of the specs, and every finished run is written at once."""
    from benchmarks.rl import backends as backends

    order = []

    def fake_train(spec, report=None, should_stop=None):
        order.append(spec.name)
        point = rl_train.CurvePoint(spec.timesteps, 0.0, 1.0, 1.0, 0.5, 0, None)
        record = rl_train.RunRecord(spec.name, spec.algo, spec.variant, spec.seed,
                                    spec.fingerprint(), spec.config(), spec.timesteps, 0.0, 0.0,
                                    None, [point], [])  # fmt: skip
        return record, b"policy"

    monkeypatch.setattr(backends, "train_run", fake_train)
    pairs = [(a, v) for a in rl_train.ALGOS for v in rl_train.VARIANTS]
    specs = rl_train.run_specs(pairs, 1, None, False, budgets="macro")
    by_name = {s.name: s for s in specs}
    results = train_all(specs, tmp_path, workers=1, progress=False, log=lambda msg: None)
    assert sorted(order) == sorted(by_name)
    hours = [by_name[n].timesteps / HP.STEPS_PER_SECOND[by_name[n].algo] for n in order]
    assert hours == sorted(hours, reverse=True) and hours[0] > 10 * hours[-1]
    assert [r.timesteps for r in results] == [s.timesteps for s in specs]
    assert all(rl_train.load_run(tmp_path, s) is not None for s in specs)  # written, reusable


def test_bad_options_are_rejected(capsys):
    for argv, message in (
        (["--eval-episodes", "1"], "--eval-episodes = 1 is out of range"),
        (["--workers", "0"], "--workers = 0; expected a positive integer"),
        (["--address", "auto"], "--address = 'auto' needs --backend ray"),
        (["--preset", "hidden", "--eval-seeds", "2"], "the noise seeds (0, 1, 2)"),
        (["--preset", "hidden", "--seed", "5"], "leave --seed and --eval-seeds out"),
    ):
        with pytest.raises(SystemExit):
            compare_rl.parse_args(argv)
        assert message in capsys.readouterr().err


def test_the_hidden_preset_takes_its_own_noise_seeds(tmp_path):
    """With the mode hidden the wing's seeds (0, 1, 2) are accepted when named; training alone
    takes any, and the scoring is handed the training's --workers."""
    opts = compare_rl.parse_args(["--preset", "hidden", "--seed", "0", "--eval-seeds", "3"])
    assert compare_rl.hidden_argv(opts, tmp_path)[-2:] == ["--workers", "2"]
    assert compare_rl.parse_args(["--preset", "hidden", "--train-only", "--eval-seeds", "2"])


def test_best_agent_is_the_median_seed_of_the_cheapest_safe_configuration():
    from types import SimpleNamespace as NS

    def agg(algo, variant, cost, v, div):
        return NS(algo=algo, variant=variant, cost_mean=cost, violation=v, diverged=div)

    def run(algo, variant, seed, cost):
        return NS(run=NS(algo=algo, variant=variant, name=f"{algo}_{variant}_s{seed}"),
                  score=NS(cost_mean=cost))  # fmt: skip

    aggs = [
        agg("ppo", "residual", 4600.0, 0.22, 0),  # too many violations
        agg("td3", "beta10000", 5000.0, 0.155, 0),  # the answer
        agg("td3", "lagrangian", 900.0, 0.10, 4),  # cheap but diverges
        agg("sac", "beta10000", 5200.0, 0.18, 0),
    ]
    runs = [run("td3", "beta10000", seed, c) for seed, c in enumerate((5200, 4700, 5100))]
    runs += [run("sac", "beta10000", 0, 10.0)]
    assert best_config(aggs, 0.15).variant == "beta10000"
    assert best_agent(aggs, runs, 0.15).run.name == "td3_beta10000_s2"  # 5100: the median
    unsafe = [agg("a", "x", 1.0, 0.9, 3), agg("b", "y", 9.0, 0.95, 0), agg("c", "z", 5.0, 0.5, 0)]
    assert best_config(unsafe, 0.15).algo == "c"  # fewest diverged, then fewest violations
    assert best_agent([], [], 0.15) is None


def test_quick_run_marks_the_rhc_points_whose_tightened_band_is_empty(quick_run):
    """The band is 3 wide with unit-variance rows: empty for individual xi > Phi(1.5) and joint
    xi > 1 - exp(-2.25 / 2) (see tests/test_chance.py); those points score the same."""
    from scipy import stats

    summary = quick_run[1]
    edge = {"individual": stats.norm.cdf(1.5), "joint": 1.0 - math.exp(-2.25 / 2.0)}
    one_step = {"RHC individual", "RHC joint"}
    rows = [r for r in summary.model_based if r.family in one_step]
    assert len(rows) == 2 * len(compare_rl.XI_SWEEP)
    for r in rows:
        assert r.tightened_band_empty == float(r.xi > edge[r.constraint]), r.name
    empty = [r for r in rows if r.tightened_band_empty == 1.0]
    # the same controller up to round-off: the slack absorbs the excess tightening, and nu
    # does not depend on xi (it differs in the last bits only)
    ref = empty[0].score
    for r in empty:
        assert r.score.violation == ref.violation, r.name
        assert r.score.cost_mean == pytest.approx(ref.cost_mean, rel=1e-12), r.name


# ------------------------------------------------------------------ the multi-step curve
def test_quick_run_scores_the_multistep_curve_and_compares_with_it(quick_run):
    """The 3-step RHC (issue 21) is a curve of the comparison: its quick levels are scored on
    the same episodes, and every other controller is compared with it at its own violation
    frequency."""
    out, summary = quick_run
    curve = next(c for c in compare_rl.MODEL_BASED_CURVES if c.family == "RHC 3-step")
    points = [r for r in summary.model_based if r.family == "RHC 3-step"]
    assert [r.xi for r in points] == list(curve.quick_xis)
    assert all(r.score.episodes == 200 for r in points)
    # its own points are 0 against themselves by construction: left out
    rows = summary.against_curves["RHC 3-step"]
    assert rows and not {d.name for d in rows} & {r.name for r in points}
    for d in rows:
        assert d.ci95[0] <= d.mean <= d.ci95[1], d.name
        assert d.mean == pytest.approx(d.cost_mean - d.curve_cost, rel=1e-9, abs=1e-9)
        assert min(curve.quick_xis) - 1e-12 <= d.xi <= max(curve.quick_xis) + 1e-12
    # the one-step point at xi = 0.85 lies inside the 3-step curve's range of frequencies
    assert "RHC individual xi=0.85" in {d.name for d in rows}
    saved = json.loads((out / "summary.json").read_text())["against_curves"]["RHC 3-step"]
    # the file holds the digits that are the same on every machine (benchmarks.core.files)
    assert saved == stable_floats([dataclasses.asdict(d) | {"ci95": list(d.ci95)} for d in rows])
    assert "## Against the RHC 3-step curve" in (out / "REPORT.md").read_text()


def test_against_curve_interpolates_at_the_controllers_own_frequency():
    """A curve of two points (frequency 0.1 at cost 100, 0.3 at cost 50) on 50 episodes: a
    controller at frequency 0.2 and cost 70 is 5 below the curve's 75 there, with xi halfway;
    a diverged controller and one outside the curve's range are left out."""
    from types import SimpleNamespace

    from benchmarks.rl.report import against_curve

    E = 50

    def row(name, cost, viol, xi=None, diverged=0):
        score = SimpleNamespace(episode_costs=np.full(E, float(cost)), cost_mean=float(cost),
                                episode_violations=np.full(E, viol), diverged=diverged)  # fmt: skip
        return SimpleNamespace(name=name, family="curve" if xi else "other", xi=xi, score=score)

    points = [row("c 0.9", 50.0, 0.3, 0.9), row("c 0.7", 100.0, 0.1, 0.7)]
    others = [row("inside", 70.0, 0.2), row("diverged", 70.0, 0.2, diverged=1),
              row("outside", 10.0, 0.5)]  # fmt: skip
    out = against_curve(points, others)
    assert [d.name for d in out] == ["inside"]
    (d,) = out
    assert d.curve_cost == pytest.approx(75.0) and d.mean == pytest.approx(-5.0)
    assert d.ci95 == pytest.approx((-5.0, -5.0))  # no spread between the episodes
    assert d.xi == pytest.approx(0.8) and d.curve == "curve"
    assert against_curve(points[:1], others) == []


@pytest.mark.slow  # reruns the --quick comparison (about 15 s)
def test_every_labelled_mark_of_the_figures_is_in_a_legend(quick_run, tmp_path, monkeypatch):
    """Issue 33: marks drawn only in the full panel of fig_cost_violation.png (diverging agents,
    beyond the zoom) had no legend entry. Every labelled artist of every saved figure must appear
    in a legend of that figure (its axes' legends or the figure's)."""
    from matplotlib.figure import Figure

    out = _copy(quick_run, tmp_path)
    unnamed: dict[str, set[str]] = {}
    real = Figure.savefig

    def spy(self, fname, *args, **kw):
        marks = {lab for ax in self.axes for lab in ax.get_legend_handles_labels()[1]}
        legends = [ax.get_legend() for ax in self.axes] + list(self.legends)
        named = {t.get_text() for lg in legends if lg is not None for t in lg.get_texts()}
        if marks - named:
            unnamed[Path(fname).name] = marks - named
        return real(self, fname, *args, **kw)

    monkeypatch.setattr(Figure, "savefig", spy)
    compare_rl.main([*ARGS, "--out", str(out)])
    assert not unnamed, unnamed
