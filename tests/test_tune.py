"""``python -m benchmarks.tune``: an Optuna study that resumes from its SQLite storage, the search
space written once, the objective on the learning curve, and the Ray Tune path (issue 31)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")
optuna = pytest.importorskip("optuna")

from benchmarks.rl import hyperparams as HP  # noqa: E402
from benchmarks.rl import train as rl_train  # noqa: E402
from benchmarks.rl import tune  # noqa: E402
from benchmarks.rl.train import CurvePoint  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _trials(out: Path, name: str) -> list[dict]:
    return json.loads((out / f"{name}.json").read_text())["trials"]


def test_quick_study_resumes_with_the_next_trial_numbers(tmp_path):
    """A study stopped after 2 trials resumes from its SQLite file: the second invocation
    (--quick: 3 trials in all) runs trial 2 only and leaves trials 0 and 1 as they were; a
    third runs nothing."""
    args = ["--quick", "--out", str(tmp_path), "--no-progress"]
    first = tune.main([*args, "--trials", "2"])
    assert [t["number"] for t in first["trials"]] == [0, 1]
    assert (tmp_path / "studies.db").is_file()
    second = tune.main(args)
    assert [t["number"] for t in second["trials"]] == [0, 1, 2]
    assert second["trials"][:2] == first["trials"]
    assert second["trials"][2]["state"] in ("COMPLETE", "PRUNED")
    assert second["trials"][2]["params"] != first["trials"][1]["params"]  # a new draw
    third = tune.main(args)
    assert third["trials"] == second["trials"]
    # each finished trial's spending: its wall time from Optuna's stamps, its CPU time recorded
    for t in second["trials"]:
        assert t["wall_s"] > 0 and t["cpu_s"] > 0
        if t["state"] == "COMPLETE":  # --quick: 500 steps x 1 seed
            assert t["env_steps"] == 500
        else:  # pruned: where its learning curve stopped
            assert t["env_steps"] == max(int(k) for k in t["intermediate"])
    # every finished trial kept its run, named by its configuration (the trial's overrides)
    runs = [name for t in second["trials"] for name in t["runs"]]
    assert len(set(runs)) == len(runs) >= 2
    for name in runs:
        record = json.loads((tmp_path / "runs" / "SDJLS-Macro-v0" / name).read_text())
        assert record["seed"] >= tune.TUNE_SEED0 and "overrides" in record["config"]
    assert second["best"]["number"] in (0, 1, 2)


def test_quick_writes_outside_the_repository_and_a_changed_study_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "temp"))  # the quick folder made here
    (tmp_path / "temp").mkdir()
    opts = tune.parse_args(["--quick"])
    assert ROOT not in opts.out.parents and opts.storage.startswith("sqlite:///")
    assert opts.out.parent == tmp_path / "temp" and opts.out.name.startswith("sdjls-gym-tune-")
    assert (opts.trials, opts.timesteps) == (3, 500)
    args = [
        "--quick",
        "--trials",
        "1",
        "--out",
        str(tmp_path),
        "--study-name",
        "s",
        "--no-progress",
    ]
    tune.main(args)
    with pytest.raises(ValueError, match="study 's'"):
        tune.main([*args, "--timesteps", "600"])


def test_bad_options_are_parser_errors(capsys):
    for argv, text in ((["--trials", "0"], "--trials = 0"),
                       (["--task", "SDJLS-Moon-v0"], "SDJLS-Moon-v0"),
                       (["--address", "auto"], "--address = 'auto' needs --backend ray"),
                       (["--storage", "studies.db"], "--storage = 'studies.db'")):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            tune.parse_args(argv)
        assert exc.value.code == 2 and text in capsys.readouterr().err


@pytest.mark.parametrize("algo", ["ppo", "sac", "td3"])
def test_search_space_holds_the_defaults_and_reaches_the_agent(algo, capsys):
    """Every default of rl_hyperparams lies in its range; a drawn configuration reaches the
    built agent (network, learning rate, batch) and the Lagrangian's dual step."""
    tune.main(["--algo", algo, "--variant", "lagrangian", "--print-space"])
    printed = capsys.readouterr().out.splitlines()
    assert printed == tune.describe_space(algo, "lagrangian")
    assert any(line.startswith("lr_dual_factor") for line in printed)
    defaults = HP.hyperparams(algo, "lagrangian")
    defaults.update(defaults.pop("policy_kwargs"))
    sb3_defaults = {"target_policy_noise": 0.2}  # SB3's, which the comparison keeps
    for name, p in tune.SEARCH_SPACE[algo].items():
        value = defaults[name] if name in defaults else sb3_defaults[name]
        if name == "net_arch":
            value = next(k for k, v in tune.NET_ARCHS.items() if v == value)
        if p.kind == "cat":
            assert value in p.choices, name
        else:
            assert p.low <= value <= p.high, name
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
    params = tune.suggest(study.ask(), algo, "lagrangian")
    spec = rl_train.RunSpec(algo, "lagrangian", 100, 1000, 1, 5, 1, "SDJLS-Solar-v0",
                            tune.overrides(params, "SDJLS-Solar-v0"))  # fmt: skip
    agent = rl_train.build_agent(spec, [lambda: rl_train._train_env(spec)])
    assert agent.learning_rate == pytest.approx(params["learning_rate"])
    assert agent.batch_size == params["batch_size"]
    assert agent.policy_kwargs["net_arch"] == tune.NET_ARCHS[params["net_arch"]]
    default_dual = rl_train.RunSpec(algo, "lagrangian", 0, 1000, 1, 5, 1, "SDJLS-Solar-v0")
    assert spec.lagrangian()["lr_dual"] == pytest.approx(
        params["lr_dual_factor"] * default_dual.lagrangian()["lr_dual"]
    )
    assert spec.fingerprint() != default_dual.fingerprint()


