"""Model files: :func:`save_model` and :func:`load_model`, JSON or TOML, always UTF-8."""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from sdjls_gym.errors import InvalidModelError
from sdjls_gym.messages import a_type, describe
from sdjls_gym.model import SDJLSModel

__all__ = ["load_model", "save_model"]

SUFFIXES = (".json", ".toml")


def _as_path(path: Any) -> Path:
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(
            f"path = {describe(path)} is {a_type(path)}; expected a str or pathlib.Path "
            "ending in .json or .toml"
        )
    return Path(path)


def load_model(path: str | os.PathLike) -> SDJLSModel:
    """Read a model from a UTF-8 ``.json`` or ``.toml`` file (see :meth:`SDJLSModel.to_dict`).

    Raises
    ------
    InvalidModelError
        If ``path`` is a folder, the file cannot be parsed (the message names the file), has a
        key twice, or a field is missing or malformed (the message names the file and the
        field).
    FileNotFoundError
        If there is no such file.
    """
    path = _as_path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise InvalidModelError(f"path = {str(path)!r}: a model file must end in .json or .toml")
    if path.is_dir():
        raise InvalidModelError(
            f"path = {str(path)!r} is a folder; expected a model file (.json or .toml)"
        )
    text = None
    try:
        text = path.read_text(encoding="utf-8")
        if suffix == ".toml":
            if sys.version_info >= (3, 11):
                import tomllib
            else:  # Python 3.10
                import tomli as tomllib
            data = tomllib.loads(text)
        else:
            data = json.loads(text, object_pairs_hook=_unique_keys)
    except InvalidModelError as exc:  # a key twice (before ValueError: it is one)
        raise InvalidModelError(f"model file {str(path)!r} {exc}") from None
    except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, TOMLDecodeError
        raise InvalidModelError(
            f"model file {str(path)!r} is not valid UTF-8 {suffix[1:].upper()}: {exc}"
        ) from None
    except RecursionError:
        field, depth = _deepest_field(text or "", toml=suffix == ".toml")
        where = f" in field {field!r}" if field is not None else ""
        raise InvalidModelError(
            f"model file {str(path)!r} nests lists or tables {depth} levels deep{where}, too "
            "deep to read; model fields are arrays of at most 3 dimensions"
        ) from None
    if not isinstance(data, dict):
        raise InvalidModelError(
            f"model file {str(path)!r} holds a {type(data).__name__}; expected a table/object "
            "of model fields (A, B, P_in, ...)"
        )
    try:
        return SDJLSModel.from_dict(data)
    except InvalidModelError as exc:
        # the same class (InvalidModelTypeError stays one), the file named first
        raise type(exc)(f"model file {str(path)!r}: {exc}") from None


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """A JSON object as a dict, refusing a key twice (JSON parsers keep the last silently; TOML
    refuses it); the message is completed with the file's name by :func:`load_model`."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise InvalidModelError(
                f"has the key {key!r} twice in one object; each field must appear once"
            )
        out[key] = value
    return out


def save_model(model: SDJLSModel, path: str | os.PathLike) -> None:
    """Write ``model`` as UTF-8 JSON (``.json``) or TOML (``.toml``) readable by :func:`load_model`.

    Raises
    ------
    TypeError
        ``model`` is not an :class:`SDJLSModel` or ``path`` is not a str or path.
    ValueError
        ``path`` does not end in ``.json`` or ``.toml``, or is a folder.
    """
    if not isinstance(model, SDJLSModel):
        hint = " (SDJLSModel.from_dict builds one from a dict)" if isinstance(model, dict) else ""
        raise TypeError(
            f"model = {describe(model)} is {a_type(model)}; expected an SDJLSModel{hint}"
        )
    path = _as_path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"path = {str(path)!r} must end in .json or .toml")
    if path.is_dir():
        raise ValueError(f"path = {str(path)!r} is a folder; expected a file path")
    data = model.to_dict()
    if suffix == ".json":
        text = json.dumps(data, indent=2, ensure_ascii=False) + "\n"
    else:
        text = _to_toml(data)
    path.write_text(text, encoding="utf-8")  # not the locale's encoding: load_model reads UTF-8


def _to_toml(data: dict[str, Any]) -> str:
    """Minimal TOML writer for the flat dict of nested number lists that ``to_dict`` returns."""

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            if not math.isfinite(v):
                raise ValueError(f"cannot write non-finite number {v} to TOML")
            return repr(v)
        if isinstance(v, str):  # a TOML basic string: JSON's escapes, raw non-ASCII but DEL
            return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
        if isinstance(v, list):
            return "[" + ", ".join(value(item) for item in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    lines = [f"{key} = {value(v)}" for key, v in data.items() if v is not None]
    return "\n".join(lines) + "\n"


def _deepest_field(text: str, toml: bool) -> tuple[str | None, int]:
    """The top-level key whose value nests deepest in a JSON or TOML text, and that depth.

    A plain scan of the brackets outside strings (no parsing), for an error message about a
    file that the parser could not read.
    """
    base = 0 if toml else 1  # depth of the top-level keys: a TOML line, inside a JSON object
    depth = best = 0
    key = best_key = last_string = None
    line_start = 0
    i, size = 0, len(text)
    while i < size:
        c = text[i]
        if c == '"' or (toml and c == "'"):
            j = i + 1
            while j < size and text[j] != c:
                j += 2 if text[j] == "\\" and c == '"' else 1
            last_string = text[i + 1 : j]
            i = j + 1
            continue
        if c in "[{":
            depth += 1
            if depth > best:
                best, best_key = depth, key
        elif c in "]}":
            depth -= 1
        elif c == "\n":
            line_start = i + 1
        elif depth == base and c == ("=" if toml else ":"):
            if toml:
                key = text[line_start:i].strip().strip("\"'")
            else:
                key = last_string
        i += 1
    return best_key, best - base
