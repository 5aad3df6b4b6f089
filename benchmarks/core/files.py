"""Writing the benchmarks' committed files: atomically, with floats at machine-stable precision."""

from __future__ import annotations

import math
import os
import secrets
import stat
from pathlib import Path
from typing import Any

import numpy as np

from sdjls_gym.model import SDJLSModel

__all__ = ["STABLE_DIGITS", "jsonable", "stable_floats", "target_error", "write_atomic"]

#: Significant digits a float keeps in a committed JSON file. A statistic summed over thousands
#: of values differs between machines (BLAS, SIMD widths) in its last two or three of float64's
#: 17 digits; 10 digits are the same everywhere, and far more than any interval resolves.
STABLE_DIGITS = 10


def stable_floats(data: Any, digits: int = STABLE_DIGITS) -> Any:
    """``data`` (dicts, lists, tuples of JSON values) with every finite float rounded to
    ``digits`` significant digits; ints, bools, strings and non-finite floats unchanged."""
    if isinstance(data, dict):
        return {key: stable_floats(value, digits) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [stable_floats(value, digits) for value in data]
    if isinstance(data, float) and math.isfinite(data):
        return float(f"{data:.{digits}g}")
    return data


def jsonable(value: Any) -> Any:
    """``value`` with numpy out of it, for ``json.dumps``: dicts (keys as ``str``), lists and
    tuples (as lists), arrays (as nested lists), numpy scalars (as Python's); other values
    unchanged; an :class:`~sdjls_gym.SDJLSModel` as ``{"SDJLSModel": its to_dict()}``. The one
    converter of the benchmarks: the runs' fingerprints hash its output."""
    if isinstance(value, SDJLSModel):  # a user's task carries its model in env_kwargs
        return {"SDJLSModel": jsonable(value.to_dict())}
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def target_error(path: str | Path) -> str | None:
    """Why :func:`write_atomic` refuses ``path``: it exists and is a folder, a block device or a
    socket (``"is a folder"``, ...), or its symbolic links loop; None if it can write there."""
    try:
        mode = os.stat(path).st_mode  # through symbolic links
    except FileNotFoundError:
        return None  # a new file (or a link to one that does not exist yet)
    except OSError as exc:
        return f"cannot be reached ({exc.strerror})"
    if stat.S_ISREG(mode) or stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return None
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISBLK, "a block device"),
             (stat.S_ISSOCK, "a socket"))  # fmt: skip
    return "is " + next((kind for test, kind in kinds if test(mode)), "not a regular file")


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path``, never leaving a part of it.

    A regular file (or a new one) is written through a temporary file in the same folder and
    :func:`os.replace`: a reader (or an interrupted run) sees the old file or the new one,
    never a part of one. A new file gets the permissions :func:`open` gives (``0o666`` less the
    umask); a file replaced keeps its permission bits. A symbolic link is followed: the file it
    names is replaced, the link stays. A FIFO or a character device (``/dev/null``,
    ``/dev/stdout``, a terminal, the pipe of a shell's ``>(...)``) is written into: a stream has
    no old version to keep, and replacing the node would break it for everyone else.

    Raises
    ------
    ValueError
        ``path`` is a folder, a block device or a socket (:func:`target_error`).
    """
    path = Path(path)
    error = target_error(path)
    if error is not None:
        raise ValueError(
            f"path = {str(path)!r} {error}; expected a file path (or a FIFO or a character "
            "device, written into)"
        )
    raw = data.encode() if isinstance(data, str) else data
    target = Path(os.path.realpath(path))  # the file a symbolic link names
    try:
        old = target.stat()
    except FileNotFoundError:
        old = None
    if old is not None and not stat.S_ISREG(old.st_mode):  # a FIFO or a character device
        with open(target, "wb") as fh:
            fh.write(raw)
        return path
    fd, tmp = _new_file(target)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        if old is not None:
            os.chmod(tmp, stat.S_IMODE(old.st_mode))
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _new_file(target: Path) -> tuple[int, Path]:
    """A new file beside ``target`` (``.<name>.<random>.tmp``), open for writing, created with
    mode ``0o666`` so that the umask applies as it does for :func:`open` (``tempfile.mkstemp``
    creates ``0o600``)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name beside {target}")
