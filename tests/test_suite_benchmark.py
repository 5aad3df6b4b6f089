"""The suite scored as one benchmark (issue 30, "Scored as one benchmark"): the reference curve
of every task, ``evaluate_suite``, rliable's aggregate, the command line.

Episodes are few (20 to 40) and every run is seeded; the assertions are exact relations that
common random numbers make hold on any number of episodes (a point of the curve has a zero gap;
a callable acting as a controller scores as that controller), not statistical claims.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from benchmarks.core.aggregate import PROFILE_TAUS, aggregate_gaps
from benchmarks.core.frontier import reference_curve
from benchmarks.core.montecarlo import rollout
from benchmarks.core.reference import REFERENCE_XIS, SUITE_XIS, curve_xis, one_step_rhc, paper_rhc
from benchmarks.evaluate import evaluate
from benchmarks.suite import check_tasks, evaluate_suite, main, parse_args
from controllers import LinearFeedbackController, MJLSLQRController
from sdjls_gym.systems import TASKS, random_task
from sdjls_gym.systems.macro import HORIZON, macro

TWO = ("SDJLS-Solar-v0", "SDJLS-Degradation-v0")
E = 30
RESAMPLES = 100  # rliable's bootstrap is slow (a Mann-Whitney test per task and resample)


# --------------------------------------------------------------------------- reference curve
def test_macro_reference_curve_is_the_papers_curve_evaluate_used():
    """The curve evaluate drew on the macro task before the suite (the paper's controller at
    REFERENCE_XIS, individual constraints), computed here from paper_rhc, episode by episode."""
    task = TASKS["SDJLS-Macro-v0"]
    assert curve_xis(task) == REFERENCE_XIS == (0.3, 0.5, 0.7, 0.8, 0.85, 0.9, 0.95, 0.99)
    curve = reference_curve(task, E, 4, action_bound=200.0)
    assert set(REFERENCE_XIS) <= set(curve.xis)  # the base grid adds levels where it bends
    for xi in REFERENCE_XIS:
        i = curve.xis.index(xi)
        ro = rollout(macro(), paper_rhc(macro(), xi, "individual"), E, HORIZON, 4, 200.0)
        np.testing.assert_array_equal(curve.costs[i], ro.episode_cost)
        np.testing.assert_array_equal(curve.violations[i], ro.any_violation.mean(axis=1))
    # and evaluate's gap on the macro task is against it: its own point has a zero gap
    score = evaluate(paper_rhc(macro(), 0.8), episodes=E, seed=4)
    assert score.curve_gap.mean == pytest.approx(0.0, abs=1e-9 * score.cost_mean)
    assert score.curve_gap.xi == pytest.approx(0.8)


def test_every_task_has_a_reference_curve_in_evaluate():
    """Before the suite, evaluate gave a gap on the paper's system only."""
    task = TASKS["SDJLS-Degradation-v0"]
    assert curve_xis(task) == SUITE_XIS
    score = evaluate(one_step_rhc(task, 0.7), episodes=E, seed=2, env_id=task.env_id)
    g = score.curve_gap
    assert g is not None and g.xi == pytest.approx(0.7)
    assert g.mean == pytest.approx(0.0, abs=1e-9 * score.cost_mean)
    assert (
        g.relative == pytest.approx(0.0, abs=1e-9) and g.relative_ci95[0] <= 0 <= g.relative_ci95[1]
    )
    # relative is the gap in % of the curve's cost
    lf = evaluate(LinearFeedbackController(task.model, task.K), episodes=E, seed=2,
                  env_id=task.env_id)  # fmt: skip
    g = lf.curve_gap
    assert g.relative == pytest.approx(100 * g.mean / g.curve_cost)
    assert g.relative_ci95 == pytest.approx(tuple(100 * c / g.curve_cost for c in g.ci95))


# --------------------------------------------------------------------------- evaluate_suite
def _feedback_callable(task):
    """u = K_mode x from the raw observation [x, one-hot mode, k / T]: a plain callable."""
    n, N = task.n, task.N

    def act(obs):
        obs = np.atleast_2d(obs)
        x, mode = obs[:, :n], obs[:, n : n + N].argmax(axis=1)
        return np.einsum("bmn,bn->bm", task.K[mode], x)

    return act


