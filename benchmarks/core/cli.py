"""What the benchmarks' command lines share: options from a dataclass, output files and folders,
names to import, agents to load.

:func:`options_parser` builds an ``argparse`` parser from an ``Options`` dataclass: one
``--flag-name`` per field, its type read from the annotation (``bool`` a switch; ``int``,
``float``, ``str``, ``Path``, optional or not; ``list[...]`` one or more values), its help,
choices and metavar from the field's ``metadata``. :func:`output_folder` is every script's rule
for ``--out``, checked before any work: a folder it can write into (:func:`out_folder_error`);
with ``--quick`` and no ``--out``, a new temporary folder per run (:func:`quick_folder`), and
never the committed ``results/`` or a full run's report (:func:`quick_out_error`).
:func:`load_cli_policy` loads the policy a ``--policy`` option names (a module's attribute, or a
stable-baselines3 ``.zip``: the only place the scoring imports stable-baselines3).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import tempfile
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import gymnasium as gym

from benchmarks.core.commands import prog
from benchmarks.core.files import target_error

__all__ = [
    "COMMITTED_RESULTS",
    "SB3_ALGOS",
    "CliError",
    "file_option_error",
    "filled",
    "holds_full_run",
    "import_attribute",
    "load_cli_policy",
    "one_of",
    "option",
    "options_parser",
    "out_folder_error",
    "output_folder",
    "parse_options",
    "plain_name_error",
    "quick_folder",
    "quick_out_error",
    "script_parser",
]

SB3_ALGOS = ("a2c", "ddpg", "ppo", "sac", "td3")
#: The policy module a saved SB3 agent names, and the ``--algo`` values that can load it.
SAVED_POLICIES = {
    "stable_baselines3.common.policies": ("a2c", "ppo"),
    "stable_baselines3.sac.policies": ("sac",),
    "stable_baselines3.td3.policies": ("ddpg", "td3"),
}
_SCALARS = {bool: bool, int: int, float: float, str: str, Path: Path}


class CliError(Exception):
    """A bad command-line input, reported by the parser (exit status 2)."""


# ----------------------------------------------------------------------------- options
def option(default: Any, help: str, **metadata: Any) -> Any:
    """A field of an options dataclass (:func:`options_parser`): its default (a list is copied
    for each instance), its ``help`` and any other metadata (``choices``, ``metavar``)."""
    meta = {"help": help, **metadata}
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _field_kind(cls: type, name: str, hint: Any) -> tuple[Any, bool]:
    """``(scalar type, takes a list)`` of an annotation: ``int | None`` -> (int, False),
    ``list[Path] | None`` -> (Path, True)."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and len(args) == 1:
        hint = args[0]
    if typing.get_origin(hint) is list:
        (item,) = typing.get_args(hint)
        if item in _SCALARS:
            return item, True
    elif hint in _SCALARS:
        return hint, False
    raise TypeError(f"{cls.__name__}.{name}: annotation {hint!r} has no command-line form")


def options_parser(options: type, **parser_kwargs: Any) -> argparse.ArgumentParser:
    """An ``argparse`` parser with one ``--flag`` per field of the dataclass ``options``.

    Parameters
    ----------
    options : dataclass type
        Its fields, in order: ``name`` gives ``--name`` (underscores as dashes); a ``bool`` is
        a switch (``store_true``), a ``list[T]`` takes one or more values (``nargs="+"``), any
        other type converts the value (``int``, ``float``, ``str``, ``Path``, or optional). The
        field's default (or default factory) is the option's default; ``metadata`` gives
        ``help`` (required), and optionally ``choices`` and ``metavar``.
    **parser_kwargs
        Passed to :class:`argparse.ArgumentParser` (``prog``, ``description``, ...).

    Returns
    -------
    argparse.ArgumentParser
    """
    if not (isinstance(options, type) and dataclasses.is_dataclass(options)):
        raise TypeError(f"options = {options!r}; expected a dataclass type")
    hints = typing.get_type_hints(options)
    parser = argparse.ArgumentParser(**parser_kwargs)
    for f in dataclasses.fields(options):
        flag, meta = "--" + f.name.replace("_", "-"), f.metadata
        kind, many = _field_kind(options, f.name, hints[f.name])
        if kind is bool and not many:
            parser.add_argument(flag, action="store_true", help=meta["help"])
            continue
        default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        kwargs: dict[str, Any] = {"default": default, "help": meta["help"]}
        if kind is not str or "choices" not in meta:  # a choice of strings needs no conversion
            kwargs["type"] = kind
        if many:
            kwargs["nargs"] = "+"
        for key in ("choices", "metavar"):
            if key in meta:
                kwargs[key] = meta[key]
        parser.add_argument(flag, **kwargs)
    return parser


_T = TypeVar("_T")


def filled(name: str, value: _T | None) -> _T:
    """``value`` of the option ``name``, which the command's ``parse_args`` fills in (a
    ValueError names an ``Options`` built by hand and left incomplete)."""
    if value is None:
        raise ValueError(f"Options.{name} is None; expected it filled in (use parse_args)")
    return value