def test_point_objective_orders_comparable_risky_and_diverging_points():
    """On a curve of two points (frequency 0.1 at cost 100, 0.3 at cost 50; the RHC's cost 80 at
    the task's xi): a point at 0.2 costing 70 is 5 / 80 below the curve; one riskier than the
    curve scores above 1, one with diverged episodes above 2."""
    import numpy as np

    curve = (np.array([0.1, 0.3]), np.array([100.0, 50.0]), 80.0)

    def point(cost, v, diverged=0):
        return CurvePoint(1000, 0.0, cost, cost, v, diverged, None)

    assert tune.point_objective(point(70.0, 0.2), 100, curve) == pytest.approx(-5 / 80)
    assert tune.point_objective(point(90.0, 0.05), 100, curve) == pytest.approx(-10 / 80)
    assert tune.point_objective(point(1e9, 0.2), 100, curve) == 0.99
    risky = tune.point_objective(point(10.0, 0.5), 100, curve)
    assert risky == pytest.approx(1.2)
    assert tune.point_objective(point(10.0, 0.5, diverged=3), 100, curve) == pytest.approx(2.03)
    late = [point(0.0, 0.9, 100)] * 7 + [point(70.0, 0.2)] * 3
    late = [CurvePoint(100 * i, 0.0, p.episode_cost_mean, 0.0, p.violation, p.diverged, None)
            for i, p in enumerate(late)]  # fmt: skip
    assert tune.late_value(late, 100, curve) == pytest.approx(-5 / 80)  # points after 70% only


def test_reference_curve_is_the_tasks_rhc():
    viols, costs, ref = tune.reference_curve("SDJLS-Degradation-v0", 20, 12345)
    assert list(viols) == sorted(viols) and len(costs) == len(viols) >= 8
    assert ref in costs and all(c > 0 for c in costs)


@pytest.mark.slow  # a local Ray instance and two quick trials (about 70 s)
def test_ray_backend_runs_two_quick_trials_into_the_study(tmp_path):
    pytest.importorskip("ray.tune")
    pytest.importorskip("ray.tune.search.optuna")
    common = ["--quick", "--algo", "td3", "--variant", "lagrangian", "--out", str(tmp_path),
              "--no-progress"]  # fmt: skip
    summary = tune.main([*common, "--trials", "2", "--backend", "ray", "--workers", "2"])
    assert sorted(t["number"] for t in summary["trials"]) == [0, 1]
    assert all(t["state"] == "COMPLETE" and t["value"] is not None for t in summary["trials"])
    assert set(summary["trials"][0]["params"]) == set(tune.space("td3", "lagrangian"))
    # the same study resumes in this process with Optuna
    again = tune.main([*common, "--trials", "3"])
    assert sorted(t["number"] for t in again["trials"]) == [0, 1, 2]