def test_evaluate_suite_on_two_controllers_and_a_callable():
    rhc = evaluate_suite(lambda t: one_step_rhc(t, t.rhc["xi"]), TWO, episodes=E, seed=1,
                         resamples=RESAMPLES)  # fmt: skip
    assert rhc.tasks == TWO and rhc.runs == 1 and rhc.missing == ()
    # the reference controller itself lies on its curve: zero gaps, IQM 0, ties with the curve
    np.testing.assert_allclose(rhc.gap_table, 0.0, atol=1e-8)
    assert rhc.aggregate.iqm_gap == pytest.approx(0.0, abs=1e-8)
    assert rhc.aggregate.probability_of_improvement == pytest.approx(0.5)
    for r in rhc.results:
        assert r.gaps[0].xi == pytest.approx(TASKS[r.env_id].rhc["xi"])

    feedback = evaluate_suite(lambda t: LinearFeedbackController(t.model, t.K), TWO, episodes=E,
                              seed=1, resamples=RESAMPLES)  # fmt: skip
    by_hand = evaluate_suite(_feedback_callable, TWO, episodes=E, seed=1, resamples=RESAMPLES)
    for a, b in zip(feedback.results, by_hand.results, strict=True):
        assert a.scores[0].cost_mean == pytest.approx(b.scores[0].cost_mean, rel=1e-6)
        assert a.scores[0].violation == b.scores[0].violation
    gaps = [r.gaps[0].relative for r in feedback.results]
    # two tasks: the IQM trims nothing (int(0.25 * 2) = 0), it is the mean
    assert feedback.aggregate.iqm_gap == pytest.approx(np.mean(gaps))
    assert by_hand.aggregate.iqm_gap == pytest.approx(feedback.aggregate.iqm_gap, rel=1e-5)
    # the gap is evaluate's, in % of the curve's cost
    for r in feedback.results:
        assert r.gaps[0] == r.scores[0].curve_gap


@pytest.mark.slow
def test_evaluate_suite_with_runs_and_a_task_record():
    """Three runs per task (rliable resamples them) and a task given as a record (a random
    system other than the registered one); the fast variant is the test above."""
    task = random_task(n=2, m=1, N=2, r=2, seed=5)
    suite = evaluate_suite(
        lambda t: [one_step_rhc(t, 0.5, "joint"), one_step_rhc(t, 0.9, "joint"),
                   LinearFeedbackController(t.model, t.K)],
        (task, "SDJLS-Degradation-v0"), episodes=20, resamples=RESAMPLES,
    )  # fmt: skip
    assert suite.runs == 3 and suite.tasks == ("SDJLS-Random-v0", "SDJLS-Degradation-v0")
    assert suite.missing == () and suite.gap_table.shape == (3, 2)
    table = np.array([[r.gaps[i].relative for r in suite.results] for i in range(3)])
    np.testing.assert_array_equal(suite.gap_table, table)
    flat = np.sort(table.ravel())
    assert suite.aggregate.iqm_gap == pytest.approx(flat[1:-1].mean())  # 6 values: cut 1 + 1
    lo, hi = suite.aggregate.iqm_gap_ci95
    assert lo < suite.aggregate.iqm_gap < hi  # three runs: a real interval
    with pytest.raises(ValueError, match=r"make_policy\('SDJLS-Degradation-v0'\) returned 1"):
        evaluate_suite(lambda t: [LinearFeedbackController(t.model, t.K)] * (
            2 if t.env_id == "SDJLS-Solar-v0" else 1), TWO, episodes=5)  # fmt: skip


def test_a_policy_outside_the_curve_counts_at_the_worst_value_and_has_no_equal_risk_view():
    suite = evaluate_suite(lambda t: MJLSLQRController(t.model, "average"), ("SDJLS-Solar-v0",),
                           episodes=E)  # fmt: skip
    (result,) = suite.results
    assert result.gaps == (None,) and "above the curve's range" in result.reasons[0]
    assert suite.gap_table.tolist() == [[100.0]] and suite.aggregate.iqm_gap == 100.0
    assert suite.equal_risk_aggregate is None and suite.equal_risk_table is None
    assert suite.missing[0].startswith("SDJLS-Solar-v0 run 0:")
    json.dumps(suite.to_dict())  # plain JSON


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"make_policy": 3}, TypeError, "make_policy = 3 is an int"),
        ({"tasks": "SDJLS-Solar-v0"}, TypeError, "tasks = 'SDJLS-Solar-v0' is a str"),
        ({"tasks": ()}, ValueError, r"tasks = \(\) is empty"),
        ({"tasks": ("SDJLS-Nope-v0",)}, ValueError, r"tasks\[0\] = 'SDJLS-Nope-v0'"),
        ({"tasks": ("SDJLS-Solar-v0", 3)}, TypeError, r"tasks\[1\] = 3 is an int"),
        ({"tasks": ("SDJLS-Solar-v0",) * 2}, ValueError, "names a task twice"),
        ({"episodes": 1}, ValueError, "episodes = 1"),
        ({"episodes": True}, TypeError, "episodes = True"),
        ({"seed": -1}, ValueError, "seed = -1"),
        ({"resamples": 10}, ValueError, "resamples = 10"),
    ],
)
def test_evaluate_suite_refuses_bad_arguments_before_any_work(kwargs, error, match):
    calls = []
    args = {"make_policy": lambda t: calls.append(t), "tasks": TWO, **kwargs}
    with pytest.raises(error, match=match):
        evaluate_suite(**args)
    assert calls == []
    assert check_tasks(list(TWO)) == (TASKS[TWO[0]], TASKS[TWO[1]])