def script_parser(options: type, script: str, description: str) -> argparse.ArgumentParser:
    """:func:`options_parser` of the command ``python -m benchmarks.<script>``: its console
    name, the first paragraph of ``description`` (a module's docstring may be passed whole) and
    every option's default in its help."""
    return options_parser(
        options,
        prog=prog(script),
        description=description.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )


def one_of(help: str, choices: tuple[str, ...], metavar: str) -> dict[str, Any]:
    """The ``metadata`` of a ``list[str]`` option whose values are ``choices``, listed in its
    help, shown as ``metavar``."""
    return {"help": f"{help}; one of: {', '.join(choices)}", "choices": choices, "metavar": metavar}


def parse_options(parser: argparse.ArgumentParser, options: type, argv: list[str] | None) -> Any:
    """``options(**parsed)``: the dataclass of the parsed command line ``argv``
    (``sys.argv[1:]`` if None)."""
    return options(**vars(parser.parse_args(argv)))


def file_option_error(name: str, path: Any) -> str | None:
    """Why ``path`` cannot be the output file of option ``name``: a folder or another node
    :func:`benchmarks.core.files.write_atomic` refuses (a FIFO or a character device such as
    ``/dev/null`` is written into), in a folder that does not exist or cannot be written into;
    None if it can."""
    path = Path(path)
    error = target_error(path)
    if error is not None:
        return f"{name} {path}: {error}; expected a file path in an existing folder"
    if not path.parent.is_dir():
        return f"{name} {path}: the folder {path.parent} does not exist"
    if path.exists() and not path.is_file():  # a FIFO or a device: written into, not replaced
        return None if os.access(path, os.W_OK) else f"{name} {path}: cannot be written into"
    if not os.access(path.parent, os.W_OK | os.X_OK):
        return f"{name} {path}: the folder {path.parent} cannot be written into"
    return None


# ----------------------------------------------------------------------------- output folders
#: The repository's committed results (``results/`` beside the ``benchmarks`` package): no
#: quick mode writes there.
COMMITTED_RESULTS = Path(__file__).resolve().parents[2] / "results"


def out_folder_error(name: str, path: Any) -> str | None:
    """Why ``path`` cannot be the output folder of option ``name``: something that is not a
    folder stands there or where one of its parent folders would be, or the nearest folder that
    exists on its way cannot be written into (permissions, a read-only file system); None if
    the run can make it and write into it."""
    path = Path(path)
    probe = path
    while not os.path.lexists(probe) and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        where = "" if probe == path else f" ({probe} is not a folder)"
        return f"{name} {path}: not a folder{where}; expected a folder to write into"
    if not os.access(probe, os.W_OK | os.X_OK):
        return (
            f"{name} {path}: the folder {probe} cannot be written into; expected a writable folder"
        )
    return None


