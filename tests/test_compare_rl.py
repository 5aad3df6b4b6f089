"""``python -m benchmarks.compare_rl --quick`` end to end, and the policy adapter it scores agents with.

The end-to-end test trains every algorithm in every kind of variant (reward alone, a fixed
penalty, residual, Lagrangian) for about a thousand steps and checks the files, the JSON schema,
that every number is finite and that the paper's controller is in the table. It takes about
30 s on one core, so it runs with the rest of the suite.
"""

from __future__ import annotations

import copy
import csv
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from benchmarks import compare_rl  # noqa: E402
from benchmarks import rl_hyperparams as HP  # noqa: E402
from benchmarks.rl_eval import SB3Policy, make_train_env, scale_observation  # noqa: E402
from sdjls_gym.systems.macro import PAPER_K, macro  # noqa: E402

ARGS = [
    "--quick",
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


def _check_row(row: dict) -> None:
    cost, viol = row["episode_cost"], row["violation"]
    assert cost["ci95"][0] <= cost["mean"] <= cost["ci95"][1], row["name"]
    assert 0.0 <= viol["wilson95"][0] <= viol["freq"] <= viol["wilson95"][1] <= 1.0, row["name"]
    assert 0 <= row["diverged"] <= row["episodes"]
    assert row["decision_time_s"]["batched"] > 0 and row["decision_time_s"]["single"] > 0
    assert row["train_time_s"] >= 0
    assert _finite(row), row["name"]


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rl")
    summary = compare_rl.main([*ARGS, "--out", str(out)])
    return out, summary


def test_quick_run_writes_every_output(quick_run):
    out, _ = quick_run
    for name in ("summary.csv", "summary.json", "REPORT.md", *FIGURES):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    runs = sorted(p.name for p in (out / "runs").glob("*.json"))
    assert len(runs) == 3 * 4
    # small files only: no checkpoint ever lands in the output folder
    assert all(p.stat().st_size < 1_000_000 for p in out.rglob("*"))
    assert not list(out.rglob("*.zip")) and not list(out.rglob("*.pkl"))


def test_quick_run_summary_schema(quick_run):
    out, returned = quick_run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"].startswith("python -m benchmarks.compare_rl --quick")
    assert set(summary["figures"]) == FIGURES
    assert summary["hyperparams"]["algorithms"]["ppo"]["n_steps"] == HP.PPO["n_steps"]

    names = {r["name"] for r in summary["model_based"]}
    assert {"RHC individual xi=0.85", "RHC joint xi=0.85", "Linear feedback (nu = 0)"} <= names
    assert "MJLS LQR" in names
    assert {f"RHC individual xi={xi:g}" for xi in compare_rl.XI_SWEEP} <= names
    for row in summary["model_based"]:
        _check_row(row)
        assert row["episodes"] == 200 and row["steps"] == 20

    runs = summary["rl_runs"]
    assert {(r["algo"], r["variant"]) for r in runs} == {
        (a, v)
        for a in ("ppo", "sac", "td3")
        for v in ("reward", "beta1000", "residual", "lagrangian")
    }
    for r in runs:
        _check_row(r)
        assert r["episodes"] == 200  # the same episodes as the model-based controllers
        assert r["timesteps"] >= 1050
        curve = r["learning_curve"]
        assert curve[0]["timesteps"] == 0 and len(curve) == 4
        assert [p["timesteps"] for p in curve] == sorted(p["timesteps"] for p in curve)
        assert len(r["incomes"]) == compare_rl.INCOME_TRAJECTORIES
        assert len(r["incomes"][0]) == 21
    for r in runs:
        if r["variant"] == "lagrangian":
            assert r["dual_ascent"], r["name"]
            betas = [p["beta"] for p in r["dual_ascent"]]
            assert all(b >= 0 for b in betas)
            assert r["final_beta"] == betas[-1] != HP.LAGRANGIAN["beta0"]
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
        else:
            assert not r["dual_ascent"]

    aggs = summary["rl_aggregates"]
    assert len(aggs) == 12
    by_config = {(r["algo"], r["variant"]): r for r in runs}
    for a in aggs:
        _check_row(a)
        assert a["episode_cost"]["ci95"][0] >= 0.0  # a cost: the interval stops at 0
        # one seed: the interval is that seed's over episodes, not a zero-width one
        assert (
            a["episode_cost"]["ci95"]
            == by_config[(a["algo"], a["variant"])]["episode_cost"]["ci95"]
        )
    for r in runs:  # the paired gap to the RHC curve, where the curve is a fair reference
        if r["curve_gap"] is not None:
            assert r["diverged"] == 0
            assert r["curve_gap"]["ci95"][0] <= r["curve_gap"]["mean"] <= r["curve_gap"]["ci95"][1]
            gap = r["episode_cost"]["mean"] - r["curve_gap"]["curve_cost"]
            assert r["curve_gap"]["mean"] == pytest.approx(gap, rel=1e-9, abs=1e-6)
        assert not any(k.startswith("_") for k in r)
    assert summary["best_agent"] in {r["name"] for r in runs}
    best = next(r for r in runs if r["name"] == summary["best_agent"])
    assert summary["best_config"] == f"{best['algo'].upper()} {best['variant']}"
    assert {s["algo"] for s in summary["learning_curves"]} == {"ppo", "sac", "td3"}
    # --timesteps overrides every per-variant default budget
    assert summary["timesteps"] == {
        a: {v: 1050 for v in ("reward", "beta1000", "residual", "lagrangian")}
        for a in ("ppo", "sac", "td3")
    }
    assert returned["model_based"][0]["name"] == summary["model_based"][0]["name"]


def test_quick_run_csv_and_report(quick_run):
    out, summary = quick_run
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == compare_rl.CSV_HEADER
    kinds = [r["kind"] for r in rows]
    assert kinds.count("rl-seed") == 12 and kinds.count("rl-aggregate") == 12
    rhc = next(r for r in rows if r["name"] == "RHC individual xi=0.85")
    assert float(rhc["violation"]) > 0 and float(rhc["episode_cost_mean"]) > 0
    for r in rows:
        for key in ("episode_cost_mean", "violation", "violation_lo", "violation_hi"):
            assert math.isfinite(float(r[key])), (r["name"], key)
    report = (out / "REPORT.md").read_text()
    assert summary["command"] in report
    assert "| RHC individual xi=0.85 |" in report
    assert "## Learning curves" in report and "| TD3 residual | 1.05k |" in report
    for fig in FIGURES:
        assert f"]({fig})" in report


def test_rerun_reuses_finished_trainings(quick_run):
    out, first = quick_run
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")}
    again = compare_rl.main([*ARGS, "--out", str(out)])
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")} == stamps
    assert [r["episode_cost"] for r in again["rl_runs"]] == [
        r["episode_cost"] for r in first["rl_runs"]
    ]


def test_policies_are_kept_small_and_fit_their_architecture(quick_run):
    """Each run keeps its policy (tens of KB); it loads strictly into the rebuilt policy."""
    out, summary = quick_run
    specs = {s.name: s for s in compare_rl.run_specs(compare_rl.parse_args(ARGS))}
    assert set(specs) == {r["name"] for r in summary["rl_runs"]}
    obs = np.random.default_rng(0).uniform(-1, 1, (64, 6)).astype(np.float32)
    for name, spec in specs.items():
        path = out / "runs" / f"{name}.pt"
        assert 0 < path.stat().st_size < 500_000, name
        a, _ = compare_rl.load_policy(spec, path).predict(obs, deterministic=True)
        assert a.shape == (64, 1) and np.all(np.abs(a) <= 1.0), name


@pytest.mark.parametrize("algo", compare_rl.ALGOS)
def test_reloaded_policy_equals_the_trained_agent(tmp_path, algo):
    """The saved state dict, rebuilt by load_policy, acts as the agent did (weights perturbed
    first, so that a policy left at its initialization could not pass by accident)."""
    import torch

    spec = compare_rl.RunSpec(algo, "residual", 0, 300, 1, 5, 1)
    make_env, _ = compare_rl._train_setup(spec)
    agent = compare_rl.build_agent(spec, [make_env])
    with torch.no_grad():
        for p in agent.policy.parameters():
            p.add_(0.3 * torch.randn_like(p))
    torch.save(agent.policy.state_dict(), tmp_path / "p.pt")
    obs = np.random.default_rng(1).uniform(-1, 1, (32, 6)).astype(np.float32)
    expected, _ = agent.predict(obs, deterministic=True)
    got, _ = compare_rl.load_policy(spec, tmp_path / "p.pt").predict(obs, deterministic=True)
    np.testing.assert_array_equal(got, expected)
    assert np.ptp(expected) > 0.01  # the actions depend on the observation


def _copy(quick_run, tmp_path) -> Path:
    """A copy of the quick run's folder, for tests that run the command on it again."""
    out = tmp_path / "rl"
    shutil.copytree(quick_run[0], out)
    return out


def test_rescoring_needs_no_training(quick_run, tmp_path):
    """More evaluation episodes: the cached runs are rescored, not trained again."""
    out, first = _copy(quick_run, tmp_path), quick_run[1]
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    args = [a if a != "200" else "300" for a in ARGS]  # --eval-episodes 300
    again = compare_rl.main([*args, "--out", str(out)])
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == stamps
    assert {r["episodes"] for r in again["rl_runs"] + again["model_based"]} == {300}
    for a, b in zip(first["rl_runs"], again["rl_runs"], strict=True):
        assert a["learning_curve"] == b["learning_curve"]


def test_a_run_without_its_policy_is_trained_again(quick_run, tmp_path):
    out = _copy(quick_run, tmp_path)
    victim = out / "runs" / "td3_reward_s0.pt"
    victim.unlink()
    stamps = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.json")}
    compare_rl.main([*ARGS, "--out", str(out)])
    assert victim.exists()
    changed = {
        p.name for p in (out / "runs").glob("*.json") if p.stat().st_mtime_ns != stamps[p.name]
    }
    assert changed == {"td3_reward_s0.json"}


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

    def mixed(runs):  # a quick run's short curves may all judge alike: force one of each
        status = real_status(runs)
        status[0]["flat"], status[1]["flat"] = True, False
        return status

    monkeypatch.setattr(Axes, "errorbar", spy)
    monkeypatch.setattr(compare_rl, "curve_status", mixed)
    summary = compare_rl.main([*ARGS, "--out", str(out)])
    flat = {(c["algo"], c["variant"]): c["flat"] for c in summary["learning_curves"]}
    assert set(flat.values()) == {True, False}
    seen = 0
    for row in summary["rl_aggregates"]:
        still = not flat[(row["algo"], row["variant"])]
        label = row["name"] + (" (still learning)" if still else "")
        marks = [mfc for lab, mfc in calls if lab == label]
        assert marks, label  # drawn in at least the full panel
        assert all((mfc == "none") == still for mfc in marks), (label, marks)
        seen += 1
    assert seen == len(flat)


class _FixedAgent:
    """Stands in for a trained SB3 model: the same action ``a`` in [-1, 1] for every state."""

    def __init__(self, a: float) -> None:
        self.a = a
        self.seen = None

    def predict(self, obs, deterministic=True):
        self.seen = np.array(obs)
        return np.full((len(obs), 1), self.a, dtype=np.float32), None


@pytest.mark.parametrize(
    ("kind", "u_bound"), [("u", None), ("u", HP.U_BOUND), ("residual", None), ("residual", 60.0)]
)
def test_adapter_matches_training_env(kind, u_bound):
    """The adapter sees what the training env shows the agent and applies the same input."""
    model = macro()
    env = make_train_env(kind, None, HP.ENV, PAPER_K, HP.RESIDUAL_NU_BOUND, u_bound)
    agent = _FixedAgent(0.3)
    bound = 200.0 if u_bound is None or kind == "residual" else u_bound
    policy = SB3Policy(agent, model, kind, bound, HP.ENV, PAPER_K, HP.RESIDUAL_NU_BOUND, 20)
    obs, info = env.reset(seed=3)
    for _ in range(5):
        x, mode, k = info["state"], info["mode"], info["k"]
        u, _ = policy.act_batch(x[None], np.array([mode]), np.array([k]))
        np.testing.assert_allclose(agent.seen[0], obs, rtol=1e-6)
        obs, _, _, _, info = env.step(np.array([agent.a], dtype=np.float32))
        np.testing.assert_allclose(info["u"], np.clip(u[0], -200, 200), rtol=1e-6, atol=1e-9)
        if kind == "u":  # a = 0.3 is u = 0.3 * bound, whatever the bound
            np.testing.assert_allclose(info["u"], [0.3 * bound], rtol=1e-6)


@pytest.mark.parametrize("bad", [0.0, -60.0, float("nan"), float("inf"), "60", True])
def test_train_env_rejects_a_bad_u_bound(bad):
    with pytest.raises(ValueError, match="u_bound"):
        make_train_env("u", None, HP.ENV, None, HP.RESIDUAL_NU_BOUND, bad)


def test_train_env_takes_a_numpy_u_bound():
    env = make_train_env("u", None, HP.ENV, None, HP.RESIDUAL_NU_BOUND, np.float32(60.0))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    np.testing.assert_allclose(info["u"], [30.0], rtol=1e-6)


def test_scaled_observation_clips_the_state_only():
    obs = np.array([[1e6, -5.0, 0.0, 1.0, 0.0, 0.5]], dtype=np.float32)
    out = scale_observation(obs, 2, 10.0, 10.0)
    np.testing.assert_allclose(out, [[10.0, -0.5, 0.0, 1.0, 0.0, 0.5]])


# ------------------------------------------------------------------ budgets and the flatness test
def test_default_budgets_per_variant():
    """The per-variant budgets override the per-algorithm ones, and only where they are listed."""
    specs = compare_rl.run_specs(compare_rl.Options())
    assert len(specs) == 3 * 6 * 3
    for s in specs:
        expected = HP.TIMESTEPS_VARIANT.get((s.algo, s.variant), HP.TIMESTEPS[s.algo])
        assert s.timesteps == expected, s.name
    assert {s.timesteps for s in specs if s.algo == "ppo" and s.variant == "residual"} == {
        HP.TIMESTEPS["ppo"]
    }
    for (algo, variant), n in HP.TIMESTEPS_VARIANT.items():
        assert algo in compare_rl.ALGOS and variant in compare_rl.VARIANTS
        assert n > HP.TIMESTEPS[algo], (algo, variant)  # an override only ever adds training
    quick = compare_rl.run_specs(compare_rl.Options(quick=True))
    assert {s.timesteps for s in quick} == {HP.QUICK_TIMESTEPS}


def test_variant_hyperparameters_change_only_their_variant(monkeypatch):
    """HYPERPARAMS_VARIANT replaces the listed entries for one (algo, variant): the agent is built
    with them, the run's fingerprint changes (so the cached run is trained again), the other
    variants and the module's dicts are untouched, and the report's budget line names the change."""
    before = copy.deepcopy(HP.HYPERPARAMS)
    base = [compare_rl.RunSpec("sac", v, 0, 1000, 1, 5, 0) for v in ("reward", "beta1000")]
    prints = [s.fingerprint() for s in base]
    monkeypatch.setattr(HP, "HYPERPARAMS_VARIANT", {("sac", "reward"): {"learning_rate": 2e-5}})
    assert HP.hyperparams("sac", "reward") == {**HP.SAC, "learning_rate": 2e-5}
    assert HP.hyperparams("sac", "beta1000") == HP.SAC
    assert HP.HYPERPARAMS == before
    assert base[0].fingerprint() != prints[0] and base[1].fingerprint() == prints[1]
    env_fn = [lambda: make_train_env("u", 0.0, HP.ENV, PAPER_K, HP.RESIDUAL_NU_BOUND, 60.0)]
    lrs = [compare_rl.build_agent(s, env_fn).learning_rate for s in base]
    assert lrs == [2e-5, HP.SAC["learning_rate"]]
    assert compare_rl._variant_changes_text({}) == ""
    text = compare_rl._variant_changes_text(
        {"sac reward": {"learning_rate": 2e-5}, "td3 beta100": {"batch_size": 64, "gamma": 0.9}}
    )
    assert text == ", except SAC reward: learning_rate 2e-05; TD3 beta100: batch_size 64, gamma 0.9"


def test_linear_learning_rate_schedule_reaches_the_agent(monkeypatch):
    """``lin_<r>`` in the tables becomes SB3's schedule: r at the start, r/4 with a quarter of the
    training left, 0 at the end and after it (never negative: that would be gradient ascent); the
    agent built from the entry uses it, and bad rates are refused with the value in the message."""
    schedule = HP.learning_rate("lin_1e-3")
    assert [schedule(p) for p in (1.0, 0.25, 0.0, -0.05)] == pytest.approx([1e-3, 2.5e-4, 0, 0])
    assert HP.learning_rate(3e-4) == 3e-4
    for bad in (
        "lin_",
        "lin_abc",
        "lin_-1e-3",
        "lin_nan",
        "cos_1e-3",
        0,
        -1e-3,
        float("inf"),
        True,
    ):
        with pytest.raises(ValueError, match="learning_rate = "):
            HP.learning_rate(bad)
    monkeypatch.setattr(
        HP, "HYPERPARAMS_VARIANT", {("sac", "reward"): {"learning_rate": "lin_2e-3"}}
    )
    spec = compare_rl.RunSpec("sac", "reward", 0, 1000, 1, 5, 0)
    env_fn = [lambda: make_train_env("u", 0.0, HP.ENV, PAPER_K, HP.RESIDUAL_NU_BOUND, 60.0)]
    agent = compare_rl.build_agent(spec, env_fn)
    assert agent.lr_schedule(1.0) == pytest.approx(2e-3)
    assert agent.lr_schedule(0.5) == pytest.approx(1e-3)
    json.dumps(spec.config())  # the entry stays text in the run's configuration
    text = compare_rl._variant_changes_text({"sac reward": {"learning_rate": "lin_2e-3"}})
    assert text == ", except SAC reward: learning_rate 2e-3 falling linearly to 0"


def test_trainings_start_longest_first(tmp_path, monkeypatch):
    """train_all starts the runs by estimated training time, longest first; results keep spec order."""
    order = []

    def fake_train(spec, path, report=None):
        order.append(spec.name)
        point = {"episode_cost_median": 1.0, "violation": 0.5, "diverged": 0}
        return {"timesteps": spec.timesteps, "train_time_s": 0.0, "learning_curve": [point]}

    monkeypatch.setattr(compare_rl, "train_run", fake_train)
    opts = compare_rl.Options(out=tmp_path, workers=1, no_progress=True)
    specs = compare_rl.run_specs(opts)
    by_name = {s.name: s for s in specs}
    results = compare_rl.train_all(opts, specs, log=lambda msg: None)
    assert sorted(order) == sorted(by_name)
    hours = [by_name[n].timesteps / HP.STEPS_PER_SECOND[by_name[n].algo] / 3600 for n in order]
    assert hours == sorted(hours, reverse=True)
    assert hours[0] > 10 * hours[-1]  # the defaults differ: the order is not the spec order
    assert [r["timesteps"] for r in results] == [s.timesteps for s in specs]


def _rhc_row(xi, v, costs, violations=None):
    """An RHC sweep point; every episode's violated share is ``v`` unless ``violations``."""
    costs = np.asarray(costs, dtype=float)
    viol = np.full(costs.size, v) if violations is None else np.asarray(violations, dtype=float)
    return {"family": "RHC individual", "xi": xi, "violation": {"freq": float(viol.mean())},
            "_episode_costs": costs, "_episode_violations": viol}  # fmt: skip


def test_paired_curve_gap_interpolates_episode_by_episode():
    rng = np.random.default_rng(5)
    noise = rng.lognormal(8.0, 0.5, 400)  # the spread every controller shares on an episode
    mb = [_rhc_row(0.5, 0.5, noise + 100), _rhc_row(0.85, 0.2, noise + 400),
          _rhc_row(0.7, 0.3, noise + 250)]  # fmt: skip
    # at v = 0.25, halfway between 0.2 (cost + 400) and 0.3 (+ 250): the curve is noise + 325
    at = np.full(400, 0.25)
    g = compare_rl.paired_curve_gap(noise + 300 + rng.normal(0, 1, 400), at, mb)
    assert g["curve_cost"] == pytest.approx(float(np.mean(noise)) + 325)
    assert g["violation"] == pytest.approx(0.25)
    assert g["ci95"][0] < -25 < g["ci95"][1] and g["ci95"][1] - g["ci95"][0] < 1.0
    # unpaired, the shared spread would swamp the 25: the paired interval is what resolves it
    assert 2 * 1.96 * np.std(noise) / np.sqrt(400) > 50
    at_point = compare_rl.paired_curve_gap(noise + 250, np.full(400, 0.3), mb)
    assert at_point["mean"] == pytest.approx(0.0, abs=1e-9)
    assert compare_rl.paired_curve_gap(noise, np.full(400, 0.6), mb) is None  # outside 0.2..0.5
    assert compare_rl.paired_curve_gap(noise, np.full(400, 0.1), mb) is None
    # the same resamples every call: the interval is reproducible
    assert compare_rl.paired_curve_gap(noise + 300, at, mb) == compare_rl.paired_curve_gap(
        noise + 300, at, mb
    )


def test_paired_curve_gap_interval_covers_the_error_of_the_violation_frequency():
    """On a steep segment of the curve, the sampling error of the agent's violation frequency
    moves the curve's cost at that frequency; the bootstrap interval must be as wide as that.
    E = 1000 episodes of 20 steps, violated share binomial(20, 0.25) / 20; 2000 resamples."""
    E = 1000
    rng = np.random.default_rng(11)
    base = np.full(E, 5000.0)  # costs without episode noise: only the frequency's error remains
    slope = -20000.0  # cost per unit of violation frequency between 0.2 and 0.3
    mb = [_rhc_row(0.85, 0.2, base), _rhc_row(0.7, 0.3, base + 0.1 * slope)]
    viol = rng.binomial(20, 0.25, E) / 20
    g = compare_rl.paired_curve_gap(base + 0.05 * slope, viol, mb)
    # the gap is the agent's cost minus the curve at the agent's own (sample) frequency
    assert g["mean"] == pytest.approx(slope * (0.25 - viol.mean()), abs=1e-6)
    expected_half = 1.96 * abs(slope) * viol.std(ddof=1) / np.sqrt(E)  # about 38
    half = (g["ci95"][1] - g["ci95"][0]) / 2
    assert 0.85 * expected_half < half < 1.15 * expected_half
    assert g["ci95"][0] < g["mean"] < g["ci95"][1]


def test_paired_curve_gap_rejects_mismatched_inputs():
    mb = [_rhc_row(0.85, 0.2, np.ones(10)), _rhc_row(0.7, 0.3, np.ones(10))]
    with pytest.raises(ValueError, match="same length"):
        compare_rl.paired_curve_gap(np.ones(10), np.ones(9), mb)
    with pytest.raises(ValueError, match="agent's 8 episodes"):
        compare_rl.paired_curve_gap(np.ones(8), np.full(8, 0.25), mb)


def test_best_agent_is_the_median_seed_of_the_cheapest_safe_configuration():
    def row(algo, variant, cost, v, div, seed=None):
        r = {"algo": algo, "variant": variant, "episode_cost": {"mean": cost},
             "violation": {"freq": v}, "diverged": div}  # fmt: skip
        return r if seed is None else r | {"seed": seed, "name": f"{algo}_{variant}_s{seed}"}

    aggs = [
        row("ppo", "residual", 4600.0, 0.22, 0),  # too many violations
        row("td3", "beta10000", 5000.0, 0.155, 0),  # the answer
        row("td3", "lagrangian", 900.0, 0.10, 4),  # cheap but diverges
        row("sac", "beta10000", 5200.0, 0.18, 0),
    ]
    runs = [row("td3", "beta10000", c, 0.155, 0, seed) for seed, c in enumerate((5200, 4700, 5100))]
    runs += [row("sac", "beta10000", 10.0, 0.18, 0, 0)]
    assert compare_rl.best_config(aggs, 0.15)["variant"] == "beta10000"
    assert compare_rl.best_agent(aggs, runs, 0.15)["name"] == "td3_beta10000_s2"  # 5100: median
    # nothing safe: fewest diverged, then fewest violations
    unsafe = [row("a", "x", 1.0, 0.9, 3), row("b", "y", 9.0, 0.95, 0), row("c", "z", 5.0, 0.5, 0)]
    assert compare_rl.best_config(unsafe, 0.15)["algo"] == "c"
    assert compare_rl.best_agent([], [], 0.15) is None


def _run(algo, variant, seed, cost, violation, diverged, episodes=100, total=1000):
    """A synthetic run record with a learning curve of ``len(cost)`` points after the first."""
    n = len(cost)
    curve = [
        {
            "timesteps": round(total * i / (n - 1)),
            "episode_cost_median": c,
            "violation": v,
            "diverged": d,
        }
        for i, (c, v, d) in enumerate(zip(cost, violation, diverged, strict=True))
    ]
    return {
        "algo": algo,
        "variant": variant,
        "seed": seed,
        "config": {"curve_episodes": episodes},
        "learning_curve": curve,
    }


def _status(runs):
    return {(s["algo"], s["variant"]): s for s in compare_rl.curve_status(runs)}


def test_curve_status_windows():
    """11 points (0%, 10%, ..., 100%): the late window is 80-100%, the earlier one 50-70%."""
    flat_cost = [9e3, 6e3, 5e3, 5e3, 5e3, 5100, 4900, 5000, 5050, 4950, 5000]
    flat_v = [0.9, 0.5, 0.3, 0.2, 0.2, 0.21, 0.19, 0.20, 0.19, 0.21, 0.20]
    # the violation frequency still falls: 0.22 in the earlier window, 0.18 in the late one
    falling_v = [0.9, 0.5, 0.3, 0.25, 0.24, 0.23, 0.22, 0.21, 0.19, 0.18, 0.17]
    # the cost still falls by about 15%
    falling_c = [9e3, 8e3, 7e3, 6e3, 6e3, 6e3, 6e3, 6e3, 5.1e3, 5.1e3, 5.1e3]
    zero = [0] * 11
    st = _status(
        [
            _run("td3", "residual", 0, flat_cost, flat_v, zero),
            _run("td3", "beta100", 0, flat_cost, falling_v, zero),
            _run("td3", "beta1000", 0, falling_c, flat_v, zero),
        ]
    )
    s = st[("td3", "residual")]
    assert s["late_window"] == [800, 1000] and s["earlier_window"] == [500, 700]
    assert s["flat"] and s["cost_rel_change"] == pytest.approx(0.0, abs=1e-12)
    assert s["violation_change"] == pytest.approx(0.0, abs=1e-12)
    assert not st[("td3", "beta100")]["flat"]
    assert st[("td3", "beta100")]["violation_change"] == pytest.approx(0.04)
    assert not st[("td3", "beta1000")]["flat"]
    assert st[("td3", "beta1000")]["cost_rel_change"] == pytest.approx(0.9e3 / 5.1e3)


def test_curve_status_averages_windows_and_seeds():
    """Noise that single points would call a change (0.17 at 70% against 0.23 at 100%) cancels
    in the window means; opposite drifts of two seeds cancel in the seed average."""
    cost = [5e3] * 11
    zero = [0] * 11
    noisy = [0.9, 0.3, 0.2, 0.2, 0.2, 0.23, 0.20, 0.17, 0.20, 0.17, 0.23]
    assert _status([_run("sac", "residual", 0, cost, noisy, zero)])[("sac", "residual")]["flat"]
    drifting = noisy[:-1] + [0.32]  # late window 0.23 against 0.20
    st = _status([_run("sac", "residual", 0, cost, drifting, zero)])
    assert not st[("sac", "residual")]["flat"]
    up = [0.9, 0.3, 0.2, 0.2, 0.2, 0.17, 0.17, 0.17, 0.23, 0.23, 0.23]
    down = [0.9, 0.3, 0.2, 0.2, 0.2, 0.23, 0.23, 0.23, 0.17, 0.17, 0.17]
    assert not _status([_run("td3", "reward", 0, cost, up, zero)])[("td3", "reward")]["flat"]
    both = _status(
        [_run("td3", "reward", 0, cost, up, zero), _run("td3", "reward", 1, cost, down, zero)]
    )
    assert both[("td3", "reward")]["flat"]


def test_curve_status_ignores_the_cost_of_diverging_episodes():
    """Where the median evaluation episode diverges, its cost is not compared, but the share of
    diverged episodes is."""
    jumping = [4e11, 2e11, 1e11, 3e11, 1e11, 4e11, 1e11, 2e11, 1e11, 3e11, 4e11]
    v = [0.9] + [0.6] * 10
    steady = [100] + [60] * 10
    falling = [100, 90, 80, 75, 70, 68, 66, 64, 58, 56, 54]
    st = _status(
        [
            _run("ppo", "beta1000", 0, jumping, v, steady),
            _run("ppo", "reward", 0, jumping, v, falling),
        ]
    )
    s = st[("ppo", "beta1000")]
    assert s["median_episode_diverges"] and s["cost_rel_change"] is None and s["flat"]
    r = st[("ppo", "reward")]
    assert r["diverged_share_change"] == pytest.approx(0.10) and not r["flat"]
    assert r["diverged_share_late"] == pytest.approx(0.56)
    # once fewer than half diverge the cost counts again: the same jumps are then a change
    half = _status([_run("ppo", "beta100", 0, jumping, v, [10] * 11)])
    assert not half[("ppo", "beta100")]["median_episode_diverges"]
    assert not half[("ppo", "beta100")]["flat"]


def test_curve_status_short_curves():
    """The quick run's curves (0 and three points): one point per window, never the untrained
    policy."""
    st = _status([_run("ppo", "residual", 0, [9e3, 5e3, 5e3, 5e3], [1, 0.2, 0.2, 0.2], [0] * 4)])
    s = st[("ppo", "residual")]
    assert s["late_window"] == [1000, 1000] and s["earlier_window"] == [667, 667]
    assert s["flat"]
    assert _status([_run("ppo", "residual", 0, [1, 2], [0, 0], [0, 0])]) == {}


# ------------------------------------------------------------------ worker processes
def _children(pid: int) -> set[int]:
    """PIDs whose parent is ``pid`` (Linux /proc)."""
    out = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = open(f"/proc/{entry}/stat").read()
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.add(int(entry))
    return out


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="uses /proc and prctl")
def test_workers_end_with_the_main_process(tmp_path):
    """SIGKILL the main process of a two-worker run while both are training: its worker processes
    (and the manager) must end within 30 s instead of training on and writing runs/*.json."""
    cmd = [
        sys.executable, "-m", "benchmarks.compare_rl", "--quick", "--algos", "ppo",
        "--variants", "reward", "residual", "--seeds", "1", "--timesteps", "10000000",
        "--workers", "2", "--no-progress", "--out", str(tmp_path),
    ]  # fmt: skip
    root = Path(compare_rl.__file__).resolve().parents[1]
    main = subprocess.Popen(cmd, cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(children) < 3:  # the manager and 2 workers
            assert main.poll() is None, "the run ended early"
            children = _children(main.pid)
            time.sleep(0.2)
        assert len(children) >= 3, f"workers did not start: {children}"
        time.sleep(5)  # let the workers import and start training
        main.kill()
        main.wait()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(_alive(p) for p in children):
            time.sleep(0.2)
        left = [p for p in children if _alive(p)]
        assert not left, f"processes {left} outlived the main process"
    finally:
        if main.poll() is None:
            main.kill()
        for p in children:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
    assert not list((tmp_path / "runs").glob("*.json"))


def _no_wall(point: dict) -> dict:
    return {k: v for k, v in point.items() if k != "wall_s"}


def test_two_workers_give_the_same_results_as_one(tmp_path):
    """The parallel path end to end: trainings in two worker processes write the same runs (and
    the same scores) as one process does; each training is seeded and uses one torch thread."""
    args = [
        "--quick", "--algos", "ppo", "td3", "--variants", "reward", "residual", "--seeds", "1",
        "--timesteps", "1050", "--eval-episodes", "50", "--no-progress",
    ]  # fmt: skip
    one = compare_rl.main([*args, "--workers", "1", "--out", str(tmp_path / "one")])
    two = compare_rl.main([*args, "--workers", "2", "--out", str(tmp_path / "two")])
    for a, b in zip(one["rl_runs"], two["rl_runs"], strict=True):
        assert a["name"] == b["name"]
        curves = [[_no_wall(p) for p in r["learning_curve"]] for r in (a, b)]
        assert curves[0] == curves[1] and len(curves[0]) == 4
        assert a["episode_cost"] == b["episode_cost"] and a["violation"] == b["violation"]


def test_reading_sorts_agents_by_their_paired_gap_to_the_curve(quick_run):
    """below / above / unresolved come from every seed's paired interval, not from the means."""
    summary = copy.deepcopy(quick_run[1])
    gaps_key = ("ppo", "reward")
    gaps = {  # per configuration: the seeds' paired 95% intervals
        gaps_key: [(-90, -10)],  # below
        ("sac", "reward"): [(5, 40)],  # above
        ("td3", "reward"): [(-30, 20)],  # not resolved
    }
    lo, hi = sorted(
        r["violation"]["freq"] for r in summary["model_based"] if r["family"] == "RHC individual"
    )[:: len(compare_rl.XI_SWEEP) - 1]
    for row in summary["rl_aggregates"] + summary["rl_runs"]:
        key = (row["algo"], row["variant"])
        row["diverged"] = 0 if key in gaps else 1
        if key in gaps:
            row["violation"]["freq"] = (lo + hi) / 2
            if row["kind"] == "rl-seed":
                (g_lo, g_hi) = gaps[key][0]
                row["curve_gap"] = {
                    "mean": (g_lo + g_hi) / 2,
                    "ci95": [g_lo, g_hi],
                    "curve_cost": row["episode_cost"]["mean"] - (g_lo + g_hi) / 2,
                }
    line = next(t for t in compare_rl.reading(summary) if t.startswith("* Against the RHC curve"))
    below = line.split("below the curve in every seed: ")[1].split("; seeds on both")[0]
    assert "PPO reward" in below and "SAC reward" not in below and "TD3 reward" not in below
    # the curve's cost it prints is the seeds' (at their own frequencies): cost minus it = gap
    ppo = next(a for a in summary["rl_aggregates"] if (a["algo"], a["variant"]) == gaps_key)
    assert f"against the curve's {ppo['episode_cost']['mean'] + 50:.4g} at the seeds'" in below
    assert "cost more than the curve in every seed (SAC reward)" in line
    assert "TD3 reward" in line.split("seeds on both sides of it or not resolved: ")[1]
    assert f"of {len(summary['rl_aggregates'])} trained configurations, " in line


def test_reading_compares_agents_outside_the_curve_with_the_right_end(quick_run):
    """An agent safer than every point of the RHC curve is compared with its safest point, one
    riskier than all of them with the linear feedback and the LQR, and one whose seeds lie on
    both sides of the curve's range is named as such (not as outside it)."""
    summary = copy.deepcopy(quick_run[1])
    curve = sorted(
        (r for r in summary["model_based"] if r["family"] == "RHC individual"),
        key=lambda r: r["violation"]["freq"],
    )
    lo, hi = curve[0]["violation"]["freq"], curve[-1]["violation"]["freq"]
    where = {("ppo", "reward"): lo / 2, ("sac", "reward"): (1 + hi) / 2}
    for row in summary["rl_aggregates"] + summary["rl_runs"]:
        key = (row["algo"], row["variant"])
        row["diverged"] = 0 if key in where else 1
        if key in where:
            row["violation"]["freq"] = where[key]
            row["curve_gap"] = None
    line = next(t for t in compare_rl.reading(summary) if t.startswith("* Against the RHC curve"))
    safer = line.split("safer than every point of the curve (")[1].split("; riskier")[0]
    assert f"its safest point, {curve[0]['name']}" in safer and "PPO reward" in safer
    riskier = line.split("riskier than every point of the curve (")[1]
    assert "the linear feedback and the LQR" in riskier and "SAC reward" in riskier
    assert "PPO reward" not in riskier
    # two seeds, one on each side of the range: neither safer nor riskier
    runs = [r for r in summary["rl_runs"] if (r["algo"], r["variant"]) == ("ppo", "reward")]
    twin = copy.deepcopy(runs[0]) | {"seed": 1}
    twin["violation"] = {**twin["violation"], "freq": (1 + hi) / 2}
    summary["rl_runs"].append(twin)
    line = next(t for t in compare_rl.reading(summary) if t.startswith("* Against the RHC curve"))
    assert "PPO reward" in line.split("some seeds inside the curve's range and some outside")[1]
    assert "safer than every point" not in line


def test_curve_status_median_divergence_is_judged_per_seed():
    """Seeds whose diverged shares are 0.8, 0.6 and 0 average below one half, yet two of the
    three medians averaged are divergence magnitudes: the cost is not compared then."""
    cost = [4e11] + [3e11, 1e11] * 5
    v = [0.9] + [0.5] * 10
    runs = [
        _run("ppo", "beta100", 0, cost, v, [80] * 11),
        _run("ppo", "beta100", 1, cost, v, [60] * 11),
        _run("ppo", "beta100", 2, [500.0] * 11, v, [0] * 11),
    ]
    s = _status(runs)[("ppo", "beta100")]
    assert s["diverged_share_late"] == pytest.approx(140 / 300)  # the mean is below one half
    assert s["median_episode_diverges"] and s["cost_rel_change"] is None


def test_eval_episodes_must_allow_an_interval(capsys):
    with pytest.raises(SystemExit):
        compare_rl.parse_args(["--eval-episodes", "1"])
    assert "--eval-episodes = 1; expected an integer >= 2" in capsys.readouterr().err


def _row(name: str, diverged: int, wilson: tuple, episode: tuple | None) -> dict:
    v = {"freq": (wilson[0] + wilson[1]) / 2, "wilson95": list(wilson)}
    if episode is not None:
        v["episode_t95"] = list(episode)
    return {"name": name, "diverged": diverged, "violation": v}


def test_interval_check_takes_the_widest_ratio_in_each_part():
    rows = [
        _row("a", 0, (0.10, 0.12), (0.10, 0.122)),  # 1.1
        _row("b", 0, (0.20, 0.22), (0.195, 0.225)),  # 1.5
        _row("c", 3, (0.50, 0.52), (0.45, 0.57)),  # 6
        _row("agg", 0, (0.0, 1.0), None),  # an aggregate: no interval over episodes, skipped
        _row("flat", 0, (1.0, 1.0), (1.0, 1.0)),  # zero Wilson width: no ratio
    ]
    check = compare_rl.interval_check(rows)
    assert check["stable"]["rows"] == 2 and check["stable"]["name"] == "b"
    assert check["stable"]["max_ratio"] == pytest.approx(1.5)
    assert check["diverging"] == {"rows": 1, "max_ratio": pytest.approx(6.0), "name": "c"}
    assert compare_rl.interval_check(rows[:2])["diverging"] is None
    assert compare_rl.interval_check(rows[3:]) is None
    text = compare_rl._interval_check_text(check)
    assert "at most 1.50 times" in text and "up to 6.0 times (c, over 1 such rows)" in text
    assert compare_rl._interval_check_text(None) == ""


def test_quick_run_reports_the_interval_over_episodes(quick_run):
    out, summary = quick_run
    for r in summary["model_based"] + summary["rl_runs"]:
        v = r["violation"]
        assert 0.0 <= v["episode_t95"][0] <= v["freq"] <= v["episode_t95"][1] <= 1.0, r["name"]
    assert summary["violation_interval_check"]["stable"]["rows"] >= 1
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        if r["kind"] == "rl-aggregate":
            assert r["violation_episode_lo"] == r["violation_episode_hi"] == ""
        else:
            lo, hi = float(r["violation_episode_lo"]), float(r["violation_episode_hi"])
            assert lo <= float(r["violation"]) <= hi, r["name"]
    assert (
        "Checked against a Student-t interval over the episodes" in (out / "REPORT.md").read_text()
    )


def test_reading_prices_every_algorithm_without_a_reward_variant(quick_run):
    """The decision times come from every variant trained, not only from ``reward``."""
    summary = copy.deepcopy(quick_run[1])
    summary["rl_aggregates"] = [a for a in summary["rl_aggregates"] if a["variant"] != "reward"]
    summary["rl_runs"] = [r for r in summary["rl_runs"] if r["variant"] != "reward"]
    summary["learning_curves"] = [s for s in summary["learning_curves"] if s["variant"] != "reward"]
    line = next(t for t in compare_rl.reading(summary) if t.startswith("* Price"))
    decides = line.split("one state at a time, in ")[1]
    for algo in ("PPO", "SAC", "TD3"):
        times = [
            a["decision_time_s"]["single"]
            for a in summary["rl_aggregates"]
            if a["algo"] == algo.lower()
        ]
        assert f"{algo} {compare_rl._fmt_time(min(times))}" in decides


def test_training_time_counts_the_evaluations_made_during_training(quick_run):
    """``eval_time_s`` is what the learning curve (and the dual ascent) cost inside
    ``agent.learn``; it used to be lost (read from a copy of the callbacks' log, always 0)."""
    _, summary = quick_run
    for r in summary["rl_runs"]:
        assert 0.0 < r["eval_time_s"] < r["train_time_s"] == r["wall_time_s"], r["name"]
        assert r["cpu_time_s"] > 0.0, r["name"]


def test_reading_names_the_trainings_that_shared_a_core():
    """Wall time over CPU time above SHARED_CPU_RATIO is named; old records (no CPU time) and
    trainings that had their core are not."""
    runs = [
        {"name": "a", "train_time_s": 150.0, "cpu_time_s": 100.0},
        {"name": "b", "train_time_s": 110.0, "cpu_time_s": 100.0},
        {"name": "c", "train_time_s": 500.0},
    ]
    text = compare_rl._shared_cpu_text(runs)
    assert "a 150 s for 100 s of CPU" in text
    assert "b 110" not in text and "c 500" not in text
    assert compare_rl._shared_cpu_text(runs[1:]) == ""


def test_quick_run_marks_the_rhc_points_whose_tightened_band_is_empty(quick_run):
    """The band is 3 wide with unit-variance rows: empty for individual xi > Phi(1.5) and joint
    xi > 1 - exp(-2.25 / 2) (see tests/test_chance.py); those points score the same."""
    from scipy import stats

    summary = copy.deepcopy(quick_run[1])
    edge = {"individual": stats.norm.cdf(1.5), "joint": 1.0 - math.exp(-2.25 / 2.0)}
    rows = [r for r in summary["model_based"] if "constraint" in r]
    assert len(rows) == 2 * len(compare_rl.XI_SWEEP)
    for r in rows:
        assert r["tightened_band_empty"] == float(r["xi"] > edge[r["constraint"]]), r["name"]
    empty = [r for r in rows if r["tightened_band_empty"] == 1.0]
    assert {r["name"] for r in empty} == {
        "RHC individual xi=0.95",
        "RHC individual xi=0.99",
        *(f"RHC joint xi={xi:g}" for xi in compare_rl.XI_SWEEP if xi >= 0.7),
    }
    lines = [t for t in compare_rl.reading(summary) if "tightened band is empty" in t]
    assert len(lines) == 1
    assert "individual xi = 0.95, 0.99; joint xi = 0.7, 0.8, 0.85, 0.9, 0.95, 0.99" in lines[0]
    assert f"Those {len(empty)} controllers score the same" in lines[0]
    assert "joint-constraint controller at xi = 0.85 is one of them" in lines[0]

    # the wording follows the numbers: different scores are listed, partial emptiness is named
    empty[0]["episode_cost"]["mean"] += 1.0
    summary["model_based"][0]["tightened_band_empty"] = 0.25
    text = "\n".join(compare_rl._empty_band_lines(summary["model_based"]))
    assert "score the same" not in text and "Their scores (cost / violations): " in text
    assert f"{summary['model_based'][0]['name']} (25% of the steps and modes)" in text
    for r in rows:
        r["tightened_band_empty"] = 0.0
    assert compare_rl._empty_band_lines(summary["model_based"]) == []
