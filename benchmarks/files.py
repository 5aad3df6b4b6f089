"""Writing the benchmarks' committed files: atomically, with floats at machine-stable precision."""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from sdjls_gym.model import SDJLSModel

__all__ = ["STABLE_DIGITS", "jsonable", "stable_floats", "write_atomic"]

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


def write_atomic(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and
    :func:`os.replace`: a reader (or an interrupted run) sees the old file or the new one,
    never a part of one."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