def holds_full_run(out: Path) -> bool:
    """Whether ``out/summary.json`` is the report of a run without ``--quick`` (its recorded
    options say ``quick: false``)."""
    try:
        options = json.loads((Path(out) / "summary.json").read_text())["options"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return False
    return isinstance(options, dict) and options.get("quick") is False


def quick_out_error(name: str, path: Any) -> str | None:
    """Why a quick run (a smoke test) must not write into the folder ``path`` of option
    ``name``: it is :data:`COMMITTED_RESULTS` or inside it, or it holds the report of a full run
    (:func:`holds_full_run`), which the smoke test would replace; None if it may."""
    resolved = Path(path).resolve()
    if resolved == COMMITTED_RESULTS or COMMITTED_RESULTS in resolved.parents:
        why = f"that folder is in the committed results ({COMMITTED_RESULTS})"
    elif holds_full_run(resolved):
        why = "that folder holds the report of a full run"
    else:
        return None
    return (f"--quick with {name} {path}: {why}, which a smoke test never replaces; give "
            f"another {name} (or none: --quick writes to a new temporary folder)")  # fmt: skip


def quick_folder(script: str) -> Path:
    """A new temporary folder for one quick run of ``script``
    (``<temp>/sdjls-gym-<script>-XXXXXXXX``): two quick runs never share their outputs."""
    return Path(tempfile.mkdtemp(prefix=f"sdjls-gym-{script}-"))


def output_folder(parser: argparse.ArgumentParser, name: str, out: Any, *, quick: bool,
                  default: Any, script: str) -> Path:  # fmt: skip
    """The output folder of option ``name`` (``--out``), checked before any work: ``out`` if
    given, else ``default``; with ``quick`` and no ``out``, a new temporary folder of this run
    (:func:`quick_folder`). A parser error (exit status 2) names the option if the folder cannot
    be written into (:func:`out_folder_error`) or if a quick run would write into the committed
    results or over a full run's report (:func:`quick_out_error`). Call it after the other
    checks, so that a refused command leaves no temporary folder behind."""
    if out is None and quick:
        return quick_folder(script)
    folder = Path(default if out is None else out)
    error = out_folder_error(name, folder) or (quick_out_error(name, folder) if quick else None)
    if error is not None:
        parser.error(error)
    return folder


def plain_name_error(name: str, value: str) -> str | None:
    """Why ``value`` of option ``name`` is not a plain name (a file name made from it must stay
    in its folder): empty, ``.`` or ``..``, or with a path separator or a NUL; None if it is."""
    if value in ("", ".", "..") or any(c in value for c in "/\\\0"):
        return (f"{name} = {value!r}; expected a plain name (no / or \\, not . or ..): it names "
                "files in the output folder")  # fmt: skip
    return None


# ----------------------------------------------------------------------------- policies
def import_attribute(text: str, option: str) -> Any:
    """``package.module:attribute`` -> the attribute (dots in it follow attributes);
    :class:`CliError` naming ``option`` if it does not import."""
    module, sep, attribute = text.partition(":")
    if not sep or not module or not attribute:
        raise CliError(f"{option} = {text!r}; expected package.module:attribute or a .zip file")
    try:
        obj: Any = importlib.import_module(module)
    except ImportError as exc:
        raise CliError(f"{option} {text}: module {module!r} cannot be imported ({exc})") from None
    for part in attribute.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise CliError(
                f"{option} {text}: module {module!r} has no attribute {attribute!r}"
            ) from None
    return obj


def _saved_algorithms(path: str) -> tuple[str, ...] | None:
    """The ``--algo`` values that can load the SB3 file ``path`` (from the policy class it
    names), or None if the file does not say."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
        return SAVED_POLICIES.get(data["policy_class"]["__module__"])
    except Exception:  # noqa: BLE001 - not a readable SB3 file: the load reports it
        return None


def _check_sb3_options(policy: str, algo: str | None, train_env: str | None,
                       vec_normalize: str | None) -> None:  # fmt: skip
    """The options that go with a stable-baselines3 ``.zip`` ``policy``, each named."""
    if algo is None:
        raise CliError(f"--policy {policy} is a stable-baselines3 file: give --algo {SB3_ALGOS}")
    if not Path(policy).is_file():
        raise CliError(f"--policy {policy}: no such file")
    if vec_normalize is not None and not Path(vec_normalize).is_file():
        raise CliError(f"--vec-normalize {vec_normalize}: no such file")
    if vec_normalize is not None and train_env is None:
        raise CliError("--vec-normalize needs --train-env (the environment it normalized)")


def _load_sb3(policy: str, algo: str) -> Any:
    """The stable-baselines3 agent of the file ``policy`` as ``algo``."""
    try:
        import stable_baselines3
    except ImportError:
        raise CliError(
            f'--policy {policy} needs stable-baselines3: pip install -e ".[rl]"'
        ) from None
    saved = _saved_algorithms(policy)
    if saved is not None and algo not in saved:
        raise CliError(
            f"--policy {policy} holds a {'/'.join(a.upper() for a in saved)} agent, not "
            f"--algo {algo}; give --algo {saved[-1]}"
        )
    try:
        return getattr(stable_baselines3, algo.upper()).load(policy, device="cpu")
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file: name it
        raise CliError(
            f"--policy {policy} cannot be loaded as a stable-baselines3 {algo.upper()} agent "
            f"({type(exc).__name__}: {exc})"
        ) from None


def _load_vec_normalize(vec_normalize: str, env: Any) -> Any:
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    try:
        return VecNormalize.load(vec_normalize, DummyVecEnv([lambda: env]))
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file: name it
        raise CliError(
            f"--vec-normalize {vec_normalize} cannot be loaded as a VecNormalize "
            f"({type(exc).__name__}: {exc})"
        ) from None


def load_cli_policy(
    policy: str, algo: str | None, train_env: str | None, vec_normalize: str | None = None
) -> Any:
    """The policy named on the command line (``python -m benchmarks.evaluate --help``):
    ``package.module:attribute``, or a stable-baselines3 ``.zip`` with its ``--algo`` (and
    optionally its training environment and VecNormalize statistics, then wrapped in
    :class:`~benchmarks.core.policies.RawEnvPolicy`); :class:`CliError` for a file, module or
    attribute that does not load."""
    if not policy.endswith(".zip"):
        if algo is not None or train_env is not None or vec_normalize is not None:
            raise CliError(
                "--algo, --train-env and --vec-normalize apply to a stable-baselines3 .zip "
                "file only"
            )
        return import_attribute(policy, "--policy")
    _check_sb3_options(policy, algo, train_env, vec_normalize)
    assert algo is not None  # checked just above
    env = None
    if train_env is not None:  # before the agent: a bad name fails fast
        env = import_attribute(train_env, "--train-env")
        env = env() if callable(env) and not isinstance(env, gym.Env) else env
    agent = _load_sb3(policy, algo)
    if env is None:
        return agent
    norm = None if vec_normalize is None else _load_vec_normalize(vec_normalize, env)
    from benchmarks.core.policies import RawEnvPolicy

    try:
        return RawEnvPolicy(agent, env, vec_normalize=norm)
    except (TypeError, ValueError) as exc:
        raise CliError(f"--train-env {train_env}: {exc}") from None
