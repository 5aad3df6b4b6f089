"""What the benchmarks' command lines share: options from a dataclass, names to import, agents
to load.

:func:`options_parser` builds an ``argparse`` parser from an ``Options`` dataclass: one
``--flag-name`` per field, its type read from the annotation (``bool`` a switch; ``int``,
``float``, ``str``, ``Path``, optional or not; ``list[...]`` one or more values), its help,
choices and metavar from the field's ``metadata``. :func:`load_cli_policy` loads the policy a
``--policy`` option names (a module's attribute, or a stable-baselines3 ``.zip``: the only place
the scoring imports stable-baselines3).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import types
import typing
from pathlib import Path
from typing import Any

import gymnasium as gym

__all__ = [
    "SB3_ALGOS",
    "CliError",
    "file_option_error",
    "import_attribute",
    "load_cli_policy",
    "one_of",
    "options_parser",
    "parse_options",
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


def one_of(help: str, choices: tuple[str, ...], metavar: str) -> dict[str, Any]:
    """The ``metadata`` of a ``list[str]`` option whose values are ``choices``, listed in its
    help, shown as ``metavar``."""
    return {"help": f"{help}; one of: {', '.join(choices)}", "choices": choices, "metavar": metavar}


def parse_options(parser: argparse.ArgumentParser, options: type, argv: list[str] | None) -> Any:
    """``options(**parsed)``: the dataclass of the parsed command line ``argv``
    (``sys.argv[1:]`` if None)."""
    return options(**vars(parser.parse_args(argv)))


def file_option_error(name: str, path: Any) -> str | None:
    """Why ``path`` cannot be the output file of option ``name`` (a folder, or in a folder that
    does not exist); None if it can."""
    path = Path(path)
    if path.is_dir():
        return f"{name} {path}: is a folder; expected a file path in an existing folder"
    if not path.parent.is_dir():
        return f"{name} {path}: the folder {path.parent} does not exist"
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


def load_cli_policy(
    policy: str, algo: str | None, train_env: str | None, vec_normalize: str | None = None
) -> Any:
    """The policy named on the command line (``python -m benchmarks.evaluate --help``):
    ``package.module:attribute``, or a stable-baselines3 ``.zip`` with its ``--algo`` (and
    optionally its training environment and VecNormalize statistics, then wrapped in
    :class:`~benchmarks.policies.RawEnvPolicy`); :class:`CliError` for a file, module or
    attribute that does not load."""
    if not policy.endswith(".zip"):
        if algo is not None or train_env is not None or vec_normalize is not None:
            raise CliError(
                "--algo, --train-env and --vec-normalize apply to a stable-baselines3 .zip "
                "file only"
            )
        return import_attribute(policy, "--policy")
    if algo is None:
        raise CliError(f"--policy {policy} is a stable-baselines3 file: give --algo {SB3_ALGOS}")
    if not Path(policy).is_file():
        raise CliError(f"--policy {policy}: no such file")
    if vec_normalize is not None and not Path(vec_normalize).is_file():
        raise CliError(f"--vec-normalize {vec_normalize}: no such file")
    if vec_normalize is not None and train_env is None:
        raise CliError("--vec-normalize needs --train-env (the environment it normalized)")
    env = None
    if train_env is not None:  # before the agent: a bad name fails fast
        env = import_attribute(train_env, "--train-env")
        env = env() if callable(env) and not isinstance(env, gym.Env) else env
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
        agent = getattr(stable_baselines3, algo.upper()).load(policy, device="cpu")
    except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file: name it
        raise CliError(
            f"--policy {policy} cannot be loaded as a stable-baselines3 {algo.upper()} agent "
            f"({type(exc).__name__}: {exc})"
        ) from None
    if env is None:
        return agent
    norm = None
    if vec_normalize is not None:
        from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

        try:
            norm = VecNormalize.load(vec_normalize, DummyVecEnv([lambda: env]))
        except Exception as exc:  # noqa: BLE001 - a corrupt or foreign file: name it
            raise CliError(
                f"--vec-normalize {vec_normalize} cannot be loaded as a VecNormalize "
                f"({type(exc).__name__}: {exc})"
            ) from None
    from benchmarks.policies import RawEnvPolicy

    try:
        return RawEnvPolicy(agent, env, vec_normalize=norm)
    except (TypeError, ValueError) as exc:
        raise CliError(f"--train-env {train_env}: {exc}") from None
