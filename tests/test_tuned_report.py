"""``benchmarks.rl.tuned_report``: tuned runs against the default runs of the same configuration.

The comparison's numbers are checked on synthetic scores against a hand computation (rliable's
IQM is scipy's 25% trimmed mean; the probability of improvement is the share of (tuned,
default) pairs with the lower tuned gap); the command runs end to end on quick runs.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import trim_mean

from benchmarks.core.frontier import WORST_GAP
from benchmarks.core.stats import CurveGap
from benchmarks.rl import compare as compare_rl
from benchmarks.rl import tuned_report

STUDY = {
    "settings": {"task": "SDJLS-Macro-v0", "algo": "ppo", "variant": "residual",
                 "timesteps": 600000, "seeds": 1},
    "trials": [{"number": 0, "state": "COMPLETE"}, {"number": 1, "state": "PRUNED"}],
    "best": {"number": 0, "value": -0.01, "params": {}, "overrides": {"learning_rate": 1e-3}},
}  # fmt: skip


def _study(tmp_path):
    path = tmp_path / "study.json"
    path.write_text(json.dumps(STUDY))
    return path


def _gap(value: float) -> CurveGap:
    return CurveGap(mean=value, ci95=(value - 1, value + 1), curve_cost=100.0, violation=0.1,
                    xi=0.9, relative=value, relative_ci95=(value - 1, value + 1))  # fmt: skip


def _agent(record, gap: float | None, tree: float):
    """A scored run: a gap at equal risk, or (gap None) a run that diverged, whose bounded gap
    is the worst value, as benchmarks.core.frontier.bounded_gap gives it."""
    score = SimpleNamespace(cost_mean=100.0, violation=0.1, diverged=0 if gap is not None else 3)
    return SimpleNamespace(run=record, result=SimpleNamespace(score=score),
                           gap=None if gap is None else _gap(gap),
                           reason="diverged in 3 episode(s)" if gap is None else None,
                           bounded=WORST_GAP if gap is None else gap,
                           tree=SimpleNamespace(value=tree),
                           tree_gap=_gap(tree), tree_reason=None)  # fmt: skip


def _fake_scoring(monkeypatch, default_gaps, tuned_gaps, tree=0.0):
    """kept_runs gives one record per spec; score_task scores them with the given gaps (in the
    order default seeds, then tuned seeds) and returns the agents shuffled."""

    def kept_runs(specs, run_dir):
        return [SimpleNamespace(seed=s.seed, overrides=s.overrides) for s in specs]

    def score_task(task, pairs, *args, **kwargs):
        gaps = [*default_gaps, *tuned_gaps]
        agents = [
            _agent(r, g, tree + i) for i, ((_, r), g) in enumerate(zip(pairs, gaps, strict=True))
        ]
        return SimpleNamespace(agents=agents[::-1])

    monkeypatch.setattr(tuned_report, "kept_runs", kept_runs)
    monkeypatch.setattr(tuned_report, "score_task", score_task)


def test_groups_are_split_by_run_and_compared_as_by_hand(monkeypatch, tmp_path):
    default = [-2.0, 5.0, 1.0, 3.0, 30.0]
    tuned = [-9.0, -4.0, 2.0, -6.0, -5.0]
    _fake_scoring(monkeypatch, default, tuned)
    out = tuned_report.compare_study(_study(tmp_path), tmp_path, 5, 200, 0, True, log=str)
    assert out["groups"]["default"]["rhc"]["gaps"] == default
    assert out["groups"]["tuned"]["rhc"]["gaps"] == tuned
    assert out["trials"] == {"COMPLETE": 1, "PRUNED": 1}
    assert out["missing"] == {"default": [], "tuned": []}
    c = out["compare_rhc"]
    iqm_t, iqm_d = trim_mean(tuned, 0.25), trim_mean(default, 0.25)
    assert out["groups"]["tuned"]["rhc"]["iqm"] == pytest.approx(iqm_t, abs=1e-12)
    assert c["iqm_difference"] == pytest.approx(iqm_t - iqm_d, abs=1e-12)
    pairs = np.array(tuned)[:, None] - np.array(default)[None, :]
    by_hand = np.mean(pairs < 0) + 0.5 * np.mean(pairs == 0)
    assert c["probability_of_improvement"] == pytest.approx(by_hand, abs=1e-12)
    lo, hi = c["iqm_difference_ci95"]
    assert lo <= c["iqm_difference"] <= hi and lo < hi
    # the tree's gaps: default seeds got 0..4, tuned 5..9
    assert c is not out["compare_tree"]
    assert out["compare_tree"]["iqm_difference"] == pytest.approx(5.0, abs=1e-12)


def test_both_groups_are_read_at_the_study_budget(monkeypatch, tmp_path):
    """Default and tuned runs are compared at the budget the study tuned at (600k here), not at
    the suite's budget of the configuration, which may have moved since (1.2M on macro)."""
    seen = []
    _fake_scoring(monkeypatch, [0.0, 1.0], [2.0, 3.0])
    fake = tuned_report.kept_runs
    monkeypatch.setattr(
        tuned_report, "kept_runs", lambda specs, d: seen.extend(specs) or fake(specs, d)
    )
    tuned_report.compare_study(_study(tmp_path), tmp_path, 2, 200, 0, False, log=str)
    assert [(s.timesteps, bool(s.overrides)) for s in seen] == [(600_000, False)] * 2 + [
        (600_000, True)
    ] * 2


