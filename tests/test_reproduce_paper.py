"""The paper-reproduction command runs end to end and its claims come out as section 6 states.

The claims are properties of the math (the closed loop's A + B K is nilpotent, so feasibility of
P3 does not depend on the state), not of the seed; with 1500 runs x 20 steps per configuration
the frequencies compared differ by 10-20 standard errors, so a different seed does not flip them.
"""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

from benchmarks.paper import reproduce as reproduce_paper

STAT_RUNS = 1500
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
        [
            "--runs",
            "10",
            "--stat-runs",
            str(STAT_RUNS),
            "--seed",
            "7",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    return out, summary


def _configs(data):
    """(study, configuration) for the paper's runs and the calibration grid."""
    return [("paper", c) for c in data["paper_configs"]] + [
        ("calibration", p)
        for k in ("individual", "joint", "bonferroni")
        for p in data["calibration"][k]
    ]


def _brackets(freq, interval):
    lo, hi = interval
    return 0.0 <= lo <= freq <= hi <= 1.0 and lo < hi


def test_files_are_written(run):
    out, _ = run
    names = {p.name for p in out.iterdir()}
    assert FIGURES | {"summary.json", "summary.csv", "summary_per_step.csv", "REPORT.md"} <= names
    for fig in FIGURES:
        png = (out / fig).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        width = int.from_bytes(png[16:20], "big")
        assert width <= 1200, (fig, width)  # readable at README page width
        assert len(png) < 300_000, (fig, len(png))


def test_summary_schema(run):
    out, summary = run
    data = json.loads((out / "summary.json").read_text())
    assert data == json.loads(json.dumps(summary))
    assert set(data) >= {
        "command",
        "options",
        "rows",
        "schema",
        "paper_configs",
        "calibration",
        "mean_square",
        "claims",
    }
    assert len(data["rows"]) == 2
    names = [c["name"] for c in data["paper_configs"]]
    assert names == [
        "individual_0.85",
        "joint_0.85",
        "individual_0.95",
        "individual_0.5",
        "individual_0.3",
    ]
    for _, cfg in _configs(data):
        runs, steps = cfg["runs"], cfg["steps"]
        assert runs == STAT_RUNS and steps == 20
        va = cfg["violation_any"]
        assert _brackets(va["freq"], va["wilson95"])
        assert va["freq"] == pytest.approx(va["count"] / (runs * steps))
        assert len(cfg["violation_rows"]) == 2 and len(cfg["per_step"]) == 20
        for j, row in enumerate(cfg["violation_rows"]):
            assert row["row"] == j
            assert _brackets(row["freq"], row["wilson95"]), (cfg["name"], row)
            assert row["freq"] == pytest.approx(row["count"] / (runs * steps))
        # a state violating any row violates at least the most violated row, at most the sum
        row_counts = [row["count"] for row in cfg["violation_rows"]]
        assert max(row_counts) <= va["count"] <= sum(row_counts)
        assert [st["k_next"] for st in cfg["per_step"]] == list(range(1, 21))
        for st in cfg["per_step"]:
            assert len(st["violation_rows"]) == 2
            assert len(st["violation_rows_count"]) == 2
            assert len(st["violation_rows_wilson95"]) == 2
            assert _brackets(st["violation_any"], st["wilson95"])
            assert st["violation_any"] == pytest.approx(st["violation_any_count"] / runs)
            for freq, count, ci in zip(
                st["violation_rows"],
                st["violation_rows_count"],
                st["violation_rows_wilson95"],
                strict=True,
            ):
                assert _brackets(freq, ci), (cfg["name"], st["k_next"], freq, ci)
                assert freq == pytest.approx(count / runs)
            assert max(st["violation_rows_count"]) <= st["violation_any_count"]
            assert st["violation_any_count"] <= sum(st["violation_rows_count"])
        # the per-step counts add up to the overall counts
        assert sum(st["violation_any_count"] for st in cfg["per_step"]) == va["count"]
        for j in range(2):
            assert sum(st["violation_rows_count"][j] for st in cfg["per_step"]) == row_counts[j]
        assert 0.0 <= cfg["rho_positive_share"] <= 1.0 and cfg["rho_max"] >= 0.0
        c = cfg["episode_cost"]
        assert c["ci95"][0] <= c["mean"] <= c["ci95"][1]
        assert cfg["solver_fallbacks"] == 0


def test_summary_csv_has_one_line_per_configuration(run):
    out, summary = run
    with (out / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 5 + 3 * len(reproduce_paper.CALIBRATION_XIS)
    assert set(rows[0]) >= {
        "study",
        "configuration",
        "constraint",
        "xi",
        "runs",
        "violation_any",
        "violation_any_lo",
        "violation_any_hi",
        "violation_row0",
        "violation_row0_lo",
        "violation_row0_hi",
        "violation_row1",
        "violation_row1_lo",
        "violation_row1_hi",
        "rho_positive_share",
        "rho_max",
        "episode_cost_mean",
        "episode_cost_lo",
        "episode_cost_hi",
    }
    assert [(r["study"], r["configuration"]) for r in rows] == [
        (study, c["name"]) for study, c in _configs(summary)
    ]
    for r in rows:
        for col in ("violation_any", "violation_row0", "violation_row1"):
            f, lo, hi = (float(r[col + end]) for end in ("", "_lo", "_hi"))
            assert _brackets(f, (lo, hi)), (r["configuration"], col)
        assert float(r["episode_cost_lo"]) <= float(r["episode_cost_mean"])
        assert float(r["episode_cost_mean"]) <= float(r["episode_cost_hi"])


def test_per_step_csv_is_long_format(run):
    out, summary = run
    with (out / "summary_per_step.csv").open() as fh:
        header = next(csv.reader(fh))
    assert header == [
        "study",
        "configuration",
        "constraint",
        "xi",
        "runs",
        "k",
        "row",
        "violations",
        "frequency",
        "wilson95_lo",
        "wilson95_hi",
    ]
    with (out / "summary_per_step.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    configs = _configs(summary)
    assert len(rows) == len(configs) * 20 * 3  # rows 0, 1 and "any" at k = 1..20
    keys = {(r["study"], r["configuration"], int(r["k"]), r["row"]) for r in rows}
    assert len(keys) == len(rows)
    assert keys == {
        (study, c["name"], k, row)
        for study, c in configs
        for k in range(1, 21)
        for row in ("0", "1", "any")
    }
    for r in rows:
        runs, count, freq = int(r["runs"]), int(r["violations"]), float(r["frequency"])
        assert runs == STAT_RUNS and 0 <= count <= runs
        assert freq == pytest.approx(count / runs, abs=1e-6)
        assert _brackets(freq, (float(r["wilson95_lo"]), float(r["wilson95_hi"])))
    assert (out / "summary_per_step.csv").stat().st_size < 400_000


def test_p_values_that_underflow_are_not_printed_as_zero(run):
    out, _ = run
    assert reproduce_paper.format_p(0.0) == "p < 1e-300"
    assert reproduce_paper.format_p(0.012) == "p = 0.012"
    text = (out / "REPORT.md").read_text()
    assert not re.search(r"p = 0(?![.0-9])", text)


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
    with pytest.raises(SystemExit):  # the intervals need two runs
        reproduce_paper.parse_args(["--stat-runs", "1"])
    assert "--stat-runs = 1; expected an integer >= 2" in capsys.readouterr().err


def test_summary_records_the_package_versions(run):
    from benchmarks.core.versions import CORE_PACKAGES

    out, _ = run
    versions = json.loads((out / "summary.json").read_text())["versions"]
    assert set(versions) == {"python", *CORE_PACKAGES}
    assert versions["numpy"] and versions["gymnasium"] and versions["python"].count(".") == 2
    assert versions["cvxpy"] and versions["osqp"]


SMALL = ["--runs", "3", "--stat-runs", "20", "--seed", "3", "--no-progress"]


def test_files_do_not_depend_on_the_installed_extras(tmp_path, monkeypatch):
    """Without the rl extra (stable-baselines3, torch absent) the reproduction writes the same
    files: the paper's results record only the packages they run on (on the base commit
    summary.json recorded stable-baselines3's version, null without the extra)."""
    from importlib import metadata

    reproduce_paper.main([*SMALL, "--out", str(tmp_path / "all")])
    real = metadata.version
    optional = {"stable-baselines3", "torch", "ray", "rl-zoo3", "rl_zoo3", "sb3-contrib"}

    def without_extras(name: str) -> str:
        if name in optional:
            raise metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(metadata, "version", without_extras)
    reproduce_paper.main([*SMALL, "--out", str(tmp_path / "core")])
    for name in ("summary.json", "summary.csv", "summary_per_step.csv", "REPORT.md"):
        core, every = ((tmp_path / d / name).read_text() for d in ("core", "all"))
        assert core.replace(str(tmp_path / "core"), "OUT") == every.replace(
            str(tmp_path / "all"), "OUT"
        )
    text = (tmp_path / "core" / "summary.json").read_text()
    assert "stable-baselines3" not in text and "null" not in text


def _floats(value):
    if isinstance(value, dict):
        return [f for v in value.values() for f in _floats(v)]
    if isinstance(value, list):
        return [f for v in value for f in _floats(v)]
    return [value] if isinstance(value, float) else []


def test_json_floats_carry_only_machine_stable_digits(run):
    """Every float of summary.json has at most 10 significant digits, so a statistic whose last
    float64 digits differ between machines (summation order) is written the same."""
    out, _ = run
    floats = _floats(json.loads((out / "summary.json").read_text()))
    assert len(floats) > 1000
    long = [f for f in floats if len(f"{f:.17g}".lstrip("-").replace(".", "").strip("0")) > 10
            and float(f"{f:.10g}") != f]  # fmt: skip
    assert not long, long[:5]
    # the same statistic from another summation order: one bit off, the same text
    cost = 4822.123456789012
    other = float(np.nextafter(cost, np.inf))
    assert reproduce_paper.dump_json({"c": cost}) == reproduce_paper.dump_json({"c": other})