# --------------------------------------------------------------------------- rliable aggregate
def test_aggregate_matches_a_hand_computation():
    """IQM, probability of improvement and profile of a seeded synthetic (runs, tasks) table,
    computed here with numpy and scipy.stats.trim_mean."""
    rng = np.random.default_rng(11)
    gaps = rng.normal(0.0, 20.0, size=(3, 5))
    gaps[1, 2] = 0.0  # a tie with the curve counts one half
    a = aggregate_gaps(gaps, resamples=RESAMPLES)
    flat = np.sort(gaps.ravel())
    cut = int(0.25 * flat.size)  # 15 values: 3 from each end
    assert a.iqm_gap == pytest.approx(flat[cut : flat.size - cut].mean(), rel=1e-12)
    assert a.iqm_gap == pytest.approx(stats.trim_mean(gaps, 0.25, axis=None), rel=1e-12)
    poi = np.mean(np.mean((gaps < 0) + 0.5 * (gaps == 0), axis=0))
    assert a.probability_of_improvement == pytest.approx(poi)
    for i in (0, 75, 100, 150):
        assert a.profile[i] == pytest.approx(np.mean(-gaps > PROFILE_TAUS[i]))
    lo, hi = a.iqm_gap_ci95
    assert lo < a.iqm_gap < hi  # three runs: runs are resampled within each task
    assert np.all(a.profile_ci95[0] <= a.profile + 1e-12)
    assert np.all(a.profile <= a.profile_ci95[1] + 1e-12)


def test_aggregate_intervals_are_seeded_and_leave_the_global_generator_alone():
    """rliable draws from numpy's legacy global generator: aggregate_gaps seeds it for the call
    (the same intervals at every call, other ones for another seed) and restores the caller's
    state (three runs, so the intervals are a real bootstrap)."""
    gaps = np.random.default_rng(3).normal(0.0, 20.0, size=(3, 5))
    before = np.random.get_state()  # noqa: NPY002 - what the call must give back
    first = aggregate_gaps(gaps, resamples=RESAMPLES).to_dict()
    after = np.random.get_state()  # noqa: NPY002
    assert after[0] == before[0] and np.array_equal(after[1], before[1])
    assert after[2:] == before[2:]
    assert aggregate_gaps(gaps, resamples=RESAMPLES).to_dict() == first
    other = aggregate_gaps(gaps, resamples=RESAMPLES, seed=1).to_dict()
    assert other["iqm_gap"] == first["iqm_gap"]  # the point does not depend on the seed
    assert other["iqm_gap_ci95"] != first["iqm_gap_ci95"]
    for name, bad in (("seed", -1), ("seed", 2**32), ("resamples", 0)):
        with pytest.raises(ValueError, match=name):
            aggregate_gaps(gaps, **{name: bad})


def test_aggregate_with_one_run_is_exact_and_its_interval_is_the_point():
    gaps = np.array([[-4.0, 1.0, 2.0, 30.0, -0.5]])
    a = aggregate_gaps(gaps, resamples=RESAMPLES)
    assert a.iqm_gap == pytest.approx((-0.5 + 1.0 + 2.0) / 3)  # 5 values: cut 1 from each end
    assert a.iqm_gap_ci95 == (a.iqm_gap, a.iqm_gap)  # nothing to resample within a task
    assert a.probability_of_improvement_ci95 == (0.4, 0.4)
    assert a.to_dict() == aggregate_gaps(gaps).to_dict()  # whatever the global generator's state
    for bad in (np.zeros((0, 3)), np.array([1.0, 2.0]), np.array([[1.0, np.nan]])):
        with pytest.raises(ValueError, match="gaps = "):
            aggregate_gaps(bad)


