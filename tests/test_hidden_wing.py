"""The hidden wing (``python -m benchmarks.hidden``, issue 48): its quick command end to end into
a temporary folder, with agents trained by ``compare_rl --preset hidden --quick``; the filter's
accuracy against a recursion written here; the rules of the aggregate (every run counts: its
bounded gap), of the summaries and of the generated conclusions against hand-made numbers and
hand computations (rliable's IQM is scipy's 25% trimmed mean, computed here by hand)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import hidden
from benchmarks.core.montecarlo import rollout
from benchmarks.hidden.report import write_outputs
from benchmarks.hidden.score import (
    BELIEF,
    CE,
    ORACLE,
    DesignScore,
    TaskResult,
    controllers,
    filter_accuracy,
)
from benchmarks.hidden.summary import (
    ConfigSummary,
    across_tasks,
    config_summaries,
    overall_sentences,
    task_sentences,
    unbounded_tasks,
)
from sdjls_gym.systems import TASKS

TASK = "SDJLS-Degradation-v0"
CONFIGS = ["ppo_state_reward", "recurrent_ppo_state_lagrangian", "ppo_belief_reward"]
RULES = {"gap", "diverged", "riskier than the curve", "safer than the curve"}
#: The protocol's noise seeds, typed in (docs/hidden.md), not imported.
SEEDS = (0, 1, 2)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """Three tiny hidden agents trained by compare_rl, then the wing's quick command."""
    pytest.importorskip("sb3_contrib")
    from benchmarks.rl import compare as compare_rl

    root = tmp_path_factory.mktemp("hidden")
    compare_rl.main(["--preset", "hidden", "--quick", "--train-only", "--tasks", TASK,
                     "--configs", *CONFIGS, "--seeds", "1", "--out", str(root / "rl"),
                     "--no-progress", "--workers", "1"])  # fmt: skip
    summary = hidden.main(["--quick", "--runs", str(root / "rl" / "runs"), "--out",
                           str(root / "out"), "--tasks", TASK, "--configs", *CONFIGS,
                           "--seeds", "1", "--episodes", "20"])  # fmt: skip
    return root, summary


def _check_bounded_gaps(designs: dict[str, dict]) -> None:
    """Every design has a bounded gap by one of the rules: its gap at equal risk (clipped)
    where it has one, +100 where an episode diverged."""
    for name, d in designs.items():
        assert d["bounded_gap_rule"] in RULES, name
        assert -100.0 <= d["bounded_gap"] <= 100.0, name
        if d["bounded_gap_rule"] == "gap":
            assert d["gap"] is not None
            assert d["bounded_gap"] == pytest.approx(np.clip(d["gap"], -100, 100)), name
        else:
            assert d["gap"] is None, name
        if d["diverged"]:
            assert (d["bounded_gap"], d["bounded_gap_rule"]) == (100.0, "diverged"), name


