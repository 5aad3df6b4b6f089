"""The paper-reproduction command runs end to end and its claims come out as section 6 states.

The claims are properties of the math (the closed loop's A + B K is nilpotent, so feasibility of
P3 does not depend on the state), not of the seed; with 1500 runs x 20 steps per configuration
the frequencies compared differ by 10-20 standard errors, so a different seed does not flip them.
"""

from __future__ import annotations

import csv
import json

import pytest

from benchmarks import reproduce_paper

FIGURES = {
    "fig_mode.png",
    "fig_cost.png",
    "fig_income_individual_joint.png",
    "fig_income_xi.png",
    "fig_calibration.png",
    "fig_mean_square.png",
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    summary = reproduce_paper.main(
        ["--runs", "10", "--stat-runs", "1500", "--seed", "7", "--out", str(out), "--no-progress"]
    )
    return out, summary


def test_files_are_written(run):
    out, _ = run
    names = {p.name for p in out.iterdir()}
    assert FIGURES | {"summary.json", "summary.csv", "REPORT.md"} <= names
    for fig in FIGURES:
        assert (out / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_summary_schema(run):
    out, summary = run
    data = json.loads((out / "summary.json").read_text())
    assert data == json.loads(json.dumps(summary))
    assert set(data) >= {
        "command",
        "options",
        "paper_configs",
        "calibration",
        "mean_square",
        "claims",
    }
    names = [c["name"] for c in data["paper_configs"]]
    assert names == [
        "individual_0.85",
        "joint_0.85",
        "individual_0.95",
        "individual_0.5",
        "individual_0.3",
    ]
    for cfg in data["paper_configs"] + [
        p for k in ("individual", "joint", "bonferroni") for p in data["calibration"][k]
    ]:
        assert cfg["runs"] == 1500 and cfg["steps"] == 20
        lo, hi = cfg["violation_any"]["wilson95"]
        assert 0.0 <= lo <= cfg["violation_any"]["freq"] <= hi <= 1.0
        assert len(cfg["violation_rows"]) == 2 and len(cfg["per_step"]) == 20
        assert 0.0 <= cfg["rho_positive_share"] <= 1.0 and cfg["rho_max"] >= 0.0
        c = cfg["episode_cost"]
        assert c["ci95"][0] <= c["mean"] <= c["ci95"][1]
        assert cfg["solver_fallbacks"] == 0
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert len(rows) == 5 + 3 * len(reproduce_paper.CALIBRATION_XIS)


def test_every_claim_of_section_6_agrees(run):
    _, summary = run
    claims = summary["claims"]
    assert len(claims) == 6
    failed = [c["claim"] + ": " + c["measured"] for c in claims if not c["agree"]]
    assert not failed, failed


def test_individual_rows_keep_the_guarantee_where_it_holds(run):
    """rho = 0 (P3 feasible): each row is violated with probability at most 1 - xi.

    Checked on the 95% Wilson interval of each row's frequency (1500 x 20 samples): its lower
    end must not exceed 1 - xi. At xi = 0.85 the lower row is active at every step (the cost
    pulls the income down onto the tightened bound), so there the frequency must also be
    statistically equal to 1 - xi.
    """
    _, summary = run
    checked = 0
    for point in summary["calibration"]["individual"]:
        if point["rho_positive_share"] == 0:
            for row in point["violation_rows"]:
                assert row["wilson95"][0] <= 1 - point["xi"], (point["name"], row)
            checked += 1
        if point["xi"] == 0.85:
            lo, hi = point["violation_rows"][0]["wilson95"]
            assert lo <= 0.15 <= hi
    assert checked >= 10


def test_mean_square_bound_holds(run):
    _, summary = run
    assert summary["mean_square"]["max_ratio"] < 1.0


def test_report_names_the_command_and_has_no_disagreement(run):
    out, _ = run
    text = (out / "REPORT.md").read_text()
    assert "python -m benchmarks.reproduce_paper --runs 10 --stat-runs 1500" in text
    assert "**no**" not in text
    assert text.count("| yes |") == 6


def test_bad_options_are_rejected(capsys):
    with pytest.raises(SystemExit):
        reproduce_paper.parse_args(["--runs", "0"])
    assert "--runs = 0" in capsys.readouterr().err
