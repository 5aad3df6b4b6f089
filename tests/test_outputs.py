"""Where the benchmarks write: ``write_atomic``'s targets and modes, and every script's output
folder (a new temporary folder per quick run, never the committed ``results/``, a parser error
for a folder it cannot write into, a study name that stays in its folder)."""

from __future__ import annotations

import importlib
import json
import os
import stat
import tempfile
import threading
from pathlib import Path

import pytest
from conftest import raises_naming

import benchmarks
from benchmarks.core.commands import SCRIPTS as SCRIPT_MODULES
from benchmarks.core.files import write_atomic

ROOT = Path(benchmarks.__file__).resolve().parents[1]
STUDY = {
    "settings": {"task": "SDJLS-Macro-v0", "algo": "ppo", "variant": "residual",
                 "timesteps": 600000, "seeds": 1},
    "trials": [{"number": 0, "state": "COMPLETE"}],
    "best": {"number": 0, "value": -0.01, "params": {}, "overrides": {"learning_rate": 1e-3}},
}  # fmt: skip
SCRIPTS = ("suite", "tune", "speed", "compare_rl", "tuned_report")


# ----------------------------------------------------------------------------- write_atomic
def test_write_atomic_writes_into_a_fifo_and_keeps_it(tmp_path):
    fifo = tmp_path / "score.json"
    os.mkfifo(fifo)
    read: list[str] = []
    reader = threading.Thread(target=lambda: read.append(fifo.read_text()), daemon=True)
    reader.start()
    write_atomic(fifo, '{"cost": 1}\n')
    reader.join(timeout=10)
    assert read == ['{"cost": 1}\n']
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_write_atomic_writes_into_a_character_device_and_keeps_it(tmp_path):
    """A node like /dev/null (made here, so that nothing outside the test is touched)."""
    node = tmp_path / "null"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    write_atomic(node, "anything")
    assert stat.S_ISCHR(os.stat(node).st_mode)
    assert [p.name for p in tmp_path.iterdir()] == ["null"]  # no temporary file left


def test_write_atomic_refuses_a_folder_and_a_block_device(tmp_path):
    with raises_naming(ValueError, "path", str(tmp_path)):
        write_atomic(tmp_path, "x")
    node = tmp_path / "disk"
    try:
        os.mknod(node, stat.S_IFBLK | 0o600, os.makedev(7, 0))
    except PermissionError:
        return  # making a device node needs root
    with raises_naming(ValueError, "path", str(node)):
        write_atomic(node, "x")
    assert stat.S_ISBLK(os.stat(node).st_mode)


def test_write_atomic_follows_a_symbolic_link_and_keeps_it(tmp_path):
    (tmp_path / "real.json").write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to("real.json")
    write_atomic(link, "new")
    assert link.is_symlink() and (tmp_path / "real.json").read_text() == "new"


def test_write_atomic_gives_the_usual_modes(tmp_path):
    """A new file: 0o666 less the umask, as open() gives; a replaced file keeps its mode."""
    old = os.umask(0o022)
    try:
        write_atomic(tmp_path / "new.json", "x")
        (tmp_path / "kept.json").write_text("x")
        (tmp_path / "kept.json").chmod(0o640)
        write_atomic(tmp_path / "kept.json", "y")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "new.json").st_mode) == 0o644
    assert stat.S_IMODE(os.stat(tmp_path / "kept.json").st_mode) == 0o640


# ----------------------------------------------------------------------------- the scripts
class _Started(Exception):
    """Raised where ``benchmarks.speed`` starts measuring: its checks have passed."""


def _parse(script: str, argv: list[str], tmp_path: Path, monkeypatch) -> None:
    """Run ``script``'s command-line checks on ``argv`` (and nothing more)."""
    if script not in ("suite", "reproduce_paper"):
        pytest.importorskip("stable_baselines3")
    if script == "speed":
        from benchmarks.speed import measure as speed

        def started(*args, **kwargs):
            raise _Started

        monkeypatch.setattr(speed, "env_step_blocks", started)
        with pytest.raises(_Started):
            speed.main(argv)
        return
    if script == "tuned_report":
        study = tmp_path / "study.json"
        study.write_text(json.dumps(STUDY))
        argv = [*argv, "--tuned", str(study), "--runs", str(tmp_path / "runs")]
    importlib.import_module(SCRIPT_MODULES[script]).parse_args(argv)


@pytest.mark.parametrize("script", SCRIPTS)
def test_each_quick_run_writes_into_a_new_folder(script, tmp_path, monkeypatch):
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.chdir(tmp_path)  # a default folder, if one were used, would be made here
    for _ in range(2):
        _parse(script, ["--quick"], tmp_path, monkeypatch)
    made = sorted(temp.iterdir())
    assert len(made) == 2 and all(p.name.startswith(f"sdjls-gym-{script}-") for p in made)


@pytest.mark.parametrize("script", SCRIPTS)
def test_no_quick_mode_writes_into_the_committed_results(script, tmp_path, monkeypatch, capsys):
    # speed's checks are reached through its main: a folder that exists, so nothing is made
    folder = ROOT / "results" / ("speed" if script == "speed" else "new-smoke-test")
    with pytest.raises(SystemExit) as exc:
        _parse(script, ["--quick", "--out", str(folder)], tmp_path, monkeypatch)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--out {folder}" in err and "committed" in err


@pytest.fixture(params=["locked", "under a file"])
def unwritable(request, tmp_path, monkeypatch):
    """A folder the run cannot make or write into: under a folder without write permission
    (root writes anyway: for it, the file system's answer is made a refusal), or under a file."""
    if request.param == "under a file":
        (tmp_path / "file").write_text("")
        yield tmp_path / "file" / "out"
        return
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    if os.access(locked, os.W_OK):
        real = os.access
        monkeypatch.setattr(os, "access", lambda path, mode, **kw: (
            False if Path(path) == locked and mode & os.W_OK else real(path, mode, **kw)))  # fmt: skip
    yield locked / "out"
    locked.chmod(0o755)


@pytest.mark.parametrize("script", [*SCRIPTS, "reproduce_paper"])
def test_an_unwritable_out_is_a_parser_error(script, unwritable, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        _parse(script, ["--out", str(unwritable)], tmp_path, monkeypatch)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--out {unwritable}" in err and "Traceback" not in err


@pytest.mark.parametrize("name", ["../../x", "a/b", "..", "a\\b"])
def test_a_study_name_is_a_plain_name(name, tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    from benchmarks.rl import tune as tune

    with pytest.raises(SystemExit) as exc:
        tune.parse_args(["--study-name", name, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and f"--study-name = {name!r}" in err