def test_the_quick_command_scores_every_design_with_the_mode_hidden(quick):
    root, _ = quick
    out = root / "out"
    for name in ("REPORT.md", "summary.json", "summary.csv", f"fig_{TASK}_cost_violation.png"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"]["kept"] == 3
    task = summary["tasks"][TASK]
    designs = {d["name"]: d for d in task["designs"]}
    assert set(designs) == {ORACLE, CE, BELIEF, *(f"{c} s0" for c in CONFIGS)}
    assert task["missing"] == {}
    assert task["seeds"] == list(SEEDS) and task["episodes_per_seed"] == 20
    for d in designs.values():
        assert d["episodes"] == 20 * len(SEEDS)  # every seed's episodes, pooled
        assert (d["gap"] is None) == (d["gap_reason"] is not None)  # a gap, or why not
        assert d["kind"] == "oracle" or d["decision_time_s"] > 0
    _check_bounded_gaps(designs)
    filtered = {n for n, d in designs.items() if d["filter"] is not None}
    assert filtered == {CE, BELIEF, "ppo_belief_reward s0"}
    for name in filtered:
        f = designs[name]["filter"]
        assert 0 <= f["top_share"] <= 1 and 0 <= f["true_probability"] <= 1
    assert (designs[ORACLE]["gap"], designs[ORACLE]["bounded_gap"]) == (0.0, 0.0)
    # the oracle is the curve's point at the task's xi, on the same pooled episodes
    point = next(p for p in task["oracle_curve"] if p["xi"] == TASKS[TASK].rhc["xi"])
    assert point["cost_mean"] == designs[ORACLE]["cost_mean"]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert len(rows) == 6
    for row in rows:
        d = designs[row["name"]]
        assert float(row["bounded_gap_percent"]) == pytest.approx(d["bounded_gap"], rel=1e-6)
        assert row["bounded_gap_rule"] == d["bounded_gap_rule"]
    # every kept run counts: each design has its aggregate, nothing left out
    assert set(summary["across_tasks"]) == {CE, BELIEF, *CONFIGS}
    for config, a in summary["across_tasks"].items():
        assert a["aggregate"] is not None and a["left_out"] == [], config
        assert a["tasks"] == [TASK] and sum(a["rules"].values()) == 1
        one = designs[config if config in (CE, BELIEF) else f"{config} s0"]
        assert a["aggregate"]["iqm_gap"] == pytest.approx(one["bounded_gap"], abs=1e-6)
    report = (out / "REPORT.md").read_text()
    assert "20 episodes x 3 noise seeds (0, 1, 2), 60 per task" in report
    assert "IQM of the bounded gaps" in report and "every run counts" in report.lower()


def test_compare_rl_hands_its_hidden_scoring_to_the_wing(quick):
    """``--score-only`` of the hidden preset writes the wing's report, not the suite's."""
    from benchmarks.rl import compare as compare_rl

    root, _ = quick
    summary = compare_rl.main(["--preset", "hidden", "--quick", "--score-only", "--tasks", TASK,
                               "--configs", *CONFIGS, "--seeds", "1", "--out", str(root / "rl"),
                               "--eval-episodes", "10"])  # fmt: skip
    task = summary["tasks"][TASK]
    assert summary["runs"]["kept"] == 3 and task["episodes_per_seed"] == 10
    assert task["episodes"] == 10 * len(SEEDS)
    assert "The mode hidden" in (root / "rl" / "REPORT.md").read_text()


def test_without_agents_the_wing_needs_no_runs(tmp_path):
    summary = hidden.main(["--quick", "--no-agents", "--tasks", TASK, "--out", str(tmp_path),
                           "--episodes", "10"])  # fmt: skip
    assert summary["runs"] == {"expected": 0, "kept": 0, "train_cpu_h": None, "budgets": {}}
    task = summary["tasks"][TASK]
    assert [d["name"] for d in task["designs"]] == [ORACLE, CE, BELIEF]
    assert {d["episodes"] for d in task["designs"]} == {10 * len(SEEDS)}
    assert TASKS[TASK].rhc["xi"] in [p["xi"] for p in task["oracle_curve"]]
    _check_bounded_gaps({d["name"]: d for d in task["designs"]})


def test_tasks_scored_on_two_workers_give_the_same_numbers(tmp_path):
    """``--workers 2`` scores the tasks in two processes: every number but the timings is the
    one process's."""
    tasks = ["--tasks", TASK, "SDJLS-Solar-v0", "--episodes", "5", "--quick", "--no-agents"]
    one = hidden.main([*tasks, "--out", str(tmp_path / "one")])
    two = hidden.main([*tasks, "--out", str(tmp_path / "two"), "--workers", "2"])
    timing = {"decision_time_s", "scoring_cpu_s"}
    for env_id in (TASK, "SDJLS-Solar-v0"):
        a, b = one["tasks"][env_id], two["tasks"][env_id]
        assert a["oracle_curve"] == b["oracle_curve"]
        assert [{k: v for k, v in d.items() if k not in timing} for d in a["designs"]] == [
            {k: v for k, v in d.items() if k not in timing} for d in b["designs"]
        ]
    assert two["scoring_cpu_min"] > 0


def test_the_episodes_are_checked_over_every_seed(capsys):
    """``--episodes`` is per noise seed: at most the core's limit divided by the seeds."""
    from benchmarks.core.evaluate import MAX_EPISODES
    from benchmarks.hidden.cli import parse_args

    with pytest.raises(SystemExit) as exc:
        parse_args(["--no-agents", "--episodes", str(MAX_EPISODES // len(SEEDS) + 1)])
    assert exc.value.code == 2 and "--episodes" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the filter
def test_the_filters_accuracy_against_a_recursion_written_here():
    """Hamilton's filter written with scipy's densities, one episode at a time, on the belief
    RHC's own episodes."""
    from scipy.stats import multivariate_normal

    task = TASKS[TASK]
    m = task.model
    policy = controllers(TASK)[BELIEF]
    ro = rollout(m, policy, 6, task.horizon, 2, task.action_bound)
    hits = probability = steps = 0.0
    for e in range(6):
        alpha = np.eye(m.N)[m.mode0]
        for k in range(task.horizon - 1):
            x, u, x_next = ro.x[e, k], ro.u[e, k], ro.x[e, k + 1]
            lik = np.array([multivariate_normal.pdf(x_next, m.A[i] @ x + m.B[i] @ u,
                                                    m.E[i] @ m.W @ m.E[i].T) for i in range(m.N)])  # fmt: skip
            beta = alpha * lik / np.sum(alpha * lik)
            inside = np.all(m.G @ x <= m.H(k))
            alpha = beta @ (m.P_in if inside else m.P_out)
            steps += 1
            hits += np.argmax(alpha) == ro.mode[e, k + 1]
            probability += alpha[ro.mode[e, k + 1]]
    got = filter_accuracy(m, [ro])
    assert got.steps == steps
    assert got.top_share == pytest.approx(hits / steps, abs=1e-12)
    assert got.true_probability == pytest.approx(probability / steps, rel=1e-9)


# ----------------------------------------------------------------------------- summaries
def _design(name: str, kind: str, config: str, seed: int | None, gap: float | None,
            diverged: int = 0, cost: float = 10.0, bounded: float | None = None,
            rule: str | None = None) -> DesignScore:  # fmt: skip
    """A hand-made run: its bounded gap is its gap (rule "gap"), +100 when it diverged, or
    ``bounded`` by ``rule`` (a run outside the curve)."""
    if bounded is None:
        bounded, rule = (100.0, "diverged") if diverged else (gap, "gap")
    return DesignScore(name=name, kind=kind, configuration=config, seed=seed, episodes=100,
                       cost_mean=cost, cost_ci95=(cost - 1, cost + 1), cost_median=cost,
                       violation=0.1, violation_wilson95=(0.09, 0.11), diverged=diverged,
                       gap=gap, gap_ci95=None if gap is None else (gap - 1, gap + 1),
                       gap_reason=None if gap is not None else (
                           "2 episode(s) diverged" if diverged else "violation frequency above"),
                       bounded_gap=bounded, bounded_gap_rule=rule)  # fmt: skip


AGENT = "ppo_state_reward"


def _task(env_id: str, ce: float | None, belief: float | None,
          agents: dict[int, DesignScore | tuple[float | None, int]]) -> TaskResult:  # fmt: skip
    """A task: the oracle, certainty equivalence and the belief RHC (diverged without a gap),
    and the agent's seeds (a hand-made run, or ``(gap, diverged)``)."""
    designs = [_design(ORACLE, "oracle", ORACLE, None, 0.0),
               _design(CE, "controller", CE, None, ce, diverged=0 if ce is not None else 3),
               _design(BELIEF, "controller", BELIEF, None, belief,
                       diverged=0 if belief is not None else 5)]  # fmt: skip
    for s, a in agents.items():
        designs.append(a if isinstance(a, DesignScore) else
                       _design(f"{AGENT} s{s}", "agent", AGENT, s, a[0], diverged=a[1]))  # fmt: skip
    return TaskResult(env_id, 0.9, 300, SEEDS, [], designs)


def _safer(seed: int, value: float) -> DesignScore:
    """An agent's seed safer than the curve: no gap at equal risk, its bounded gap ``value``."""
    return _design(f"{AGENT} s{seed}", "agent", AGENT, seed, None, bounded=value,
                   rule="safer than the curve")  # fmt: skip


def test_an_agent_configuration_is_summed_up_by_medians_over_its_seeds():
    """The gap at equal risk over the seeds that have one; the bounded gap over all of them
    (the diverged seed at +100)."""
    r = _task("A", 2.0, 1.0, {0: (4.0, 0), 1: (None, 7), 2: (10.0, 0)})
    s = {c.configuration: c for c in config_summaries(r)}[AGENT]
    assert (s.seeds, s.bounded_seeds, s.gap_seeds, s.gap, s.diverged) == (3, 2, 2, 7.0, 0.0)
    assert s.bounded_gap == 10.0  # median of 4, 100, 10
    assert s.bounded_gap_rules == ("gap", "diverged", "gap")
    assert not s.bounded
    r = _task("A", 2.0, 1.0, {0: (4.0, 0), 1: _safer(1, -30.0), 2: (10.0, 0), 3: (None, 2)})
    s = {c.configuration: c for c in config_summaries(r)}[AGENT]
    assert s.gap == 7.0 and s.bounded_gap == 7.0  # medians of (4, 10) and (-30, 4, 10, 100)


def test_a_diverged_seed_enters_the_aggregate_at_the_worst_value():
    """Every run counts: a task where a seed diverged or is outside the curve stays in the
    aggregate, that seed at its bounded gap (+100 diverged, its own value safer)."""
    results = [_task("A", 2.0, -1.0, {0: (4.0, 0), 1: (6.0, 0)}),
               _task("B", None, 3.0, {0: (None, 4), 1: (8.0, 0)}),
               _task("C", 1.0, 2.0, {0: (5.0, 0), 1: _safer(1, -20.0)})]  # fmt: skip
    across = {a.configuration: a for a in across_tasks(results, [AGENT], 20)}
    agent = across[AGENT]
    assert agent.tasks == ("A", "B", "C") and agent.seeds == (0, 1) and agent.left_out == ()
    assert agent.rules == {"diverged": 1, "gap": 4, "safer than the curve": 1}
    # the 25% trimmed mean of 4, 6, 100, 8, 5, -20: one value cut at each end, (4+5+6+8)/4
    assert agent.aggregate is not None and agent.aggregate.iqm_gap == pytest.approx(5.75)
    assert (agent.aggregate.runs, agent.aggregate.tasks) == (2, 3)
    # certainty equivalence diverged on B: B is in, at +100; one run of three tasks, so the
    # trimmed mean cuts int(0.25 * 3) = 0 values at each end: (2 + 100 + 1) / 3
    assert across[CE].tasks == ("A", "B", "C") and across[CE].left_out == ()
    assert across[CE].aggregate.iqm_gap == pytest.approx(103 / 3)
    assert across[CE].rules == {"diverged": 1, "gap": 2}
    assert across[BELIEF].aggregate.iqm_gap == pytest.approx(4 / 3)  # of -1, 3, 2


def test_only_missing_runs_are_left_out_of_the_aggregate():
    """A task without a kept run, and a seed not kept on every task, are left out and named;
    a seed without a gap is not."""
    results = [_task("A", 2.0, -1.0, {0: (4.0, 0), 1: (6.0, 0)}),
               _task("B", 1.0, 3.0, {0: (None, 4), 1: (8.0, 0)}),
               _task("D", 1.0, 3.0, {0: (3.0, 0)}),
               _task("E", 1.0, 3.0, {})]  # fmt: skip
    agent = {a.configuration: a for a in across_tasks(results, [AGENT], 20)}[AGENT]
    assert agent.tasks == ("A", "B", "D") and agent.seeds == (0,)
    assert set(agent.left_out) == {"E: no kept run", "seed 1: not kept on D"}
    # seed 0 on A, B, D: 4, 100 (diverged), 3; the 25% trimmed mean of three values cuts
    # int(0.25 * 3) = 0 at each end: (4 + 100 + 3) / 3
    assert agent.aggregate is not None and agent.aggregate.iqm_gap == pytest.approx(107 / 3)
    nothing = {a.configuration: a for a in across_tasks([_task("E", 1.0, 3.0, {})], [AGENT])}
    nothing = nothing[AGENT]
    assert nothing.aggregate is None and nothing.left_out == ("E: no kept run",)


def _summary(config: str, kind: str, gap: float | None, bounded: int, seeds: int = 1,
             diverged: float = 0.0, bounded_gap: float | None = None,
             rules: tuple[str, ...] | None = None, gap_seeds: int | None = None) -> ConfigSummary:  # fmt: skip
    if bounded_gap is None:
        bounded_gap = 100.0 if diverged else (gap if gap is not None else 100.0)
    if rules is None:
        rules = ("diverged",) * seeds if diverged else ("gap",) * seeds
    if gap_seeds is None:
        gap_seeds = seeds if gap is not None else 0
    return ConfigSummary(config, kind, seeds, 10.0, 0.1, diverged, bounded, gap, gap_seeds,
                         bounded_gap, 100, rules)  # fmt: skip


def test_the_conclusions_follow_from_hand_made_numbers():
    lost = [_summary(ORACLE, "oracle", 0.0, 1), _summary(CE, "controller", None, 0, diverged=40),
            _summary(BELIEF, "controller", None, 0, diverged=90),
            _summary(AGENT, "agent", None, 0, seeds=5, diverged=100)]  # fmt: skip
    kept = [_summary(ORACLE, "oracle", 0.0, 1), _summary(CE, "controller", 3.5, 1),
            _summary(BELIEF, "controller", -1.25, 1),
            _summary(AGENT, "agent", -7.0, 4, seeds=5, gap_seeds=4, bounded_gap=-6.5,
                     rules=("gap", "gap", "diverged", "gap", "gap"))]  # fmt: skip
    per_task = {"A": lost, "B": kept}
    assert unbounded_tasks(per_task) == ["A"]
    text = " ".join(task_sentences("A", lost))
    assert "No design kept every episode bounded on A" in text
    assert all(f"{n:g} of 100" in text for n in (40, 90, 100))
    assert f"{CE} no gap: episodes diverged, bounded gap +100.0% (diverged)" in text
    text = " ".join(task_sentences("B", kept))
    assert f"{CE} and {BELIEF} kept every one of the 100" in text  # not the agent: 4 of 5 seeds
    assert f"{AGENT} on 1 of 5 seed(s)" in text
    assert "+3.5%" in text and "-1.2%" in text
    assert (f"{AGENT} -7.0% (median of 4 of 5 seeds), bounded gap -6.5% (median of 5 seed(s); "
            "1 of 5 diverged)") in text  # fmt: skip
    assert text.endswith(f"{BELIEF} (-1.2%; at equal risk: -1.2%).")  # not the agent
    overall = overall_sentences(per_task)
    assert overall[0].endswith("on A.") and overall[1].startswith("B:") and BELIEF in overall[1]
    assert len(overall) == 2  # nothing about A beyond its first sentence
    assert overall_sentences({"B": kept})[0].startswith("On every task")
    # bounded but outside the curve: costlier and riskier than the oracle (10 / 8 = x1.25)
    oracle = ConfigSummary(ORACLE, "oracle", 1, 8.0, 0.05, 0.0, 1, 0.0, 1, 0.0, 100, ("gap",))
    riskier = [oracle, _summary(CE, "controller", None, 1, rules=("riskier than the curve",))]
    text = " ".join(overall_sentences({"C": riskier}))
    assert "+100.0% (riskier than the curve)" in text and "x1.25" in text
    assert "No bounded design has a gap to the oracle's curve at equal risk" in text
    assert "costlier and riskier" in " ".join(task_sentences("C", riskier))
    # a gap beyond the worst value: the bounded gap says it is clipped; an equal one is not said
    clipped = [kept[0], _summary(CE, "controller", 250.0, 1, bounded_gap=100.0), kept[2]]
    text = " ".join(task_sentences("D", clipped))
    assert f"{CE} +250.0%, bounded gap +100.0%;" in text and f"{BELIEF} -1.2%." in text


def test_the_cheapest_bounded_design_ranks_by_its_bounded_gap():
    """A configuration bounded on every seed whose median gap at equal risk is the smallest,
    but one of whose seeds is riskier than the curve (+100), is not the cheapest: its bounded
    gap is the median over all its seeds."""
    summaries = [
        _summary(ORACLE, "oracle", 0.0, 1), _summary(CE, "controller", 2.0, 1),
        _summary(BELIEF, "controller", 1.0, 1),
        _summary(AGENT, "agent", -10.0, 3, seeds=3, gap_seeds=2, bounded_gap=4.0,
                 rules=("gap", "riskier than the curve", "gap")),
    ]  # fmt: skip
    text = task_sentences("T", summaries)[-1]
    assert text.endswith(f"{BELIEF} (+1.0%; at equal risk: +1.0%).")
    line = overall_sentences({"T": summaries})[1]
    assert line.startswith("T: the smallest bounded gap") and f"({BELIEF};" in line
    summaries[3] = _summary(AGENT, "agent", -10.0, 3, seeds=3, bounded_gap=-10.0)
    assert task_sentences("T", summaries)[-1].endswith(
        f"{AGENT} (-10.0% (median of 3 seed(s)); at equal risk: -10.0%)."
    )


# ----------------------------------------------------------------------------- the files
def test_the_report_states_bounded_gaps_and_the_episodes_of_the_data(tmp_path):
    """The files from hand-made results: the episodes per seed and the seeds read from the
    data, the bounded gap beside the gap, the aggregate of the bounded gaps."""
    results = [_task("A", 2.0, -1.0, {0: (4.0, 0), 1: (6.0, 0)}),
               _task("B", None, 3.0, {0: (None, 4), 1: (8.0, 0)})]  # fmt: skip
    across = across_tasks(results, [AGENT], 20)
    meta = {"command": "hand-made", "scoring_cpu_min": 0.0,
            "runs": {"expected": 4, "kept": 4, "train_cpu_h": None, "budgets": {}}}  # fmt: skip
    write_outputs(tmp_path, results, across, meta, {})
    report = (tmp_path / "REPORT.md").read_text()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert "100 episodes x 3 noise seeds (0, 1, 2), 300 per task" in report
    assert "IQM of the bounded gaps, % (95% CI)" in report
    assert "every run counts: its bounded gap, +100 for a diverged run" in report.lower()
    assert "left out whole" not in report
    # the agent: trimmed mean of 4, 100, 6, 8 (cut one at each end): 7
    agent = summary["across_tasks"][AGENT]
    assert agent["aggregate"]["iqm_gap"] == pytest.approx(7.0)
    assert agent["tasks"] == ["A", "B"] and agent["rules"] == {"diverged": 1, "gap": 3}
    row = next(line for line in report.splitlines() if line.startswith(f"| {AGENT} | 2 x 2 |"))
    assert "+7.0" in row and "diverged: 1, gap: 3" in row
    assert f"| {AGENT} s0 |" in report and "| +100.0 (diverged) |" in report
    b = {s["configuration"]: s for s in summary["tasks"]["B"]["summaries"]}
    assert b[CE]["bounded_gap"] == 100.0 and b[AGENT]["bounded_gap"] == pytest.approx(54.0)
    # the short table, by hand: A keeps all three designs bounded, B only the belief RHC
    assert "| A | 3 of 3 | +2.0% | -1.0% | ppo_state_reward +5.0% (median of 2 seed(s)) |" in report
    assert ("| B | 1 of 3 | +100.0% (diverged) | +3.0% | ppo_state_reward +54.0% (median of 2 "
            "seed(s); 1 of 2 diverged) |") in report  # fmt: skip
    assert report.index("## The price in short") < report.index("## The price of the hidden")
    rows = list(csv.DictReader((tmp_path / "summary.csv").open()))
    ce_b = next(r for r in rows if r["task"] == "B" and r["name"] == CE)
    assert (ce_b["bounded_gap_percent"], ce_b["bounded_gap_rule"]) == ("100.0", "diverged")


def test_the_summary_names_the_evaluation_seeds(quick):
    _, summary = quick
    assert summary["evaluation_seeds"] == list(hidden.EVAL_SEEDS) == list(SEEDS)
    assert Path(summary["options"]["out"]).name == "out"
