"""The speed benchmark's quick mode runs end to end and its correctness checks hold.

No timing is asserted here (the machines are shared and noisy); timings are read from the
committed ``results/speed/`` run. What is asserted is what the benchmark must get right whatever
the load: every section is written, and the decisions it times agree with the references.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.speed import measure as speed
from controllers import RecedingHorizonController
from sdjls_gym.systems import TASKS


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("speed")
    result = speed.main(["--quick", "--out", str(out)])
    return out, result


def test_quick_run_writes_json_and_markdown(quick):
    out, result = quick
    data = json.loads((out / "speed.json").read_text())
    assert data == json.loads(json.dumps(result))
    assert {
        "command",
        "machine",
        "targets",
        "env_step",
        "act",
        "batched",
        "tree",
        "scaling",
    } <= set(data)
    text = (out / "SPEED.md").read_text()
    assert "python -m benchmarks.speed" in text
    assert text.count("\n|") >= 8  # the targets table and the scaling tables


def test_timed_decisions_agree_with_the_references(quick):
    _, result = quick
    tol = result["targets"]["agreement_tol"]
    assert tol == 1e-6
    diffs = result["act"]["max_abs_diff_u"]
    assert set(diffs) >= {"rebuild", "parametric", "active_set"}
    assert max(diffs.values()) <= tol, diffs
    assert result["batched"]["max_abs_diff_act_batch_vs_act"] <= tol
    # the multi-step controller's fast path against its cvxpy reference, every tree of the issue
    rows = result["tree"]["rows"]
    assert [(row["steps"], row["branching"]) for row in rows] == [
        (1, 1),
        (2, 2),
        (3, 3),
        (5, 5),
        (10, 2),
    ]
    assert [row["nodes"] for row in rows] == [1, 4, 13, 121, 76]
    for row in rows:
        assert row["max_abs_diff_u_vs_cvxpy"] <= tol, row
        assert row["cvxpy_states"] >= 1 and row["qp_solves_per_decision"] >= 1.0


def test_every_measurement_is_a_positive_finite_number(quick):
    _, result = quick
    sections = [result[name] for name in ("env_step", "act", "batched")] + result["tree"]["rows"]
    for section in sections:
        for key, value in section.items():
            if isinstance(value, float):
                assert 0.0 < value < float("inf") or key.startswith("max_abs_diff"), (key, value)
    for row in result["scaling"]["p3"]:
        for key, value in row.items():
            if isinstance(value, float) and not key.startswith("max_"):
                assert 0.0 <= value < float("inf"), (key, value)


def test_scaling_rows_agree_with_the_daqp_floor_and_act_batch(quick):
    """Each scaling row's act() answers against the DAQP floor of the same P3 (written from the
    model in the benchmark, not read from the controller) and against act_batch."""
    _, result = quick
    rows = result["scaling"]["p3"]
    assert [(row["n"], row["m"], row["r"], row["N"]) for row in rows] == list(
        speed.QUICK_SCALING_SIZES
    )
    for row in rows:
        assert row["max_rel_diff_u_vs_floor"] <= 1e-6, row
        assert row["max_abs_diff_u_batch_vs_act"] <= result["targets"]["agreement_tol"], row
    assert any(row["active_share"] > 0.0 for row in rows)
    # issue 30: the suite's tasks in the scaling study, each on its own model and settings
    suite = result["scaling"]["suite"]
    assert [row["task"] for row in suite] == list(speed.QUICK_SUITE_SCALING)
    for row in suite:
        model = speed.TASKS[row["task"]].model
        assert (row["n"], row["m"], row["r"], row["N"]) == (model.n, model.m, model.r, model.N)
        assert row["max_rel_diff_u_vs_floor"] <= 1e-6, row
        assert row["max_abs_diff_u_batch_vs_act"] <= result["targets"]["agreement_tol"], row
    big = result["tree"]["large"]
    assert big["nodes"] == 111 and big["ok_share"] == 1.0, big


def test_no_controller_privates_are_read():
    """speed.py uses the controllers' public hooks only (issue 32)."""
    import re

    source = Path(speed.__file__).read_text(encoding="utf-8")
    assert not re.findall(r"(?:ctrl|fast|fam|engine)\._[a-z]", source)


def test_round_ratio_is_the_median_of_each_rounds_ratio():
    """A ratio of two blocks is read within each round, then the median over the rounds: a
    round where the machine was slow for both blocks moves neither the ratio nor the answer,
    while the ratio of the two blocks' own medians would (here 5 / 1.75 = 2.86 instead of 2)."""
    rounds = [[2.0, 1.0], [4.0, 2.0], [20.0, 10.0], [6.0, 1.5]]
    assert speed.round_ratio(rounds, 0, 1) == 2.0
    assert speed.round_ratio(rounds, 1, 0) == 0.5
    calls: list[str] = []
    blocks = [lambda: calls.append("a") or 1.0, lambda: calls.append("b") or 2.0]
    got = speed.timed_rounds(blocks, 3, after_warmup=lambda: calls.append("warm"))
    assert got == [[1.0, 2.0]] * 3
    assert calls == ["a", "b", "warm", "a", "b", "a", "b", "a", "b"]  # alternating, warm-up first


def test_the_references_import_none_of_the_projects_solver_code():
    """A reference shares no code with what it measures: benchmarks/speed/references.py imports
    no module of controllers (DAQP, scipy and cvxpy through their public APIs)."""
    from test_structure import imports

    path = Path(speed.__file__).with_name("references.py")
    assert not [m for m, _ in imports(path) if m.split(".")[0] == "controllers"]


@pytest.mark.parametrize("env_id", sorted(TASKS))
def test_the_independent_floor_gives_the_controllers_inputs(env_id):
    """The DAQP floor (daqp.Model on P3 written from the paper) and the controller answer the
    same P3: the same u on 60 closed-loop states, to DAQP's tolerance (1e-6 of the scale)."""
    from benchmarks.speed.references import DaqpFloor, P3Data

    task = TASKS[env_id]
    ctrl = RecedingHorizonController(task.model, task.K, horizon=task.horizon, **task.rhc)
    floor = DaqpFloor(P3Data(task.model, task.K, dict(task.rhc)))
    x, mode, k = speed.closed_loop_states(task.model, ctrl, 60, seed=2)
    for xi, mi, ki in zip(x, mode, k, strict=True):
        u = ctrl.act(xi, int(mi), int(ki))[0]
        scale = max(1.0, float(np.max(np.abs(u))), float(np.max(np.abs(xi))))
        assert np.allclose(floor.solve(xi, int(mi), int(ki))[0], u, rtol=0, atol=1e-6 * scale)


def test_the_hidden_mode_rows(quick):
    """Issue 48: the belief controller's act() against the mode controller's on each quick task,
    the filter's step, and the belief controller at a certain belief giving P3's answer."""
    from benchmarks.speed.hidden import QUICK_TASKS

    out, result = quick
    rows = result["hidden"]["tasks"]
    assert [row["task"] for row in rows] == list(QUICK_TASKS)
    for row in rows:
        for key in ("belief_act_us", "mode_act_us", "belief_vs_mode", "filter_step_us",
                    "filter_step_batch_per_row_us"):  # fmt: skip
            assert 0.0 < row[key] < float("inf"), (key, row)
        assert row["max_abs_diff_u_certain_belief_vs_mode"] <= 1e-6, row
    assert "belief / mode" in (out / "SPEED.md").read_text()
