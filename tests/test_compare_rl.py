"""``python -m benchmarks.compare_rl --quick`` end to end, and the policy adapter it scores agents with.

The end-to-end test trains every algorithm in every kind of variant (reward alone, a fixed
penalty, residual, Lagrangian) for about a thousand steps and checks the files, the JSON schema,
that every number is finite and that the paper's controller is in the table. It takes about
30 s on one core, so it runs with the rest of the suite.
"""

from __future__ import annotations

import csv
import json
import math

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
        else:
            assert not r["dual_ascent"]

    aggs = summary["rl_aggregates"]
    assert len(aggs) == 12
    for a in aggs:
        _check_row(a)
    assert summary["best_agent"] in {r["name"] for r in runs}
    assert {s["algo"] for s in summary["learning_curves"]} == {"ppo", "sac", "td3"}
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