# --------------------------------------------------------------------------- command line
@pytest.fixture
def factory_module(tmp_path, monkeypatch):
    (tmp_path / "suite_policy.py").write_text(
        "from controllers import LinearFeedbackController\n"
        "def factory(task):\n"
        "    return LinearFeedbackController(task.model, task.K)\n"
        "not_callable = 3\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "suite_policy", raising=False)
    return tmp_path


def test_cli_scores_a_factory_on_the_given_tasks(factory_module, capsys):
    path = factory_module / "suite.json"
    suite = main(["--policy", "suite_policy:factory", "--tasks", *TWO, "--episodes", "20",
                  "--json", str(path), "--no-progress"])  # fmt: skip
    out = capsys.readouterr().out
    assert all(env_id in out for env_id in TWO)
    data = json.loads(path.read_text())
    assert data["tasks"] == list(TWO) and data["episodes"] == 20 and data["policy"]
    assert data["aggregate"]["iqm_gap"] == pytest.approx(suite.aggregate.iqm_gap)


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["--episodes", "1"], "--episodes = 1"),
        (["--seed", "-2"], "--seed = -2"),
        (["--tree-episodes", "1"], "--tree-episodes = 1"),
        (["--tasks", "SDJLS-Nope-v0"], "--tasks"),
        (["--policy", "suite_policy"], "--policy"),
        (["--policy", "no_such_module_x:factory"], "no_such_module_x"),
        (["--policy", "suite_policy:missing"], "'missing'"),
        (["--policy", "suite_policy:not_callable"], "not_callable"),
        (["--policy", "suite_policy:factory", "--quick"], "--quick"),
        (["--policy", "suite_policy:factory", "--out", "x"], "--out"),
        (["--policy", "suite_policy:factory", "--json", "/no/such/dir/s.json"], "--json"),
        (["--json", "s.json"], "--json"),
    ],
)
def test_cli_refuses_bad_options_with_exit_2(factory_module, capsys, argv, named):
    with pytest.raises(SystemExit) as exc:
        parse_args(argv)
    assert exc.value.code == 2
    assert named in capsys.readouterr().err


def test_cli_quick_writes_elsewhere_and_never_over_full_references(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "temp"))  # the quick folder made here
    (tmp_path / "temp").mkdir()
    opts, factory = parse_args(["--quick"])
    assert factory is None and Path(opts.out).parent == tmp_path / "temp"
    assert Path(opts.out).name.startswith("sdjls-gym-suite-")
    assert opts.episodes == 50
    (tmp_path / "summary.json").write_text(json.dumps({"options": {"quick": False}}))
    with pytest.raises(SystemExit) as exc:
        parse_args(["--quick", "--out", str(tmp_path)])
    assert exc.value.code == 2 and "--quick with --out" in capsys.readouterr().err


def test_cli_references_quick_on_one_task(tmp_path):
    out = tmp_path / "refs"
    summary = main(["--quick", "--tasks", "SDJLS-Degradation-v0", "--episodes", "10",
                    "--tree-episodes", "3", "--out", str(out), "--no-progress"])  # fmt: skip
    names = {p.name for p in out.iterdir()}
    assert {"summary.json", "summary.csv", "REPORT.md", "fig_aggregate.png",
            "fig_SDJLS-Degradation-v0.png"} <= names  # fmt: skip
    assert not [n for n in names if n.endswith(".tmp")]
    data = json.loads((out / "summary.json").read_text())
    assert data["options"]["quick"] is True and summary["options"]["episodes"] == 10
    (task,) = data["tasks"]
    families = {p["family"] for p in task["points"]}
    assert families == {"RHC individual", "RHC joint", "RHC 3-step", "Linear feedback", "MJLS LQ"}
    tree = [p for p in task["points"] if p["family"] == "RHC 3-step"]
    assert {p["episodes"] for p in tree} == {3} and {p["xi"] for p in tree} == {0.5, 0.9}
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 1 + len(task["points"])


def test_docs_suite_tables_are_copied_from_the_committed_report():
    """The manual's model-based results of the suite (docs/benchmarks.md) are rows of
    results/suite/REPORT.md."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    readme = (root / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    readme = readme[readme.index("## The suite, scored as one benchmark") :]
    readme = readme[: readme.index("\n## ")]  # the section
    report = set((root / "results/suite/REPORT.md").read_text(encoding="utf-8").splitlines())
    families = ("| RHC joint |", "| RHC 3-step |", "| Linear feedback |", "| MJLS LQ |")
    rows = [
        line
        for line in readme.splitlines()
        if (line.startswith("| `SDJLS-") and " / " in line) or line.startswith(families)
    ]
    assert len(rows) >= 10, rows
    missing = [row for row in rows if row not in report]
    assert not missing, f"README rows not in results/suite/REPORT.md: {missing[:2]}"
    assert "python -m benchmarks.suite" in readme