def test_a_run_without_a_gap_counts_at_the_worst_value(monkeypatch, tmp_path):
    """Every run counts (issue 47): a diverged seed enters its group at +WORST_GAP, not left
    out, so the comparison is not made on the lucky seeds alone."""
    _fake_scoring(monkeypatch, [1.0, None, 2.0], [0.0, -1.0, -2.0])
    out = tuned_report.compare_study(_study(tmp_path), tmp_path, 3, 200, 0, True, log=str)
    d = out["groups"]["default"]["rhc"]
    assert d["gaps"] == [1.0, WORST_GAP, 2.0]
    assert d["iqm"] == pytest.approx(trim_mean([1.0, WORST_GAP, 2.0], 0.25), abs=1e-12)
    assert out["compare_rhc"] is not None and out["compare_tree"] is not None
    assert out["compare_rhc"]["iqm_difference"] < 0  # the tuned group never diverged
    text = tuned_report.write_markdown([out], "python -m benchmarks.tuned_report", 200)
    assert "diverged in 3 episode(s)" in text  # the row says why that seed sits at the worst value


def test_bad_options_are_parser_errors(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    for argv, words in (
        (["--tuned", str(bad)], ["bad.json", "not a benchmarks.rl.tune summary"]),
        (["--tuned", str(_study(tmp_path)), "--seeds", "0"], ["--seeds = 0"]),
        (["--tuned", str(_study(tmp_path)), "--eval-episodes", "1"], ["--eval-episodes = 1"]),
    ):
        with pytest.raises(SystemExit) as exc:
            tuned_report.parse_args(argv)
        err = capsys.readouterr().err
        assert exc.value.code == 2 and all(w in err for w in words), err


@pytest.mark.slow  # two quick trainings and their scoring (about 30 s)
def test_quick_command_scores_default_and_tuned_runs(tmp_path):
    study = _study(tmp_path)
    base = ["--quick", "--tasks", "SDJLS-Macro-v0", "--configs", "ppo_residual", "--seeds", "1",
            "--train-only", "--no-progress", "--out", str(tmp_path / "cmp")]  # fmt: skip
    compare_rl.main(base)
    compare_rl.main([*base, "--tuned", str(study)])
    results = tuned_report.main(["--quick", "--seeds", "1", "--tuned", str(study), "--runs",
                                 str(tmp_path / "cmp" / "runs"), "--out", str(tmp_path / "rep")])  # fmt: skip
    (r,) = results
    assert r["missing"] == {"default": [], "tuned": []}
    assert [len(r["groups"][g]["rows"]) for g in ("default", "tuned")] == [1, 1]
    text = (tmp_path / "rep" / "TUNED.md").read_text()
    assert "| default | 0 |" in text and "| tuned | 0 |" in text
    assert json.loads((tmp_path / "rep" / "tuned.json").read_text())["studies"][0]["task"] == (
        "SDJLS-Macro-v0"
    )


def test_spent_budget_and_search_space_are_reported(monkeypatch, tmp_path):
    """The study's spending by hand (600k steps x 2 seeds per trial): a complete trial that
    recorded nothing counts both seeds' budget, a pruned or failed one its last learning-curve
    step (pruning stops a trial in its first seed), a recorded ``env_steps`` counts as such; the
    finished trials' wall times are summed (a running trial has no stamps, a failed one's span
    a stopped process), and the CPU times of those that recorded one; TUNED.md states them and
    the search space line by line."""
    study = {
        **STUDY,
        "settings": {**STUDY["settings"], "seeds": 2},
        "search_space": ["learning_rate: log-uniform in [3e-05, 0.003]", "net_arch: one of 64x64"],
        "trials": [
            {"number": 0, "state": "COMPLETE", "intermediate": {"300000": 0.1, "600000": 0.0},
             "wall_s": 1800.0, "cpu_s": None},
            {"number": 1, "state": "PRUNED", "intermediate": {"180000": 2.0},
             "wall_s": 900.0, "cpu_s": 720.0},
            {"number": 2, "state": "RUNNING", "intermediate": {}, "wall_s": None, "cpu_s": None},
            {"number": 3, "state": "FAIL", "intermediate": {"60000": 2.5}, "wall_s": 9e4,
             "cpu_s": None},
            {"number": 4, "state": "PRUNED", "intermediate": {"240000": 2.0}, "wall_s": None,
             "cpu_s": None, "env_steps": 250000},
        ],
    }  # fmt: skip
    path = tmp_path / "study.json"
    path.write_text(json.dumps(study))
    _fake_scoring(monkeypatch, [-1.0, 0.0], [-2.0, 1.0])
    (r,) = tuned_report.main(["--tuned", str(path), "--seeds", "2", "--runs", str(tmp_path),
                              "--out", str(tmp_path / "rep")])  # fmt: skip
    steps = 600000 * 2 + 180000 + 0 + 60000 + 250000
    assert r["spent"] == {"env_steps": steps, "wall_h": 2700 / 3600, "wall_trials": 2,
                          "cpu_h": 720 / 3600, "cpu_trials": 1, "trials": 5}  # fmt: skip
    text = (tmp_path / "rep" / "TUNED.md").read_text()
    assert "Spent: 1.69M env steps over its 5 trials" in text
    assert "sum to 0.75 h (2 trials" in text and "used 0.20 CPU-hours" in text
    assert "- learning_rate: log-uniform in [3e-05, 0.003]\n- net_arch: one of 64x64" in text
