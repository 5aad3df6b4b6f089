"""A kept run whose files were tampered with or corrupted is refused, naming the file and what
is wrong: by ``benchmarks.rl.runs.load_agent``, by ``python -m benchmarks.evaluate --run`` (a parser
error, exit status 2) and by ``python -m benchmarks.compare_rl --score-only`` before it scores
anything.

Each case starts from a committed run of the suite (its record and its policy copied into a
temporary folder) and changes one thing, as a hostile or unlucky user would.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

import benchmarks  # noqa: E402
from benchmarks import evaluate  # noqa: E402
from benchmarks.rl import compare as compare_rl  # noqa: E402
from benchmarks.rl import runs  # noqa: E402
from sdjls_gym.errors import InvalidRunError  # noqa: E402

ROOT = Path(benchmarks.__file__).resolve().parents[1]
TASK = "SDJLS-Solar-v0"
KEPT = ROOT / "results" / "rl_suite" / "runs" / TASK
NAME = "ppo_residual_s0"
#: The command that finds the run above among the runs it expects (the suite's budget).
SCORE_ONLY = ["--score-only", "--tasks", TASK, "--configs", "ppo_residual", "--seeds", "1",
              "--eval-episodes", "10", "--no-progress"]  # fmt: skip


def _copy(name: str, folder: Path) -> Path:
    """The committed run ``name`` copied into ``folder``: the path of its record."""
    (record,) = KEPT.glob(f"{name}-*.json")
    folder.mkdir(parents=True, exist_ok=True)
    for path in (record, record.with_suffix(".pt")):
        shutil.copy(path, folder / path.name)
    return folder / record.name


def _edit(path: Path, change, refingerprint: bool = False) -> Path:
    """``change(data)`` applied to the record at ``path``; with ``refingerprint``, the record's
    fingerprint made the hash of its edited configuration and both files renamed to match (a
    careful forger)."""
    data = json.loads(path.read_text())
    change(data)
    if not refingerprint:
        path.write_text(json.dumps(data))
        return path
    config = json.dumps(data["config"], sort_keys=True).encode()
    data["fingerprint"] = hashlib.sha256(config).hexdigest()[:16]  # the rule, written here
    new = path.with_name(f"{data['name']}-{data['fingerprint']}.json")
    path.with_suffix(".pt").rename(new.with_suffix(".pt"))
    path.unlink()
    new.write_text(json.dumps(data))
    return new


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _net_arch(data):
    data["config"]["hyperparams"]["policy_kwargs"]["net_arch"] = [8, 8]


def _truncate(path: Path) -> Path:
    pt = path.with_suffix(".pt")
    pt.write_bytes(pt.read_bytes()[: pt.stat().st_size // 2])
    return path


def _foreign_policy(path: Path) -> Path:
    other = _copy("sac_lagrangian_s0", path.parent / "other")
    shutil.copy(other.with_suffix(".pt"), path.with_suffix(".pt"))
    return path


#: ``name -> (tamper(record path) -> the path to load, what the message says)``.
TAMPERED = {
    "a JSON list": (lambda p: _write(p, "[1, 2, 3]"), "JSON list"),
    "deep nesting": (lambda p: _write(p, "[" * 100_000 + "]" * 100_000), "too deep"),
    "an edited algo": (lambda p: _edit(p, lambda d: d.update(algo="sac")), "algo = 'sac'"),
    "an edited net_arch": (lambda p: _edit(p, _net_arch), "fingerprint = "),
    "an edited net_arch, fingerprint and name": (
        lambda p: _edit(p, _net_arch, refingerprint=True), "does not fit"),
    "another run's policy": (_foreign_policy, "does not fit"),
    "a truncated policy": (_truncate, "cannot be read"),
    "a mismatched fingerprint": (
        lambda p: _edit(p, lambda d: d.update(fingerprint="0123456789abcdef")),
        "fingerprint = '0123456789abcdef'"),
    "a deleted task_digest": (
        lambda p: _edit(p, lambda d: d["config"].pop("task_digest")), "fingerprint = "),
    "a deleted task_digest, fingerprint and name": (
        lambda p: _edit(p, lambda d: d["config"].pop("task_digest"), refingerprint=True),
        "task_digest = None"),
}  # fmt: skip


@pytest.mark.parametrize("case", TAMPERED)
def test_load_agent_refuses_a_tampered_run_naming_the_file(tmp_path, case):
    tamper, says = TAMPERED[case]
    path = tamper(_copy(NAME, tmp_path))
    with pytest.raises(InvalidRunError) as exc:
        runs.load_agent(path)
    message = str(exc.value)
    assert path.name in message and says in message, message


@pytest.mark.parametrize("case", TAMPERED)
def test_evaluate_run_refuses_a_tampered_run_with_a_parser_error(tmp_path, case, capsys):
    tamper, says = TAMPERED[case]
    path = tamper(_copy(NAME, tmp_path))
    with pytest.raises(SystemExit) as exc:
        evaluate.main(["--run", str(path), "--episodes", "10"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    (line,) = [line for line in err.splitlines() if "error:" in line]
    assert "--run" in line and path.name in line and says in line, line


def test_the_untampered_copy_loads(tmp_path):
    """The cases above fail for what they change, not for the copy itself."""
    path = _copy(NAME, tmp_path)
    assert runs.read_run(path).name == NAME
    assert runs.load_agent(path).agent is not None


@pytest.mark.parametrize("case", ["a JSON list", "a truncated policy", "a mismatched fingerprint",
                                  "a deleted task_digest", "another run's policy"])  # fmt: skip
def test_score_only_checks_every_run_before_scoring(tmp_path, monkeypatch, capsys, case):
    """The run in the place of its configuration is refused by name before any scoring (the
    scoring is replaced by a trap); a lost run is still only missing."""

    def scored(*args, **kwargs):
        raise AssertionError("the scoring started")

    monkeypatch.setattr(compare_rl, "report_suite", scored)
    monkeypatch.setattr(compare_rl, "report_macro", scored)
    out = tmp_path / "out"
    tamper, says = TAMPERED[case]
    path = tamper(_copy(NAME, out / "runs" / TASK))
    with pytest.raises(SystemExit) as exc:
        compare_rl.main([*SCORE_ONLY, "--out", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    (line,) = [line for line in err.splitlines() if "error:" in line]
    assert "--score-only" in line and path.name in line and says in line, line


def test_score_only_accepts_a_kept_run_and_a_lost_one(tmp_path):
    out = tmp_path / "out"
    _copy(NAME, out / "runs" / TASK)
    assert compare_rl.parse_args([*SCORE_ONLY, "--out", str(out)]).score_only
    shutil.rmtree(out / "runs")  # nothing kept: the report names the runs as missing
    assert compare_rl.parse_args([*SCORE_ONLY, "--out", str(out)]).score_only
