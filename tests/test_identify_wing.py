"""The identify wing (issue 49): the learner, the step grid, the within-5% rule, the agents'
curves, the command end to end and its cache."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import raises_naming

import benchmarks.identify.run as run_module
from benchmarks.core.evaluate import evaluate
from benchmarks.identify import EXPLORATION, across_seeds, learn, main, step_grid, steps_within
from benchmarks.identify.agents import read_agents
from benchmarks.identify.cli import SEEDS
from benchmarks.identify.learner import (
    EXPLORATION_SEED_OFFSET,
    designer_template,
    explore,
    identification_errors,
    min_episodes,
)
from benchmarks.identify.steps import agent_budgets
from benchmarks.identify.summary import order_stats
from controllers import (
    InsufficientDataError,
    LMIInfeasibleError,
    RecedingHorizonController,
    identify,
)
from sdjls_gym.systems import TASKS


# ----------------------------------------------------------------------------- the learner
def test_the_learner_recovers_the_true_model_controller_at_a_large_budget():
    """Degradation, 30000 steps (1000 episodes), exploration seed 0, scored on 200 episodes of
    evaluation seed 0: the gap is -0.03% (95% interval -0.24 to +0.14). Over exploration seeds
    0-4 the gaps were -0.03 to -0.09% and the [A B] errors 0.003 to 0.007: a margin of 10."""
    controller, info = learn("SDJLS-Degradation-v0", 30000, 0)
    assert (info.episodes, info.steps, info.fallback) == (1000, 30000, "none")
    assert info.errors["AB"] <= 0.05 and info.errors["P"] <= 0.1 and info.prior_rows == 0
    assert info.K_source.startswith("Proposition 2")
    assert info.Psi_source.startswith("MJLS LQ value matrices")
    score = evaluate(controller, episodes=200, seed=0, env_id="SDJLS-Degradation-v0")
    assert score.curve_gap is not None and abs(score.curve_gap.relative) <= 1.0


def test_a_budget_is_a_prefix_of_the_seeds_exploration():
    task = TASKS["SDJLS-Solar-v0"]
    data = explore(task, 20, seed=3)
    assert data.x.shape == (20, task.horizon + 1, 1) and np.all(data.length == task.horizon)
    again = explore(task, 20, seed=3)
    np.testing.assert_array_equal(data.x, again.x)
    _, five = learn(task, 5 * task.horizon + 7, 3, exploration=data)  # 5 whole episodes
    estimate = identify(data.trajectories(5), designer_template(task.model))
    assert five.episodes == 5 and five.errors == identification_errors(estimate, task.model)
    other = explore(task, 20, seed=4)
    assert not np.array_equal(other.x, data.x)


def test_the_exploration_noise_is_not_the_evaluations():
    """The exploration's environment seed is offset from the evaluation seeds (0, 1, 2)."""
    assert EXPLORATION_SEED_OFFSET > 2 and set(EXPLORATION) == set(TASKS)


def test_too_small_a_budget_is_refused():
    task = TASKS["SDJLS-VTOL-v0"]
    assert min_episodes(task) == 1  # N (n + m + 1) = 21 steps of 60
    with raises_naming(ValueError, "steps", 59):
        learn(task, 59, 0)
    with raises_naming(ValueError, "exploration", 2):
        learn(task, 3 * task.horizon, 0, exploration=explore(task, 2, 0))


def test_a_mode_not_seen_is_insufficient_data():
    """Macro, one episode of exploration seed 1: the boom mode is the mode of 2 steps."""
    with pytest.raises(InsufficientDataError, match="mode 1"):
        learn("SDJLS-Macro-v0", 20, 1)


def test_where_proposition_2_fails_the_task_gains_take_over(monkeypatch):
    original = RecedingHorizonController.from_model.__func__

    def infeasible_without_k(cls, model, **kw):
        if kw.get("K") is None:
            raise LMIInfeasibleError("Proposition 2 infeasible (forced by the test)")
        return original(cls, model, **kw)

    monkeypatch.setattr(RecedingHorizonController, "from_model",
                        classmethod(infeasible_without_k))  # fmt: skip
    controller, info = learn("SDJLS-Solar-v0", 500, 0)
    assert info.fallback == "task_K" and info.K_source == "given"
    np.testing.assert_array_equal(controller.K, TASKS["SDJLS-Solar-v0"].K)


