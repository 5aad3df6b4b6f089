"""The hidden wing (``python -m benchmarks.hidden``, issue 48): its quick command end to end into
a temporary folder, with agents trained by ``compare_rl --preset hidden --quick``; the filter's
accuracy against a recursion written here; the rules of the aggregate and of the generated
conclusions against hand-made numbers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import hidden
from benchmarks.core.montecarlo import rollout
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


def test_the_quick_command_scores_every_design_with_the_mode_hidden(quick):
    root, summary = quick
    out = root / "out"
    for name in ("REPORT.md", "summary.json", "summary.csv", f"fig_{TASK}_cost_violation.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "summary.json").read_text())["runs"]["kept"] == 3
    task = summary["tasks"][TASK]
    designs = {d["name"]: d for d in task["designs"]}
    assert set(designs) == {ORACLE, CE, BELIEF, *(f"{c} s0" for c in CONFIGS)}
    assert task["missing"] == {}
    for d in designs.values():
        assert d["episodes"] == 20
        assert (d["gap"] is None) == (d["gap_reason"] is not None)  # a gap, or why not
        assert d["kind"] == "oracle" or d["decision_time_s"] > 0
    filtered = {n for n, d in designs.items() if d["filter"] is not None}
    assert filtered == {CE, BELIEF, "ppo_belief_reward s0"}
    for name in filtered:
        f = designs[name]["filter"]
        assert 0 <= f["top_share"] <= 1 and 0 <= f["true_probability"] <= 1
    assert designs[ORACLE]["gap"] == 0.0
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == 1 + 6
    assert set(summary["across_tasks"]) == {CE, BELIEF, *CONFIGS}


def test_compare_rl_hands_its_hidden_scoring_to_the_wing(quick):
    """``--score-only`` of the hidden preset writes the wing's report, not the suite's."""
    from benchmarks.rl import compare as compare_rl

    root, _ = quick
    summary = compare_rl.main(["--preset", "hidden", "--quick", "--score-only", "--tasks", TASK,
                               "--configs", *CONFIGS, "--seeds", "1", "--out", str(root / "rl"),
                               "--eval-episodes", "10"])  # fmt: skip
    assert summary["runs"]["kept"] == 3 and summary["tasks"][TASK]["episodes"] == 10
    assert "The mode hidden" in (root / "rl" / "REPORT.md").read_text()


def test_without_agents_the_wing_needs_no_runs(tmp_path):
    summary = hidden.main(["--quick", "--no-agents", "--tasks", TASK, "--out", str(tmp_path),
                           "--episodes", "10"])  # fmt: skip
    assert summary["runs"] == {"expected": 0, "kept": 0, "train_cpu_h": None, "budgets": {}}
    assert [d["name"] for d in summary["tasks"][TASK]["designs"]] == [ORACLE, CE, BELIEF]


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
            diverged: int = 0, cost: float = 10.0) -> DesignScore:  # fmt: skip
    return DesignScore(name, kind, config, seed, 100, cost, (cost - 1, cost + 1), cost, 0.1,
                       (0.09, 0.11), diverged, gap, None if gap is None else (gap - 1, gap + 1),
                       None if gap is not None else ("2 episode(s) diverged" if diverged
                                                     else "violation frequency above"))  # fmt: skip


def _task(env_id: str, ce: float | None, belief: float | None,
          agents: dict[int, tuple[float | None, int]]) -> TaskResult:  # fmt: skip
    designs = [_design(ORACLE, "oracle", ORACLE, None, 0.0),
               _design(CE, "controller", CE, None, ce, diverged=0 if ce is not None else 3),
               _design(BELIEF, "controller", BELIEF, None, belief,
                       diverged=0 if belief is not None else 5)]  # fmt: skip
    designs += [_design(f"ppo_state_reward s{s}", "agent", "ppo_state_reward", s, g, diverged=d)
                for s, (g, d) in agents.items()]  # fmt: skip
    return TaskResult(env_id, 0.9, 100, (0,), [], designs)


def test_an_agent_configuration_is_summed_up_by_medians_over_its_seeds():
    r = _task("A", 2.0, 1.0, {0: (4.0, 0), 1: (None, 7), 2: (10.0, 0)})
    s = {c.configuration: c for c in config_summaries(r)}["ppo_state_reward"]
    assert (s.seeds, s.bounded_seeds, s.gap_seeds, s.gap, s.diverged) == (3, 2, 2, 7.0, 0.0)
    assert not s.bounded


def test_a_task_where_a_seed_has_no_gap_is_left_out_of_the_aggregate():
    results = [_task("A", 2.0, -1.0, {0: (4.0, 0), 1: (6.0, 0)}),
               _task("B", None, 3.0, {0: (None, 4), 1: (8.0, 0)}),
               _task("C", 1.0, 2.0, {0: (5.0, 0)})]  # fmt: skip
    across = {a.configuration: a for a in across_tasks(results, ["ppo_state_reward"], 20)}
    agent = across["ppo_state_reward"]
    assert agent.tasks == ("A", "C") and agent.seeds == (0,)
    assert any(line.startswith("B: seed 0") for line in agent.left_out)
    assert any("seed(s) 1" in line for line in agent.left_out)
    assert agent.aggregate is not None and agent.aggregate.iqm_gap == pytest.approx(4.5)
    assert across[CE].tasks == ("A", "C") and across[BELIEF].tasks == ("A", "B", "C")


def _summary(config: str, kind: str, gap: float | None, bounded: int, seeds: int = 1,
             diverged: float = 0.0) -> ConfigSummary:  # fmt: skip
    return ConfigSummary(
        config, kind, seeds, 10.0, 0.1, diverged, bounded, gap, seeds if gap is not None else 0, 100
    )


def test_the_conclusions_follow_from_hand_made_numbers():
    lost = [_summary(ORACLE, "oracle", 0.0, 1), _summary(CE, "controller", None, 0, diverged=40),
            _summary(BELIEF, "controller", None, 0, diverged=90),
            _summary("ppo_state_reward", "agent", None, 0, seeds=5, diverged=100)]  # fmt: skip
    kept = [_summary(ORACLE, "oracle", 0.0, 1), _summary(CE, "controller", 3.5, 1),
            _summary(BELIEF, "controller", -1.25, 1),
            _summary("ppo_state_reward", "agent", -7.0, 4, seeds=5)]  # fmt: skip
    per_task = {"A": lost, "B": kept}
    assert unbounded_tasks(per_task) == ["A"]
    text = " ".join(task_sentences("A", lost))
    assert "No design kept every episode bounded on A" in text
    assert all(f"{n:g} of 100" in text for n in (40, 90, 100))
    text = " ".join(task_sentences("B", kept))
    assert f"{CE} and {BELIEF} kept every one of the 100" in text  # not the agent: 4 of 5 seeds
    assert "ppo_state_reward on 1 of 5 seed(s)" in text
    assert "+3.5%" in text and "-1.2%" in text and "-7.0%" in text
    assert text.endswith(f"{BELIEF} (-1.2%).")  # the cheapest bounded design, not the agent
    overall = overall_sentences(per_task)
    assert overall[0].endswith("on A.") and "B" in overall[1] and BELIEF in overall[1]
    assert overall_sentences({"B": kept})[0].startswith("On every task")
    # bounded but outside the curve: costlier and riskier than the oracle (10 / 8 = x1.25)
    oracle = ConfigSummary(ORACLE, "oracle", 1, 8.0, 0.05, 0.0, 1, 0.0, 1, 100)
    riskier = [oracle, _summary(CE, "controller", None, 1)]
    text = " ".join(overall_sentences({"C": riskier}))
    assert "C: no bounded design has a gap" in text and "x1.25" in text
    assert "costlier and riskier" in " ".join(task_sentences("C", riskier))


def test_the_summary_names_the_evaluation_seeds(quick):
    _, summary = quick
    assert summary["evaluation_seeds"] == list(hidden.EVAL_SEEDS)
    assert Path(summary["options"]["out"]).name == "out"
