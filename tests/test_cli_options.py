"""The command lines built from dataclasses (:mod:`benchmarks.core.cli`): the builder's rules,
and every script's flags and parsed values, written out here by hand (they are the scripts'
contract: the flags were the same before the scripts shared the builder)."""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import raises_naming

from benchmarks.core import cli as cli_options
from benchmarks.core.cli import options_parser, parse_options
from benchmarks.core.commands import SCRIPTS


class _Parsed(Exception):
    def __init__(self, parser, opts):
        self.parser, self.opts = parser, opts


def parsed(monkeypatch, module: str, argv: list[str]):
    """``(parser, options)`` a script builds from ``argv``, stopped before its checks and work."""
    mod = importlib.import_module(SCRIPTS[module])

    def stop(parser, options, argv):
        raise _Parsed(parser, parse_options(parser, options, argv))

    monkeypatch.setattr(mod, "parse_options", stop, raising=False)  # imported at the top
    monkeypatch.setattr(cli_options, "parse_options", stop)  # or inside parse_args
    entry = mod.main if module == "render_picture" else mod.parse_args
    with pytest.raises(_Parsed) as caught:
        entry(argv)
    return caught.value.parser, caught.value.opts


FLAGS = {
    "compare_rl": "--preset --tasks --configs --algos --variants --timesteps --seeds "
    "--eval-episodes --seed --eval-seeds --out --workers --backend --address --quick --train-only "
    "--score-only "
    "--tuned "
    "--retrain --no-progress",
    "reproduce_paper": "--runs --stat-runs --seed --out --no-progress",
    "render_picture": "--out --seed --episodes --fps-only --before",
    "suite": "--policy --tasks --episodes --seed --seeds --json --out --tree-episodes --workers "
    "--quick --no-progress",
    "tune": "--algo --variant --task --trials --timesteps --seeds --storage --study-name --out "
    "--backend --address --workers --seed --quick --print-space --no-progress",
}


@pytest.mark.parametrize("module", sorted(FLAGS))
def test_every_script_keeps_its_flags(monkeypatch, module):
    parser, _ = parsed(monkeypatch, module, [])
    usage = parser.format_usage()
    assert re.findall(r"\[(--[a-z][a-z-]*)", usage) == FLAGS[module].split()


def test_compare_rl_parses_lists_paths_and_switches(monkeypatch):
    _, opts = parsed(monkeypatch, "compare_rl", [
        "--tasks", "SDJLS-Solar-v0", "SDJLS-VTOL-v0", "--configs", "ppo_reward", "--tuned",
        "a.json", "b.json", "--out", "x", "--address", "auto", "--workers", "3", "--train-only",
    ])  # fmt: skip
    assert opts.tasks == ["SDJLS-Solar-v0", "SDJLS-VTOL-v0"] and opts.configs == ["ppo_reward"]
    assert opts.tuned == [Path("a.json"), Path("b.json")] and opts.out == Path("x")
    assert (opts.address, opts.workers, opts.train_only, opts.retrain) == ("auto", 3, True, False)
    assert (opts.preset, opts.backend, opts.eval_episodes, opts.seeds) == (
        "suite", "process", 1000, None,
    )  # fmt: skip
    parser, _ = parsed(monkeypatch, "compare_rl", [])
    assert "--tasks TASK [TASK ...]" in parser.format_usage()
    assert "[--tuned STUDY.json [STUDY.json ...]]" in parser.format_usage()
    with pytest.raises(SystemExit):
        parsed(monkeypatch, "compare_rl", ["--tasks", "CartPole-v1"])


def test_the_other_scripts_parse_their_types(monkeypatch):
    _, opts = parsed(monkeypatch, "reproduce_paper", ["--runs", "3", "--no-progress"])
    assert (opts.runs, opts.stat_runs, opts.seed, opts.out, opts.no_progress) == (
        3, 2000, 0, Path("results/paper"), True,
    )  # fmt: skip
    _, opts = parsed(monkeypatch, "render_picture", ["--before", "b.json", "--fps-only"])
    assert (opts.out, opts.seed, opts.episodes, opts.fps_only, opts.before) == (
        Path("results/render"), 0, 10, True, Path("b.json"),
    )  # fmt: skip
    _, opts = parsed(monkeypatch, "suite", ["--tasks", "SDJLS-Solar-v0", "--episodes", "7"])
    assert (opts.tasks, opts.episodes, opts.json, opts.quick) == (
        ["SDJLS-Solar-v0"], 7, None, False,
    )  # fmt: skip
    _, opts = parsed(monkeypatch, "suite", [])
    assert len(opts.tasks) == 6  # the default: the whole suite
    _, opts = parsed(monkeypatch, "tune", ["--algo", "sac", "--study-name", "s", "--trials", "4"])
    assert (opts.algo, opts.study_name, opts.trials, opts.out, opts.storage) == (
        "sac", "s", 4, None, None,
    )  # fmt: skip


# ----------------------------------------------------------------------------- the builder
@dataclass
class _Example:
    count: int = field(default=1, metadata={"help": "an int"})
    rate: float | None = field(default=None, metadata={"help": "a float"})
    where: Path = field(default=Path("out"), metadata={"help": "a path"})
    kind: str = field(default="a", metadata={"help": "a choice", "choices": ("a", "b")})
    names: list[str] = field(default_factory=lambda: ["x"], metadata={"help": "names"})
    files: list[Path] | None = field(default=None, metadata={"help": "paths", "metavar": "F"})
    dry_run: bool = field(default=False, metadata={"help": "a switch"})


def test_options_parser_reads_the_annotations():
    parser = options_parser(_Example, prog="example")
    assert parse_options(parser, _Example, []) == _Example()
    opts = parse_options(parser, _Example, [
        "--count", "3", "--rate", "0.5", "--where", "w", "--kind", "b", "--names", "p", "q",
        "--files", "f.json", "--dry-run",
    ])  # fmt: skip
    assert opts == _Example(3, 0.5, Path("w"), "b", ["p", "q"], [Path("f.json")], True)
    assert "[--files F [F ...]]" in parser.format_usage()
    for bad in (["--count", "1.5"], ["--kind", "c"], ["--names"]):
        with pytest.raises(SystemExit):
            parse_options(parser, _Example, bad)


def test_options_parser_refuses_what_has_no_command_line_form():
    with raises_naming(TypeError, "options", "3"):
        options_parser(3)

    @dataclass
    class Nested:
        table: dict[str, int] = field(default_factory=dict, metadata={"help": "no form"})

    with raises_naming(TypeError, "Nested.table", "dict[str, int]"):
        options_parser(Nested)