# ----------------------------------------------------------------------------- the grid, the rule
def test_the_grid_covers_the_agents_budgets_in_whole_episodes():
    task = TASKS["SDJLS-Solar-v0"]  # T = 50
    grid = step_grid(task, [40_000, 600_000])
    assert all(s % 50 == 0 for s in grid) and list(grid) == sorted(set(grid))
    assert grid[0] == 50 and grid[-1] == 600_000
    for budget in (40_000, 600_000):
        assert {j * budget // 10 for j in range(1, 11)} <= set(grid)
    assert {100, 250, 500, 5000, 500_000} <= set(grid)  # the 1-2-5 sequence of episodes
    vtol = step_grid(TASKS["SDJLS-VTOL-v0"], [80_000])  # T = 60: 8000 / 60 is 133.3 episodes
    assert 133 * 60 in vtol and vtol[-1] == 1333 * 60


def test_the_grid_reaches_every_agent_budget_of_the_suite():
    budgets = agent_budgets("SDJLS-VTOL-v0")
    assert len(budgets) == 5 and max(budgets.values()) == 2_400_000
    assert step_grid("SDJLS-VTOL-v0", budgets.values())[-1] == 2_400_000


@pytest.mark.parametrize(
    ("gaps", "kept", "first"),
    [
        ([12.0, 3.0, 7.0, 1.0], 1000, 200),  # within, out again, within
        ([12.0, 3.0, -40.0, 5.0], 200, 200),  # cheaper is within; +5.0 exactly is within
        ([1.0, None, 2.0, 3.0], 500, 100),  # no gap is not within
        ([1.0, 2.0, 3.0, 6.0], None, 100),  # out at the last budget: never kept
        ([None, None, None, None], None, None),
        ([float("inf"), 1.0, 1.0, 1.0], 200, 200),
    ],
)
def test_the_within_rules_on_hand_made_curves(gaps, kept, first):
    steps = [100, 200, 500, 1000]
    assert steps_within(steps, gaps) == kept
    assert steps_within(steps, gaps, rule="first") == first


def test_the_median_over_seeds_counts_a_seed_never_within_as_never():
    assert across_seeds([200, 100, None, 1000, 500])["median"] == 500
    assert across_seeds([200, None, None, 1000, 500])["median"] == 1000
    assert across_seeds([200, None, None, None, 500]) == {
        "median": None, "low": 200, "high": 500, "within": 2, "seeds": 5,
    }  # fmt: skip
    assert order_stats([3.0, None, -1.0, 2.0, 10.0]) == {"median": 3.0, "q25": 2.0, "q75": 10.0}
    assert order_stats([3.0, None, None, 2.0, None])["median"] is None


def test_bad_rule_and_lengths_are_refused():
    with raises_naming(ValueError, "rule", "best"):
        steps_within([1], [1.0], rule="best")
    with pytest.raises(ValueError, match="steps has 2 points"):
        steps_within([1, 2], [1.0])


# ----------------------------------------------------------------------------- the agents
def _agents_file(tmp_path, gaps):
    run = {"algo": "sac", "variant": "lagrangian", "seed": 0,
           "learning_curve": [{"timesteps": s} for s in (0, 4000, 8000)],
           "learning_curve_gaps": gaps, "score": {"curve_gap": {"relative": -3.0}},
           "curve_gap_reason": None}  # fmt: skip
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"tasks": {"SDJLS-Solar-v0": {"rl_runs": [run]}}}))
    return path


def test_the_agents_curves_are_read_from_the_suite_summary(tmp_path):
    curves = read_agents(_agents_file(tmp_path, [None, 8.0, 2.0]))
    (c,) = curves["SDJLS-Solar-v0"]
    assert (c.config, c.seed, c.steps, c.gaps, c.final_gap) == (
        "sac_lagrangian", 0, (0, 4000, 8000), (None, 8.0, 2.0), -3.0,
    )  # fmt: skip
    assert read_agents(tmp_path / "missing.json") == {}
    (tmp_path / "bad.json").write_text('{"tasks": {"x": {}}}')
    with pytest.raises(ValueError, match="bad.json"):
        read_agents(tmp_path / "bad.json")


def test_the_committed_agents_have_the_suites_seeds():
    from benchmarks.rl import SUITE_SEEDS

    assert SEEDS == SUITE_SEEDS
    curves = read_agents()
    if not curves:
        pytest.skip("results/rl_suite/summary.json is not here")
    for env_id, runs in curves.items():
        grid = set(step_grid(env_id, agent_budgets(env_id).values()))
        T = TASKS[env_id].horizon
        assert {s // T * T for r in runs for s in r.steps if s} <= grid, env_id


# ----------------------------------------------------------------------------- the command
def test_the_quick_command_end_to_end_and_its_cache(tmp_path, monkeypatch):
    out = tmp_path / "quick"
    summary = main(["--quick", "--out", str(out), "--agents", str(_agents_file(tmp_path, [
        None, 8.0, 2.0]))])  # fmt: skip
    for name in ("summary.json", "summary.csv", "REPORT.md", "fig_learning_curves.png",
                 "fig_identification_errors.png"):  # fmt: skip
        assert (out / name).is_file(), name
    data = json.loads((out / "summary.json").read_text())
    assert [t["env_id"] for t in data["tasks"]] == ["SDJLS-Solar-v0", "SDJLS-Degradation-v0"]
    solar = data["tasks"][0]
    assert solar["grid"] == [100, 500] and solar["seeds"] == [0]
    assert [c["with_gap"] for c in solar["learner"]["curve"]] == [1, 1]
    assert solar["agents"]["sac_lagrangian"]["within"]["kept"]["median"] == 8000
    assert solar["agents"]["sac_lagrangian"]["within"]["first"]["median"] == 8000
    assert len((out / "summary.csv").read_text().splitlines()) == 1 + 2 * 3
    assert "| `SDJLS-Solar-v0` |" in (out / "REPORT.md").read_text()
    assert len(list((out / "points").rglob("*.json"))) == 6 == summary["points"]

    def refuse(*args, **kwargs):
        raise AssertionError("a cached point was computed again")

    monkeypatch.setattr(run_module, "compute_point", refuse)
    again = main(["--quick", "--out", str(out), "--agents", str(tmp_path / "summary.json")])
    assert again["tasks"] == summary["tasks"]


def test_a_point_of_another_configuration_is_not_reused(monkeypatch, tmp_path):
    task = TASKS["SDJLS-Solar-v0"]
    plan = run_module.Plan(task, (0,), (100, 500), 20)
    before = run_module.fingerprint(plan, 0, 100)
    assert run_module.fingerprint(run_module.Plan(task, (0,), (100, 500), 30), 0, 100) != before
    assert run_module.fingerprint(run_module.Plan(task, (0,), (100, 1000), 20), 0, 100) != before
    assert run_module.eval_seed() == run_module.EVAL_SEEDS == (0, 1, 2)
    monkeypatch.setattr(run_module, "EVAL_SEEDS", (0,))  # other evaluation seeds: scored again
    assert run_module.fingerprint(plan, 0, 100) != before
    assert run_module.eval_seed() == 0


@pytest.mark.parametrize(
    ("argv", "option", "value"),
    [
        (["--episodes", "1"], "--episodes", "1"),
        (["--seeds", "0"], "--seeds", "0"),
        (["--tasks", "CartPole-v1"], "--tasks", "CartPole-v1"),
        (["--agents", "/nonexistent/summary.json"], "--agents", "/nonexistent/summary.json"),
        (["--quick", "--out", "results/identify"], "--out", "results/identify"),
        (["--seeds", "two"], "--seeds", "two"),
    ],
)
def test_bad_options_are_parser_errors_naming_the_option(argv, option, value, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert option in err and value in err, err
